"""Command line: ``o3d-ofp`` / ``python -m o3d_ofp``.

A thin shell over the library: argparse subcommands whose flags map 1:1 to the library's
keyword options, ``main(argv) -> int``, heavy imports deferred to the command that needs them.

Exit codes: 0 success; 2 bad usage or bad input (one line on stderr naming the file and the
problem, no traceback); 1 internal error (``-v`` adds the traceback). Progress of the long
stages goes to stderr when it is a terminal (or with ``-v``); ``-q`` leaves only errors.
Every output file is written atomically: a failure never leaves a half-written file.
"""

from __future__ import annotations

import argparse
import contextlib
import logging
import os
import sys
import time
from collections.abc import Iterator, Sequence
from typing import Any

__all__ = ["main"]

logger = logging.getLogger(__name__)

_MESH_HELP = "mesh or point cloud (any format Open3D reads: PLY, OBJ, OFF, STL, GLB, ...)"


class UsageError(Exception):
    """Bad input or arguments: reported in one line, exit code 2."""


@contextlib.contextmanager
def _stage(what: str) -> Iterator[None]:
    logger.info("%s ...", what)
    t0 = time.perf_counter()
    yield
    logger.info("%s: done in %.2f s", what, time.perf_counter() - t0)


# --------------------------------------------------------------------------- inputs


def _read(path: str) -> Any:
    from . import adapters

    adapters.require_open3d()
    if not os.path.exists(path):
        raise UsageError(f"{path}: no such file")
    if os.path.isdir(path):
        raise UsageError(f"{path}: is a directory, not a mesh file")
    try:
        return adapters.read_geometry(path)
    except ValueError as exc:
        raise UsageError(f"{path}: cannot read a mesh or point cloud ({exc})") from exc


def _arrays(geometry: Any, path: str) -> tuple[Any, Any]:
    from .adapters import geometry_to_arrays

    try:
        return geometry_to_arrays(geometry)
    except ValueError as exc:
        raise UsageError(f"{path}: {exc}") from exc


def _load_npy(path: str, what: str) -> Any:
    import numpy as np

    if not os.path.isfile(path):
        raise UsageError(f"{path}: no such file")
    try:
        return np.load(path, allow_pickle=False)
    except (OSError, ValueError) as exc:
        raise UsageError(f"{path}: not a NumPy .npy file ({what}): {exc}") from exc


def _signal(geometry: Any, V: Any, path: str, spec: str, texture: str | None) -> tuple[Any, str]:
    """Per-vertex values named by ``--signal`` on ``geometry`` (vertices ``V``), and their kind."""
    import numpy as np

    from . import adapters

    if spec == "colors":
        colors = adapters.vertex_colors(geometry)
        if colors is None:
            hint = ""
            if getattr(geometry, "has_triangle_uvs", lambda: False)():
                hint = " (it has texture coordinates: use --signal texture)"
            raise UsageError(f"{path}: has no vertex colors{hint}")
        return colors, "colors"
    if spec == "texture":
        try:
            return adapters.texture_colors(geometry, texture), "colors"
        except (ValueError, TypeError, FileNotFoundError) as exc:
            raise UsageError(f"{path}: {exc}") from exc
    if spec == "xyz":
        return V, "xyz"
    if spec.endswith(".npy"):
        f = _load_npy(spec, "per-vertex signal")
        if f.ndim not in (1, 2) or f.shape[0] != V.shape[0]:
            raise UsageError(
                f"{spec}: has shape {f.shape} but {path} has {V.shape[0]} vertices "
                "(expected (n,) or (n, d))"
            )
        if not np.issubdtype(f.dtype, np.number) or not np.all(np.isfinite(f)):
            raise UsageError(f"{spec}: must hold finite numbers")
        return f.astype(np.float64), "array"
    raise UsageError(f"--signal must be colors, texture, xyz or a FILE.npy; got {spec!r}")


def _tol_options(args: argparse.Namespace) -> dict[str, Any]:
    if args.tol is not None:
        return {"tol": args.tol, "preset": None}
    return {"tol": None, "preset": args.preset}


def _eig_options(args: argparse.Namespace) -> dict[str, Any]:
    return {"components": args.components}


