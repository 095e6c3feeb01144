"""Maps between shapes that are already aligned in space: closest points on the source surface.

A high-resolution scan and its simplified or remeshed copy occupy the same place: the map from
the copy to the scan is, for every target vertex, the closest point on the source *surface*
(a triangle and barycentric coordinates in it, not just the nearest source vertex). Open3D's
:class:`open3d.t.geometry.RaycastingScene` (an Embree BVH) finds the closest triangle; the
point on it is then recomputed in float64, so the result does not depend on the units or
position of the shapes (the scene itself works in float32, on centred, unit-diagonal copies).

For shapes that are only *almost* aligned, ``align=True`` first registers the target onto the
source with a rigid point-to-plane ICP. Shapes that are not aligned at all need the spectral
estimate instead (:func:`o3d_ofp.match_eigenbases`); the quality report says
so when the closest points are far away. Without ``align``, the report also says when a rigid
motion would bring the target much closer (a turned or moved copy: closest points slide along
the surface), and names ``align=True``.
"""

from __future__ import annotations

import logging
import math
import numbers
import time
from typing import Any

import numpy as np

from ..core._validation import as_faces, as_vertices
from ..core._warnings import warn
from ..core.geometry import closest_on_triangles, face_areas_normals, units_change
from ..core.wording import Said
from ..workflows.maps import Correspondence, MapQuality, shape_signature
from ..workflows.quality import AREA_RATIO_NOTE, MAX_MEAN_DISTANCE
from .convert import require_open3d

__all__ = [
    "ICP_MAX_SAMPLES",
    "ICP_MIN_SAMPLES",
    "ICP_SAMPLES_PER_VERTEX",
    "MAX_FACING_AWAY",
    "MAX_MEAN_DISTANCE",
    "closest_correspondence",
    "closest_points",
]

logger = logging.getLogger(__name__)

#: (:data:`MAX_MEAN_DISTANCE`, above which the map is suspect, lives in ``workflows.quality``:
#: a doubtful spectral map advises closest points for shapes below it.)
#: Above this mean distance (but below :data:`MAX_MEAN_DISTANCE`) a note says the shapes may be
#: misaligned or differ in geometry: a 10° turn gives 0.006-0.03.
MEAN_DISTANCE_NOTE = 0.02
#: A note is added when the largest distance exceeds this fraction (a part of the target is
#: missing from the source, or a few vertices are far away).
MAX_DISTANCE_NOTE = 0.1
#: The map is suspect when fewer distinct source positions than this fraction of the smaller
#: shape's are hit: the target's vertices crowd onto a few source vertices, as they do when the
#: shapes are not in the same pose. Measured (coverage of the smaller shape): FAUST 093 onto
#: its decimated copy, or its subdivided one, either way 1.00; the aligned detail-transfer
#: donuts 0.70; smoothed copies of FAUST 093 (its 30-eigenfunction low-pass: 0.33, decimated
#: 0.56-0.79; scripts/eval_closest_checks.py); FAUST 093 onto 087 (another pose, same place)
#: 0.18; FAUST 093 turned by 5° 0.70, 20° 0.43, 45° 0.33 (those are said by the misalignment
#: check, :data:`MISALIGNED_RATIO`).
#: Copies of a vertex (seams of a mesh read with its UVs) count once.
MIN_COVERAGE = 0.25
#: Without ``align``, a rigid motion is fitted to the closest points (point-to-plane, from the
#: identity, against the exact surface: :func:`_misaligned`). The map is suspect when that
#: motion brings the target's mean distance to the source below :data:`MISALIGNED_RATIO` of
#: what it was, by more than :data:`MISALIGNED_GAIN` of the diagonal: the shapes are the same
#: surface, slightly turned or moved, and closest points slide along it. Measured by
#: ``scripts/eval_closest_checks.py`` (mean distance after / before the motion): FAUST 093
#: turned by 0.3-45° or moved by 0.3-1 % of the diagonal, 0.00 (to 1e-9 or less); the
#: bunny's decimated copy moved by 0.35 % 0.46, turned by 2° 0.30; aligned shapes keep their
#: distance: decimated, subdivided or noisy copies 1.00-1.11, the paper's detail donuts 1.00
#: both ways, FAUST 093's low-pass copies 0.82-0.84 (a rigid motion slides a shrunken copy a
#: little closer), FAUST 093 onto 087 (another pose in the same place) 0.83. Known limit: the
#: low-pass copy turned by 5° (0.89) is not said: a misalignment is seen only when it
#: dominates the distance. Other copies agree: smoothed ones 0.71-0.96, turned or moved
#: decimated bunnies 0.13-0.35.
MISALIGNED_RATIO = 0.5
#: See :data:`MISALIGNED_RATIO`: 0.0005 of the diagonal is about FAUST turned by 0.6° or the bunny
#: moved by 0.15 % of the diagonal; a smaller gain above :data:`MISALIGNED_NOTE` adds a note.
MISALIGNED_GAIN = 0.0005
MISALIGNED_NOTE = 0.0001
#: The misalignment probe fits the motion to at most this many target vertices (seeded sample),
#: in at most :data:`MISALIGNMENT_ITERATIONS` steps, stopping after a step below
#: :data:`MISALIGNMENT_STEP` (fractions of the diagonal; the verdict only needs the distance to
#: a few digits). Measured: turned 1-45° or moved copies converge in 3-8 steps to below 1e-11
#: of the diagonal; shapes that are not rigid copies stop after 3-8 steps where 20 steps of
#: 1e-8 leave them (ratios equal to 3 digits); 0.2 s instead of 0.4-1.4 s on 7k-100k vertices.
MISALIGNMENT_SAMPLES = 20_000
MISALIGNMENT_ITERATIONS = 8
MISALIGNMENT_STEP = 1e-5
#: Default ICP correspondence distance, as a fraction of the source's bounding-box diagonal.
ICP_DISTANCE = 0.05
#: ICP (Open3D) aligns onto points sampled uniformly (seeded) on the source surface, with their
#: triangle's normal: this many per target vertex, between :data:`ICP_MIN_SAMPLES` and
#: :data:`ICP_MAX_SAMPLES` (a point-cloud source: at most that many of its points). A refinement
#: against the exact surface follows, so the sampling only needs to bring ICP close: on blob(5)
#: turned by 4°, 60k samples leave 1e-5 of the diagonal, the refinement 1e-16.
ICP_SAMPLES_PER_VERTEX = 20
ICP_MIN_SAMPLES = 50_000
ICP_MAX_SAMPLES = 200_000
#: ICP iterations at each of the two correspondence distances (3x the maximum, then the maximum).
ICP_ITERATIONS = 50
#: At most this many iterations of the final point-to-plane refinement against the exact source
#: surface; it stops when a step (rotation vector and translation, in fractions of the diagonal)
#: is smaller than :data:`REFINE_STEP` (measured: 3-4 iterations; below 1e-9 the steps only
#: wander between triangles).
REFINE_ITERATIONS = 20
REFINE_STEP = 1e-8
#: Below this fitness (fraction of target vertices within the ICP distance) the ICP result is
#: doubtful and a note says so.
ICP_MIN_FITNESS = 0.8
#: With ``align``, a turn above this many degrees that leaves the target farther than
#: :data:`MEAN_DISTANCE_NOTE` (of the diagonal) from the source makes the map suspect: ICP
#: turned shapes that are not copies of one surface. Measured by ``python
#: scripts/eval_closest_checks.py --align``: copies turned 0.3-45° or moved (``align``'s use) end
#: at 0.0000 of the diagonal; smoothed or noisy copies at 0.0014-0.0086 (turned 0-11°: ok, a
#: known limit, as the smoothed copy's 11° turn is spurious: its error is 0.043); FAUST
#: 093 onto 087 and 094 (other poses, same place; errors 0.14 and 0.22, passed as ok) 11° at
#: 0.028 and 8.5° at 0.042; the paper's aligned detail donuts t1 -> t0 turned 88-106° about
#: their axis (three runs) at 0.030 (the bumps moved; flagged too), t0 -> t1 0.0° (ok).
ICP_DOUBTFUL_TURN = 2.0
#: With ``align``, a turn above :data:`ICP_DOUBTFUL_TURN` that leaves more than this share of the
#: target's area facing more than 45° away from the source surface (each target triangle
#: against the source triangle closest to its centroid, either way round:
#: ``options["facing_away"]``) makes the map suspect: ICP stopped in a wrong place, on the
#: surface but across it. Measured by ``python scripts/eval_closest_checks.py --align``: right
#: registrations (copies turned up to 45°, a part turned 30°, decimated, subdivided) 0.000-0.006,
#: a noisy copy 0.064, smoothed copies 0.15-0.17 (turned 5-11° by ICP); FAUST 093 with its legs
#: cut turned 62° and 90° about an oblique axis, which ICP turned by 34° and 47° only, 0.67 and
#: 0.66, and another cut of it turned 62° (ICP: 72.8°, map error 0.22, which the distance
#: rule passes) 0.52; other poses and the detail donuts (flagged by the distance) 0.37-0.52.
#: Face normals, not vertex normals: a vertex normal at a crease would flag right
#: registrations of shapes with creases (a box 0.75, a 4-sided cone 0.38). Without ``align``
#: it is not a verdict: the aligned detail donuts, the detail transfer's own pair, face away
#: on 0.35-0.43 (their bumps).
MAX_FACING_AWAY = 0.3
#: Barycentric weights below this are snapped to 0 (the point lies on an edge or at a vertex),
#: so ties between the triangles sharing it are broken the same way whatever the float32 BVH
#: returned: by the smallest face index.
_SNAP = 1e-8


