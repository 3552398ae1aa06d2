"""The layer order of docs/ARCHITECTURE.md, enforced on every import in the code.

Data flows one way: config -> runfolder -> assets -> character -> scene/sim/motion -> skills -> envs ->
models -> train -> eval -> runs -> cli/server/public face (`detach/__init__.py`). A module may
import its own layer or a lower one, never a higher one, and no set of modules may import each
other in a cycle. Every import counts, also those inside functions and under TYPE_CHECKING.
`from a.b import c` depends on module a.b (the package a.b's __init__ when a.b is a package).
"""

from __future__ import annotations

import ast
import re
import subprocess
import sys
import textwrap
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("detach", "scene_builder", "server")

LAYERS: tuple[tuple[str, tuple[str, ...]], ...] = (
    ("config", ("detach.config", "detach.torch_math", "detach.host_sync", "detach.lazy_exports")),
    ("runfolder", ("detach.runfolder",)),
    ("assets", ("scene_builder",)),
    ("character", ("detach.character",)),
    ("scene", ("scene_builder.scene", "detach.sim", "detach.motion")),
    ("skills", ("detach.skills",)),
    ("envs", ("detach.envs",)),
    ("models", ("detach.models",)),
    ("train", ("detach.train",)),
    ("eval", ("detach.eval",)),
    ("runs", ("detach.runs",)),
    ("cli", ("detach.cli", "scene_builder.cli", "detach.motion.cli", "server", "detach")),
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


def test_the_env_stays_an_orchestrator() -> None:
    """`LHEnv` wires the env's parts and runs the step; each job (world, starts, bonuses,
    episode books, views) lives in its own module of detach/envs. Issue 58 measured nine jobs
    in 360 lines; a file that grows past 200 lines has taken one back."""
    lines = len((ROOT / "detach/envs/lh_env.py").read_text(encoding="utf-8").splitlines())
    assert lines <= 200, f"detach/envs/lh_env.py has {lines} lines (at most 200): move a job out of LHEnv"


def _register_model_calls(path: Path) -> list[ast.Call]:
    """The `register_model(...)` calls at the top level of a module."""
    return [node.value for node in ast.parse(path.read_text(encoding="utf-8")).body
            if isinstance(node, ast.Expr) and isinstance(node.value, ast.Call)
            and getattr(node.value.func, "id", None) == "register_model"]


def test_every_built_in_model_kind_is_a_torch_free_config_and_one_registered_network() -> None:
    """A built-in model kind is its config class in `detach.models.configs`, which imports only
    the configuration layer (that layer reads it without torch), and its trunk and rsl-rl model
    in one module under detach/models that registers it once with `register_model`, named in
    `BUILTIN_NETWORKS`; every shipped model YAML's kind is one and its name has a label there."""
    from detach.config import load_merged
    from detach.models import model_order, registered_models
    from detach.models.configs import BUILTIN_NETWORKS

    found = {name: len(_register_model_calls(path)) for name, path in modules().items()
             if name.startswith("detach.models.")}
    assert all(n <= 1 for n in found.values()), found
    registering = sorted(name for name, n in found.items() if n == 1)
    entries = [e for e in registered_models() if e.network.__module__.startswith("detach.")]
    assert sorted(e.network.__module__ for e in entries) == registering
    assert {e.config_class: e.network.__module__ for e in entries} == BUILTIN_NETWORKS
    for e in entries:
        assert e.config_class.__module__ == "detach.models.configs", e.kind
        assert e.network.trunk_class.__module__ == e.network.__module__, e.kind
    config_deps = graph()["detach.models.configs"]
    assert all(layer_of(d) == 0 for d in config_deps), f"detach.models.configs imports {sorted(config_deps)}"
    kinds = {e.kind for e in entries}
    for path in (ROOT / "configs" / "models").glob("*.yaml"):
        kind = load_merged(path)[0]["model"]["kind"]
        assert kind in kinds, f"{path.name}: kind {kind!r} is not a built-in kind"
        assert path.stem in model_order(), f"{path.name}: no label registered with kind {kind}"



def test_resolving_a_config_imports_no_torch() -> None:
    """The configuration layer imports nothing above it, and the model kinds' config classes are
    torch-free: in a fresh process, resolving the task with every shipped model YAML, reading
    the dump back and listing the keys (`detach-run keys`) leave torch unimported."""
    code = textwrap.dedent("""\
        import sys, tempfile
        from pathlib import Path
        from detach.config import dump, load_run_config, resolve
        from detach.config.keys import all_keys, format_keys
        for model in sorted(p.stem for p in Path("configs/models").glob("*.yaml")):
            cfg = resolve("configs/tasks/lh1.yaml", model)
            with tempfile.NamedTemporaryFile("w", suffix=".yaml") as f:
                f.write(dump(cfg))
                f.flush()
                assert load_run_config(f.name) == cfg, model
        format_keys(all_keys())
        print(sorted(m for m in sys.modules if m == "torch" or m.startswith(("torch.", "detach.models."))))
        """)
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.strip() == "['detach.models.configs']", out.stdout

def test_no_model_table_outside_the_registry() -> None:
    """The networks and their labels are registered with their kind: no module keeps a list of
    model classes (MODEL_CLASSES) or writes a registered label ("TokenHSI (adapters)") itself."""
    from detach.models import registered_models

    labels = {label: e.network.__module__ for e in registered_models() for label in
              (*e.labels.values(), *e.paper_labels.values())}
    found = []
    for name, path in modules().items():
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.Name) and node.id == "MODEL_CLASSES":
                found.append(f"{name}:{node.lineno}: MODEL_CLASSES")
            if isinstance(node, ast.Constant) and isinstance(node.value, str) and labels.get(node.value, name) != name:
                found.append(f"{name}:{node.lineno}: the label {node.value!r} of {labels[node.value]}")
    assert not found, "\n".join(found)