def _load_basis(path: str, V: Any, F: Any, mesh_path: str, args: argparse.Namespace) -> Any:
    """Read a cached basis and check that it was computed for this mesh and these options."""
    from .basis import OFPBasis
    from .spectrum import shape_digest

    if not os.path.isfile(path):
        raise UsageError(f"{path}: no such basis file")
    try:
        B = OFPBasis.load(path)
    except ValueError as exc:
        raise UsageError(f"{path}: {exc}") from exc
    expected = shape_digest(V, F, **_eig_options(args))
    if B.eig.digest != expected:
        raise UsageError(
            f"{path}: this basis was computed for another mesh than {mesh_path} (or with other "
            "cleaning options); recompute it with: o3d-ofp basis " + mesh_path
        )
    return B


def _compute_basis(
    V: Any, F: Any, path: str, args: argparse.Namespace, k: int, eig_k: int | None = None
) -> tuple[Any, Any]:
    """(OFP basis on ``k`` eigenfunctions, the eigenbasis it came from with ``eig_k`` ≥ k)."""
    from .basis import ofp_basis
    from .cache import cached_basis
    from .spectrum import eigenbasis

    tol = _tol_options(args)
    if args.cache:
        with _stage(f"basis of {path} (cache {args.cache})"):
            B = cached_basis(
                V, F, k=k, order=args.order, cache_dir=args.cache, **tol, **_eig_options(args)
            )
        return B, B.eig
    eig_k = max(k, eig_k or 0)
    with _stage(f"eigenbasis of {path} ({V.shape[0]} vertices, k={eig_k})"):
        eig = eigenbasis(V, F, k=eig_k, clamp_k=eig_k > k, **_eig_options(args))
    with _stage(f"orthogonalized products of {path} (order {args.order})"):
        return ofp_basis(eig, order=args.order, k=min(k, eig.k), **tol), eig


def _basis(
    V: Any,
    F: Any,
    path: str,
    args: argparse.Namespace,
    file: str | None,
    k: int,
    eig_k: int | None = None,
) -> tuple[Any, Any]:
    """(OFP basis, its eigenbasis): from ``file`` (checked against the mesh) or computed."""
    if file:
        B = _load_basis(file, V, F, path, args)
        return B, B.eig
    return _compute_basis(V, F, path, args, k, eig_k)


def _landmarks(spec: str | None) -> Any:
    import numpy as np

    if not spec:
        return None
    if os.path.isfile(spec):
        try:
            pairs = np.loadtxt(spec, dtype=np.float64, ndmin=2)
        except ValueError as exc:
            raise UsageError(f"{spec}: not a landmark file (two integer columns): {exc}") from exc
    else:
        try:
            pairs = np.array(
                [[float(x) for x in item.split(":")] for item in spec.split(",")], dtype=float
            )
        except ValueError as exc:
            raise UsageError(
                f"--landmarks must be a file or pairs like 12:40,500:611; got {spec!r}"
            ) from exc
    if pairs.ndim != 2 or pairs.shape[1] != 2 or np.any(pairs != np.round(pairs)):
        raise UsageError(f"--landmarks must be integer (source, target) pairs; got {spec!r}")
    return pairs.astype(np.int64)


def _p2p_map(spec: str, V1: Any, V2: Any) -> Any:
    """Return the target→source map of ``--map`` (None for "estimate")."""
    import numpy as np

    from .correspondence import p2p_from_template
    from .io import read_vts

    n1, n2 = V1.shape[0], V2.shape[0]
    if spec == "estimate":
        return None
    if spec == "identity":
        if n1 != n2:
            raise UsageError(
                f"--map identity needs shapes with the same vertices; got {n1} and {n2}"
            )
        return np.arange(n2)
    files = spec.split(",")
    for f in files:
        if not os.path.isfile(f):
            raise UsageError(f"{f}: no such map file (--map estimate|identity|FILE[,FILE])")
    if len(files) == 2:  # correspondences of both shapes to a common template
        try:
            return p2p_from_template(read_vts(files[0]), read_vts(files[1]), V2)
        except ValueError as exc:
            raise UsageError(f"--map {spec}: {exc}") from exc
    if len(files) != 1:
        raise UsageError(f"--map takes one file or two comma-separated .vts files; got {spec!r}")
    if files[0].endswith(".npy"):
        p2p = _load_npy(files[0], "0-based target->source map")
    else:
        try:
            p2p = read_vts(files[0])
        except ValueError as exc:
            raise UsageError(str(exc)) from exc
    p2p = np.asarray(p2p)
    if p2p.shape != (n2,) or not np.issubdtype(p2p.dtype, np.integer):
        raise UsageError(
            f"{files[0]}: a map file lists one source vertex per target vertex ({n2} integers); "
            f"got shape {p2p.shape}"
        )
    if p2p.min() < 0 or p2p.max() >= n1:
        raise UsageError(f"{files[0]}: source indices must lie in [0, {n1}) (1-based in .vts)")
    return p2p


