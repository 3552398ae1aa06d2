"""Optional launch form: start `detach-run` as a child process (only with --allow-launch).

Every value of the form is checked on the server against the server's own lists, never
against what the browser sends: a websocket client can send any value for a dropdown (and
even replace the dropdown's options), so the task and model must be names found in configs/,
the task file must resolve inside configs/tasks/, the seed is range-checked, overrides may
only set training keys, and at most `limit` launched runs may be alive at once.

The dashboard never talks to the run it starts: the new run folder shows up in the runs
panel like any other. The child gets its own session and writes its console to a file in
the temp folder (not to a pipe), so stopping the dashboard does not stop the training; the
panel shows the tail of that console until the child exits.
"""

from __future__ import annotations

import os
import re
import shlex
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Sequence

import viser

from server.markup import md_code, md_text

MAX_SEED = 2**31 - 1
"""Seeds are 0 .. 2**31 - 1 (what numpy and torch accept everywhere)."""
DEFAULT_LIMIT = 2
"""Runs started from the dashboard that may be alive at the same time."""
OVERRIDE_SECTIONS = ("sim", "env", "train", "eval", "rewards", "model")
"""Config sections a launch may override; not the task (its scene names files) and not
`model.kind` (which names a Python module to import)."""
_OVERRIDE = re.compile(r"^\+?(?P<key>(?:%s)(?:\.[A-Za-z_][A-Za-z0-9_/]*(?:\[\d+\])?)+)=(?P<value>.*)$"
                       % "|".join(OVERRIDE_SECTIONS))
FORBIDDEN_KEYS = ("model.kind",)


class LaunchRefused(ValueError):
    """A launch request that is not started; the message is one line for the form."""


@dataclass(frozen=True)
class LaunchRequest:
    task: str
    model: str
    seed: int
    overrides: tuple[str, ...] = ()


def config_dir() -> Path | None:
    """configs/ of the working directory, else of the source checkout."""
    for root in (Path.cwd(), Path(__file__).resolve().parents[1]):
        if (root / "configs" / "tasks").is_dir():
            return root / "configs"
    return None


@dataclass(frozen=True)
class LaunchOptions:
    """What the form offers: task and model names found in configs/ at start-up."""

    configs: Path
    tasks: tuple[str, ...]
    models: tuple[str, ...]

    @classmethod
    def find(cls, configs: Path | None = None) -> "LaunchOptions | None":
        configs = configs or config_dir()
        if configs is None:
            return None
        tasks = tuple(sorted(p.stem for p in (configs / "tasks").glob("*.yaml")))
        models = tuple(sorted(p.stem for p in (configs / "models").glob("*.yaml")))
        return cls(configs.resolve(), tasks, models)

    def task_file(self, task: str) -> Path:
        """configs/tasks/<task>.yaml, refused unless it resolves inside configs/tasks/."""
        folder = (self.configs / "tasks").resolve()
        path = (folder / f"{task}.yaml").resolve()
        if not path.is_relative_to(folder) or not path.is_file():
            raise LaunchRefused(f"task {task!r} is not a file in {folder}")
        return path

    def validate(self, task: Any, model: Any, seed: Any, overrides: Any) -> LaunchRequest:
        """The request, or LaunchRefused naming the value and what was expected."""
        if not isinstance(task, str) or task not in self.tasks:
            raise LaunchRefused(f"task {task!r} is not one of {', '.join(self.tasks)}")
        self.task_file(task)
        if not isinstance(model, str) or model not in self.models:
            raise LaunchRefused(f"model {model!r} is not one of {', '.join(self.models)}")
        if isinstance(seed, bool) or not isinstance(seed, (int, float)) or \
                not float(seed).is_integer() or not 0 <= seed <= MAX_SEED:
            raise LaunchRefused(f"seed {seed!r} must be a whole number from 0 to {MAX_SEED}")
        return LaunchRequest(task, model, int(seed), parse_overrides(overrides))


def parse_overrides(text: Any) -> tuple[str, ...]:
    """`key=value ...` (shell quoting) with keys of `OVERRIDE_SECTIONS` only."""
    if not isinstance(text, str):
        raise LaunchRefused(f"overrides must be text, found {type(text).__name__}")
    if "\n" in text or "\r" in text or "\x00" in text:
        raise LaunchRefused("overrides must be one line")
    try:
        words = shlex.split(text)
    except ValueError as exc:
        raise LaunchRefused(f"overrides: {exc}") from None
    for word in words:
        m = _OVERRIDE.match(word)
        if m is None:
            raise LaunchRefused(
                f"override {word!r} must be key=value with a key under "
                f"{', '.join(s + '.' for s in OVERRIDE_SECTIONS)}")
        if m.group("key") in FORBIDDEN_KEYS:
            raise LaunchRefused(f"override {word!r}: {m.group('key')} cannot be set from the "
                                f"dashboard")
    return tuple(words)


