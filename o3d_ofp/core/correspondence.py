"""Point-to-point maps: nearest neighbours in spectral embeddings, and p2p <-> functional map.

Conventions (``DESIGN.md``): ``fmap_12`` has shape (k2+1, k1+1) and maps source coefficients to
target coefficients; ``p2p_21`` has shape (n2,) and gives, for every target vertex, a source
vertex index (0-based).
"""

from __future__ import annotations

import logging
import math
import time
from typing import Any

import numpy as np
from scipy.sparse.csgraph import dijkstra
from scipy.spatial import cKDTree

from ._threads import single_threaded_below
from ._validation import as_faces, as_vertices, check_int
from .geometry import edge_graph
from .spectrum import EigenBasis

__all__ = [
    "check_fmap",
    "check_p2p",
    "fmap_between",
    "fmap_from_p2p",
    "nearest_neighbors",
    "p2p_from_fmap",
    "p2p_from_template",
    "template_pairs",
]

logger = logging.getLogger(__name__)

#: Up to this many (query × data) pairs the exact blocked brute force is always used.
_BRUTE_MAX_PAIRS = 5e8
#: Queries timed with each method before choosing one for a large search.
_PROBE = 256
#: Queries are scaled to magnitudes of at most 2^this (squared norms stay finite in float64).
_QUERY_EXP_MAX = 480


