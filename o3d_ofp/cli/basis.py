"""``o3d-ofp basis``: compute a basis once and store it."""

from __future__ import annotations

import argparse

from ._common import MESH_HELP, add_basis_options, basis_for, check_output, read_shape, report

__all__ = ["add_parser", "run"]


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Register the command."""
    p = sub.add_parser("basis", help="compute a basis once and store it (.npz)")
    p.add_argument("mesh", help=MESH_HELP)
    add_basis_options(p)
    p.add_argument("-o", "--output", required=True, help="basis file (.npz)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Compute the basis of ``args.mesh`` and write it to ``args.output``."""
    from ..core.products import n_eigenproducts
    from ._common import check_cache_dir

    check_output(args.output, (".npz",), inputs=(args.mesh,))
    check_cache_dir(args.cache)
    _, V, F = read_shape(args.mesh)
    B, _ = basis_for(V, F, args.mesh, args, k=args.k)
    B.save(args.output)
    cleaning = B.eig.cleaning.report if B.eig.cleaning is not None else None
    report(
        [
            f"{args.mesh}: {V.shape[0]} vertices, k={B.k}, order {B.order}, tol {B.tol:g}: "
            f"kept {B.size} of {n_eigenproducts(B.k, B.order)} products",
            *([f"cleaning: {cleaning}"] if cleaning is not None else []),
            f"wrote {args.output}",
        ]
    )
    return 0