def launch_command(task_file: Path, model: str, seed: int, runs_dir: Path,
                   overrides: Sequence[str] = ()) -> list[str]:
    """argv of the run (no shell)."""
    return [sys.executable, "-m", "detach.cli", "train", str(task_file), "--model", model,
            "--seed", str(int(seed)), "--runs", str(runs_dir), *overrides]


@dataclass
class Launched:
    proc: subprocess.Popen
    log_path: Path
    shown: str
    """The command as shown in the form (without the interpreter)."""


class Launcher:
    """Starts validated requests; refuses while `limit` launched runs are still alive."""

    def __init__(self, options: LaunchOptions, runs_dir: Path, limit: int = DEFAULT_LIMIT) -> None:
        self.options, self.runs_dir, self.limit = options, Path(runs_dir), limit
        self.launched: list[Launched] = []
        self._lock = threading.Lock()

    def alive(self) -> list[Launched]:
        return [run for run in self.launched if run.proc.poll() is None]

    def start(self, request: LaunchRequest) -> Launched:
        with self._lock:
            alive = self.alive()
            if len(alive) >= self.limit:
                raise LaunchRefused(f"{len(alive)} runs started here are still running (at most "
                                    f"{self.limit} at a time; see --launch-limit)")
            cmd = launch_command(self.options.task_file(request.task), request.model,
                                 request.seed, self.runs_dir.resolve(), request.overrides)
            fd, name = tempfile.mkstemp(prefix="detach-dashboard-launch-", suffix=".log")
            with os.fdopen(fd, "w", encoding="utf-8") as out:  # a file, not a pipe: the run
                proc = subprocess.Popen(cmd, cwd=self.options.configs.parent, stdout=out,
                                        stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                                        start_new_session=True)  # outlives the dashboard
            launched = Launched(proc, Path(name), " ".join(shlex.quote(c) for c in cmd[1:]))
            self.launched.append(launched)
            return launched


def launch_panel(gui: viser.GuiApi, launcher: Launcher | None) -> None:
    """Task, model, seed, overrides and a start button; shows the child's output."""
    if launcher is None:
        gui.add_markdown("*No configs/ folder found: start the dashboard from the checkout.*")
        return
    options = launcher.options
    task = gui.add_dropdown("Task", options.tasks,
                            initial_value="lh1" if "lh1" in options.tasks else None)
    model = gui.add_dropdown("Model", options.models,
                             initial_value="detach" if "detach" in options.models else None)
    seed = gui.add_number("Seed", 0, min=0, max=MAX_SEED, step=1)
    overrides = gui.add_text("Overrides", "", hint="key=value ... (YAML values) under "
                             + ", ".join(OVERRIDE_SECTIONS) + ", e.g. train.max_iterations=50")
    start = gui.add_button("Start run", icon=viser.Icon.ROCKET, color="green")
    output = gui.add_markdown(f"Runs are written to `{launcher.runs_dir}`; at most "
                              f"{launcher.limit} started here run at a time.")

    @start.on_click
    def _(_event: object) -> None:
        try:
            request = options.validate(task.value, model.value, seed.value, overrides.value)
            launched = launcher.start(request)
        except LaunchRefused as exc:
            output.content = f"**Not started:** {md_text(exc)}"
            return
        output.content = f"Started pid {launched.proc.pid}: {md_code('python ' + launched.shown)}"
        threading.Thread(target=follow_output, args=(launched, output), daemon=True).start()


def follow_output(launched: Launched, output: Any) -> None:
    """Show the last lines the child printed (its console log), then its exit code."""
    last = None
    proc = launched.proc
    while True:
        code = proc.poll()
        try:
            text = launched.log_path.read_text(encoding="utf-8", errors="replace")
        except OSError:
            text = ""
        # progress bars redraw with carriage returns: show each line's final state
        lines = [ln.rsplit("\r", 1)[-1] for ln in text.splitlines() if ln.strip()][-12:]
        state = "running" if code is None else f"exited with code {code}"
        content = (f"pid {proc.pid} {state}: {md_code('python ' + launched.shown)} (console: "
                   f"{md_code(launched.log_path)})\n\n```\n"
                   + "\n".join(lines).replace("```", "'''") + "\n```")  # the fence stays closed
        if content != last:
            output.content = last = content
        if code is not None:
            return
        time.sleep(1.0)
