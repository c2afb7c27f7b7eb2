"""The documentation site (``mkdocs.yml``, the ``docs`` extra): it builds strictly, its code blocks run, no internal
link is broken, and a headless Chromium renders its home page and its leaderboard.

The site is built once per session into a temporary folder. Without the ``docs`` extra (or, for the rendering
test, without Chromium) these tests skip, naming what is missing; CI sets ``COVERT_ENV_REQUIRE_DOCS=1``, which
turns the skips into failures.
"""

from __future__ import annotations

import functools
import http.server
import os
import re
import shutil
import subprocess
import sys
import threading
from html.parser import HTMLParser
from pathlib import Path
from urllib.parse import unquote, urlsplit

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
REQUIRED = os.environ.get("COVERT_ENV_REQUIRE_DOCS") == "1"
CHROMIUM_FLAGS = ("--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                  "--disable-background-networking", "--disable-component-update", "--disable-sync",
                  "--hide-scrollbars")


def _missing(what: str):
    if REQUIRED:
        pytest.fail(f"{what} (COVERT_ENV_REQUIRE_DOCS=1)")
    pytest.skip(what)


def _pages() -> list[Path]:
    return sorted(p for p in DOCS.rglob("*.md"))


def _blocks(path: Path) -> list[str]:
    """The page's plain ```python blocks (``python framework=...`` blocks run in tests/test_frameworks.py)."""
    return re.findall(r"^```python\n(.*?)^```", path.read_text(encoding="utf-8"), flags=re.S | re.M)


BLOCKS = [(p, i, code) for p in _pages() for i, code in enumerate(_blocks(p))]


@pytest.fixture(scope="session")
def site(tmp_path_factory) -> Path:
    import importlib.util

    for module in ("mkdocs", "material", "mkdocstrings_handlers.python"):
        if importlib.util.find_spec(module.split(".")[0]) is None:
            _missing(f'{module.split(".")[0]} is not installed: pip install -e ".[docs]"')
    out = tmp_path_factory.mktemp("site")
    # This interpreter's mkdocs (the venv under test), not whichever is first on PATH.
    run = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "-q", "-d", str(out)], cwd=ROOT,
                         capture_output=True, text=True, env={**os.environ, "NO_MKDOCS_2_WARNING": "1"})
    assert run.returncode == 0, f"mkdocs build --strict failed:\n{run.stdout}\n{run.stderr}"
    return out


def test_site_builds_strictly_with_every_page(site):
    pages = {p.relative_to(site).as_posix() for p in site.rglob("*.html")}
    for want in ("index.html", "getting-started.html", "environments.html", "tasks.html", "frameworks.html",
                 "training.html", "leaderboards.html", "performance.html", "model.html", "paper_to_code.html",
                 "decisions/index.html", "api/environments.html", "changelog.html"):
        assert want in pages, f"{want} not built; built: {sorted(pages)}"
    for family in ("sparse", "paper", "winding", "dense", "downtown", "towers"):
        assert (site / "images" / "families" / f"{family}.png").stat().st_size > 10_000
    board = (site / "leaderboards.html").read_text(encoding="utf-8")
    assert "score IQM" in board and "planner" in board and "<!-- generated" not in board
    envs = (site / "environments.html").read_text(encoding="utf-8")
    assert envs.count("own offset from the target") == 2, "the env docstrings' observation tables are missing"
    for page in site.rglob("*.html"):
        text = page.read_text(encoding="utf-8")
        assert "{OBSERVATION_TABLE}" not in text and ":class:<code>" not in text, page
        assert "Convert a string or number to a floating point number" not in text, f"{page}: float's docstring"


def test_the_docs_have_code_blocks():
    assert len(BLOCKS) >= 3, [f"{p.name}#{i}" for p, i, _ in BLOCKS]


