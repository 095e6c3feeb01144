"""Functional maps on large shapes: exact point maps by local search, coarse-to-fine maps.

:func:`o3d_ofp.core.correspondence.p2p_from_fmap` compares every target vertex with every
source vertex: O(n1 · n2 · d), 100 s at 110k vertices per shape with d = 100, and a k-d tree
does not help in 100 dimensions. :func:`local_p2p_from_fmap` returns the same answer (the exact
nearest neighbour, to the index) while looking at a few thousand source vertices per target
vertex: the source is cut into spatially compact cells, each bounded in the embedding by a
ball and a thin slab, and only the cells that can hold the nearest neighbour are searched.

The 100 eigenpairs of a large mesh cost more than the search (80 s per shape at 440k
vertices): :func:`coarse_eigenbasis` computes them on a subsample, a map estimated between two
coarse versions is carried to the full shapes by :func:`extend_p2p` (interpolated coarse
eigenfunctions, exact local search) and projected on small full-resolution bases by
:func:`extend_fmap`. :func:`coarse_mesh` gives the coarse versions that
:mod:`o3d_ofp.workflows.dense` matches (a point-cloud subsample, :func:`coarse_eigenbasis`,
measured on FAUST x4: error 0.21 instead of 0.03).

The final point map of a match is read here too, by the same searches:
:func:`anchored_p2p_from_fmap` (the spectral embedding with the landmark functions) and
:func:`dirichlet_p2p` (one smoothing step of that map).
"""

from __future__ import annotations

import logging
import math
import time
from typing import Any, NamedTuple

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as sla
from scipy.spatial import cKDTree

from ._processes import processes_available, side_by_side
from ._rows import unique_rows
from ._threads import one_blas_thread
from ._validation import as_faces, as_vertices, check_int
from .cleaning import weld_groups
from .correspondence import (
    check_p2p,
    fmap_between,
    fmap_from_p2p,
    nearest_neighbors,
    p2p_from_fmap,
)
from .fmap import (
    Anchors,
    _anchor_functions,
    farthest_points,
    grid_samples,
    landmark_embedding,
    unit_area,
)
from .geometry import closest_on_triangles, edge_graph
from .spectrum import EigenBasis, check_eigenbasis, eigenbasis

__all__ = [
    "anchored_p2p_from_fmap",
    "cell_restriction",
    "coarse_eigenbasis",
    "coarse_mesh",
    "coarse_samples",
    "dirichlet_p2p",
    "extend_fmap",
    "extend_p2p",
    "local_p2p_from_fmap",
    "surface_prolongation",
]

logger = logging.getLogger(__name__)

#: float32 unit round-off.
_U32 = float(np.finfo(np.float32).eps) / 2.0
#: Dimension of the flat slab bounding each cell in the embedding (its principal directions).
_SLAB = 3
#: Target vertices per block of the coarse stage (distances to all cells).
_BLOCK = 512
#: FPS runs on a random pool of this many vertices per wanted sample: exact FPS over all
#: vertices costs O(n · samples), 8 s for 3000 samples at 440k vertices.
_FPS_POOL = 4
#: Source vertices per chunk when building the cells' embeddings.
_CHUNK = 65536
#: Target vertices above which the local search runs two halves of them side by side.
SPLIT_QUERIES = 20_000


def _morton_order(vertices: np.ndarray) -> np.ndarray:
    """Order of the vertices along a Z-order curve (10 bits per axis): nearby runs of it."""
    lo = vertices.min(axis=0)
    extent = float((vertices.max(axis=0) - lo).max())
    q = np.zeros(vertices.shape, dtype=np.int64)
    if extent > 0:
        q = np.minimum((vertices - lo) * (1023.0 / extent), 1023.0).astype(np.int64)
    code = np.zeros(vertices.shape[0], dtype=np.int64)
    for bit in range(10):
        for axis in range(3):
            code |= ((q[:, axis] >> bit) & 1) << (3 * bit + axis)
    return np.argsort(code, kind="stable")


def _cell_count(n_samples: int | None, n1: int) -> int:
    """Source cells before splitting: ``n_samples`` (checked), at most ``n1``.

    The default ``2 sqrt(n1)`` (at least 64) balances the coarse stage (∝ s per query) and the
    fine one (∝ n1 / s).
    """
    if n_samples is None:
        return int(min(n1, max(64, round(2.0 * math.sqrt(n1)))))
    return min(check_int(n_samples, name="n_samples", minimum=1), n1)


def _sample(
    vertices: np.ndarray, count: int, seed: int, *, assign: bool = True
) -> tuple[np.ndarray, np.ndarray | None]:
    """Return farthest-point samples (s,) and the 3-D Voronoi cell (n,) of every vertex."""
    n = vertices.shape[0]
    if count >= n:
        return np.arange(n), np.arange(n)
    pool_size = min(n, _FPS_POOL * count)
    pool = np.arange(n)
    if pool_size < n:
        pool = np.sort(np.random.default_rng(seed).choice(n, pool_size, replace=False))
    samples = pool[farthest_points(vertices[pool], count)]
    if not assign:
        return samples, None
    cell = cKDTree(vertices[samples]).query(vertices, k=1, workers=-1)[1].astype(np.int64)
    cell[samples] = np.arange(count)  # duplicated positions: every sample heads its own cell
    return samples, cell


def _split(
    emb: np.ndarray, samples: np.ndarray, cell: np.ndarray, rounds: int = 12
) -> tuple[np.ndarray, np.ndarray]:
    """Split the cells that are wide in the embedding or crowded, until none is.

    Wide cells (3-D Voronoi cells over parts close in space but not on the surface, or where
    the embedding varies fast) give loose bounds and large float32 errors; crowded ones
    (finely meshed parts) many candidates. Each round, every cell whose radius exceeds 1.5 ×
    the median, or whose size 4 × the mean, gets its farthest member (in the embedding) as a
    new sample, and its members go to the nearer of the two.

    Parameters
    ----------
    emb : (n, d) ndarray of float32
        Source embedding.
    samples : (s,) ndarray of int64
        Initial samples.
    cell : (n,) ndarray of int64
        Initial cell of every vertex.
    rounds : int
        Bound on the rounds.

    Returns
    -------
    samples : (s',) ndarray of int64
    cell : (n,) ndarray of int64
    """
    cell = cell.copy()
    dist2 = np.empty(cell.shape[0])
    for a in range(0, cell.shape[0], _CHUNK):  # chunks: no (n, d) temporaries
        diff = emb[a : a + _CHUNK] - emb[samples[cell[a : a + _CHUNK]]]
        dist2[a : a + _CHUNK] = np.einsum("ij,ij->i", diff, diff)
    r2 = np.zeros(samples.shape[0])
    np.maximum.at(r2, cell, dist2)
    wide = 2.25 * float(np.median(r2))
    crowded = 4.0 * cell.shape[0] / samples.shape[0]
    for _ in range(rounds):
        s = samples.shape[0]
        r2 = np.zeros(s)
        np.maximum.at(r2, cell, dist2)
        split = (r2 > wide) | (np.bincount(cell, minlength=s) > crowded)
        if not split.any():
            break
        members = np.flatnonzero(split[cell])
        by = np.lexsort((-dist2[members], cell[members]))
        members = members[by]
        mc = cell[members]
        heads = np.flatnonzero(np.concatenate([[True], mc[1:] != mc[:-1]]))
        far = members[heads]
        new_id = np.full(s, -1, dtype=np.int64)
        new_id[mc[heads]] = s + np.arange(heads.shape[0])
        diff = emb[members] - emb[far[np.searchsorted(mc[heads], mc)]]
        dn = np.einsum("ij,ij->i", diff, diff)
        move = dn < dist2[members]
        move[heads] = True
        cell[members[move]] = new_id[mc[move]]
        dist2[members[move]] = dn[move]
        samples = np.concatenate([samples, far])
    return samples, cell