def _positions(vertices: np.ndarray) -> np.ndarray:
    """(n,) index of each vertex's distinct position (copies of a vertex share one)."""
    return np.unique(vertices, axis=0, return_inverse=True)[1].reshape(-1)


def _units(V2: np.ndarray, diag_1: float) -> Said | str:
    """Advice for a target in other units (its size a power of ten off the source's), or "".

    A target in millimetres onto a source in metres lies hundreds of diagonals away: the
    advice is the factor to rescale it by, not ICP (which does not scale).
    """
    ratio = _frame(V2)[1] / diag_1
    found = units_change(ratio)
    # a named change only (millimetres, centimetres, metres): a target 10 times off is
    # another shape or a mistake, not a unit
    if found is None or not found[1] or not 0.5 <= ratio * found[0] <= 2.0:
        return ""
    factor, change = found
    return Said(
        "the target's bounding box is {ratio:.3g} times the source's: shapes in other units? "
        "multiply the target's coordinates by {factor:g}{change}, e.g. {target_scale}, then "
        "match again; ",
        {"ratio": ratio, "factor": factor, "change": f" ({change})" if change else ""},
    )


def _hit_weights(ans: Any) -> np.ndarray:
    """(q, 3) barycentric weights of Open3D's ray-casting answers, clipped to >= 0, summing to 1.

    Open3D's primitive uv (s, t) is the point (1 - s - t) a + s b + t c.
    """
    uv = ans["primitive_uvs"].numpy().astype(np.float64)
    w = np.clip(np.column_stack([1.0 - uv[:, 0] - uv[:, 1], uv[:, 0], uv[:, 1]]), 0.0, None)
    return w / np.maximum(w.sum(axis=1, keepdims=True), 1e-12)


def _frame(vertices: np.ndarray) -> tuple[np.ndarray, float]:
    """Centre and diagonal of the bounding box of ``vertices`` ((3,) ndarray, float > 0)."""
    lo, hi = vertices.min(axis=0), vertices.max(axis=0)
    diag = float(np.linalg.norm(hi - lo))
    return 0.5 * (lo + hi), diag if diag > 0 else 1.0


