"""Without the optional extras the suite skips, never fails: the tests of an optional package skip with a reason
naming the package and the extra (``tests/_extras.py``), here checked with those packages made unimportable."""

from __future__ import annotations

import ast
import re
import subprocess
import sys
from pathlib import Path

import pytest
from _extras import EXTRA_OF, reason

ROOT = Path(__file__).resolve().parents[1]
TESTS = ROOT / "tests"


def _touches_optional(node: ast.AST) -> bool:
    """``node`` calls ``needs(...)`` or imports a package of :data:`_extras.EXTRA_OF`."""
    for n in ast.walk(node):
        if isinstance(n, ast.Call) and isinstance(n.func, ast.Name) and n.func.id == "needs":
            return True
        names = [a.name for a in n.names] if isinstance(n, ast.Import) else \
            [n.module or ""] if isinstance(n, ast.ImportFrom) else []
        if any(name.split(".")[0] in EXTRA_OF for name in names):
            return True
    return False


def optional_tests() -> list[str]:
    """Node ids of the tests that touch an optional package: whole files where the module level does, else the
    test functions that do."""
    ids = []
    for path in sorted(TESTS.glob("test_*.py")):
        if path.name == Path(__file__).name:
            continue
        tree = ast.parse(path.read_text(encoding="utf-8"))
        top = [n for n in tree.body if not isinstance(n, (ast.FunctionDef, ast.ClassDef))]
        if any(_touches_optional(n) for n in top):
            ids.append(f"tests/{path.name}")
            continue
        ids += [f"tests/{path.name}::{n.name}" for n in tree.body
                if isinstance(n, ast.FunctionDef) and n.name.startswith("test_") and _touches_optional(n)]
    return ids


def test_every_extra_of_a_skip_is_in_pyproject():
    tomllib = pytest.importorskip("tomllib", reason="tomllib: Python >= 3.11")
    extras = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["optional-dependencies"]
    for package, extra in EXTRA_OF.items():
        assert extra in extras, (package, extra)
        if package != "torch":                        # torch comes with stable-baselines3
            wanted = package.replace("_", "-")
            assert any(re.match(rf"{wanted}\b", req.replace("_", "-")) for req in extras[extra]), (package, extra)
    assert reason("ray.rllib") == 'needs ray: pip install -e ".[rllib]"'


def test_optional_packages_are_skipped_through_needs():
    """A bare ``pytest.importorskip`` of an optional package would skip without naming its extra."""
    bare = re.compile(r"importorskip\(\s*[\"'](\w+)")
    for path in TESTS.glob("test_*.py"):
        for name in bare.findall(path.read_text(encoding="utf-8")):
            assert name not in EXTRA_OF, f"{path.name}: importorskip({name!r}); use _extras.needs"


@pytest.mark.slow
def test_suite_skips_without_the_optional_packages():
    """All tests collected, and those that touch an optional package run, with every package of
    :data:`_extras.EXTRA_OF` unimportable: nothing fails or errors, each skip names its package and extra."""
    inner = optional_tests()
    assert "tests/test_training.py" in inner, inner
    code = f"""
import sys
sys.modules.update(dict.fromkeys({sorted(EXTRA_OF)!r}))
import pytest
print("COLLECT", int(pytest.main(["-q", "-p", "no:cacheprovider", "--co", "tests"])))
print("RUN", int(pytest.main(["-q", "-p", "no:cacheprovider", "-rs", *{inner!r}])))
"""
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, timeout=600)
    out = res.stdout
    assert res.returncode == 0, res.stderr[-3000:]
    assert "COLLECT 0" in out and "RUN 0" in out, out[-5000:]
    skips = [line for line in out.splitlines() if line.startswith("SKIPPED")]
    assert len(skips) >= 5, out[-5000:]
    for line in skips:
        assert "_extras.py" not in line, line                # the skip is reported at the test's own line
        assert re.search(r'needs (\w+): pip install -e "\.\[(\w+)\]"', line), line