# --------------------------------------------------------------------------- outputs


def _check_output(path: str, allowed: Sequence[str]) -> None:
    ext = os.path.splitext(path)[1].lower()
    if ext not in allowed:
        raise UsageError(f"{path}: the output must end with one of {', '.join(allowed)}")
    folder = os.path.dirname(os.path.abspath(path))
    if not os.path.isdir(folder):
        raise UsageError(f"{path}: the folder {folder} does not exist")


_MESH_OUT = (".ply", ".obj", ".off", ".stl", ".glb", ".gltf")
_CLOUD_OUT = (".ply", ".pcd", ".xyz", ".xyzn", ".xyzrgb", ".pts")


def _save_npy(path: str, values: Any) -> None:
    import numpy as np

    from ._atomic import atomic_path

    with atomic_path(path, suffix=".npy") as tmp:
        np.save(tmp, values)


def _write_result(path: str, like: Any, V: Any, values: Any, kind: str) -> list[str]:
    """Write ``values`` on the geometry ``like`` (vertices ``V``): colored, moved, or .npy."""
    import numpy as np

    from . import adapters
    from .render import colormap

    written = []
    if path.lower().endswith(".npy"):
        _save_npy(path, values)
        return [path]
    colors = adapters.vertex_colors(like)
    if kind == "colors" or (kind == "array" and values.ndim == 2 and values.shape[1] == 3):
        colors = np.clip(values, 0.0, 1.0)
    elif kind == "xyz":
        V = values
    else:  # a scalar (or first channel) shown with a colormap; the values go to a .npy too
        colors = colormap(values if values.ndim == 1 else values[:, 0])
    if kind == "array":
        npy = os.path.splitext(path)[0] + ".npy"
        _save_npy(npy, values)
        written.append(npy)
    _, F = adapters.geometry_to_arrays(like)
    geometry = (
        adapters.point_cloud_from_arrays(V, colors=colors)
        if F is None
        else adapters.triangle_mesh_from_arrays(V, F, colors=colors)
    )
    adapters.write_geometry(path, geometry)
    return [path, *written]


class _Output:
    """The command's result lines on stdout; nothing with ``-q``."""

    quiet = False

    def write(self, text: str) -> None:
        if not self.quiet:
            sys.stdout.write(text)


_OUT = _Output()


def _report(lines: Sequence[str]) -> None:
    for line in lines:
        _OUT.write(line + "\n")


# --------------------------------------------------------------------------- commands


def _cmd_basis(args: argparse.Namespace) -> int:
    from .products import n_eigenproducts

    _check_output(args.output, (".npz",))
    geometry = _read(args.mesh)
    V, F = _arrays(geometry, args.mesh)
    B, _ = _compute_basis(V, F, args.mesh, args, args.k)
    B.save(args.output)
    report = B.eig.cleaning.report if B.eig.cleaning is not None else None
    _report(
        [
            f"{args.mesh}: {V.shape[0]} vertices, k={B.k}, order {B.order}, tol {B.tol:g}: "
            f"kept {B.size} of {n_eigenproducts(B.k, B.order)} products",
            *([f"cleaning: {report}"] if report is not None else []),
            f"wrote {args.output}",
        ]
    )
    return 0


