"""Partial functional maps: a part of a shape (a cut, a one-sided scan) onto the whole shape.

When the target is a part of the source, in the same units, the functional map that pulls
source functions back to the target is the *restriction* operator. It is not orthogonal: its
target eigenfunction ``ψ_j`` is matched by the source eigenfunctions of about the same
frequency, and a part of area ratio ``r = area(target) / area(source)`` has ``1/r`` times as
many eigenvalues below a given frequency as its part of the whole (Weyl's law), so the map is
a *slanted* diagonal band of rank about ``r k`` (Rodolà et al. 2017). Everything here works on
eigenbases of both shapes expressed in the same units (:func:`rescaled`): eigenvalues can then
be compared directly, which gives the slant without estimating ``r``.

Method (what :func:`fit_partial_fmap`, :func:`partial_zoomout` and :func:`partial_p2p` do):

1. Descriptors that agree on a part and on the whole: mean and Gaussian curvature diffused
   at four scales (:func:`curvature_descriptors`, weighted :data:`CURVATURE_WEIGHT`), plus
   wave kernel signatures at *common* energies, not normalized per shape (Rodolà et al. use
   local SHOT descriptors for the same reason). Measured on true pairs of a FAUST cut and a
   blob cut: correlation 0.97-1.0 for the curvatures, -0.3 to 0.99 for the wave kernel
   (which is not local at the bandwidth of ~100 eigenfunctions): with the wave kernel alone
   the map error of a blob cut was 0.35-0.44, with both 0.003-0.025.
2. A descriptor fit of the rectangular map ``C`` (k2+1, k1+1), ``k1`` chosen so that the
   source eigenvalues reach the target's largest one: data term ``‖C A − B‖²``, the
   commutativity with the Laplacians ``‖C Λ₁ − Λ₂ C‖²`` (in common units its zero set is the
   slanted diagonal: it plays the role of Rodolà's slanted mask), descriptor commutativity,
   the orientation-preserving term of Ren et al. 2018 (all hold for a restriction) and
   ``‖C Cᵀ − I‖²`` (a restriction has orthonormal rows; without it the row of the constant
   grows unboundedly).
3. A *partial ZoomOut*: alternate the point map (each target point to its nearest row of
   ``Φ Cᵀ``; the rows of source points outside the part are near zero, so they are not
   chosen) and the least-squares map of that point map, growing the target size by one and
   the source size along the slant at each step.
   The chosen map is then refined by geodesic distances (:func:`geodesic_refine`: each target
   vertex placed by its distances to the anchors the map keeps right, which pulls back regions
   sent to the wrong place) and the partial ZoomOut is run again from that map; its point map
   is polished with twice the slant's target functions (:func:`partial_polish`), after the
   checks.
4. The source membership ``v = Φ Cᵀ 1``: the smooth indicator of the part on the source
   (Rodolà's ``v``, here read off the map rather than optimized), whose area is the overlap.

5. A check without ground truth (:func:`geodesic_distortion`): a part of a near-isometric
   shape keeps geodesic distances, so the mean change of the distances between target samples
   and between their images ranks the refined starts and, on the final map, flags a map that
   sends a region to the wrong place or a target that is no part of the source;
   :func:`map_stretch` (mapped edge lengths) flags the tears of a misplaced region too.

This replaces the alternation of C with a TV-regularized membership of the original
algorithm by the ZoomOut refinement; it is not shown to be as good as the original on every
cut: ``scripts/eval_partial.py`` measures it (the benchmarks page, "Partial shapes").

References
----------
.. [1] E. Rodolà, L. Cosmo, M. M. Bronstein, A. Torsello, D. Cremers, "Partial Functional
   Correspondence", Computer Graphics Forum 36(1), 2017.
.. [2] S. Melzi et al., "ZoomOut: Spectral Upsampling for Efficient Shape Correspondence",
   ACM TOG 38(6), 2019.
.. [3] J. Ren et al., "Continuous and Orientation-preserving Correspondences via Functional
   Maps", ACM TOG 37(6), 2018.
"""

from __future__ import annotations

import dataclasses
import logging
import math
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from typing import Any

import numpy as np
import scipy.sparse as sp
import scipy.sparse.csgraph as csgraph
import scipy.sparse.linalg as sla

from ._processes import side_by_side
from ._threads import one_blas_thread
from ._validation import check_int
from .correspondence import check_p2p, nearest_neighbors
from .descriptors import _kernel_signature, wks_energies
from .fmap import _energy_of, _landmark_pairs, _LeadingFits, _scaled, _shape_terms, farthest_points
from .geometry import edge_graph, unique_edges
from .spectrum import EigenBasis

__all__ = [
    "DistortionProbe",
    "boundary_length",
    "distortion_probe",
    "fit_partial_fmap",
    "fit_partial_fmaps",
    "geodesic_distortion",
    "geodesic_features",
    "geodesic_refine",
    "map_stretch",
    "membership",
    "partial_descriptors",
    "partial_p2p",
    "partial_polish",
    "partial_polish_fit",
    "partial_zoomout",
    "polish_target_size",
    "rescaled",
    "slant",
]

logger = logging.getLogger(__name__)


def rescaled(eig: EigenBasis, area: float) -> EigenBasis:
    """Return the same eigenbasis on the shape centred and divided by ``sqrt(area)``.

    With ``area`` the *source's* area for both shapes, the two bases are in the same units
    and the source has unit area (the target keeps its area ratio).

    Parameters
    ----------
    eig : EigenBasis
    area : float
        The reference area (positive).

    Returns
    -------
    EigenBasis
        A new basis (no digest): eigenvalues times ``area``, eigenfunctions times
        ``sqrt(area)``, mass divided by ``area``.
    """
    if not (area > 0 and math.isfinite(area)):
        raise ValueError(f"area must be positive and finite; got {area}")
    return _scaled(eig, area)


