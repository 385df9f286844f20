"""The house rules: no import circles, a spec core and shared modules that know no track, one
place that switches on the workflow kind, and a new track added without editing a module."""
import ast
import json
import os
import subprocess
import sys
from pathlib import Path


import opalflow
from opalflow import registry
from opalflow.cli import main
from opalflow.jit import njit

PACKAGE = Path(opalflow.__file__).resolve().parent
#: modules every track may use; they import no track
SHARED = ("spec", "registry", "structure", "units", "materials", "store", "resources", "neighbors", "packing", "io", "api",
          "version", "lammps", "analysis", "runs", "linalg", "progress", "vocabulary", "jit", "heap")
#: track packages, each owning its spec sections, their validation and its runner: every package of opalflow that
#: is not shared (a new one is a track from the moment it exists)
TRACKS = tuple(sorted(p.name for p in PACKAGE.iterdir() if (p / "__init__.py").exists() and p.name not in SHARED))


def module_name(path: Path) -> str:
    parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def modules() -> dict[str, Path]:
    return {module_name(p): p for p in PACKAGE.rglob("*.py")}


def imports(name: str, path: Path, known: set[str]) -> set[str]:
    """opalflow modules that ``name`` imports anywhere in its file (inside functions too).

    ``from opalflow.x import y`` is an import of ``opalflow.x.y`` when that is a module, else
    of ``opalflow.x``; relative imports are resolved against the module's package.
    """
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            targets = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = package.split(".")[:len(package.split(".")) - node.level + 1]
                base = ".".join(anchor + ([base] if base else []))
            targets = [f"{base}.{a.name}" if f"{base}.{a.name}" in known else base for a in node.names]
        else:
            continue
        found |= {t for t in targets if t in known and t != name}
    return found


def import_graph() -> dict[str, set[str]]:
    mods = modules()
    known = set(mods)
    return {name: imports(name, path, known) for name, path in mods.items()}


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan)."""
    index, low, stack, on, out = {}, {}, [], set(), []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in graph[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in graph:
        if v not in index:
            visit(v)
    return out


def test_no_import_circles():
    graph = import_graph()
    assert len(graph) > 30 and "opalflow.registry" in graph["opalflow.cli"]
    assert cycles(graph) == []


def test_the_circle_finder_finds_a_circle():
    assert cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert cycles({"a": {"b"}, "b": set()}) == []


def test_spec_core_and_shared_modules_import_no_track():
    graph = import_graph()
    tracks = tuple(f"opalflow.{t}" for t in TRACKS)
    for name, deps in graph.items():
        if any(name == f"opalflow.{s}" or name.startswith(f"opalflow.{s}.") for s in SHARED):
            assert not [d for d in deps if d.startswith(tracks)], f"{name} imports a track"
    assert graph["opalflow.spec"] == set()


def test_tracks_import_only_the_pipeline_of_other_tracks():
    """A scene may build on the compression pipeline (opalflow.bpm); no track imports another."""
    assert {"aerogel", "bpm", "opal", "studies", "tersoff"} <= set(TRACKS) and not set(TRACKS) & set(SHARED)
    graph = import_graph()
    for track in TRACKS:
        others = tuple(f"opalflow.{t}" for t in TRACKS if t not in (track, "bpm"))
        for name, deps in graph.items():
            if name.startswith(f"opalflow.{track}"):
                assert not [d for d in deps if d.startswith(others)], f"{name} imports another track"


def test_only_the_registry_switches_on_kind():
    hits = [f"{p.relative_to(PACKAGE)}:{n}" for p in PACKAGE.rglob("*.py")
            for n, line in enumerate(p.read_text().splitlines(), 1) if "kind ==" in line or "kind.startswith" in line]
    assert all(h.startswith("registry.py:") for h in hits), hits


def test_every_shipped_workflow_names_a_registered_kind():
    for path in (PACKAGE.parent / "workflows").glob("*.toml"):
        spec = registry.load_spec(path)
        assert isinstance(spec, registry.get(spec.kind).spec_class())


# ----------------------------------------------------------------------------- a new track (conftest: toytrack)
def test_a_new_track_registered_at_run_time_runs_through_the_cli(toytrack, capsys, monkeypatch):
    monkeypatch.setattr(registry, "_REGISTERED", {})
    from toytrack import KIND

    registry.register(KIND)
    out = toytrack / "run"
    assert main(["run", str(toytrack / "toy.toml"), "--out", str(out)]) == 0
    assert capsys.readouterr().out.startswith("sum = 55, ")
    assert json.loads((out / "summary.json").read_text())["sum"] == 55
    # its spec is checked like any other, and it refuses the options it does not take
    assert main(["run", str(toytrack / "toy.toml"), "--out", str(toytrack / "bad"), "--set", "toy.n=0"]) == 2
    assert capsys.readouterr().err.strip() == "error: toy.n = 0: must be in [1, 100]"
    assert main(["run", str(toytrack / "toy.toml"), "--out", str(toytrack / "bad"), "--np", "2"]) == 2
    assert not (toytrack / "bad").exists()


def test_a_new_track_installed_as_a_plugin_runs_through_python_m_opalflow(toytrack):
    env_path = str(toytrack / "site")
    proc = subprocess.run([sys.executable, "-m", "opalflow", "run", str(toytrack / "toy.toml"), "--out",
                           str(toytrack / "plugin_run")], capture_output=True, text=True,
                          env={**os.environ, "PYTHONPATH": env_path})
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.startswith("sum = 55, ")
    info = subprocess.run([sys.executable, "-m", "opalflow", "info"], capture_output=True, text=True,
                          env={**os.environ, "PYTHONPATH": env_path})
    assert any(line.split()[:1] == ["toy"] for line in info.stdout.splitlines())


def test_architecture_doc_names_what_exists():
    """docs/reference/architecture.md: every opalflow path it names exists, and every package is described."""
    import re

    doc = (PACKAGE.parent / "docs" / "reference" / "architecture.md").read_text()
    named = set(re.findall(r"`(opalflow/[A-Za-z0-9_/.]*)", doc))
    assert len(named) > 10
    missing = [n for n in named if not (PACKAGE.parent / n.split("<")[0]).exists() and "<" not in n]
    assert missing == []
    packages = {p.parent.name for p in PACKAGE.glob("*/__init__.py")}
    assert {p for p in packages if f"`opalflow/{p}/`" not in doc} == set()


def test_no_import_by_string_inside_opalflow():
    """Modules are imported, not named by a string: ``resolve("opalflow...")`` / ``import_module("opalflow...")``
    with a constant appears nowhere (the registry's kinds and the study types name their lazy runners as fields,
    resolved where used; the bonded-particle methods' runners are imported: opalflow.bpm.run.RUNNERS)."""
    hits = []
    for path in PACKAGE.rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Call) and node.args and isinstance(node.args[0], ast.Constant):
                name = node.func.attr if isinstance(node.func, ast.Attribute) else getattr(node.func, "id", "")
                if name in ("resolve", "import_module") and str(node.args[0].value).startswith("opalflow"):
                    hits.append(f"{path.relative_to(PACKAGE)}:{node.lineno}")
    assert hits == []


