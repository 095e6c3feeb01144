"""Texture transfer between meshes: baking into the target's own UV layout, or UV pull-back.

:func:`transfer_texture` bakes a new image in the target's UV layout: every texel covered by a
target UV triangle is a target surface point; the map carries it to a source surface point and
the source texture (or, for a source without UVs, its vertex colors) is sampled there.
Per-vertex colors can only vary linearly over a target triangle; a baked texture keeps the
source's detail inside the triangles, and a textured target keeps its own texture layout.

:func:`texture_pullback` is the cheap alternative (pyFM's texture export): the target borrows
the source's image and gets, at each triangle corner, the source UV of the mapped point.

:func:`texture_error` measures either result against the truth on shapes in the same pose.

Maps are given per target vertex (:class:`o3d_ofp.Correspondence`, with or
without its precise ``faces_21`` / ``barycentric_21`` surface points, or a plain ``p2p_21``);
a texel inside target triangle (a, b, c) with barycentric weights (wa, wb, wc) goes to the
source surface point nearest to ``wa P(a) + wb P(b) + wc P(c)``, with P the mapped points.
"""

from __future__ import annotations

import functools
import logging
import math
import time
from typing import Any

import numpy as np
from scipy import ndimage

from ..core._warnings import warn
from ..core.texture import MAX_TEXTURE_SIZE
from ..core.wording import AdvisedError, Said
from ..workflows.maps import Correspondence, check_correspondence
from ..workflows.options import moved_keywords
from ..workflows.plan import plan_pair, prepare
from ._verbosity import open3d_errors_only
from .closest import _hit_weights
from .convert import geometry_kind, geometry_to_arrays, require_open3d, vertex_colors
from .io import read_if_path
from .texture import (
    MeshTexture,
    VertexColorSurface,
    as_uint8,
    corner_uvs,
    has_uvs,
    legacy_texture_image,
    mesh_texture,
    set_albedo,
    surface_colors,
)

__all__ = [
    "has_uvs",
    "source_colors_at",
    "texture_error",
    "texture_pullback",
    "transfer_texture",
    "with_uv_atlas",
]

logger = logging.getLogger(__name__)

#: Queries per call to Open3D's closest-point search (bounds the temporary memory).
_CHUNK = 1 << 20
#: What a bake samples: a source's texture, or its vertex colors.
_Colors = MeshTexture | VertexColorSurface


