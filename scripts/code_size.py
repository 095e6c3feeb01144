"""Print the package's size as issue 40 measures it: code lines, long functions, parameters.

Code lines are the lines that hold a token other than a comment or a line break, minus the
docstrings (of modules, classes and functions). A function's length runs from its ``def`` to
its last line (docstring included); parameters count every named, ``*args`` and ``**kwargs``
one except ``self`` / ``cls``.

    python scripts/code_size.py                 # o3d_ofp/ of this checkout
    python scripts/code_size.py PATH --long 100 # functions over 100 lines
"""

from __future__ import annotations

import argparse
import ast
import io
import pathlib
import tokenize

PUBLIC = ("match", "transfer_colors", "transfer_detail", "transfer_texture")
SKIPPED = {tokenize.COMMENT, tokenize.NL, tokenize.NEWLINE, tokenize.INDENT, tokenize.DEDENT,
           tokenize.ENDMARKER}  # fmt: skip


def _docstring_lines(tree: ast.Module) -> set[int]:
    lines: set[int] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Module | ast.FunctionDef | ast.AsyncFunctionDef | ast.ClassDef):
            first = node.body[0] if node.body else None
            if isinstance(first, ast.Expr) and isinstance(first.value, ast.Constant) and isinstance(
                first.value.value, str
            ):
                lines.update(range(first.lineno, first.end_lineno + 1))
    return lines


def _code_lines(source: str, tree: ast.Module) -> int:
    lines: set[int] = set()
    for token in tokenize.generate_tokens(io.StringIO(source).readline):
        if token.type not in SKIPPED:
            lines.update(range(token.start[0], token.end[0] + 1))
    return len(lines - _docstring_lines(tree))


def _parameters(node: ast.FunctionDef | ast.AsyncFunctionDef) -> int:
    a = node.args
    named = [*a.posonlyargs, *a.args, *a.kwonlyargs]
    count = len(named) + (a.vararg is not None) + (a.kwarg is not None)
    return count - (bool(a.args) and a.args[0].arg in ("self", "cls"))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("path", nargs="?", default="o3d_ofp", help="the package folder")
    parser.add_argument("--long", type=int, default=120, help="list functions over this many lines")
    args = parser.parse_args()
    root = pathlib.Path(args.path)
    total, folders, functions = 0, {}, []
    for path in sorted(root.rglob("*.py")):
        source = path.read_text()
        tree = ast.parse(source)
        n = _code_lines(source, tree)
        total += n
        part = path.relative_to(root).parts
        folder = part[0] if len(part) > 1 else "(top)"
        folders[folder] = folders.get(folder, 0) + n
        for node in ast.walk(tree):
            if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
                length = node.end_lineno - node.lineno + 1
                functions.append((length, _parameters(node), f"{path}:{node.lineno} {node.name}"))
    print(f"code lines in {root}/: {total}")
    for folder, n in sorted(folders.items()):
        print(f"  {folder}: {n}")
    long = sorted((f for f in functions if f[0] > args.long), reverse=True)
    print(f"functions over {args.long} lines: {len(long)}")
    for length, params, where in long:
        print(f"  {length:4d} lines, {params:2d} parameters  {where}")
    api = {name: p for _, p, where in functions for name in PUBLIC
           if where.endswith(f" {name}") and "boundary" in where}  # fmt: skip
    print("parameters: " + ", ".join(f"{name} {api.get(name, '?')}" for name in PUBLIC))


if __name__ == "__main__":
    main()