def _brute64(data: np.ndarray, queries: np.ndarray, d2: np.ndarray) -> np.ndarray:
    """Exact nearest neighbours in float64 by blocks of −2 q·d + ‖d‖² (BLAS-3)."""
    out = np.empty(queries.shape[0], dtype=np.int64)
    # ≤ 32 MB of distances per block, updated in place: large temporaries are fresh pages
    # from the OS every time (page faults cost as much as the product itself).
    step = max(1, int(2**22 // max(data.shape[0], 1)))
    for s in range(0, queries.shape[0], step):
        dist = queries[s : s + step] @ data.T
        dist *= -2.0
        dist += d2
        out[s : s + step] = np.argmin(dist, axis=1)
    return out


def _pow2_exponent(a: np.ndarray) -> int | None:
    """``e`` with ``max|a| · 2⁻ᵉ`` in [1/2, 1); None if ``a`` is empty, zero or not finite."""
    if a.size == 0:
        return None
    top = max(float(a.max()), -float(a.min()))
    return math.frexp(top)[1] if 0.0 < top < math.inf else None


def _pow2_scale(data: np.ndarray, queries: np.ndarray) -> int:
    """Exponent ``k`` such that ``2ᵏ · data`` has its largest magnitude in [1/2, 1).

    Multiplying by a power of two is exact in binary floating point (barring overflow and
    underflow, which is what it avoids) and scales every distance by the same factor, so
    nearest neighbours do not change. ``k`` is lowered when the queries would exceed
    ``2^_QUERY_EXP_MAX``, which keeps their squared norms finite in float64; 0 if both are zero.
    """
    e = _pow2_exponent(data)
    k = 0 if e is None else -e
    e_queries = _pow2_exponent(queries)
    if e_queries is not None:
        k = min(k, _QUERY_EXP_MAX - e_queries)
    return k


def _brute(data: np.ndarray, queries: np.ndarray) -> np.ndarray:
    """Exact nearest neighbours: float32 screening, float64 where the screening is not sure.

    The data are centred and both arrays scaled by a power of two (exact, see
    :func:`_pow2_scale`) so that the data's largest coordinate magnitude is in [1/2, 1): single
    precision then neither overflows nor loses the data to subnormals, and squared norms do
    not overflow or underflow in double precision, whatever the input's scale (1e-200 or
    1e200). Distances ``‖d‖² − 2 q·d`` are computed in single precision (SGEMM: about twice
    the speed of DGEMM, half the memory traffic) with the rounding-error bound of a d-term dot
    product, ``E = 2u·max‖d‖² + (2γ_d + 6u)·‖q‖·max‖d‖`` (u = 2⁻²⁴, γ_d = d·u/(1 − d·u)),
    plus ``2⁻¹⁴⁹·(d + 1 + √d·(max‖d‖ + 2‖q‖))`` for entries or products that fall into
    float32's subnormal range (absolute error at most half of 2⁻¹⁴⁹ each; after the scaling
    this term is some 35 orders of magnitude below the others). A row whose best candidate beats the
    second by more than 2E has that candidate as its exact nearest neighbour; the other rows
    (measured: under 1 % on spectral embeddings), and queries so far away that a float32
    partial sum could overflow, are recomputed in double precision. The result is the float64
    search's, to the index.
    """
    n, dim = data.shape
    k = _pow2_scale(data, queries)  # first bring the magnitudes to O(1): the mean is finite
    if k:
        data, queries = np.ldexp(data, k), np.ldexp(queries, k)
    center = data.mean(axis=0)  # distances do not change; norms (and the bound) shrink
    X = data - center
    Y = queries - center
    k = _pow2_scale(X, Y)  # then the centred data's spread to O(1)
    if k:
        np.ldexp(X, k, out=X)
        np.ldexp(Y, k, out=Y)
    d2 = np.einsum("ij,ij->i", X, X)
    d2_max = float(d2.max())
    if d2_max == 0.0:  # every data point is the same point: all are nearest, take the first
        return np.zeros(Y.shape[0], dtype=np.int64)
    u = float(np.finfo(np.float32).eps) / 2.0
    if dim * u >= 0.1:  # absurd dimensions: no useful single-precision bound
        return _brute64(X, Y, d2)
    gamma = dim * u / (1.0 - dim * u)
    x_max = math.sqrt(d2_max)
    Xt32 = np.ascontiguousarray(X.T, dtype=np.float32)  # (dim, n)
    d2_32 = d2.astype(np.float32)
    q_norm = np.sqrt(np.einsum("ij,ij->i", Y, Y))
    bound = 2.0 * u * d2_max + (2.0 * gamma + 6.0 * u) * q_norm * x_max
    bound += 2.0**-149 * (dim + 1.0 + math.sqrt(dim) * (x_max + 2.0 * q_norm))
    # |partial sums| <= 2‖q‖·max‖d‖ + max‖d‖²: beyond 2^120 float32 might overflow (~2^128).
    far = 2.0 * q_norm * x_max + d2_max > 2.0**120
    any_far = bool(far.any())
    out = np.empty(Y.shape[0], dtype=np.int64)
    # Tiles of 512 queries × 2048 points (4 MB of float32 distances) stay in cache while they
    # are scanned; a running best / second best per query merges the tiles. Measured 2x
    # faster than whole rows of distances (50k × 20k points, 30-D).
    rs, cs = 512, 2048
    # One tile buffer for the whole search: a fresh 4 MB array per tile would be fresh pages
    # from the OS each time (page faults cost as much as the product).
    buf = np.empty((rs, min(cs, n)), dtype=np.float32)
    for s in range(0, Y.shape[0], rs):
        q = -2.0 * Y[s : s + rs]
        if any_far:
            q[far[s : s + rs]] = 0.0  # decided in float64 below; keep the float32 pass finite
        q = q.astype(np.float32)
        m = q.shape[0]
        r = np.arange(m)
        best_val = np.full(m, np.inf, dtype=np.float32)
        second = np.full(m, np.inf, dtype=np.float32)
        best = np.zeros(m, dtype=np.int64)
        for c in range(0, n, cs):
            cols = Xt32[:, c : c + cs]
            dist = np.matmul(q, cols, out=buf[:m, : cols.shape[1]])
            dist += d2_32[c : c + cs]
            tile_best = np.argmin(dist, axis=1)
            tile_val = dist[r, tile_best]
            dist[r, tile_best] = np.inf
            tile_second = np.min(dist, axis=1) if dist.shape[1] > 1 else dist[:, 0]
            better = tile_val < best_val
            second = np.minimum(
                np.minimum(second, tile_second), np.where(better, best_val, tile_val)
            )
            best = np.where(better, tile_best + c, best)
            best_val = np.minimum(best_val, tile_val)
        out[s : s + m] = best
        gap = second.astype(np.float64) - best_val.astype(np.float64)
        sure = gap > 2.0 * bound[s : s + m]
        if any_far:
            sure &= ~far[s : s + m]
        unsure = np.flatnonzero(~sure)
        if unsure.size:
            out[s + unsure] = _brute64(X, Y[s + unsure], d2)
    return out


def _tree(data: np.ndarray, queries: np.ndarray, tree: cKDTree | None = None) -> np.ndarray:
    tree = cKDTree(data) if tree is None else tree
    return tree.query(queries, k=1, workers=-1)[1].astype(np.int64)


def nearest_neighbors(data: Any, queries: Any, *, method: str = "auto") -> np.ndarray:
    """Index of the nearest row of ``data`` for every row of ``queries`` (exact, Euclidean).

    Parameters
    ----------
    data : (n, d) array_like of float
        Points searched.
    queries : (m, d) array_like of float
        Query points.
    method : {"auto", "brute", "kdtree"}, default "auto"
        "brute": blocked matrix products, predictable cost. "kdtree": ``scipy.spatial.cKDTree``
        on all cores, fast on well-aligned low-dimensional embeddings but it degrades badly on
        poorly aligned ones. "auto": brute force for up to 5e8 pairs; above, both are timed
        on 256 queries and the faster is used for the rest, so a degenerate tree never hangs.

    Returns
    -------
    (m,) ndarray of int64
        Row indices into ``data``.

    Raises
    ------
    ValueError
        On mismatched shapes, empty or non-finite data, or an unknown method.

    Notes
    -----
    Both methods work on the inputs scaled by a power of two that brings the data's largest
    magnitude to [1/2, 1): exact in binary floating point, so the answer is that of the
    unscaled search wherever that one is computable, and embeddings of any magnitude
    (1e-200 or 1e200, whose squared distances underflow or overflow in float64) are searched
    as exactly as embeddings of magnitude 1.

    Examples
    --------
    >>> import numpy as np
    >>> import o3d_ofp as ofp
    >>> data = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])
    >>> queries = np.array([[0.9, 0.1], [0.1, 0.2], [0.2, 0.8], [1.0, 1.1]])
    >>> ofp.nearest_neighbors(data, queries).tolist()
    [1, 0, 2, 2]
    """
    X = np.ascontiguousarray(data, dtype=np.float64)
    Y = np.ascontiguousarray(queries, dtype=np.float64)
    if X.ndim != 2 or Y.ndim != 2 or X.shape[1] != Y.shape[1]:
        raise ValueError(f"data and queries must be (n, d) and (m, d); got {X.shape} and {Y.shape}")
    if X.shape[0] == 0:
        raise ValueError("data is empty")
    if method not in ("auto", "brute", "kdtree"):
        raise ValueError(f"method must be one of 'auto', 'brute', 'kdtree'; got {method!r}")
    if not (np.isfinite(X).all() and np.isfinite(Y).all()):
        raise ValueError("data and queries must be finite; they hold NaN or inf")
    k = _pow2_scale(X, Y)
    if k:
        X, Y = np.ldexp(X, k), np.ldexp(Y, k)
    if method == "brute" or (method == "auto" and X.shape[0] * Y.shape[0] <= _BRUTE_MAX_PAIRS):
        return _brute(X, Y)
    if method == "kdtree":
        return _tree(X, Y)
    probe = Y[np.linspace(0, Y.shape[0] - 1, min(_PROBE, Y.shape[0])).astype(int)]
    whole = Y.shape[0] / probe.shape[0]  # the whole search's time over the probe's
    t0 = time.perf_counter()
    tree = cKDTree(X)
    t1 = time.perf_counter()
    _tree(X, probe, tree)
    t2 = time.perf_counter()
    _brute(X, probe)
    use_tree = (t1 - t0) + (t2 - t1) * whole < (time.perf_counter() - t2) * whole
    logger.debug("nearest_neighbors: %d x %d in %d-D via %s", X.shape[0], Y.shape[0],
                 X.shape[1], "kd-tree" if use_tree else "brute force")  # fmt: skip
    return _tree(X, Y, tree) if use_tree else _brute(X, Y)


def check_fmap(fmap: Any, rows: int, cols: int, *, name: str = "fmap_12") -> np.ndarray:
    """Return the top-left (rows, cols) block of a functional map after checking its shape."""
    C = np.asarray(fmap, dtype=np.float64)
    if C.ndim != 2:
        raise ValueError(f"{name} must be a 2-D matrix; got shape {C.shape}")
    if C.shape[0] < rows or C.shape[1] < cols:
        raise ValueError(
            f"{name} has shape {C.shape} but at least ({rows}, {cols}) = (k2+1, k1+1) is needed "
            "(target rows, source columns; are source and target swapped?)"
        )
    if not np.all(np.isfinite(C)):
        raise ValueError(f"{name} holds NaN or inf")
    return C[:rows, :cols]


def fmap_between(C: Any, eig_1: EigenBasis, eig_2: EigenBasis, name: str = "fmap_12") -> np.ndarray:
    """Check a whole functional map against the bases it maps between (at most their sizes)."""
    C = np.asarray(C, dtype=np.float64)
    if C.ndim != 2:
        raise ValueError(f"{name} must be a 2-D matrix; got shape {C.shape}")
    if not (1 <= C.shape[0] <= eig_2.k + 1 and 1 <= C.shape[1] <= eig_1.k + 1):
        raise ValueError(
            f"{name} has shape {C.shape} but the eigenbases allow at most "
            f"({eig_2.k + 1}, {eig_1.k + 1}) (target rows, source columns)"
        )
    return check_fmap(C, *C.shape, name=name)


def check_p2p(p2p: Any, n_target: int, n_source: int, *, name: str = "p2p_21") -> np.ndarray:
    """Check a target-to-source vertex map: shape (n_target,), values in [0, n_source)."""
    p = np.asarray(p2p)
    if p.ndim != 1 or not np.issubdtype(p.dtype, np.integer):
        raise TypeError(f"{name} must be a 1-D integer array; got dtype {p.dtype} shape {p.shape}")
    if p.shape[0] != n_target:
        raise ValueError(
            f"{name} has {p.shape[0]} entries but the target has {n_target} vertices "
            "(p2p_21 gives a source vertex for every target vertex)"
        )
    if p.size and (p.min() < 0 or p.max() >= n_source):
        one_based = p.min() >= 1 and p.max() == n_source
        raise ValueError(
            f"{name} values must be source vertex indices in [0, {n_source}); "
            f"got range [{p.min()}, {p.max()}]"
            + (" (1-based indices? they count from 0: subtract 1)" if one_based else "")
        )
    return p.astype(np.int64)


def fmap_from_p2p(
    p2p_21: Any,
    eig_1: EigenBasis,
    eig_2: EigenBasis,
    *,
    k1: int | None = None,
    k2: int | None = None,
) -> np.ndarray:
    """Functional map of a point-to-point map: ``C = Ψᵀ M₂ Φ[p2p_21]`` (mass-weighted projection).

    Parameters
    ----------
    p2p_21 : (n2,) array_like of int
        For every target vertex, its source vertex.
    eig_1, eig_2 : EigenBasis
        Source and target eigenbases.
    k1, k2 : int, optional
        Non-constant eigenfunctions used on each side (default: all).

    Returns
    -------
    (k2+1, k1+1) ndarray
        ``fmap_12``, mapping source coefficients to target coefficients.

    Examples
    --------
    >>> import numpy as np
    >>> import open3d as o3d
    >>> import o3d_ofp as ofp
    >>> sphere = o3d.geometry.TriangleMesh.create_sphere(radius=1.0, resolution=10)
    >>> eig = ofp.eigenbasis(sphere, k=8)
    >>> C = ofp.fmap_from_p2p(np.arange(182), eig, eig)  # the identity map
    >>> C.shape, bool(np.allclose(C, np.eye(9)))
    ((9, 9), True)
    """
    k1 = eig_1.k if k1 is None else check_int(k1, name="k1", minimum=1, maximum=eig_1.k)
    k2 = eig_2.k if k2 is None else check_int(k2, name="k2", minimum=1, maximum=eig_2.k)
    p = check_p2p(p2p_21, eig_2.n_vertices, eig_1.n_vertices)
    psi = eig_2.evecs[:, : k2 + 1]
    return psi.T @ (eig_2.mass[:, None] * eig_1.evecs[p, : k1 + 1])


def p2p_from_fmap(
    fmap_12: Any, eig_1: EigenBasis, eig_2: EigenBasis, *, method: str = "auto"
) -> np.ndarray:
    """Point-to-point map of a functional map: nearest neighbour of each row of Ψ among ΦCᵀ.

    Parameters
    ----------
    fmap_12 : (k2+1, k1+1) array_like
        Functional map from source to target coefficients.
    eig_1, eig_2 : EigenBasis
        Source and target eigenbases (with at least k1 and k2 non-constant functions).
    method : {"auto", "brute", "kdtree"}
        Passed to :func:`nearest_neighbors`.

    Returns
    -------
    (n2,) ndarray of int64
        ``p2p_21``: for every target vertex, a source vertex.

    References
    ----------
    .. [1] M. Ovsjanikov et al., "Functional Maps: A Flexible Representation of Maps Between
       Shapes", ACM TOG 31(4), 2012.

    Examples
    --------
    >>> import numpy as np
    >>> import open3d as o3d
    >>> import o3d_ofp as ofp
    >>> sphere = o3d.geometry.TriangleMesh.create_sphere(radius=1.0, resolution=10)
    >>> eig = ofp.eigenbasis(sphere, k=8)
    >>> p2p = ofp.p2p_from_fmap(np.eye(9), eig, eig)
    >>> p2p.shape, bool((p2p == np.arange(182)).all())
    ((182,), True)
    """
    C = fmap_between(fmap_12, eig_1, eig_2)
    rows, cols = C.shape
    # fmap_12 maps coefficients in the shapes' own eigenbases (fmap_from_p2p's convention, in
    # which a copy scaled to s² the area has C = s·I): on unit-area bases the mapped source
    # rows are A1/A2 times Φ Cᵀ, so the two embeddings are compared at the same scale.
    with single_threaded_below(max(eig_1.n_vertices, eig_2.n_vertices)):
        mapped = eig_1.evecs[:, :cols] @ C.T * (eig_1.area / eig_2.area)
        return nearest_neighbors(mapped, eig_2.evecs[:, :rows], method=method)


def template_pairs(corr_1: Any, corr_2: Any) -> tuple[np.ndarray, np.ndarray]:
    """Return the listed target vertices of two template files and the source vertex of each.

    A target vertex listed on several rows takes the source vertex of its first row.

    Parameters
    ----------
    corr_1, corr_2 : (t,) array_like of int
        0-based source / target vertex of each template point.

    Returns
    -------
    listed : (u,) ndarray of int
        The distinct target vertices, ascending.
    images : (u,) ndarray of int
        The source vertex of each.
    """
    listed, first = np.unique(np.asarray(corr_2), return_index=True)
    return listed, np.asarray(corr_1)[first]


def p2p_from_template(
    corr_1: Any, corr_2: Any, vertices_2: Any, *, faces_2: Any | None = None
) -> np.ndarray:
    """Dense target→source map from correspondences of both shapes to a common template.

    Benchmarks (FAUST remeshed, TOSCA, SHREC) give, for each shape, the vertex matching each
    template point (``.vts`` files). Target vertices listed there get the source vertex of the
    same template point; every other target vertex takes the answer of the nearest listed
    target vertex: along the target's edges when its ``faces_2`` are given (vertices of a
    piece holding no listed vertex: in space), else in space. Along the surface a hand resting
    on a thigh does not take the thigh's answer: measured on FAUST remeshed 000 -> 007 with
    every 11th of its 5000 template rows (9 % of the target listed), mean geodesic error of
    the filled vertices ×100 / √area 4.87 in space, 3.67 along the edges; with every 50th,
    8.10 and 4.75. Whether the two files belong to these shapes is not checked here:
    ``o3d_ofp.workflows.maps.template_misfit`` says when they do not (the command line
    checks with it).

    Parameters
    ----------
    corr_1, corr_2 : (t,) array_like of int
        0-based source / target vertex of each template point.
    vertices_2 : (n2, 3) array_like of float
        Target vertices.
    faces_2 : (m2, 3) array_like of int, optional
        Target triangles (0-based): the unlisted vertices take their answer along its edges.

    Returns
    -------
    p2p_21 : (n2,) ndarray of int64
        Source vertex of every target vertex.

    Examples
    --------
    Two template points, matched to source vertices 5 and 7 and to target vertices 0 and 3;
    the other target vertices take the answer of the nearest of those two:

    >>> import numpy as np
    >>> import o3d_ofp as ofp
    >>> target = np.array([[0.0, 0.0, 0.0], [0.4, 0.0, 0.0], [0.7, 0.0, 0.0], [1.0, 0.0, 0.0]])
    >>> ofp.p2p_from_template([5, 7], [0, 3], target).tolist()
    [5, 5, 7, 7]
    """
    a = np.asarray(corr_1)
    b = np.asarray(corr_2)
    V2 = as_vertices(vertices_2, name="vertices_2")
    if a.ndim != 1 or a.shape != b.shape or a.size == 0:
        raise ValueError(
            f"corr_1 and corr_2 must be 1-D of equal, non-zero length; got {a.shape} and {b.shape}"
        )
    if not (np.issubdtype(a.dtype, np.integer) and np.issubdtype(b.dtype, np.integer)):
        raise TypeError("corr_1 and corr_2 must hold integer vertex indices")
    if b.min() < 0 or b.max() >= V2.shape[0]:
        raise ValueError(
            f"corr_2 indices span [{b.min()}, {b.max()}] but the target has {V2.shape[0]} vertices"
        )
    if a.min() < 0:
        raise ValueError("corr_1 holds negative vertex indices")
    listed, images = template_pairs(a, b)
    source_of = np.full(V2.shape[0], -1, dtype=np.int64)
    source_of[listed] = images
    nearest = listed[nearest_neighbors(V2[listed], V2)]
    if faces_2 is not None:
        F2 = as_faces(faces_2, V2.shape[0], name="faces_2")
        # scipy gives each vertex the listed vertex it is nearest along the edges (-9999: none
        # in its piece of the mesh, which keeps the nearest in space)
        _, _, along = dijkstra(edge_graph(V2, F2), directed=False, indices=listed,
                               return_predecessors=True, min_only=True)  # fmt: skip
        nearest = np.where(along >= 0, along, nearest)
    return source_of[nearest]
