"""The layer order of docs/ARCHITECTURE.md, enforced on every import in the code.

Data flows one way: config -> assets -> character -> scene/sim/motion -> skills -> envs ->
models -> train -> eval -> runs -> cli/server. A module may import its own layer or a lower
one, never a higher one, and no set of modules may import each other in a cycle. Every import
counts, also those inside functions and under TYPE_CHECKING. `from a.b import c` depends on
module a.b (the package a.b's __init__ when a.b is a package).
"""

from __future__ import annotations

import ast
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("detach", "scene_builder", "server")

LAYERS: tuple[tuple[str, tuple[str, ...]], ...] = (
    ("config", ("detach", "detach.yaml_source", "detach.config_validate", "detach.config_schema",
                "detach.config", "detach.torch_math", "detach.host_sync", "detach.run_contract")),
    ("assets", ("scene_builder",)),
    ("character", ("detach.character",)),
    ("scene", ("scene_builder.scene", "detach.sim", "detach.motion")),
    ("skills", ("detach.skills",)),
    ("envs", ("detach.envs",)),
    ("models", ("detach.models",)),
    ("train", ("detach.train",)),
    ("eval", ("detach.eval",)),
    ("runs", ("detach.runs",)),
    ("cli", ("detach.cli", "scene_builder.cli", "detach.motion.cli", "server")),
)
"""Layer name and the module prefixes in it; the longest matching prefix decides."""


def modules() -> dict[str, Path]:
    out = {}
    for pkg in PACKAGES:
        for path in (ROOT / pkg).rglob("*.py"):
            parts = path.relative_to(ROOT).with_suffix("").parts
            name = ".".join(parts[:-1] if parts[-1] == "__init__" else parts)
            out[name] = path
    return out


def layer_of(module: str) -> int:
    best, best_len = None, -1
    for i, (_name, prefixes) in enumerate(LAYERS):
        for p in prefixes:
            if (module == p or module.startswith(p + ".")) and len(p) > best_len:
                best, best_len = i, len(p)
    assert best is not None, f"{module} is in no layer: add it to LAYERS and docs/ARCHITECTURE.md"
    return best