def _cmd_approximate(args: argparse.Namespace) -> int:
    _check_output(args.output, (*_MESH_OUT, *_CLOUD_OUT, ".npy"))
    geometry = _read(args.mesh)
    V, F = _arrays(geometry, args.mesh)
    f, kind = _signal(geometry, V, args.mesh, args.signal, args.texture)
    B, _ = _basis(V, F, args.mesh, args, args.basis, args.k)
    approx = B.approximate(f)
    err = B.approximation_error(f)
    written = _write_result(args.output, geometry, V, approx, kind)
    _report(
        [
            f"{args.mesh}: {B.size} basis functions (k={B.k}, order {B.order}, tol {B.tol:g}); "
            f"relative error ‖f − f̃‖_M / ‖f‖_M = {err:.4%}",
            "wrote " + ", ".join(written),
        ]
    )
    return 0


def _read_pair(args: argparse.Namespace) -> dict[str, Any]:
    """Read both shapes, the map and the landmarks (everything that can fail fast)."""
    source, target = _read(args.source), _read(args.target)
    V1, F1 = _arrays(source, args.source)
    V2, F2 = _arrays(target, args.target)
    p2p = _p2p_map(args.map, V1, V2)
    landmarks = _landmarks(args.landmarks)
    if landmarks is not None:
        if p2p is not None:
            raise UsageError("--landmarks only apply with --map estimate")
        for col, n, name in ((0, V1.shape[0], "source"), (1, V2.shape[0], "target")):
            if landmarks[:, col].min() < 0 or landmarks[:, col].max() >= n:
                raise UsageError(f"--landmarks: {name} indices must lie in [0, {n})")
    return {
        "source": source,
        "target": target,
        "V1": V1,
        "F1": F1,
        "V2": V2,
        "F2": F2,
        "p2p": p2p,
        "landmarks": landmarks,
    }


#: Eigenfunctions the estimated map is refined to by ZoomOut (as pyFM's standard pipeline).
_ZOOMOUT_K = 99


def _add_bases(args: argparse.Namespace, pair: dict[str, Any]) -> None:
    """Add the (cached or new) OFP bases and the eigenbases the map estimation needs."""
    from .spectrum import eigenbasis

    estimate = pair["p2p"] is None
    bases, eigs = [], []
    for side, k, file in ((1, args.k1, args.basis_1), (2, args.k2, args.basis_2)):
        V, F, path = (
            pair[f"V{side}"],
            pair[f"F{side}"],
            getattr(args, ("source", "target")[side - 1]),
        )
        B, eig = _basis(V, F, path, args, file, k, _ZOOMOUT_K if estimate else None)
        want = min(_ZOOMOUT_K, V.shape[0] - 1)
        if estimate and eig.k < want:  # a cached basis with fewer eigenfunctions
            with _stage(f"eigenbasis of {path} for map estimation (k={want})"):
                eig = eigenbasis(V, F, k=want, clamp_k=True, **_eig_options(args))
        bases.append(B)
        eigs.append(eig)
    pair["bases"] = (bases[0], bases[1])
    pair["eigenbases"] = (eigs[0], eigs[1])


def _cmd_transfer(args: argparse.Namespace) -> int:
    from .pipeline import match, transfer_function

    out_ext = (*_MESH_OUT, *_CLOUD_OUT, ".npy")
    _check_output(args.output, out_ext)
    pair = _read_pair(args)
    f, kind = _signal(pair["source"], pair["V1"], args.source, args.signal, args.texture)
    _add_bases(args, pair)
    p2p = pair["p2p"]
    eig_1, eig_2 = pair["eigenbases"]
    if p2p is None:
        with _stage("map estimation (fit + ZoomOut)"):
            _, p2p = match(eig_1, eig_2, landmarks=pair["landmarks"])
    with _stage("transfer"):
        g = transfer_function(f, eig_1, eig_2, p2p_21=p2p, bases=pair["bases"])
    written = _write_result(args.output, pair["target"], pair["V2"], g, kind)
    B1, B2 = pair["bases"]
    _report(
        [
            f"{args.source} -> {args.target}: {B1.size} -> {B2.size} basis functions, map "
            f"{args.map}",
            "wrote " + ", ".join(written),
        ]
    )
    return 0