class _Surface:
    """Closest points on a triangle mesh (Open3D ``RaycastingScene``), in float32 around a centre.

    Parameters
    ----------
    vertices : (n, 3) ndarray of float
        Vertex positions (2D UVs are given with a zero third coordinate).
    faces : (m, 3) ndarray of int
        Triangles.
    """

    def __init__(self, vertices: np.ndarray, faces: np.ndarray) -> None:
        self._o3d = require_open3d()
        self.centre = vertices.mean(axis=0)
        self.scene = self._o3d.t.geometry.RaycastingScene()
        self.scene.add_triangles(
            np.ascontiguousarray(vertices - self.centre, dtype=np.float32),
            np.ascontiguousarray(faces, dtype=np.uint32),
        )

    def closest(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Closest surface points of ``points`` (p, 3), :data:`_CHUNK` queries at a time.

        Returns
        -------
        triangles : (p,) ndarray of int64
            Triangle of each closest point.
        barycentric : (p, 3) ndarray of float64
            Its barycentric weights (of the triangle's corners 0, 1, 2).
        distance : (p,) ndarray of float64
            Distance from the query to it.
        """
        n = points.shape[0]
        tri, bary, dist = np.empty(n, dtype=np.int64), np.empty((n, 3)), np.empty(n)
        for start in range(0, n, _CHUNK):
            sl = slice(start, start + _CHUNK)
            q = np.ascontiguousarray(points[sl] - self.centre, dtype=np.float32)
            ans = self.scene.compute_closest_points(self._o3d.core.Tensor(q))
            tri[sl], bary[sl] = ans["primitive_ids"].numpy(), _hit_weights(ans)
            dist[sl] = np.linalg.norm(ans["points"].numpy().astype(np.float64) - q, axis=1)
        return tri, bary, dist

    def covering(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Triangles of a flat (z = 0) mesh under points of the plane (vertical rays).

        Returns
        -------
        triangles : (p,) ndarray of int64
            The triangle each point lies in, -1 for none.
        barycentric : (p, 3) ndarray of float64
            The point's barycentric weights in it (undefined where none).
        """
        rays = np.zeros((points.shape[0], 6), dtype=np.float32)
        rays[:, :2] = points[:, :2] - self.centre[:2]
        rays[:, 2] = 1.0 - self.centre[2]
        rays[:, 5] = -1.0
        ans = self.scene.cast_rays(self._o3d.core.Tensor(rays))
        ids = ans["primitive_ids"].numpy().astype(np.int64)
        return np.where(np.isfinite(ans["t_hit"].numpy()), ids, -1), _hit_weights(ans)


def _callers_kind(out: Any, target: Any) -> Any:
    """``out`` (a new legacy textured mesh) as a tensor mesh when ``target`` was one.

    ``TriangleMesh.from_legacy`` drops the textures: the one image the triangles use goes to
    the material's ``albedo`` map, in the top-down row order :func:`mesh_texture` reads and
    tensor meshes keep. A result with several images (a pull-back from a source
    with several materials) stays legacy: a tensor mesh holds one albedo map.
    """
    if geometry_kind(target) != "tensor_mesh":
        return out
    images = mesh_texture(out).used_images() if out.has_triangle_uvs() else []
    if len(images) > 1:
        logger.warning(
            "the result uses %d texture images; a tensor mesh holds one (its albedo map): "
            "returned as a legacy mesh", len(images),
        )  # fmt: skip
        return out
    result = require_open3d().t.geometry.TriangleMesh.from_legacy(out)
    if images:
        set_albedo(result, images[0])
    return result


def _legacy_copy(target: Any) -> Any:
    """Copy ``target`` into a new legacy mesh, every attribute kept (tensor meshes converted)."""
    kind = geometry_kind(target)
    if kind not in ("legacy_mesh", "tensor_mesh"):
        raise TypeError("target must be an Open3D TriangleMesh with texture coordinates")
    return target.to_legacy() if kind == "tensor_mesh" else type(target)(target)


def with_uv_atlas(mesh: Any, *, size: int = 1024) -> Any:
    """Return a legacy copy of a mesh with a new UV atlas (Open3D's ``compute_uvatlas``).

    Parameters
    ----------
    mesh : open3d.geometry.TriangleMesh or open3d.t.geometry.TriangleMesh
        The mesh (not modified).
    size : int, default 1024
        Texture size the atlas is laid out for (the gutter between charts is in texels).

    Returns
    -------
    open3d.geometry.TriangleMesh
        The mesh with its vertices, triangles and other attributes, and ``triangle_uvs``.

    Raises
    ------
    ValueError
        If Open3D changed the vertices or gave no UVs.
    """
    o3d = require_open3d()
    kind = geometry_kind(mesh)
    if kind not in ("legacy_mesh", "tensor_mesh"):
        raise TypeError("a UV atlas needs a triangle mesh")
    t = mesh.clone() if kind == "tensor_mesh" else o3d.t.geometry.TriangleMesh.from_legacy(mesh)
    n = t.vertex.positions.shape[0]
    logger.info("texture transfer: computing a UV atlas for the target (%d vertices)", n)
    t0 = time.perf_counter()
    try:
        with open3d_errors_only():  # it prints "[Open3D INFO] actual parallel_partitions ..."
            t.compute_uvatlas(size=int(size))
    except RuntimeError as exc:  # e.g. size 3: "[Open3D Error] ..." and nothing of the size
        raise ValueError(
            f"size={size}: Open3D could not lay out a UV atlas in {size} x {size} texels; give "
            "a larger size (the default is 1024)"
        ) from exc
    out = t.to_legacy()
    if len(out.vertices) != n or not out.has_triangle_uvs():
        raise ValueError("Open3D's compute_uvatlas changed the mesh's vertices or gave no UVs")
    # said apart from the bake's own time (an atlas can take many times the bake)
    logger.info("texture transfer: UV atlas done in %.1f s", time.perf_counter() - t0)
    return out


def _mapped_points(
    V1: np.ndarray, F1: np.ndarray, V2: np.ndarray, F2: np.ndarray, given: Correspondence | None
) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
    """Source surface point of every target vertex (a map estimated when none is given).

    Returns the (n2, 3) points, and their source triangles and barycentric weights when the
    map gives them (a surface map, ``faces_21``: a closest-point map), else None.
    """
    plan = plan_pair(V1, F1, V2, F2, task="texture", given=given)
    if given is None:
        logger.info("texture transfer: no map given, estimating one (eigenbases and ZoomOut)")
    corr = prepare(plan, V1, F1, V2, F2, given=given).correspondence
    if corr.faces_21 is None:
        return V1[corr.p2p_21], None, None
    tri = np.asarray(corr.faces_21, dtype=np.int64)
    if tri.min() < 0 or tri.max() >= F1.shape[0]:
        raise ValueError(
            f"correspondence.faces_21 must index the source's {F1.shape[0]} triangles; got "
            f"[{tri.min()}, {tri.max()}]"
        )
    bary = np.asarray(corr.barycentric_21, dtype=np.float64)
    return np.einsum("pk,pkd->pd", bary, V1[F1[tri]]), tri, bary


def _rasterize(
    uv: np.ndarray, size: int, band: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Find the texels of a (size × size) image that UV triangles cover or nearly cover.

    Parameters
    ----------
    uv : (m, 3, 2) ndarray of float
        Corner UVs (v up); coordinates outside [0, 1] wrap around (GL_REPEAT).
    size : int
        Image side.
    band : float
        Texels whose centre lies within this distance (in texels) of a triangle are kept, with
        the nearest point of the nearest triangle.

    Returns
    -------
    texels : (p,) ndarray of int64
        Flat indices (row-major, rows top-down) of the kept texels.
    triangles : (p,) ndarray of int64
        The triangle of each.
    barycentric : (p, 3) ndarray of float64
        The barycentric weights of the texel centre (of its nearest point) in it.
    inside : (p,) ndarray of bool
        True where a triangle covers the texel centre.
    """
    shift = np.floor(uv.mean(axis=1))  # bring every triangle next to [0, 1]^2
    local = uv - shift[:, None, :]
    pad = (band + 1.0) / size
    lo, hi = local.min(axis=1), local.max(axis=1)
    idx = np.flatnonzero(np.any(lo < pad, axis=1) | np.any(hi > 1.0 - pad, axis=1))
    # the triangles near the square's border are copied into the 8 squares around it
    shifts = [np.array([du, dv]) for du in (-1.0, 0.0, 1.0) for dv in (-1.0, 0.0, 1.0) if du or dv]
    all_uv = np.concatenate([local, *(local[idx] + d for d in shifts)])
    all_owner = np.concatenate([np.arange(uv.shape[0]), *[idx] * len(shifts)])
    k = all_uv.shape[0]
    pts = np.concatenate([all_uv.reshape(-1, 2), np.zeros((3 * k, 1))], axis=1)
    surface = _Surface(pts, np.arange(3 * k).reshape(k, 3))
    n = size * size
    # Centres inside a triangle: one vertical ray each (much cheaper than closest points).
    parts = []
    for start in range(0, n, _CHUNK):
        flat = np.arange(start, min(start + _CHUNK, n))
        tri, bary = surface.covering(_centres(flat, size))
        parts.append((flat[tri >= 0], tri[tri >= 0], bary[tri >= 0]))
    hit_idx, hit_tri, hit_bary = (np.concatenate(part) for part in zip(*parts, strict=True))
    hit = np.zeros(n, dtype=bool)
    hit[hit_idx] = True
    # Centres near a triangle: around the hit texels and around every triangle corner (a chart
    # smaller than a texel covers no centre), closest points within ``band`` texels.
    seeds = hit.reshape(size, size).copy()
    corner = np.floor(all_uv.reshape(-1, 2) * size).astype(np.int64)
    corner = corner[np.all((corner >= 0) & (corner < size), axis=1)]
    seeds[size - 1 - corner[:, 1], corner[:, 0]] = True
    grown = ndimage.binary_dilation(seeds, np.ones((3, 3), bool), math.ceil(band) + 1)
    near_idx = np.flatnonzero(grown.ravel() & ~hit)
    tri, bary, dist = surface.closest(_centres(near_idx, size))
    keep = dist * size <= band
    return (
        np.concatenate([hit_idx, near_idx[keep]]),
        all_owner[np.concatenate([hit_tri, tri[keep]])],
        np.concatenate([hit_bary, bary[keep]]),
        np.concatenate([np.ones(hit_idx.size, dtype=bool), dist[keep] * size < 1e-3]),
    )


#: A bake warns when more than this share of the target's UV area lies on texels other
#: triangles cover too. Measured at 256 and 1024 texels: spot's and Open3D atlases of FAUST
#: 087 share 0.0000-0.0003 (texel rounding); a side projection of 087 0.51, an atlas tiled
#: twice 0.60 (a mirrored layout bakes at error 0.39 against 0.18 for the target's own).
UV_OVERLAP = 0.05


def _uv_overlap(uv: np.ndarray, inside: int, size: int) -> float:
    """Share of the UV triangles' area (wrapped into the image) that other triangles cover too.

    ``uv``: (m, 3, 2) corner UVs; ``inside``: the texels whose centre a triangle covers (each
    counted once, whatever covers it), of a (size × size) image.
    """
    e1, e2 = uv[:, 1] - uv[:, 0], uv[:, 2] - uv[:, 0]
    area = 0.5 * float(np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]).sum())
    if area * size * size < 64:  # a few texels: no measure
        return 0.0
    return max(0.0, 1.0 - inside / (size * size) / area)


def _centres(flat: np.ndarray, size: int) -> np.ndarray:
    """(p, 3) UV centres (z = 0) of texels given by flat row-major indices, rows top-down."""
    rows, cols = np.divmod(flat, size)
    return np.column_stack([(cols + 0.5) / size, 1.0 - (rows + 0.5) / size, np.zeros(flat.size)])


def _dilate(image: np.ndarray, filled: np.ndarray, dilate: int) -> np.ndarray:
    """Grow the filled region ``dilate`` texels outward (nearest filled texel); rest: mean color."""
    out = image.copy()
    if not np.any(filled):
        return out
    dist, (ir, ic) = ndimage.distance_transform_edt(~filled, return_indices=True)
    grow = ~filled & (dist <= dilate)
    out[grow] = image[ir[grow], ic[grow]]
    rest = ~filled & ~grow
    out[rest] = image[filled].mean(axis=0)
    return out


@moved_keywords("p2p_21", "partial")
def transfer_texture(
    source: Any,
    target: Any,
    *,
    correspondence: Correspondence | None = None,
    size: int = 1024,
    texture: Any = None,
    dilate: int = 8,
    atlas: bool = False,
) -> Any:
    """Bake the source's texture (or vertex colors) into a new image in the target's UV layout.

    Every texel covered by a target UV triangle is the target surface point at its centre; it
    is carried to the source surface through the map (the mapped points of the triangle's
    corners interpolated with the texel's barycentric weights, then projected onto the source
    with Open3D's ``RaycastingScene.compute_closest_points``) and the source texture is
    sampled there (bilinear); a source without UVs has its vertex colors interpolated there
    instead, so a textured target keeps its own layout and a coarse target keeps the colors
    of a finer source inside its triangles. Texels whose centre lies outside every triangle
    but within √2 texels of one (they are read by bilinear sampling at the triangle's edges)
    take the nearest point of the nearest triangle; the baked region is then grown ``dilate``
    texels outward with the nearest baked texel's color, so seams do not turn black.

    Parameters
    ----------
    source : Open3D TriangleMesh (legacy or tensor), MeshTexture, VertexColorSurface or path
        The source (a file path is read with :func:`o3d_ofp.read_geometry`): textured
        (per-corner UVs and an image, read as :func:`o3d_ofp.texture_colors` reads them), or
        without UVs and with vertex colors; or its arrays already read by
        ``o3d_ofp.boundary.texture.surface_colors`` (picklable: what a collection run sends to
        its workers); not modified.
    target : open3d.geometry.TriangleMesh or open3d.t.geometry.TriangleMesh or path
        The target, with its own per-corner UVs (``triangle_uvs``); not modified.
    correspondence : Correspondence, optional
        The map, one source point per target vertex: its precise surface points
        (``faces_21``, ``barycentric_21``) when it has them, else its vertex map ``p2p_21``
        (a map the caller brings: :meth:`o3d_ofp.Correspondence.from_p2p`). Without it one is
        estimated with the steps and defaults of :func:`o3d_ofp.match` (shapes must be close
        to isometric; check the logged quality report; a part: ``match(partial=True)``
        first).
    size : int, default 1024
        Side of the baked (size × size) image.
    texture : str, os.PathLike, ndarray or Open3D image, optional
        The source's texture, rows top-down as in a file; default the source's own images
        (the source then needs UVs: its vertex colors are not used).
    dilate : int, default 8
        Texels the baked region is grown by; texels beyond get the mean baked color.
    atlas : bool, default False
        For a target without UVs: give it a new UV atlas first (Open3D's
        ``compute_uvatlas``, ``size`` texels wide; its vertices are kept) and bake into it.
        Without it such a target is an error (per-vertex colors: :func:`transfer_colors`).

    Returns
    -------
    open3d.geometry.TriangleMesh or open3d.t.geometry.TriangleMesh
        A new mesh of the target's kind: a copy of the target (every attribute kept,
        ``triangle_uvs`` unchanged) with ``textures`` = [the baked image] and all
        ``triangle_material_ids`` 0 (legacy; the image stored bottom-up like every legacy
        Open3D texture, so ``open3d.io.write_triangle_mesh`` writes it the right way up), or
        the image as the material's ``albedo`` map (tensor).

    Raises
    ------
    ValueError
        If the target has no UVs (and not ``atlas``), the source neither a texture nor
        vertex colors (or UVs without an image), or the map does not fit the shapes.
    """
    if not isinstance(atlas, bool):
        raise TypeError(f"atlas must be True or False; got {atlas!r}")
    if int(size) != size or not 1 <= int(size) <= MAX_TEXTURE_SIZE:
        raise ValueError(f"size must be an integer in [1, {MAX_TEXTURE_SIZE}]; got {size!r}")
    if int(dilate) != dilate or dilate < 0:
        raise ValueError(f"dilate must be a non-negative integer; got {dilate!r}")
    size, dilate = int(size), int(dilate)
    src = _bake_source(source, texture)
    target = read_if_path(target, "target")
    if check_correspondence(correspondence) is not None:  # before an atlas (seconds of work)
        correspondence.check(src.vertices.shape[0], geometry_to_arrays(target)[0].shape[0])
    if not has_uvs(target):
        if not atlas:
            raise AdvisedError(Said(
                "the target has no texture coordinates: pass {atlas} to bake into a new UV "
                "atlas, or transfer per-vertex colors (transfer_colors)", {}, "no_uvs",
            ))  # fmt: skip
        target = with_uv_atlas(target, size=size)
    target_uv = corner_uvs(target)
    V2, F2 = geometry_to_arrays(target)
    assert F2 is not None
    points, _, _ = _mapped_points(src.vertices, src.faces, V2, F2, correspondence)
    out = _legacy_copy(target)
    out.textures = [legacy_texture_image(_bake(src, target_uv, points[F2], size, dilate))]
    out.triangle_material_ids = require_open3d().utility.IntVector(np.zeros(len(F2), np.int32))
    return _callers_kind(out, target)


def _bake_source(source: Any, texture: Any) -> _Colors:
    """Return the colors a bake samples: the source's as given, or read from the source mesh."""
    if not isinstance(source, _Colors):
        src = surface_colors(read_if_path(source, "source"), texture)
        if isinstance(src, VertexColorSurface):
            logger.info("texture transfer: the source has no UVs; its vertex colors are baked")
        return src
    if texture is not None:
        raise ValueError(
            f"texture= applies to a source mesh; a {type(source).__name__} has its colors"
        )
    return source


def _bake(src: _Colors, uv: np.ndarray, corners: np.ndarray, size: int, dilate: int) -> np.ndarray:
    """Return the (size, size, 3) image of the source's colors in the target's UV layout.

    ``uv`` and ``corners``: (m, 3, 2) UVs and (m, 3, 3) mapped points of the target's triangles.
    """
    texels, tri2, bary2, inside = _rasterize(uv, size, band=math.sqrt(2.0) + 1e-6)
    n_inside = int(np.count_nonzero(inside))
    logger.debug(
        "texture transfer: %d texels inside %d target triangles, %d at their edges",
        n_inside, uv.shape[0], inside.size - n_inside,
    )  # fmt: skip
    shared = _uv_overlap(uv, n_inside, size)
    if shared > UV_OVERLAP:
        warn(logger, Said(
            "the target's UV triangles overlap: {percent:.0f} % of their UV area shares texels "
            "with other triangles (mirrored, stacked or tiled UVs), and a shared texel holds "
            "the colors of one of them only, wrong on the others; bake into a layout of the "
            "target's own (remove its UVs and pass {atlas}), or transfer per-vertex colors "
            "(transfer_colors)", {"percent": 100 * shared}, "uv_overlap",
        ))  # fmt: skip
    q = np.einsum("pk,pkd->pd", bary2, corners[tri2])
    tri1, bary1, _ = _Surface(src.vertices, src.faces).closest(q)
    image = np.zeros((size, size, 3), dtype=np.float32)
    filled = np.zeros((size, size), dtype=bool)
    image.reshape(-1, 3)[texels] = src.sample(tri1, bary1)
    filled.reshape(-1)[texels] = True
    return _dilate(image, filled, dilate)


def _plane_barycentric(points: np.ndarray, corners: np.ndarray) -> np.ndarray:
    """Barycentric weights (possibly negative) of points projected onto triangles' planes.

    Parameters
    ----------
    points : (p, 3) ndarray
        Points.
    corners : (p, 3, 3) ndarray
        One triangle per point.

    Returns
    -------
    (p, 3) ndarray of float64
        Weights summing to 1 (NaN for a degenerate triangle).
    """
    a = corners[:, 0]
    e1, e2, d = corners[:, 1] - a, corners[:, 2] - a, points - a
    dot = functools.partial(np.einsum, "ij,ij->i")
    g11, g12, g22, r1, r2 = dot(e1, e1), dot(e1, e2), dot(e2, e2), dot(e1, d), dot(e2, d)
    det = g11 * g22 - g12**2
    ok = det > 1e-30 * (g11 + g22) ** 2
    with np.errstate(divide="ignore", invalid="ignore"):
        s = np.where(ok, (g22 * r1 - g12 * r2) / det, np.nan)
        t = np.where(ok, (g11 * r2 - g12 * r1) / det, np.nan)
    return np.column_stack([1.0 - s - t, s, t])


@moved_keywords("p2p_21", "partial")
def texture_pullback(
    source: Any,
    target: Any,
    *,
    correspondence: Correspondence | None = None,
    texture: Any = None,
) -> Any:
    """Give the target the source's texture image and, at its triangle corners, source UVs.

    The cheap alternative to :func:`transfer_texture` (pyFM's texture export): no new image,
    each target triangle corner gets the source UV of its mapped point, and the texture varies
    inside a target triangle as the source's does inside the image of that triangle in UV
    space. A target triangle whose corners land in different source UV charts would span the
    atlas; such corners get the UV the chart of the triangle's centre extends to them (the
    point's barycentric weights in that source triangle's plane), so the triangle stays in one
    chart. Texture detail is still lost where the map is coarse or a target triangle covers
    more than one source chart.

    Parameters
    ----------
    source : open3d.geometry.TriangleMesh or open3d.t.geometry.TriangleMesh or path
        The textured source; not modified.
    target : open3d.geometry.TriangleMesh or open3d.t.geometry.TriangleMesh or path
        The target (its own UVs, if any, are replaced); not modified.
    correspondence : Correspondence, optional
        The map (its ``faces_21`` / ``barycentric_21`` surface points when present); without it
        one is estimated (see :func:`transfer_texture`).
    texture : str, os.PathLike, ndarray or Open3D image, optional
        The source's texture, rows top-down as in a file; default the source's own images.

    Returns
    -------
    open3d.geometry.TriangleMesh or open3d.t.geometry.TriangleMesh
        A new mesh of the target's kind: a copy of the target with ``triangle_uvs`` in the
        source's layout, the source's images as ``textures`` (bottom-up, as legacy meshes
        keep them) and each triangle's material id that of the source triangle under its
        centre; for a tensor target, the image as the material's ``albedo`` map (a source with
        several images gives a legacy mesh, with a warning).
    """
    o3d = require_open3d()
    source, target = read_if_path(source, "source"), read_if_path(target, "target")
    try:
        src = mesh_texture(source, texture)
    except ValueError as exc:  # said of the source
        if texture is not None:  # the message names texture= itself
            raise
        raise ValueError(
            f"texture_pullback needs a textured source (UVs and an image): the source: {exc}"
        ) from exc
    V2, F2 = geometry_to_arrays(target)
    assert F2 is not None
    V1, F1 = src.vertices, src.faces
    check_correspondence(correspondence)
    points, tri, bary = _mapped_points(V1, F1, V2, F2, correspondence)
    surface = _Surface(V1, F1)
    if tri is None:
        tri, bary, _ = surface.closest(points)
    assert bary is not None
    own = src.uv_at(tri, bary)[F2]  # (m2, 3, 2): each corner's UV in its own triangle
    ref_tri, ref_bary, _ = surface.closest(points[F2].mean(axis=1))
    ref_uv = src.uv_at(ref_tri, ref_bary)  # (m2, 2)
    corner_points = points[F2].reshape(-1, 3)
    ref_of_corner = np.repeat(ref_tri, 3)
    w = _plane_barycentric(corner_points, V1[F1[ref_of_corner]])
    extended = np.einsum("pk,pkd->pd", w, src.uvs[ref_of_corner]).reshape(-1, 3, 2)
    same_material = src.material[tri][F2] == src.material[ref_tri][:, None]
    far = np.linalg.norm(own - extended, axis=2) > np.linalg.norm(
        extended - ref_uv[:, None, :], axis=2
    )
    swap = np.isfinite(extended).all(axis=2) & (far | ~same_material)
    uv = np.where(swap[:, :, None], extended, own)
    logger.debug(
        "texture pull-back: %d of %d corners moved into the chart of their triangle's centre",
        int(np.count_nonzero(swap)),
        swap.size,
    )
    out = _legacy_copy(target)
    out.triangle_uvs = o3d.utility.Vector2dVector(uv.reshape(-1, 2))
    # Only the loaded images go along (not the OBJ reader's empty default): renumber them.
    loaded = [i for i, img in enumerate(src.images) if img.size > 0]
    renumber = np.zeros(len(src.images), dtype=np.int32)
    renumber[loaded] = np.arange(len(loaded), dtype=np.int32)
    out.textures = [legacy_texture_image(as_uint8(src.images[i])) for i in loaded]
    material = renumber[np.maximum(src.material[ref_tri], 0)]
    out.triangle_material_ids = o3d.utility.IntVector(material)
    return _callers_kind(out, target)


def source_colors_at(source: Any, points: Any, *, texture: Any = None) -> np.ndarray:
    """Sample the source's colors at the source surface points nearest to ``points``.

    Parameters
    ----------
    source : open3d.geometry.TriangleMesh or open3d.t.geometry.TriangleMesh or path
        The source, textured or (without UVs) colored per vertex (see
        :func:`~o3d_ofp.boundary.texture.surface_colors`); not modified.
    points : (p, 3) array_like of float
        Query points (e.g. the target's vertices, for shapes in the same pose).
    texture : str, os.PathLike, ndarray or Open3D image, optional
        The source's texture, rows top-down; default the source's own images.

    Returns
    -------
    (p, 3) ndarray of float64
        Colors in [0, 1].
    """
    src = surface_colors(read_if_path(source, "source"), texture)
    P = np.asarray(points, dtype=np.float64)
    if P.ndim != 2 or P.shape[1] != 3 or not np.all(np.isfinite(P)):
        raise ValueError(f"points must be a finite (p, 3) array; got shape {P.shape}")
    tri, bary, _ = _Surface(src.vertices, src.faces).closest(P)
    return src.sample(tri, bary)


def _surface_samples(
    V: np.ndarray, F: np.ndarray, n: int, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray]:
    area = 0.5 * np.linalg.norm(np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]]), axis=1)
    tri = rng.choice(F.shape[0], size=n, p=area / area.sum())
    r1, r2 = np.sqrt(rng.random(n)), rng.random(n)
    bary = np.column_stack([1.0 - r1, r1 * (1.0 - r2), r1 * r2])
    return tri, bary


def texture_error(
    mesh: Any,
    source: Any,
    *,
    colors: str = "auto",
    samples: int = 20000,
    seed: int = 0,
    texture: Any = None,
) -> float:
    """Mean color error of a colored target at random surface points, against the source.

    The truth at a target surface point is the source texture at the source surface point
    nearest to it: a measure for a target that is the source remeshed in the same pose (the
    closest point is then the true corresponding point).

    Parameters
    ----------
    mesh : open3d.geometry.TriangleMesh or open3d.t.geometry.TriangleMesh
        The colored target, e.g. a result of :func:`transfer_texture`; not modified.
    source : open3d.geometry.TriangleMesh or open3d.t.geometry.TriangleMesh
        The source, textured or (without UVs) colored per vertex; not modified.
    colors : {"auto", "texture", "vertex"}, default "auto"
        What colors the target: its UV texture (sampled bilinearly), or its vertex colors
        (interpolated linearly over the triangles). "auto": the texture when the mesh has
        UVs and an image, else the vertex colors.
    samples : int, default 20000
        Number of random surface points (uniform by area).
    seed : int, default 0
        Seed of the random points.
    texture : str, os.PathLike, ndarray or Open3D image, optional
        The source's texture, rows top-down; default the source's own images.

    Returns
    -------
    float
        Mean absolute difference per color channel, in [0, 1].
    """
    if colors not in ("auto", "texture", "vertex"):
        raise ValueError(f"colors must be 'auto', 'texture' or 'vertex'; got {colors!r}")
    tex: MeshTexture | None = None
    if colors in ("auto", "texture"):
        try:
            tex = mesh_texture(mesh)
        except ValueError:
            if colors == "texture":
                raise
    V, F = geometry_to_arrays(mesh)
    if F is None or F.shape[0] == 0:
        raise ValueError("mesh must be a triangle mesh")
    rng = np.random.default_rng(seed)
    tri, bary = _surface_samples(V, F, int(samples), rng)
    if tex is not None:
        got = tex.sample(tri, bary)
    else:
        C = vertex_colors(mesh)
        if C is None:
            raise ValueError("the mesh has neither a texture nor vertex colors")
        got = VertexColorSurface(vertices=V, faces=F, colors=C).sample(tri, bary)
    truth = source_colors_at(source, np.einsum("pk,pkd->pd", bary, V[F[tri]]), texture=texture)
    return float(np.abs(got - truth).mean())
