"""The package's layers: imports go one way, Open3D only at the boundary and above.

Every module of ``o3d_ofp`` is parsed (imports inside functions included). The test fails on a
cycle between modules, on a module importing from a higher layer, and on ``open3d`` imported
(by ``import``, ``from`` or ``importlib.import_module("open3d")``) below the boundary layer.
"""

from __future__ import annotations

import ast
import inspect
import subprocess
import sys
from pathlib import Path

import pytest

import o3d_ofp as ofp

ROOT = Path(__file__).resolve().parents[1] / "o3d_ofp"

#: Layer of each top-level part of the package: a module may import from its own layer or a
#: lower one, never from a higher one.
LAYERS = {
    "core": 0,
    "workflows": 1,
    "boundary": 2,
    "render": 3,
    "collections": 3,
    "cli": 4,
}
ROOT_LAYER = 5  # o3d_ofp/__init__.py and __main__.py
BOUNDARY = LAYERS["boundary"]


def _module_name(path: Path) -> str:
    parts = ("o3d_ofp", *path.relative_to(ROOT).with_suffix("").parts)
    name = ".".join(parts)
    return name.removesuffix(".__init__")


def _modules() -> dict[str, Path]:
    return {_module_name(p): p for p in ROOT.rglob("*.py")}


def _layer(module: str) -> int:
    parts = module.split(".")
    if len(parts) == 1 or parts[1] not in LAYERS:
        return ROOT_LAYER
    return LAYERS[parts[1]]


def _imports(module: str, path: Path, modules: dict[str, Path]) -> tuple[set[str], set[str]]:
    """(package modules imported, external top-level names imported) by one module."""
    tree = ast.parse(path.read_text(), filename=str(path))
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    internal: set[str] = set()
    external: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                name = alias.name
                if name.split(".")[0] == "o3d_ofp":
                    internal.add(_deepest(name, modules))
                else:
                    external.add(name.split(".")[0])
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")
                base = base[: len(base) - (node.level - 1)]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ""
                if target.split(".")[0] != "o3d_ofp":
                    external.add(target.split(".")[0])
                    continue
            for alias in node.names:  # `from pkg import submodule` imports the submodule
                sub = f"{target}.{alias.name}"
                internal.add(sub if sub in modules else _deepest(target, modules))
        elif (
            isinstance(node, ast.Call)
            and isinstance(node.func, ast.Attribute)
            and node.func.attr == "import_module"
            and node.args
            and isinstance(node.args[0], ast.Constant)
            and isinstance(node.args[0].value, str)
        ):
            external.add(node.args[0].value.split(".")[0])
    internal.discard(module)
    return internal, external


def _deepest(name: str, modules: dict[str, Path]) -> str:
    while name not in modules and "." in name:
        name = name.rpartition(".")[0]
    return name


def _graph() -> tuple[dict[str, set[str]], dict[str, set[str]]]:
    modules = _modules()
    graph, external = {}, {}
    for name, path in modules.items():
        graph[name], external[name] = _imports(name, path, modules)
    return graph, external


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    out: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in sorted(graph.get(v, ())):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


def test_layers_are_the_folders():
    top = {p.name for p in ROOT.iterdir() if p.is_dir() and (p / "__init__.py").exists()}
    assert top <= set(LAYERS), f"a folder without a layer: {sorted(top - set(LAYERS))}"
    assert {"core", "workflows", "boundary", "render", "cli"} <= top
    loose = sorted(p.name for p in ROOT.glob("*.py"))
    assert loose == ["__init__.py", "__main__.py"], f"modules outside the layers: {loose}"


def test_no_import_cycles():
    graph, _ = _graph()
    cycles = _cycles(graph)
    assert not cycles, "import cycles: " + "; ".join(" -> ".join(c) for c in cycles)


def test_imports_only_go_down():
    graph, _ = _graph()
    upward = [
        f"{a} (layer {_layer(a)}) imports {b} (layer {_layer(b)})"
        for a, targets in sorted(graph.items())
        for b in sorted(targets)
        if _layer(b) > _layer(a)
    ]
    assert not upward, "upward imports:\n" + "\n".join(upward)


def test_open3d_only_at_the_boundary_and_above():
    _, external = _graph()
    below = sorted(m for m, names in external.items() if "open3d" in names and _layer(m) < BOUNDARY)
    assert not below, f"open3d imported below the boundary layer: {below}"


def test_the_checks_catch_what_they_are_named_after():
    # A cycle, an upward edge and an open3d import in core must all be seen.
    assert _cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": set()}) == [["a", "b", "c"]]
    assert _layer("o3d_ofp.core.basis") < _layer("o3d_ofp.workflows.pipeline")
    fake = ROOT / "core" / "_probe_for_test.py"
    assert not fake.exists()
    source = "def f():\n    import open3d\n    from ..workflows import pipeline\n"
    tree_imports = _imports_of_source(source, "o3d_ofp.core._probe_for_test")
    assert "open3d" in tree_imports[1]
    assert "o3d_ofp.workflows.pipeline" in tree_imports[0]


