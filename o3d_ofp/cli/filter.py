"""``o3d-ofp filter``: smooth or sharpen a shape spectrally."""

from __future__ import annotations

import argparse

from ._common import (
    CLOUD_OUT,
    MESH_HELP,
    MESH_OUT,
    UsageError,
    add_basis_options,
    basis_for,
    check_cache_dir,
    check_output,
    read_shape,
    report,
    stage,
)
from ._types import bounded_float, positive_int

__all__ = ["add_parser", "run"]

#: Sharpening amounts beyond this multiply the highest frequencies by more than 11: the shape
#: is then noise, not a sharper version of itself.
MAX_SHARPEN = 10.0


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Register the command."""
    p = sub.add_parser("filter", help="smooth or sharpen a shape spectrally")
    p.add_argument("mesh", help=MESH_HELP)
    p.add_argument(
        "--smooth", type=bounded_float(0.0, 1e3), help="low-pass strength in [0, 1000] (e.g. 5)"
    )
    p.add_argument(
        "--sharpen",
        type=bounded_float(0.0, MAX_SHARPEN),
        help=f"enhancement amount in [0, {MAX_SHARPEN:g}] (e.g. 2)",
    )
    p.add_argument("-k", "--k", type=positive_int, help="eigenfunctions (14, as the paper)")
    add_basis_options(p, k=None, preset="ours*", order=3)
    p.add_argument("--basis", help="cached basis of MESH (.npz)")
    p.add_argument("-o", "--output", required=True, help="filtered mesh or cloud")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Filter the coordinates and write the shape."""
    from ..boundary.api import filter_geometry
    from ..boundary.io import write_geometry
    from ..core.filtering import sharpen_gains, smooth_gains

    check_output(args.output, (*MESH_OUT, *CLOUD_OUT), inputs=(args.mesh,))
    check_cache_dir(args.cache)
    if (args.smooth is None) == (args.sharpen is None):
        raise UsageError("give exactly one of --smooth STRENGTH or --sharpen AMOUNT")
    gains = smooth_gains(args.smooth) if args.smooth is not None else sharpen_gains(args.sharpen)
    geometry, V, F = read_shape(args.mesh)
    B, _ = basis_for(V, F, args.mesh, args, k=args.k, default_k=14, file=args.basis)
    with stage("spectral filter"):
        out = filter_geometry(geometry, gains=gains, basis=B)
    write_geometry(args.output, out)
    what = f"smooth {args.smooth}" if args.smooth is not None else f"sharpen {args.sharpen}"
    report([f"{args.mesh}: {what} with {B.size} basis functions", f"wrote {args.output}"])
    return 0
