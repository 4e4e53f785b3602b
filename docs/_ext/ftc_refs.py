"""Local Sphinx extension: ftc_verify's own names resolved where they are documented.

Two things the stock autodoc does not do for a package laid out as this one:

* A subpackage re-exports its modules' objects (``ftc_verify.controllers.Controller`` is
  ``ftc_verify.controllers.controller.Controller``), and a module's ``__all__`` may list a
  name imported from a sibling (``ftc_verify.model.system`` re-exports ``JointChain``).
  The API pages document every object once, in the module that defines it
  (:func:`skip_reexport`), and a reference to a re-exported name is resolved to that
  place (:func:`resolve_reexport`).
* A type alias of ``ftc_type_aliases`` in conf.py (``Matrix``, ``Signal``, ``Opt``)
  written by name in an annotation autodoc could not evaluate (a name imported under
  ``TYPE_CHECKING``, a subscripted alias such as ``Opt[int]``) is resolved to the
  alias the configuration names (:func:`resolve_reexport`).
* A dataclass field with a ``default_factory`` has the default ``<factory>`` in the
  generated ``__init__``, which is not Python, so the signature would be split at every
  comma; it is shown as the factory's call, ``dict()`` (:func:`factory_defaults`).
* A documented module-level alias such as ``Matrix = NDArray[np.float64]`` is callable,
  so numpydoc's signature hook would take the aliased class's docstring signature
  (``ndarray(shape, ...)``) for the alias, which autodoc 9 cannot attach to data;
  :func:`data_signature` keeps data without a signature.
* A name that cannot be imported (a module or object that does not exist) stays
  unresolved, so ``sphinx -n`` reports it.
"""

from __future__ import annotations

import dataclasses
import importlib
from typing import Any

from docutils import nodes
from sphinx.addnodes import pending_xref
from sphinx.application import Sphinx
from sphinx.environment import BuildEnvironment
from sphinx.util.nodes import make_refnode

__all__ = ["setup", "skip_reexport", "resolve_reexport", "factory_defaults", "data_signature"]

_current_module: list[str] = [""]


def _note_module(app: Sphinx, what: str, name: str, obj: Any, options: Any, lines: list[str]) -> None:
    """Remember which module autodoc is documenting (its docstring comes before its members)."""
    if what == "module":
        _current_module[0] = name


def skip_reexport(app: Sphinx, what: str, name: str, obj: Any, skip: bool, options: Any) -> bool | None:
    """Skip a module member (class or function) that another module defines."""
    if what != "module":
        return None
    home = getattr(obj, "__module__", None)
    if isinstance(obj, type) or callable(obj):
        if home and home.startswith("ftc_verify") and home != _current_module[0]:
            return True
    return None


def _import_target(target: str) -> Any:
    """The object a dotted ``ftc_verify...`` name denotes, or None."""
    parts = target.split(".")
    for cut in range(len(parts), 0, -1):
        try:
            obj: Any = importlib.import_module(".".join(parts[:cut]))
        except ImportError:
            continue
        for attr in parts[cut:]:
            if not hasattr(obj, attr):
                return None
            obj = getattr(obj, attr)
        return obj
    return None


def _canonical(obj: Any, target: str, objects: dict[str, Any]) -> str | None:
    """Where ``obj`` (reached as ``target``) is documented, if it is."""
    module, qualname = getattr(obj, "__module__", None), getattr(obj, "__qualname__", None)
    if isinstance(module, str) and isinstance(qualname, str) and f"{module}.{qualname}" in objects:
        return f"{module}.{qualname}"
    # A constant or a re-exported name: the one documented object of that name in the
    # package the reference names.
    if target in objects:
        return target
    package, _, last = target.rpartition(".")
    found = [name for name in objects if name.startswith(package + ".") and name.rsplit(".", 1)[-1] == last]
    return found[0] if len(found) == 1 else None


def resolve_reexport(app: Sphinx, env: BuildEnvironment, node: pending_xref,
                     contnode: nodes.TextElement) -> nodes.reference | None:
    """Resolve ``ftc_verify.pkg.Name`` to ``ftc_verify.pkg.module.Name`` when that is documented."""
    if node.get("refdomain") != "py":
        return None
    target = node.get("reftarget", "")
    target = app.config.ftc_type_aliases.get(target, target)
    if not target.startswith("ftc_verify."):
        # A bare name in a docstring or a type hint: what that name is in the module
        # whose docstring holds it (the module's own import of it).
        module = node.get("py:module") or ""
        if not module.startswith("ftc_verify") or target.startswith((".", "~")):
            return None
        target = f"{module}.{target}"
    obj = _import_target(target)
    if obj is None:
        return None
    domain = env.get_domain("py")
    objects = domain.objects  # type: ignore[attr-defined]
    name = _canonical(obj, target, objects)
    if name is None:
        return None
    entry = objects[name]
    return make_refnode(app.builder, node["refdoc"], entry.docname, entry.node_id, contnode, name)


def factory_defaults(app: Sphinx, what: str, name: str, obj: Any, options: Any, signature: str | None,
                     return_annotation: str | None) -> tuple[str | None, str | None] | None:
    """Show a dataclass field's ``<factory>`` default as the factory's call, ``dict()``."""
    if what != "class" or not signature or "<factory>" not in signature or not dataclasses.is_dataclass(obj):
        return None
    for f in dataclasses.fields(obj):
        if f.init and f.default_factory is not dataclasses.MISSING:
            called = getattr(f.default_factory, "__qualname__", "")
            signature = signature.replace("<factory>", f"{called}()" if called.isidentifier() else "...", 1)
    return signature, return_annotation


def data_signature(app: Sphinx, what: str, name: str, obj: Any, options: Any, signature: str | None,
                   return_annotation: str | None) -> tuple[str | None, str | None] | None:
    """Module-level data keeps the signature autodoc gives it (runs before numpydoc's hook)."""
    return (signature, return_annotation) if what == "data" else None


def setup(app: Sphinx) -> dict[str, Any]:
    app.add_config_value("ftc_type_aliases", {}, "env", dict)
    app.connect("autodoc-process-docstring", _note_module)
    app.connect("autodoc-process-signature", factory_defaults)
    app.connect("autodoc-process-signature", data_signature, priority=400)
    app.connect("autodoc-skip-member", skip_reexport)
    app.connect("missing-reference", resolve_reexport)
    return {"parallel_read_safe": False, "parallel_write_safe": True}
