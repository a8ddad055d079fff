"""The docs site as a reader sees it: every page of the built site in headless Chromium at
1280 px.

- No page scrolls sideways: ``document.documentElement.scrollWidth <= innerWidth`` (a wide
  table or code block scrolls inside its own box).
- Every ``<img>`` loads (``naturalWidth > 0``).
- The home page's first screen (its top 800 px) shows ``make test`` and ``make benchmark``.

The site is built with ``mkdocs build --strict`` and served from 127.0.0.1; one Chromium
process loads a harness page that opens each page in a 1280 x 800 frame, measures it and
writes the measurements into its own DOM, which ``--dump-dom`` prints.  Chromium is Debian's
``chromium`` package (``apt-get install -y chromium``): without it the test is skipped, except
under CI (the ``CI`` environment variable set), where it fails.
"""

from __future__ import annotations

import functools
import html
import http.server
import json
import os
import re
import shutil
import subprocess
import sys
import threading
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
WIDTH, HEIGHT = 1280, 800
INSTALL = "sudo apt-get install -y chromium  (Debian's package; as root, without sudo)"
#: Where the harness page is served.
HARNESS = "__site_check__.html"


def chromium() -> str:
    """Returns Chromium's path; skips the test where it is missing, fails under CI."""
    for name in ("chromium", "chromium-browser", "google-chrome"):
        if found := shutil.which(name):
            return found
    message = f"headless Chromium is needed for the site check: {INSTALL}"
    if os.environ.get("CI"):
        pytest.fail(message)
    pytest.skip(message)


#: Measures one page in its frame: sideways overflow (and the elements that cause it, outside
#: any box that scrolls), images that did not load, and where the home page's two commands sit.
MEASURE = r"""
function measure(win, path) {
  const doc = win.document, root = doc.documentElement;
  const scrolls = (el) => {
    for (let e = el; e && e !== root; e = e.parentElement) {
      const s = win.getComputedStyle(e);
      if (['auto', 'scroll', 'hidden'].includes(s.overflowX) && e.scrollWidth > e.clientWidth)
        return true;
    }
    return false;
  };
  const wide = [];
  for (const el of doc.body.querySelectorAll('*')) {
    if (el.closest('.md-search') || el.offsetParent === null) continue;  // hidden
    const r = el.getBoundingClientRect();
    if (r.right > win.innerWidth + 1 && r.width > 0 && !scrolls(el.parentElement))
      wide.push(el.tagName.toLowerCase() + (el.className ? '.' + el.className : ''));
  }
  const images = [...doc.images].map((i) => ({src: i.getAttribute('src'),
    loaded: i.complete && i.naturalWidth > 0}));
  const found = {};
  for (const phrase of ['make test', 'make benchmark']) {
    // the smallest element that holds the phrase (highlighting splits it into tokens)
    let best = null;
    for (const el of doc.body.querySelectorAll('*')) {
      if (el.textContent.includes(phrase) && ![...el.children].some(
          (c) => c.textContent.includes(phrase))) { best = el; break; }
    }
    if (best) {
      const r = best.getBoundingClientRect();
      if (r.height > 0) found[phrase] = r.bottom + win.scrollY;
    }
  }
  return {path, scrollWidth: root.scrollWidth, innerWidth: win.innerWidth,
          wide: wide.slice(0, 5), images, commands: found};
}
"""

HARNESS_PAGE = """<!doctype html><html><body style="margin:0">
<iframe id="frame" style="width:{width}px;height:{height}px;border:0"></iframe>
<pre id="result"></pre>
<script>{measure}
const pages = {pages};
const out = [];
const frame = document.getElementById('frame');
function next(i) {{
  if (i >= pages.length) {{
    document.getElementById('result').textContent = JSON.stringify(out);
    return;
  }}
  frame.onload = () => setTimeout(() => {{
    try {{ out.push(measure(frame.contentWindow, pages[i])); }}
    catch (e) {{ out.push({{path: pages[i], error: String(e)}}); }}
    next(i + 1);
  }}, 400);
  frame.src = pages[i];
}}
next(0);
</script></body></html>"""


