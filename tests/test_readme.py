"""The README's Python snippets run as written (the framework snippets, tagged ``python framework=...``, run in
tests/test_frameworks.py where their framework is installed)."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

README = Path(__file__).resolve().parents[1] / "README.md"
BLOCKS = re.findall(r"^```python\n(.*?)^```", README.read_text(encoding="utf-8"), flags=re.S | re.M)


def test_readme_has_snippets():
    assert len(BLOCKS) >= 2


@pytest.mark.parametrize("code", BLOCKS, ids=[f"block{i}" for i in range(len(BLOCKS))])
def test_readme_snippet_runs(code, monkeypatch, tmp_path):
    monkeypatch.chdir(tmp_path)                 # snippets that write files write them here
    exec(compile(code, str(README), "exec"), {"__name__": "__readme__"})
