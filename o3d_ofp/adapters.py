"""Open3D adapters: the only module of the package that imports :mod:`open3d`.

Open3D geometries go in as copies (``np.asarray`` on an Open3D vector is a *live view*; we never
hand one out) and come back as new geometries built from validated arrays (Open3D does not
bounds-check triangle indices and crashes the interpreter on bad ones).

Both the legacy API (``open3d.geometry.TriangleMesh``/``PointCloud``) and the tensor API
(``open3d.t.geometry.TriangleMesh``/``PointCloud``) are accepted.
"""

from __future__ import annotations

import importlib
import logging
import os
from types import ModuleType
from typing import Any

import numpy as np

from ._atomic import atomic_path
from ._validation import as_faces, as_signal, as_vertices

__all__ = [
    "OPEN3D_INSTALL_HINT",
    "filter_geometry",
    "geometry_to_arrays",
    "is_open3d_geometry",
    "point_cloud_from_arrays",
    "read_geometry",
    "require_open3d",
    "texture_colors",
    "transfer_colors",
    "transfer_detail",
    "triangle_mesh_from_arrays",
    "vertex_colors",
    "write_geometry",
]

logger = logging.getLogger(__name__)

OPEN3D_INSTALL_HINT = (
    "pip install open3d-cpu   (CPU-only build, Linux x86_64; or: pip install open3d; from a "
    "clone of o3d_ofp: pip install '.[cpu]'). On a fresh Debian/Ubuntu also run: "
    "apt-get install -y --no-install-recommends libgl1 libegl1 libusb-1.0-0"
)


def require_open3d() -> ModuleType:
    """Import and return :mod:`open3d`, or raise an ``ImportError`` saying how to install it.

    Returns
    -------
    module
        The ``open3d`` module.

    Raises
    ------
    ImportError
        If Open3D (or one of the system libraries it loads) is missing.
    """
    try:
        return importlib.import_module("open3d")
    except ImportError as exc:
        raise ImportError(
            f"this function needs Open3D, which could not be imported ({exc}). Install it with: "
            f"{OPEN3D_INSTALL_HINT}"
        ) from exc


def is_open3d_geometry(obj: Any) -> bool:
    """Tell whether ``obj`` is an Open3D geometry, without importing Open3D.

    Parameters
    ----------
    obj : object
        Anything.

    Returns
    -------
    bool
        True for instances of classes defined in an ``open3d`` module.
    """
    return type(obj).__module__.split(".")[0] == "open3d"


def _kind(geometry: Any) -> str:
    """Return one of ``legacy_mesh``, ``legacy_cloud``, ``tensor_mesh``, ``tensor_cloud``."""
    o3d = require_open3d()
    if isinstance(geometry, o3d.geometry.TriangleMesh):
        return "legacy_mesh"
    if isinstance(geometry, o3d.geometry.PointCloud):
        return "legacy_cloud"
    if isinstance(geometry, o3d.t.geometry.TriangleMesh):
        return "tensor_mesh"
    if isinstance(geometry, o3d.t.geometry.PointCloud):
        return "tensor_cloud"
    raise TypeError(
        "geometry must be an Open3D TriangleMesh or PointCloud (legacy open3d.geometry or "
        f"tensor open3d.t.geometry); got {type(geometry).__module__}.{type(geometry).__name__}"
    )


def _tensor_attr(attrs: Any, key: str) -> np.ndarray | None:
    if key not in attrs:
        return None
    return np.array(attrs[key].cpu().numpy(), copy=True)


