"""Conversion between Open3D geometries and arrays: the only way Open3D data enters the package.

Open3D geometries go in as copies (``np.asarray`` on an Open3D vector is a *live view*; we never
hand one out) and come back as new geometries built from validated arrays (Open3D does not
bounds-check triangle indices and crashes the interpreter on bad ones).

Both the legacy API (``open3d.geometry.TriangleMesh``/``PointCloud``) and the tensor API
(``open3d.t.geometry.TriangleMesh``/``PointCloud``) are accepted. Open3D itself is imported
lazily, by :func:`require_open3d`, so importing this module does not import Open3D.
"""

from __future__ import annotations

import importlib
import logging
import math
from types import ModuleType
from typing import Any

import numpy as np

from ..core._validation import as_faces, as_signal, as_vertices

__all__ = [
    "OPEN3D_INSTALL_HINT",
    "geometry_kind",
    "geometry_to_arrays",
    "is_open3d_geometry",
    "like_target",
    "point_cloud_from_arrays",
    "point_normals",
    "require_open3d",
    "scaled_copy",
    "triangle_mesh_from_arrays",
    "vertex_colors",
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


def geometry_kind(geometry: Any, name: str = "geometry") -> str:
    """Return one of ``legacy_mesh``, ``legacy_cloud``, ``tensor_mesh``, ``tensor_cloud``.

    ``name`` (e.g. "target") starts the TypeError for anything else.
    """
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
        f"{name} must be an Open3D TriangleMesh or PointCloud (legacy open3d.geometry or "
        f"tensor open3d.t.geometry); got {type(geometry).__module__}.{type(geometry).__name__}"
    )


def _tensor_attr(attrs: Any, key: str, default: Any = None) -> Any:
    return np.array(attrs[key].cpu().numpy(), copy=True) if key in attrs else default