# ------------------------------------------------------------------ the run folder has one owner
RUN_FOLDER_PACKAGE = "detach.runfolder"
RUN_FILE_PATH = re.compile(r"\S*(?:config\.yaml|status\.json|stdout\.log|log\.mcap|eval\S*\.json|selection\.json"
                           r"|provenance\.json|agent\.yaml|(?:model|amp_replay)_\S*\.pt)")
"""A string that is a path ending in one of a run folder's files (`detach.runfolder.names`); an
f-string counts with its fields as `*` (f"model_{it}.pt"). Prose naming a file has spaces."""
RUN_NAME_CONSTANTS = {"CONFIG_FILE", "STATUS_FILE", "STDOUT_FILE", "LOG_FILE", "CHECKPOINT_DIR", "EVAL_FILE",
                      "EVAL_GLOB", "SELECTION_FILE", "PROVENANCE_FILE", "PARAMS_DIR", "AGENT_PARAMS_FILE",
                      "EXPORT_DIR", "RUN_MARKERS", "REPLAY_PREFIX"}


def _outside_run_folder_package() -> dict[str, Path]:
    return {n: p for n, p in modules().items()
            if n != RUN_FOLDER_PACKAGE and not n.startswith(RUN_FOLDER_PACKAGE + ".")}


def _docstrings(tree: ast.AST) -> set[int]:
    found = set()
    for node in ast.walk(tree):
        body = getattr(node, "body", None)
        if isinstance(body, list):
            for stmt in body:  # a module's, class's or function's docstring, and attribute docstrings
                value = stmt.value if isinstance(stmt, ast.Expr) else None
                if isinstance(value, ast.Constant) and isinstance(value.value, str):
                    found.add(id(value))
    return found


def _labels(tree: ast.AST) -> set[int]:
    """Names used only to be printed: inside an f-string's replacement fields."""
    return {id(n) for f in ast.walk(tree) if isinstance(f, ast.FormattedValue) for n in ast.walk(f.value)}


def _string_of(node: ast.AST) -> str | None:
    if isinstance(node, ast.Constant) and isinstance(node.value, str):
        return node.value
    if isinstance(node, ast.JoinedStr):
        return "".join(v.value if isinstance(v, ast.Constant) else "*" for v in node.values)
    return None


def test_only_the_run_folder_package_names_the_run_folders_files() -> None:
    """Every reader of a run folder (the CLI's list and tables, evaluation, the dashboard) goes
    through `detach.runfolder`, so they cannot disagree about what a run holds: no module outside
    it writes a path to a run file (prose and docstrings may name one), nor uses the package's
    name constants except to print them (in an f-string)."""
    found = []
    for name, path in sorted(_outside_run_folder_package().items()):
        tree = ast.parse(path.read_text(encoding="utf-8"))
        docs, labels = _docstrings(tree), _labels(tree)
        for node in ast.walk(tree):
            where = f"{path.relative_to(ROOT)}:{getattr(node, 'lineno', '?')}"
            text = _string_of(node) if id(node) not in docs else None
            if text is not None and RUN_FILE_PATH.fullmatch(text):
                found.append(f"{where}: {text[:60]!r}")
            elif isinstance(node, (ast.Name, ast.Attribute)) and id(node) not in labels:
                ident = node.id if isinstance(node, ast.Name) else node.attr
                if ident in RUN_NAME_CONSTANTS:
                    found.append(f"{where}: {ident} used outside a label")
    assert not found, "run-folder file names outside detach.runfolder:\n" + "\n".join(found)


def _imports_re(path: Path) -> bool:
    tree = ast.parse(path.read_text(encoding="utf-8"))
    return any(isinstance(n, ast.Import) and any(a.name == "re" for a in n.names) or
               isinstance(n, ast.ImportFrom) and n.module == "re" for n in ast.walk(tree))