def slant(evals_1: np.ndarray, evals_2: np.ndarray, k2: int) -> int:
    """Source size matched by the first ``k2`` target eigenfunctions (same units).

    Parameters
    ----------
    evals_1, evals_2 : (k1+1,), (k2'+1,) ndarray
        Source and target eigenvalues in the same units, constant first.
    k2 : int
        Non-constant target eigenfunctions.

    Returns
    -------
    int
        The number of non-constant source eigenvalues not above ``evals_2[k2]`` (at least 1,
        at most ``len(evals_1) - 1``): about ``k2 / r`` for a part of area ratio ``r``.
    """
    count = int(np.searchsorted(evals_1, evals_2[k2], side="right")) - 1
    return max(1, min(count, evals_1.shape[0] - 1))


def boundary_length(
    vertices: np.ndarray, faces: np.ndarray | None, *, longest: bool = False
) -> float:
    """Length of a mesh's boundary edges (edges of one triangle only), or of its longest curve.

    Parameters
    ----------
    vertices : (n, 3) ndarray
    faces : (m, 3) ndarray of int or None
        ``None`` (a point cloud): 0.
    longest : bool, default False
        The length of the longest boundary curve only (the boundary edges' connected pieces):
        a cut leaves long curves, a scan's holes short ones.

    Returns
    -------
    float
    """
    if faces is None or len(faces) == 0:
        return 0.0
    unique, counts = unique_edges(faces)
    single = unique[counts == 1]
    V = np.asarray(vertices, dtype=np.float64)
    lengths = np.linalg.norm(V[single[:, 0]] - V[single[:, 1]], axis=1)
    if not longest or single.size == 0:
        return float(lengths.sum())
    n = V.shape[0]
    graph = sp.coo_matrix((np.ones(len(single)), (single[:, 0], single[:, 1])), shape=(n, n))
    _, piece = csgraph.connected_components(graph, directed=False)
    return float(np.bincount(piece[single[:, 0]], weights=lengths).max())


def map_stretch(
    p2p_21: np.ndarray, vertices_1: np.ndarray, vertices_2: np.ndarray, faces_2: np.ndarray | None
) -> float:
    """How much a point map tears the target apart: mapped edge length over edge length.

    ``Σ_e ‖x₁(π(i)) − x₁(π(j))‖ / Σ_e ‖x₂(i) − x₂(j)‖`` over the target's edges ``e = (i, j)``,
    both shapes in the same units. A continuous map of a near-isometric part is about 1 (a
    nearest-vertex map is a staircase, but a path's image has about the path's length,
    whatever the two resolutions); every place where the map jumps (a limb sent to the other
    limb, a piece turned over) adds the length of the jump. Measured on the final partial maps
    of ``scripts/eval_partial.py`` (FAUST, remeshed FAUST, TOSCA centaurs): right maps
    1.03-1.23, maps wrong on a large region 1.55-1.88 (see
    :data:`o3d_ofp.workflows.quality.MAX_STRETCH`).

    Parameters
    ----------
    p2p_21 : (n2,) ndarray of int
        For every target vertex, its source vertex.
    vertices_1, vertices_2 : (n1, 3), (n2, 3) ndarray
        Source and target vertices, same units.
    faces_2 : (m2, 3) ndarray of int or None
        Target triangles; ``None`` (a point cloud): NaN.

    Returns
    -------
    float
    """
    if faces_2 is None or len(faces_2) == 0:
        return math.nan
    edges = unique_edges(faces_2)[0]
    V1 = np.asarray(vertices_1, dtype=np.float64)
    V2 = np.asarray(vertices_2, dtype=np.float64)
    p2p = np.asarray(p2p_21, dtype=np.int64)
    length = np.linalg.norm(V2[edges[:, 0]] - V2[edges[:, 1]], axis=1).sum()
    mapped = np.linalg.norm(V1[p2p[edges[:, 0]]] - V1[p2p[edges[:, 1]]], axis=1).sum()
    return float(mapped / length) if length > 0 else math.nan


def geodesic_distortion(
    p2p_21: np.ndarray,
    vertices_1: np.ndarray,
    faces_1: np.ndarray | None,
    vertices_2: np.ndarray,
    faces_2: np.ndarray | None,
    *,
    samples: int = 40,
) -> float:
    """Mean change of geodesic distances under a point map, relative to the mean distance.

    ``mean |d₂(a, b) − d₁(π a, π b)| / mean d₂(a, b)`` over pairs of ``samples`` farthest-point
    target samples, with ``d`` the shortest-path distance along the mesh edges (on both shapes,
    so its overestimate of the geodesic cancels to first order). A map of a part onto the
    same kind of shape (a near-isometry, same units) keeps distances: measured 0.07-0.16 on
    correct maps of ``scripts/eval_partial.py``; a map that sends a region to the wrong place
    (a limb onto another) changes the distances from that region, but a shell turned onto
    another of about the same shape (a body's back onto its front) may change them little.

    Parameters
    ----------
    p2p_21 : (n2,) ndarray of int
        For every target vertex, its source vertex.
    vertices_1, faces_1, vertices_2, faces_2
        Source and target meshes, same units. ``None`` faces (a point cloud): NaN.
    samples : int, default 40
        Target samples (Dijkstra runs from each, on both shapes).

    Returns
    -------
    float
    """
    probe = distortion_probe(vertices_1, faces_1, vertices_2, faces_2, samples=samples)
    return math.nan if probe is None else probe.distortions([p2p_21])[0]


@dataclasses.dataclass(frozen=True, eq=False)
class DistortionProbe:
    """What :func:`geodesic_distortion` measures maps between two meshes against.

    Made once by :func:`distortion_probe` for every map between the same two shapes (the
    target's samples and their distances, computed once for all of them).

    Attributes
    ----------
    graph_1 : (n1, n1) scipy.sparse.csr_matrix
        The source's edge graph (edge lengths).
    samples_2 : (s,) ndarray of int64
        The target's farthest-point samples.
    distances_2 : (s, s) ndarray
        Their edge-path distances on the target (``inf`` between pieces not connected).
    """

    graph_1: sp.csr_matrix
    samples_2: np.ndarray
    distances_2: np.ndarray

    def distortions(self, p2ps_21: Sequence[np.ndarray]) -> list[float]:
        """Return the geodesic distortion of each point map (:func:`geodesic_distortion`).

        Parameters
        ----------
        p2ps_21 : sequence of (n2,) ndarray of int
            Point maps: for every target vertex, its source vertex.

        Returns
        -------
        list of float
        """
        d2 = self.distances_2
        found = []
        for p2p_21 in p2ps_21:
            s1 = np.asarray(p2p_21, dtype=np.int64)[self.samples_2]
            d1 = csgraph.dijkstra(self.graph_1, directed=False, indices=s1)[:, s1]
            ok = np.isfinite(d1) & np.isfinite(d2)  # pieces not connected (islands): left out
            scale = d2[ok].mean() if ok.any() else 0.0
            found.append(float(np.abs(d1[ok] - d2[ok]).mean() / scale) if scale > 0 else math.nan)
        return found


