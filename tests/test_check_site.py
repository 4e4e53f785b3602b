"""``docs/check_site.py``: the built site needs no network and its math is typeset offline.

CI runs the script on the real site after the docs build (``.ci/run``); these tests check
that each of its checks fails where it must, on small sites made here. The browser test
runs where headless Chromium (Debian's ``chromium``) and MathJax (``django-static-mathjax``,
the docs extra) are installed, and is skipped elsewhere.
"""

from __future__ import annotations

import importlib.util
import shutil
from pathlib import Path
from types import ModuleType

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _load() -> ModuleType:
    spec = importlib.util.spec_from_file_location("check_site", ROOT / "docs" / "check_site.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


check_site = _load()
CDN = '<script defer="defer" src="https://cdn.jsdelivr.net/npm/mathjax@3/es5/tex-mml-chtml.js"></script>'
LOCAL = '<script defer="defer" src="_static/mathjax/tex-svg-full.js"></script>'
MATH = '<p><span class="math notranslate nohighlight">\\(\\dot x = A x\\)</span></p>'


def _site(tmp_path: Path, script: str, *, mathjax: Path | None = None) -> Path:
    site = tmp_path / "html"
    (site / "_static" / "mathjax").mkdir(parents=True)
    (site / "tutorials").mkdir()
    (site / "index.html").write_text("<html><body>home</body></html>")
    body = f"<html><head>{script.replace('_static', '../_static')}</head><body>{MATH}</body></html>"
    (site / "tutorials" / "page.html").write_text(body)
    if mathjax is not None:
        shutil.copyfile(mathjax, site / check_site.MATHJAX)
    return site


def test_static_check_finds_a_cdn_script_and_a_missing_mathjax(tmp_path: Path) -> None:
    problems = check_site.static_problems(_site(tmp_path, CDN))
    assert any("loads https://cdn.jsdelivr.net" in p for p in problems), problems
    assert any("does not load the site's MathJax" in p for p in problems), problems
    assert any(p.startswith("_static/mathjax/tex-svg-full.js: missing") for p in problems), problems


def test_static_check_passes_a_site_that_needs_no_network(tmp_path: Path) -> None:
    site = _site(tmp_path, LOCAL)
    (site / check_site.MATHJAX).write_text("/* MathJax */")
    assert check_site.static_problems(site) == []


def test_rendered_dom_with_untypeset_or_broken_math_is_refused() -> None:
    typeset = '<span class="math"><mjx-container class="MathJax"><svg></svg></mjx-container></span>'
    assert check_site.rendered_problems("p.html", f"<html>{typeset}{typeset}</html>") == []
    assert check_site.rendered_problems("p.html", f"<html>{MATH}{typeset}</html>") == [
        "p.html: 2 math elements, 1 typeset by MathJax", "p.html: 1 math errors or untypeset TeX"]
    broken = '<span class="math"><mjx-container><mjx-merror>x</mjx-merror></mjx-container></span>'
    assert check_site.rendered_problems("p.html", broken) == ["p.html: 1 math errors or untypeset TeX"]


def _mathjax() -> Path | None:
    spec = importlib.util.find_spec("mathjax")
    if spec is None or spec.origin is None:
        return None
    path = Path(spec.origin).parent / "static" / "mathjax" / "es5" / "tex-svg-full.js"
    return path if path.is_file() else None


@pytest.mark.slow(15)
@pytest.mark.skipif(check_site.browser() is None or _mathjax() is None,
                    reason="needs headless Chromium (apt-get install -y chromium) and the docs extra's MathJax")
def test_a_real_browser_typesets_offline_only_with_the_local_mathjax(tmp_path: Path) -> None:
    command = check_site.browser()
    good = _site(tmp_path / "good", LOCAL, mathjax=_mathjax())
    problems, shots = check_site.browser_problems(good, tmp_path / "shots", command)
    assert problems == [] and len(shots) == 1 and shots[0].read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    remote = _site(tmp_path / "remote", CDN)  # the CDN cannot be reached: the math stays TeX
    problems, _ = check_site.browser_problems(remote, tmp_path / "shots2", command)
    assert "tutorials/page.html: 1 math elements, 0 typeset by MathJax" in problems, problems
