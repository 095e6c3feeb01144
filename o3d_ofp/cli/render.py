"""``o3d-ofp render``: meshes side by side in a PNG, headless."""

from __future__ import annotations

import argparse
import os

import numpy as np

from ..render.panel import MAX_SIDE, MIN_SIDE
from ._common import MESH_HELP, UsageError, check_output, load_npy, read_shape, report, stage
from ._types import bounded_int, positive_int, unit_float, vector3

__all__ = ["add_parser", "run"]


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Register the command."""
    p = sub.add_parser("render", help="render meshes side by side into a PNG (headless)")
    p.add_argument("mesh", nargs="+", help=MESH_HELP)
    p.add_argument("--titles", help="comma-separated titles (default: the file names)")
    p.add_argument(
        "--scalars", nargs="+", help="one .npy of per-vertex scalars per mesh ('-' for none)"
    )
    p.add_argument("--colormap", default="viridis", help="matplotlib colormap (viridis)")
    p.add_argument("--label", help="label of the color bar (with --scalars)")
    side = bounded_int(MIN_SIDE, MAX_SIDE)
    p.add_argument("--width", type=side, help=f"tile width in pixels ({MIN_SIDE}-{MAX_SIDE})")
    p.add_argument("--height", type=side, help=f"tile height in pixels ({MIN_SIDE}-{MAX_SIDE})")
    p.add_argument(
        "--columns", type=positive_int, help="tiles per row (default: all, up to 6 per row)"
    )
    p.add_argument("--front", type=vector3, default=(0.0, 0.0, 1.0), help="camera direction x,y,z")
    p.add_argument("--up", type=vector3, default=(0.0, 1.0, 0.0), help="up direction x,y,z")
    p.add_argument("--zoom", type=unit_float, default=0.6, help="zoom in (0, 1) (0.6)")
    p.add_argument("-o", "--output", required=True, help="PNG file")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Read the meshes (and scalars), render, write the PNG."""
    from ..render.panel import View, colormap, geometry_items, render_panel

    check_output(args.output, (".png",), inputs=args.mesh)
    if args.label and not args.scalars:
        raise UsageError("--label names the color bar of --scalars: give --scalars too")
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
    titles = args.titles.split(",") if args.titles else [os.path.basename(p) for p in args.mesh]
    if len(titles) != len(args.mesh):
        raise UsageError(f"--titles has {len(titles)} entries for {len(args.mesh)} meshes")
    scalars = args.scalars or []
    if scalars and len(scalars) != len(args.mesh):
        raise UsageError(
            f"--scalars has {len(scalars)} entries for {len(args.mesh)} meshes ('-' for none)"
        )
    items, textures = [], []
    for i, path in enumerate(args.mesh):
        geometry, V, F = read_shape(path)
        (item,), (texture,) = geometry_items([geometry])  # colors, or the mesh's own texture
        colors = item[2]
        if scalars and scalars[i] != "-":
            values = load_npy(scalars[i], "per-vertex scalars", flag="--scalars")
            if values.ndim == 2 and values.shape[1] == 1:
                values = values[:, 0]
            if values.shape != (V.shape[0],):
                raise UsageError(
                    f"--scalars {scalars[i]}: shape {values.shape}, expected ({V.shape[0]},) "
                    f"for {path}"
                )
            colors, texture = values.astype(np.float64), None
        items.append((V, F, colors))
        textures.append(texture)
    options = {k: v for k, v in (("width", args.width), ("height", args.height)) if v}
    if args.label:
        options["colorbar_label"] = args.label
    with stage(f"rendering {len(items)} views"):
        try:
            panel = render_panel(
                items,
                args.output,
                titles=titles,
                textures=textures,
                columns=args.columns,
                view=view,
                cmap=args.colormap,
                **options,
            )
        except ValueError as exc:
            raise UsageError(str(exc)) from exc
    report([f"wrote {args.output} ({panel.shape[1]}x{panel.shape[0]} pixels)"])
    return 0
