"""``o3d-ofp basis``: compute a basis once and store it; or the bases of a whole collection."""

from __future__ import annotations

import argparse
import os

from ..collections import bases_many
from ..core.products import n_eigenproducts
from . import _common as common
from ._common import report
from ._progress import ENABLED

__all__ = ["add_parser", "run"]


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Register the command."""
    p = sub.add_parser("basis", help="compute a basis once and store it (.npz), or cache the bases "
                       "of a collection")  # fmt: skip
    p.add_argument("mesh", nargs="+",
                   help=common.MESH_HELP + "; several, or folders of them, with --cache DIR")
    common.add_basis_options(p)
    p.add_argument("-o", "--output", help="basis file (.npz) of one shape")
    common.add_collection_options(p, description="give several shapes, or folders of them, with "
                                  "--cache DIR and no -o: each shape's bases are stored in DIR (a "
                                  "line per shape printed; entries already cached are checked "
                                  "and kept)", force=False)  # fmt: skip
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Compute the basis of ``args.mesh`` and write it to ``args.output`` (or to the cache)."""
    common.check_folder_to_make(args.cache, "--cache")
    if args.output is None or not common.single(args, "mesh"):
        return _run_many(args)
    common.check_output(args.output, (".npz",), inputs=(args.mesh,))
    _, V, F = common.read_shape(args.mesh)
    B = common.shape_basis(V, F, args.mesh, args)
    B.save(args.output)
    cleaning = B.eig.cleaning.report if B.eig.cleaning is not None else None
    report([f"{args.mesh}: {V.shape[0]} vertices, k={B.k}, order {B.order}, tol {B.tol:g}: kept "
            f"{B.size} of {n_eigenproducts(B.k, B.order)} products",
            *([f"cleaning: {cleaning}"] if cleaning is not None else []),
            f"wrote {args.output}"])  # fmt: skip
    return 0


def _run_many(args: argparse.Namespace) -> int:
    """Cache the eigenbasis (for map estimation) and the OFP basis of every shape."""
    common.refuse(
        (args.output is not None, "-o names the basis file of ONE shape; for several shapes give "
         "--cache DIR"),
        (args.cache is None, "give -o FILE.npz (one shape) or --cache DIR (any number of shapes)"),
        # before any work, as transfer and detail do for their targets
        *((not os.path.exists(m), f"{m}: no such shape file or folder") for m in args.mesh),
    )  # fmt: skip
    records = bases_many(args.mesh, cache_dir=args.cache, client=args.scheduler,
                         components=args.components, workers=args.workers, progress=ENABLED.on,
                         **common.basis_flags(args, k=args.k))  # fmt: skip
    return common.report_records(records)