def geometry_to_arrays(geometry: Any) -> tuple[np.ndarray, np.ndarray | None]:
    """Copy an Open3D geometry into plain arrays.

    Parameters
    ----------
    geometry : open3d.geometry.TriangleMesh, PointCloud, or their ``open3d.t`` counterparts
        The input; it is not modified.

    Returns
    -------
    vertices : (n, 3) ndarray of float64
        A copy of the vertex positions (points of a cloud).
    faces : (m, 3) ndarray of int64 or None
        A copy of the triangles, or ``None`` for a point cloud.

    Raises
    ------
    TypeError
        If ``geometry`` is not one of the supported types.
    ValueError
        If it has no vertices, non-finite coordinates or out-of-range triangles.
    """
    kind = _kind(geometry)
    if kind == "legacy_mesh":
        raw_v = np.array(geometry.vertices, dtype=np.float64, copy=True)
        raw_f = np.array(geometry.triangles, dtype=np.int64, copy=True)
    elif kind == "legacy_cloud":
        raw_v, raw_f = np.array(geometry.points, dtype=np.float64, copy=True), None
    elif kind == "tensor_mesh":
        raw_v = _tensor_attr(geometry.vertex, "positions")
        raw_f = _tensor_attr(geometry.triangle, "indices")
        if raw_v is None:
            raw_v = np.zeros((0, 3))
        if raw_f is None:
            raw_f = np.zeros((0, 3), dtype=np.int64)
    else:
        raw_v, raw_f = _tensor_attr(geometry.point, "positions"), None
        if raw_v is None:
            raw_v = np.zeros((0, 3))
    vertices = as_vertices(raw_v.reshape(-1, 3), name="geometry vertices")
    if raw_f is None:
        return vertices, None
    faces = as_faces(raw_f.reshape(-1, 3), vertices.shape[0], name="geometry triangles")
    return vertices, faces


def vertex_colors(geometry: Any) -> np.ndarray | None:
    """Copy the per-vertex (per-point) RGB colors of an Open3D geometry.

    Parameters
    ----------
    geometry : Open3D TriangleMesh or PointCloud (legacy or tensor)
        The input; it is not modified.

    Returns
    -------
    (n, 3) ndarray of float64 or None
        Colors in [0, 1], or ``None`` when the geometry has none.
    """
    kind = _kind(geometry)
    if kind == "legacy_mesh":
        colors = (
            np.array(geometry.vertex_colors, dtype=np.float64)
            if geometry.has_vertex_colors()
            else None
        )
    elif kind == "legacy_cloud":
        colors = np.array(geometry.colors, dtype=np.float64) if geometry.has_colors() else None
    else:
        attrs = geometry.vertex if kind == "tensor_mesh" else geometry.point
        colors = _tensor_attr(attrs, "colors")
        if colors is not None:
            if np.issubdtype(colors.dtype, np.integer):  # uint8 colors in the tensor API
                colors = colors.astype(np.float64) / np.iinfo(colors.dtype).max
            colors = colors.astype(np.float64)
    if colors is None or colors.size == 0:
        return None
    return colors.reshape(-1, 3)


def _image_array(image: Any, o3d: ModuleType, name: str) -> np.ndarray:
    if isinstance(image, (str, os.PathLike)):
        path = os.fspath(image)
        if not os.path.isfile(path):
            raise FileNotFoundError(f"{path}: no such texture file")
        with o3d.utility.VerbosityContextManager(o3d.utility.VerbosityLevel.Error):
            image = o3d.io.read_image(path)
        if np.asarray(image).size == 0:
            raise ValueError(f"{path}: Open3D could not read this image (PNG and JPEG are read)")
    arr = np.array(np.asarray(image), copy=True)
    if arr.ndim not in (2, 3) or arr.size == 0:
        raise ValueError(f"{name} must be an (H, W[, C]) image; got shape {arr.shape}")
    return arr


