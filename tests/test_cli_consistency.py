"""One command-line style: `detach-run` subcommands next to the earlier forms, tasks by name,
`--runs` everywhere, `--version`, `detach-run keys`, fast `--help`, and README's table."""

from __future__ import annotations

import dataclasses
import re
import resource
import subprocess
import sys
from pathlib import Path

import pytest

from detach import cli
from detach.config import ConfigError, builtin_configs, find_task_file
from detach.config.keys import SECTIONS, all_keys, field_docs, select
from detach.config.schema import SimCfg

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.parametrize(("new", "old"), [
    (["train", "lh1", "--model", "mlp", "--runs", "R", "sim.num_envs=4"],
     ["lh1", "--model", "mlp", "--out", "R", "sim.num_envs=4"]),
    (["eval", "runs/x", "--task", "lh2", "--trials", "3"], ["--eval", "runs/x", "--task", "lh2", "--trials", "3"]),
    (["resume", "runs/x", "train.max_iterations=9"], ["--resume", "runs/x", "train.max_iterations=9"]),
    (["sweep", "s.yaml", "--runs", "R", "--jobs", "2", "--quick"], ["--sweep", "s.yaml", "--out", "R", "--jobs", "2",
                                                                   "--quick"]),
])
def test_subcommands_parse_like_the_earlier_forms(new: list[str], old: list[str]) -> None:
    a, b = vars(cli.parse_args(new)), vars(cli.parse_args(old))
    assert a["command"] == b["command"] == new[0]
    for key in cli.DEFAULTS:
        assert a[key] == b[key], key


def test_the_earlier_forms_work_for_one_release_with_a_one_line_deprecation(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.chdir(tmp_path)
    assert cli.main(["follow", "--model", "mlp", "--dry-run", "--runs", "out", "sim.num_envs=4"]) == 0
    captured = capsys.readouterr()
    assert "num_envs: 4" in captured.out
    assert captured.err.splitlines() == ["detach-run: deprecated: `detach-run TASK ...` is now `detach-run train "
                                         "TASK ...` (the earlier form goes in the next release)"]
    assert cli.main(["--resume", "missing"]) == 2
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 2 and "`detach-run resume RUN_DIR`" in err[0] and "not a run folder" in err[1], err
    assert cli.main(["train", "follow", "--model", "mlp", "--dry-run", "--runs", "out"]) == 0
    assert capsys.readouterr().err == ""


def test_runs_folder_is_runs_everywhere() -> None:
    for argv in (["train", "lh1", "--runs", "R"], ["sweep", "s.yaml", "--runs", "R"], ["list", "--runs", "R"],
                 ["list", "--out", "R"], ["lh1", "--runs", "R"], ["table", "s.yaml", "--runs", "R"]):
        assert cli.parse_args(argv).runs == Path("R"), argv


def test_version(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exit_:
        cli.main(["--version"])
    assert exit_.value.code == 0
    assert re.fullmatch(r"detach-run \d+\.\d+\.\d+\S*\n", capsys.readouterr().out)


def test_task_by_name_or_path(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(tmp_path)  # no configs/ here: the shipped ones are found
    assert find_task_file("lh1").resolve() == (builtin_configs() / "tasks/lh1.yaml").resolve()
    assert find_task_file(ROOT / "configs/tasks/follow.yaml") == ROOT / "configs/tasks/follow.yaml"
    with pytest.raises(ConfigError, match="available: .*lh1"):
        find_task_file("lh9")
    mine = tmp_path / "configs" / "tasks"
    mine.mkdir(parents=True)
    (mine / "lh1.yaml").write_text("extends: x.yaml\n")
    assert find_task_file("lh1").resolve() == (mine / "lh1.yaml").resolve()  # the working directory's first


def test_dry_run_by_task_name_from_another_directory(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                     capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.chdir(tmp_path)
    assert cli.main(["train", "follow", "--model", "mlp", "--dry-run", "--runs", "out", "sim.num_envs=4"]) == 0
    text = capsys.readouterr().out
    assert "num_envs: 4" in text and re.search(r"# run folder: out/\d{8}-\d{6}-follow-mlp-s0", text)
    assert cli.main(["train", "nope", "--dry-run"]) == 2
    assert "unknown task 'nope'" in capsys.readouterr().err


def test_keys_list_every_field_with_type_default_and_doc(capsys: pytest.CaptureFixture[str]) -> None:
    keys = all_keys(tuple(s for s in SECTIONS if s != "model"))
    paths = {k.path for k in keys}
    for section, cls in SECTIONS.items():
        if section == "model":
            continue
        prefix = "" if section == "task" else f"{section}."
        for f in dataclasses.fields(cls):
            if f.init and f.metadata.get("dump") is not False:
                assert any(p == prefix + f.name or p.startswith((prefix + f.name + ".", prefix + f.name + "["))
                           for p in paths), prefix + f.name
    assert cli.main(["keys", "sim"]) == 0
    out = capsys.readouterr().out
    assert f"sim.num_envs: int = {SimCfg().num_envs}" in out
    doc = field_docs(SimCfg)["substeps"]
    assert doc and doc.split()[0] in out
    assert all(k.section == "sim" for k in select("sim"))


def test_keys_of_a_model_kind(capsys: pytest.CaptureFixture[str]) -> None:
    from detach.models.mlp import MLPCfg

    assert cli.main(["keys", "model.mlp"]) == 0
    out = capsys.readouterr().out
    for f in dataclasses.fields(MLPCfg):
        if f.init and f.name != "kind":
            assert f"model.{f.name}:" in out, f.name
    assert cli.main(["keys", "nosuch"]) == 2
    assert "sections: task, sim" in capsys.readouterr().err


@pytest.mark.parametrize("command", ["detach-scene", "detach-motion"])
def test_help_is_fast(command: str) -> None:
    """CPU time of the child (not wall time: a busy machine must not fail it)."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    out = subprocess.run([sys.executable, "-c", f"import sys; sys.argv[0] = '{command}'; "
                          f"from {'scene_builder.cli' if command == 'detach-scene' else 'detach.motion.cli'} "
                          "import main; sys.exit(main(['--help']))"], capture_output=True, text=True, cwd=ROOT)
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    assert out.returncode == 0 and "usage:" in out.stdout
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    assert cpu < 1.0, f"{command} --help took {cpu:.2f} s of CPU"


@pytest.mark.parametrize("command", cli.COMMANDS)
def test_every_subcommand_has_help_and_a_readme_row(command: str, capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exit_:
        cli.main([command, "--help"])
    assert exit_.value.code == 0
    assert f"usage: detach-run {command}" in capsys.readouterr().out
    readme = (ROOT / "README.md").read_text()
    assert f"`detach-run {command}" in readme
    assert f"detach-run {command}" in cli.DESCRIPTION


def test_scene_seed_is_named_for_coacd() -> None:
    from scene_builder.cli import _parser

    assert _parser().parse_args(["build", "--coacd-seed", "3"]).seed == 3
    assert _parser().parse_args(["build", "--seed", "3"]).seed == 3  # the earlier spelling