def _cmd_detail(args: argparse.Namespace) -> int:
    from . import adapters
    from .pipeline import match

    _check_output(args.output, (*_MESH_OUT, *_CLOUD_OUT))
    pair = _read_pair(args)
    if pair["F1"] is None:
        raise UsageError(f"{args.source}: the detail source must be a triangle mesh")
    _add_bases(args, pair)
    p2p = pair["p2p"]
    if p2p is None:
        with _stage("map estimation (fit + ZoomOut)"):
            _, p2p = match(*pair["eigenbases"], landmarks=pair["landmarks"])
    with _stage(f"detail transfer ({args.mode})"):
        moved = adapters.transfer_detail(
            pair["source"],
            pair["target"],
            mode=args.mode,
            k1=args.k1,
            k2=args.k2,
            order=args.order,
            **_tol_options(args),
            p2p_21=p2p,
            bases=pair["bases"],
            eigenbases=pair["eigenbases"],
            k_low=args.k_low,
        )
    adapters.write_geometry(args.output, moved)
    _report([f"{args.source} -> {args.target}: detail ({args.mode})", f"wrote {args.output}"])
    return 0


def _cmd_filter(args: argparse.Namespace) -> int:
    from . import adapters
    from .filtering import sharpen_gains, smooth_gains

    _check_output(args.output, (*_MESH_OUT, *_CLOUD_OUT))
    if (args.smooth is None) == (args.sharpen is None):
        raise UsageError("give exactly one of --smooth STRENGTH or --sharpen AMOUNT")
    gains = smooth_gains(args.smooth) if args.smooth is not None else sharpen_gains(args.sharpen)
    geometry = _read(args.mesh)
    V, F = _arrays(geometry, args.mesh)
    B, _ = _basis(V, F, args.mesh, args, args.basis, args.k)
    with _stage("spectral filter"):
        out = adapters.filter_geometry(geometry, gains=gains, basis=B)
    adapters.write_geometry(args.output, out)
    what = f"smooth {args.smooth}" if args.smooth is not None else f"sharpen {args.sharpen}"
    _report([f"{args.mesh}: {what} with {B.size} basis functions", f"wrote {args.output}"])
    return 0


def _parse_vector(text: str, name: str) -> tuple[float, float, float]:
    try:
        values = tuple(float(x) for x in text.split(","))
    except ValueError:
        values = ()
    if len(values) != 3 or not any(values):
        raise UsageError(f"{name} must be three comma-separated numbers, not all 0; got {text!r}")
    return values  # type: ignore[return-value]


def _cmd_render(args: argparse.Namespace) -> int:
    import numpy as np

    from . import adapters
    from .render import View, render_panel

    _check_output(args.output, (".png",))
    titles = args.titles.split(",") if args.titles else [os.path.basename(p) for p in args.mesh]
    if len(titles) != len(args.mesh):
        raise UsageError(f"--titles has {len(titles)} entries for {len(args.mesh)} meshes")
    scalars = args.scalars or []
    if scalars and len(scalars) != len(args.mesh):
        raise UsageError(
            f"--scalars has {len(scalars)} entries for {len(args.mesh)} meshes ('-' for none)"
        )
    items = []
    for i, path in enumerate(args.mesh):
        geometry = _read(path)
        V, F = _arrays(geometry, path)
        colors = adapters.vertex_colors(geometry)
        if scalars and scalars[i] != "-":
            values = _load_npy(scalars[i], "per-vertex scalars")
            if values.ndim == 2 and values.shape[1] == 1:
                values = values[:, 0]
            if values.shape != (V.shape[0],):
                raise UsageError(
                    f"{scalars[i]}: shape {values.shape}, expected ({V.shape[0]},) for {path}"
                )
            colors = values.astype(np.float64)
        items.append((V, F, colors))
    view = View(
        front=_parse_vector(args.front, "--front"),
        up=_parse_vector(args.up, "--up"),
        zoom=args.zoom,
    )
    with _stage(f"rendering {len(items)} views"):
        panel = render_panel(
            items,
            args.output,
            titles=titles,
            width=args.width,
            height=args.height,
            columns=args.columns,
            view=view,
            cmap=args.colormap,
        )
    _report([f"wrote {args.output} ({panel.shape[1]}x{panel.shape[0]} pixels)"])
    return 0