def site_pages(site: Path) -> list[str]:
    """Returns every page of the built site as its URL path ("/", "/env/", ...)."""
    pages = []
    for index in sorted(site.rglob("index.html")):
        rel = index.parent.relative_to(site).as_posix()
        pages.append("/" if rel == "." else f"/{rel}/")
    return pages


@pytest.fixture(scope="module")
def site(tmp_path_factory) -> Path:
    for module in ("mkdocs", "material", "mkdocstrings_handlers.python"):
        pytest.importorskip(module, reason="the docs tools (pip install -e '.[dev]')")
    out = tmp_path_factory.mktemp("site")
    done = subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(out)],
        cwd=ROOT,
        capture_output=True,
        text=True,
    )
    assert done.returncode == 0, done.stderr[-3000:]
    return out


@pytest.fixture(scope="module")
def measured(site) -> dict[str, dict]:
    return measure_site(site, chromium())


def measure_site(site: Path, browser: str) -> dict[str, dict]:
    """Returns each page of a built site's measurements, by its URL path."""
    pages = site_pages(site)
    harness = HARNESS_PAGE.format(
        width=WIDTH, height=HEIGHT, measure=MEASURE, pages=json.dumps(pages)
    )
    (site / HARNESS).write_text(harness)
    handler = functools.partial(_QuietHandler, directory=str(site))
    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    try:
        url = f"http://127.0.0.1:{server.server_address[1]}/{HARNESS}"
        done = subprocess.run(
            [browser, "--headless", "--no-sandbox", "--disable-gpu", "--no-first-run",
             "--disable-extensions", "--hide-scrollbars",
             f"--window-size={WIDTH + 20},{HEIGHT + 200}", "--virtual-time-budget=120000",
             "--dump-dom", url],
            capture_output=True, text=True, timeout=300,
        )  # fmt: skip
    finally:
        server.shutdown()
    found = re.search(r'<pre id="result">(.*?)</pre>', done.stdout, flags=re.S)
    assert found and found.group(1), f"the harness did not finish: {done.stderr[-2000:]}"
    results = json.loads(html.unescape(found.group(1)))
    assert [r["path"] for r in results] == pages
    return {r["path"]: r for r in results}


class _QuietHandler(http.server.SimpleHTTPRequestHandler):
    def log_message(self, *args) -> None:  # the test's output stays the test's
        pass


def test_every_page_is_measured(measured):
    errors = {p: r["error"] for p, r in measured.items() if "error" in r}
    assert not errors, errors
    assert {"/", "/env/", "/results/", "/mechanism/", "/models/"} <= set(measured)


def test_no_page_scrolls_sideways_at_1280_px(measured):
    wide = {
        p: (r["scrollWidth"], r["wide"])
        for p, r in measured.items()
        if r["scrollWidth"] > r["innerWidth"]
    }
    assert not wide, f"pages wider than {WIDTH} px (scrollWidth, widest elements): {wide}"


def test_every_image_loads(measured):
    broken = {p: [i["src"] for i in r["images"] if not i["loaded"]] for p, r in measured.items()}
    broken = {p: srcs for p, srcs in broken.items() if srcs}
    assert not broken, broken
    pictured = ("/", "/env/", "/mechanism/", "/results/", "/your_arm/", "/identify/")
    bare = [p for p in pictured if not measured[p]["images"]]
    assert not bare, f"pages without a figure: {bare}"
    cards = [p for p in measured if p.startswith("/models/") and p != "/models/"]
    assert cards and all(measured[p]["images"] for p in cards)


def test_the_home_pages_first_screen_shows_the_two_commands(measured):
    commands = measured["/"]["commands"]
    for phrase in ("make test", "make benchmark"):
        # snapshot: the home page's first screen shows the two commands a visitor runs
        assert phrase in commands, f"{phrase!r} is not on the home page"
        assert commands[phrase] <= HEIGHT, f"{phrase!r} ends at {commands[phrase]:.0f} px"
