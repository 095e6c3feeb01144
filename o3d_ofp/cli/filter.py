"""``o3d-ofp filter``: smooth or sharpen a shape (a low-pass over its Laplacian's spectrum).

``--smooth`` is one length at every scale and resolution (a fraction of √area, see
:mod:`o3d_ofp.core.filtering`); ``--sharpen`` is a gain in [0, 2].
"""

from __future__ import annotations

import argparse

from ._common import (
    CLOUD_OUT,
    MESH_HELP,
    MESH_OUT,
    UsageError,
    about,
    check_memory,
    check_output,
    check_output_kind,
    load_basis_file,
    read_shape,
    report,
    stage,
)
from ._types import bounded_float

__all__ = ["add_parser", "run"]


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Register the command."""
    from ..core.filtering import DEFAULT_SMOOTH, MAX_SHARPEN, MAX_SMOOTH
    from ..workflows.options import COMPONENTS

    p = sub.add_parser("filter", help="smooth or sharpen a shape (volume kept)")
    p.add_argument("mesh", help=MESH_HELP)
    p.add_argument(
        "--smooth", type=bounded_float(0.0, MAX_SMOOTH),
        help=f"smoothing radius as a fraction of sqrt(surface area), in [0, {MAX_SMOOTH:g}]: "
        "detail smaller than about SMOOTH * sqrt(area) is removed, the same at every scale and "
        f"resolution (e.g. {DEFAULT_SMOOTH:g}); with --sharpen: the size of the detail enhanced "
        f"({DEFAULT_SMOOTH:g})",
    )  # fmt: skip
    p.add_argument(
        "--sharpen", type=bounded_float(0.0, MAX_SHARPEN),
        help=f"detail gain in [0, {MAX_SHARPEN:g}]: the detail smaller than --smooth is multiplied "
        "by 1 + SHARPEN (beyond 2 triangles turn over)",
    )  # fmt: skip
    p.add_argument("--keep-size", choices=("volume", "none"), default="volume",
                   help="rescale the result to the input's enclosed volume (a cloud: its spread) "
                   "(volume)")  # fmt: skip
    p.add_argument(
        "--components", choices=COMPONENTS, default="auto",
        help="several connected components: auto keeps the largest if it holds >= 90%% of the "
        "area (else refuses), largest always keeps it, error always refuses (default: auto)",
    )  # fmt: skip
    p.add_argument("--basis", help="cached basis of MESH (.npz; its Laplacian is used)")
    p.add_argument("-o", "--output", required=True, help="filtered mesh or cloud")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Filter the coordinates and write the shape.

    The low-pass is two complex sparse factorizations of the whole mesh (no eigenfunctions):
    its stage says so, and that it still runs (the library reports no progress inside them).
    """
    from ..boundary.api import filter_geometry
    from ..boundary.io import write_geometry
    from ..core.filtering import DEFAULT_SMOOTH

    check_output(args.output, (*MESH_OUT, *CLOUD_OUT), inputs=(args.mesh,))
    if args.smooth is None and args.sharpen is None:
        raise UsageError("give --smooth RADIUS and/or --sharpen GAIN")
    geometry, V, F = read_shape(args.mesh)
    check_output_kind(args.output, F)
    n, points = V.shape[0], "vertices" if F is not None else "points"
    basis = None
    if args.basis:
        basis = load_basis_file(args.basis, V, F, args.mesh, args, "--basis").eig
    else:
        check_memory(args.mesh, n, k=1, order=1, advice="use a simplified mesh (fewer vertices)")
    size = DEFAULT_SMOOTH if args.smooth is None else args.smooth
    if args.sharpen is None:
        what = f"smooth {size:g} (radius {size:g} sqrt(area))"
    else:
        what = f"sharpen {args.sharpen:g} (detail smaller than {size:g} sqrt(area))"
    laplacian = "" if basis is not None else "its Laplacian, then "
    with stage(f"{what.split(' (')[0]} of {args.mesh} ({n} {points}: {laplacian}two complex "
               "sparse factorizations)"), about(args.mesh):  # fmt: skip
        out = filter_geometry(
            geometry, smooth=args.smooth, sharpen=args.sharpen, basis=basis,
            keep_volume=args.keep_size == "volume", components=args.components,
        )  # fmt: skip
    write_geometry(args.output, out, protect=(args.mesh,))
    report([f"{args.mesh}: {what}", f"wrote {args.output}"])
    return 0