class _Cells:
    """Source cells in the embedding: sample, members' offsets and slab bounds.

    With s cells, n1 vertices, d dimensions and p = ``_SLAB``: ``order`` (n1,) lists the source
    vertices by cell, ``starts`` and ``sizes`` (s,) index into it; ``centre`` (s, d) float64
    holds the samples' embeddings (globally centred) and ``centre2`` (s,) float32 their squared
    norms; ``offsets`` (n1, d) float32 each member minus its cell's centre, in cell order, and
    ``norms`` (n1,) their squared norms;
    ``radius`` (s,) the largest offset norm; ``basis`` (s, d, p) orthonormal directions along
    which the cell spreads (the embedding's differential along the cell's 3-D extent),
    ``flat`` (s,) the largest offset component in their span and ``thick`` (s,) off it.
    """

    def __init__(
        self,
        phi: np.ndarray,
        Ct: np.ndarray,
        shift: np.ndarray,
        vertices: np.ndarray,
        samples: np.ndarray,
        cell: np.ndarray,
    ) -> None:
        s = samples.shape[0]
        n1, d = phi.shape[0], Ct.shape[1]
        cols = Ct.shape[0]
        self.phi, self.Ct, self.shift = phi, Ct, shift  # the float64 redo of unsure queries
        self.order = np.argsort(cell, kind="stable").astype(np.int64)
        self.sizes = np.bincount(cell, minlength=s).astype(np.int64)
        self.starts = np.concatenate([[0], np.cumsum(self.sizes)[:-1]]).astype(np.int64)
        self.centre = phi[samples, :cols] @ Ct - shift
        self.centre2 = np.einsum("ij,ij->i", self.centre, self.centre).astype(np.float32)
        self.offsets = np.empty((n1, d), dtype=np.float32)
        self.norms = np.empty(n1, dtype=np.float32)
        self.basis = np.zeros((s, d, _SLAB))
        r2 = np.zeros(s)
        in2_max = np.zeros(s)
        out2_max = np.zeros(s)
        ends = self.starts + self.sizes
        c0 = 0
        while c0 < s:  # chunks of whole cells
            c1 = max(c0 + 1, int(np.searchsorted(ends, self.starts[c0] + _CHUNK, side="right")))
            a, b = int(self.starts[c0]), int(ends[c1 - 1])
            idx = self.order[a:b]
            c = cell[idx]
            Z = phi[idx, :cols] @ Ct
            Z -= shift
            Z -= self.centre[c]
            self.offsets[a:b] = Z
            z2 = np.einsum("ij,ij->i", Z, Z)
            # Directions: span of Σ_j z_j (v_j − v_c)ᵀ, the embedding's first-order change
            # across the cell (any orthonormal directions give valid bounds; these give tight
            # ones). One batched SVD of (d, 3) matrices, by decreasing spread.
            P = vertices[idx] - vertices[samples[c]]
            heads = np.flatnonzero(np.concatenate([[True], c[1:] != c[:-1]]))
            moment = np.stack(
                [np.add.reduceat(Z * P[:, k : k + 1], heads, axis=0) for k in range(3)], axis=2
            )
            basis = np.linalg.svd(moment, full_matrices=False)[0][:, :, :_SLAB]
            self.basis[c[heads]] = basis
            bounds = np.concatenate([heads, [b - a]])
            in2 = np.empty(b - a)
            for i in range(heads.shape[0]):  # in-slab coordinates, one small product per cell
                lo, hi = bounds[i], bounds[i + 1]
                inside = Z[lo:hi] @ basis[i]
                in2[lo:hi] = np.einsum("ij,ij->i", inside, inside)
            r2[c[heads]] = np.maximum.reduceat(z2, heads)
            in2_max[c[heads]] = np.maximum.reduceat(in2, heads)
            out2_max[c[heads]] = np.maximum.reduceat(np.maximum(z2 - in2, 0.0), heads)
            c0 = c1
        self.norms[:] = np.einsum("ij,ij->i", self.offsets, self.offsets)
        # float64 round-off of the bounds: far below the float32 margins used with them.
        slack = 1.0 + 1e-9
        self.radius = np.sqrt(r2) * slack
        self.flat = np.sqrt(in2_max) * slack
        self.thick = np.sqrt(out2_max) * slack

    def members(self, c: int) -> slice:
        """Positions (in cell order) of the vertices of cell ``c``."""
        return slice(int(self.starts[c]), int(self.starts[c] + self.sizes[c]))


def local_p2p_from_fmap(
    fmap_12: Any,
    eig_1: EigenBasis,
    eig_2: EigenBasis,
    *,
    n_samples: int | None = None,
    seed: int = 0,
) -> np.ndarray:
    """Point map of a functional map by exact nearest neighbours, searched locally.

    For every target vertex, the source vertex whose embedding ``Φ̂ Ĉᵀ`` is nearest to its
    embedding ``Ψ̂`` (Φ̂, Ψ̂, Ĉ the eigenbases and the map between the unit-area shapes, see
    :func:`o3d_ofp.core.fmap.unit_area`): the answer of the brute force
    ``p2p_from_fmap(Ĉ, unit_area(eig_1), unit_area(eig_2))``, at a cost of about
    ``n2 · (s + c · n1 / s) · d`` instead of ``n1 · n2 · d`` (c ≈ 8-15 cells per query;
    with s ∝ √n1, O(n^1.5). Measured on one core, d = 100: 0.7 s at 27.5k vertices per
    shape, 2.5 s at 110k, 15 s at 440k, where the brute force takes 4.4 s, 98 s and about
    26 min; above :data:`SPLIT_QUERIES` target vertices two halves of the target are searched
    side by side where a second process can be made: the extension's search at 440k 8.4 s
    instead of 13.0 s, measured on a slower day):

    1. The source is cut into ``s`` cells, the 3-D Voronoi cells of farthest-point samples;
       cells wide in the embedding (over parts close in space but not on the surface) or
       crowded are split in it. Each cell is bounded, around its sample, by a ball and by a
       slab: three directions of the embedding (its first-order change across the cell), the
       largest extent along them and the largest distance off them.
    2. For a block of target vertices (a run of a Z-order curve), one product with the
       samples gives, for every cell, the ball's lower bound on the distance to any of its
       vertices, and the distance to the sample, an upper bound on the nearest one; the
       slab's tighter bound is computed for the pairs that pass.
    3. Every query searches the cell of its nearest sample, then every other cell whose lower
       bound is below its best distance so far (one product per cell with all the queries
       that still need it).

    No cell that can hold the nearest neighbour is skipped, so the result is exact. The
    products run in float32 with the rounding-error bound of
    :func:`o3d_ofp.core.correspondence.nearest_neighbors` (bounds widened by it; distances
    taken relative to each cell's sample, so the error is that of a few units, not of the
    whole embedding); queries whose winner is not certain (a few %) are redone in float64 on
    the same cells, and ties go to the smallest source index, as in the brute force. Since
    only the exact answer is returned, it does not depend on the units, position, orientation
    or vertex order of either shape (to round-off in the eigenbases), nor on ``n_samples``.

    Parameters
    ----------
    fmap_12 : (k2+1, k1+1) array_like
        Functional map from source to target coefficients, in this package's convention
        (``fmap_from_p2p(p2p, eig_1, eig_2)``, not between unit-area bases).
    eig_1, eig_2 : EigenBasis
        Source and target eigenbases, with at least k1 and k2 non-constant functions.
    n_samples : int, optional
        Source cells ``s`` before splitting (default ``2 sqrt(n1)``, at least 64: 660 at 110k
        vertices, 1330 at 440k; measured fastest within ±20 %). Changes the speed only.
    seed : int, default 0
        Seed of the random pool the source samples are drawn from (speed only).

    Returns
    -------
    (n2,) ndarray of int64
        ``p2p_21``: for every target vertex, a source vertex.
    """
    eig_1 = check_eigenbasis(eig_1, "eig_1")
    eig_2 = check_eigenbasis(eig_2, "eig_2")
    C = fmap_between(fmap_12, eig_1, eig_2)
    count = _cell_count(n_samples, eig_1.n_vertices)
    a1, a2 = eig_1.area, eig_2.area
    # Unit-area embeddings without copying the bases: Φ̂ = Φ√A1, Ψ̂ = Ψ√A2, Ĉ = C√(A1/A2),
    # so Φ̂ Ĉᵀ = Φ (A1/√A2) Cᵀ (the scales go into the small matrix).
    Ct = np.ascontiguousarray(C.T) * (a1 / math.sqrt(a2))
    return _local_search(
        eig_1.evecs, Ct, eig_2.evecs, math.sqrt(a2), eig_1.vertices, eig_2.vertices, count, seed
    )


