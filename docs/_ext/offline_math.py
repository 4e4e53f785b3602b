"""Local Sphinx extension: MathJax served from the built site, so math renders offline.

Sphinx's ``sphinx.ext.mathjax`` loads MathJax from a CDN by default; on a machine without
network the theory pages would show raw ``\\(\\dot x = ...\\)``. The PyPI package
``django-static-mathjax`` (in the ``docs`` extra; it does not need Django) ships the
official MathJax 3 build as package data. This extension copies its single-file
``tex-svg-full.js`` component (TeX input with every TeX extension, SVG output with the
fonts inside the script, so no further file is fetched) into the site's ``_static/mathjax/``
and points ``mathjax_path`` at it (:data:`MATHJAX_FILE`, relative to ``_static``).
A build without the package fails with one line saying what to install.
"""

from __future__ import annotations

import importlib.util
import shutil
from pathlib import Path

from sphinx.application import Sphinx
from sphinx.config import Config
from sphinx.errors import ExtensionError

__all__ = ["MATHJAX_FILE", "mathjax_source", "setup"]

#: Where the script lands in the built site, relative to ``_static`` (``mathjax_path``).
MATHJAX_FILE = "mathjax/tex-svg-full.js"


def mathjax_source() -> Path:
    """The ``tex-svg-full.js`` shipped by ``django-static-mathjax``.

    Raises
    ------
    sphinx.errors.ExtensionError
        If the package is not installed or does not hold the file.
    """
    spec = importlib.util.find_spec("mathjax")
    if spec is None or spec.origin is None:
        raise ExtensionError('MathJax for the offline site: install the docs extra, pip install -e ".[docs]" '
                             "(django-static-mathjax)")
    path = Path(spec.origin).parent / "static" / "mathjax" / "es5" / "tex-svg-full.js"
    if not path.is_file():
        raise ExtensionError(f"MathJax for the offline site: {path} is missing (django-static-mathjax >= 3.2.2)")
    return path


def _set_path(app: Sphinx, config: Config) -> None:
    mathjax_source()  # fail before the build, not after it
    config.mathjax_path = MATHJAX_FILE


def _copy(app: Sphinx, exception: BaseException | None) -> None:
    if exception is not None or app.builder.format != "html":
        return
    target = Path(app.outdir) / "_static" / MATHJAX_FILE
    target.parent.mkdir(parents=True, exist_ok=True)
    shutil.copyfile(mathjax_source(), target)


def setup(app: Sphinx) -> dict[str, object]:
    """Register the hooks; ``sphinx.ext.mathjax`` must be loaded too."""
    app.setup_extension("sphinx.ext.mathjax")
    app.connect("config-inited", _set_path)
    app.connect("build-finished", _copy)
    return {"parallel_read_safe": True, "parallel_write_safe": True}