def _imports_of_source(source: str, module: str) -> tuple[set[str], set[str]]:
    import tempfile

    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "probe.py"
        path.write_text(source)
        return _imports(module, path, _modules())


def test_import_does_not_import_open3d_or_dask():
    code = (
        "import sys, o3d_ofp\n"
        "bad = [m for m in ('open3d', 'dask', 'distributed', 'matplotlib') if m in sys.modules]\n"
        "assert not bad, bad\n"
    )
    subprocess.run([sys.executable, "-c", code], check=True)


@pytest.mark.parametrize(
    "name",
    ["transfer_colors", "transfer_detail", "filter_geometry", "texture_colors", "read_geometry",
     "write_geometry", "eigenbasis", "match"],
)  # fmt: skip
def test_package_functions_have_real_signatures_and_docs(name):
    fn = getattr(ofp, name)
    params = inspect.signature(fn).parameters
    assert params, name
    assert not any(p.kind in (p.VAR_POSITIONAL,) for p in params.values()), name
    assert fn.__doc__ and "Parameters" in fn.__doc__, name
    assert name in ofp.__all__


def test_the_version_is_the_projects():
    import tomllib

    from o3d_ofp import __version__

    with open(ROOT.parent / "pyproject.toml", "rb") as fh:
        assert tomllib.load(fh)["project"]["version"] == __version__


def _code_names(module_path: Path) -> set[str]:
    """Names a module's code uses (attributes and identifiers, not its comments or strings)."""
    names: set[str] = set()
    for node in ast.walk(ast.parse(module_path.read_text())):
        if isinstance(node, ast.Name):
            names.add(node.id)
        elif isinstance(node, ast.Attribute):
            names.add(node.attr)
        elif isinstance(node, ast.alias):
            names.add(node.asname or node.name.rpartition(".")[2])
    return names


#: Each decision of a job between two shapes, the names its rule is made with, and the one
#: module allowed to use them (besides where they are defined). The README's "Architecture"
#: names the function: workflows.plan.plan_pair decides, workflows.plan.prepare runs it.
DECISIONS = {
    "dense path or not": (
        {"DENSE_VERTICES"}, {"o3d_ofp.workflows.plan", "o3d_ofp.workflows.dense"},
    ),
    "eigenbasis sizes": (
        {"needs"},
        {"o3d_ofp.workflows.plan", "o3d_ofp.workflows.strategy", "o3d_ofp.workflows.partial",
         "o3d_ofp.workflows.detail"},
    ),
    "partial or full, which estimator": (
        {"strategy_of", "FullMatch", "PartialMatch"},
        {"o3d_ofp.workflows.plan", "o3d_ofp.workflows.estimate", "o3d_ofp.workflows.matching",
         "o3d_ofp.workflows.partial"},
    ),
}  # fmt: skip


@pytest.mark.parametrize("decision", sorted(DECISIONS))
def test_each_decision_is_made_in_one_place(decision):
    names, allowed = DECISIONS[decision]
    found = sorted(
        f"{module} uses {sorted(names & _code_names(path))}"
        for module, path in _modules().items()
        if module not in allowed and names & _code_names(path)
    )
    assert not found, f"{decision} is re-decided outside its place: {found}"


def test_front_ends_run_the_planner_and_never_re_decide():
    """The command line and the collections plan with workflows.plan; no estimation internals."""
    internals = {
        "ESTIMATION_K", "FIT_K", "required_k", "DENSE_VERTICES", "match_eigenbases", "estimate",
        "estimate_dense", "strategy_of", "FullMatch", "PartialMatch", "coarse_copies",
        "refuse_clouds",
    }  # fmt: skip
    found = sorted(
        f"{module}: {sorted(internals & _code_names(path))}"
        for module, path in _modules().items()
        if module.split(".")[1:2] in (["cli"], ["collections"]) and internals & _code_names(path)
    )
    assert not found, found


def test_the_checks_of_decisions_catch_a_re_decision(tmp_path):
    probe = tmp_path / "probe.py"
    probe.write_text("from ..workflows.dense import DENSE_VERTICES\nx = n > DENSE_VERTICES\n")
    assert "DENSE_VERTICES" in _code_names(probe)
    probe.write_text('"""DENSE_VERTICES in words only."""\n# DENSE_VERTICES\n')
    assert "DENSE_VERTICES" not in _code_names(probe)


def test_the_defaults_of_the_bases_are_written_once():
    """K = 29 and k2 = 39 (the paper's K = 30 / 40) as literals in one place each.

    29 is core.spectrum.DEFAULT_K; 39 is BasisOptions.k2 (and the full match's second fit
    size, WIDE_FIT_K, a measured constant of its own).
    """
    found: dict[int, set[str]] = {29: set(), 39: set()}
    for module, path in _modules().items():
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Constant) and type(node.value) is int and node.value in found:
                found[node.value].add(module)
    assert found[29] <= {"o3d_ofp.core.spectrum"}, found
    assert found[39] <= {"o3d_ofp.workflows.options", "o3d_ofp.workflows.matching"}, found