def anchored_p2p_from_fmap(
    fmap_12: Any, eig_1: EigenBasis, eig_2: EigenBasis, anchors: Anchors | None, *,
    local: bool = False,
) -> np.ndarray:  # fmt: skip
    """Point map of a functional map that also compares the vertices' landmark functions.

    For every target vertex, the source vertex nearest in
    :func:`~o3d_ofp.core.fmap.landmark_embedding`: the unit-area spectral embeddings of
    :func:`local_p2p_from_fmap` (``Φ̂ Ĉᵀ`` against ``Ψ̂``) followed by the landmark functions
    of ``anchors`` (distances and biharmonic coordinates), as every anchored ZoomOut step
    compares them. No anchors, or anchors without functions (a point cloud), give the
    spectral point map (:func:`~o3d_ofp.p2p_from_fmap`, or :func:`local_p2p_from_fmap`).

    Parameters
    ----------
    fmap_12 : (k2+1, k1+1) array_like
        Functional map, in this package's convention.
    eig_1, eig_2 : EigenBasis
        Source and target eigenbases.
    anchors : Anchors or None
        :func:`o3d_ofp.core.fmap.landmark_anchors` of the two shapes (None: no landmarks).
    local : bool, default False
        Search by :func:`local_p2p_from_fmap`'s cell-pruned exact search instead of a scan
        (the same answer; faster on large pairs).

    Returns
    -------
    (n2,) ndarray of int64
        ``p2p_21``.
    """
    eig_1 = check_eigenbasis(eig_1, "eig_1")
    eig_2 = check_eigenbasis(eig_2, "eig_2")
    C = fmap_between(fmap_12, eig_1, eig_2)
    d1, d2 = _anchor_functions(anchors, eig_1, eig_2)
    if d1 is None or d2 is None:
        return local_p2p_from_fmap(C, eig_1, eig_2) if local else p2p_from_fmap(C, eig_1, eig_2)
    rows, cols = C.shape
    a1, a2 = eig_1.area, eig_2.area
    # Unit-area embeddings, as local_p2p_from_fmap's: Φ̂ Ĉᵀ = Φ (A1/√A2) Cᵀ and Ψ̂ = Ψ √A2.
    phi = landmark_embedding(eig_1.evecs[:, :cols] @ C.T * (a1 / math.sqrt(a2)), d1)
    psi = landmark_embedding(eig_2.evecs[:, :rows] * math.sqrt(a2), d2)
    return _nearest_rows(phi, psi, eig_1, eig_2, local=local)


def _nearest_rows(
    phi: np.ndarray, psi: np.ndarray, eig_1: EigenBasis, eig_2: EigenBasis, *, local: bool
) -> np.ndarray:
    """Nearest row of ``phi`` (source) for every row of ``psi`` (target): scan or local search."""
    if not local:
        return nearest_neighbors(phi, psi)
    count = _cell_count(None, eig_1.n_vertices)
    return _local_search(phi, np.eye(phi.shape[1]), psi, 1.0, eig_1.vertices, eig_2.vertices,
                         count, 0)  # fmt: skip


#: Heat time (on the unit-area target) of :func:`dirichlet_p2p`'s smoothing of the positions a
#: point map sends the target's vertices to: a diffusion length of about
#: sqrt(DIRICHLET_TIME) = 0.03 sqrt(area), a few edges of a 5k-vertex body.
DIRICHLET_TIME = 1e-3
#: Weight of those positions in :func:`dirichlet_p2p`'s embedding: their squared distances
#: count ``DIRICHLET_WEIGHT · k`` times (``k`` the map's size: a unit-area spectral row's
#: squared norm grows as ``k``). Measured as a scratch step after ``ofp.match``'s final point
#: map (``scripts/eval_nonisometric.py``-style, 300 points, mean geodesic error x100;
#: gorilla -> human with 6 landmarks, 6.15 without the step): once, as here, 5.85 (TOSCA
#: animals without landmarks 2.71 against 3.05); repeated 3 times 5.84 (2.70), 6 times 5.99
#: (2.85). Three steps with weights 0.3, 3, 30, 100, 300, 1000 (time 1e-3): 6.36, 6.20, 5.90,
#: 5.84, 5.83, 5.89; at weight 100 times 1e-4 and 3e-3: 5.98 and 6.20.
DIRICHLET_WEIGHT = 100.0