def imports(name: str, path: Path, known: dict[str, Path]) -> set[str]:
    """Project modules imported by one module (resolved to the deepest known module)."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    is_pkg = path.name == "__init__.py"
    found = set()
    for node in ast.walk(tree):
        targets: list[str] = []
        if isinstance(node, ast.Import):
            targets = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = name.split(".") if is_pkg else name.split(".")[:-1]
                anchor = anchor[:len(anchor) - (node.level - 1)]
                base = ".".join([*anchor, base] if base else anchor)
            targets = [f"{base}.{a.name}" if f"{base}.{a.name}" in known else base for a in node.names]
        for t in targets:
            while t and t not in known:
                t = t.rpartition(".")[0]
            if t and t != name:
                found.add(t)
    return found


def graph() -> dict[str, set[str]]:
    known = modules()
    return {name: imports(name, path, known) for name, path in known.items()}


def test_no_import_runs_against_the_layer_order() -> None:
    upward = []
    for module, deps in sorted(graph().items()):
        for dep in sorted(deps):
            if layer_of(dep) > layer_of(module):
                upward.append(f"{module} ({LAYERS[layer_of(module)][0]}) imports {dep} "
                              f"({LAYERS[layer_of(dep)][0]})")
    assert not upward, "imports against the layer order:\n" + "\n".join(upward)


def test_no_import_cycle() -> None:
    g = graph()
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    cycles: list[list[str]] = []

    def visit(v: str) -> None:  # Tarjan's strongly connected components
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in g[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                cycles.append(sorted(comp))

    for v in sorted(g):
        if v not in index:
            visit(v)
    assert not cycles, f"import cycles: {cycles}"


def test_no_package_level_cycle() -> None:
    """Between packages too (e.g. runs <-> train): collapse modules to their package."""
    def pkg(m: str) -> str:
        return ".".join(m.split(".")[:2])

    edges: dict[str, set[str]] = {}
    for module, deps in graph().items():
        edges.setdefault(pkg(module), set()).update(pkg(d) for d in deps if pkg(d) != pkg(module))
    for a, targets in edges.items():
        for b in targets:
            assert a not in _reachable(edges, b), f"package cycle through {a} and {b}"


def _reachable(edges: dict[str, set[str]], start: str) -> set[str]:
    seen, todo = set(), [start]
    while todo:
        v = todo.pop()
        for w in edges.get(v, ()):
            if w not in seen:
                seen.add(w)
                todo.append(w)
    return seen


def test_no_character_name_outside_the_character_package() -> None:
    """Characters are plug-ins: no code outside detach/character branches on a name."""
    found = []
    for name, path in modules().items():
        if name.startswith("detach.character"):
            continue
        for i, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
            if re.search(r"""["']puppet["']""", line):
                found.append(f"{path.relative_to(ROOT)}:{i}: {line.strip()}")
    assert not found, "\n".join(found)


def test_code_cites_only_documents_of_the_repository() -> None:
    cited = set()
    for path in modules().values():
        cited |= set(re.findall(r"(?:[a-z_]+/)*[A-Z_]+\.md", path.read_text(encoding="utf-8")))
    missing = [c for c in cited if not (ROOT / c).exists() and ("/" in c or (
        not (ROOT / "docs" / c).exists() and not (ROOT / "benchmarks" / c).exists()))]
    assert not missing, f"cited but not in the repository: {missing}"


def test_the_linter_excludes_no_code_folder() -> None:
    """ruff's `extend-exclude` takes a bare name ("runs") for every folder of that name in the
    tree: it once left out detach/runs/ with the top-level runs/ folder, whose unused imports
    and long lines went unseen. Only anchored paths ("./runs") may name a folder."""
    import tomllib

    patterns = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["ruff"].get("extend-exclude", [])
    bare = {p.strip("/") for p in patterns if "/" not in p.strip("/")}
    folders = {d.name for pkg in (*PACKAGES, "tests", "benchmarks") for d in (ROOT / pkg).rglob("*") if d.is_dir()}
    named = bare & (folders | set(PACKAGES))
    assert not named, f"extend-exclude names code folders: {sorted(named)}"


# ------------------------------------------------------------------ the API under the command line
CLI_MAX_LINES = 550
"""detach/cli.py is argparse definitions plus one call per command (835 lines with run logic)."""

CLI_MAY_IMPORT = {"detach.config", "detach.eval.trial_sets", "detach.runs.actions", "detach.runs.command",
                  "detach.runs.listing", "detach.runs.tables_cli", "detach.config_keys"}
"""ConfigError and a flag's bound; the API; how a command ends; the read-only reports (list,
table, keys). Anything else (run folders, sessions, jobs, training, sweeps) is run logic, which
belongs to the API (`detach.runs.actions`), where a sweep's worker calls it too."""


def test_no_module_of_detach_imports_the_dashboard() -> None:
    """`detach-run play` finds the live viewer through the `detach.viewers` entry point."""
    found = [f"{module} imports {dep}" for module, deps in sorted(graph().items()) if module.startswith("detach")
             for dep in sorted(deps) if dep == "server" or dep.startswith("server.")]
    assert not found, "\n".join(found)


def test_the_command_line_only_parses_and_calls_the_api() -> None:
    path = ROOT / "detach" / "cli.py"
    lines = len(path.read_text(encoding="utf-8").splitlines())
    assert lines <= CLI_MAX_LINES, f"detach/cli.py has {lines} lines (at most {CLI_MAX_LINES}): move logic to the API"
    extra = imports("detach.cli", path, modules()) - CLI_MAY_IMPORT
    assert not extra, f"detach/cli.py imports {sorted(extra)}: call detach.runs.actions instead"


def test_a_sweep_launches_cells_only_through_the_worker_entry() -> None:
    """No module of detach builds a `python -m detach.cli` command line; the sweep's launchers
    run `detach.runs.worker` on a job file, and the worker calls the API's functions."""
    old_form = [str(path.relative_to(ROOT)) for name, path in modules().items()
                if name.startswith("detach.") and name != "detach.cli"
                and re.search(r"""["']detach\.cli["']""", path.read_text(encoding="utf-8"))]
    assert not old_form, f"modules building a detach.cli command line: {old_form}"
    from detach.runs import actions, job_file, sweep_launchers, worker

    launchers = (ROOT / "detach/runs/sweep_launchers.py").read_text(encoding="utf-8")
    assert launchers.count("subprocess.Popen(") == 1 and "subprocess.Popen(worker_command(" in launchers
    assert sweep_launchers.worker_command is job_file.worker_command
    assert job_file.worker_command(Path("j.json"))[1:] == ["-m", worker.__name__, "j.json"]
    assert set(worker.ACTIONS) == set(job_file.JOB_ACTIONS)
    assert all(worker.ACTIONS[name] is getattr(actions, name) for name in job_file.JOB_ACTIONS)
    assert all(callable(getattr(actions, name)) for name in ("train", "resume", "evaluate", "export", "play"))