def test_no_regular_expression_reads_config_yaml() -> None:
    """config.yaml is YAML: read with the project's loader, never by pattern (the dashboard
    once matched `task_name:` lines and missed a config in flow style). The modules that read
    a run's config.yaml (they name `CONFIG_FILE`, `config_path` or `config_text`) import no `re`."""
    readers = []
    for name, path in sorted(modules().items()):
        text = path.read_text(encoding="utf-8")
        if re.search(r"\b(CONFIG_FILE|config_path|config_text)\b", text) and _imports_re(path):
            readers.append(name)
    assert not readers, f"modules that read config.yaml and import re: {readers}"


PUBLIC_FACE = "detach"
"""`detach/__init__.py`: what code outside the package imports (besides the run-folder package)."""


def test_the_dashboard_reads_runs_only_through_the_run_folder_package() -> None:
    """server/ reads run folders, logs included, only through `detach.runfolder`: no module of
    its own decodes MCAP, and everything else of detach it takes from the public face."""
    known = modules()
    found = []
    for name, path in sorted(known.items()):
        if not (name == "server" or name.startswith("server.")):
            continue
        for dep in sorted(imports(name, path, known)):
            if dep.startswith("detach") and not (dep.startswith(RUN_FOLDER_PACKAGE + ".") or dep == RUN_FOLDER_PACKAGE
                                                 or dep == PUBLIC_FACE):
                found.append(f"{name} imports {dep}")
        tree = ast.parse(path.read_text(encoding="utf-8"))
        for node in ast.walk(tree):
            mods = ([a.name for a in node.names] if isinstance(node, ast.Import) else
                    [node.module or ""] if isinstance(node, ast.ImportFrom) else [])
            found += [f"{name} imports {m}" for m in mods if m.split(".")[0] in ("mcap", "zstandard", "lz4")]
    assert not found, "the dashboard reads runs around detach.runfolder or the public face:\n" + "\n".join(found)


# ------------------------------------------------------------------------------ the public face
SCRIPT_FOLDERS = ("examples", "benchmarks", "results", "docs")
"""Code that uses detach from outside: it imports the public face only."""


def test_scripts_import_detach_only_through_its_public_face() -> None:
    """Examples, benchmarks, diagnosis scripts and the docs' scripts import `from detach import
    NAME` with NAME public (or `detach.runfolder`), never a module path inside the package, so
    that the package can be reorganised without breaking them."""
    import detach

    found = []
    for folder in SCRIPT_FOLDERS:
        for path in sorted((ROOT / folder).rglob("*.py")):
            tree = ast.parse(path.read_text(encoding="utf-8"))
            where = path.relative_to(ROOT)
            for node in ast.walk(tree):
                if isinstance(node, ast.Import):
                    found += [f"{where}:{node.lineno} import {a.name}" for a in node.names
                              if a.name.startswith("detach.") and not a.name.startswith(RUN_FOLDER_PACKAGE)]
                elif isinstance(node, ast.ImportFrom) and (node.module or "").split(".")[0] == "detach":
                    if node.module == PUBLIC_FACE:
                        found += [f"{where}:{node.lineno} {a.name} is not public" for a in node.names
                                  if a.name not in detach.__all__]
                    elif not node.module.startswith(RUN_FOLDER_PACKAGE):
                        found.append(f"{where}:{node.lineno} from {node.module}")
    assert not found, "imports past detach's public face:\n" + "\n".join(found)


def test_the_public_face_loads_nothing_until_used_and_every_name_resolves() -> None:
    """`import detach` (which every `import detach.x` runs first) loads neither torch nor MuJoCo,
    each public name resolves to its module's object, and what type checkers see (the
    TYPE_CHECKING imports) names exactly the public names, from the same modules."""
    import subprocess
    import sys

    probe = "import sys, detach; print(sorted({'torch', 'mujoco'} & set(sys.modules)))"
    loaded = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, check=True)
    assert loaded.stdout.strip() == "[]", loaded.stdout
    import importlib

    import detach

    for module, names in detach.PUBLIC.items():
        for name in names:
            owner = importlib.import_module(module)
            attribute = detach.RENAMED.get(name, name)
            expected = getattr(owner, attribute, None) or importlib.import_module(f"{module}.{attribute}")
            assert getattr(detach, name) is expected, name
    tree = ast.parse((ROOT / "detach" / "__init__.py").read_text(encoding="utf-8"))
    typed = {}
    for node in ast.walk(tree):
        if isinstance(node, ast.If) and isinstance(node.test, ast.Name) and node.test.id == "TYPE_CHECKING":
            for imp in node.body:
                assert isinstance(imp, ast.ImportFrom), ast.dump(imp)
                for a in imp.names:
                    typed[a.asname or a.name] = (imp.module, a.name)
    public = {name: (module, detach.RENAMED.get(name, name)) for module, names in detach.PUBLIC.items()
              for name in names}
    assert typed == public


# ------------------------------------------------------------------ the API under the command line
CLI_MAX_LINES = 550
"""detach/cli.py is argparse definitions plus one call per command (835 lines with run logic)."""

CLI_MAY_IMPORT = {"detach.config", "detach.eval.trial_sets", "detach.runs.actions", "detach.runs.command",
                  "detach.runs.listing", "detach.runs.tables_cli", "detach.config.keys"}
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