def distortion_probe(
    vertices_1: np.ndarray,
    faces_1: np.ndarray | None,
    vertices_2: np.ndarray,
    faces_2: np.ndarray | None,
    *,
    samples: int = 40,
) -> DistortionProbe | None:
    """Return the :class:`DistortionProbe` of two meshes; None if either has no faces.

    Parameters
    ----------
    vertices_1, faces_1, vertices_2, faces_2, samples
        As in :func:`geodesic_distortion`.

    Returns
    -------
    DistortionProbe or None
        None for a point cloud (its distortion is unknown: NaN).
    """
    if faces_1 is None or faces_2 is None or len(faces_1) == 0 or len(faces_2) == 0:
        return None
    V1 = np.asarray(vertices_1, dtype=np.float64)
    V2 = np.asarray(vertices_2, dtype=np.float64)
    s2 = farthest_points(V2, min(samples, V2.shape[0]))
    d2 = csgraph.dijkstra(edge_graph(V2, faces_2), directed=False, indices=s2)[:, s2]
    return DistortionProbe(edge_graph(V1, faces_1), np.asarray(s2, dtype=np.int64), d2)


#: Target anchors of :func:`geodesic_refine` (farthest-point samples): on a unit-area shape
#: they are about 0.1 apart, finer than the limbs of the shapes of scripts/eval_partial.py.
GEODESIC_ANCHORS = 100
#: Fraction of the anchors :func:`geodesic_refine` trusts (those whose distances to the other
#: anchors change least). Measured from the chosen maps of the 8 cuts of scripts/eval_partial.py
#: (3-40 % of the target wrongly mapped): with 50 %, errors 0.037-0.053 on the 7 cuts whose map
#: was right on most of the part (from 0.03-0.25). In a variant with Gaussian-weighted distances,
#: 30 % was worse than 50 % on 5 cuts (too few anchors on some limbs) and 80 % better on 6 but
#: worse on the cut whose map was 40 % wrong: a wrong map needs the stricter choice.
GEODESIC_KEEP = 0.5


def geodesic_refine(
    p2p_21: np.ndarray,
    vertices_1: np.ndarray,
    faces_1: np.ndarray,
    vertices_2: np.ndarray,
    faces_2: np.ndarray,
    *,
    anchors: int = GEODESIC_ANCHORS,
    keep: float = GEODESIC_KEEP,
    iterations: int = 3,
    queries: np.ndarray | None = None,
) -> np.ndarray:
    """Re-map every target vertex by its geodesic distances to the anchors the map keeps right.

    A part of a near-isometric shape keeps geodesic distances. Anchors (farthest-point target
    samples) are ranked by how much the map changes their distances to the other anchors
    (``mean_j |d₁(π a, π b_j) − d₂(a, b_j)|`` over ``mean_j d₂(a, b_j)``); the ``keep``
    fraction that changes them least is trusted, and each target vertex ``x`` goes to the
    source vertex ``y`` whose distances to the trusted anchors' images are nearest to those of
    ``x`` to the anchors (least squares: a nearest-neighbour search on the distance vectors).
    Repeated ``iterations`` times. A region sent to the wrong place (a limb onto another, a
    piece turned over) is pulled back by the anchors mapped right; the result is as precise as
    the shortest-path distances along the edges (``d`` on both shapes, as in
    :func:`geodesic_distortion`) and the isometry allow: measured 0.022-0.039 (map error over
    sqrt(source area)) from the true maps of the cuts of ``scripts/eval_partial.py``, so a
    spectral refinement follows it (:class:`o3d_ofp.workflows.partial.PartialMatch`).
    Cost: ``anchors`` Dijkstra runs on the target, and on the source at most ``anchors`` per
    iteration (the distances from a source vertex are computed once); the iterations re-map
    the anchors only, and one ``anchors``-dimensional nearest-neighbour search re-maps every
    target vertex (or the ``queries``) at the end; memory ``anchors × n1`` floats per iteration
    (80 MB for a 100k-vertex source).

    Parameters
    ----------
    p2p_21 : (n2,) ndarray of int
        For every target vertex, its source vertex: right on most of the part.
    vertices_1, faces_1 : (n1, 3) ndarray, (m1, 3) ndarray of int
        Source (whole) mesh.
    vertices_2, faces_2 : (n2, 3) ndarray, (m2, 3) ndarray of int
        Target (part) mesh, in the source's units.
    anchors : int, default GEODESIC_ANCHORS
        Target samples (two Dijkstra runs from each per iteration).
    keep : float, default GEODESIC_KEEP
        Fraction of the anchors trusted, in (0, 1].
    iterations : int, default 3
    queries : (q,) ndarray of int, optional
        Re-map only these target vertices (default: all). The iterations re-map the anchors
        alone, so the result for a vertex does not depend on which others are queried.

    Returns
    -------
    (n2,) or (q,) ndarray of int64
        The refined ``p2p_21`` (of the ``queries``, when given).
    """
    f1, f2 = geodesic_features(
        p2p_21, vertices_1, faces_1, vertices_2, faces_2, anchors=anchors, keep=keep,
        iterations=iterations,
    )  # fmt: skip
    return nearest_neighbors(f1.T, (f2 if queries is None else f2[:, queries]).T)


