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
import inspect
import sys
from typing import Any

from docutils import nodes

ALIASES = {"np": "numpy", "o3d": "open3d", "sp": "scipy"}
#: One page per documented object on these sites (their own layouts).
SITES = {
    "numpy": "https://numpy.org/doc/stable/reference/generated/{name}.html",
    "scipy": "https://docs.scipy.org/doc/scipy/reference/generated/{name}.html",
    "open3d": "https://www.open3d.org/docs/release/python_api/{name}.html",
    "dask": "https://docs.dask.org/en/stable/generated/{name}.html",
    "distributed": "https://distributed.dask.org/en/stable/api.html#{name}",
}
BUILTIN_PAGES = {
    "functions": {"int", "float", "str", "bool", "object", "type", "bytes", "complex", "range"},
    "stdtypes": {"list", "dict", "tuple", "set", "frozenset"},
    "constants": {"None", "True", "False", "Ellipsis", "NotImplemented"},
}


def _resolve(name: str) -> tuple[str, list[Any]]:
    """Return the longest importable module prefix of a dotted name and the objects along it.

    Raises LookupError when the name does not lead to an object.
    """
    parts = name.split(".")
    for cut in range(len(parts), 0, -1):
        module_name = ".".join(parts[:cut])
        try:
            obj = importlib.import_module(module_name)
        except ImportError:
            continue
        chain = [obj]
        for attr in parts[cut:]:
            if not hasattr(chain[-1], attr):
                raise LookupError(name)
            chain.append(getattr(chain[-1], attr))
        return module_name, chain
    raise LookupError(name)


def _canonical(name: str) -> str:
    head, _, rest = name.partition(".")
    return ALIASES.get(head, head) + ("." + rest if rest else "")


def _builtin_url(name: str) -> str | None:
    for page, names in BUILTIN_PAGES.items():
        if name in names:
            return f"https://docs.python.org/3/library/{page}.html#{name}"
    obj = getattr(builtins, name, None)
    if isinstance(obj, type) and issubclass(obj, BaseException):
        return f"https://docs.python.org/3/library/exceptions.html#{name}"
    if callable(obj):
        return f"https://docs.python.org/3/library/functions.html#{name}"
    return None


def url_for(name: str) -> str | None:
    """Return the documentation address of an importable name outside o3d_ofp, or None."""
    if "." not in name and (name in vars(builtins) or name in BUILTIN_PAGES["constants"]):
        return _builtin_url(name)
    name = _canonical(name)
    top = name.split(".")[0]
    if top not in SITES and top not in sys.stdlib_module_names:
        return None
    try:
        module_name, chain = _resolve(name)
    except LookupError:
        return None
    if top in sys.stdlib_module_names:  # one page per module, an anchor per object
        return f"https://docs.python.org/3/library/{module_name}.html#{name}"
    if top == "open3d" and len(chain) > 1 and inspect.isclass(chain[-2]):
        owner = name.rsplit(".", 1)[0]  # a member: an anchor on its class's page
        return SITES[top].format(name=owner) + f"#{name}"
    if top == "numpy" and name.startswith("numpy.typing."):
        return f"https://numpy.org/doc/stable/reference/typing.html#{name}"
    if top == "distributed" or name.startswith("dask.distributed."):
        short = name.replace("dask.distributed.", "distributed.")
        return f"https://distributed.dask.org/en/stable/api.html#{short}"
    return SITES[top].format(name=name)


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