def _canonical_faces(
    faces: np.ndarray, n1: int, face_ids: np.ndarray, bary: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Move points on an edge or at a vertex to the smallest-index triangle holding it.

    Parameters
    ----------
    faces : (m, 3) ndarray of int64
        Source triangles.
    n1 : int
        Number of source vertices.
    face_ids : (n,) ndarray of int64
        Triangle of each point.
    bary : (n, 3) ndarray of float64
        Its weights, with exact zeros where the point lies on the triangle's boundary.

    Returns
    -------
    face_ids : (n,) ndarray of int64
    bary : (n, 3) ndarray of float64
        The same points, expressed in the canonical triangle.
    """
    corners = faces[face_ids]  # (n, 3)
    support = bary > 0
    n_support = support.sum(axis=1)
    new_ids = face_ids.copy()
    # A key per vertex (v) or edge (min * n1 + max + n1 * n1, never equal to a vertex key).
    keys = np.full(face_ids.shape[0], -1, dtype=np.int64)
    at_vertex = n_support == 1
    keys[at_vertex] = corners[at_vertex, np.argmax(bary[at_vertex], axis=1)]
    on_edge = n_support == 2
    if on_edge.any():
        pair = np.sort(corners[on_edge][support[on_edge]].reshape(-1, 2), axis=1)
        keys[on_edge] = pair[:, 0] * n1 + pair[:, 1] + n1 * n1
    moved = keys >= 0
    if not moved.any():
        return face_ids, bary
    wanted = np.unique(keys[moved])
    # Keys of every vertex and edge of the candidate triangles, with the triangle's index.
    wanted_vertices = np.unique(
        np.concatenate([wanted[wanted < n1], (wanted[wanted >= n1] - n1 * n1) // n1])
    )
    candidates = np.flatnonzero(np.isin(faces, wanted_vertices).any(axis=1))
    cf = faces[candidates]
    edge_keys = [
        np.minimum(cf[:, i], cf[:, j]) * n1 + np.maximum(cf[:, i], cf[:, j]) + n1 * n1
        for i, j in ((0, 1), (1, 2), (2, 0))
    ]
    all_keys = np.concatenate([cf[:, 0], cf[:, 1], cf[:, 2], *edge_keys])
    all_faces = np.tile(candidates, 6)
    order = np.lexsort((all_faces, all_keys))  # by key, then by face index
    all_keys, all_faces = all_keys[order], all_faces[order]
    first = np.flatnonzero(np.r_[True, all_keys[1:] != all_keys[:-1]])
    pos = np.searchsorted(all_keys[first], keys[moved])
    new_ids[moved] = all_faces[first[pos]]
    # Carry each non-zero weight to the corner of the new triangle holding the same vertex.
    rows = np.flatnonzero(moved & (new_ids != face_ids))
    if rows.size:
        old_c, new_c = corners[rows], faces[new_ids[rows]]
        new_b = np.zeros((rows.size, 3))
        for j in range(3):
            k = np.argmax(old_c[:, j, None] == new_c, axis=1)
            w = np.where(support[rows, j], bary[rows, j], 0.0)
            np.add.at(new_b, (np.arange(rows.size), k), w)
        bary = bary.copy()
        bary[rows] = new_b
    return new_ids, bary


def closest_points(
    vertices: np.ndarray, faces: np.ndarray, points: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Closest point on a triangle mesh's surface to each query point.

    The closest triangle comes from Open3D's ``RaycastingScene`` (float32, on a copy centred on
    the mesh's bounding box and scaled to unit diagonal); the point on it is recomputed in
    float64. A point on an edge or at a vertex is reported in the smallest-index triangle
    holding it, so the answer does not depend on the BVH's order.

    Parameters
    ----------
    vertices : (n, 3) array_like of float
        Mesh vertices.
    faces : (m, 3) array_like of int
        Mesh triangles.
    points : (q, 3) array_like of float
        Query points.

    Returns
    -------
    face_ids : (q,) ndarray of int64
        Triangle holding each closest point.
    barycentric : (q, 3) ndarray of float64
        Its barycentric coordinates: weights of the triangle's vertices in face order
        (non-negative, rows sum to 1).
    closest : (q, 3) ndarray of float64
        The closest points, ``sum_i barycentric[:, i] * vertices[faces[face_ids, i]]``.
    distances : (q,) ndarray of float64
        Distance from each query point to its closest point.

    Raises
    ------
    ValueError
        On badly shaped arrays or out-of-range faces (the message names the argument).
    """
    V = as_vertices(vertices, name="vertices")
    F = as_faces(faces, V.shape[0], name="faces")
    P = as_vertices(points, name="points")
    return _Surface(V, F).closest(P)


class _Surface:
    """A source mesh ready for closest-point queries.

    An Open3D ``RaycastingScene`` of its copy centred on its bounding box and scaled to unit
    diagonal (the scene works in float32).

    Parameters
    ----------
    V : (n1, 3) ndarray of float64
        Vertices (checked).
    F : (m1, 3) ndarray of int64
        Triangles (checked).
    """

    def __init__(self, V: np.ndarray, F: np.ndarray) -> None:
        self._o3d = o3d = require_open3d()
        self.V, self.F = V, F
        self.centre, self.diag = _frame(V)
        self.scene = o3d.t.geometry.RaycastingScene()
        self.scene.add_triangles(
            o3d.core.Tensor(np.ascontiguousarray(self.normalize(V), dtype=np.float32)),
            o3d.core.Tensor(np.ascontiguousarray(F, dtype=np.uint32)),
        )

    def normalize(self, P: np.ndarray) -> np.ndarray:
        """Points in the centred, unit-diagonal frame ((q, 3) -> (q, 3))."""
        return (P - self.centre) / self.diag

    def query(
        self, Pn: np.ndarray, *, canonical: bool = True
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Closest surface points of normalized query points.

        Parameters
        ----------
        Pn : (q, 3) ndarray of float64
            Query points in the normalized frame.
        canonical : bool, default True
            Report points on an edge or at a vertex in the smallest-index triangle holding them
            (not needed while aligning).

        Returns
        -------
        face_ids : (q,) ndarray of int64
        barycentric : (q, 3) ndarray of float64
        corners : (q, 3, 3) ndarray of float64
            The triangles' corners, normalized frame.
        distances : (q,) ndarray of float64
            Distances in the normalized frame (fractions of the diagonal).
        """
        ans = self.scene.compute_closest_points(self._o3d.core.Tensor(Pn.astype(np.float32)))
        face_ids = ans["primitive_ids"].numpy().astype(np.int64)
        corners = self.normalize(self.V[self.F[face_ids]])  # (q, 3, 3), float64
        bary = np.clip(closest_on_triangles(Pn, *corners.transpose(1, 0, 2)), 0.0, 1.0)
        d64 = np.linalg.norm(Pn - np.einsum("qi,qij->qj", bary, corners), axis=1)
        d32 = np.linalg.norm(Pn - ans["points"].numpy().astype(np.float64), axis=1)
        bad = ~np.isfinite(d64) | (d64 > d32 + 1e-6)  # degenerate triangles: keep Open3D's answer
        if bad.any():
            logger.debug("closest points: %d degenerate triangles kept as found", bad.sum())
            bary[bad] = _hit_weights(ans)[bad]
        bary[bary < _SNAP] = 0.0
        bary /= bary.sum(axis=1, keepdims=True)
        if canonical:
            face_ids, bary = _canonical_faces(self.F, self.V.shape[0], face_ids, bary)
            corners = self.normalize(self.V[self.F[face_ids]])
        distances = np.linalg.norm(Pn - np.einsum("qi,qij->qj", bary, corners), axis=1)
        return face_ids, bary, corners, distances

    def closest(self, P: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """:func:`closest_points` in the shapes' units (same returns)."""
        face_ids, bary, _, _ = self.query(self.normalize(P))
        closest = np.einsum("qi,qij->qj", bary, self.V[self.F[face_ids]])
        return face_ids, bary, closest, np.linalg.norm(P - closest, axis=1)


def _facing_away(surface: _Surface, V2: np.ndarray, F2: np.ndarray) -> float:
    """Share of the target's area whose triangles face more than 45° off the source surface.

    Each target triangle (``V2`` as queried: after ICP) is compared with the source triangle
    closest to its centroid, face normal with face normal, either way round (a mesh wound the
    other way, or inconsistently, is the same surface); weighted by the target triangles'
    areas. Degenerate triangles on either side are left out (no normal). Face normals, not
    vertex normals: a vertex normal at a crease (a box's corner) is far from every face there,
    though the surfaces coincide.
    """
    areas_2, normals_2 = face_areas_normals(V2, F2)
    faces, _, _, _ = surface.closest(V2[F2].mean(axis=1))
    # the source triangles hit only (a 0.5M-vertex source has 1M triangles)
    areas_1, normals_1 = face_areas_normals(surface.V, surface.F[faces])
    usable = (areas_2 > 0) & (areas_1 > 0)
    total = areas_2[usable].sum()
    if not total > 0:
        return math.nan
    cos = np.abs(np.einsum("ij,ij->i", normals_2, normals_1))
    return float(areas_2[usable & (cos < math.sqrt(0.5))].sum() / total)


def _check_options(align: Any, distance: Any) -> tuple[bool, float | None]:
    if not isinstance(align, (bool, np.bool_)):
        raise TypeError(f"align must be True or False; got {align!r}")
    if distance is not None:
        if isinstance(distance, bool) or not isinstance(distance, numbers.Real):
            raise TypeError(f"max_icp_distance must be a positive number; got {distance!r}")
        distance = float(distance)
        if not (math.isfinite(distance) and distance > 0):
            raise ValueError(f"max_icp_distance must be a positive finite number; got {distance}")
    return bool(align), distance


def _surface_samples(
    V: np.ndarray, F: np.ndarray, n: int, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray]:
    """Uniform random points on a mesh's surface, with their triangle's normal.

    Parameters
    ----------
    V : (n1, 3) ndarray
        Vertices.
    F : (m1, 3) ndarray
        Triangles.
    n : int
        Number of points.
    rng : numpy.random.Generator
        Random source.

    Returns
    -------
    points : (n, 3) ndarray
    normals : (n, 3) ndarray
        Unit normals of the triangles the points lie in (point-to-plane ICP against these
        planes is exact, unlike planes through the vertices).
    """
    areas, face_normals = face_areas_normals(V, F)
    total = areas.sum()
    if not total > 0:
        raise ValueError("faces_1: every triangle is degenerate (the source has no area)")
    cdf = np.cumsum(areas / total)
    face = np.minimum(np.searchsorted(cdf, rng.random(n) * cdf[-1], side="right"), F.shape[0] - 1)
    r1, r2 = np.sqrt(rng.random(n)), rng.random(n)
    bary = np.stack([1.0 - r1, r1 * (1.0 - r2), r1 * r2], axis=1)
    return np.einsum("qi,qij->qj", bary, V[F[face]]), face_normals[face]


def _subset(n: int, at_most: int, rng: np.random.Generator) -> np.ndarray:
    """Return the sorted indices of ``at_most`` of ``n`` items drawn at random (all if fewer)."""
    return np.sort(rng.choice(n, at_most, replace=False)) if n > at_most else np.arange(n)


def _rotation(omega: np.ndarray) -> np.ndarray:
    """Rotation matrix (3, 3) of the rotation vector ``omega`` (3,) (Rodrigues)."""
    angle = float(np.linalg.norm(omega))
    if angle == 0.0:
        return np.eye(3)
    k = omega / angle
    K = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.eye(3) + math.sin(angle) * K + (1.0 - math.cos(angle)) * (K @ K)


def _fit(
    surface: _Surface, Pn: np.ndarray, T: np.ndarray, distance: float
) -> tuple[float, float, np.ndarray, np.ndarray, np.ndarray]:
    """Exact fit of transformed target points to the source surface (normalized frame).

    Returns
    -------
    fitness : float
        Fraction of points within ``distance`` of the surface.
    rmse : float
        RMS distance of those (0 when there are none).
    X : (q, 3) ndarray
        The transformed points.
    closest : (q, 3) ndarray
        Their closest surface points.
    normals : (q, 3) ndarray
        Unit normals of the triangles holding those (zero for degenerate triangles).
    """
    X = Pn @ T[:3, :3].T + T[:3, 3]
    _, bary, corners, d = surface.query(X, canonical=False)
    closest = np.einsum("qi,qij->qj", bary, corners)
    n = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    norm = np.linalg.norm(n, axis=1, keepdims=True)
    n = np.divide(n, norm, out=np.zeros_like(n), where=norm > 0)
    inlier = d < distance
    rmse = float(np.sqrt(np.mean(d[inlier] ** 2))) if inlier.any() else 0.0
    return float(inlier.mean()), rmse, X, closest, n


def _refine_on_surface(
    surface: _Surface, Pn: np.ndarray, T: np.ndarray, distance: float, *,
    iterations: int = REFINE_ITERATIONS, tolerance: float = REFINE_STEP,
) -> np.ndarray:  # fmt: skip
    """Point-to-plane ICP against the exact closest points on the source's triangles.

    Open3D's ICP matches sampled points; this last stage matches the surface itself, so a target
    lying on the source surface is put back exactly (to float precision), whatever the sampling.

    Parameters
    ----------
    surface : _Surface
        The source.
    Pn : (q, 3) ndarray
        Target points, normalized frame.
    T : (4, 4) ndarray
        Starting transform (normalized frame).
    distance : float
        Correspondence distance (fraction of the diagonal).
    iterations : int, default REFINE_ITERATIONS
        At most this many steps.
    tolerance : float, default REFINE_STEP
        Stop after a step smaller than this (rotation vector and translation).

    Returns
    -------
    (4, 4) ndarray
        The refined transform.
    """
    T = T.copy()
    for _ in range(iterations):
        _, _, X, Q, n = _fit(surface, Pn, T, distance)
        inlier = np.linalg.norm(X - Q, axis=1) < distance
        if inlier.sum() < 6:
            break
        A = np.hstack([np.cross(X, n), n])[inlier]
        r = np.einsum("ij,ij->i", Q - X, n)[inlier]
        step = np.linalg.lstsq(A, r, rcond=None)[0]
        dR = _rotation(step[:3])
        T[:3, :3] = dR @ T[:3, :3]
        T[:3, 3] = dR @ T[:3, 3] + step[3:]
        if np.linalg.norm(step) < tolerance:
            break
    return T


def _rotation_degrees(R: np.ndarray) -> float:
    """Angle of the rotation matrix ``R`` (3, 3), in degrees."""
    return math.degrees(math.acos(float(np.clip((np.trace(R) - 1) / 2, -1.0, 1.0))))


def _icp(
    V1: np.ndarray, F1: np.ndarray | None, surface: _Surface | None, V2: np.ndarray,
    centre: np.ndarray, diag: float, max_distance: float,
) -> tuple[np.ndarray, float, float, float]:  # fmt: skip
    """Rigid point-to-plane ICP of the target vertices onto the source, from the identity.

    Open3D's ICP on points sampled on the source surface (3x the distance, then the distance),
    then, for a mesh source, a point-to-plane refinement against the exact closest points.

    Parameters
    ----------
    V1 : (n1, 3) ndarray
        Source vertices.
    F1 : (m1, 3) ndarray or None
        Source triangles (None: normals are estimated from the points).
    surface : _Surface or None
        The source mesh's closest-point scene (None for a point cloud).
    V2 : (n2, 3) ndarray
        Target vertices.
    centre : (3,) ndarray
        Centre of the source's bounding box.
    diag : float
        Its diagonal.
    max_distance : float
        Correspondence distance, in the shapes' units.

    Returns
    -------
    transform : (4, 4) ndarray
        Rigid transform taking the target into the source's frame (shapes' units).
    fitness : float
        Fraction of target vertices within ``max_distance`` of the source after alignment.
    inlier_rmse : float
        RMS distance of those, in the shapes' units.
    fitness_identity : float
        The fitness before alignment. When ICP ends with a worse fit (lower fitness, or equal
        fitness and a larger RMSE) than the identity, the identity is returned.
    """
    o3d = require_open3d()
    reg = o3d.pipelines.registration
    rng = np.random.default_rng(0)
    n_samples = min(ICP_MAX_SAMPLES, max(ICP_MIN_SAMPLES, ICP_SAMPLES_PER_VERTEX * V2.shape[0]))
    if F1 is not None:
        points, normals = _surface_samples(V1, F1, n_samples, rng)
    else:
        points, normals = V1[_subset(V1.shape[0], n_samples, rng)], None
    source = o3d.geometry.PointCloud(o3d.utility.Vector3dVector((points - centre) / diag))
    if normals is not None:
        source.normals = o3d.utility.Vector3dVector(normals)
    else:
        source.estimate_normals(o3d.geometry.KDTreeSearchParamKNN(knn=20))
    Pn = (V2 - centre) / diag
    target = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(Pn))
    distance = max_distance / diag
    T = np.eye(4)
    criteria = reg.ICPConvergenceCriteria(
        relative_fitness=1e-7, relative_rmse=1e-7, max_iteration=ICP_ITERATIONS
    )
    plane = reg.TransformationEstimationPointToPlane()
    for scale in (3.0, 1.0):  # coarse to fine: 3x the distance, then the distance itself
        result = reg.registration_icp(target, source, scale * distance, T, plane, criteria)
        T = np.asarray(result.transformation, dtype=np.float64).copy()
    if surface is not None:
        T = _refine_on_surface(surface, Pn, T, distance)
        start = _fit(surface, Pn, np.eye(4), distance)[:2]
        end = _fit(surface, Pn, T, distance)[:2]
    else:
        first = reg.evaluate_registration(target, source, distance, np.eye(4))
        start = (float(first.fitness), float(first.inlier_rmse))
        end = (float(result.fitness), float(result.inlier_rmse))
    if (end[0], -end[1]) < (start[0], -start[1]):
        logger.info(
            "ICP fits worse than the identity (fitness %.3f < %.3f): the identity is kept",
            end[0], start[0],
        )  # fmt: skip
        T, end = np.eye(4), start
    T[:3, 3] = centre - T[:3, :3] @ centre + diag * T[:3, 3]  # back to the shapes' units
    return T, end[0], end[1] * diag, start[0]


def _aligned_query(
    V1: np.ndarray, F1: np.ndarray | None, surface: _Surface | None, V2: np.ndarray,
    max_icp_distance: float | None, options: dict[str, Any], notes: list[Said],
) -> np.ndarray:  # fmt: skip
    """Register the target onto the source (:func:`_icp`); return its vertices moved there.

    Records the registration in ``options["icp"]`` and adds a note when its fitness is below
    :data:`ICP_MIN_FITNESS`.
    """
    centre, diag = _frame(V1)
    max_distance = ICP_DISTANCE * diag if max_icp_distance is None else max_icp_distance
    transform, fitness, rmse, fitness_0 = _icp(V1, F1, surface, V2, centre, diag, max_distance)
    angle = _rotation_degrees(transform[:3, :3])
    options["icp"] = {
        "transformation": transform.tolist(), "fitness": fitness, "fitness_identity": fitness_0,
        "inlier_rmse": rmse, "max_correspondence_distance": max_distance,
        "rotation_degrees": angle, "translation": float(np.linalg.norm(transform[:3, 3])),
    }  # fmt: skip
    logger.info(
        "ICP: rotation %.3g°, fitness %.3f, inlier RMSE %.3g of the diagonal",
        angle, fitness, rmse / diag,
    )  # fmt: skip
    if fitness < ICP_MIN_FITNESS:
        notes.append(Said(
            "ICP fitness {fitness:.2f}: only that fraction of the target lies within "
            "{distance:.3g} (the shapes' units, {rel:.2g} of the source's bounding-box diagonal) "
            "of the source after alignment: a partial target, a pose too far from the source's "
            "for ICP, or shapes in other units (ICP does not scale: rescale the target first)",
            {"fitness": fitness, "distance": max_distance, "rel": max_distance / diag},
            "icp_fitness",
        ))  # fmt: skip
    return V2 @ transform[:3, :3].T + transform[:3, 3]


def _closest_on_source(
    V1: np.ndarray, surface: _Surface | None, query: np.ndarray
) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None, np.ndarray]:
    """Return (p2p, faces, barycentric, distances) of the query points on the source.

    On a mesh: the closest surface point and the vertex of its largest weight; on a point
    cloud: the nearest point (no faces and barycentric coordinates: None).
    """
    if surface is None:
        from scipy.spatial import cKDTree

        distances, p2p = cKDTree(V1).query(query, workers=-1)
        return p2p.astype(np.int64), None, None, distances
    faces_21, bary, _, distances = surface.closest(query)
    return surface.F[faces_21, np.argmax(bary, axis=1)], faces_21, bary, distances


