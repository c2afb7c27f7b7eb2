"""The project's import graph has no cycles, and the model never imports the environments' users.

Every ``import`` of a project module counts, at module level or inside a function: a cycle hidden in a function
still means two modules that cannot be read (or loaded) one before the other. An import of ``pkg.sub`` counts as
an edge to ``pkg.sub`` (Python loads ``pkg`` first anyway, and every module depends on its package).

A module named in a string (``importlib.import_module("training.mappo")``, an ``"module:function"`` reference)
is an import too: covert_env's code holds no such string of a higher package. What the higher packages provide to
covert_env (the ``covert-env`` subcommands, the policies) they declare as entry points in ``pyproject.toml``."""

from __future__ import annotations

import ast
import importlib.metadata
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("covert_env", "baselines", "training")


def _modules() -> dict[str, Path]:
    mods = {}
    for pkg in PACKAGES:
        for path in (ROOT / pkg).rglob("*.py"):
            parts = path.relative_to(ROOT).with_suffix("").parts
            name = ".".join(parts[:-1] if parts[-1] == "__init__" else parts)
            mods[name] = path
    return mods


def _project_module(name: str, mods: dict[str, Path]) -> str | None:
    while name and name not in mods:
        name = name.rpartition(".")[0]
    return name or None


def import_graph() -> dict[str, set[str]]:
    """Module -> the project modules it imports (anywhere in its file)."""
    mods = _modules()
    graph: dict[str, set[str]] = {m: set() for m in mods}
    for mod, path in mods.items():
        package = mod if path.name == "__init__.py" else mod.rpartition(".")[0]
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                base = node.module or ""
                if node.level:
                    anchor = package.split(".")[: len(package.split(".")) - (node.level - 1)]
                    base = ".".join(anchor + ([base] if base else []))
                subs = [f"{base}.{a.name}" for a in node.names]
                targets = [s if s in mods else base for s in subs]
            else:
                continue
            for target in targets:
                found = _project_module(target, mods)
                if found and found != mod:
                    graph[mod].add(found)
    return graph


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan's algorithm, iterative)."""
    index, low, on_stack, stack, out = {}, {}, set(), [], []
    for root in sorted(graph):
        if root in index:
            continue
        work = [(root, iter(sorted(graph[root])))]
        index[root] = low[root] = len(index)
        stack.append(root)
        on_stack.add(root)
        while work:
            v, children = work[-1]
            for w in children:
                if w not in index:
                    index[w] = low[w] = len(index)
                    stack.append(w)
                    on_stack.add(w)
                    work.append((w, iter(sorted(graph[w]))))
                    break
                if w in on_stack:
                    low[v] = min(low[v], index[w])
            else:
                work.pop()
                if work:
                    low[work[-1][0]] = min(low[work[-1][0]], low[v])
                if low[v] == index[v]:
                    comp = []
                    while True:
                        w = stack.pop()
                        on_stack.discard(w)
                        comp.append(w)
                        if w == v:
                            break
                    if len(comp) > 1:
                        out.append(sorted(comp))
    return out


