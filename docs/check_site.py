"""Check the built documentation site offline, in a real headless browser, with screenshots.

Usage (after ``python -m sphinx -W -n -b html docs docs/_build/html``; CI runs it)::

    python docs/check_site.py docs/_build/html [--screenshots DIR] [--require-browser]

1. Every page (static check, no browser): no ``<script>`` or stylesheet loaded over
   http(s), so nothing depends on a network; every page with math loads the MathJax
   that ``docs/_ext/offline_math.py`` copied into the site, and that file is there.
2. The tutorial and theory pages, the getting-started page and the report schema (see
   :data:`BROWSER_PAGES`) are opened in headless Chromium with every host name unresolvable
   (``--host-resolver-rules``: a machine without network), the DOM read after the
   scripts ran: every math element was typeset by MathJax (an ``mjx-container`` each,
   no ``merror``, no raw ``\\(`` left). A screenshot of each page is written (default
   ``<site>/../screenshots/``) for a human to look at. (Table cells lost to an unescaped
   ``|`` are checked in the markdown source by ``tests/test_markdown_tables.py``: the
   parser drops them, so the rendered page cannot show what is missing.)

Chromium is Debian's ``chromium`` package (``apt-get install -y chromium``). Without it
the browser part is skipped with a message, or is an error with ``--require-browser``.
Exit 0 when every check passed, 1 with one line per problem.
"""

from __future__ import annotations

import argparse
import re
import shutil
import subprocess
import sys
import tempfile
from collections.abc import Sequence
from html.parser import HTMLParser
from pathlib import Path

__all__ = ["BROWSER_PAGES", "browser", "static_problems", "rendered_problems", "main"]

#: Pages opened in the browser (globs relative to the site).
BROWSER_PAGES = ("tutorials/*.html", "theory/*.html", "getting-started.html", "reference/report-schema.html")
#: Where ``docs/_ext/offline_math.py`` puts MathJax, relative to the site.
MATHJAX = "_static/mathjax/tex-svg-full.js"
_REMOTE = re.compile(r"""<(?:script|link)\b[^>]*\b(?:src|href)=["']((?:https?:)?//[^"']+)["'][^>]*>""", re.I)
_MATH = re.compile(r"""class="[^"]*\bmath\b[^"]*"[^>]*>""")


def static_problems(site: Path) -> list[str]:
    """Remote scripts or stylesheets, and math pages without the site's MathJax."""
    problems = []
    if not (site / MATHJAX).is_file():
        problems.append(f"{MATHJAX}: missing (docs/_ext/offline_math.py copies it from django-static-mathjax)")
    for page in sorted(site.rglob("*.html")):
        text = page.read_text(encoding="utf-8", errors="replace")
        name = page.relative_to(site)
        for match in _REMOTE.finditer(text):
            tag = match.group(0)
            if tag.startswith("<script") or "stylesheet" in tag:
                problems.append(f"{name}: loads {match.group(1)} over the network")
        if _MATH.search(text) and "mathjax/tex-svg-full.js" not in text:
            problems.append(f"{name}: has math but does not load the site's MathJax")
    return problems


class _Rendered(HTMLParser):
    """Counts in a rendered DOM: math elements, MathJax output, errors."""

    def __init__(self) -> None:
        super().__init__()
        self.math = self.typeset = self.errors = 0
        self._in_script = False

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        classes = (dict(attrs).get("class") or "").split()
        self._in_script = tag in ("script", "style")
        if tag in ("span", "div") and "math" in classes:
            self.math += 1
        elif tag == "mjx-container":
            self.typeset += 1
        elif tag == "mjx-merror" or any(k == "data-mjx-error" for k, _ in attrs):
            self.errors += 1

    def handle_endtag(self, tag: str) -> None:
        self._in_script = False

    def handle_data(self, data: str) -> None:
        if not self._in_script and ("\\(" in data or "\\[" in data):
            self.errors += 1  # math left as TeX source