def _not_aligned(
    mean_rel: float, align: bool, V2: np.ndarray, diag: float, retry: Said | str
) -> list[Said]:
    """Return the reason (in a list; empty if none) when the target lies far from the source."""
    if mean_rel <= MAX_MEAN_DISTANCE:
        return []
    return [Said(
        "the shapes are not aligned{after}: mean closest-point distance {mean:.3g} times the "
        "source's bounding-box diagonal (> {bound}). A closest-point map ({closest}) is only "
        "for shapes in the same place: {retry}otherwise use the spectral estimate ({estimate})",
        {"after": Said(" even after ICP ({align})") if align else "", "mean": mean_rel,
         "bound": MAX_MEAN_DISTANCE, "retry": _units(V2, diag) or retry}, "not_aligned",
    )]  # fmt: skip


def _misaligned(
    surface: _Surface, V2: np.ndarray, distances_rel: np.ndarray, options: dict[str, Any],
    notes: list[Said],
) -> list[Said]:  # fmt: skip
    """Return the reason (in a list; empty if none) when a rigid motion brings the target closer.

    The motion: point-to-plane iterations against the exact closest points
    (:func:`_refine_on_surface`, from the identity, correspondences up to 3x
    :data:`ICP_DISTANCE`) on at most :data:`MISALIGNMENT_SAMPLES` target vertices,
    :data:`MISALIGNMENT_ITERATIONS` steps. ``distances_rel`` are the target's closest-point
    distances (fractions of the diagonal). ``options["misalignment"]`` gets the mean distance
    of the sampled vertices without and with the motion (``mean_distance_rel``,
    ``mean_distance_rel_moved``), its ``rotation_degrees`` and ``translation_rel`` (at the
    source's bounding-box centre); a smaller gain (above :data:`MISALIGNED_NOTE`) is a note.
    """
    sample = _subset(V2.shape[0], MISALIGNMENT_SAMPLES, np.random.default_rng(0))
    Pn = surface.normalize(V2[sample])
    T = _refine_on_surface(
        surface, Pn, np.eye(4), 3.0 * ICP_DISTANCE,
        iterations=MISALIGNMENT_ITERATIONS, tolerance=MISALIGNMENT_STEP,
    )  # fmt: skip
    before = float(distances_rel[sample].mean())
    after = float(surface.query(Pn @ T[:3, :3].T + T[:3, 3], canonical=False)[3].mean())
    degrees, shift = _rotation_degrees(T[:3, :3]), float(np.linalg.norm(T[:3, 3]))
    options["misalignment"] = {
        "mean_distance_rel": before, "mean_distance_rel_moved": after,
        "rotation_degrees": degrees, "translation_rel": shift,
    }  # fmt: skip
    logger.debug(
        "closest map: a rigid motion (%.3g°, shift %.3g of the diagonal) takes the mean "
        "distance from %.3g to %.3g of the diagonal", degrees, shift, before, after,
    )  # fmt: skip
    gain = before - after
    explained = after < MISALIGNED_RATIO * before  # the distance is mostly the motion
    values = {"degrees": degrees, "shift": shift, "before": before, "after": after}
    motion = "a rigid motion (a {degrees:.2g}° turn, a shift of {shift:.2g} of the diagonal)"
    if explained and gain > MISALIGNED_GAIN:
        return [Said(
            motion + " brings the target from {before:.3g} to {after:.3g} of the source's "
            "diagonal on average: the shapes are not quite aligned, and closest points slide "
            "along the surface; pass {align} to register them first", values, "misaligned",
        )]  # fmt: skip
    if explained and gain > MISALIGNED_NOTE:
        notes.append(Said(
            motion + " would bring the target from {before:.3g} to {after:.3g} of the source's "
            "diagonal: {align} registers them exactly", values, "misaligned_note",
        ))  # fmt: skip
    return []