def test_the_walker_finds_a_planted_cycle():
    graph = {"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}
    assert cycles(graph) == [["a", "b", "c"]]
    assert cycles({"a": {"b"}, "b": set()}) == []


def test_no_import_cycles():
    found = cycles(import_graph())
    assert found == [], "import cycles: " + "; ".join(" <-> ".join(c) for c in found)


@pytest.mark.parametrize("low, high", [("covert_env", "baselines"), ("covert_env", "training"),
                                       ("baselines", "training")])
def test_layers(low, high):
    """The model and its envs never import the planner or training; the planner never imports training."""
    bad = sorted((m, t) for m, ts in import_graph().items() if m.split(".")[0] == low
                 for t in ts if t.split(".")[0] == high)
    assert bad == []


#: covert_env's model, floor by floor: each subpackage imports only itself and the floors below it.
MODEL_FLOORS = ("covert_env.geometry", "covert_env.world")


@pytest.mark.parametrize("floor", range(len(MODEL_FLOORS)))
def test_the_model_is_in_floors(floor):
    """covert_env.geometry (scene-free geometry) imports nothing else of covert_env; covert_env.world (the scenes and
    their measures) imports geometry; neither imports the environments, the evaluation or the command line."""
    own, allowed = MODEL_FLOORS[floor], MODEL_FLOORS[: floor + 1]
    graph = import_graph()
    members = [m for m in graph if m == own or m.startswith(own + ".")]
    assert len(members) > 1, own
    bad = sorted((m, t) for m in members for t in graph[m]
                 if t.split(".")[0] == "covert_env" and not any(t == a or t.startswith(a + ".") for a in allowed))
    assert bad == []


def test_the_old_module_paths_give_the_moved_modules(recwarn):
    """``covert_env.zone``, ``covert_env.config``, ``training.evaluate``, ... (covert_env.moved, and training's own
    map): the module at its new place, with a DeprecationWarning naming both."""
    import importlib
    import sys

    import training
    from covert_env.moved import MOVED

    for old, new in {**MOVED, **training.MOVED}.items():
        sys.modules.pop(old, None)                                    # an earlier import of the old path: again
        assert (ROOT / (new.replace(".", "/") + ".py")).is_file(), new
        assert not (ROOT / (old.replace(".", "/") + ".py")).exists(), old
        assert importlib.import_module(old) is importlib.import_module(new)
    from covert_env.config import Config  # noqa: F401  (the from-import form too)

    said = [str(w.message) for w in recwarn if issubclass(w.category, DeprecationWarning)]
    assert any("covert_env.zone moved to covert_env.geometry.zone" in m for m in said), said
    assert any("training.evaluate moved to covert_env.evaluation.evaluate" in m for m in said), said


def test_python_m_runs_a_moved_module_and_says_so():
    """``python -m training.evaluate`` runs the moved module as __main__ (with its own __file__), and warns where a
    person sees it, with Python's default warning filters."""
    import subprocess
    import sys

    out = subprocess.run([sys.executable, "-m", "training.evaluate", "--help"], cwd=ROOT, capture_output=True,
                         text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.startswith("usage: python -m covert_env.evaluation.evaluate")
    assert "FutureWarning: training.evaluate moved to covert_env.evaluation.evaluate" in out.stderr


#: A module of a higher package named in a string: ``training``, ``training.mappo``, ``baselines.dp:DPPlanner``.
HIGHER_MODULE = re.compile(r"(?<![\w.])(baselines|training)(\.\w+)*(:\w+)?")


def _docstrings(tree: ast.Module) -> set[int]:
    """The ids of the module's, classes' and functions' docstring nodes (prose, which may cite any module)."""
    out = set()
    for node in ast.walk(tree):
        if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)) and node.body:
            first = node.body[0]
            if isinstance(first, ast.Expr) and isinstance(first.value, ast.Constant):
                out.add(id(first.value))
    return out


def module_strings(path: Path, packages: tuple[str, ...] = ("baselines", "training")) -> list[tuple[int, str]]:
    """(line, string) of every string constant of the file's code (docstrings left out) that is a module name, or a
    ``module:attribute`` reference, of one of ``packages``."""
    tree = ast.parse(path.read_text(), str(path))
    skip = _docstrings(tree)
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Constant) and isinstance(node.value, str) and id(node) not in skip:
            m = HIGHER_MODULE.fullmatch(node.value.strip())
            if m and m.group(1) in packages:
                out.append((node.lineno, node.value))
    return out


def test_the_string_check_finds_planted_module_names(tmp_path):
    f = tmp_path / "m.py"
    f.write_text('"""Cites training.mappo in prose."""\nimport importlib\n'
                 'X = {"mappo": "training.mappo", "animate": "baselines.animate:main"}\n'
                 'importlib.import_module("baselines")\nY = "training scenes"\n')
    assert module_strings(f) == [(3, "training.mappo"), (3, "baselines.animate:main"), (4, "baselines")]


@pytest.mark.parametrize("high", ["baselines", "training"])
def test_covert_env_names_no_higher_module_in_code(high):
    """No import by string either: covert_env (the CLI included) finds the higher packages' commands and policies
    through entry points, never by a module name of its own."""
    bad = [(str(path.relative_to(ROOT)), line, text) for path in sorted((ROOT / "covert_env").rglob("*.py"))
           for line, text in module_strings(path, (high,))]
    assert bad == []


def _declared_entry_points() -> dict[str, dict[str, str]]:
    tomllib = pytest.importorskip("tomllib", reason="tomllib: Python >= 3.11")
    return tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["entry-points"]


def test_the_declared_entry_points_point_up_and_are_installed():
    """The entry points covert_env reads are declared by the packages above it, and the installed metadata holds
    them (after editing pyproject.toml: pip install -e . again)."""
    declared = _declared_entry_points()
    assert "covert_env.commands" in declared
    for group, entries in declared.items():
        assert group.startswith("covert_env."), group
        for name, value in entries.items():
            assert value.split(".")[0] in ("baselines", "training"), (group, name, value)
        installed = {ep.name: ep.value for ep in importlib.metadata.entry_points(group=group)}
        assert installed == entries, (f"the installed metadata of {group} differs from pyproject.toml: "
                                      f"reinstall (pip install -e .)")


def test_every_declared_entry_point_loads():
    for group, entries in _declared_entry_points().items():
        for name in entries:
            (ep,) = importlib.metadata.entry_points(group=group, name=name)
            assert callable(ep.load()), (group, name)