def geodesic_features(
    p2p_21: np.ndarray,
    vertices_1: np.ndarray,
    faces_1: np.ndarray,
    vertices_2: np.ndarray,
    faces_2: np.ndarray,
    *,
    anchors: int = GEODESIC_ANCHORS,
    keep: float = GEODESIC_KEEP,
    iterations: int = 3,
) -> tuple[np.ndarray, np.ndarray]:
    """Compute the distance features :func:`geodesic_refine` matches (same parameters).

    Returns
    -------
    f1 : (t, n1) ndarray
        Distances of every source vertex to the trusted anchors' images.
    f2 : (t, n2) ndarray
        Distances of every target vertex to the trusted anchors; a target vertex ``i`` goes to
        the source vertex whose column of ``f1`` is nearest to column ``i`` of ``f2``.
    """
    if not (0 < keep <= 1):
        raise ValueError(f"keep must be in (0, 1]; got {keep}")
    iterations = check_int(iterations, name="iterations", minimum=1)
    V1 = np.asarray(vertices_1, dtype=np.float64)
    V2 = np.asarray(vertices_2, dtype=np.float64)
    p2p = np.array(p2p_21, dtype=np.int64)
    n_anchors = check_int(anchors, name="anchors", minimum=2)
    s2 = farthest_points(V2, min(n_anchors, V2.shape[0]))
    images = p2p[s2]  # the map enters through the anchors' images only
    graph_1, graph_2 = edge_graph(V1, faces_1), edge_graph(V2, faces_2)
    # The target's runs and those from the anchors' first images are independent: side by
    # side (SciPy's Dijkstra holds the GIL, so in processes).
    first = np.unique(images)
    d2, found = side_by_side(
        [lambda: csgraph.dijkstra(graph_2, directed=False, indices=s2),
         lambda: csgraph.dijkstra(graph_1, directed=False, indices=first)],
        what="shortest paths", memory_each=24.0 * s2.size * max(V1.shape[0], V2.shape[0]),
    )  # fmt: skip
    # Unreachable pieces (islands): a distance far beyond the shape's, the same on both sides.
    far = 10.0 * float(np.max(d2[np.isfinite(d2)], initial=1.0))
    # distances from a source vertex: computed once
    rows: dict[int, np.ndarray] = dict(zip(first.tolist(), found, strict=True))
    for i in range(iterations):
        new = np.unique(images[[int(v) not in rows for v in images]])
        if new.size:
            found = csgraph.dijkstra(graph_1, directed=False, indices=new)
            rows.update((int(v), row) for v, row in zip(new, found, strict=True))
        d1 = np.stack([rows[int(v)] for v in images])
        pair_1, pair_2 = d1[:, images], d2[:, s2]
        ok = np.isfinite(pair_1) & np.isfinite(pair_2)
        change = np.where(ok, np.abs(pair_1 - pair_2), 0.0).sum(axis=1)
        mean = np.where(ok, pair_2, 0.0).sum(axis=1)
        score = np.where(mean > 0, change / np.maximum(mean, 1e-300), np.inf)
        trusted = np.argsort(score, kind="stable")[: max(2, math.ceil(keep * s2.size))]
        f1 = np.where(np.isfinite(d1[trusted]), d1[trusted], far)
        f2 = np.where(np.isfinite(d2[trusted]), d2[trusted], far)
        if i < iterations - 1:  # the next iteration needs the anchors' new images only
            images = nearest_neighbors(f1.T, f2[:, s2].T)
    return f1, f2


#: Weight of the curvature descriptors against the wave kernel's (each column has unit norm on
#: the source). Measured on a blob cut (fits of 9 and 16 functions + ZoomOut): weight 1 gave
#: errors 0.03, weight 5 gave 0.002-0.007.
CURVATURE_WEIGHT = 5.0


#: Diffusion times (in units of the source's area) of the curvature descriptors: lengths
#: sqrt(t) from 2 % to 17 % of sqrt(area).
CURVATURE_SCALES = (0.0005, 0.002, 0.008, 0.03)


def curvature_descriptors(
    eig: EigenBasis, *, scales: tuple[float, ...] = CURVATURE_SCALES
) -> np.ndarray:
    """Mean and Gaussian curvature, diffused at several scales: local descriptors.

    ``|H| = ‖L x‖ / (2 m)`` (the cotangent Laplacian of the positions) and the angle defect
    ``K = (2π − Σθ) / m``, set to 0 on boundary vertices (where both formulas measure the
    boundary instead), each smoothed by one implicit heat step ``(M + t L) f_t = M f``. They
    depend on the geometry near a point only, so they agree on a part and on the whole away
    from the cut, unlike spectral descriptors at the bandwidth of ~100 eigenfunctions
    (measured, FAUST and a bumpy blob cut by a plane: correlation 0.97-1.0 on true pairs,
    against -0.3 to 0.99 for the wave kernel at common energies).

    Parameters
    ----------
    eig : EigenBasis
        A mesh's eigenbasis (its stiffness, mass, vertices and faces are used), in the units
        the scales refer to (:func:`rescaled`).
    scales : tuple of float
        Diffusion times.

    Returns
    -------
    (n, 2 len(scales)) ndarray
    """
    V, F, M, L = eig.vertices, eig.faces, eig.mass, eig.stiffness
    n = V.shape[0]
    safe = np.where(M > 0, M, 1.0)
    H = 0.5 * np.linalg.norm(L @ V, axis=1) / safe
    angles = np.zeros(n)
    if F is None:
        K = np.zeros(n)
    else:
        for i in range(3):
            a = V[F[:, (i + 1) % 3]] - V[F[:, i]]
            b = V[F[:, (i + 2) % 3]] - V[F[:, i]]
            cos = np.einsum("ij,ij->i", a, b)
            cos /= np.maximum(np.linalg.norm(a, axis=1) * np.linalg.norm(b, axis=1), 1e-300)
            np.add.at(angles, F[:, i], np.arccos(np.clip(cos, -1.0, 1.0)))
        K = (2 * np.pi - angles) / safe
        unique, counts = unique_edges(F)
        border = np.unique(unique[counts == 1])
        H[border] = 0.0
        K[border] = 0.0
    H[M <= 0] = 0.0
    K[M <= 0] = 0.0
    out = []
    for t in scales:
        # vertices removed by the cleaning (zero mass, e.g. small islands) get a unit diagonal
        # so the system stays regular; their right-hand side is 0
        lu = sla.splu(sp.csc_matrix(sp.diags(np.where(M > 0, M, 1.0)) + t * L))
        out.extend(lu.solve(M * f) for f in (H, K))
    return np.stack(out, axis=1)