def _coverage(
    V1: np.ndarray, V2: np.ndarray, p2p: np.ndarray, retry: Said | str
) -> tuple[float, float, list[Said]]:
    """Return (coverage, coverage_ratio, reasons): the distinct source positions hit.

    Positions, not vertices: a mesh read with its UVs has copies of the vertices along the
    seams (Spot: 17564 vertices at 2930 positions), which are no other points. The reason
    (below :data:`MIN_COVERAGE` of the smaller shape) says the target's vertices crowd.
    """
    at_1 = _positions(V1)
    distinct_1 = int(at_1.max()) + 1
    hit = np.unique(at_1[p2p]).size
    smaller = min(distinct_1, int(_positions(V2).max()) + 1)
    if hit >= MIN_COVERAGE * smaller:
        return hit / distinct_1, hit / smaller, []
    return hit / distinct_1, hit / smaller, [Said(
            "the target's vertices crowd onto {hit} source vertices ({share:.2f} of the smaller "
            "shape, < {bound}): the shapes are not in the same place or not the same pose. A "
            "closest-point map ({closest}) is only for shapes in the same place: {retry}"
            "otherwise use the spectral estimate ({estimate}; with {partial} when the target "
            "is a part of the source)",
            {"hit": hit, "share": hit / smaller, "bound": MIN_COVERAGE, "retry": retry},
            "crowded",
        )]  # fmt: skip


