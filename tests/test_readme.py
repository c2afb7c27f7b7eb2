"""The README: its Python snippets run as written, it stays short (at most 200 lines), its links lead to files of
the repository, and its leaderboard is the published suite run's (python -m covert_env.evaluation.leaderboard --check).
The documentation site's pages are tested in tests/test_docs.py."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

README = Path(__file__).resolve().parents[1] / "README.md"
BLOCKS = re.findall(r"^```python\n(.*?)^```", README.read_text(encoding="utf-8"), flags=re.S | re.M)


def test_readme_has_snippets():
    assert len(BLOCKS) >= 1


def test_readme_is_short():
    lines = README.read_text(encoding="utf-8").count("\n")
    assert lines <= 200, f"README.md has {lines} lines; keep it at most 200 (the rest belongs in docs/)"


def test_readme_links_lead_to_files():
    text = README.read_text(encoding="utf-8")
    targets = re.findall(r"\]\(([^)\s]+)\)", text) + re.findall(r'src="([^"]+)"', text)
    local = [t.split("#")[0] for t in targets if not t.startswith(("http://", "https://", "#"))]
    assert local, "the README links no file"
    missing = [t for t in local if not (README.parent / t).exists()]
    assert not missing, f"README links to missing files: {missing}"


def test_readme_leaderboard_is_the_published_run():
    from covert_env.evaluation.leaderboard import check

    assert check() == []


@pytest.mark.parametrize("code", BLOCKS, ids=[f"block{i}" for i in range(len(BLOCKS))])
def test_readme_snippet_runs(code, monkeypatch, tmp_path):
    monkeypatch.chdir(tmp_path)                 # snippets that write files write them here
    exec(compile(code, str(README), "exec"), {"__name__": "__readme__"})