def _slanted_identity(evals_1: np.ndarray, evals_2: np.ndarray, k2: int, k1: int) -> np.ndarray:
    C = np.zeros((k2 + 1, k1 + 1))
    for j in range(1, k2 + 1):
        C[j, min(slant(evals_1, evals_2, j), k1)] = 1.0
    return C


@one_blas_thread
def partial_descriptors(
    eig_1: EigenBasis,
    eig_2: EigenBasis,
    *,
    landmarks: Any = None,
    n_descriptors: int = 100,
    k_descriptors: int = 100,
) -> tuple[np.ndarray, np.ndarray]:
    """Descriptors of :func:`fit_partial_fmap`, for several fits between the same two shapes.

    They do not depend on the map's size: a caller fitting maps of several sizes computes
    them once and passes them as ``descriptors=``. Measured (FAUST 093 -> 087 with the legs
    cut, the 10 fits of a partial match): computed per fit they took 1.1 s of the fits' 5.8 s
    (the diffused curvatures' sparse factorizations); once, 0.23 s.

    Parameters
    ----------
    eig_1, eig_2 : EigenBasis
        Source (whole) and target (part) eigenbases in the same units (:func:`rescaled`).
    landmarks, n_descriptors, k_descriptors
        As in :func:`fit_partial_fmap`.

    Returns
    -------
    D1, D2 : (n1, p), (n2, p) ndarray
        Curvature descriptors and wave kernels at common energies (not normalized per shape),
        one scale per column (the source's norms).
    """
    n_descriptors = check_int(n_descriptors, name="n_descriptors", minimum=1)
    k_descriptors = check_int(k_descriptors, name="k_descriptors", minimum=2)
    ev1 = eig_1.evals[1 : min(k_descriptors, eig_1.k) + 1]
    ev2 = eig_2.evals[1 : min(k_descriptors, eig_2.k) + 1]
    common = np.array([max(ev1[0], ev2[0]), min(ev1[-1], ev2[-1])])
    energies, sigma = wks_energies(common, n_descriptors)
    if not sigma > 0:
        ratio = eig_2.area / eig_1.area
        raise ValueError(
            "the two spectra do not overlap: the target cannot be a part of the source in the "
            f"same units (its area is {ratio:.3g} times the source's in these units); rescale "
            "the target to the source's units"
        )

    def signature(eig: EigenBasis, ev: np.ndarray, points: np.ndarray | None) -> np.ndarray:
        """Return the local wave kernel (equal on a part and on the whole), its maps at points."""
        phi = eig.evecs[:, 1 : ev.shape[0] + 1]
        coefs = np.exp(-((energies[:, None] - np.log(ev)[None, :]) ** 2) / (2 * sigma**2))
        maps = [] if points is None else [_kernel_signature(phi, coefs, points, False)]
        return np.concatenate([_kernel_signature(phi, coefs, None, False), *maps], axis=1)

    lm1, lm2 = _landmark_pairs(landmarks)
    C1 = curvature_descriptors(eig_1)
    mean = eig_1.mass @ C1  # centred: the constant part carries no information
    D1 = np.concatenate([signature(eig_1, ev1, lm1), C1 - mean], axis=1)
    D2 = np.concatenate([signature(eig_2, ev2, lm2), curvature_descriptors(eig_2) - mean], axis=1)
    norms = np.sqrt(eig_1.mass @ D1**2)  # one scale per column for both shapes
    keep = norms > 0
    w = np.ones(D1.shape[1])
    w[-C1.shape[1] :] = CURVATURE_WEIGHT
    return D1[:, keep] * (w / norms)[keep], D2[:, keep] * (w / norms)[keep]


def fit_partial_fmap(
    eig_1: EigenBasis,
    eig_2: EigenBasis,
    *,
    k2: int,
    landmarks: Any = None,
    n_descriptors: int = 100,
    k_descriptors: int = 100,
    w_descr: float = 1.0,
    w_lap: float = 1e-2,
    w_dcomm: tuple[float, ...] = (0.1, 0.0),
    w_orient: float = 1.0,
    w_rows: float = 1.0,
    solver: str = "lbfgs",
    maxiter: int = 15000,
    descriptors: tuple[np.ndarray, np.ndarray] | None = None,
) -> list[np.ndarray]:
    """Fit restriction maps (source full, target a part) to common-energy descriptors.

    Minimizes over C (k2+1, k1+1), first column fixed to ``(√r, 0, ..., 0)``,

    ``w_descr ‖C A − B‖² + w_lap ‖C Λ₁ − Λ₂ C‖² + w_dcomm Σ_i ‖C Dᵢ¹ − Dᵢ² C‖²
    + w_orient Σ_i ‖C Gᵢ¹ − Gᵢ² C‖²``

    (see :func:`o3d_ofp.core.fmap.estimate_fmap` for the terms), with ``k1 = slant(k2)``.

    Parameters
    ----------
    eig_1, eig_2 : EigenBasis
        Source (whole) and target (part) eigenbases **in the same units** (:func:`rescaled`
        with the source's area for both).
    k2 : int
        Non-constant target eigenfunctions of the map.
    landmarks : (p, 2) ndarray of int, optional
        Known (source, target) vertex pairs: their wave kernel maps join the descriptors.
    n_descriptors, k_descriptors : int
        Energies of the WKS and eigenpairs it is computed from.
    w_descr, w_lap, w_orient : float
        Weights (the orientation term is rescaled to ``w_orient`` times the others at the
        slanted identity).
    w_dcomm : tuple of float
        One map is fitted per descriptor-commutativity weight (the operators are built once).
    w_rows : float
        Weight of ``½ ‖C Cᵀ − I‖²`` (``solver="lbfgs"`` only).
    solver : {"lbfgs", "direct"}, default "lbfgs"
        ``"lbfgs"``: L-BFGS-B on the energy with the row term (quartic) from C = 0;
        ``"direct"``: the exact minimizer of the quadratic energy without the row term, one
        linear solve (:func:`o3d_ofp.core.fmap._minimize_quadratic`). The two are different
        starts, not the same minimizer.
    maxiter : int
        Bound on L-BFGS-B iterations.
    descriptors : tuple of two ndarray, optional
        ``(D1, D2)`` of :func:`partial_descriptors` for these shapes (with the same
        ``landmarks``, ``n_descriptors`` and ``k_descriptors``), when several fits share them;
        computed here otherwise.

    Returns
    -------
    list of (k2+1, k1+1) ndarray
        One map per ``w_dcomm`` weight.

    References
    ----------
    .. [1] E. Rodolà et al., "Partial Functional Correspondence", CGF 36(1), 2017.
    """
    [maps] = fit_partial_fmaps(
        eig_1, eig_2, fits=[(k2, solver)], landmarks=landmarks, n_descriptors=n_descriptors,
        k_descriptors=k_descriptors, w_descr=w_descr, w_lap=w_lap, w_dcomm=w_dcomm,
        w_orient=w_orient, w_rows=w_rows, maxiter=maxiter, descriptors=descriptors,
    )  # fmt: skip
    return maps