def _icp_doubts(turn: float, mean_rel: float, facing: float) -> list[Said]:
    """Return the reason (in a list; empty if none) when ICP turned the target wrongly.

    A turn above :data:`ICP_DOUBTFUL_TURN` that leaves the target farther than
    :data:`MEAN_DISTANCE_NOTE` from the source, or facing away from it on more than
    :data:`MAX_FACING_AWAY` of its area.
    """
    if turn > ICP_DOUBTFUL_TURN and mean_rel > MEAN_DISTANCE_NOTE:
        return [Said(
            "ICP turned the target by {turn:.3g}° and it still lies {mean:.3g} of the source's "
            "bounding-box diagonal from the source on average (> {bound}): the shapes are not "
            "copies of one surface (another pose, other geometry), or the target was turned too "
            "far for ICP, so that turn, and the closest points, may be wrong. If they were "
            "already aligned, match {no_align}; if the target is a turned copy, turn it "
            "roughly into place first; otherwise use the spectral estimate ({estimate})",
            {"turn": turn, "mean": mean_rel, "bound": MEAN_DISTANCE_NOTE}, "icp_far",
        )]  # fmt: skip
    if turn > ICP_DOUBTFUL_TURN and facing > MAX_FACING_AWAY:
        return [Said(
            "ICP turned the target by {turn:.3g}°, but {facing:.2f} of its area faces more than "
            "45° away from the source surface it lies on (> {bound}): ICP stopped in a wrong "
            "place (the target turned too far for it, or a part that fits elsewhere); turn the "
            "target roughly into place first, or use the spectral estimate ({estimate})",
            {"turn": turn, "facing": facing, "bound": MAX_FACING_AWAY}, "icp_facing",
        )]  # fmt: skip
    return []


