"""``o3d-ofp render``: meshes side by side in a PNG, headless."""

from __future__ import annotations

import argparse
import os

import numpy as np

from ..render.panel import MAX_SIDE, MIN_SIDE, View, colormap, geometry_items, render_panel
from . import _common as common
from ._common import UsageError, report, stage

__all__ = ["add_parser", "run"]


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Register the command."""
    p = sub.add_parser("render", help="render meshes side by side into a PNG (headless)")
    a, side = p.add_argument, common.bounded_int(MIN_SIDE, MAX_SIDE)
    a("mesh", nargs="+", help=common.MESH_HELP)
    a("--titles", help="comma-separated titles (default: the file names)")
    a("--scalars", nargs="+", help="one .npy of per-vertex scalars per mesh ('-' for none)")
    a("--colormap", default="viridis", help="matplotlib colormap (viridis)")
    a("--label", help="label of the color bar (with --scalars)")
    a("--width", type=side, help=f"tile width in pixels ({MIN_SIDE}-{MAX_SIDE})")
    a("--height", type=side, help=f"tile height in pixels ({MIN_SIDE}-{MAX_SIDE})")
    a("--columns", type=common.positive_int, help="tiles per row (default: all, up to 6 per row)")
    a("--front", type=common.vector3, default=(0.0, 0.0, 1.0), help="camera direction x,y,z")
    a("--up", type=common.vector3, default=(0.0, 1.0, 0.0), help="up direction x,y,z")
    a("--zoom", type=common.unit_float, default=0.6,
      help="camera distance in (0, 1): smaller is closer (0.6: the shape fills 90%% of a tile)")
    a("-o", "--output", required=True, help="PNG file")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Read the meshes (and scalars), render, write the PNG."""
    common.check_output(args.output, (".png",), inputs=args.mesh)
    n = len(args.mesh)
    titles = args.titles.split(",") if args.titles else [os.path.basename(p) for p in args.mesh]
    scalars = args.scalars or ["-"] * n
    common.refuse(
        (args.label and not args.scalars, "--label names the color bar of --scalars: give "
         "--scalars too"),
        (len(titles) != n, f"--titles has {len(titles)} entries for {n} meshes"),
        (len(scalars) != n, f"--scalars has {len(scalars)} entries for {n} meshes ('-' for none)"),
    )  # fmt: skip
    view = View(front=args.front, up=args.up, zoom=args.zoom)
    try:
        view.check()
    except ValueError as exc:
        up, front = (",".join(f"{x:g}" for x in v) for v in (args.up, args.front))
        raise UsageError(f"--up {up} is parallel to --front {front}; give another --up") from exc
    try:  # an unknown colormap, named by its flag before any work
        colormap(np.zeros(1), args.colormap)
    except ValueError as exc:
        raise UsageError(f"--colormap {args.colormap}: {exc}") from exc
    # each mesh's colors, or its own texture, or its scalars
    items, textures = geometry_items([common.read_shape(path)[0] for path in args.mesh])
    for i, (path, npy, (V, F, _)) in enumerate(zip(args.mesh, scalars, items, strict=True)):
        if npy != "-":
            values = common.load_npy(npy, "per-vertex scalars", flag="--scalars")
            values = values[:, 0] if values.ndim == 2 and values.shape[1] == 1 else values
            common.refuse((values.shape != (V.shape[0],), f"--scalars {npy}: shape "
                           f"{values.shape}, expected ({V.shape[0]},) for {path}"))  # fmt: skip
            items[i], textures[i] = (V, F, values.astype(np.float64)), None
    options = {k: v for k, v in (("width", args.width), ("height", args.height),
                                 ("colorbar_label", args.label)) if v}  # fmt: skip
    with stage(f"rendering {len(items)} views"):
        panel = render_panel(items, args.output, titles=titles, textures=textures,
                             columns=args.columns, view=view, cmap=args.colormap, **options)
    report([f"wrote {args.output} ({panel.shape[1]}x{panel.shape[0]} pixels)"])
    return 0