@one_blas_thread
def fit_partial_fmaps(
    eig_1: EigenBasis,
    eig_2: EigenBasis,
    *,
    fits: Sequence[tuple[int, str]],
    landmarks: Any = None,
    n_descriptors: int = 100,
    k_descriptors: int = 100,
    w_descr: float = 1.0,
    w_lap: float = 1e-2,
    w_dcomm: tuple[float, ...] = (0.1, 0.0),
    w_orient: float = 1.0,
    w_rows: float = 1.0,
    maxiter: int = 15000,
    descriptors: tuple[np.ndarray, np.ndarray] | None = None,
    report: Callable[[int], None] | None = None,
) -> list[list[np.ndarray]]:
    """Partial fits of several sizes and solvers, their operator stacks built once.

    The maps :func:`fit_partial_fmap` fits for every ``(k2, solver)`` of ``fits``: the
    descriptors' coefficients and multiplication and orientation operators are built once, at
    the largest target size and its slanted source size (the two shapes on two threads), and
    each fit takes their leading blocks, which are the operators of its own sizes (the same
    maps as fits built one by one, up to the order of the sums). Measured (2026-12-02, the
    five fits of a partial match, FAUST 093 -> 087 with the legs removed, 6.9k vertices):
    3.4 s instead of 5.1 s fit by fit; with 6 landmarks, whose wave kernel maps make 708
    descriptors instead of 108, 12.7 s instead of 20.9 s.

    Parameters
    ----------
    eig_1, eig_2 : EigenBasis
        Source (whole) and target (part) eigenbases in the same units (:func:`rescaled`).
    fits : sequence of (int, str)
        The target size ``k2`` and the solver (``"lbfgs"`` or ``"direct"``) of each fit.
    landmarks, n_descriptors, k_descriptors, w_descr, w_lap, w_dcomm
        As in :func:`fit_partial_fmap`.
    w_orient, w_rows, maxiter, descriptors
        As in :func:`fit_partial_fmap`.
    report : callable, optional
        ``report(i)`` before fit ``i`` (0-based) is solved, the operators built.

    Returns
    -------
    list of list of (k2+1, k1+1) ndarray
        For every fit, one map per ``w_dcomm`` weight (``k1 = slant(k2)``).
    """
    checked = []
    for k2, solver in fits:
        if solver not in ("lbfgs", "direct"):
            raise ValueError(f"solver must be 'lbfgs' or 'direct'; got {solver!r}")
        checked.append((check_int(k2, name="k2", minimum=1, maximum=eig_2.k), solver))
    if not checked:
        raise ValueError("fits must name at least one (k2, solver) fit")
    if descriptors is None:
        descriptors = partial_descriptors(
            eig_1,
            eig_2,
            landmarks=landmarks,
            n_descriptors=n_descriptors,
            k_descriptors=k_descriptors,
        )
    D1, D2 = _checked_descriptors(descriptors, eig_1, eig_2)
    orient = w_orient > 0 and eig_1.faces is not None and eig_2.faces is not None
    dcomm = max(w_dcomm) > 0
    top = max(k2 for k2, _ in checked)  # slant grows with k2: the largest source size too
    with ThreadPoolExecutor(max_workers=2) as pool:  # one shape a thread (one BLAS thread)
        job = pool.submit(_shape_terms, eig_2, top, D2, D2, dcomm, orient)
        top_1 = slant(eig_1.evals, eig_2.evals, top)
        terms = (_shape_terms(eig_1, top_1, D1, D1, dcomm, orient), job.result())
    root_r = math.sqrt(eig_2.area / eig_1.area)
    maps = []
    for i, (k2, solver) in enumerate(checked):
        if report is not None:
            report(i)
        k1 = slant(eig_1.evals, eig_2.evals, k2)
        energy = _energy_of(eig_1, eig_2, terms, k1 + 1, k2 + 1, (True, True))
        C0 = np.zeros((k2 + 1, k1 + 1))
        C0[0, 0] = root_r  # ⟨ψ0, φ0 on the part⟩ = area₂ / √(area₁ area₂)
        ref = _slanted_identity(eig_1.evals, eig_2.evals, k2, k1)
        ref[0, 0] = root_r
        found = []
        for wc in w_dcomm:
            weights = (w_descr, w_lap, float(wc), 0.0)
            if energy.orient is not None:
                weights = energy.orientation_weighted(ref, weights, w_orient)
            what = f"fit_partial_fmap ({k2} functions, w_dcomm {wc:g})"
            found.append(energy.solve(C0, weights, solver, {"maxiter": maxiter}, what, w_rows))
        maps.append(found)
    return maps


