"""Optional launch form: start `detach-run` as a child process (only with --allow-launch).

The dashboard never talks to the run it starts: the new run folder shows up in the runs
panel like any other. The child gets its own session and writes its console to a file in
the temp folder (not to a pipe), so stopping the dashboard does not stop the training; the
panel shows the tail of that console until the child exits.
"""

from __future__ import annotations

import os
import shlex
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import viser


def config_dir() -> Path | None:
    """configs/ of the working directory, else of the source checkout."""
    for root in (Path.cwd(), Path(__file__).resolve().parents[1]):
        if (root / "configs" / "tasks").is_dir():
            return root / "configs"
    return None


def launch_command(task_file: Path, model: str, seed: int, runs_dir: Path,
                   overrides: str = "") -> list[str]:
    """argv of the run (no shell); raises ValueError on an override without '='."""
    extra = shlex.split(overrides)
    bad = [o for o in extra if "=" not in o or o.startswith("-")]
    if bad:
        raise ValueError(f"overrides must be key=value, found {' '.join(bad)!r}")
    return [sys.executable, "-m", "detach.cli", str(task_file), "--model", model,
            "--seed", str(int(seed)), "--out", str(runs_dir), *extra]


def launch_panel(gui: viser.GuiApi, runs_dir: Path) -> None:
    """Task, model, seed, overrides and a start button; shows the child's output."""
    configs = config_dir()
    if configs is None:
        gui.add_markdown("*No configs/ folder found: start the dashboard from the checkout.*")
        return
    tasks = sorted(p.stem for p in (configs / "tasks").glob("*.yaml"))
    models = sorted(p.stem for p in (configs / "models").glob("*.yaml"))
    task = gui.add_dropdown("Task", tasks, initial_value="lh1" if "lh1" in tasks else None)
    model = gui.add_dropdown("Model", models,
                             initial_value="detach" if "detach" in models else None)
    seed = gui.add_number("Seed", 0, min=0, step=1)
    overrides = gui.add_text("Overrides", "", hint="key=value ... (YAML values), e.g. "
                                                   "train.max_iterations=50")
    start = gui.add_button("Start run", icon=viser.Icon.ROCKET, color="green")
    output = gui.add_markdown(f"Runs are written to `{runs_dir}`.")

    @start.on_click
    def _(_event: object) -> None:
        try:
            cmd = launch_command(configs / "tasks" / f"{task.value}.yaml", model.value,
                                 int(seed.value), runs_dir.resolve(), overrides.value)
        except ValueError as exc:
            output.content = f"**Not started:** {exc}"
            return
        fd, name = tempfile.mkstemp(prefix="detach-dashboard-launch-", suffix=".log")
        log_path = Path(name)
        with os.fdopen(fd, "w", encoding="utf-8") as out:  # a file, not a pipe: the run
            proc = subprocess.Popen(cmd, cwd=configs.parent, stdout=out,  # outlives us
                                    stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                                    start_new_session=True)
        shown = " ".join(shlex.quote(c) for c in cmd[1:])
        output.content = f"Started pid {proc.pid}: `python {shown}`"
        threading.Thread(target=_follow, args=(proc, log_path, output, shown),
                         daemon=True).start()


def _follow(proc: subprocess.Popen, log_path: Path, output: viser.GuiMarkdownHandle,
            shown: str) -> None:
    """Show the last lines the child printed (its console log), then its exit code."""
    last = None
    while True:
        code = proc.poll()
        try:
            text = log_path.read_text(encoding="utf-8", errors="replace")
        except OSError:
            text = ""
        # progress bars redraw with carriage returns: show each line's final state
        lines = [ln.rsplit("\r", 1)[-1] for ln in text.splitlines() if ln.strip()][-12:]
        state = "running" if code is None else f"exited with code {code}"
        content = (f"pid {proc.pid} {state}: `python {shown}` (console: `{log_path}`)\n\n"
                   "```\n" + "\n".join(lines) + "\n```")
        if content != last:
            output.content = last = content
        if code is not None:
            return
        time.sleep(1.0)
