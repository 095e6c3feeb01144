"""``o3d-ofp demo``: the quick start on procedural shapes; meshes, a picture and the errors."""

from __future__ import annotations

import argparse
import os

from ..boundary.convert import require_open3d, triangle_mesh_from_arrays
from ..boundary.io import write_geometry
from ..core._atomic import output_folder
from ..render.panel import RenderError, render_panel
from ..workflows.options import BasisOptions
from . import _common as common
from ._common import UsageError, positive_int, report, stage

__all__ = ["add_parser", "run"]


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Register the command."""
    p = sub.add_parser(
        "demo", help="approximate and transfer colors on procedural shapes; write meshes and a PNG",
        description="Build the eigenbasis and both OFP bases of a procedural shape, approximate "
        "its RGB colors and coordinates, transfer the colors to a deformed copy with an estimated "
        "map, write the meshes as PLY and a picture, and print the errors.",
    )  # fmt: skip
    default, a = BasisOptions(), p.add_argument
    a("-o", "--output", default="demo_out", help="output folder (demo_out)")
    a("-k", "--k", type=positive_int, default=default.k1, help=f"eigenfunctions ({default.k1})")
    a("--order", type=positive_int, default=default.order,
      help=f"product order N ({default.order})")
    a("--subdivisions", type=common.bounded_int(2, 9), default=5, help="icosphere subdivisions of "
      "the shape, 2-9 (5: 10242 vertices; the map estimate needs the 162 of 2)")
    a("--seed", type=common.nonnegative_int, default=0, help="shape seed (0)")  # fmt: skip
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Run the demo workflow, print its table, write its meshes and picture."""
    require_open3d()
    out = os.path.abspath(args.output)
    common.check_folder_to_make(args.output, "-o")  # made with its parents after the checks
    n_vertices = 10 * 4**args.subdivisions + 2  # the icosphere the blob is made from
    common.refuse((args.k > n_vertices - 1, f"-k {args.k}: the shape of --subdivisions "
                   f"{args.subdivisions} has {n_vertices} vertices: at most {n_vertices - 1}"))
    try:
        with output_folder(out):  # a refused or interrupted demo leaves no empty folder
            return _run(args, out)
    except OSError as exc:
        if exc.filename and os.path.abspath(exc.filename) == out:
            raise UsageError(f"-o {args.output}: cannot make the folder ({exc.strerror})") from exc
        raise


def _run(args: argparse.Namespace, out: str) -> int:
    from ..workflows.demo import run_demo

    with stage("demo: bases, approximations and a transfer"):
        result = run_demo(subdivisions=args.subdivisions, seed=args.seed, k=args.k,
                          order=args.order)  # fmt: skip
    V, F = result.vertices, result.faces
    lines = [f"demo: procedural blob with {len(V)} vertices, k={result.k} eigenfunctions, order "
             f"{result.order}",
             f"{'basis':<8} {'functions':>9} {'RGB error':>10} {'XYZ error':>10} {'seconds':>8}"]
    shapes = [("original", "original", V, result.colors)]
    for row in result.rows:
        lines.append(f"{row.name:<8} {row.size:>9d} {100 * row.rgb_error:>9.2f}% "
                     f"{100 * row.xyz_error:>9.2f}% {row.seconds:>8.2f}")  # fmt: skip
        tag = {"K eigs": "eigs", "ours": "ours", "ours*": "ours_star"}[row.name]
        shapes.append((tag, f"{row.name} ({row.size})", V, row.colors))
    lines.append(f"transfer to a bent copy: map error {result.map_error:.4f} (mean distance / "
                 f"sqrt(area)), RGB error {100 * result.transfer_error:.2f}%, "
                 f"{result.transfer_seconds:.2f} s")  # fmt: skip
    shapes.append(("transfer_target", "transferred", result.target_vertices, result.transferred))
    written = [os.path.join(out, f"blob_{tag}.ply") for tag, *_ in shapes]
    for path, (_, _, X, colors) in zip(written, shapes, strict=True):
        write_geometry(path, triangle_mesh_from_arrays(X, F, colors=colors))
    png = os.path.join(out, "demo.png")
    try:
        with stage("rendering demo.png"):
            render_panel([(X, F, c) for *_, X, c in shapes], png, titles=[t for _, t, *_ in shapes])
        written.append(png)
    except RenderError as exc:
        lines.append(f"no picture: {exc}")
    report([*lines, "wrote " + ", ".join(os.path.relpath(p) for p in written),
            "errors are ‖f − f̃‖_M / ‖f‖_M (XYZ centred on the area-weighted mean)"])  # fmt: skip
    return 0