def _checked_descriptors(
    descriptors: tuple[np.ndarray, np.ndarray], eig_1: EigenBasis, eig_2: EigenBasis
) -> tuple[np.ndarray, np.ndarray]:
    """Return the descriptors ``(D1, D2)`` as float arrays, checked against both shapes."""
    D1, D2 = (np.asarray(D, dtype=np.float64) for D in descriptors)
    rows = (D1.shape[0], D2.shape[0]) if D1.ndim == D2.ndim == 2 else None
    if rows != (eig_1.n_vertices, eig_2.n_vertices) or D1.shape[1] != D2.shape[1]:
        raise ValueError(
            f"descriptors must be (n1, p) and (n2, p) arrays for shapes of {eig_1.n_vertices} "
            f"and {eig_2.n_vertices} vertices; got {D1.shape} and {D2.shape}"
        )
    return D1, D2


@one_blas_thread
def partial_zoomout(
    fmap_12: np.ndarray,
    eig_1: EigenBasis,
    eig_2: EigenBasis,
    *,
    k2_final: int,
    subsample: int | None = 2000,
) -> np.ndarray:
    """Partial ZoomOut: grow a restriction map along its slant through point maps.

    At each step, every target sample goes to the source sample whose row of ``Φ Cᵀ`` is
    nearest to its row of ``Ψ``; the map is refitted by least squares with one more target
    eigenfunction and ``slant(k2)`` source ones.

    Parameters
    ----------
    fmap_12 : (k2+1, k1+1) ndarray
        Initial map (bases in the same units, see :func:`rescaled`).
    eig_1, eig_2 : EigenBasis
        Source (whole) and target (part) eigenbases in the same units.
    k2_final : int
        Final number of non-constant target eigenfunctions (the source side follows the
        slant, at most ``eig_1.k``).
    subsample : int or None, default 2000
        Farthest-point samples per shape the iterations run on (None: all vertices).

    Returns
    -------
    (k2_final+1, slant(k2_final)+1) ndarray
    """
    k2_final = check_int(k2_final, name="k2_final", minimum=1, maximum=eig_2.k)
    C = np.asarray(fmap_12, dtype=np.float64)
    if subsample is None:
        s1, s2 = np.arange(eig_1.n_vertices), np.arange(eig_2.n_vertices)
    else:
        subsample = check_int(subsample, name="subsample", minimum=k2_final + 1)
        s1 = farthest_points(eig_1.vertices, subsample)
        s2 = farthest_points(eig_2.vertices, subsample)
    k1_final = slant(eig_1.evals, eig_2.evals, k2_final)
    phi = eig_1.evecs[s1, : max(k1_final, C.shape[1] - 1) + 1]
    psi = eig_2.evecs[s2, : k2_final + 1]
    k2 = C.shape[0] - 1
    fits = _LeadingFits(psi)  # each step fits one more leading column of psi
    while k2 < k2_final:
        p2p = nearest_neighbors(phi[:, : C.shape[1]] @ C.T, psi[:, : C.shape[0]])
        k2 += 1
        k1 = slant(eig_1.evals, eig_2.evals, k2)
        C = fits.solve(k2 + 1, phi[p2p, : k1 + 1])
    return C


#: Source size, as a fraction of the final one, at which :func:`partial_polish` starts.
#: Measured on the final maps of the 12 cuts of scripts/eval_partial.py --remeshed (99
#: eigenfunctions per shape; the polish applied to the match's maps, with all 99 target
#: functions): from 60 of 99, every one of the 9 right maps as precise or more (errors
#: 0.0166-0.0436 -> 0.0161-0.0399; with twice the slant's target functions 0.0156-0.0400);
#: with the single size 99, less gain (0.0162-0.0418); from 30, worse on 3 of the 9.
POLISH_FROM = 0.6
#: Target functions of :func:`partial_polish`'s fits, as a multiple of those the slant gives
#: (at most all of the target's). Measured on the same maps: with twice the slant, or all 99
#: target functions, the same errors within 0.001 on the cuts of 55-80 % of the area; on a
#: cut of 25 % (FAUST legs removed, kept 0.25), all 99 made the map rough (35 % of the
#: triangles turned over, where the map before the polish turned fewer: it was not flagged).
POLISH_TARGET_FACTOR = 2


@one_blas_thread
def partial_polish(
    p2p_21: np.ndarray,
    eig_1: EigenBasis,
    eig_2: EigenBasis,
    *,
    k1_final: int,
    subsample: int | None = 2000,
) -> tuple[np.ndarray, np.ndarray]:
    """Sharpen a right partial point map: fits with twice the slant's target functions.

    The partial ZoomOut (:func:`partial_zoomout`) fits ``Ψ C ≈ Φ[π]`` with as many target
    eigenfunctions as the slant allows (about ``r k1``): the restrictions of the source's
    eigenfunctions to the part are then represented only roughly near the cut, and from the
    *true* map the ZoomOut drifts (measured on the 8 cuts of scripts/eval_partial.py: errors
    0.016-0.027 read off at 29 target functions, 0.018-0.101 after the ZoomOut). Here the fit
    uses :data:`POLISH_TARGET_FACTOR` times as many target functions (at most all of them:
    more than the source functions need; :func:`polish_target_size`), and each target sample
    goes to the source sample whose ``Φ`` row is nearest to its row of ``Ψ C`` (the source
    embedding is not projected). Source sizes grow
    from :data:`POLISH_FROM` of ``k1_final`` to ``k1_final``. From the true maps this ends at
    0.009-0.016 (``python scripts/eval_partial.py --from-truth``: it keeps a right map where
    it is), and it does not move a map much: it sharpens a map that is right, and repairs
    nothing (a wrong map stays wrong).

    Parameters
    ----------
    p2p_21 : (n2,) ndarray of int
        For every target vertex, its source vertex (a refined partial map).
    eig_1, eig_2 : EigenBasis
        Source (whole) and target (part) eigenbases in the same units (:func:`rescaled`).
    k1_final : int
        Final source size (at most ``eig_1.k``).
    subsample : int or None, default 2000
        Farthest-point samples per shape the iterations run on, at least one more than the
        largest fit's target size (a shape with fewer vertices: all of them; None: all
        vertices of both).

    Returns
    -------
    p2p_21 : (n2,) ndarray of int64
        The polished point map, every target vertex.
    fmap : (k2+1, k1_final+1) ndarray
        The last fit (``k2 = polish_target_size(k1_final)``), ``Ψ C ≈ Φ[π]`` for the samples'
        map ``π`` of the last iteration; ``p2p_21`` is read off it.
    """
    C = partial_polish_fit(p2p_21, eig_1, eig_2, k1_final=k1_final, subsample=subsample)
    polished = nearest_neighbors(eig_1.evecs[:, : C.shape[1]], eig_2.evecs[:, : C.shape[0]] @ C)
    return polished, C


