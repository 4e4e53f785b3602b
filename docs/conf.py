"""Sphinx configuration of the ftc-verify documentation.

Built offline: ``python -m sphinx -W -n -b html docs docs/_build/html``. No intersphinx
(the build machine has no network and none of numpy, scipy, python-control or fmpy ships
its ``objects.inv`` in the installed package), so references to third-party and standard
library objects in type hints are not links; ``nitpick_ignore_regex`` below lists exactly
those targets, never one of ``ftc_verify``'s own.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(Path(__file__).resolve().parent / "_ext"))

from ftc_verify import __version__  # noqa: E402

project = "ftc-verify"
author = "the ftc-verify developers"
copyright = "the ftc-verify developers"
version = release = __version__

extensions = [
    "myst_parser",
    "sphinx.ext.autodoc",
    "sphinx.ext.mathjax",
    "offline_math",  # MathJax from the docs extra, copied into the site: no CDN (docs/_ext/offline_math.py)
    "sphinx.ext.viewcode",
    "numpydoc",
    "sphinxarg.ext",
    "ftc_refs",
]

source_suffix = {".rst": "restructuredtext", ".md": "markdown"}
root_doc = "index"
exclude_patterns = ["_build", "Thumbs.db", ".DS_Store"]
templates_path: list[str] = []

# MyST: dollar math for the theory pages, heading anchors for links like page.md#section.
myst_enable_extensions = ["dollarmath", "amsmath", "deflist", "colon_fence"]
myst_heading_anchors = 3

# autodoc + numpydoc: members in source order, type hints in the signature only.
autodoc_default_options = {"members": True, "member-order": "bysource", "show-inheritance": True}
autodoc_typehints = "signature"
autodoc_preserve_defaults = True
autoclass_content = "class"
# The package's type aliases, where they are documented: docs/_ext/ftc_refs.py resolves
# an alias left by name in a signature (an annotation autodoc cannot evaluate: a name
# imported under ``TYPE_CHECKING``, a subscripted alias such as ``Opt[int]``). Not
# ``autodoc_type_aliases``: Sphinx 9 renders an alias inside ``X | None`` or
# ``tuple[X, ...]`` as its internal ``TypeAliasForwardRef`` class.
ftc_type_aliases = {
    "Matrix": "ftc_verify.model.matrices.Matrix",
    "Signal": "ftc_verify.model.system.Signal",
    "Opt": "ftc_verify.testing.strategies.Opt",
}
numpydoc_show_class_members = False
numpydoc_class_members_toctree = False
numpydoc_attributes_as_param_list = False
# FTC_DOCS_VALIDATE=1 turns numpydoc's docstring validation on (a report for the
# developers, see developer.md); the CI build leaves it off.
if os.environ.get("FTC_DOCS_VALIDATE"):
    numpydoc_validation_checks = {"all", "ES01", "EX01", "SA01", "SS05", "GL08", "RT02", "PR01", "PR02"}

nitpicky = True
# Third-party and standard-library targets only (no intersphinx inventories offline).
# Anything under ftc_verify must resolve.
nitpick_ignore_regex = [
    (r"py:.*", r"(?!ftc_verify\b)[A-Za-z_][\w.]*\.[\w.]+"),  # dotted names outside ftc_verify
    (r"py:.*", r"(int|float|str|bytes|bool|object|None|type|dict|list|tuple|set|frozenset|complex|"
               r"Any|Callable|Iterator|Iterable|Sequence|Mapping|Literal|Path|ndarray|NDArray|"
               r"BaseException|Exception|ValueError|RuntimeError|OSError|TimeoutError|KeyboardInterrupt|"
               r"ArgumentParser|Namespace|TextIO|BinaryIO|IO|Generator|ContextManager|Self|"
               r"SeedSequence|StateSpace|SearchStrategy|ArrayLike|tomllib)"),
]

html_theme = "furo"
html_title = f"ftc-verify {release}"
html_static_path: list[str] = []