def dirichlet_p2p(
    p2p_21: Any, eig_1: EigenBasis, eig_2: EigenBasis, anchors: Anchors | None, *, k: int,
    local: bool = False,
) -> np.ndarray:  # fmt: skip
    """One smoothing step of a point map: its images made smooth on the target, then snapped.

    After Magnet, Ren, Sorkine-Hornung and Ovsjanikov, "Smooth non-rigid shape matching via
    effective Dirichlet energy optimization" (3DV 2022): a spectral point map is noisy where
    the shapes are not isometric (the images of neighbouring target vertices scatter), and a
    map whose images vary smoothly over the target is closer to the truth. On the unit-area
    shapes:

    1. ``C`` = the map's own functional map on ``k`` eigenfunctions
       (:func:`~o3d_ofp.core.correspondence.fmap_from_p2p`: ZoomOut's step at that size);
    2. ``Y`` = the source positions ``V̂₁[p2p_21]``, smoothed on the target by one implicit
       heat step ``(M₂ + t K₂) Y' = M₂ Y`` (``t`` = :data:`DIRICHLET_TIME`);
    3. every target vertex goes to the source vertex nearest in ``[Φ̂ Ĉᵀ, landmark
       functions, a V̂₁]`` against ``[Ψ̂, landmark functions, a Y']``, with
       ``a² = DIRICHLET_WEIGHT · k``: the smoothed position decides, the spectral embedding
       and the landmark functions (:func:`~o3d_ofp.core.fmap.landmark_embedding`) tell apart
       the source vertices near it (two limbs that touch).

    Parameters
    ----------
    p2p_21 : (n2,) array_like of int
        The point map: source vertex of every target vertex.
    eig_1, eig_2 : EigenBasis
        Source and target eigenbases (meshes or point clouds: a cloud's smoothing uses its own
        Laplacian), in any units, with at least ``k`` non-constant eigenfunctions.
    anchors : Anchors or None
        :func:`o3d_ofp.core.fmap.landmark_anchors` of the two shapes (None: no landmarks).
    k : int
        Size of the map's functional map.
    local : bool, default False
        Search by :func:`local_p2p_from_fmap`'s cell-pruned exact search instead of a scan.

    Returns
    -------
    (n2,) ndarray of int64

    Raises
    ------
    ValueError
        If ``k`` is out of range, the map does not fit the shapes or the anchors were made for
        other shapes.
    """
    eig_1 = check_eigenbasis(eig_1, "eig_1")
    eig_2 = check_eigenbasis(eig_2, "eig_2")
    k = check_int(k, name="k", minimum=1, maximum=min(eig_1.k, eig_2.k))
    p2p = check_p2p(p2p_21, eig_2.n_vertices, eig_1.n_vertices)
    u1, u2 = unit_area(eig_1), unit_area(eig_2)
    C = fmap_from_p2p(p2p, u1, u2, k1=k, k2=k)
    mass = u2.mass
    out = mass <= 0  # vertices left out of the surface: a unit diagonal keeps the system regular
    heat = sp.diags(np.where(out, 1.0, mass)) + DIRICHLET_TIME * u2.stiffness
    lu = sla.splu(heat.tocsc())
    smooth = lu.solve(mass[:, None] * u1.vertices[p2p])
    a = math.sqrt(DIRICHLET_WEIGHT * k)
    d1, d2 = _anchor_functions(anchors, eig_1, eig_2)
    phi = np.hstack([landmark_embedding(u1.evecs[:, : k + 1] @ C.T, d1), a * u1.vertices])
    psi = np.hstack([landmark_embedding(u2.evecs[:, : k + 1], d2), a * smooth])
    return _nearest_rows(phi, psi, eig_1, eig_2, local=local)


@one_blas_thread
def _local_search(
    phi: np.ndarray,
    Ct: np.ndarray,
    psi: np.ndarray,
    root2: float,
    vertices_1: np.ndarray,
    vertices_2: np.ndarray,
    n_samples: int,
    seed: int,
) -> np.ndarray:
    """Nearest row of ``phi[:, :cols] @ Ct`` for every row of ``root2 * psi[:, :rows]``.

    Above :data:`SPLIT_QUERIES` target rows, where a second process can be made, the queries
    are split into two compact halves of the target (along its Z-order curve) searched side by
    side (:func:`~o3d_ofp.core._processes.side_by_side`); every answer is exact, so the split
    changes the time only.
    """
    t0 = time.perf_counter()
    n1, n2 = phi.shape[0], psi.shape[0]
    rows = Ct.shape[1]
    emb, shift = _source_embedding(phi, Ct)
    samples, cell = _sample(vertices_1, n_samples, seed)
    samples, cell = _split(emb, samples, cell)
    del emb
    cells = _Cells(phi, Ct, shift, vertices_1, samples, cell)
    t_cells = time.perf_counter() - t0

    def search(queries: np.ndarray | None) -> tuple[np.ndarray, int, int, int]:
        """Answers of ``queries`` (all when None), comparisons made, the float64 redone."""
        if queries is None:
            part_psi, part_vertices = psi, vertices_2
        else:
            part_psi, part_vertices = psi[queries, :rows], vertices_2[queries]
        target = _Target(part_psi, rows, root2, shift)
        best_cell, pairs, looked = _coarse_stage(cells, target, part_vertices)
        best, upper2, certain, searched = _fine_stage(cells, target, best_cell, pairs)
        out = cells.order[best]
        # Queries whose float32 winner is not certain: float64 on the same cells, ties to the
        # smallest source index.
        unsure = np.flatnonzero(~certain)
        if unsure.size:
            out[unsure] = _redo64(unsure, best_cell, pairs, upper2, cells, target)
        return out, looked, searched, unsure.size

    if n2 > SPLIT_QUERIES and processes_available() > 1:
        halves = np.array_split(_morton_order(vertices_2), 2)
        # Each half's target rows in float64 and float32, its bounds and candidate pairs.
        each = halves[0].size * (12.0 * rows + 200.0)
        parts = side_by_side([lambda q=q: search(q) for q in halves], what="nearest neighbours",
                             memory_each=each)  # fmt: skip
        out = np.empty(n2, dtype=np.int64)
        for q, part in zip(halves, parts, strict=True):
            out[q] = part[0]
        n_looked, searched, redone = (sum(part[i] for part in parts) for i in (1, 2, 3))
    else:
        out, n_looked, searched, redone = search(None)
    logger.debug(
        "local_p2p_from_fmap: %d -> %d vertices, %d cells (%.2fs), %.0f cells per query, "
        "%.0f candidates per query (%.2f%% of the source), %d redone in float64, %.2fs",
        n1, n2, samples.shape[0], t_cells, n_looked / n2, searched / n2,
        100.0 * searched / (n1 * n2), redone, time.perf_counter() - t0,
    )  # fmt: skip
    return out