def _distance_notes(
    mean_rel: float, max_rel: float, retry: Said | str, suspect: bool
) -> list[Said]:
    """Return the notes on the closest-point distances (fractions of the source's diagonal)."""
    values = {"mean": mean_rel, "max": max_rel, "retry": retry}
    notes = [Said(
        "closest-point distance: mean {mean:.3g}, max {max:.3g} times the source's bounding-box "
        "diagonal", values, "distances",
    )]  # fmt: skip
    if MEAN_DISTANCE_NOTE < mean_rel <= MAX_MEAN_DISTANCE:
        notes.append(Said(
            "the target lies {mean:.3g} of the diagonal from the source on average: the shapes "
            "differ in geometry or are slightly misaligned ({retry}a closest-point map needs "
            "shapes in the same place; shapes of other kinds or in other poses match by "
            "{estimate})", values, "far_on_average",
        ))  # fmt: skip
    if max_rel > MAX_DISTANCE_NOTE and not suspect:
        notes.append(Said(
            "some target vertices lie far from the source (up to {max:.3g} of its diagonal): "
            "parts of the target may be missing from the source", values, "far_vertices",
        ))  # fmt: skip
    return notes


def _area_ratio(
    V1: np.ndarray, F1: np.ndarray | None, V2: np.ndarray, F2: np.ndarray | None, notes: list[Said]
) -> float:
    """Return target area / source area (NaN without both shapes' triangles); a note if far off."""
    if F2 is None or F1 is None:
        return math.nan
    a1, a2 = (face_areas_normals(V, F)[0].sum() for V, F in ((V1, F1), (V2, F2)))
    area_ratio = float(a2 / a1) if a1 > 0 else math.nan
    if not 1 / AREA_RATIO_NOTE <= area_ratio <= AREA_RATIO_NOTE:
        notes.append(Said(
            "the target's area is {ratio:.3g} times the source's: not the same surface "
            "(different units, or a partial shape)", {"ratio": area_ratio}, "area_ratio",
        ))  # fmt: skip
    return area_ratio


def _closest_quality(
    V1: np.ndarray, F1: np.ndarray | None, V2: np.ndarray, F2: np.ndarray | None,
    surface: _Surface | None, query: np.ndarray, p2p: np.ndarray, distances: np.ndarray,
    options: dict[str, Any], notes: list[Said],
) -> MapQuality:  # fmt: skip
    """Return the quality report of a closest-point map (see :func:`closest_correspondence`).

    ``p2p`` and ``distances`` are those of the target's vertices as queried (``query``: after
    ICP); ``options`` gets the distances, ``facing_away`` and ``misalignment``; ``notes``
    holds those made so far (ICP's).
    """
    align = bool(options["align"])
    diag = _frame(V1)[1]
    mean_rel = options["mean_distance_rel"] = float(distances.mean() / diag)
    max_rel = options["max_distance_rel"] = float(distances.max() / diag)
    facing = math.nan
    if surface is not None and F2 is not None:
        facing = options["facing_away"] = _facing_away(surface, query, F2)
    retry = "" if align else Said("pass {align} if they are almost aligned; ")
    reasons = _not_aligned(mean_rel, align, V2, diag, retry)
    misaligned = []
    if surface is not None and not align:
        misaligned = _misaligned(surface, V2, distances / diag, options, notes)
    coverage, coverage_ratio, crowded = _coverage(V1, V2, p2p, retry)
    if align and not reasons:
        reasons = _icp_doubts(float(options["icp"]["rotation_degrees"]), mean_rel, facing)
    if reasons:  # not aligned at all: that reason names the fixes
        notes.extend(misaligned)
    else:
        reasons.extend([*misaligned, *crowded])
    notes.extend(_distance_notes(mean_rel, max_rel, retry, bool(reasons)))
    area_ratio = _area_ratio(V1, F1, V2, F2, notes)
    nan = math.nan  # no functional map: no orthogonality, inconsistency or reversed triangles
    return MapQuality(
        coverage=coverage, coverage_ratio=coverage_ratio, orthogonality=nan, inconsistency=nan,
        reversed_fraction=nan, area_ratio=area_ratio, suspect=bool(reasons),
        reasons=tuple(reasons), notes=tuple(notes),
    )  # fmt: skip


