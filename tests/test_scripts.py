"""The scripts under ``scripts/`` use names the package still has.

Each script is parsed, not run (they read ../shared/data and take minutes). Checked: every
``import o3d_ofp...`` / ``from o3d_ofp... import X`` resolves; every attribute read from a name
bound to the package or one of its modules or classes (``ofp.X``, ``matching.Y``,
``ofp.Correspondence.from_p2p``) exists; every call of a function or class of the package
reached that way binds to its signature (keyword names and the number of positional
arguments); and names taken from a sibling script (``from bench_match import Peak``,
``E.some_function``) are defined there. Code a script hands to a child Python process in a
string (``python -c``) is checked the same way. Names are bound scope by scope (an import in
a function holds there; a local variable of the same name hides it). Not checked: what calls
return (attributes of their results, their types: a quality's reasons are ``Said`` objects,
not strings); running a script in its quickest mode shows those.
"""

from __future__ import annotations

import ast
import importlib
import inspect
from pathlib import Path
from typing import Any

import pytest

SCRIPTS_DIR = Path(__file__).resolve().parents[1] / "scripts"
SCRIPTS = sorted(SCRIPTS_DIR.glob("*.py"))
PACKAGE = "o3d_ofp"


def _from_module(module: str, name: str) -> Any:
    """``from module import name`` as Python does it: an attribute, else a submodule."""
    mod = importlib.import_module(module)
    if hasattr(mod, name):
        return getattr(mod, name)
    if not hasattr(mod, "__path__"):  # a module, not a package: no submodule either
        raise AttributeError(f"{module} has no {name!r}")
    try:
        return importlib.import_module(f"{module}.{name}")
    except ModuleNotFoundError:
        raise AttributeError(f"{module} has no {name!r}") from None


def _top_level_names(path: Path) -> set[str]:
    """Names a script defines at its top level (functions, classes, assignments, imports)."""
    names: set[str] = set()
    for node in ast.parse(path.read_text(), filename=str(path)).body:
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef | ast.ClassDef):
            names.add(node.name)
        elif isinstance(node, ast.Assign | ast.AnnAssign | ast.AugAssign):
            targets = node.targets if isinstance(node, ast.Assign) else [node.target]
            for target in targets:
                names.update(n.id for n in ast.walk(target) if isinstance(n, ast.Name))
        elif isinstance(node, ast.Import | ast.ImportFrom):
            names.update((a.asname or a.name).split(".")[0] for a in node.names)
    return names


def _chain(node: ast.AST) -> list[str] | None:
    """``a.b.c`` as ["a", "b", "c"]; None for anything else than names and attributes."""
    parts: list[str] = []
    while isinstance(node, ast.Attribute):
        parts.append(node.attr)
        node = node.value
    if not isinstance(node, ast.Name):
        return None
    return [node.id, *reversed(parts)]


def _code_strings(tree: ast.AST) -> list[ast.Module]:
    """Python code held in string constants that import the package (a child's ``-c`` code)."""
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Constant) and isinstance(node.value, str):
            if f"import {PACKAGE}" in node.value or f"from {PACKAGE}" in node.value:
                try:
                    out.append(ast.parse(node.value))
                except SyntaxError:
                    continue
    return out


def problems(path: Path) -> list[str]:
    """Return what a script uses that the package (or a sibling script) does not have."""
    tree = ast.parse(path.read_text(), filename=str(path))
    out: list[str] = []
    for module in [tree, *_code_strings(tree)]:
        out += _problems(module, path.parent)
    return out


#: Nodes that open a scope of their own: names bound in them do not reach the code around.
_SCOPES = (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda, ast.ClassDef)


def _own_nodes(scope: ast.AST) -> list[ast.AST]:
    """Return the nodes of a scope's own code (a nested scope: its node, defaults, decorators)."""
    out: list[ast.AST] = []
    todo = list(ast.iter_child_nodes(scope))
    while todo:
        node = todo.pop()
        out.append(node)
        if not isinstance(node, _SCOPES):
            todo.extend(ast.iter_child_nodes(node))
            continue
        todo += getattr(node, "decorator_list", []) + getattr(node, "bases", [])
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef | ast.Lambda):
            todo += node.args.defaults + [d for d in node.args.kw_defaults if d is not None]
    return out