@pytest.mark.parametrize("page, index, code", BLOCKS, ids=[f"{p.relative_to(DOCS)}#{i}" for p, i, _ in BLOCKS])
def test_docs_code_block_runs(page, index, code, monkeypatch, tmp_path):
    monkeypatch.chdir(tmp_path)                 # blocks that write files write them here
    exec(compile(code, f"{page}#block{index}", "exec"), {"__name__": "__docs__"})


class _Links(HTMLParser):
    def __init__(self):
        super().__init__()
        self.links, self.ids = [], set()

    def handle_starttag(self, tag, attrs):
        a = dict(attrs)
        if a.get("id"):
            self.ids.add(a["id"])
        if tag == "a" and a.get("href"):
            self.links.append(a["href"])
        if tag in ("img", "script") and a.get("src"):
            self.links.append(a["src"])
        if tag == "link" and a.get("href"):
            self.links.append(a["href"])


@functools.cache
def _parse(path: Path) -> _Links:
    p = _Links()
    p.feed(path.read_text(encoding="utf-8"))
    return p


def test_no_internal_link_is_broken(site):
    broken = []
    for page in site.rglob("*.html"):
        for href in _parse(page).links:
            parts = urlsplit(href)
            if parts.scheme or parts.netloc or href.startswith(("mailto:", "data:", "javascript:")):
                continue
            base = site if parts.path.startswith("/") else page.parent          # 404.html links from the root
            target = page if not parts.path else (base / unquote(parts.path).lstrip("/")).resolve()
            if target.is_dir():
                target = target / "index.html"
            if not target.exists():
                broken.append(f"{page.relative_to(site)}: {href} (no file)")
            elif parts.fragment and target.suffix == ".html" and unquote(parts.fragment) not in _parse(target).ids:
                broken.append(f"{page.relative_to(site)}: {href} (no anchor)")
    assert not broken, "\n".join(broken[:40])


@pytest.fixture(scope="session")
def served(site):
    handler = functools.partial(http.server.SimpleHTTPRequestHandler, directory=str(site))
    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler)
    handler.log_message = lambda *a: None
    threading.Thread(target=server.serve_forever, daemon=True).start()
    yield f"http://127.0.0.1:{server.server_address[1]}"
    server.shutdown()


def _chromium() -> str:
    for name in ("chromium", "chromium-browser", "google-chrome"):
        if shutil.which(name):
            return shutil.which(name)
    _missing("no Chromium on PATH (Debian: apt-get install chromium)")


@pytest.mark.parametrize("page, expect", [("index.html", "The suite's leaderboard"),
                                          ("leaderboards.html", "score IQM")])
def test_chromium_renders_the_page(served, page, expect, tmp_path):
    """Chromium loads the page from a local server, runs its scripts (the theme's navigation and search), and
    the rendered DOM holds the page's content; its screenshot is not blank."""
    chrome = _chromium()
    shot = tmp_path / f"{page}.png"
    flags = [chrome, *CHROMIUM_FLAGS, f"--user-data-dir={tmp_path / 'profile'}", "--window-size=1280,1000"]
    run = subprocess.run([*flags, f"--screenshot={shot}", f"{served}/{page}"], capture_output=True, text=True,
                         timeout=120)
    assert shot.exists(), f"no screenshot: {run.stderr[-2000:]}"
    import matplotlib.image

    pixels = matplotlib.image.imread(shot)[..., :3]
    assert pixels.shape[:2] == (1000, 1280)
    assert pixels.std() > 0.05, "the screenshot is (nearly) one colour: the page did not render"
    dom = subprocess.run([*flags, "--dump-dom", f"{served}/{page}"], capture_output=True, text=True, timeout=120)
    assert expect in dom.stdout, f"{expect!r} not in the rendered DOM of {page}"
    assert 'class="md-nav' in dom.stdout, "the theme's navigation did not render"
    keep = os.environ.get("COVERT_ENV_SCREENSHOTS")
    if keep:
        Path(keep).mkdir(parents=True, exist_ok=True)
        shutil.copy(shot, Path(keep) / shot.name)