def test_module_level_names_are_unique():
    """A registry or constant has one name in the whole package (METHODS named three registries, EXECUTORS two);
    a scene's ``SCENE`` is the interface every scene module gives."""
    where: dict[str, list[str]] = {}
    for path in PACKAGE.rglob("*.py"):
        for node in ast.parse(path.read_text()).body:
            targets = node.targets if isinstance(node, ast.Assign) else [node.target] if isinstance(node, ast.AnnAssign) else []
            for t in targets:
                if isinstance(t, ast.Name) and t.id.isupper() and len(t.id) > 2 and t.id != "SCENE":
                    where.setdefault(t.id, []).append(str(path.relative_to(PACKAGE)))
    assert {k: v for k, v in where.items() if len(v) > 1} == {}


def test_the_docs_name_the_run_record_schema_the_code_writes():
    from opalflow.runs.record import SCHEMA

    assert f"`schema` {SCHEMA})" in (PACKAGE.parent / "docs" / "reference" / "usage.md").read_text()


def test_a_run_folders_files_are_named_in_one_module():
    """``run.json``, ``summary.json`` and ``results.h5`` are spelled in code only in opalflow/store.py (RECORD,
    SUMMARY, RESULTS); docstrings may name them to the reader."""
    spelled = {}
    for path in PACKAGE.rglob("*.py"):
        tree = ast.parse(path.read_text())
        docs = {id(n.body[0].value) for n in ast.walk(tree)
                if isinstance(n, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef))
                and n.body and isinstance(n.body[0], ast.Expr) and isinstance(n.body[0].value, ast.Constant)}
        for node in ast.walk(tree):
            if isinstance(node, ast.Constant) and isinstance(node.value, str) and id(node) not in docs:
                for name in ("run.json", "summary.json", "results.h5"):
                    if name in node.value:
                        spelled.setdefault(name, set()).add(str(path.relative_to(PACKAGE)))
    assert spelled == {name: {"store.py"} for name in ("run.json", "summary.json", "results.h5")}


def test_no_function_is_over_80_lines():
    """A function (method included, the functions defined inside it counted in its lines) fits a screen: 80 lines
    at most (issue 54; the nonlinear method's kernel and event loop had grown to 100 and 145)."""
    long = [f"{path.relative_to(PACKAGE)}:{node.name} ({node.end_lineno - node.lineno + 1} lines)"
            for path in PACKAGE.rglob("*.py") for node in ast.walk(ast.parse(path.read_text()))
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)) and node.end_lineno - node.lineno >= 80]
    assert long == []


@njit(nogil=True)
def _twice(x):
    return 2.0 * x


@njit(nogil=True)
def _sum_twice(values):
    total = 0.0
    for v in values:
        total += _twice(v)
    return total


def test_a_lazy_kernel_calls_another():
    """opalflow.jit.njit: a kernel that calls another such kernel compiles (against the callee's dispatcher) and
    gives the callee's numbers."""
    import numpy as np

    assert _sum_twice(np.arange(4.0)) == 12.0


def test_every_result_class_compares_as_its_summary():
    """Every kind's result class keeps Result's mapping equality (a ``@dataclass`` without ``eq=False`` would put
    back field-by-field equality, and ``opalflow.run(...) == summary`` would be False)."""
    from opalflow.runs.result import Result

    classes = {k.result_class() for k in registry.kinds().values()}
    assert len(classes) >= 8 and all(c.__eq__ is Result.__eq__ for c in classes)