def rendered_problems(name: str, dom: str) -> list[str]:
    """Problems of one page's DOM after its scripts ran (module docstring, step 2)."""
    seen = _Rendered()
    seen.feed(dom)
    problems = []
    if seen.typeset < seen.math:
        problems.append(f"{name}: {seen.math} math elements, {seen.typeset} typeset by MathJax")
    if seen.errors:
        problems.append(f"{name}: {seen.errors} math errors or untypeset TeX")
    return problems


def browser() -> str | None:
    """The headless browser's command, or None."""
    for candidate in ("chromium", "chromium-browser", "google-chrome"):
        found = shutil.which(candidate)
        if found:
            return found
    return None


def _chromium(command: str, profile: str, url: str, *extra: str) -> subprocess.CompletedProcess[str]:
    argv = [command, "--headless", "--no-sandbox", "--disable-gpu", "--hide-scrollbars",
            f"--user-data-dir={profile}", "--host-resolver-rules=MAP * ~NOTFOUND",
            "--virtual-time-budget=20000", *extra, url]
    return subprocess.run(argv, capture_output=True, text=True, timeout=120)


def browser_problems(site: Path, shots: Path, command: str) -> tuple[list[str], list[Path]]:
    """Open each page of :data:`BROWSER_PAGES` offline; its problems and the screenshots."""
    problems: list[str] = []
    written: list[Path] = []
    shots.mkdir(parents=True, exist_ok=True)
    pages = sorted({p for pattern in BROWSER_PAGES for p in site.glob(pattern)})
    if not pages:
        return [f"{site}: none of the pages {BROWSER_PAGES}"], written
    with tempfile.TemporaryDirectory(prefix="ftc-site-") as profile:
        for page in pages:
            name = str(page.relative_to(site))
            url = page.resolve().as_uri()
            dom = _chromium(command, profile, url, "--dump-dom")
            if dom.returncode != 0 or "<html" not in dom.stdout:
                problems.append(f"{name}: the browser failed (exit {dom.returncode}): {dom.stderr.strip()[-200:]}")
                continue
            problems += rendered_problems(name, dom.stdout)
            png = shots / (name.replace("/", "_").removesuffix(".html") + ".png")
            shot = _chromium(command, profile, url, f"--screenshot={png}", "--window-size=1280,2400")
            if shot.returncode != 0 or not png.is_file() or png.stat().st_size < 10_000:
                problems.append(f"{name}: no screenshot (exit {shot.returncode})")
            else:
                written.append(png)
    return problems, written


def main(argv: Sequence[str] | None = None) -> int:
    """The command line of the module docstring; returns the exit code."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0], allow_abbrev=False)
    parser.add_argument("site", type=Path, help="the built site (default docs/_build/html)", nargs="?",
                        default=Path("docs/_build/html"))
    parser.add_argument("--screenshots", type=Path, default=None,
                        help="folder for the screenshots (default: screenshots/ beside the site)")
    parser.add_argument("--require-browser", action="store_true",
                        help="fail when no headless Chromium is installed (default: skip that part)")
    args = parser.parse_args(argv)
    site: Path = args.site
    if not (site / "index.html").is_file():
        print(f"check_site: {site}: no index.html (build the site first)", file=sys.stderr)
        return 2
    problems = static_problems(site)
    command = browser()
    if command is None:
        print("check_site: no headless Chromium (apt-get install -y chromium): browser check skipped")
        if args.require_browser:
            problems.append("no headless Chromium and --require-browser")
    else:
        more, shots = browser_problems(site, args.screenshots or site.parent / "screenshots", command)
        problems += more
        print(f"check_site: {len(shots)} pages rendered offline in {Path(command).name}, screenshots in "
              f"{shots[0].parent if shots else '-'}")
    for line in problems:
        print(f"check_site: {line}")
    print(f"check_site: {'ok' if not problems else f'{len(problems)} problems'}")
    return 0 if not problems else 1


if __name__ == "__main__":
    sys.exit(main())