def texture_colors(mesh: Any, texture: Any = None) -> np.ndarray:
    """Per-vertex RGB colors sampled from a mesh's UV texture (bilinear).

    Parameters
    ----------
    mesh : open3d.geometry.TriangleMesh (or ``open3d.t.geometry.TriangleMesh``)
        A mesh with per-triangle-corner UVs (``triangle_uvs``), e.g. read from an OBJ.
    texture : str, os.PathLike, ndarray or open3d.geometry.Image, optional
        The texture image; default the mesh's own textures (loaded by Open3D from the OBJ's
        material file), one per material id.

    Returns
    -------
    (n, 3) ndarray of float64
        Colors in [0, 1]: at each vertex, the mean of its triangle corners' samples. Open3D
        splits OBJ vertices along UV seams; the two copies of a seam vertex are welded again
        when a basis is built (see :mod:`o3d_ofp.cleaning`), so the shape stays one surface
        and the welded vertex gets the mean of both sides' colors.

    Raises
    ------
    ValueError
        If the mesh has no UVs, or no texture image is given or loaded.
    """
    from .texture import corner_colors_to_vertices, sample_texture

    o3d = require_open3d()
    if _kind(mesh) == "tensor_mesh":
        mesh = mesh.to_legacy()
    if _kind(mesh) != "legacy_mesh":
        raise TypeError("mesh must be an Open3D TriangleMesh with texture coordinates")
    V, F = geometry_to_arrays(mesh)
    uv = np.array(mesh.triangle_uvs, dtype=np.float64)
    if uv.shape[0] != 3 * F.shape[0]:
        raise ValueError(
            f"the mesh has no per-corner texture coordinates ({uv.shape[0]} UVs for "
            f"{F.shape[0]} triangles): there is no texture to sample"
        )
    if texture is not None:
        images = [_image_array(texture, o3d, "texture")]
        material = np.zeros(F.shape[0], dtype=np.int64)
    else:
        images = [np.array(np.asarray(t), copy=True) for t in mesh.textures]
        if not images or all(im.size == 0 for im in images):
            raise ValueError(
                "the mesh has UVs but no texture image was loaded (no material file next to "
                "it?): pass the image explicitly (texture=... / --texture FILE)"
            )
        material = np.array(mesh.triangle_material_ids, dtype=np.int64)
        if material.shape[0] != F.shape[0]:
            material = np.zeros(F.shape[0], dtype=np.int64)
    corners = np.zeros((3 * F.shape[0], 3))
    corner_material = np.repeat(material, 3)
    for mid, img in enumerate(images):
        sel = corner_material == mid
        if not np.any(sel) or img.size == 0:
            continue
        sampled = sample_texture(img, uv[sel])
        if sampled.shape[1] == 1:
            sampled = np.repeat(sampled, 3, axis=1)
        corners[sel] = sampled[:, :3]
    return np.clip(corner_colors_to_vertices(F, corners, V.shape[0]), 0.0, 1.0)


def _checked_colors(colors: Any, n: int, name: str) -> np.ndarray:
    arr = as_signal(colors, n, name=name)
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise ValueError(f"{name} must have shape (n, 3) with n = {n}; got {arr.shape}")
    return np.clip(arr, 0.0, 1.0)


def _checked_normals(normals: Any, n: int, name: str) -> np.ndarray:
    arr = as_signal(normals, n, name=name)
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise ValueError(f"{name} must have shape (n, 3) with n = {n}; got {arr.shape}")
    return arr


def triangle_mesh_from_arrays(
    vertices: Any,
    faces: Any,
    *,
    colors: Any = None,
    normals: Any = None,
) -> Any:
    """Build a new legacy ``open3d.geometry.TriangleMesh`` from validated arrays.

    Parameters
    ----------
    vertices : (n, 3) array_like of float
        Vertex positions.
    faces : (m, 3) array_like of int
        Triangles, 0-based indices into ``vertices``.
    colors : (n, 3) array_like of float, optional
        Per-vertex RGB; values are clipped to [0, 1].
    normals : (n, 3) array_like of float, optional
        Per-vertex normals. When omitted, normals are computed by Open3D so the mesh renders lit.

    Returns
    -------
    open3d.geometry.TriangleMesh
        A new mesh that shares no memory with the inputs.

    Raises
    ------
    ValueError
        If the shapes disagree or an index is out of range (checked here because Open3D does
        not check and crashes on bad indices).
    """
    o3d = require_open3d()
    v = as_vertices(vertices)
    f = as_faces(faces, v.shape[0])
    mesh = o3d.geometry.TriangleMesh(
        o3d.utility.Vector3dVector(v), o3d.utility.Vector3iVector(f.astype(np.int32))
    )
    if colors is not None:
        mesh.vertex_colors = o3d.utility.Vector3dVector(
            _checked_colors(colors, v.shape[0], "colors")
        )
    if normals is not None:
        mesh.vertex_normals = o3d.utility.Vector3dVector(
            _checked_normals(normals, v.shape[0], "normals")
        )
    else:
        mesh.compute_vertex_normals()
    return mesh


def point_cloud_from_arrays(points: Any, *, colors: Any = None, normals: Any = None) -> Any:
    """Build a new legacy ``open3d.geometry.PointCloud`` from validated arrays.

    Parameters
    ----------
    points : (n, 3) array_like of float
        Point positions.
    colors : (n, 3) array_like of float, optional
        Per-point RGB; values are clipped to [0, 1].
    normals : (n, 3) array_like of float, optional
        Per-point normals.

    Returns
    -------
    open3d.geometry.PointCloud
        A new point cloud that shares no memory with the inputs.
    """
    o3d = require_open3d()
    p = as_vertices(points, name="points")
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(p))
    if colors is not None:
        cloud.colors = o3d.utility.Vector3dVector(_checked_colors(colors, p.shape[0], "colors"))
    if normals is not None:
        cloud.normals = o3d.utility.Vector3dVector(_checked_normals(normals, p.shape[0], "normals"))
    return cloud