def geometry_to_arrays(
    geometry: Any, *, name: str = "geometry"
) -> tuple[np.ndarray, np.ndarray | None]:
    """Copy an Open3D geometry into plain arrays.

    Parameters
    ----------
    geometry : open3d.geometry.TriangleMesh, PointCloud, or their ``open3d.t`` counterparts
        The input; it is not modified.
    name : str, default "geometry"
        What the error messages call it (the caller's keyword: "source", "target").

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
    kind = geometry_kind(geometry, name)
    if kind == "legacy_mesh":
        raw_v = np.array(geometry.vertices, dtype=np.float64, copy=True)
        raw_f = np.array(geometry.triangles, dtype=np.int64, copy=True)
    elif kind == "legacy_cloud":
        raw_v, raw_f = np.array(geometry.points, dtype=np.float64, copy=True), None
    elif kind == "tensor_mesh":
        raw_v = _tensor_attr(geometry.vertex, "positions", np.zeros((0, 3)))
        raw_f = _tensor_attr(geometry.triangle, "indices", np.zeros((0, 3), dtype=np.int64))
    else:
        raw_v, raw_f = _tensor_attr(geometry.point, "positions", np.zeros((0, 3))), None
    vertices = as_vertices(raw_v.reshape(-1, 3), name=f"{name} vertices")
    if raw_f is None:
        return vertices, None
    faces = as_faces(raw_f.reshape(-1, 3), vertices.shape[0], name=f"{name} triangles")
    return vertices, faces


def stray_colors(geometry: Any) -> str | None:
    """Say when a legacy geometry's colors are not one per vertex (Open3D then ignores them).

    Returns a sentence for an error message (e.g. "it has 100 colors for its 6890 vertices"),
    or None when its colors are one per vertex or absent (a tensor geometry's attributes are).
    """
    kind = geometry_kind(geometry)
    if kind not in ("legacy_mesh", "legacy_cloud"):
        return None
    mesh = kind == "legacy_mesh"
    count = len(geometry.vertex_colors if mesh else geometry.colors)
    n = len(geometry.vertices if mesh else geometry.points)
    if count == 0 or count == n:
        return None
    return f"it has {count} colors for its {n} {'vertices' if mesh else 'points'}"


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
    kind = geometry_kind(geometry)
    if kind == "legacy_mesh":
        colors = (
            np.array(geometry.vertex_colors, dtype=np.float64)
            if geometry.has_vertex_colors()  # False too when they are not one per vertex
            else None
        )
    elif kind == "legacy_cloud":
        colors = np.array(geometry.colors, dtype=np.float64) if geometry.has_colors() else None
    else:
        attrs = geometry.vertex if kind == "tensor_mesh" else geometry.point
        colors = _tensor_attr(attrs, "colors", np.zeros(0))
        if np.issubdtype(colors.dtype, np.integer):  # uint8 colors in the tensor API
            colors = colors / np.iinfo(colors.dtype).max
        colors = colors.astype(np.float64)
        if colors.ndim == 2 and colors.shape[1] == 4 and colors.size:  # RGBA: the RGB
            logger.info("the geometry's colors are RGBA: their RGB channels are used")
            colors = colors[:, :3]
        elif colors.size and (colors.ndim != 2 or colors.shape[1] != 3):
            raise ValueError(
                f"the geometry's colors have shape {colors.shape}: expected (n, 3) RGB "
                "(or (n, 4) RGBA) values"
            )
    if colors is None or colors.size == 0:
        return None
    return colors.reshape(-1, 3)


#: Neighbours of each point for the normals Open3D estimates on a cloud without normals (the
#: point-cloud Laplacian's default neighbourhood, :func:`o3d_ofp.core.laplacian.laplacian`).
NORMAL_NEIGHBORS = 30


def point_normals(geometry: Any, points: Any = None) -> np.ndarray:
    """Return unit normals of a point cloud: its own, or estimated and oriented by Open3D.

    Parameters
    ----------
    geometry : Open3D PointCloud (legacy or tensor)
        The cloud; it is not modified.
    points : (n, 3) array_like, optional
        Its points as arrays (default: read from ``geometry``).

    Returns
    -------
    (n, 3) ndarray of float64
        The cloud's normals when it has them, else normals fitted on the
        :data:`NORMAL_NEIGHBORS` nearest points and oriented consistently over the cloud
        (``orient_normals_consistent_tangent_plane``; the global sign is arbitrary).
    """
    kind = geometry_kind(geometry)
    given = None
    if kind == "legacy_cloud" and geometry.has_normals():
        given = np.array(geometry.normals, dtype=np.float64)
    elif kind == "tensor_cloud":
        given = _tensor_attr(geometry.point, "normals")
    P = as_vertices(geometry_to_arrays(geometry)[0] if points is None else points)
    if given is not None and given.shape == P.shape and np.all(np.isfinite(given)):
        n = np.asarray(given, dtype=np.float64)
    else:
        o3d = require_open3d()
        cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(P))
        k = min(NORMAL_NEIGHBORS, max(P.shape[0] - 1, 3))
        cloud.estimate_normals(o3d.geometry.KDTreeSearchParamKNN(knn=k))
        cloud.orient_normals_consistent_tangent_plane(min(15, k))
        n = np.array(cloud.normals, dtype=np.float64)
        logger.debug("estimated normals of a %d-point cloud (%d neighbours)", P.shape[0], k)
    norm = np.linalg.norm(n, axis=1, keepdims=True)
    return np.divide(n, norm, out=np.zeros_like(n), where=norm > 0)


def _checked(values: Any, n: int, name: str) -> np.ndarray:
    """Return ``values`` checked as (n, 3) finite vectors (``colors``: clipped to [0, 1])."""
    arr = as_signal(values, n, name=name)
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise ValueError(f"{name} must have shape (n, 3) with n = {n}; got {arr.shape}")
    return np.clip(arr, 0.0, 1.0) if name == "colors" else arr


def triangle_mesh_from_arrays(
    vertices: Any, faces: Any, *, colors: Any = None, normals: Any = None
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
        mesh.vertex_colors = o3d.utility.Vector3dVector(_checked(colors, len(v), "colors"))
    if normals is not None:
        mesh.vertex_normals = o3d.utility.Vector3dVector(_checked(normals, len(v), "normals"))
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
        cloud.colors = o3d.utility.Vector3dVector(_checked(colors, len(p), "colors"))
    if normals is not None:
        cloud.normals = o3d.utility.Vector3dVector(_checked(normals, len(p), "normals"))
    return cloud


def like_target(target: Any, *, vertices: Any = None, colors: Any = None) -> Any:
    """Return a copy of ``target`` (same kind, every attribute kept) with new positions or colors.

    Parameters
    ----------
    target : Open3D TriangleMesh or PointCloud (legacy or tensor), or (vertices, faces) tuple
        The geometry the result is made like; it is not modified. A tuple gives a new legacy
        ``TriangleMesh`` (``PointCloud`` when faces is None).
    vertices : (n, 3) array_like of float, optional
        New positions (normals, where the target has them, are recomputed for meshes).
    colors : (n, 3) array_like of float, optional
        New per-vertex colors in [0, 1] (clipped).

    Returns
    -------
    geometry
        A new geometry of the target's own kind: triangles, UVs, textures, material ids,
        normals and every other attribute the target has are carried over; only what is
        passed is replaced.
    """
    if isinstance(target, tuple):
        V, F = target
        V = as_vertices(V if vertices is None else vertices)
        if F is None:
            return point_cloud_from_arrays(V, colors=colors)
        return triangle_mesh_from_arrays(V, F, colors=colors)
    n = geometry_to_arrays(target)[0].shape[0]
    V = None if vertices is None else as_vertices(vertices)
    if V is not None and V.shape[0] != n:
        raise ValueError(f"vertices has {V.shape[0]} rows; the target has {n} vertices")
    return _copy_with(target, V, None if colors is None else _checked(colors, n, "colors"))


def _copy_with(target: Any, V: Any, C: Any, *, new_normals: bool = True) -> Any:
    """Copy ``target`` (its kind, every attribute) with positions ``V`` and colors ``C``.

    Either may be None (kept). With ``new_normals``, the normals the target has are computed
    again for the new positions.
    """
    o3d = require_open3d()
    kind = geometry_kind(target)
    if kind in ("legacy_mesh", "legacy_cloud"):
        out = type(target)(target)  # Open3D's copy constructor: every attribute
        mesh = kind == "legacy_mesh"
        if V is not None:
            setattr(out, "vertices" if mesh else "points", o3d.utility.Vector3dVector(V))
        if V is not None and new_normals:
            if mesh and target.has_triangle_normals():
                out.compute_triangle_normals()
            if mesh and target.has_vertex_normals():
                out.compute_vertex_normals()
            if not mesh and target.has_normals():
                out.estimate_normals()
        if C is not None:
            setattr(out, "vertex_colors" if mesh else "colors", o3d.utility.Vector3dVector(C))
        return out
    out = target.clone()
    attrs = out.vertex if kind == "tensor_mesh" else out.point
    if V is not None:
        attrs["positions"] = o3d.core.Tensor(V).to(attrs["positions"].dtype)
    if V is not None and new_normals:
        if kind == "tensor_mesh" and "normals" in attrs:
            out.compute_vertex_normals()
        if kind == "tensor_mesh" and "normals" in out.triangle:
            out.compute_triangle_normals()
        if kind == "tensor_cloud" and "normals" in attrs:
            out.estimate_normals()
    if C is not None:
        old = attrs["colors"].numpy() if "colors" in attrs else np.empty((0, 3), np.float32)
        # the target's colors' type (integer: full scale); other than RGB (RGBA): float RGB
        dtype = old.dtype if old.ndim == 2 and old.shape[1] == 3 else np.float32
        if np.issubdtype(dtype, np.integer):
            C = np.round(C * np.iinfo(dtype).max)
        attrs["colors"] = o3d.core.Tensor(C.astype(dtype))
    return out


def scaled_copy(geometry: Any, factor: float) -> Any:
    """Return a copy of ``geometry`` with its coordinates multiplied by ``factor``.

    Unlike :func:`like_target` with new positions, the normals are kept as they are (a
    uniform scaling leaves them unchanged): a file's own normals survive a scaling and its
    inverse. The scaling is about the origin, as Open3D's ``scale(factor, center=(0, 0, 0))``.

    Parameters
    ----------
    geometry : Open3D TriangleMesh or PointCloud (legacy or tensor), or (vertices, faces) tuple
        The geometry; it is not modified.
    factor : float
        A positive, finite factor.

    Returns
    -------
    geometry
        A new geometry of the same kind, every other attribute carried over.
    """
    if not (isinstance(factor, (int, float)) and math.isfinite(factor) and factor > 0):
        raise ValueError(f"factor must be a positive, finite number; got {factor!r}")
    if isinstance(geometry, tuple):
        V, F = geometry
        return as_vertices(V) * factor, F
    return _copy_with(geometry, geometry_to_arrays(geometry)[0] * factor, None, new_normals=False)