def _demo_signal(vertices: Any) -> Any:
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
    from .pipeline import match, transfer_function
    from .render import RenderError, render_panel
    from .shapes import blob
    from .spectrum import eigenbasis

    adapters.require_open3d()
    out = os.path.abspath(args.output)
    os.makedirs(out, exist_ok=True)
    vertices, faces = blob(args.subdivisions, seed=args.seed)
    colors = _demo_signal(vertices)
    stream = _OUT
    stream.write(
        f"demo: procedural blob with {len(vertices)} vertices, k={args.k} eigenfunctions, "
        f"order {args.order}\n"
    )
    t0 = time.perf_counter()
    with _stage("eigenbasis"):
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
    bases = {}
    for preset in ("ours", "ours*"):
        t0 = time.perf_counter()
        with _stage(f"ofp basis ({preset})"):
            B = ofp_basis(eig, order=args.order, preset=preset)
        bases[preset] = B
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
    panel_items = [(vertices, faces, colors)]
    titles = ["original"]
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
        panel_items.append((vertices, faces, np.clip(rgb, 0, 1)))
        titles.append(f"{name} ({size})")

    # Transfer to a bent, turned copy, with an estimated map (no correspondence is given).
    target = vertices.copy()
    target[:, 1] += 0.15 * target[:, 0] ** 2
    c, s = np.cos(0.7), np.sin(0.7)
    target = target @ np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]).T
    t0 = time.perf_counter()
    with _stage("transfer to a bent copy (estimated map)"):
        eig_1 = eigenbasis(vertices, faces, k=max(args.k, 60))
        eig_2 = eigenbasis(target, faces, k=max(args.k, 60))
        _, p2p = match(eig_1, eig_2)
        g = transfer_function(
            colors, eig_1, eig_2, k1=args.k, k2=args.k, order=args.order, p2p_21=p2p
        )
    p2p_err = float(np.linalg.norm(vertices[p2p] - vertices, axis=1).mean() / np.sqrt(eig.area))
    t_transfer = time.perf_counter() - t0
    path = os.path.join(out, "blob_transfer_target.ply")
    adapters.write_geometry(
        path, adapters.triangle_mesh_from_arrays(target, faces, colors=np.clip(g, 0, 1))
    )
    written.append(path)
    stream.write(
        f"transfer to a bent copy: map error {p2p_err:.4f} (mean distance / sqrt(area)), "
        f"RGB error {100 * approximation_error(colors, g, eig_2.mass):.2f}%, "
        f"{t_transfer:.2f} s\n"
    )
    panel_items.append((target, faces, np.clip(g, 0, 1)))
    titles.append("transferred")
    png = os.path.join(out, "demo.png")
    try:
        with _stage("rendering demo.png"):
            render_panel(panel_items, png, titles=titles, width=320, height=320)
        written.append(png)
    except RenderError as exc:
        stream.write(f"no picture: {exc}\n")
    stream.write("wrote " + ", ".join(os.path.relpath(p) for p in written) + "\n")
    stream.write("errors are ‖f − f̃‖_M / ‖f‖_M (XYZ centred on the area-weighted mean)\n")
    return 0


# --------------------------------------------------------------------------- parser


