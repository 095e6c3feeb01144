"""``o3d-ofp filter``: smooth or sharpen a shape (a low-pass over its Laplacian's spectrum).

``--smooth`` is one length at every scale and resolution (a fraction of √area, see
:mod:`o3d_ofp.core.filtering`); ``--sharpen`` is a gain in [0, 2].
"""

from __future__ import annotations

import argparse

from ..boundary.api import filter_geometry
from ..boundary.io import write_geometry
from ..core.filtering import DEFAULT_SMOOTH, MAX_SHARPEN, MAX_SMOOTH
from . import _common as common
from ._common import MESH_HELP, bounded_float

__all__ = ["add_parser", "run"]


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Register the command."""
    p = sub.add_parser("filter", help="smooth or sharpen a shape (volume kept)")
    a = p.add_argument
    a("mesh", help=MESH_HELP)
    a("--smooth", type=bounded_float(0.0, MAX_SMOOTH), help="radius in [0, "
      f"{MAX_SMOOTH:g}] times sqrt(area): smaller detail is removed at any scale (e.g. "
      f"{DEFAULT_SMOOTH:g}); with --sharpen, the size of the detail enhanced ({DEFAULT_SMOOTH:g})")
    a("--sharpen", type=bounded_float(0.0, MAX_SHARPEN), help=f"gain in [0, {MAX_SHARPEN:g}]: "
      "multiplies the detail smaller than --smooth by 1 + SHARPEN (up to 2, a few triangles "
      "in a thousand may turn over; beyond, more)")
    a("--keep-size", choices=("volume", "none"), default="volume", help="rescale the result to the "
      "input's enclosed volume (a cloud: its spread) (volume)")
    common.add_components_option(p)
    a("--basis", help="cached basis of MESH (.npz; its Laplacian is used)")
    a("-o", "--output", required=True, help="filtered mesh or cloud")  # fmt: skip
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Filter the coordinates and write the shape.

    The low-pass is two complex sparse factorizations of the whole mesh (no eigenfunctions):
    its stage says so, and that it still runs (the library reports no progress inside them).
    """
    common.check_output(args.output, common.GEOMETRY_OUT, inputs=(args.mesh,))
    common.refuse((args.smooth is None and args.sharpen is None,
                   "give --smooth RADIUS and/or --sharpen GAIN"))  # fmt: skip
    geometry, V, F = common.read_shape(args.mesh)
    common.check_output_kind(args.output, F)
    n, points, basis = V.shape[0], "vertices" if F is not None else "points", None
    if args.basis:  # its eigenbasis: the Laplacian is used
        basis = common.load_basis_file(args.basis, V, F, args.mesh, args, "--basis").eig
    else:  # the Laplacian only: an eigenbasis of one function
        common.check_memory(args.mesh, n, k=1, order=1, advice="use a simplified mesh (fewer "
                            "vertices)")  # fmt: skip
    size = DEFAULT_SMOOTH if args.smooth is None else args.smooth
    what, detail = ((f"smooth {size:g}", f"radius {size:g} sqrt(area)") if args.sharpen is None
                    else (f"sharpen {args.sharpen:g}", f"detail smaller than {size:g} sqrt(area)"))
    laplacian = "" if basis is not None else "its Laplacian, then "
    with common.stage(f"{what} of {args.mesh} ({n} {points}: {laplacian}two complex sparse "
                      "factorizations)"), common.about(args.mesh):  # fmt: skip
        out = filter_geometry(geometry, smooth=args.smooth, sharpen=args.sharpen, basis=basis,
                              keep_volume=args.keep_size == "volume", components=args.components)
    write_geometry(args.output, out, protect=(args.mesh,))
    common.report([f"{args.mesh}: {what} ({detail})", f"wrote {args.output}"])
    return 0
