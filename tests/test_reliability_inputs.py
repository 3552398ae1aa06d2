"""Bad input is one line naming what was wrong and what was expected, exit code 2, and
nothing written: command-line numbers, config values out of range, a folder that cannot be
written, YAML alias bombs and oversized files (docs/RELIABILITY.md)."""

from __future__ import annotations

import time
from pathlib import Path

import pytest

from detach import cli
from detach.config.yaml_source import MAX_YAML_BYTES, ConfigError, load_yaml, parse_scalar
from tests.test_runner_cli import FOLLOW, TINY


def _one_line(capsys: pytest.CaptureFixture[str]) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    return err[0]


@pytest.mark.parametrize("extra,message", [
    (["--trials", "0"], "--trials: expected an integer >= 1, found 0"),
    (["--trials", "-5"], "--trials: expected an integer >= 1, found -5"),
    (["--trials", "many"], "--trials: expected an integer, found 'many'"),
    (["--seed", "-1"], "--seed: expected an integer in [0, 4294967295], found -1"),
    (["--seed", str(2**32)], "--seed: expected an integer in [0, 4294967295], found 4294967296"),
    (["--no-such-flag"], "unrecognized arguments: --no-such-flag"),
    (["train.max_iterations=0"], "train.max_iterations: expected a value >= 1, found 0"),
    (["sim.num_envs=0"], "sim.num_envs: expected a value in [1, 1048576], found 0"),
    (["sim.num_envs=-4"], "sim.num_envs: expected a value in [1, 1048576], found -4"),
    (["sim.num_envs=1000000000000"], "sim.num_envs: expected a value in [1, 1048576], found 1000000000000"),
    (["eval.trials=0"], "eval.trials: expected a value >= 1, found 0"),
    (["train.gamma=1.5"], "train.gamma: expected a value in [0, 1], found 1.5"),
    (["sim.physics_dt=0"], "sim.physics_dt: expected a value > 0, found 0"),
    (["train.keep_checkpoints.last=-1"], "train.keep_checkpoints.last: expected a value >= 0, found -1"),
    (["train.learning_rate=.nan"], "train.learning_rate: expected a value > 0, found nan"),
    (["sim.physics_dt=.inf"], "sim.physics_dt: expected a finite value > 0, found inf"),
    (["train.max_grad_norm=-.inf"], "train.max_grad_norm: expected a finite value > 0, found -inf"),
    (["train.amp.grad_penalty=.inf"], "train.amp.grad_penalty: expected a finite value >= 0, found inf"),
    (["--device", "cuda:abc"], "--device: expected cpu, cuda or cuda:N, found 'cuda:abc'"),
    (["--device", "cuda:-1"], "--device: expected cpu, cuda or cuda:N, found 'cuda:-1'"),
    (["--device", "tpu"], "--device: expected cpu, cuda or cuda:N, found 'tpu'"),
])
def test_bad_numbers_are_one_line_and_create_nothing(extra: list[str], message: str, tmp_path: Path,
                                                    capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "runs"
    assert cli.main(["train", FOLLOW, "--model", "mlp", "--out", str(out), *TINY, *extra]) == 2
    assert message in _one_line(capsys)
    assert not out.exists(), "nothing half-written"


def test_eval_and_resume_check_their_numbers_too(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert cli.main(["eval", str(tmp_path), "--trials", "0"]) == 2
    assert "--trials: expected an integer >= 1, found 0" in _one_line(capsys)
    assert cli.main(["sweep", str(tmp_path / "s.yaml"), "--jobs", "0"]) == 2
    assert "--jobs: expected an integer >= 1, found 0" in _one_line(capsys)
    assert cli.main(["list", str(tmp_path), "--bogus"]) == 2
    assert "unrecognized arguments: --bogus" in _one_line(capsys)


def test_an_out_folder_that_cannot_be_written_is_one_line(tmp_path: Path,
                                                          capsys: pytest.CaptureFixture[str]) -> None:
    blocker = tmp_path / "a-file"
    blocker.write_text("not a folder")
    assert cli.main(["train", FOLLOW, "--model", "mlp", "--out", str(blocker / "runs"), *TINY]) == 2
    line = _one_line(capsys)
    assert f"cannot create a run folder under --runs {blocker / 'runs'}" in line
    assert cli.main(["train", FOLLOW, "--model", "mlp", "--out", str(blocker), *TINY]) == 2  # --out is a file
    assert f"cannot create a run folder under --runs {blocker} ({blocker} is a file)" in _one_line(capsys)
    assert blocker.read_text() == "not a folder"
    assert cli.main(["train", FOLLOW, "--model", "mlp", "--out", "/proc/detach-runs", *TINY]) == 2
    assert "cannot create a run folder under --runs /proc/detach-runs" in _one_line(capsys)


def test_a_run_folder_is_all_or_nothing(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                        capsys: pytest.CaptureFixture[str]) -> None:
    from detach.runfolder import atomic

    def read_only(*_args, **_kwargs):
        raise PermissionError(13, "Permission denied")

    monkeypatch.setattr(atomic, "atomic_writer", read_only)
    assert cli.main(["train", FOLLOW, "--model", "mlp", "--out", str(tmp_path), *TINY]) == 2
    assert "Permission denied" in _one_line(capsys)
    assert list(tmp_path.iterdir()) == [], "the half-made run folder is removed"


ALIAS_BOMB = """\
a: &a ["lol", "lol", "lol", "lol", "lol", "lol", "lol", "lol", "lol"]
b: &b [*a, *a, *a, *a, *a, *a, *a, *a, *a]
c: &c [*b, *b, *b, *b, *b, *b, *b, *b, *b]
d: &d [*c, *c, *c, *c, *c, *c, *c, *c, *c]
e: &e [*d, *d, *d, *d, *d, *d, *d, *d, *d]
f: &f [*e, *e, *e, *e, *e, *e, *e, *e, *e]
g: &g [*f, *f, *f, *f, *f, *f, *f, *f, *f]
h: &h [*g, *g, *g, *g, *g, *g, *g, *g, *g]
i: &i [*h, *h, *h, *h, *h, *h, *h, *h, *h]
"""


def test_a_yaml_alias_bomb_is_refused_at_once(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    bomb = tmp_path / "bomb.yaml"
    bomb.write_text(ALIAS_BOMB)
    assert len(ALIAS_BOMB) < 2048
    start = time.process_time()  # CPU time: a busy shared machine must not fail the test, a hang must
    assert cli.main(["train", str(bomb), "--model", "mlp", "--out", str(tmp_path / "runs")]) == 2
    assert time.process_time() - start < 10
    line = _one_line(capsys)
    assert str(bomb) in line and "possible alias bomb" in line
    with pytest.raises(ConfigError, match="possible alias bomb"):
        parse_scalar("[" + ALIAS_BOMB.splitlines()[0].split(": ", 1)[1] + ", "
                     + ", ".join(line.split(": ", 1)[1] for line in ALIAS_BOMB.splitlines()[1:]) + "]")


def test_oversized_and_deeply_nested_yaml_is_refused_without_reading_it(tmp_path: Path) -> None:
    huge = tmp_path / "huge.yaml"
    with open(huge, "w") as f:
        f.write("# padding\n" * (MAX_YAML_BYTES // 10 + 10))
        f.write("name: x\n")
    start = time.process_time()
    with pytest.raises(ConfigError, match="larger than 4 MB"):
        load_yaml(huge)
    with pytest.raises(ConfigError, match="larger than 4 MB"):
        load_yaml(Path("/dev/zero"))
    assert time.process_time() - start < 10
    deep = tmp_path / "deep.yaml"
    deep.write_text("a: " + "[" * 5000 + "]" * 5000 + "\n")
    with pytest.raises(ConfigError, match="nested more than 64 levels"):
        load_yaml(deep)
    deep.write_text("a: " + "[" * 100 + "]" * 100 + "\n")
    with pytest.raises(ConfigError, match="nested more than 64 levels"):
        load_yaml(deep)