def read_geometry(path: str | os.PathLike[str]) -> Any:
    """Read a triangle mesh (or, when the file holds no triangles, a point cloud) with Open3D.

    Parameters
    ----------
    path : str or os.PathLike
        Any format Open3D reads (PLY, OBJ, OFF, STL, GLB, ...).

    Returns
    -------
    open3d.geometry.TriangleMesh or open3d.geometry.PointCloud
        The geometry as stored (no vertex merging or other post-processing; cleaning happens
        when a basis is built). A file whose faces Open3D cannot read (PLY triangle strips)
        comes back as a point cloud, which gets the point-cloud Laplacian.

    Raises
    ------
    FileNotFoundError
        If ``path`` does not exist.
    ValueError
        If Open3D cannot read it or it holds no points.
    """
    o3d = require_open3d()
    path = os.fspath(path)
    if not os.path.isfile(path):
        raise FileNotFoundError(f"{path}: no such file")
    # Open3D prints a warning for a file with points but no triangles: that case is handled.
    with o3d.utility.VerbosityContextManager(o3d.utility.VerbosityLevel.Error):
        mesh = o3d.io.read_triangle_mesh(path)
    if len(mesh.vertices) and len(mesh.triangles):
        return mesh
    cloud = o3d.io.read_point_cloud(path)
    if len(cloud.points):
        logger.info(
            "%s: no triangles Open3D can read (a point cloud, or e.g. PLY triangle strips): "
            "read as a point cloud of %d points",
            path,
            len(cloud.points),
        )
        return cloud
    raise ValueError(f"{path}: Open3D could not read any vertices from this file")


def write_geometry(path: str | os.PathLike[str], geometry: Any) -> None:
    """Write an Open3D mesh or point cloud atomically (temporary file, then rename).

    Parameters
    ----------
    path : str or os.PathLike
        Destination; the extension picks the format.
    geometry : open3d.geometry.TriangleMesh or open3d.geometry.PointCloud
        What to write.

    Raises
    ------
    OSError
        If Open3D fails to write; no partial file is left at ``path``.
    """
    o3d = require_open3d()
    path = os.fspath(path)
    with atomic_path(path, suffix=os.path.splitext(path)[1]) as tmp:
        # Open3D prints warnings (e.g. "OFF cannot include triangle normals") on stdout.
        with o3d.utility.VerbosityContextManager(o3d.utility.VerbosityLevel.Error):
            if isinstance(geometry, o3d.geometry.TriangleMesh):
                ok = o3d.io.write_triangle_mesh(tmp, geometry)
            else:
                ok = o3d.io.write_point_cloud(tmp, geometry)
        if not ok:
            raise OSError(f"{path}: Open3D failed to write the file")


def _same_kind_from_arrays(geometry: Any, vertices: np.ndarray, *, colors: Any = None) -> Any:
    """Build a new legacy geometry of the input's kind (mesh or cloud) with the given vertices."""
    _, faces = geometry_to_arrays(geometry)
    if faces is None:
        return point_cloud_from_arrays(vertices, colors=colors)
    return triangle_mesh_from_arrays(vertices, faces, colors=colors)


def _eigenbases_for(
    V1: np.ndarray,
    F1: np.ndarray | None,
    V2: np.ndarray,
    F2: np.ndarray | None,
    k1: int,
    k2: int,
    fmap_12: Any,
    p2p_21: Any,
    eigenbases: tuple[Any, Any] | None,
    bases: tuple[Any, Any] | None,
) -> tuple[Any, Any]:
    """Given eigenbases (checked against the shapes), else those of the bases, else computed.

    Computed ones are as large as the map needs: a given map may be larger than k1/k2 (all of
    it is used); an estimated map is refined by ZoomOut to ~100 eigenfunctions (as in pyFM's
    standard pipeline), never more than a shape allows.
    """
    from .spectrum import eigenbasis

    estimate = fmap_12 is None and p2p_21 is None
    if eigenbases is None and bases is not None and not estimate:
        eigenbases = (bases[0].eig, bases[1].eig)  # no estimation: the bases' own suffice
    if eigenbases is None:
        if estimate:
            k1, k2 = max(k1, 99), max(k2, 99)
        elif p2p_21 is None:
            rows, cols = np.shape(fmap_12)
            k1, k2 = max(k1, cols - 1), max(k2, rows - 1)
        return (
            eigenbasis(V1, F1, k=k1, clamp_k=estimate),
            eigenbasis(V2, F2, k=k2, clamp_k=estimate),
        )
    for eig, V, name in ((eigenbases[0], V1, "source"), (eigenbases[1], V2, "target")):
        if eig.n_vertices != V.shape[0]:
            raise ValueError(
                f"the {name} eigenbasis has {eig.n_vertices} vertices but the {name} has "
                f"{V.shape[0]}: it belongs to another shape"
            )
    return eigenbases