def _stored(nodes: list[ast.AST]) -> set[str]:
    """Names a scope binds otherwise than by an import (assignments, loops, arguments, defs)."""
    names = {n.id for n in nodes if isinstance(n, ast.Name) and isinstance(n.ctx, ast.Store)}
    names |= {n.arg for n in nodes if isinstance(n, ast.arg)}
    names |= {n.name for n in nodes if isinstance(n, ast.FunctionDef | ast.AsyncFunctionDef)}
    names |= {n.name for n in nodes if isinstance(n, ast.ClassDef)}
    return names


def _problems(tree: ast.Module, folder: Path) -> list[str]:
    """Check a module scope by scope: each sees the imports of its own and enclosing scopes."""
    out: list[str] = []
    _check_scope(tree, {}, folder, out)
    return sorted(set(out), key=lambda s: int(s.split(":")[0].split()[1]))


def _check_scope(scope: ast.AST, outer: dict[str, Any], folder: Path, out: list[str]) -> None:
    # name -> ("package", [objects it may stand for]) or ("script", path of a sibling script)
    nodes = _own_nodes(scope)
    bound = {k: v for k, v in outer.items() if k not in _stored(nodes)}  # its arguments too
    for node in sorted((n for n in nodes if isinstance(n, ast.Import | ast.ImportFrom)),
                       key=lambda n: n.lineno):  # fmt: skip
        _bind(node, bound, folder, out)

    def resolve(node: ast.AST) -> tuple[list[Any], str] | None:
        """Return what an attribute chain rooted at a bound name may be (checked on the way)."""
        parts = _chain(node)
        if parts is None or bound.get(parts[0], ("", None))[0] != "package":
            return None
        objs = bound[parts[0]][1]
        for i, attr in enumerate(parts[1:], start=1):
            found = [getattr(o, attr) for o in objs if hasattr(o, attr)]
            if not found:
                where = ".".join(parts[:i])
                return [], f"line {node.lineno}: {where} has no attribute {attr!r}"
            if not all(inspect.ismodule(o) or inspect.isclass(o) for o in found):
                return found, ""  # an instance or a function: its own attributes are not checked
            objs = found
        return objs, ""

    for node in nodes:
        if isinstance(node, _SCOPES):
            _check_scope(node, bound, folder, out)
        elif isinstance(node, ast.Attribute) and not isinstance(node.ctx, ast.Store):
            parts = _chain(node)
            kind, what = bound.get(parts[0], ("", None)) if parts else ("", None)
            if kind == "script" and parts[1] not in _top_level_names(what):
                out.append(f"line {node.lineno}: {parts[0]}.{parts[1]}: the script {what.name} "
                           f"defines no {parts[1]}")  # fmt: skip
            elif kind == "package" and (got := resolve(node)) and got[1]:
                out.append(got[1])
        elif isinstance(node, ast.Call):
            out += _call_problems(node, resolve)


def _bind(node: ast.Import | ast.ImportFrom, bound: dict[str, Any], folder: Path,
          out: list[str]) -> None:  # fmt: skip
    """Bind the names an import of the package or of a sibling script makes; report others."""
    if isinstance(node, ast.Import):
        for alias in node.names:
            top = alias.name.split(".")[0]
            name = alias.asname or top
            if top == PACKAGE:
                try:
                    mod = importlib.import_module(alias.name)
                except ImportError as e:
                    out.append(f"line {node.lineno}: import {alias.name}: {e}")
                    continue
                bound[name] = ("package", [mod if alias.asname else importlib.import_module(top)])
            elif (folder / f"{top}.py").exists() and alias.name == top:
                bound[name] = ("script", folder / f"{top}.py")
            else:
                bound.pop(name, None)
        return
    top = (node.module or "").split(".")[0]
    for alias in node.names:
        name = alias.asname or alias.name
        bound.pop(name, None)
        if node.level == 0 and top == PACKAGE:
            try:
                bound[name] = ("package", [_from_module(node.module, alias.name)])
            except (ImportError, AttributeError) as e:
                out.append(f"line {node.lineno}: from {node.module} import {alias.name}: {e}")
        elif node.level == 0 and node.module == top and (folder / f"{top}.py").exists():
            if alias.name not in _top_level_names(folder / f"{top}.py"):
                out.append(f"line {node.lineno}: from {top} import {alias.name}: the script "
                           f"{top}.py defines no {alias.name}")  # fmt: skip


