"""Resolve references to NumPy, SciPy, Open3D, Dask and the standard library without the network.

CI builds the documentation where only package registries are reachable, so intersphinx cannot
download the other projects' inventories. Instead, a reference Sphinx cannot resolve in this
project is looked up in the installed package: when the dotted name imports, it becomes a link to
that object's page on the project's site (the page layouts below are those sites' own); when it
does not, it stays unresolved and the strict (nitpicky, -W) build fails on it, as it would with
intersphinx.
"""

from __future__ import annotations

import builtins
import importlib
import sys
from typing import Any

from docutils import nodes

ALIASES = {"np": "numpy", "o3d": "open3d", "sp": "scipy"}
BUILTIN_PAGES = {
    "functions": {"int", "float", "str", "bool", "object", "type", "bytes", "complex", "range"},
    "stdtypes": {"list", "dict", "tuple", "set", "frozenset"},
    "constants": {"None", "True", "False", "Ellipsis", "NotImplemented"},
}


def _resolve(name: str) -> Any:
    """Return the object a dotted name refers to, or raise LookupError."""
    parts = name.split(".")
    for cut in range(len(parts), 0, -1):
        try:
            obj = importlib.import_module(".".join(parts[:cut]))
        except ImportError:
            continue
        for attr in parts[cut:]:
            if not hasattr(obj, attr):
                raise LookupError(name)
            obj = getattr(obj, attr)
        return obj
    raise LookupError(name)


def _canonical(name: str) -> str:
    head, _, rest = name.partition(".")
    return ALIASES.get(head, head) + ("." + rest if rest else "")


def url_for(name: str) -> str | None:
    """Return the documentation address of an importable name outside o3d_ofp, or None."""
    if name in vars(builtins) or name in BUILTIN_PAGES["constants"]:
        for page, names in BUILTIN_PAGES.items():
            if name in names:
                return f"https://docs.python.org/3/library/{page}.html#{name}"
        if isinstance(getattr(builtins, name, None), type) and issubclass(
            getattr(builtins, name), BaseException
        ):
            return f"https://docs.python.org/3/library/exceptions.html#{name}"
        return None
    name = _canonical(name)
    top = name.split(".")[0]
    try:
        _resolve(name)
    except LookupError:
        return None
    if top == "numpy":
        if name.startswith("numpy.typing."):
            return f"https://numpy.org/doc/stable/reference/typing.html#{name}"
        return f"https://numpy.org/doc/stable/reference/generated/{name}.html"
    if top == "scipy":
        return f"https://docs.scipy.org/doc/scipy/reference/generated/{name}.html"
    if top == "open3d":
        return f"https://www.open3d.org/docs/release/python_api/{name}.html"
    if top in ("dask", "distributed"):
        short = name.replace("dask.distributed.", "distributed.")
        if short.startswith("distributed."):
            return f"https://distributed.dask.org/en/stable/api.html#{short}"
        return f"https://docs.dask.org/en/stable/generated/{name}.html"
    if top in sys.stdlib_module_names:
        return f"https://docs.python.org/3/library/{top}.html#{name}"
    return None


def _missing_reference(app: Any, env: Any, node: Any, contnode: Any) -> Any:
    if node.get("refdomain") != "py":
        return None
    target = node.get("reftarget", "")
    if target.startswith(("o3d_ofp", "~o3d_ofp")):
        return None  # ours must resolve in this build
    url = url_for(target.lstrip("~"))
    if url is None:
        return None
    reference = nodes.reference("", "", internal=False, refuri=url, reftitle=target)
    reference.append(contnode)
    return reference


def setup(app: Any) -> dict[str, Any]:
    """Register the resolver (after Sphinx's own domains have tried)."""
    app.connect("missing-reference", _missing_reference, priority=900)
    return {"parallel_read_safe": True, "parallel_write_safe": True}


__all__ = ["setup", "url_for"]