def _number(cast: type, ok: Any, expected: str) -> Any:
    """Make an argparse ``type``: ``cast(text)``, which must satisfy ``ok`` ("expected ...")."""

    def parse(text: str) -> Any:
        try:
            value = cast(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {expected}, got {text!r}") from None
        if not ok(value):
            raise argparse.ArgumentTypeError(f"expected {expected}, got {value}")
        return value

    return parse


_positive_int = _number(int, lambda v: v >= 1, "a positive integer")
_unit_float = _number(float, lambda v: 0.0 < v < 1.0, "a number in (0, 1)")
_nonnegative_float = _number(float, lambda v: v >= 0.0, "a number >= 0")


def _add_basis_options(
    p: argparse.ArgumentParser, *, k: bool = True, preset: str = "ours", order: int = 2
) -> None:
    if k:
        p.add_argument(
            "-k", "--k", type=_positive_int, default=29, help="non-constant eigenfunctions (29)"
        )
    p.add_argument("--order", type=_positive_int, default=order, help=f"product order N ({order})")
    p.add_argument(
        "--preset",
        choices=("ours", "ours*"),
        default=preset,
        help=f"orthogonalization threshold: ours = 1e-2, ours* = 1e-9 ({preset})",
    )
    p.add_argument("--tol", type=_unit_float, help="explicit threshold in (0, 1) (over --preset)")
    p.add_argument(
        "--components",
        choices=("auto", "largest", "error"),
        default="auto",
        help="several connected components: keep the largest if it holds >= 90%% of the area "
        "(auto), always keep the largest, or refuse (auto)",
    )
    p.add_argument(
        "--cache",
        metavar="DIR",
        help="reuse bases cached in DIR (computed and stored there the first time)",
    )


def _add_pair_options(p: argparse.ArgumentParser, preset: str) -> None:
    p.add_argument("source", help="source " + _MESH_HELP)
    p.add_argument("target", help="target " + _MESH_HELP)
    p.add_argument("--k1", type=_positive_int, default=29, help="source eigenfunctions (29)")
    p.add_argument("--k2", type=_positive_int, default=39, help="target eigenfunctions (39)")
    _add_basis_options(p, k=False, preset=preset)
    p.add_argument(
        "--map",
        default="estimate",
        help="estimate (default: WKS fit + ZoomOut), identity (same vertices), a file with one "
        "source vertex per target vertex (.vts 1-based / .npy 0-based), or two .vts files "
        "SRC.vts,TGT.vts matching both shapes to a template",
    )
    p.add_argument(
        "--landmarks", help="known pairs for the estimation: 12:40,500:611 or a 2-column file"
    )
    p.add_argument("--basis-1", help="cached source basis (.npz from 'o3d-ofp basis')")
    p.add_argument("--basis-2", help="cached target basis (.npz from 'o3d-ofp basis')")


class _Parser(argparse.ArgumentParser):
    """An ArgumentParser whose usage errors are one line (and a pointer to --help)."""

    def error(self, message: str) -> Any:  # type: ignore[override]
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def _build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="o3d-ofp",
        description="Orthogonalized Fourier Polynomials (Maggioli et al., EG 2021) for Open3D: "
        "bases, approximation, filtering and transfer of signals between shapes.",
    )
    parser.add_argument(
        "-v", "--verbose", action="count", default=0, help="progress and details (repeatable)"
    )
    parser.add_argument(
        "-q", "--quiet", action="store_true", help="print nothing but errors (files are written)"
    )
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    p = sub.add_parser("basis", help="compute a basis once and store it (.npz)")
    p.add_argument("mesh", help=_MESH_HELP)
    _add_basis_options(p)
    p.add_argument("-o", "--output", required=True, help="basis file (.npz)")
    p.set_defaults(func=_cmd_basis)

    p = sub.add_parser("approximate", help="approximate a signal in the basis; print the error")
    p.add_argument("mesh", help=_MESH_HELP)
    p.add_argument(
        "--signal",
        default="colors",
        help="colors (vertex colors), texture (UV texture), xyz (coordinates) or FILE.npy",
    )
    p.add_argument("--texture", help="texture image for --signal texture (default: the mesh's)")
    _add_basis_options(p)
    p.add_argument("--basis", help="cached basis of MESH (.npz)")
    p.add_argument("-o", "--output", required=True, help="output mesh, cloud or .npy")
    p.set_defaults(func=_cmd_approximate)

    p = sub.add_parser("transfer", help="transfer a signal from a source to a target shape")
    _add_pair_options(p, "ours")
    p.add_argument(
        "--signal",
        default="colors",
        help="colors, texture, xyz or FILE.npy of the source (default colors)",
    )
    p.add_argument("--texture", help="texture image for --signal texture (default: the mesh's)")
    p.add_argument(
        "-o", "--output", required=True, help="colored target (mesh/cloud), or .npy values"
    )
    p.set_defaults(func=_cmd_transfer)

    p = sub.add_parser("detail", help="give the target the source's geometric detail")
    _add_pair_options(p, "ours*")
    p.add_argument(
        "--mode",
        choices=("add", "replace"),
        default="add",
        help="add: source detail along the target's normals; replace: transferred coordinates "
        "(the paper's Fig. 13) (add)",
    )
    p.add_argument("--k-low", type=_positive_int, help="low-pass size for --mode add (k1)")
    p.add_argument("-o", "--output", required=True, help="displaced target")
    p.set_defaults(func=_cmd_detail)

    p = sub.add_parser("filter", help="smooth or sharpen a shape spectrally")
    p.add_argument("mesh", help=_MESH_HELP)
    p.add_argument("--smooth", type=_nonnegative_float, help="low-pass strength (e.g. 5)")
    p.add_argument("--sharpen", type=_nonnegative_float, help="enhancement amount (e.g. 2)")
    p.add_argument(
        "-k", "--k", type=_positive_int, default=14, help="eigenfunctions (14, as the paper)"
    )
    _add_basis_options(p, k=False, preset="ours*", order=3)
    p.add_argument("--basis", help="cached basis of MESH (.npz)")
    p.add_argument("-o", "--output", required=True, help="filtered mesh or cloud")
    p.set_defaults(func=_cmd_filter)

    p = sub.add_parser("render", help="render meshes side by side into a PNG (headless)")
    p.add_argument("mesh", nargs="+", help=_MESH_HELP)
    p.add_argument("--titles", help="comma-separated titles (default: the file names)")
    p.add_argument(
        "--scalars", nargs="+", help="one .npy of per-vertex scalars per mesh ('-' for none)"
    )
    p.add_argument("--colormap", choices=("viridis", "coolwarm"), default="viridis")
    p.add_argument("--width", type=_positive_int, default=400, help="tile width (400)")
    p.add_argument("--height", type=_positive_int, default=400, help="tile height (400)")
    p.add_argument("--columns", type=_positive_int, help="tiles per row (up to 6)")
    p.add_argument("--front", default="0,0,1", help="camera direction x,y,z (0,0,1)")
    p.add_argument("--up", default="0,1,0", help="up direction x,y,z (0,1,0)")
    p.add_argument("--zoom", type=_unit_float, default=0.6, help="zoom in (0, 1) (0.6)")
    p.add_argument("-o", "--output", required=True, help="PNG file")
    p.set_defaults(func=_cmd_render)

    p = sub.add_parser(
        "demo",
        help="approximate and transfer colors on procedural shapes; write meshes and a PNG",
        description="Build the eigenbasis and both OFP bases of a procedural shape, approximate "
        "its RGB colors and coordinates, transfer the colors to a deformed copy with an "
        "estimated map, write the meshes as PLY and a picture, and print the errors.",
    )
    p.add_argument("-o", "--output", default="demo_out", help="output folder (demo_out)")
    p.add_argument("-k", "--k", type=_positive_int, default=29, help="eigenfunctions (29)")
    p.add_argument("--order", type=_positive_int, default=2, help="product order N (2)")
    p.add_argument(
        "--subdivisions",
        type=_positive_int,
        default=5,
        help="icosphere subdivisions of the shape (5: 10242 vertices)",
    )
    p.add_argument("--seed", type=int, default=0, help="shape seed")
    p.set_defaults(func=_cmd_demo)
    return parser


