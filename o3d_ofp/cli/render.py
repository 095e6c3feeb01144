"""``o3d-ofp render``: meshes side by side in a PNG, headless."""

from __future__ import annotations

import argparse
import logging
import os

import numpy as np

from ..boundary.texture import corner_uvs, has_uvs, missing_texture_files
from ..render.panel import (
    MAX_SIDE,
    MIN_SIDE,
    View,
    colormap,
    geometry_items,
    read_png,
    render_panel,
)
from . import _common as common
from ._common import UsageError, report, stage

__all__ = ["add_parser", "run"]

logger = logging.getLogger(__name__)


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Register the command."""
    p = sub.add_parser("render", help="render meshes side by side into a PNG (headless)")
    a, side = p.add_argument, common.bounded_int(MIN_SIDE, MAX_SIDE)
    a("mesh", nargs="+", help=common.MESH_HELP)
    a("--titles", help="comma-separated titles (default: the file names)")
    a("--scalars", nargs="+", help="one .npy of per-vertex scalars per mesh ('-' for none)")
    a("--textures", nargs="+", metavar="IMAGE", help="one texture image per mesh, for meshes "
      "with UVs whose material does not name it ('-' for none; default: each mesh's own)")
    a("--colormap", default="viridis", help="matplotlib colormap (viridis)")
    a("--label", help="label of the color bar (with --scalars)")
    a("--width", type=side, help=f"tile width in pixels ({MIN_SIDE}-{MAX_SIDE}; default 600)")
    a("--height", type=side, help=f"tile height in pixels ({MIN_SIDE}-{MAX_SIDE}; default 600)")
    a("--columns", type=common.positive_int, help="tiles per row (default: all, up to 6 per row)")
    a("--front", type=common.vector3, default=(0.0, 0.0, 1.0),
      help="direction from the shape to the camera x,y,z (default 0,0,1)")
    a("--up", type=common.vector3, default=(0.0, 1.0, 0.0), help="up direction x,y,z "
      "(default 0,1,0)")
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
    images = args.textures or ["-"] * n
    common.refuse(
        (args.label and not args.scalars, "--label names the color bar of --scalars: give "
         "--scalars too"),
        (len(titles) != n, f"--titles has {len(titles)} entries for {n} meshes"),
        (len(scalars) != n, f"--scalars has {len(scalars)} entries for {n} meshes ('-' for none)"),
        (len(images) != n, f"--textures has {len(images)} entries for {n} meshes ('-' for none)"),
        *((im != "-" and not os.path.isfile(im), f"--textures {im}: no such image file")
          for im in images),
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
    # each mesh's colors, or its own texture (or the one given), or its scalars
    geometries = [common.read_shape(path)[0] for path in args.mesh]
    items, textures = geometry_items(geometries)
    for i, (path, npy, (V, F, _)) in enumerate(zip(args.mesh, scalars, items, strict=True)):
        if npy != "-":
            values = common.load_npy(npy, "per-vertex scalars", flag="--scalars")
            values = values[:, 0] if values.ndim == 2 and values.shape[1] == 1 else values
            common.refuse((values.shape != (V.shape[0],), f"--scalars {npy}: shape "
                           f"{values.shape}, expected ({V.shape[0]},) for {path}"),
                          (not np.isfinite(values).all(), f"--scalars {npy}: holds NaN or inf "
                           f"(for {path})"))  # fmt: skip
            items[i], textures[i] = (V, F, values.astype(np.float64)), None
        elif images[i] != "-":
            textures[i] = _given_texture(geometries[i], path, images[i])
        elif textures[i] is None and F is not None:
            _say_missing_texture(geometries[i], path)
    options = {k: v for k, v in (("width", args.width), ("height", args.height),
                                 ("colorbar_label", args.label)) if v}  # fmt: skip
    with stage(f"rendering {len(items)} view{'s' if len(items) > 1 else ''}"):
        panel = render_panel(items, args.output, titles=titles, textures=textures,
                             columns=args.columns, view=view, cmap=args.colormap, **options)
    report([f"wrote {args.output} ({panel.shape[1]}x{panel.shape[0]} pixels)"])
    return 0


def _given_texture(geometry: object, path: str, image: str) -> tuple[np.ndarray, np.ndarray]:
    """Return the (corner UVs, pixels) of ``--textures IMAGE`` for the mesh read from ``path``."""
    common.refuse((not has_uvs(geometry), f"--textures {image}: {path} has no texture "
                   "coordinates (UVs) to put it on"))  # fmt: skip
    try:
        pixels = read_png(image)
    except (OSError, ValueError) as exc:
        raise UsageError(f"--textures {image}: cannot read the image ({exc})") from exc
    return corner_uvs(geometry).reshape(-1, 2), pixels


def _say_missing_texture(geometry: object, path: str) -> None:
    """Warn when a mesh with UVs is drawn without a texture: what is missing, and the fix."""
    if not has_uvs(geometry):
        return
    missing = missing_texture_files(path)
    why = (f"the files its material names are not there ({', '.join(missing)})" if missing
           else "no texture image came with it")  # fmt: skip
    logger.warning("%s has texture coordinates but %s: drawn without a texture; give the image "
                   "with --textures", path, why)  # fmt: skip
