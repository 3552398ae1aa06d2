"""Hostile run folders (links out of the folder, FIFOs, huge and exploding files, copies) and a
hostile browser (a backtracking filter, names that are HTML): every reader stays bounded, shows
no file from outside the run folder and never hangs (docs/RELIABILITY.md, issue 62)."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import threading
import time
from html.parser import HTMLParser
from pathlib import Path
from typing import Any, Callable

import pytest

from detach import cli
from detach.config import resolve
from detach.runfolder.folder import RunFolder, find_runs
from detach.runs.tables_cli import collect_evals
from server.run_index import RunIndex
from tests.test_reliability_tables import _eval
from tests.test_runner_cli import FOLLOW, TINY

SECRET = "TOPSECRET root:x:0:0:root:/root:/bin/bash"


def _run(parent: Path, rate: float = 0.5) -> RunFolder:
    run = RunFolder.create(parent, resolve(FOLLOW, "mlp"))
    run.set_state("finished")
    run.eval_path.write_text(json.dumps(_eval(rate)))
    run.stdout_path.write_text("training...\ndone\n")
    return run


def _within(seconds: float, fn: Callable[..., Any], *args: Any) -> Any:
    """fn(*args), failing the test (not hanging it) when it does not return in time."""
    out: dict[str, Any] = {}

    def call() -> None:
        try:
            out["value"] = fn(*args)
        except BaseException as exc:  # noqa: BLE001 - re-raised in the test's thread
            out["error"] = exc

    thread = threading.Thread(target=call, daemon=True)
    thread.start()
    thread.join(seconds)
    assert not thread.is_alive(), f"{getattr(fn, '__name__', fn)} still blocked after {seconds} s"
    if "error" in out:
        raise out["error"]
    return out["value"]


def _shown(fn: Callable[[], str]) -> str:
    """What a reader gives the page: its text, or the one line of its refusal."""
    try:
        return fn()
    except (OSError, ValueError) as exc:
        return str(exc)


def test_a_file_linked_out_of_the_run_folder_is_never_shown(tmp_path: Path,
                                                            capsys: pytest.CaptureFixture[str]) -> None:
    secret = tmp_path / "secret.txt"
    secret.write_text(SECRET + "\n")
    runs = tmp_path / "runs"
    good, run = _run(runs), _run(runs)
    run.config_path.unlink()
    run.config_path.symlink_to(secret)
    run.stdout_path.unlink()
    run.stdout_path.symlink_to(secret)
    (good.path / "inner.log").write_text("inside\n")
    good.stdout_path.unlink()
    good.stdout_path.symlink_to("inner.log")  # a link inside the run folder is fine

    assert cli.main(["list", str(runs)]) == 0
    out = capsys.readouterr().out
    assert "TOPSECRET" not in out
    (note,) = [line for line in out.splitlines() if line.startswith(f"  {run.path.name}:")]
    assert "config.yaml" in note and "leaves the run folder" in note
    assert cli.main(["resume", str(run.path)]) == 2
    err = capsys.readouterr().err
    assert "TOPSECRET" not in err and len(err.strip().splitlines()) == 1

    index = RunIndex(runs)
    infos = {i.run_id: i for i in index.refresh()}
    assert any("leaves the run folder" in p for p in infos[run.path.name].problems)
    reader = index.reader(run.path.name)
    assert reader is not None
    for shown in (_shown(reader.config_text), _shown(reader.stdout_tail)):
        assert "TOPSECRET" not in shown and "leaves the run folder" in shown
    assert index.reader(good.path.name).stdout_tail() == "inside"


def _unblock(fifo: Path) -> None:
    """Open the FIFO for writing once, so that a reader blocked in open() (the bug) returns."""
    try:
        os.close(os.open(fifo, os.O_WRONLY | os.O_NONBLOCK))
    except OSError:
        pass


def test_a_fifo_in_a_run_folder_hangs_no_reader(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    good, run = _run(tmp_path, 0.25), _run(tmp_path)
    run.eval_path.unlink()
    os.mkfifo(run.eval_path)
    try:
        assert _within(20, cli.main, ["list", str(tmp_path)]) == 0
        out = capsys.readouterr().out
        assert f"  {run.path.name}: eval.json ignored:" in out and "named pipe" in out
        assert _within(20, cli.main, ["table", str(tmp_path), "--kind", "skills", "--task", "follow",
                                      "--out", str(tmp_path / "tables")]) == 0
        err = capsys.readouterr().err
        assert f"skipped {run.eval_path}" in err and "named pipe" in err
        infos = {i.run_id: i for i in _within(20, RunIndex(tmp_path).refresh)}
        assert any("named pipe" in p for p in infos[run.path.name].problems)
        assert infos[good.path.name].lh_sr == 0.25
    finally:
        for _ in range(3):
            _unblock(run.eval_path)


def _alias_bomb(levels: int = 7) -> str:
    """A few hundred bytes of YAML that expand to 9**levels values."""
    anchors = ['&a0 ["x","x","x","x","x","x","x","x","x"]']
    anchors += [f"&a{i} [" + ",".join([f"*a{i - 1}"] * 9) + "]" for i in range(1, levels)]
    return "task_name: [" + ", ".join(anchors) + "]\nmodel_name: mlp\nseed: 0\n"


def test_the_dashboard_refuses_oversized_endless_and_exploding_files(tmp_path: Path) -> None:
    big, endless, bomb = _run(tmp_path), _run(tmp_path), _run(tmp_path)
    with open(big.eval_path, "r+b") as f:
        f.truncate(200 * 1024 * 1024)  # sparse: 200 MB on paper, nothing on the disk
    endless_eval = endless.path / "eval_lh2.json"
    endless_eval.symlink_to("/dev/zero")
    bomb.config_path.write_text(_alias_bomb())
    assert len(_alias_bomb()) < 600

    start = time.monotonic()
    infos = {i.run_id: i for i in _within(30, RunIndex(tmp_path).refresh)}
    assert time.monotonic() - start < 10
    assert any("eval.json" in p and "larger than 16 MB" in p for p in infos[big.path.name].problems)
    assert any("eval_lh2.json" in p and "refused" in p for p in infos[endless.path.name].problems)
    problems = infos[bomb.path.name].problems
    assert any("config.yaml" in p and "200000 values" in p for p in problems), problems
    assert len(infos[bomb.path.name].task) < 100


@pytest.mark.parametrize("pattern", [".*.*.*.*.*.*.*.*Z", "(.|.)*Z", "(a+)+Z", "(a|aa)*Z", "(x*)*(y*)*Z"])
def test_the_metric_filter_takes_linear_time_whatever_the_pattern(pattern: str) -> None:
    from server.curves import matching

    keys = [f"Loss/{'a' * 16}{i:02d}" for i in range(20)]  # a backtracking engine: seconds already
    start = time.monotonic()
    assert matching(keys, pattern) == []
    assert time.monotonic() - start < 0.5, "a backtracking pattern must not stall the server"
    assert matching(["Loss/value", "Loss/surrogate", "Train/lr"], "loss/(value|surr)") == [
        "Loss/value", "Loss/surrogate"], "regular expressions still work"


ALLOWED_TAGS = {"p", "div", "table", "thead", "tbody", "tr", "th", "td", "strong", "em", "code",
                "ul", "li", "span", "br", "pre"}


class _Tags(HTMLParser):
    def __init__(self) -> None:
        super().__init__()
        self.tags: list[tuple[str, list[tuple[str, str | None]]]] = []

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        self.tags.append((tag, attrs))


def _rendered_tags(markdown: str) -> list[tuple[str, list[tuple[str, str | None]]]]:
    """The HTML tags a browser gets from this Markdown (raw HTML passes, as in viser)."""
    from markdown_it import MarkdownIt

    parser = _Tags()
    parser.feed(MarkdownIt("commonmark", {"html": True}).enable("table").render(markdown))
    return parser.tags


HOSTILE = ["<img src=x onerror=alert(1)>", "<script>alert(2)</script>", "[click](javascript:alert(3))",
           "![](http://evil.example/t.png)", "a`<b>`b|c\n<iframe src=//evil>", "<http://evil.example>"]


def test_text_from_run_folders_reaches_the_page_as_text_not_html(tmp_path: Path) -> None:
    from server.curves import legend_markdown
    from server.run_index import RunInfo
    from server.run_views import diff_markdown, run_labels, runs_table, status_markdown

    infos = [RunInfo(run_id=f"2026-{i}-{name}", path=tmp_path, task=name, model=name, seed=i,
                     cell=f"{name}/x/{name}/s0", state="failed", error=name, problems=(name,) if i % 2 else ())
             for i, name in enumerate(HOSTILE)]
    labels = run_labels(infos)
    pages = [runs_table(infos, [i.run_id for i in infos], by)
             for by in ("nothing", "task", "model", "sweep cell", "state")]
    pages += [status_markdown(i) for i in infos]
    pages += [diff_markdown(HOSTILE[0], HOSTILE[1], [(name, name, {"k": name}) for name in HOSTILE]),
              legend_markdown(list(labels.values()))]
    for page in pages:
        for tag, attrs in _rendered_tags(page):
            assert tag in ALLOWED_TAGS, f"<{tag}> reached the page from:\n{page}"
            assert not any(k.startswith("on") or k in ("src", "href") for k, _v in attrs), (tag, attrs)


def _dead_pid() -> int:
    proc = subprocess.Popen([sys.executable, "-c", "pass"])
    proc.wait()
    return proc.pid


def test_a_run_killed_before_its_first_checkpoint_restarts_from_iteration_0(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from detach.train.run_config import resolve_run

    run = RunFolder.create(tmp_path, resolve_run(FOLLOW, "mlp", [*TINY, "train.max_iterations=1"]))
    run.set_state("running", iteration=0)
    status = json.loads(run.status_path.read_text())
    run.status_path.write_text(json.dumps({**status, "pid": _dead_pid()}))
    orphan = run.checkpoints / "amp_replay_7.pt"  # its model_7.pt was never written (killed between)
    orphan.write_bytes(b"half a replay buffer")
    assert cli.main(["list", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "no checkpoint yet" in out and f"detach-run --resume {run.path}" in out
    assert cli.main(["--resume", str(run.path), "--no-eval"]) == 0, capsys.readouterr().err
    assert "restarting it from iteration 0" in capsys.readouterr().out
    assert run.status().state == "finished" and run.latest_checkpoint() is not None
    assert not orphan.exists()
    for sidecar in run.checkpoints.glob("amp_replay_*.pt"):
        assert (run.checkpoints / sidecar.name.replace("amp_replay_", "model_")).exists(), sidecar


def test_trials_are_recorded_so_that_resume_and_re_evaluation_repeat_them(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert cli.main(["train", FOLLOW, "--model", "mlp", "--out", str(tmp_path), "--trials", "2", "--no-eval",
                     "train.max_iterations=1", *TINY]) == 0
    (run,) = find_runs(tmp_path)
    assert run.config().eval.trials == 2, "config.yaml records --trials"
    assert cli.main(["resume", str(run.path)]) == 0, capsys.readouterr().err  # killed in its evaluation
    assert json.loads(run.eval_path.read_text())["trials"] == 2
    old = RunFolder(tmp_path / "old")  # a run folder of an earlier version: no eval.trials
    shutil.copytree(run.path, old.path)
    text = old.config_path.read_text()
    assert "eval: {trials: 2, " in text
    old.config_path.write_text(text.replace("eval: {trials: 2, ", "eval: {", 1))
    assert old.config().eval.trials == 100, "a config without eval.trials means the old default"


def test_a_copied_run_folder_counts_once_with_a_warning(tmp_path: Path,
                                                         capsys: pytest.CaptureFixture[str]) -> None:
    run, other = _run(tmp_path, 0.5), _run(tmp_path, 0.25)
    shutil.copytree(run.path, tmp_path / (run.path.name + ".bak"))
    evals = collect_evals(find_runs(tmp_path))
    assert sorted(e.lh_success.rate for e in evals) == [0.25, 0.5]
    assert sum(e.trials for e in evals) == 20, "n does not double"
    err = capsys.readouterr().err
    assert "copy" in err and run.path.name in err
    assert cli.main(["list", str(tmp_path)]) == 0
    assert f"copy of {run.path.name}" in capsys.readouterr().out
    from server.run_index import RunIndex

    index = RunIndex(tmp_path)  # the dashboard's tables count the copy once too
    index.refresh()
    assert sum(e.trials for _r, e in index.evals_by_run()) == 20
    for folder in (run, other):  # folders of earlier versions have no run id: each is its own run
        status = json.loads(folder.status_path.read_text())
        status.pop("run_id", None)
        folder.status_path.write_text(json.dumps(status))
    shutil.rmtree(tmp_path / (run.path.name + ".bak"))
    assert len(collect_evals(find_runs(tmp_path))) == 2