@one_blas_thread
def partial_polish_fit(
    p2p_21: np.ndarray,
    eig_1: EigenBasis,
    eig_2: EigenBasis,
    *,
    k1_final: int,
    subsample: int | None = 2000,
) -> np.ndarray:
    """Run the iterations of :func:`partial_polish`, without its read-off on every vertex.

    The polished map is read off as each target vertex's row of ``Ψ C`` against the source's
    rows of ``Φ``: on the vertices of these bases by :func:`partial_polish`, on a finer copy
    of the shapes by :func:`o3d_ofp.core.multiscale.extend_p2p` with ``adjoint=True`` (the
    dense path).

    Parameters
    ----------
    p2p_21 : (n2,) ndarray of int
        For every target vertex, its source vertex (a refined partial map).
    eig_1, eig_2 : EigenBasis
        Source (whole) and target (part) eigenbases in the same units (:func:`rescaled`).
    k1_final : int
        Final source size (at most ``eig_1.k``).
    subsample : int or None, default 2000
        Farthest-point samples per shape the iterations run on (as in :func:`partial_polish`).

    Returns
    -------
    (k2+1, k1_final+1) ndarray
        The last fit ``Ψ C ≈ Φ[π]`` (``k2 = polish_target_size(k1_final)``), in the bases'
        own units as well (both are scaled alike by :func:`rescaled`).
    """
    k1_final = check_int(k1_final, name="k1_final", minimum=1, maximum=eig_1.k)
    p2p = check_p2p(p2p_21, eig_2.n_vertices, eig_1.n_vertices)
    k2_max = polish_target_size(eig_1.evals, eig_2.evals, k1_final)
    n1, n2 = eig_1.n_vertices, eig_2.n_vertices
    if subsample is not None:
        # at least one sample per unknown of a fit (the target size can exceed the ZoomOut's)
        count = max(check_int(subsample, name="subsample", minimum=2), k2_max + 1)
    if subsample is None or count >= max(n1, n2):
        s1, s2 = np.arange(n1), np.arange(n2)
        current = p2p  # indices into s1: source vertices
    else:  # farthest_points gives every vertex of a shape with at most ``count``
        s1 = farthest_points(eig_1.vertices, min(count, n1))
        s2 = farthest_points(eig_2.vertices, min(count, n2))
        # each target sample's image, moved to the nearest source sample
        current = nearest_neighbors(eig_1.vertices[s1], eig_1.vertices[p2p[s2]])
    phi = eig_1.evecs[s1, : k1_final + 1]
    psi = eig_2.evecs[s2, : k2_max + 1]
    fits = _LeadingFits(psi)  # the fits use leading columns of psi (as in ZoomOut)
    for k1 in range(max(1, round(POLISH_FROM * k1_final)), k1_final + 1):
        size = polish_target_size(eig_1.evals, eig_2.evals, k1)
        C = fits.solve(size + 1, phi[current, : k1 + 1])
        current = nearest_neighbors(phi[:, : k1 + 1], psi[:, : size + 1] @ C)
    return C


def polish_target_size(evals_1: np.ndarray, evals_2: np.ndarray, k1: int) -> int:
    """Target size of :func:`partial_polish`'s fit with ``k1`` source functions.

    Parameters
    ----------
    evals_1, evals_2 : (k1'+1,), (k2'+1,) ndarray
        Source and target eigenvalues in the same units, constant first.
    k1 : int
        Non-constant source eigenfunctions of the fit.

    Returns
    -------
    int
        :data:`POLISH_TARGET_FACTOR` times the non-constant target eigenvalues not above the
        source's ``k1``-th (the slant read backwards: about ``r k1`` for a part of area ratio
        ``r``), at least 1, at most ``len(evals_2) - 1``.
    """
    count = int(np.searchsorted(evals_2, evals_1[k1], side="right")) - 1
    return max(1, min(POLISH_TARGET_FACTOR * count, evals_2.shape[0] - 1))


def partial_p2p(fmap_12: np.ndarray, eig_1: EigenBasis, eig_2: EigenBasis) -> np.ndarray:
    """Point map of a restriction map: each target vertex to its nearest row of ``Φ Cᵀ``.

    Parameters
    ----------
    fmap_12 : (k2+1, k1+1) ndarray
        Map between bases in the same units.
    eig_1, eig_2 : EigenBasis

    Returns
    -------
    (n2,) ndarray of int64
        ``p2p_21``.
    """
    C = np.asarray(fmap_12, dtype=np.float64)
    return nearest_neighbors(eig_1.evecs[:, : C.shape[1]] @ C.T, eig_2.evecs[:, : C.shape[0]])


def membership(fmap_12: np.ndarray, eig_1: EigenBasis, eig_2: EigenBasis) -> np.ndarray:
    """Smooth indicator on the source of the region the target covers: ``v = Φ Cᵀ 1``.

    The restriction map's adjoint extends a target function by zero; applied to the target's
    constant function it gives the part's indicator, band-limited to the source eigenfunctions
    of the map.

    Parameters
    ----------
    fmap_12 : (k2+1, k1+1) ndarray
        Map between bases in the same units.
    eig_1, eig_2 : EigenBasis

    Returns
    -------
    (n1,) ndarray
        About 1 on the covered region, 0 elsewhere.
    """
    C = np.asarray(fmap_12, dtype=np.float64)
    ones = math.sqrt(eig_2.area) * C[0]  # coefficients of 1 on the target: √area₂ ψ0
    return eig_1.evecs[:, : C.shape[1]] @ ones