def closest_correspondence(
    vertices_1: Any, faces_1: Any, vertices_2: Any, *, faces_2: Any = None, align: bool = False,
    max_icp_distance: float | None = None,
) -> Correspondence:  # fmt: skip
    """Map every target vertex to the closest point on the source surface (aligned shapes).

    For shapes that already occupy the same place (a scan and its simplified or remeshed
    copy): no eigenbasis is computed. With ``align=True`` a rigid point-to-plane ICP first
    brings an *almost* aligned target onto the source; shapes that are not aligned at all need
    the spectral estimate (the report marks the map suspect then).

    Parameters
    ----------
    vertices_1 : (n1, 3) array_like of float
        Source vertices.
    faces_1 : (m1, 3) array_like of int or None
        Source triangles; None for a point-cloud source (nearest source point, no barycentric
        coordinates).
    vertices_2 : (n2, 3) array_like of float
        Target vertices.
    faces_2 : (m2, 3) array_like of int, optional
        Target triangles: used for the area ratio and the target's normals in the quality
        report (``facing_away``).
    align : bool, default False
        Rigidly register the target onto the source (ICP from the identity) before the query.
    max_icp_distance : float, optional
        ICP correspondence distance in the shapes' units; default 5 % of the source's
        bounding-box diagonal. The ICP runs at 3x this distance, then at this distance.

    Returns
    -------
    Correspondence
        ``method="closest"``; ``p2p_21`` (n2,) is the source vertex of largest barycentric weight
        in the closest triangle (the nearest source point for a point cloud), ``faces_21`` (n2,)
        and ``barycentric_21`` (n2, 3) give the closest point itself (weights of the triangle's
        vertices in face order). ``options`` (JSON-serializable) holds ``align``, ``source``
        (``"mesh"`` or ``"points"``), ``max_icp_distance`` (as given), ``mean_distance_rel`` and
        ``max_distance_rel`` (closest-point distances as fractions of the source's
        bounding-box diagonal) and, when ``align=True``, ``icp``: ``transformation`` (4x4 list,
        taking the target into the source's frame: the query points are
        ``V2 @ T[:3, :3].T + T[:3, 3]``), ``fitness`` and ``inlier_rmse`` (shapes' units) after
        alignment, ``fitness_identity`` before it, ``max_correspondence_distance`` (shapes'
        units), ``rotation_degrees`` and ``translation``; without ``align`` and with a mesh
        source, ``misalignment``: the mean distance before (``mean_distance_rel``) and after
        (``mean_distance_rel_moved``) the rigid motion fitted to the closest points, its
        ``rotation_degrees`` and ``translation_rel``; with both shapes' triangles,
        ``facing_away``: the share of the target's area whose triangles face more than 45° off
        the source triangle closest to their centroids. The quality report is suspect when the
        mean distance exceeds :data:`MAX_MEAN_DISTANCE` of the source's diagonal, when that
        rigid motion would bring the target much closer (:data:`MISALIGNED_RATIO`,
        :data:`MISALIGNED_GAIN`: a turned or moved copy; the fix is ``align=True``) or
        when the target's vertices crowd onto few source vertices (:data:`MIN_COVERAGE`),
        or when ICP turned the target and left it far from the source or facing away from it
        (:data:`ICP_DOUBTFUL_TURN`, :data:`MAX_FACING_AWAY`: ICP stopped in a wrong place);
        orthogonality, inconsistency and reversed_fraction are NaN (no functional map),
        area_ratio too unless ``faces_2`` is given.

    Raises
    ------
    ValueError
        On badly shaped arrays, out-of-range faces or a non-positive ``max_icp_distance``
        (the message names the argument).
    TypeError
        On non-numeric arrays or a non-boolean ``align``.
    """
    t0 = time.perf_counter()
    V1 = as_vertices(vertices_1, name="vertices_1")
    F1 = None if faces_1 is None else as_faces(faces_1, V1.shape[0], name="faces_1")
    V2 = as_vertices(vertices_2, name="vertices_2")
    F2 = None if faces_2 is None else as_faces(faces_2, V2.shape[0], name="faces_2")
    align, max_icp_distance = _check_options(align, max_icp_distance)
    options: dict[str, Any] = {
        "align": align, "source": "points" if F1 is None else "mesh",
        "max_icp_distance": max_icp_distance,
    }  # fmt: skip
    notes: list[Said] = []
    surface = None if F1 is None else _Surface(V1, F1)
    query = _aligned_query(V1, F1, surface, V2, max_icp_distance, options, notes) if align else V2
    p2p, faces_21, bary, distances = _closest_on_source(V1, surface, query)
    quality = _closest_quality(V1, F1, V2, F2, surface, query, p2p, distances, options, notes)
    logger.info(
        "closest map: %d target vertices onto %d source vertices in %.2f s, mean distance "
        "%.3g times the diagonal", V2.shape[0], V1.shape[0], time.perf_counter() - t0,
        options["mean_distance_rel"],
    )  # fmt: skip
    if quality.suspect:
        warn(logger, quality.reasons[0])
    return Correspondence(
        p2p_21=p2p, n_source=V1.shape[0], method="closest", options=options, quality=quality,
        faces_21=faces_21, barycentric_21=bary,
        signatures=(shape_signature(vertices_1), shape_signature(vertices_2)),
    )  # fmt: skip
