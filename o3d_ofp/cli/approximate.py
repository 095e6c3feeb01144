"""``o3d-ofp approximate``: approximate a signal in the basis and print the error."""

from __future__ import annotations

import argparse

from ..core.basis import approximation_error
from . import _common as common
from ._common import report

__all__ = ["add_parser", "run"]


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Register the command."""
    p = sub.add_parser("approximate", help="approximate a signal in the basis; print the error")
    p.add_argument("mesh", help=common.MESH_HELP)
    p.add_argument("--signal", default="colors", help="colors (vertex colors), texture (UV "
                   "texture), xyz (coordinates) or FILE.npy")  # fmt: skip
    p.add_argument("--texture", help="texture image for --signal texture (default: the mesh's)")
    common.add_basis_options(p)
    p.add_argument("--basis", help="cached basis of MESH (.npz)")
    p.add_argument("-o", "--output", required=True, help="output mesh, cloud or .npy")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Approximate the signal and write it."""
    inputs = (args.mesh, args.signal, args.texture, args.basis)
    common.check_output(args.output, (*common.GEOMETRY_OUT, ".npy"), inputs=inputs,
                 side=common.signal_sides(args))  # fmt: skip
    common.check_folder_to_make(args.cache, "--cache")
    geometry, V, F = common.read_shape(args.mesh)
    common.check_output_kind(args.output, F)  # (a .npy output holds values, no faces)
    f, kind = common.read_signal(geometry, V, args.mesh, args.signal, args.texture, args.output)
    B = common.shape_basis(V, F, args.mesh, args)
    g = B.approximate(f)
    written = common.write_result(args.output, geometry, g, kind, protect=inputs)
    if kind == "xyz":  # about the centroid: the error of the shape, not of where it sits
        # (the basis holds the constant, so f − f̃ is the same for the centred coordinates)
        centroid = (B.mass @ f) / B.mass.sum()
        f, g = f - centroid, g - centroid
        what = "relative error of the coordinates about their centroid ‖f − f̃‖_M / ‖f − f̄‖_M"
    else:
        what = "relative error ‖f − f̃‖_M / ‖f‖_M"
    report([f"{args.mesh}: {B.size} basis functions (k={B.k}, order {B.order}, tol {B.tol:g}); "
            f"{what} = {approximation_error(f, g, B.mass):.4%}",
            "wrote " + ", ".join(written)])  # fmt: skip
    return 0