@contextlib.contextmanager
def _logging_to_stderr(level: int) -> Iterator[None]:
    """Send the package's log records to the current stderr for the duration of a command."""
    root = logging.getLogger("o3d_ofp")
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(logging.Formatter("o3d-ofp: %(message)s"))
    saved = (root.level, root.propagate)
    root.addHandler(handler)
    root.setLevel(level)
    root.propagate = False
    try:
        yield
    finally:
        root.removeHandler(handler)
        root.setLevel(saved[0])
        root.propagate = saved[1]


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
    if args.quiet:
        level = logging.ERROR
    elif args.verbose > 1:
        level = logging.DEBUG
    elif args.verbose == 1 or sys.stderr.isatty():
        level = logging.INFO  # progress of the long stages
    else:
        level = logging.WARNING
    prog = f"o3d-ofp {args.command}"
    _OUT.quiet = bool(args.quiet)
    with _logging_to_stderr(level):
        try:
            return args.func(args)
        except (UsageError, ValueError, TypeError, FileNotFoundError, IsADirectoryError) as exc:
            sys.stderr.write(f"{prog}: error: {exc}\n")
            return 2
        except PermissionError as exc:
            sys.stderr.write(f"{prog}: error: {exc}\n")
            return 2
        except ImportError as exc:
            sys.stderr.write(f"{prog}: error: {exc}\n")
            return 1
        except KeyboardInterrupt:
            sys.stderr.write(f"{prog}: interrupted\n")
            return 130
        except Exception as exc:
            if args.verbose:
                logger.exception("internal error")
            sys.stderr.write(f"{prog}: internal error: {type(exc).__name__}: {exc}\n")
            return 1