def _call_problems(node: ast.Call, resolve: Any) -> list[str]:
    """Whether a call of a package function or class binds to its signature."""
    got = resolve(node.func)
    if not got or got[1]:
        return []
    starred = any(isinstance(a, ast.Starred) for a in node.args)
    spread = any(k.arg is None for k in node.keywords)
    out = []
    for obj in got[0][:1]:
        if not callable(obj) or inspect.ismodule(obj):
            continue
        try:
            sig = inspect.signature(obj)
        except (TypeError, ValueError):
            continue
        name = ast.unparse(node.func)
        params = sig.parameters.values()
        if not any(p.kind is p.VAR_KEYWORD for p in params):
            accepted = {p.name for p in params if p.kind is not p.POSITIONAL_ONLY}
            for kw in node.keywords:
                if kw.arg is not None and kw.arg not in accepted:
                    out.append(f"line {node.lineno}: {name}() has no parameter {kw.arg!r}")
        if out or starred or spread:
            continue
        try:
            sig.bind(*node.args, **{k.arg: k.value for k in node.keywords})
        except TypeError as e:
            out.append(f"line {node.lineno}: {name}(): {e}")
    return out


def test_there_are_scripts():
    assert len(SCRIPTS) >= 10, SCRIPTS_DIR


@pytest.mark.parametrize("path", SCRIPTS, ids=lambda p: p.name)
def test_script_uses_names_the_package_has(path: Path):
    found = problems(path)
    assert not found, f"{path.name} uses names the package does not have:\n" + "\n".join(found)


def test_the_check_sees_removed_and_renamed_names(tmp_path: Path):
    """The check fails on the kinds of breakage a change of the API makes."""
    (tmp_path / "helper.py").write_text("def there():\n    pass\n")
    script = tmp_path / "broken.py"
    script.write_text(
        "import o3d_ofp as ofp\n"
        "from o3d_ofp.workflows.pipeline import BasesAhead\n"
        "from o3d_ofp.workflows import matching\n"
        "from helper import there, gone\n"
        "import helper as H\n"
        "def main():\n"
        "    from o3d_ofp.workflows.estimate import match_eigenbases\n"
        "    ofp.transfer_colors(1, 2, p2p_21=3)\n"
        "    ofp.no_such_name\n"
        "    matching.no_such_constant\n"
        "    match_eigenbases(1, 2, zoomout_to=99)\n"
        "    ofp.Correspondence.from_p2p(1, 2, 3, 4, 5, 6)\n"
        "    ofp.MatchOptions(zoomout_to=99).whatever\n"
        "    H.missing()\n"
        "CHILD = 'import o3d_ofp as ofp\\nofp.gone_too()'\n"
    )  # fmt: skip
    found = "\n".join(problems(script))
    for needle in (
        "BasesAhead",
        "from helper import gone",
        "transfer_colors() has no parameter 'p2p_21'",
        "no attribute 'no_such_name'",
        "no attribute 'no_such_constant'",
        "match_eigenbases() has no parameter 'zoomout_to'",
        "from_p2p(): too many positional arguments",
        "H.missing",
        "no attribute 'gone_too'",
    ):
        assert needle in found, (needle, found)
    assert "whatever" not in found  # an instance's attributes are not checked


def test_the_check_follows_scopes(tmp_path: Path):
    """A name imported in one function is that import there only; a local name hides it."""
    script = tmp_path / "scoped.py"
    script.write_text(
        "def planned():\n"
        "    from o3d_ofp.workflows import plan\n"
        "    return plan.DENSE_VERTICES, plan.not_there\n"
        "def run(plan):\n"
        "    return plan.estimator\n"
        "def other():\n"
        "    plan = make()\n"
        "    return plan.exact, lambda plan: plan.task\n"
    )  # fmt: skip
    assert problems(script) == ["line 3: plan has no attribute 'not_there'"]