def _source_embedding(phi: np.ndarray, Ct: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Return the source embedding ``phi[:, :cols] @ Ct`` in float32, centred, and its mean.

    The cells are shaped on the embedding; the mean (float64) is the global centre of both
    embeddings, for smaller norms (and rounding errors) in the float32 products.
    """
    cols, d = Ct.shape
    n1 = phi.shape[0]
    emb = np.empty((n1, d), dtype=np.float32)
    shift = np.zeros(d)
    for b in range(0, n1, _CHUNK):
        X = phi[b : b + _CHUNK, :cols] @ Ct
        shift += X.sum(axis=0)
        emb[b : b + _CHUNK] = X
    shift /= n1
    emb -= shift.astype(np.float32)
    return emb, shift


class _Target:
    """The target embedding ``root2 * psi[:, :rows] − shift`` in float32, with its norms.

    float32 halves the memory traffic of float64 in the products; its rounding, at most
    u‖y‖ (``round``), enters every error bound of the search. ``norm`` (n2,) holds the
    float64 norms of the rows.
    """

    def __init__(self, psi: np.ndarray, rows: int, root2: float, shift: np.ndarray) -> None:
        n2 = psi.shape[0]
        self.psi, self.root2 = psi, root2
        self.Y32 = np.empty((n2, rows), dtype=np.float32)
        self.norm = np.empty(n2)
        for b in range(0, n2, _CHUNK):
            Y = psi[b : b + _CHUNK, :rows] * root2
            Y -= shift
            self.norm[b : b + _CHUNK] = np.sqrt(np.einsum("ij,ij->i", Y, Y))
            self.Y32[b : b + _CHUNK] = Y
        self.round = 1.01 * _U32 * self.norm  # ‖Y32 − y‖


class _Pairs(NamedTuple):
    """(query, cell) pairs of the coarse stage, by cell, with a lower bound on the distance.

    Compact (a few per query): int32 indices, float32 bounds rounded down.
    """

    query: np.ndarray
    cell: np.ndarray
    lower: np.ndarray


def _coarse_stage(
    cells: _Cells, target: _Target, vertices_2: np.ndarray
) -> tuple[np.ndarray, _Pairs, int]:
    """Bound the distance of every query to every cell; keep the cells that may hold its nearest.

    Blocks of queries close on the target (runs of a Z-order curve: their candidate cells
    overlap) are compared with all the samples at once. Returns the cell of every query's
    nearest sample (searched first), the other candidate cells and the (query, cell)
    comparisons made.
    """
    s, d = cells.centre.shape
    n2 = target.Y32.shape[0]
    p = _SLAB
    gamma = d * _U32 / (1.0 - d * _U32)
    # Distances to the samples by float32 GEMMs: [−2y, 1, ‖y‖²] · [x_c; ‖x_c‖²; 1] is
    # ‖y − x_c‖², within ±err (the dot product's rounding-error bound).
    samples_t = np.empty((d + 2, s), dtype=np.float32)
    samples_t[:d] = cells.centre.T
    samples_t[d] = cells.centre2
    samples_t[d + 1] = 1.0
    basis_rows = np.ascontiguousarray(
        cells.basis.transpose(0, 2, 1).reshape(s * p, d), dtype=np.float32
    )  # row c·p + k: direction k of cell c
    centre_in = np.einsum("sd,sdp->sp", cells.centre, cells.basis)  # Bᵀ x_c
    c_max = math.sqrt(float(cells.centre2.max()))
    radius32 = cells.radius.astype(np.float32)
    gamma2 = (d + 2) * _U32 / (1.0 - (d + 2) * _U32)
    by_z = _morton_order(vertices_2)
    best_cell = np.empty(n2, dtype=np.int64)
    pair_q: list[np.ndarray] = []
    pair_c: list[np.ndarray] = []
    pair_lb: list[np.ndarray] = []
    q_buf = np.empty((_BLOCK, d + 2), dtype=np.float32)
    prod_buf = np.empty((_BLOCK, s), dtype=np.float32)
    n_looked = 0
    for b in range(0, n2, _BLOCK):
        qb = by_z[b : b + _BLOCK]
        m = qb.shape[0]
        r = np.arange(m)
        y_norm = target.norm[qb]
        qa = q_buf[:m]
        np.multiply(target.Y32[qb], -2.0, out=qa[:, :d])
        qa[:, d] = 1.0
        qa[:, d + 1] = y_norm**2
        # GEMM rounding, and Y32 for y in the cross term
        err = (gamma2 + 2.0 * _U32) * (y_norm + c_max) ** 2 + 2.0 * target.round[qb] * c_max
        dist2 = np.matmul(qa, samples_t, out=prod_buf[:m])
        n_looked += m * s
        near = np.argmin(dist2, axis=1)
        best_cell[qb] = near
        upper = np.sqrt(dist2[r, near].astype(np.float64) + err)
        # Ball bound first (‖y − x_c‖ − R_c), on the whole block in place ...
        dist = np.sqrt(np.maximum(dist2, 0.0, out=dist2), out=dist2)
        dist -= radius32
        dist[r, near] = np.inf  # searched first anyway
        slack = np.sqrt(err) + 1e-6 * (y_norm + c_max)  # float32 round-off of sqrt and −
        flat = np.flatnonzero(dist <= (upper + slack)[:, None].astype(np.float32))
        if flat.size == 0:
            continue
        qi, ci = np.divmod(flat, s)
        # ... then the slab bound on the pairs that pass it: −2 Bᵀy by one GEMM on the
        # directions of the cells that occur.
        w2 = (dist.ravel()[flat].astype(np.float64) + cells.radius[ci]) ** 2
        w2_low = np.maximum(w2 - err[qi] - 1e-5 * (y_norm[qi] + c_max) ** 2, 0.0)
        # The cells that occur, ascending, and each pair's position among them: a counting
        # lookup over the s cells (np.unique would sort the pairs: 2.7 s of a 110k match).
        present = np.bincount(ci, minlength=s) > 0
        used = np.flatnonzero(present)
        pos = (np.cumsum(present) - 1)[ci]
        rows_p = (used[:, None] * p + np.arange(p)).ravel()
        proj = qa[:, :d] @ basis_rows[rows_p].T  # (m, |used| p): −2 Bᵀy
        cols_p = pos[:, None] * p + np.arange(p)
        par = -0.5 * proj[qi[:, None], cols_p].astype(np.float64) - centre_in[ci]
        par_norm = np.sqrt(np.einsum("ij,ij->i", par, par))
        par_err = math.sqrt(p) * (gamma + 3.0 * _U32) * y_norm[qi] + target.round[qb[qi]]
        low_par = np.maximum(par_norm - par_err - cells.flat[ci], 0.0)
        perp2 = w2_low - (par_norm + par_err) ** 2
        low_perp = np.maximum(np.sqrt(np.maximum(perp2, 0.0)) - cells.thick[ci], 0.0)
        lower = np.sqrt(low_par**2 + low_perp**2)
        keep = lower <= upper[qi]
        pair_q.append(qb[qi[keep]].astype(np.int32))
        pair_c.append(ci[keep].astype(np.int32))
        pair_lb.append((lower[keep] * (1.0 - 1e-6)).astype(np.float32))
    pq = np.concatenate(pair_q) if pair_q else np.empty(0, dtype=np.int32)
    pc = np.concatenate(pair_c) if pair_c else np.empty(0, dtype=np.int32)
    plb = np.concatenate(pair_lb) if pair_lb else np.empty(0, dtype=np.float32)
    by_cell = np.argsort(pc, kind="stable")
    return best_cell, _Pairs(pq[by_cell], pc[by_cell], plb[by_cell]), n_looked


def _fine_stage(
    cells: _Cells, target: _Target, best_cell: np.ndarray, pairs: _Pairs
) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """Search the cell of every query's nearest sample, then every cell still possible.

    For each query: the best value (float32 products, float64 sums) and its error bound, and
    the smallest "value − error" of every other candidate (the winner is certain when that
    floor stays above "best + error"). Returns the winner's position in cell order, the upper
    bound "best + error" on its squared distance, whether it is certain, and the candidates
    compared.
    """
    s, d = cells.centre.shape
    n2 = target.Y32.shape[0]
    gamma = d * _U32 / (1.0 - d * _U32)
    centre32 = cells.centre.astype(np.float32)
    centre_norm = np.sqrt(cells.centre2.astype(np.float64))
    best_val = np.full(n2, np.inf)
    best_err = np.zeros(n2)
    floor = np.full(n2, np.inf)
    best = np.zeros(n2, dtype=np.int64)
    searched = 0

    def search(c: int, q: np.ndarray) -> None:
        sl = cells.members(c)
        W = target.Y32[q]
        W -= centre32[c]
        w2 = np.einsum("ij,ij->i", W, W, dtype=np.float64)
        W *= -2.0
        dist = W @ cells.offsets[sl].T
        dist += cells.norms[sl]
        r = np.arange(q.shape[0])
        j = np.argmin(dist, axis=1)
        val = dist[r, j].astype(np.float64) + w2
        if dist.shape[1] > 1:
            dist[r, j] = np.inf
            sec = dist.min(axis=1).astype(np.float64) + w2
        else:
            sec = np.full(q.shape[0], np.inf)
        rc = float(cells.radius[c])
        w_norm = np.sqrt(w2)
        e = 2.0 * _U32 * rc * rc + (2.0 * gamma + 6.0 * _U32) * w_norm * rc
        e += 4.0 * _U32 * (w2 + rc * rc)  # the float64 sum of float32 terms
        # W (float32) is y − x_c within ``shift_w``; the offsets are within u·R of theirs.
        shift_w = target.round[q] + _U32 * (centre_norm[c] + w_norm + rc)
        e += 2.0 * shift_w * (w_norm + rc) + shift_w**2
        old, old_e = best_val[q], best_err[q]
        better = val < old
        floor[q] = np.minimum(floor[q], np.where(better, np.minimum(old - old_e, sec - e), val - e))
        best_val[q] = np.where(better, val, old)
        best_err[q] = np.where(better, e, old_e)
        best[q] = np.where(better, sl.start + j, best[q])

    by_cell = np.argsort(best_cell, kind="stable")
    bounds = np.searchsorted(best_cell[by_cell], np.arange(s + 1))
    for c in range(s):
        q = by_cell[bounds[c] : bounds[c + 1]]
        if q.size:
            search(c, q)
            searched += q.size * int(cells.sizes[c])
    bounds = np.searchsorted(pairs.cell, np.arange(s + 1))
    for c in range(s):
        sl = slice(bounds[c], bounds[c + 1])
        q = pairs.query[sl]
        if q.size == 0:
            continue
        q = q[pairs.lower[sl] ** 2 <= best_val[q] + best_err[q]]
        if q.size:
            search(c, q)
            searched += q.size * int(cells.sizes[c])
    upper2 = best_val + best_err
    return best, upper2, floor > upper2, searched


def _redo64(
    queries: np.ndarray,
    best_cell: np.ndarray,
    pairs: _Pairs,
    upper2: np.ndarray,
    cells: _Cells,
    target: _Target,
) -> np.ndarray:
    """Return the answers of an exact float64 search of ``queries`` over their possible cells."""
    phi, Ct, shift, psi, root2 = cells.phi, cells.Ct, cells.shift, target.psi, target.root2
    cols, rows = Ct.shape
    pq, pc, plb = pairs
    n2 = psi.shape[0]
    flag = np.zeros(n2, dtype=bool)
    flag[queries] = True
    keep = flag[pq]
    keep[keep] = plb[keep] ** 2 <= upper2[pq[keep]]
    q_all = np.concatenate([queries, pq[keep]])
    c_all = np.concatenate([best_cell[queries], pc[keep]])
    order = np.argsort(c_all, kind="stable")
    q_all, c_all = q_all[order], c_all[order]
    val = np.full(n2, np.inf)
    idx = np.full(n2, np.iinfo(np.int64).max)
    starts = np.flatnonzero(np.concatenate([[True], c_all[1:] != c_all[:-1]]))
    ends = np.concatenate([starts[1:], [c_all.shape[0]]])
    for a, b in zip(starts, ends, strict=True):
        c = int(c_all[a])
        q = q_all[a:b]
        src = cells.order[cells.members(c)]
        X = phi[src, :cols] @ Ct
        X -= shift
        X -= cells.centre[c]
        W = psi[q, :rows] * root2
        W -= shift
        W -= cells.centre[c]
        dist = np.einsum("ij,ij->i", X, X) - 2.0 * (W @ X.T)
        dist += np.einsum("ij,ij->i", W, W)[:, None]
        low = dist.min(axis=1)
        j = np.where(dist == low[:, None], src[None, :], np.iinfo(np.int64).max).min(axis=1)
        cur_v, cur_i = val[q], idx[q]
        take = (low < cur_v) | ((low == cur_v) & (j < cur_i))
        val[q] = np.where(take, low, cur_v)
        idx[q] = np.where(take, j, cur_i)
    return idx[queries]


def coarse_eigenbasis(
    vertices: Any, count: int, *, k: int = 99, seed: int = 0
) -> tuple[EigenBasis, np.ndarray]:
    """Eigenbasis of a farthest-point subsample of a shape, as a point cloud.

    The 100 eigenpairs of a 110k- or 440k-vertex mesh take minutes; those of a well-spread
    subsample of a few thousand points (point-cloud Laplacian) take a second or two, and a
    map estimated between two such subsamples is carried to the full shapes by
    :func:`extend_p2p` / :func:`extend_fmap`.

    Parameters
    ----------
    vertices : (n, 3) array_like of float
        The full shape's vertices (a mesh's or a point cloud's).
    count : int
        Points kept (farthest-point sampling over a random pool of ``4 · count`` vertices).
    k : int, default 99
        Non-constant eigenfunctions of the subsample.
    seed : int, default 0
        Seed of the pool.

    Returns
    -------
    basis : EigenBasis
        Eigenbasis of the subsample (``count`` points, no faces).
    samples : (count,) ndarray of int64
        Indices of the kept vertices.
    """
    V = as_vertices(vertices)
    count = check_int(count, name="count", minimum=k + 2, maximum=V.shape[0])
    samples, _ = _sample(V, count, seed, assign=False)
    return eigenbasis(V[samples], None, k=k), samples


def _interpolation(coarse: np.ndarray, fine: np.ndarray, neighbours: int) -> sp.csr_matrix:
    """(n_fine, n_coarse) weights: inverse squared distance to the nearest coarse points."""
    n_c = coarse.shape[0]
    kk = min(neighbours, n_c)
    dist, idx = cKDTree(coarse).query(fine, k=kk, workers=-1)
    dist, idx = dist.reshape(fine.shape[0], kk), idx.reshape(fine.shape[0], kk)
    extent = float(np.linalg.norm(coarse.max(axis=0) - coarse.min(axis=0)))
    w = 1.0 / np.maximum(dist, 1e-9 * max(extent, np.finfo(float).tiny)) ** 2
    w /= w.sum(axis=1, keepdims=True)
    rows = np.repeat(np.arange(fine.shape[0]), kk)
    return sp.csr_matrix((w.ravel(), (rows, idx.ravel())), shape=(fine.shape[0], n_c))


def extend_p2p(
    fmap_coarse: Any,
    coarse_1: EigenBasis,
    coarse_2: EigenBasis,
    vertices_1: Any,
    vertices_2: Any,
    *,
    neighbours: int = 4,
    n_samples: int | None = None,
    adjoint: bool = False,
    images: Any = None,
) -> np.ndarray:
    """Point map between two full-resolution shapes from a map between coarse versions.

    The coarse eigenfunctions (unit area) are interpolated to the full shapes' vertices
    (inverse squared distance from the ``neighbours`` nearest coarse points), and every full
    target vertex gets the full source vertex nearest in the embedding, as in
    :func:`local_p2p_from_fmap` with the interpolated bases: the point map has the full
    resolution although no full-resolution eigenpair was computed.

    With ``adjoint=True`` the map is read the other way round: each target vertex's row of
    ``Ψ C`` is compared with the source's rows of ``Φ`` (pyFM's ``use_adj=True``), the
    read-off of a least-squares fit ``Ψ C ≈ Φ[π]`` of the source's functions pulled back by a
    point map ``π`` (this package's convention: ``fmap_from_p2p`` is its projection), such as
    :func:`o3d_ofp.core.partial.partial_polish_fit`'s, whose target basis can be larger than
    the source's. In unit-area terms ``Φ̂ = Φ √A1`` and
    ``Ψ̂ Ĉ = Ψ C √A1``: the same comparison in the bases' own units. A fit made between both
    bases scaled by one common factor (``rescaled(·, A1)`` of :mod:`o3d_ofp.core.partial`) is
    the same; a map converted for the usual read-off (the partial match's ``C · A2/A1``) is not.

    Parameters
    ----------
    fmap_coarse : (k2+1, k1+1) array_like
        Map between the coarse bases, in this package's convention (``Ψ C ≈ Φ[π]`` between
        the bases in their own units).
    coarse_1, coarse_2 : EigenBasis
        Eigenbases of the coarse source and target (a decimated mesh, or
        :func:`coarse_eigenbasis`), in the same coordinates as the full shapes.
    vertices_1, vertices_2 : (n1, 3), (n2, 3) array_like of float
        Full source and target vertices.
    neighbours : int, default 4
        Coarse points each full vertex is interpolated from.
    n_samples : int, optional
        Source cells of the search (see :func:`local_p2p_from_fmap`).
    adjoint : bool, default False
        Compare ``Ψ C`` with ``Φ`` instead of ``Ψ`` with ``Φ Cᵀ`` (above).
    images : (n2, 3) array_like of float, optional
        Where on the source each full target vertex should go, in the source's coordinates:
        the coarse point map's images interpolated along the target
        (``o3d_ofp.workflows.dense.CoarseShape.prolongation``). They join the embedding as
        in :func:`dirichlet_p2p` (unit-area positions weighted by ``a² = DIRICHLET_WEIGHT ·
        k``): the images decide between the full source vertices of a coarse cell, which the
        interpolated eigenfunctions barely tell apart, and the point map follows the coarse
        point map (its landmarks and Dirichlet step) rather than its functional map alone.
        Not with ``adjoint``.

    Returns
    -------
    (n2,) ndarray of int64
        ``p2p_21`` between the full shapes.
    """
    coarse_1 = check_eigenbasis(coarse_1, "coarse_1")
    coarse_2 = check_eigenbasis(coarse_2, "coarse_2")
    V1, V2 = as_vertices(vertices_1, name="vertices_1"), as_vertices(vertices_2, name="vertices_2")
    C = fmap_between(fmap_coarse, coarse_1, coarse_2, "fmap_coarse")
    rows, cols = C.shape
    neighbours = check_int(neighbours, name="neighbours", minimum=1)
    count = _cell_count(n_samples, V1.shape[0])
    t0 = time.perf_counter()
    if not isinstance(adjoint, bool):
        raise TypeError(f"adjoint must be True or False; got {adjoint!r}")
    a1, a2 = coarse_1.area, coarse_2.area
    if adjoint:  # Φ against Ψ C, both times √A1 (a common factor: left out)
        coarse_phi, coarse_psi = coarse_1.evecs[:, :cols], coarse_2.evecs[:, :rows] @ C
        dims, root2 = cols, 1.0
    else:
        Ct = np.ascontiguousarray(C.T) * (a1 / math.sqrt(a2))
        # The source embedding Φ Ĉᵀ is interpolated directly (rows × d instead of cols columns).
        coarse_phi, coarse_psi = coarse_1.evecs[:, :cols] @ Ct, coarse_2.evecs[:, :rows]
        dims, root2 = rows, math.sqrt(a2)
    if images is not None:
        if adjoint:
            raise ValueError("images: not with adjoint=True (a partial fit's read-off)")
        images = as_vertices(images, name="images")
        if images.shape[0] != V2.shape[0]:
            raise ValueError(f"images: one position per target vertex ({V2.shape[0]}) is "
                             f"needed; got {images.shape[0]}")  # fmt: skip
    phi = np.asarray(_interpolation(coarse_1.vertices, V1, neighbours) @ coarse_phi)
    psi = np.asarray(_interpolation(coarse_2.vertices, V2, neighbours) @ coarse_psi)
    if images is not None:
        # unit-area positions (the embeddings are unit-area rows: Ψ √A2 against Φ Ĉᵀ);
        # psi is multiplied by root2 in the search
        a = math.sqrt(DIRICHLET_WEIGHT * (dims - 1)) / math.sqrt(a1)
        phi = np.hstack([phi, a * V1])
        psi = np.hstack([psi, (a / root2) * images])
        dims += 3
    t_interp = time.perf_counter() - t0
    out = _local_search(phi, np.eye(dims), psi, root2, V1, V2, count, 0)
    logger.debug("extend_p2p: interpolation %.2fs, total %.2fs", t_interp, time.perf_counter() - t0)
    return out


def extend_fmap(
    fmap_coarse: Any,
    coarse_1: EigenBasis,
    coarse_2: EigenBasis,
    eig_1: EigenBasis,
    eig_2: EigenBasis,
    *,
    k1: int | None = None,
    k2: int | None = None,
    neighbours: int = 4,
) -> tuple[np.ndarray, np.ndarray]:
    """Carry a map between coarse versions of two shapes to their full-resolution bases.

    :func:`extend_p2p` gives the full-resolution point map; its functional map in the full
    bases ``eig_1``, ``eig_2`` (typically k ≈ 30-40, much cheaper than the coarse k = 99)
    is then ``fmap_from_p2p``.

    Parameters
    ----------
    fmap_coarse : (K2+1, K1+1) array_like
        Map between the coarse bases.
    coarse_1, coarse_2 : EigenBasis
        Coarse source and target eigenbases (same coordinates as the full shapes).
    eig_1, eig_2 : EigenBasis
        Full-resolution source and target eigenbases.
    k1, k2 : int, optional
        Size of the returned map (default: all of ``eig_1``, ``eig_2``).
    neighbours : int, default 4
        Passed to :func:`extend_p2p`.

    Returns
    -------
    fmap_12 : (k2+1, k1+1) ndarray
        The map between the full-resolution bases.
    p2p_21 : (n2,) ndarray of int64
        The full-resolution point map it was projected from.
    """
    eig_1 = check_eigenbasis(eig_1, "eig_1")
    eig_2 = check_eigenbasis(eig_2, "eig_2")
    p2p = extend_p2p(
        fmap_coarse, coarse_1, coarse_2, eig_1.vertices, eig_2.vertices, neighbours=neighbours
    )
    return fmap_from_p2p(p2p, eig_1, eig_2, k1=k1, k2=k2), p2p


def coarse_samples(vertices: np.ndarray, count: int) -> np.ndarray:
    """Return the coarse vertices of :func:`coarse_mesh`: ``count`` well-spread ones, or all.

    :func:`~o3d_ofp.core.fmap.grid_samples`; from ``count >= n`` every vertex: the mesh is its
    own coarse copy. A grid of n cubes keeps only ~0.9 n vertices and re-triangulates the
    rest (measured: FAUST's 6890 vertices became 6228, and a 6890-vertex source matched onto
    a 110k target 0.0215 sqrt(area) off instead of 0.0208 as itself).

    Parameters
    ----------
    vertices : (n, 3) ndarray of float
        The mesh's (welded) vertices.
    count : int
        Coarse vertices wanted.

    Returns
    -------
    (s,) ndarray of int64
        Sorted vertex indices: ``count`` ± 10 % of them, or all ``n``.
    """
    n = vertices.shape[0]
    return np.arange(n, dtype=np.int64) if count >= n else grid_samples(vertices, count)


def coarse_mesh(
    vertices: Any, faces: Any, count: int | None = None, *, samples: Any = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Build a coarse triangle mesh of a dense one: the dual of its geodesic Voronoi cells.

    About ``count`` well-spread vertices (one per occupied cube of a grid in the shape's
    principal frame: O(n), and independent of the pose, scale and vertex order), or the given
    ``samples``, become the coarse vertices; every vertex joins the cell of the sample nearest
    along the mesh's edges (one multi-source Dijkstra, O(n log n)), and every face whose three
    corners lie in three different cells gives a coarse triangle between them (once, oriented
    as that face). Cells follow the surface, so parts close in space but not on the surface
    (hands by the thighs) stay apart. Vertices at one position (a mesh split along its seams,
    an STL file) are welded first, as the cleaning does: cells cross the seams, and the results
    index the given vertices (repeated positions share their cell).

    Parameters
    ----------
    vertices : (n, 3) array_like of float
    faces : (m, 3) array_like of int
    count : int, optional
        Coarse vertices wanted (at most n; the result has ``count`` ± 10 %; ``n``: every vertex,
        the mesh itself).
    samples : (s,) array_like of int, optional
        The coarse vertices themselves, instead of ``count`` (another mesh's, with the same
        triangulation: the two coarse copies then sample the shapes alike).

    Returns
    -------
    coarse_vertices : (s, 3) ndarray of float64
        Positions of the samples.
    coarse_faces : (f, 3) ndarray of int64
        Coarse triangles.
    samples : (s,) ndarray of int64
        Index of every coarse vertex in ``vertices``.
    cell : (n,) ndarray of int64
        Coarse vertex (cell) of every vertex.

    Raises
    ------
    TypeError
        Both or neither of ``count`` and ``samples`` given.
    ValueError
        ``count`` out of [4, n], or ``samples`` not at least 4 distinct indices in [0, n).
    """
    from scipy.sparse.csgraph import dijkstra

    V = as_vertices(vertices)
    F = as_faces(faces, V.shape[0])
    group, first = weld_groups(V)
    if first.shape[0] < V.shape[0]:  # repeated positions: built on one vertex each
        if samples is not None:
            samples = np.asarray(samples)
            if samples.dtype.kind in "iu" and samples.ndim == 1 and samples.size:
                if samples.min() >= 0 and samples.max() < V.shape[0]:
                    samples = np.unique(group[samples])  # a repeated position once
        if count is not None and first.shape[0] >= 4:
            count = min(count, first.shape[0])
        Vc, Fc, picked, cell = coarse_mesh(V[first], group[F], count, samples=samples)
        return Vc, Fc, first[picked], cell[group]
    n = V.shape[0]
    if (count is None) == (samples is None):
        raise TypeError("coarse_mesh takes either count or samples")
    if samples is None:
        samples = coarse_samples(V, check_int(count, name="count", minimum=4, maximum=n))
    else:
        samples = np.asarray(samples)
        if (samples.ndim != 1 or samples.size < 4 or samples.dtype.kind not in "iu"
                or samples.min() < 0 or samples.max() >= n
                or np.unique(samples).size != samples.size):  # fmt: skip
            raise ValueError(f"samples must be at least 4 distinct vertex indices in [0, {n}); "
                             f"got {samples.size} of dtype {samples.dtype}")  # fmt: skip
        samples = samples.astype(np.int64)
    count = samples.shape[0]
    _, _, source = dijkstra(
        edge_graph(V, F), directed=False, indices=samples, min_only=True, return_predecessors=True
    )
    label = np.full(n, -1, dtype=np.int64)
    label[samples] = np.arange(count)
    cell = label[np.maximum(source, 0)]
    cell[source < 0] = -1
    far = np.flatnonzero(cell < 0)  # vertices no sample reaches (other components)
    if far.size:
        cell[far] = cKDTree(V[samples]).query(V[far], k=1, workers=-1)[1]
    L = cell[F]
    L = L[(L[:, 0] != L[:, 1]) & (L[:, 1] != L[:, 2]) & (L[:, 0] != L[:, 2])]
    _, first = unique_rows(np.sort(L, axis=1), return_index=True)
    return V[samples], L[np.sort(first)], samples, cell


def surface_prolongation(
    coarse_vertices: np.ndarray, coarse_faces: np.ndarray, cell: np.ndarray, vertices: np.ndarray
) -> sp.csr_matrix:
    """Interpolation from a :func:`coarse_mesh` to its dense mesh, along the surface.

    Every dense vertex takes the value at its closest point on the coarse triangles around
    the coarse vertex of its own cell (barycentric weights; the samples themselves get their
    own value exactly). Only triangles of its cell are looked at, so a vertex never reads a
    part close in space but not on the surface. The nearest coarse points in space would: on
    a strip folded in two, its arms closer than the coarse spacing (``tests/test_multiscale.py``),
    a smooth function of the arc length read back from the 735 coarse vertices is 113 % off
    (relative L2) through the 4 nearest points' inverse squared distances, 1.3 % through the
    cell's triangles (most of it at the strip's open ends, which no coarse triangle reaches).

    Parameters
    ----------
    coarse_vertices : (s, 3) ndarray of float
        Coarse vertices.
    coarse_faces : (f, 3) ndarray of int
        Coarse triangles.
    cell : (n,) ndarray of int
        Coarse vertex (cell) of every dense vertex.
    vertices : (n, 3) ndarray of float
        Dense vertices.

    Returns
    -------
    (n, s) scipy.sparse.csr_matrix
        Rows of at most three non-negative weights summing to 1 (a vertex whose cell has no
        coarse triangle takes its cell's value).
    """
    Vc = as_vertices(coarse_vertices, name="coarse_vertices")
    V = as_vertices(vertices)
    s = Vc.shape[0]
    Fc = as_faces(coarse_faces, s) if len(coarse_faces) else np.empty((0, 3), dtype=np.int64)
    cell = np.asarray(cell, dtype=np.int64)
    n, nf = V.shape[0], Fc.shape[0]
    around = sp.csr_matrix(
        (np.ones(3 * nf), (Fc.ravel(), np.repeat(np.arange(nf), 3))), shape=(s, nf)
    )  # row c: the coarse triangles at coarse vertex c
    degree = np.diff(around.indptr)[cell]
    best = np.full(n, np.inf)
    corners = np.repeat(cell[:, None], 3, axis=1)
    weights = np.zeros((n, 3))
    weights[:, 0] = 1.0
    for j in range(int(degree.max(initial=0))):  # the j-th triangle around every vertex's cell
        q = np.flatnonzero(degree > j)
        tri = around.indices[around.indptr[cell[q]] + j]
        a, b, c = (Vc[Fc[tri, i]] for i in range(3))
        w = closest_on_triangles(V[q], a, b, c)
        gap = np.linalg.norm(w[:, :1] * a + w[:, 1:2] * b + w[:, 2:] * c - V[q], axis=1)
        closer = np.isfinite(gap) & (gap < best[q])  # (NaN: a degenerate triangle)
        q, tri = q[closer], tri[closer]
        best[q] = gap[closer]
        corners[q] = Fc[tri]
        weights[q] = w[closer]
    return sp.csr_matrix(
        (weights.ravel(), (np.repeat(np.arange(n), 3), corners.ravel())), shape=(n, s)
    )


def cell_restriction(cell: np.ndarray, weights: np.ndarray, count: int) -> sp.csr_matrix:
    """Weighted averages over the cells of a :func:`coarse_mesh`: dense values to coarse ones.

    Parameters
    ----------
    cell : (n,) ndarray of int
        Cell (coarse vertex) of every dense vertex.
    weights : (n,) ndarray of float
        Non-negative weight of every dense vertex (its area: the average is the cell's mean).
    count : int
        Number of cells ``s``.

    Returns
    -------
    (s, n) scipy.sparse.csr_matrix
        Row c averages the values of cell c's vertices (rows of empty or weightless cells
        are zero).
    """
    cell = np.asarray(cell, dtype=np.int64)
    w = np.asarray(weights, dtype=np.float64)
    total = np.bincount(cell, weights=w, minlength=count)
    scale = np.divide(w, total[cell], out=np.zeros_like(w), where=total[cell] > 0)
    return sp.csr_matrix((scale, (cell, np.arange(cell.shape[0]))), shape=(count, cell.shape[0]))