def transfer_colors(
    source: Any,
    target: Any,
    *,
    signal: Any = None,
    k1: int = 29,
    k2: int = 39,
    order: int = 2,
    preset: str | None = "ours",
    tol: float | None = None,
    fmap_12: Any = None,
    p2p_21: Any = None,
    landmarks: Any = None,
    method: str = "p2p",
    eigenbases: tuple[Any, Any] | None = None,
    bases: tuple[Any, Any] | None = None,
) -> Any:
    """Transfer vertex colors (or any per-vertex signal) from one Open3D geometry to another.

    Parameters
    ----------
    source, target : Open3D TriangleMesh or PointCloud (legacy or tensor)
        The shapes; neither is modified.
    signal : (n1, d) array_like, optional
        Per-vertex values on the source (default: its vertex colors).
    k1, k2 : int, default 29, 39
        Eigenfunctions multiplied on the source and the target (the paper's K = 30 / 40 for
        humans; order 3 with k ≈ 11-14 for other shapes).
    order : int, default 2
        Product order.
    preset, tol
        Orthogonalization threshold ("ours" = 1e-2 by default, "ours*" = 1e-9).
    fmap_12, p2p_21, landmarks
        A known functional map, a known point-to-point map (target vertex → source vertex),
        or known (source, target) landmark pairs for the estimation. Without any of them the
        map is estimated (WKS descriptors, orientation term, ZoomOut to 100).
    method : {"p2p", "analytic"}
        Transfer matrix computation (see :func:`o3d_ofp.transfer_matrix`).
    eigenbases : (EigenBasis, EigenBasis), optional
        Precomputed eigenbases of source and target (e.g. from cached bases); with an
        estimated map they should hold ~100 eigenfunctions for ZoomOut.
    bases : (OFPBasis, OFPBasis), optional
        Precomputed OFP bases (then ``k1``, ``k2``, ``order``, ``preset``, ``tol`` are unused).

    Returns
    -------
    open3d.geometry.TriangleMesh or open3d.geometry.PointCloud, or ndarray
        A new geometry like ``target`` colored with the transferred colors (clipped to
        [0, 1]) when the signal has 3 channels; otherwise the transferred (n2, d) array.

    References
    ----------
    .. [1] G. Maggioli et al., "Orthogonalized Fourier Polynomials for Signal Approximation
       and Transfer", Computer Graphics Forum 40(2), 2021. doi:10.1111/cgf.142645
    """
    from .pipeline import transfer_function

    V1, F1 = geometry_to_arrays(source)
    V2, F2 = geometry_to_arrays(target)
    if signal is None:
        signal = vertex_colors(source)
        if signal is None:
            raise ValueError("source has no vertex colors; pass signal= with per-vertex values")
    f = as_signal(signal, V1.shape[0], name="signal")
    eig_1, eig_2 = _eigenbases_for(V1, F1, V2, F2, k1, k2, fmap_12, p2p_21, eigenbases, bases)
    g = transfer_function(
        f,
        eig_1,
        eig_2,
        k1=k1,
        k2=k2,
        order=order,
        preset=preset,
        tol=tol,
        fmap_12=fmap_12,
        p2p_21=p2p_21,
        landmarks=landmarks,
        method=method,
        bases=bases,
    )
    if g.ndim == 2 and g.shape[1] == 3:
        return _same_kind_from_arrays(target, V2, colors=np.clip(g, 0.0, 1.0))
    return g


