"""Command line: ``o3d-ofp`` / ``python -m o3d_ofp``.

A thin shell over the library: argparse subcommands, ``main(argv) -> int``, heavy imports
deferred to the command that needs them. Exit codes: 0 success, 2 bad usage or bad input
(one line on stderr naming the problem), 1 internal error.
"""

from __future__ import annotations

import argparse
import logging
import os
import sys
import time
from collections.abc import Sequence

__all__ = ["main"]

logger = logging.getLogger(__name__)


class _UsageError(Exception):
    """Bad input or arguments: reported in one line, exit code 2."""


def _demo_signal(vertices):
    """RGB pattern on a shape: smooth bands, a sharp-edged region and fine stripes."""
    import numpy as np

    x, y, z = (vertices - vertices.mean(0)).T / np.ptp(vertices, axis=0).max()
    red = 0.5 + 0.5 * np.sin(6 * np.pi * x)
    green = 0.5 + 0.5 * np.cos(4 * np.pi * (y + z))
    blue = (np.sin(12 * np.pi * z) > 0).astype(float)  # sharp stripes: beyond any low band
    return np.column_stack([red, green, blue])


def _cmd_demo(args: argparse.Namespace) -> int:
    import numpy as np

    from . import adapters
    from .basis import approximation_error, ofp_basis
    from .shapes import blob
    from .spectrum import eigenbasis

    adapters.require_open3d()
    out = os.path.abspath(args.output)
    os.makedirs(out, exist_ok=True)
    vertices, faces = blob(args.subdivisions, seed=args.seed)
    colors = _demo_signal(vertices)
    stream = sys.stdout
    stream.write(
        f"demo: procedural blob with {len(vertices)} vertices, k={args.k} eigenfunctions, "
        f"order {args.order}\n"
    )
    t0 = time.perf_counter()
    eig = eigenbasis(vertices, faces, k=args.k)
    t_eig = time.perf_counter() - t0
    xyz = vertices - (eig.mass @ vertices) / eig.area
    rows = [
        (
            "K eigs",
            eig.evecs.shape[1],
            eig.reconstruct(eig.project(colors)),
            eig.reconstruct(eig.project(xyz)),
            t_eig,
        )
    ]
    for preset in ("ours", "ours*"):
        t0 = time.perf_counter()
        B = ofp_basis(eig, order=args.order, preset=preset)
        rows.append(
            (preset, B.size, B.approximate(colors), B.approximate(xyz), time.perf_counter() - t0)
        )

    written = [os.path.join(out, "blob_original.ply")]
    adapters.write_geometry(
        written[0], adapters.triangle_mesh_from_arrays(vertices, faces, colors=colors)
    )
    stream.write(
        f"{'basis':<8} {'functions':>9} {'RGB error':>10} {'XYZ error':>10} {'seconds':>8}\n"
    )
    for name, size, rgb, pos, seconds in rows:
        e_rgb = approximation_error(colors, rgb, eig.mass)
        e_xyz = approximation_error(xyz, pos, eig.mass)
        stream.write(
            f"{name:<8} {size:>9d} {100 * e_rgb:>9.2f}% {100 * e_xyz:>9.2f}% {seconds:>8.2f}\n"
        )
        tag = {"K eigs": "eigs", "ours": "ours", "ours*": "ours_star"}[name]
        path = os.path.join(out, f"blob_{tag}.ply")
        adapters.write_geometry(
            path, adapters.triangle_mesh_from_arrays(vertices, faces, colors=np.clip(rgb, 0, 1))
        )
        written.append(path)
    stream.write("wrote " + ", ".join(os.path.relpath(p) for p in written) + "\n")
    stream.write("errors are ‖f − f̃‖_M / ‖f‖_M (XYZ centred on the area-weighted mean)\n")
    return 0


def _build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="o3d-ofp",
        description="Orthogonalized Fourier Polynomials (Maggioli et al., EG 2021) for Open3D.",
    )
    parser.add_argument(
        "-v", "--verbose", action="count", default=0, help="more log output (repeatable)"
    )
    parser.add_argument("-q", "--quiet", action="store_true", help="only errors")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    demo = sub.add_parser(
        "demo",
        help="approximate a colored procedural shape; write meshes and print the errors",
        description="Build the eigenbasis and both OFP bases of a procedural shape, approximate "
        "its RGB colors and coordinates, write the original and approximated colored meshes "
        "as PLY and print the relative errors.",
    )
    demo.add_argument(
        "-o", "--output", default="demo_out", help="output folder (default: demo_out)"
    )
    demo.add_argument(
        "-k", "--k", type=int, default=29, help="non-constant eigenfunctions (default 29)"
    )
    demo.add_argument("--order", type=int, default=2, help="product order N (default 2)")
    demo.add_argument(
        "--subdivisions",
        type=int,
        default=5,
        help="icosphere subdivisions of the shape (5: 10242 vertices)",
    )
    demo.add_argument("--seed", type=int, default=0, help="shape seed")
    demo.set_defaults(func=_cmd_demo)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line.

    Parameters
    ----------
    argv : sequence of str, optional
        Arguments without the program name (default: ``sys.argv[1:]``).

    Returns
    -------
    int
        Exit code: 0 success, 2 bad usage or input, 1 internal error.
    """
    parser = _build_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:  # argparse exits 2 on bad usage, 0 on --help
        return int(exc.code or 0)
    level = (
        logging.ERROR
        if args.quiet
        else (
            logging.INFO
            if args.verbose == 1
            else logging.DEBUG
            if args.verbose > 1
            else logging.WARNING
        )
    )
    logging.basicConfig(level=level, format="%(levelname)s %(name)s: %(message)s")
    try:
        return args.func(args)
    except (ValueError, TypeError, FileNotFoundError, _UsageError) as exc:
        sys.stderr.write(f"o3d-ofp {args.command}: error: {exc}\n")
        return 2
    except ImportError as exc:
        sys.stderr.write(f"o3d-ofp {args.command}: error: {exc}\n")
        return 1
    except Exception as exc:
        logger.debug("internal error", exc_info=True)
        sys.stderr.write(f"o3d-ofp {args.command}: internal error: {type(exc).__name__}: {exc}\n")
        return 1