def transfer_detail(
    source: Any,
    target: Any,
    *,
    mode: str = "add",
    k1: int = 29,
    k2: int = 39,
    order: int = 2,
    preset: str | None = "ours*",
    tol: float | None = None,
    fmap_12: Any = None,
    p2p_21: Any = None,
    landmarks: Any = None,
    k_low: int | None = None,
    eigenbases: tuple[Any, Any] | None = None,
    bases: tuple[Any, Any] | None = None,
) -> Any:
    """Give the target the source's geometric detail; return a new displaced geometry.

    Parameters
    ----------
    source : Open3D TriangleMesh
        Shape with the detail.
    target : Open3D TriangleMesh or PointCloud
        Shape to displace (a cloud without normals gets estimated, consistently oriented
        ones). Neither input is modified.
    mode : {"add", "replace"}, default "add"
        "replace": the paper's Fig. 13, the target takes the transferred source coordinates.
        "add": the target keeps its shape and pose and gets the source's high-frequency
        heights along its normals (see :func:`o3d_ofp.pipeline.transfer_detail_arrays`).
    k1, k2, order, preset, tol, fmap_12, p2p_21, landmarks
        As in :func:`transfer_colors` (default preset "ours*").
    k_low : int, optional
        Eigenfunctions of the low-pass that separates detail from shape ("add" mode;
        default ``k1``).
    eigenbases, bases
        Precomputed eigenbases / OFP bases, as in :func:`transfer_colors`.

    Returns
    -------
    open3d.geometry.TriangleMesh or open3d.geometry.PointCloud
        A new geometry like ``target`` with moved vertices (and the target's colors, if any).
    """
    from .pipeline import transfer_detail_arrays

    o3d = require_open3d()
    V1, F1 = geometry_to_arrays(source)
    V2, F2 = geometry_to_arrays(target)
    if F1 is None:
        raise ValueError("source must be a TriangleMesh (its normals and detail need faces)")
    normals_2 = None
    if F2 is None:
        cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(V2))
        kind = _kind(target)
        if kind == "legacy_cloud" and target.has_normals():
            normals_2 = np.asarray(target.normals, dtype=np.float64).copy()
        else:
            cloud.estimate_normals()
            cloud.orient_normals_consistent_tangent_plane(15)
            normals_2 = np.asarray(cloud.normals, dtype=np.float64).copy()
    eig_1, eig_2 = _eigenbases_for(
        V1, F1, V2, F2, max(k1, k_low or 0), k2, fmap_12, p2p_21, eigenbases, bases
    )
    moved = transfer_detail_arrays(
        eig_1,
        eig_2,
        mode=mode,
        k1=k1,
        k2=k2,
        order=order,
        preset=preset,
        tol=tol,
        fmap_12=fmap_12,
        p2p_21=p2p_21,
        landmarks=landmarks,
        k_low=k_low,
        normals_2=normals_2,
        bases=bases,
    )
    return _same_kind_from_arrays(target, moved, colors=vertex_colors(target))


def filter_geometry(
    geometry: Any,
    *,
    gains: Any,
    k: int = 14,
    order: int = 3,
    preset: str | None = "ours*",
    tol: float | None = None,
    basis: Any = None,
) -> Any:
    """Spectrally filter the vertex coordinates of a mesh (the paper's Figs. 14-15).

    Parameters
    ----------
    geometry : Open3D TriangleMesh or PointCloud
        Input; not modified.
    gains : callable or (q,) array_like
        See :func:`o3d_ofp.filtering.spectral_filter` (e.g. ``smooth_gains(5)``,
        ``sharpen_gains(2)``).
    k, order, preset, tol
        The basis (the paper uses order 3 on the first 15 eigenfunctions: ``k=14``).
    basis : OFPBasis, optional
        A precomputed basis of this geometry (then ``k``, ``order``, ``preset``, ``tol`` are
        unused).

    Returns
    -------
    open3d.geometry.TriangleMesh or open3d.geometry.PointCloud
        A new geometry with filtered vertex positions (colors kept).
    """
    from .basis import ofp_basis
    from .filtering import spectral_filter
    from .spectrum import eigenbasis

    V, F = geometry_to_arrays(geometry)
    if basis is None:
        B = ofp_basis(eigenbasis(V, F, k=k), order=order, preset=preset, tol=tol)
    elif basis.n_vertices != V.shape[0]:
        raise ValueError(
            f"basis has {basis.n_vertices} vertices but the geometry has {V.shape[0]}: it "
            "belongs to another shape"
        )
    else:
        B = basis
    return _same_kind_from_arrays(
        geometry, spectral_filter(B, V, gains), colors=vertex_colors(geometry)
    )
