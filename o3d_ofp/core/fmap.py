"""Functional maps: estimation, refinement (ICP, ZoomOut) and lifting to eigenproducts.

``fmap_12`` has shape (k2+1, k1+1): it maps the coefficients of a source function in the source
eigenbasis (constant first) to those of its image in the target eigenbasis.
"""

from __future__ import annotations

import dataclasses
import functools
import logging
import math
from collections.abc import Iterator, Sequence
from concurrent.futures import ThreadPoolExecutor
from typing import Any, NamedTuple

import numpy as np
import scipy.linalg
import scipy.optimize
import scipy.sparse as sp
import scipy.spatial
from scipy.sparse import csgraph
from scipy.sparse.linalg import splu

from ._threads import one_blas_thread
from ._validation import check_int
from .correspondence import check_fmap, fmap_from_p2p, nearest_neighbors, p2p_from_fmap
from .descriptors import hks, wks
from .geometry import edge_graph, face_areas_normals, hat_gradients, outward_sign, point_frames
from .products import eigenproduct_indices
from .spectrum import EigenBasis, check_eigenbasis

__all__ = [
    "LANDMARK_DISTANCES",
    "LANDMARK_SCALES",
    "LANDMARK_WEIGHT",
    "Anchors",
    "estimate_fmap",
    "estimate_fmaps",
    "farthest_points",
    "icp_refine",
    "landmark_anchors",
    "landmark_coordinates",
    "landmark_embedding",
    "lift_fmap",
    "unit_area",
    "zoomout_refine",
]

logger = logging.getLogger(__name__)

#: :func:`farthest_points` samples ``count`` of at most this many times ``count`` vertices
#: (spread by :func:`grid_samples`) on shapes larger than that: with 2000 samples, above 64k
#: vertices. Smaller pools change the samples of mid-sized shapes enough to move their maps
#: (measured, ZoomOut on FAUST x4 = 27.5k vertices: pool 4x 0.0273, 8x 0.0291, exact 0.0255).
FPS_POOL = 32
#: The commutativity and orientation terms use every OPERATOR_STEP-th descriptor (pyFM's
#: documented ``subsample_step=5``: 20 of 100 wave-kernel energies); the descriptor term uses
#: all of them. Measured on the 6 ground-truth pairs of ../shared/data (scripts/eval_matching.py
#: pairs, fits of 29 and 39, ZoomOut to 99): step 1 (all 100) 0.0166 / 0.1868 / 0.0149 /
#: 0.0133 / 0.0212 / 0.324, step 5 0.0143 / 0.1868 / 0.0149 / 0.0133 / 0.0212 / 0.494 (both
#: SHREC'19 maps are wrong), step 10 loses the centaurs (0.0194); the operators, their Hessians
#: and the solves take about a third of the time with step 5 (the match: 14.3 s against 21.2
#: s over the six pairs).
OPERATOR_STEP = 5


def unit_area(eig: EigenBasis) -> EigenBasis:
    """Return the same eigenbasis on the shape centred and scaled to unit area.

    Eigenfunctions scale by √area, eigenvalues by area, the mass by 1/area; the stiffness of
    a surface does not change. Map estimation and refinement work on these, so that their
    result does not depend on the units of either shape.

    Parameters
    ----------
    eig : EigenBasis

    Returns
    -------
    EigenBasis
        A new basis (no digest, the same cleaning map).
    """
    return _scaled(eig, eig.area)


def _scaled(eig: EigenBasis, area: float) -> EigenBasis:
    """Return the basis on the shape centred and divided by ``sqrt(area)``.

    Eigenvalues times ``area``, eigenfunctions times ``sqrt(area)``, mass divided by ``area``;
    no digest (:func:`unit_area` and :func:`o3d_ofp.core.partial.rescaled`).
    """
    root = math.sqrt(area)
    centre = (eig.mass @ eig.vertices) / eig.area
    return dataclasses.replace(
        eig,
        evals=eig.evals * area,
        evecs=eig.evecs * root,
        mass=eig.mass / area,
        vertices=(eig.vertices - centre) / root,
        digest="",
    )


def _projection(eig: EigenBasis, k: int) -> np.ndarray:
    """(k+1, n) mass-weighted transpose of the first k+1 eigenvectors: f ↦ Φᵀ M f."""
    return (eig.evecs[:, : k + 1] * eig.mass[:, None]).T


def _descriptors(
    eig: EigenBasis, kind: str, n: int, landmarks: np.ndarray | None, k: int, geodesic: bool,
    step: int, functions: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """Return the descriptors and the functions of the fits' operators, each of unit norm.

    The operators (commutativity, orientation) take every ``step``-th descriptor of the
    family; with landmarks between meshes (``geodesic``), each landmark's distance function
    and biharmonic coordinate too (see :data:`LANDMARK_SCALES`; ``functions``: those already
    computed, an :class:`Anchors`' ``distances_1`` or ``distances_2``); with a point cloud,
    every ``step``-th column of the landmarks' kernel maps, continuing the same stride. A
    column that is zero on a shape (a landmark's Gaussian on a piece the cleaning left out)
    stays zero, so that both shapes keep the same columns.
    """
    fn = wks if kind == "wks" else hks
    kw = {"n_energies": n, "k": k} if kind == "wks" else {"n_times": n, "k": k}
    family = fn(eig, **kw)
    parts, ops = [family], [family[:, ::step]]
    if landmarks is not None and geodesic:
        if functions is None:
            functions = _landmark_functions(eig, landmarks)
        d, w = np.hsplit(functions, 2)
        parts += [*(np.exp(-((d / s) ** 2)) for s in LANDMARK_SCALES), d, w]
        ops += [d, w]
    elif landmarks is not None:
        kernels = fn(eig, landmarks=landmarks, **kw)
        parts.append(kernels)
        ops.append(kernels[:, (-family.shape[1]) % step :: step])
    return _unit_columns(eig, np.hstack(parts)), _unit_columns(eig, np.hstack(ops))


def _unit_columns(eig: EigenBasis, D: np.ndarray) -> np.ndarray:
    """Columns scaled to unit mass norm (zero columns stay zero)."""
    norms = np.sqrt(eig.mass @ D**2)
    return D / np.where(norms > 0, norms, 1.0)


#: Vertices per chunk when building the descriptor operators: bounds the temporary
#: (rows, (k+1)²) product matrix to ~15 MB at k = 29.
_CHUNK = 2048


def _descriptor_ops(eig: EigenBasis, k: int, D: np.ndarray) -> np.ndarray:
    """Stack (p, k+1, k+1) of the multiplication operators Φᵀ M diag(dᵢ) Φ (chunked GEMMs).

    The operators are symmetric: only the pairs a <= b of eigenfunctions are multiplied and
    summed (half the products of all pairs), then mirrored.
    """
    phi = eig.evecs[:, : k + 1]
    a = k + 1
    rows, cols = np.triu_indices(a)
    MD = eig.mass[:, None] * D
    T = np.zeros((rows.size, D.shape[1]))
    P_buf = np.empty((min(_CHUNK, phi.shape[0]), rows.size))  # reused: no fresh pages per chunk
    for s in range(0, phi.shape[0], _CHUNK):
        ph = phi[s : s + _CHUNK]
        P = P_buf[: ph.shape[0]]
        start = 0
        for i in range(a):  # row i of the upper triangle: φ_i φ_j for j >= i
            np.multiply(ph[:, i : i + 1], ph[:, i:], out=P[:, start : start + a - i])
            start += a - i
        T += P.T @ MD[s : s + _CHUNK]
    ops = np.empty((D.shape[1], a, a))
    ops[:, rows, cols] = T.T
    ops[:, cols, rows] = T.T
    return ops


def _orientation_ops(eig: EigenBasis, k: int, D: np.ndarray) -> np.ndarray:
    """Stack (p, k+1, k+1) of the reduced operators g ↦ <n × ∇dᵢ, ∇g> (Ren et al. 2018).

    ``O_i[b, a] = Σ_x W[x, b] H[x, a, i]`` with ``H[x, a, i] = ∇φ_a · (n × ∇d_i)`` and ``W``
    the weights of Φ: on a mesh, per face, the area-weighted face sums of Φ (``to_vertexᵀ Φ``:
    the per-face field spread to the vertices by area, then projected with Φᵀ M); on a point
    cloud, per point, ``M Φ`` (:func:`_point_fields`). One GEMM per chunk.
    """
    a, p = k + 1, D.shape[1]
    T = np.zeros((a, a * p))
    fields = _face_fields if eig.faces is not None else _point_fields
    for W, H in fields(eig, eig.evecs[:, :a], D):
        T += W.T @ H.reshape(H.shape[0], a * p)
    return np.ascontiguousarray(T.reshape(a, a, p).transpose(2, 0, 1))


def _face_fields(eig: EigenBasis, phi: np.ndarray, D: np.ndarray) -> Iterator[tuple[Any, Any]]:
    """Yield :func:`_orientation_ops`' ``(W, H)`` of a mesh, by chunks of faces.

    Everything per chunk of faces, from the corner values and hat gradients (no sparse
    products): memory stays ~(chunk · (k+1) · p) doubles (50 MB at k = 29, p = 100) however
    large the mesh.
    """
    V, F = eig.vertices, eig.faces
    areas, normals = face_areas_normals(V, F)
    # Outward normals whatever the winding: a shape whose faces are wound inwards would
    # otherwise make the orientation-preserving term prefer the mirror map (measured: FAUST
    # 093 -> 087 with the target's faces reversed, 0.068 instead of 0.014).
    normals = normals * outward_sign(V, F)
    hats = hat_gradients(V, F)  # (m, 3 corners, 3 coords)
    H_buf = np.empty((min(_CHUNK, F.shape[0]), phi.shape[1], D.shape[1]))  # reused per chunk
    for s in range(0, F.shape[0], _CHUNK):
        sl = slice(s, s + _CHUNK)
        f, E = F[sl], hats[sl]
        phi_c = phi[f]  # (c, 3 corners, k+1)
        grad_phi = np.matmul(phi_c.transpose(0, 2, 1), E)  # (c, k+1, 3): ∇φ_a
        gd = np.matmul(E.transpose(0, 2, 1), D[f])  # (c, 3, p): ∇d_i
        rot = np.cross(normals[sl, :, None], gd, axis=1)  # (c, 3, p): n × ∇d_i on each face
        W = (areas[sl] / 3.0)[:, None] * phi_c.sum(axis=1)  # area-weighted corner sums
        yield W, np.matmul(grad_phi, rot, out=H_buf[: f.shape[0]])  # ∇φ_a · (n × ∇d_i)


def _point_fields(eig: EigenBasis, phi: np.ndarray, D: np.ndarray) -> Iterator[tuple[Any, Any]]:
    """Yield :func:`_orientation_ops`' ``(W, H)`` of a point cloud, by chunks of points.

    The same integral, sampled at the points: ``W = M Φ`` and the outward normals and the
    tangent-plane gradients of :mod:`o3d_ofp.core.geometry` (:func:`point_frames`: the
    gradients of :func:`point_gradient_operator` with the normals of :func:`point_normals`,
    from one neighbour search). In the frame ``(t₁, t₂, n)``, ``n × (g₁t₁ + g₂t₂) =
    g₁t₂ − g₂t₁``, so ``∇φ · (n × ∇d) = ∇₂φ ∇₁d − ∇₁φ ∇₂d``.
    """
    g1, g2 = point_frames(eig.vertices, eig.mass)
    p1, p2, d1, d2 = g1 @ phi, g2 @ phi, g1 @ D, g2 @ D  # (n, a), (n, a), (n, p), (n, p)
    W = eig.mass[:, None] * phi
    for s in range(0, phi.shape[0], _CHUNK):
        sl = slice(s, s + _CHUNK)
        yield W[sl], p2[sl, :, None] * d1[sl, None, :] - p1[sl, :, None] * d2[sl, None, :]


#: Weights of a map's energy terms: descriptors, Laplacian, commutativity, orientation.
_Weights = tuple[float, float, float, float]


class _Commutator:
    """The term ½ Σᵢ ‖C O1ᵢ − O2ᵢ C‖² for stacks O1 (p, a, a), O2 (p, b, b), as four GEMMs."""

    def __init__(self, O1: np.ndarray, O2: np.ndarray) -> None:
        p, a, _ = O1.shape
        b = O2.shape[1]
        self.p, self.a, self.b = p, a, b
        self.O1, self.O2 = O1, O2
        self.O1_h = np.ascontiguousarray(O1.transpose(1, 0, 2).reshape(a, p * a))  # [O1_1 ..]
        self.O1T_v = np.ascontiguousarray(O1.transpose(0, 2, 1).reshape(p * a, a))  # [O1_iᵀ;]
        self.O2_v = np.ascontiguousarray(O2.reshape(p * b, b))  # [O2_1; O2_2; ...]
        self.O2T_h = np.ascontiguousarray(O2.transpose(2, 0, 1).reshape(b, p * b))  # [O2_iᵀ ..]

    def __call__(self, C: np.ndarray) -> tuple[float, np.ndarray]:
        p, a, b = self.p, self.a, self.b
        O2C = (self.O2_v @ C).reshape(p, b, a).transpose(1, 0, 2).reshape(b, p * a)
        d = C @ self.O1_h - O2C  # block i (columns i·a .. i·a+a): C O1_i − O2_i C
        d_v = d.reshape(b, p, a).transpose(1, 0, 2).reshape(p * b, a)  # [d_1; d_2; ...]
        grad = d @ self.O1T_v - self.O2T_h @ d_v  # Σ d_i O1_iᵀ − Σ O2_iᵀ d_i
        return 0.5 * float(np.sum(d * d)), grad

    def hessian(self) -> np.ndarray:
        """(b·a, b·a) Hessian of the term in the row-major vectorization of C (b, a).

        ``vec(C P) = (I ⊗ Pᵀ) vec C`` and ``vec(Q C) = (Q ⊗ I) vec C``, so the term is
        ``½ Σᵢ ‖Kᵢ vec C‖²`` with ``Kᵢ = I ⊗ O1ᵢᵀ − O2ᵢ ⊗ I`` and
        ``Σ KᵢᵀKᵢ = I ⊗ Σ O1ᵢO1ᵢᵀ + Σ O2ᵢᵀO2ᵢ ⊗ I − (M + Mᵀ)``, ``M = Σᵢ O2ᵢ ⊗ O1ᵢ``.
        """
        a, b = self.a, self.b
        P = self.O1_h @ self.O1_h.T  # Σ O1ᵢ O1ᵢᵀ
        Q = self.O2_v.T @ self.O2_v  # Σ O2ᵢᵀ O2ᵢ
        H = np.kron(np.eye(b), P) + np.kron(Q, np.eye(a))
        # M[(r, s), (t, u)] = Σᵢ O2ᵢ[r, t] O1ᵢ[s, u]: one GEMM over the stack axis
        M = np.tensordot(self.O2, self.O1, axes=(0, 0)).transpose(0, 2, 1, 3)
        M = M.reshape(b * a, b * a)
        H -= M
        H -= M.T
        return H


def _energy(
    C: np.ndarray,
    A: np.ndarray,
    B: np.ndarray,
    sqdiff: np.ndarray,
    ops: _Commutator | None,
    orient: _Commutator | None,
    weights: _Weights,
) -> tuple[float, np.ndarray]:
    """Evaluate the map energy of :func:`estimate_fmap` and its gradient with respect to C."""
    wd, wl, wc, wo = weights
    diff = C @ A - B
    energy = 0.5 * wd * np.sum(diff**2) + 0.5 * wl * np.sum(C**2 * sqdiff)
    grad = wd * diff @ A.T + wl * C * sqdiff
    for w, term in ((wc, ops), (wo, orient)):
        if w == 0 or term is None:
            continue
        e, g = term(C)
        energy += w * e
        grad += w * g
    return float(energy), grad


def _minimize_quadratic(
    C0: np.ndarray,
    A: np.ndarray,
    B: np.ndarray,
    sqdiff: np.ndarray,
    ops: _Commutator | None,
    orient: _Commutator | None,
    weights: _Weights,
) -> np.ndarray:
    """Exact minimizer of the :func:`_energy` over C with its first column fixed to C0's.

    The energy is ``½ cᵀ H c − gᵀ c + const`` in the row-major vectorization c of C (b, a),
    with ``H = wd I ⊗ A Aᵀ + wl diag(sqdiff) + wc H_dcomm + wo H_orient`` and
    ``g = wd vec(B Aᵀ)``; the free entries solve ``H_ff c_f = g_f − H_fx c_x``.
    """
    wd, wl, wc, wo = weights
    b, a = C0.shape
    H = wd * np.kron(np.eye(b), A @ A.T)
    H[np.diag_indices_from(H)] += wl * sqdiff.ravel()
    for w, term in ((wc, ops), (wo, orient)):
        if w != 0 and term is not None:
            H += w * term.hessian()
    g = wd * (B @ A.T).ravel()
    fixed = np.zeros((b, a), dtype=bool)
    fixed[:, 0] = True
    fixed = fixed.ravel()
    free = ~fixed
    rhs = g[free] - H[np.ix_(free, fixed)] @ C0.ravel()[fixed]
    H_ff = H[np.ix_(free, free)]
    try:
        x = scipy.linalg.cho_solve(scipy.linalg.cho_factor(H_ff, check_finite=False), rhs)
    except np.linalg.LinAlgError:  # only semi-definite (e.g. descriptors of rank < a)
        x = scipy.linalg.lstsq(H_ff, rhs, check_finite=False)[0]
    c = C0.ravel().copy()
    c[free] = x
    return c.reshape(b, a)


class _Energy(NamedTuple):
    """The terms of a map's :func:`_energy`, and their minimizer over the maps C.

    The minimizer keeps the first column of its start C0 (the constant's image).
    """

    A: np.ndarray
    B: np.ndarray
    sqdiff: np.ndarray
    ops: _Commutator | None
    orient: _Commutator | None

    def orientation_weighted(self, ref: np.ndarray, weights: _Weights, w_orient: float) -> _Weights:
        """Return ``weights`` with an orientation weight relative to the other terms.

        At the reference map ``ref``, the orientation term weighs ``w_orient`` times the other
        terms (with ``weights``, whose orientation weight is ignored).
        """
        native = _energy(ref, self.A, self.B, self.sqdiff, self.ops, None, weights)[0]
        unit = (0.0, 0.0, 0.0, 1.0)
        o_energy = _energy(ref, self.A, self.B, self.sqdiff, None, self.orient, unit)[0]
        return (*weights[:3], w_orient * native / max(o_energy, 1e-300))

    def solve(
        self, C0: np.ndarray, weights: _Weights, solver: str, options: dict[str, Any], what: str,
        w_rows: float = 0.0,
    ) -> np.ndarray:  # fmt: skip
        """Minimize from C0: exactly (``"direct"``: :func:`_minimize_quadratic`) or by L-BFGS-B.

        L-BFGS-B (``options``: SciPy's) minimizes the energy plus ``½ w_rows ‖C Cᵀ − I‖²``;
        ``what`` names the fit in the debug log.
        """
        b, a = C0.shape
        if solver == "direct":
            C = _minimize_quadratic(C0, *self, weights)
            energy = _energy(C, *self, weights)[0]
            logger.debug("%s: direct solve %dx%d (energy %.4g)", what, b, a, energy)
            return C
        eye = np.eye(b)

        def fun(x: np.ndarray) -> tuple[float, np.ndarray]:
            C = x.reshape(b, a)
            e, g = _energy(C, *self, weights)
            if w_rows > 0:  # a restriction has orthonormal rows: C Cᵀ = I
                R = C @ C.T - eye
                e += 0.5 * w_rows * float(np.sum(R * R))
                g = g + 2.0 * w_rows * (R @ C)
            g[:, 0] = 0.0  # the first column stays fixed
            return e, g.ravel()

        res = scipy.optimize.minimize(fun, C0.ravel(), jac=True, method="L-BFGS-B", options=options)
        logger.debug(
            "%s: L-BFGS-B %dx%d, %s after %d iterations (energy %.4g)",
            what, b, a, res.message, res.nit, res.fun,
        )  # fmt: skip
        return res.x.reshape(b, a)


def _shape_terms(
    eig: EigenBasis, k: int, D: np.ndarray, Dop: np.ndarray, dcomm: bool, orient: bool
) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
    """One shape's terms: descriptor coefficients (k+1, p) and the operator stacks of ``Dop``.

    The multiplication (``dcomm``) and orientation (``orient``) operators, or None.
    """
    return (
        _projection(eig, k) @ D,
        _descriptor_ops(eig, k, Dop) if dcomm else None,
        _orientation_ops(eig, k, Dop) if orient else None,
    )


def _energy_of(
    eig_1: EigenBasis, eig_2: EigenBasis, terms: tuple, a: int, b: int, wanted: tuple
) -> _Energy:
    """Build the energy of (b, a) maps from both shapes' :func:`_shape_terms` (leading blocks).

    ``wanted``: whether the commutativity and the orientation terms are; the Laplacian term is
    normalized to unit sum.
    """
    (A, dcomm_1, orient_1), (B, dcomm_2, orient_2) = terms
    sqdiff = (eig_1.evals[None, :a] - eig_2.evals[:b, None]) ** 2
    sqdiff /= sqdiff.sum()

    def block(O1: Any, O2: Any, wanted: bool) -> _Commutator | None:
        return _Commutator(O1[:, :a, :a], O2[:, :b, :b]) if wanted and O1 is not None else None

    dcomm, orient = wanted
    return _Energy(A[:a], B[:b], sqdiff, block(dcomm_1, dcomm_2, dcomm),
                   block(orient_1, orient_2, orient))  # fmt: skip


def _landmark_pairs(landmarks: Any) -> tuple[np.ndarray | None, np.ndarray | None]:
    """Split (p, 2) landmark pairs into source and target vertices (None, None without)."""
    if landmarks is None:
        return None, None
    lm = np.asarray(landmarks)
    if lm.ndim != 2 or lm.shape[1] != 2 or not np.issubdtype(lm.dtype, np.integer):
        raise ValueError(
            f"landmarks must be a (p, 2) integer array of vertex pairs; got {lm.dtype}{lm.shape}"
        )
    return lm[:, 0], lm[:, 1]


def _landmark_vertices(
    landmarks: Any, eig_1: EigenBasis, eig_2: EigenBasis
) -> tuple[np.ndarray, np.ndarray]:
    """Split (p, 2) landmark pairs into source and target vertices, each checked on its shape."""
    source, target = _landmark_pairs(landmarks)
    if source is None or target is None or source.size == 0:
        raise ValueError("landmarks: give at least one (source, target) pair")
    source, target = source.astype(np.int64), target.astype(np.int64)
    for v, eig, name in ((source, eig_1, "source"), (target, eig_2, "target")):
        if v.min() < 0 or v.max() >= eig.n_vertices:
            raise ValueError(f"landmarks: {name} vertices must be in [0, {eig.n_vertices})")
    return source, target


class _FitTerms:
    """The terms of :func:`estimate_fmap`'s energy on unit-area copies of two bases, built once.

    On the copies (``eig_1``, ``eig_2``) every term is independent of the shapes' units; a map
    between them times ``scale`` is the map between the bases given. Descriptors are computed
    from ``k_descriptors`` eigenpairs whatever the map's size, so the coefficients and
    operator stacks of a smaller map are the leading blocks of a larger one's: :meth:`fit`
    solves any size up to the one they were built for. ``options`` are :func:`estimate_fmap`'s
    ``(descriptors, n_descriptors, k_descriptors, landmarks, operator_step)``; ``dcomm`` and
    ``orient`` say whether the commutativity and orientation operators are wanted.
    """

    def __init__(
        self, eig_1: EigenBasis, eig_2: EigenBasis, k1: int, k2: int, options: tuple, dcomm: bool,
        orient: bool,
    ) -> None:  # fmt: skip
        descriptors, n_descriptors, k_descriptors, landmarks, operator_step = options
        lm1 = lm2 = f1 = f2 = None
        if isinstance(landmarks, Anchors):  # the landmark functions, computed once
            pairs = np.stack([landmarks.source, landmarks.target], axis=1)
            lm1, lm2 = _landmark_vertices(pairs, eig_1, eig_2)
            f1, f2 = _anchor_functions(landmarks, eig_1, eig_2)
        elif landmarks is not None:
            lm1, lm2 = _landmark_vertices(landmarks, eig_1, eig_2)
        if descriptors not in ("wks", "hks"):
            raise ValueError(f"descriptors must be 'wks' or 'hks'; got {descriptors!r}")
        k_descriptors = check_int(k_descriptors, name="k_descriptors", minimum=2)
        operator_step = check_int(operator_step, name="operator_step", minimum=1)
        self.scale = math.sqrt(eig_2.area / eig_1.area)
        self.eig_1 = eig_1 = unit_area(eig_1)
        self.eig_2 = eig_2 = unit_area(eig_2)

        # Landmarks enter as functions of the distances to them when both shapes are meshes
        # (LANDMARK_SCALES), as their kernel maps otherwise.
        geodesic = eig_1.faces is not None and eig_2.faces is not None

        def terms(
            eig: EigenBasis, k: int, lm: np.ndarray | None, functions: np.ndarray | None
        ) -> tuple[Any, ...]:  # fmt: skip
            D, ops = _descriptors(
                eig, descriptors, n_descriptors, lm, min(k_descriptors, eig.k), geodesic,
                operator_step, functions,
            )  # fmt: skip
            return _shape_terms(eig, k, D, ops, dcomm, orient)

        # The two shapes' terms are independent: one thread each (their BLAS on one thread).
        with ThreadPoolExecutor(max_workers=2) as pool:
            job = pool.submit(terms, eig_2, k2, lm2, f2)
            self.terms = (terms(eig_1, k1, lm1, f1), job.result())

    def fit(
        self, k1: int, k2: int, *, weights: _Weights, solver: str = "direct",
        maxiter: int = 15000, ftol: float = 2.2e-9,
    ) -> np.ndarray:  # fmt: skip
        """Minimize the energy over (k2+1, k1+1) maps, the constant kept on the constant.

        ``weights`` are (descriptors, Laplacian, commutativity, orientation); the orientation
        weight is relative (rescaled so that, at the identity map, the term equals it times the
        others).
        """
        a, b = k1 + 1, k2 + 1
        w_descr, w_lap, wc, w_orient = weights
        energy = _energy_of(self.eig_1, self.eig_2, self.terms, a, b, (wc > 0, w_orient > 0))
        weights = (w_descr, w_lap, wc, 0.0)
        if energy.orient:
            weights = energy.orientation_weighted(np.eye(b, a), weights, w_orient)
        C0 = np.zeros((b, a))
        C0[0, 0] = 1.0  # constant ↦ constant (both φ0 = 1 on unit-area shapes)
        options = {"maxiter": maxiter, "ftol": ftol, "gtol": ftol}
        return energy.solve(C0, weights, solver, options, f"estimate_fmap (w_dcomm {wc:g})")


@one_blas_thread
def estimate_fmap(
    eig_1: EigenBasis,
    eig_2: EigenBasis,
    *,
    k1: int | None = None,
    k2: int | None = None,
    descriptors: str = "wks",
    n_descriptors: int = 100,
    k_descriptors: int = 100,
    landmarks: Any = None,
    w_descr: float = 1.0,
    w_lap: float = 1e-2,
    w_dcomm: float | tuple[float, ...] = 1e-1,
    w_orient: float = 1.0,
    operator_step: int = OPERATOR_STEP,
    refine: str | None = "zoomout",
    zoomout_to: int | None = None,
    icp_iterations: int = 10,
    solver: str = "direct",
    maxiter: int = 15000,
    ftol: float = 2.2e-9,
) -> np.ndarray:
    """Estimate a functional map between two shapes without any correspondence.

    Minimizes, over C (k2+1, k1+1) with its first column fixed (constant to constant),

    ``w_descr ‖C A − B‖² + w_lap ‖C Λ₁ − Λ₂ C‖² + w_dcomm Σ_i ‖C Dᵢ¹ − Dᵢ² C‖²
    + w_orient Σ_i ‖C Gᵢ¹ − Gᵢ² C‖²``

    with A, B the descriptors' coefficients, Dᵢ the multiplication operators of the descriptors
    (Nogneng & Ovsjanikov 2017) and Gᵢ the orientation-preserving operators
    ``g ↦ <n × ∇dᵢ, ∇g>`` (Ren et al. 2018; without them maps between symmetric shapes can
    flip left and right). Every term is quadratic in C: the minimizer solves one linear system
    of (k2+1)·k1 unknowns, whose matrix is assembled from the operators' Kronecker structure
    (``solver="direct"``, exact); ``solver="lbfgs"`` runs L-BFGS-B with analytic gradients
    instead (pyFM's way: stops near the same minimizer, 20-60 times slower). Then optional
    refinement.

    Parameters
    ----------
    eig_1, eig_2 : EigenBasis
        Source and target eigenbases.
    k1, k2 : int, optional
        Size of the optimized map (default: all eigenfunctions, up to 30 on each side).
    descriptors, n_descriptors : {"wks", "hks"}, int
        Descriptor family (default "wks") and its number of energies (times) (default 100).
    k_descriptors : int, default 100
        Eigenpairs the descriptors are computed from (fewer if a basis has fewer), so the
        result does not depend on how many eigenpairs the caller computed.
    landmarks : (p, 2) array_like of int or Anchors, optional
        Known pairs (source vertex, target vertex), added to the descriptors: between meshes,
        each landmark's shortest-path distance (over sqrt(area)), Gaussians of it
        (``o3d_ofp.core.fmap.LANDMARK_SCALES``) and its biharmonic coordinate
        (``o3d_ofp.core.fmap.landmark_coordinates``); with a point cloud, each landmark's
        wave (heat) kernel map. ``landmark_anchors`` of the two shapes (``Anchors``) give the
        same pairs with those functions already computed (a match that also anchors its
        ZoomOut with them computes them once).
    w_descr, w_lap, w_dcomm : float
        Weights of the descriptor, Laplacian and descriptor-commutativity terms. Everything is
        computed on unit-area copies of the shapes and the Laplacian term normalized to unit
        sum, so the weights do not depend on the shapes' scale. ``w_dcomm`` may be a tuple of
        weights (with ``refine=None``): one map per weight is returned, in a list, the
        descriptors and operators being built once.
    w_orient : float, default 1.0
        Weight of the orientation term relative to the others (it is rescaled so that, at
        the identity map, it equals ``w_orient`` times the other terms). On a point cloud
        (no faces) it is built from estimated normals and tangent-plane gradients
        (``o3d_ofp.core.geometry.point_normals`` and ``point_gradient_operator``).
    operator_step : int, default OPERATOR_STEP (5)
        The commutativity and orientation terms use every ``operator_step``-th descriptor
        (pyFM's ``subsample_step``); the descriptor term uses all of them.
    refine : {"zoomout", "icp", None}, default "zoomout"
        Refinement after the optimization (ICP: ``icp_iterations`` iterations, default 10).
    zoomout_to : int, optional
        Final size of ZoomOut (default: ``min(eig_1.k, eig_2.k)``); the result is then cut
        back to (k2+1, k1+1).
    solver : {"direct", "lbfgs"}, default "direct"
        How the energy is minimized (see above).
    maxiter, ftol : int, float
        L-BFGS-B's bound on iterations (default 15000) and its relative energy and gradient
        tolerances (default 2.2e-9, SciPy's ftol), with ``solver="lbfgs"``.

    Returns
    -------
    (k2+1, k1+1) ndarray
        ``fmap_12`` (a list of them when ``w_dcomm`` is a tuple).

    References
    ----------
    .. [1] D. Nogneng, M. Ovsjanikov, "Informative Descriptor Preservation via Commutativity
       for Shape Matching", Computer Graphics Forum 36(2), 2017.
    .. [2] J. Ren, A. Poulenard, P. Wonka, M. Ovsjanikov, "Continuous and Orientation-preserving
       Correspondences via Functional Maps", ACM TOG 37(6), 2018.
    .. [3] S. Melzi et al., "ZoomOut: Spectral Upsampling for Efficient Shape Correspondence",
       ACM TOG 38(6), 2019.

    Examples
    --------
    >>> import numpy as np
    >>> import open3d as o3d
    >>> import o3d_ofp as ofp
    >>> sphere = o3d.geometry.TriangleMesh.create_sphere(radius=1.0, resolution=10)
    >>> xyz = np.asarray(sphere.vertices)
    >>> shape = o3d.geometry.TriangleMesh(sphere)  # a bumpy ellipsoid with no symmetry
    >>> bumps = 0.2 * xyz[:, [1, 2, 0]] ** 2
    >>> shape.vertices = o3d.utility.Vector3dVector(xyz * [1.0, 0.7, 0.5] + bumps)
    >>> moved = o3d.geometry.TriangleMesh(shape)
    >>> _ = moved.rotate(moved.get_rotation_matrix_from_xyz((0.3, 0.2, 0.1)), center=(0, 0, 0))
    >>> eig_1, eig_2 = ofp.eigenbasis(shape, k=10), ofp.eigenbasis(moved, k=10)
    >>> C = ofp.estimate_fmap(eig_1, eig_2)
    >>> C.shape
    (11, 11)
    >>> p2p = ofp.p2p_from_fmap(C, eig_1, eig_2)  # the vertices of the rotated copy are in order
    >>> bool((p2p == np.arange(182)).mean() > 0.9)
    True
    """
    k1, k2 = _checked_sizes(eig_1, eig_2, k1, k2, solver, refine, w_dcomm)
    options = (descriptors, n_descriptors, k_descriptors, landmarks, operator_step)
    terms = _FitTerms(eig_1, eig_2, k1, k2, options, max(np.atleast_1d(w_dcomm)) > 0, w_orient > 0)
    fit = functools.partial(terms.fit, k1, k2, solver=solver, maxiter=maxiter, ftol=ftol)
    fits = [fit(weights=(w_descr, w_lap, float(wc), w_orient)) for wc in np.atleast_1d(w_dcomm)]
    if len(fits) > 1:
        return [C * terms.scale for C in fits]
    return _refined(fits[0], terms, refine, zoomout_to, icp_iterations) * terms.scale


def _checked_sizes(
    eig_1: EigenBasis, eig_2: EigenBasis, k1: Any, k2: Any, solver: str, refine: Any, w_dcomm: Any
) -> tuple[int, int]:
    """Check :func:`estimate_fmap`'s bases, solver and refinement; return the map's sizes."""
    check_eigenbasis(eig_1, "eig_1")
    check_eigenbasis(eig_2, "eig_2")
    k1 = min(eig_1.k, 30) if k1 is None else check_int(k1, name="k1", minimum=1, maximum=eig_1.k)
    k2 = min(eig_2.k, 30) if k2 is None else check_int(k2, name="k2", minimum=1, maximum=eig_2.k)
    if solver not in ("direct", "lbfgs"):
        raise ValueError(f"solver must be 'direct' or 'lbfgs'; got {solver!r}")
    if refine not in ("zoomout", "icp", None):
        raise ValueError(f"refine must be 'zoomout', 'icp' or None; got {refine!r}")
    if np.size(w_dcomm) > 1 and refine is not None:
        raise ValueError("several w_dcomm weights give several maps: use refine=None")
    return k1, k2


def _refined(
    C: np.ndarray, terms: _FitTerms, refine: str | None, zoomout_to: int | None, icp_iterations: int
) -> np.ndarray:
    """Refine a map between the unit-area bases as :func:`estimate_fmap`'s ``refine`` says.

    ZoomOut's result is cut back to the map's size.
    """
    eig_1, eig_2 = terms.eig_1, terms.eig_2
    if refine == "icp":
        return icp_refine(C, eig_1, eig_2, iterations=icp_iterations)
    if refine == "zoomout":
        target = min(eig_1.k, eig_2.k) if zoomout_to is None else zoomout_to
        if target > max(C.shape) - 1:
            return zoomout_refine(C, eig_1, eig_2, k_final=target)[: C.shape[0], : C.shape[1]]
    return C


@one_blas_thread
def estimate_fmaps(
    eig_1: EigenBasis,
    eig_2: EigenBasis,
    *,
    sizes: Sequence[int],
    w_dcomm: Sequence[float] = (1e-1,),
    descriptors: str = "wks",
    n_descriptors: int = 100,
    k_descriptors: int = 100,
    landmarks: Any = None,
    w_descr: float = 1.0,
    w_lap: float = 1e-2,
    w_orient: float = 1.0,
    operator_step: int = OPERATOR_STEP,
) -> list[tuple[int, float, np.ndarray]]:
    """Square descriptor fits of several sizes and commutativity weights, the terms built once.

    The same energy and exact solve as :func:`estimate_fmap` (``solver="direct"``, no
    refinement) for every size in ``sizes`` and every weight in ``w_dcomm``: the descriptors
    and the operator stacks are built once, at the largest size, and the smaller fits use
    their leading blocks (the same maps :func:`estimate_fmap` gives size by size).

    Parameters
    ----------
    eig_1, eig_2 : EigenBasis
        Source and target eigenbases, with at least ``max(sizes)`` eigenfunctions each.
    sizes : sequence of int
        Non-constant eigenfunctions of each fitted map (k1 = k2 = k).
    w_dcomm : sequence of float, default (0.1,)
        Weights of the descriptor-commutativity term.
    descriptors, n_descriptors, k_descriptors, landmarks, w_descr, w_lap, w_orient, operator_step
        As in :func:`estimate_fmap`.

    Returns
    -------
    list of (int, float, (k+1, k+1) ndarray)
        ``(k, w_dcomm, fmap_12)`` for every size, then every weight, in the order given.
    """
    check_eigenbasis(eig_1, "eig_1")
    check_eigenbasis(eig_2, "eig_2")
    top = min(eig_1.k, eig_2.k)
    sizes = [check_int(k, name="sizes", minimum=1, maximum=top) for k in sizes]
    weights = [float(w) for w in w_dcomm]
    if not sizes or not weights:
        raise ValueError("sizes and w_dcomm must name at least one fit each")
    k = max(sizes)
    options = (descriptors, n_descriptors, k_descriptors, landmarks, operator_step)
    terms = _FitTerms(eig_1, eig_2, k, k, options, max(weights) > 0, w_orient > 0)
    fits = [(size, wc) for size in sizes for wc in weights]
    with ThreadPoolExecutor(max_workers=2) as pool:
        maps = pool.map(
            lambda f: terms.fit(f[0], f[0], weights=(w_descr, w_lap, f[1], w_orient)), fits
        )
        return [(size, wc, terms.scale * C) for (size, wc), C in zip(fits, maps, strict=True)]


@one_blas_thread
def icp_refine(
    fmap_12: Any, eig_1: EigenBasis, eig_2: EigenBasis, *, iterations: int = 10
) -> np.ndarray:
    """Spectral ICP (Ovsjanikov et al. 2012): alternate p2p extraction and orthogonal projection.

    Parameters
    ----------
    fmap_12 : (k2+1, k1+1) array_like
        Initial map.
    eig_1, eig_2 : EigenBasis
        Source and target eigenbases.
    iterations : int, default 10
        Number of iterations (stops early when the map no longer changes).

    Returns
    -------
    (k2+1, k1+1) ndarray
        The refined map (closest to orthogonal for the matched points, on the unit-area
        shapes; converted back to the shapes' own areas).

    Examples
    --------
    >>> import numpy as np
    >>> import open3d as o3d
    >>> import o3d_ofp as ofp
    >>> sphere = o3d.geometry.TriangleMesh.create_sphere(radius=1.0, resolution=10)
    >>> xyz = np.asarray(sphere.vertices)
    >>> shape = o3d.geometry.TriangleMesh(sphere)  # a bumpy ellipsoid with no symmetry
    >>> bumps = 0.2 * xyz[:, [1, 2, 0]] ** 2
    >>> shape.vertices = o3d.utility.Vector3dVector(xyz * [1.0, 0.7, 0.5] + bumps)
    >>> eig = ofp.eigenbasis(shape, k=10)
    >>> C = ofp.fmap_from_p2p(np.arange(182), eig, eig, k1=6, k2=6)  # the identity map
    >>> noisy = C + 0.1 * np.random.default_rng(0).standard_normal(C.shape)
    >>> bool((ofp.p2p_from_fmap(noisy, eig, eig) == np.arange(182)).all())
    False
    >>> refined = ofp.icp_refine(noisy, eig, eig)
    >>> refined.shape, bool((ofp.p2p_from_fmap(refined, eig, eig) == np.arange(182)).all())
    ((7, 7), True)
    """
    scale = math.sqrt(eig_2.area / eig_1.area)
    C = np.array(fmap_12, dtype=np.float64) / scale
    eig_1, eig_2 = unit_area(eig_1), unit_area(eig_2)
    rows, cols = C.shape
    for _ in range(check_int(iterations, name="iterations", minimum=0)):
        p2p = p2p_from_fmap(C, eig_1, eig_2)
        W = fmap_from_p2p(p2p, eig_1, eig_2, k1=cols - 1, k2=rows - 1)
        U, _, Vt = np.linalg.svd(W, full_matrices=False)
        C_new = U @ Vt
        if np.allclose(C_new, C, atol=1e-10):
            break
        C = C_new
    return C * scale


def grid_samples(vertices: np.ndarray, count: int) -> np.ndarray:
    """About ``count`` well-spread vertices: one per occupied cube of a grid, in O(n).

    The grid sits in the shape's principal frame, centred on its centroid (cells centred on
    it too, so flipping an axis gives the mirror grid): the samples do not depend on the
    position, orientation, scale or vertex order of the shape. The cube side is adjusted
    until the occupied cubes number ``count`` within 10 %; in each, the vertex nearest the
    mean of its members is kept.
    """
    X = vertices - vertices.mean(axis=0)
    _, axes = np.linalg.eigh(X.T @ X)
    X = X @ axes
    span = np.ptp(X, axis=0)
    extent = float(span.max())
    if extent == 0.0:
        return np.arange(min(count, vertices.shape[0]), dtype=np.int64)
    # A surface fills about ``count`` cubes of side h when count · h² ≈ its area; start from
    # the bounding box's and correct by the occupied count (4-8 rounds).
    h = math.sqrt(float(span[0] * span[1] + span[1] * span[2] + span[0] * span[2]) / count)
    for _ in range(12):
        keys = np.floor(X / h + 0.5).astype(np.int64)
        keys -= keys.min(axis=0)
        dims = keys.max(axis=0) + 1
        key = (keys[:, 0] * dims[1] + keys[:, 1]) * dims[2] + keys[:, 2]
        uniq, inverse = np.unique(key, return_inverse=True)
        m = uniq.shape[0]
        if abs(m - count) <= 0.1 * count:
            break
        h *= (m / count) ** 0.5
    size = np.bincount(inverse, minlength=m).astype(np.float64)
    mean = np.stack([np.bincount(inverse, weights=X[:, a], minlength=m) for a in range(3)], 1)
    mean /= size[:, None]
    d2 = np.einsum("ij,ij->i", X - mean[inverse], X - mean[inverse])
    # Nearest first, per cube; ties (two members are equally far from their mean) go to the
    # one nearer the cube's centre, not to the vertex order. Round-off of the mean is not a
    # difference: distances are compared to 1e-9 h².
    d2 = np.round(d2 / (h * h) * 1e9)
    off = X / h - np.floor(X / h + 0.5)
    order = np.lexsort((np.arange(X.shape[0]), np.einsum("ij,ij->i", off, off), d2, inverse))
    firsts = np.flatnonzero(np.concatenate([[True], inverse[order][1:] != inverse[order][:-1]]))
    return np.sort(order[firsts]).astype(np.int64)


def _off_centre(X: np.ndarray) -> int:
    """Return the vertex farthest from the centroid (whatever the order, position and scale)."""
    return int(np.argmax(np.einsum("ij,ij->i", X - X.mean(axis=0), X - X.mean(axis=0))))


def farthest_points(vertices: np.ndarray, count: int, *, start: int | None = None) -> np.ndarray:
    """Farthest-point sampling (Euclidean): ``count`` well-spread vertex indices.

    On shapes of more than ``FPS_POOL · count`` vertices (without ``start``), the sampling
    runs on ``FPS_POOL · count`` vertices spread by :func:`grid_samples`: O(n + count²·8)
    instead of O(n · count), with the same independence from pose, scale and vertex order.

    Parameters
    ----------
    vertices : (n, 3) ndarray
    count : int
        Samples wanted (all vertices if ``count >= n``).
    start : int, optional
        First sample (default: the vertex farthest from the centroid, which does not depend
        on the vertex order, the position or the scale of the shape).

    Returns
    -------
    (count,) ndarray of int64
    """
    n = vertices.shape[0]
    if count >= n:
        return np.arange(n)
    X = np.ascontiguousarray(vertices, dtype=np.float64)
    if start is None and n > FPS_POOL * count:
        # Exact FPS costs n · count (25 s for the 9 samplings of a 110k-vertex match): run it
        # on ``FPS_POOL · count`` grid-spread vertices instead, as well spread at this scale.
        pool = grid_samples(X, FPS_POOL * count)
        if pool.shape[0] > count:
            # exact on the pool, however many it holds (a symmetric shape's grid may keep more
            # cells than asked for; sampling the pool again could then go on forever)
            return pool[farthest_points(X[pool], count, start=_off_centre(X[pool]))]
    if start is None:
        start = _off_centre(X)
    chosen = np.empty(count, dtype=np.int64)
    chosen[0] = start
    diff = X - X[start]
    dist = np.einsum("ij,ij->i", diff, diff)
    # A new sample c can only bring closer the vertices within its own distance r = dist[c]
    # (the largest of all: every other vertex has dist ≤ r, and d(i, c) > r leaves it): a
    # k-d tree finds them, ~n / i of them at step i, instead of updating all n. The distances
    # are computed by the same formula on that subset, so the samples are exactly those of
    # the full update (tested against it).
    tree = scipy.spatial.cKDTree(X)
    for i in range(1, count):
        c = int(np.argmax(dist))
        chosen[i] = c
        near = tree.query_ball_point(X[c], math.sqrt(dist[c]) * (1.0 + 1e-9) + 1e-300)
        near = np.asarray(near, dtype=np.int64)
        diff = X[near] - X[c]
        dist[near] = np.minimum(dist[near], np.einsum("ij,ij->i", diff, diff))
    return chosen


#: Known pairs in ZoomOut: their rows weigh, all together, this share of the fit's total weight
#: (the samples' count, or the unit area at full resolution), and ...
LANDMARK_WEIGHT = 0.2
#: ... every nearest-neighbour step compares, beside the spectral embeddings, the vertices'
#: shortest-path distances to the landmarks (over sqrt(area)) and their biharmonic
#: coordinates (``landmark_coordinates``), both times this. Without either, a
#: spectral refinement drifts from the landmarks that started it (they landed 0.06-0.18
#: sqrt(area) from their pairs on gorilla -> human maps). Measured in ``ofp.match``
#: (``scripts/eval_nonisometric.py``, 6 well-spread landmarks, mean geodesic error x100):
#: gorilla -> human 14.0 -> 8.7 (worst 17.2 -> 10.1), TOSCA pairs of one animal in two poses
#: 2.6 -> 2.6 (worst 6.0 both); with the final ZoomOut in steps of five
#: (``workflows.matching.ZOOMOUT_STEP``) 8.4 (worst 11.8) and 2.5 (worst 5.9); all of these
#: with the landmarks' kernel maps as the fits' descriptors, before ``LANDMARK_SCALES``. Chosen
#: on a scratch ZoomOut from each map's restriction to 30 eigenfunctions (gorilla / TOSCA):
#: weight alone 12.1 / 2.24, with distances x1 11.2 / 2.19, x3 8.3 / 2.17, x10 8.9 / 2.26;
#: weights 0.05 and 1 within 0.4 of 0.2; 4 landmarks x3 14.3 -> 9.6 and 2.72 -> 2.32.
LANDMARK_DISTANCES = 3.0
#: Between meshes, the fits' descriptors of a landmark are its shortest-path distance (over
#: sqrt(area)) and ``exp(-(d / s)²)`` for each ``s`` here: functions of where a point lies
#: relative to the landmark that hold between shapes of other proportions, where its wave
#: kernel map (the former descriptors, kept for point clouds) follows each shape's own
#: spectrum. The commutativity and orientation operators take each landmark's distance
#: function. Measured in ``ofp.match`` (``scripts/eval_nonisometric.py``, well-spread
#: landmarks, mean geodesic error x100 on 300 points; gorilla -> human, then TOSCA pairs of one
#: animal): 6 landmarks 7.2 and 2.33 against 8.3 and 2.50 with the kernel maps; 4 landmarks
#: 11.1 against 12.3 (gorilla); 10 landmarks 6.5 against 6.6. The operators of one Gaussian
#: per landmark instead gave 7.1-7.7 (the widest best), of all five 7.7; with operators of
#: mixed scales, scales (0.05, ..., 0.4) and (0.2, ..., 1.6) did no better than these, and the
#: distance functions alone, without WKS, gave 9.1. The biharmonic coordinates
#: (``landmark_coordinates``) join the descriptors, the operators and (at the weight of
#: ``LANDMARK_DISTANCES``) ZoomOut's point maps: gorilla -> human 6.4 against 7.2 with 6
#: landmarks, 6.3 against 11.1 with 4, 6.0 against 6.5 with 10; TOSCA animals 2.32 against
#: 2.33, 10 of the 30 pairs of TOSCA people 1.57 against 1.57. Unclipped (the biharmonic
#: minimizer itself): 6.4, 6.4 and 6.7 (three gorilla pairs 8.3-9.7 with 10 landmarks), 2.21,
#: 1.60. Scratch sweeps, 6 landmarks, unclipped: in the point maps only 6.5 (at twice the
#: weight 6.8, four times 8.2); in the point maps in place of the distances 7.2 (twice the
#: weight 6.4, but 10.1 with 4 landmarks).
LANDMARK_SCALES = (0.1, 0.2, 0.4, 0.8)


@dataclasses.dataclass(frozen=True, eq=False)
class Anchors:
    """Known pairs as ZoomOut uses them (made by :func:`landmark_anchors`).

    Attributes
    ----------
    source, target : (p,) ndarray of int
        The landmarks' source and target vertices.
    distances_1, distances_2 : (n1, 2p), (n2, 2p) ndarray or None
        Where every vertex lies relative to the landmarks: its shortest-path distances along
        the edges to them, over sqrt(area), then its biharmonic coordinates
        (``landmark_coordinates``; both the same in any units); None when either shape is a
        point cloud.
    """

    source: np.ndarray
    target: np.ndarray
    distances_1: np.ndarray | None
    distances_2: np.ndarray | None


def _landmark_functions(eig: EigenBasis, vertices: np.ndarray) -> np.ndarray:
    """Return where every vertex lies relative to the landmarks (an Anchors' rows).

    (n, 2p): the shortest-path distances to them over sqrt(area), then their biharmonic
    coordinates.
    """
    return np.hstack([_landmark_distances(eig, vertices), landmark_coordinates(eig, vertices)])


def _anchor_functions(
    anchors: Anchors | None, eig_1: EigenBasis, eig_2: EigenBasis
) -> tuple[np.ndarray | None, np.ndarray | None]:
    """Return the anchors' landmark functions on both shapes (None, None without anchors).

    Functions made for other shapes (another vertex count, or not two columns per landmark)
    are refused.
    """
    if anchors is None:
        return None, None
    d1, d2 = anchors.distances_1, anchors.distances_2
    columns = 2 * anchors.source.size
    for functions, eig, name in ((d1, eig_1, "source"), (d2, eig_2, "target")):
        if functions is None:
            continue
        if functions.shape[0] != eig.n_vertices:
            raise ValueError(f"anchors: made for another {name} ({functions.shape[0]} vertices, "
                             f"not {eig.n_vertices})")  # fmt: skip
        if functions.shape[1] != columns:
            raise ValueError(f"anchors: the {name}'s functions have {functions.shape[1]} "
                             f"columns, not two per landmark ({columns})")  # fmt: skip
    return d1, d2


def _landmark_distances(eig: EigenBasis, vertices: np.ndarray) -> np.ndarray:
    assert eig.faces is not None
    d = csgraph.dijkstra(edge_graph(eig.vertices, eig.faces), directed=False, indices=vertices).T
    finite = np.isfinite(d)
    # Vertices on other pieces than a landmark's: ten times the shape's longest distance away.
    far = 10.0 * float(np.max(d[finite], initial=1.0))
    return np.where(finite, d, far) / math.sqrt(eig.area)


def landmark_coordinates(eig: EigenBasis, vertices: Any) -> np.ndarray:
    """Biharmonic coordinates of a mesh's vertices with respect to landmark vertices, in [0, 1].

    Column ``j`` is the smoothest function that is 1 at landmark ``j`` and 0 at the others:
    it minimizes the biharmonic energy ``fᵀ L M⁻¹ L f`` (``L`` the cotangent stiffness, ``M``
    the lumped mass) under those values. Along a limb between two landmarks it goes from one
    to the other in proportion to the way covered, so it tells where a point lies relative
    to the landmarks also between shapes of other proportions (a gorilla's arm and a
    human's), where a distance grows with the limb's length. Beyond the outermost landmarks
    the minimizer goes on as it came (measured on FAUST with 6 farthest-point landmarks:
    -1.06 to 2.60), a reach that follows each shape's own proportions there: the result is
    clipped to [0, 1], which keeps where a point lies between the landmarks and drops how
    far beyond them (see ``LANDMARK_SCALES`` for what the clipping gained). Unclipped, the
    columns sum to 1 on every piece that holds a landmark; they are 0 on the others, and
    the same in any units.

    Parameters
    ----------
    eig : EigenBasis
        A mesh's basis (its stiffness and mass are used, no eigenfunction).
    vertices : (p,) array_like of int
        The landmark vertices (a vertex given twice gets the same column twice).

    Returns
    -------
    (n, p) ndarray

    Raises
    ------
    ValueError
        If ``eig`` is a point cloud's, or a landmark is outside the shape.
    """
    if eig.faces is None:
        raise ValueError("landmark_coordinates needs a mesh (a point cloud's basis was given)")
    given = np.asarray(vertices, dtype=np.int64).ravel()
    n = eig.n_vertices
    if given.size == 0 or given.min() < 0 or given.max() >= n:
        raise ValueError(f"vertices: landmark vertices in [0, {n}) are needed")
    lm, column = np.unique(given, return_inverse=True)
    # On the unit-area shape (the cotangent stiffness does not depend on the units): the
    # same coordinates in any units, to round-off.
    mass = np.asarray(eig.mass, dtype=np.float64) / eig.area
    out = mass <= 0  # vertices left out of the surface: no energy, pinned to 0 below
    K = eig.stiffness.tocsr()
    # The small mass term keeps a piece without a landmark (no constraint there) definite:
    # its coordinates are then 0.
    Q = K @ sp.diags(1.0 / np.where(out, 1.0, mass)) @ K
    Q = (Q + sp.diags(_BIHARMONIC_SHIFT * mass + out)).tocsc()
    free = np.ones(n, dtype=bool)
    free[lm] = False
    W = np.zeros((n, lm.size))
    W[lm, np.arange(lm.size)] = 1.0
    rhs = -(Q[:, lm][free]).toarray()  # the landmarks' unit values moved to the right side
    W[free] = splu(Q[free][:, free].tocsc()).solve(rhs)
    return np.clip(W[:, column], 0.0, 1.0)


#: Mass term of ``landmark_coordinates``' energy, relative to the biharmonic term of a
#: unit-area shape (whose squared lowest non-zero eigenvalue is 21-41 on FAUST, a TOSCA
#: gorilla and cat: 4.6-6.4 squared): it only decides a piece without a landmark.
_BIHARMONIC_SHIFT = 1e-6


def landmark_anchors(eig_1: EigenBasis, eig_2: EigenBasis, landmarks: Any) -> Anchors:
    """Return the landmarks as :func:`~o3d_ofp.zoomout_refine` anchors them.

    Parameters
    ----------
    eig_1, eig_2 : EigenBasis
        Source and target (their vertices, faces and areas; no eigenfunction is used).
    landmarks : (p, 2) array_like of int
        ``[source vertex, target vertex]`` pairs.

    Returns
    -------
    Anchors
        With distances and biharmonic coordinates when both shapes are meshes (``p``
        shortest-path runs and one sparse solve on each).
    """
    source, target = _landmark_vertices(landmarks, eig_1, eig_2)
    if eig_1.faces is None or eig_2.faces is None:
        return Anchors(source, target, None, None)
    return Anchors(source, target, *(
        _landmark_functions(eig, v) for eig, v in ((eig_1, source), (eig_2, target))
    ))  # fmt: skip


def landmark_embedding(spectral: np.ndarray, functions: np.ndarray | None) -> np.ndarray:
    """Return a point map's coordinates: spectral, then the weighted landmark functions.

    Parameters
    ----------
    spectral : (n, d) ndarray
        The vertices' spectral coordinates (a source's ``Φ Cᵀ`` or a target's ``Ψ``).
    functions : (n, 2p) ndarray or None
        Their landmark functions (``Anchors.distances_1`` or ``.distances_2``); None: none.

    Returns
    -------
    (n, d + 2p) ndarray
        ``[spectral, LANDMARK_DISTANCES · functions]`` (``spectral`` itself without functions).
    """
    if functions is None:
        return spectral
    return np.hstack([spectral, LANDMARK_DISTANCES * functions])


@one_blas_thread
def zoomout_refine(
    fmap_12: Any,
    eig_1: EigenBasis,
    eig_2: EigenBasis,
    *,
    k_final: int,
    step: int = 1,
    subsample: int | None = None,
    samples: tuple[np.ndarray, np.ndarray] | None = None,
    anchors: Anchors | None = None,
) -> np.ndarray:
    """ZoomOut (Melzi et al. 2019): grow the map one eigenfunction at a time through p2p maps.

    Parameters
    ----------
    fmap_12 : (k2+1, k1+1) array_like
        Initial map.
    eig_1, eig_2 : EigenBasis
        Source and target eigenbases with at least ``k_final`` non-constant eigenfunctions.
    k_final : int
        Final number of non-constant eigenfunctions on both sides.
    step : int, default 1
        Growth per iteration.
    subsample : int, optional
        Run the iterations on this many farthest-point samples of each shape (as in the
        ZoomOut paper): each step then costs a small nearest-neighbour search and a small
        least-squares fit instead of full-resolution ones. ``None``: all vertices, with the
        mass-weighted projection.
    samples : tuple of two (s,) int arrays, optional
        The samples of each shape, when the caller already has them (``farthest_points`` of
        both shapes with ``subsample`` samples, as computed here otherwise): callers that
        refine several maps between the same shapes sample them once.
    anchors : Anchors, optional
        Known pairs (:func:`o3d_ofp.core.fmap.landmark_anchors`): every fit also asks the
        landmarks to map onto each other (their rows weigh
        :data:`~o3d_ofp.core.fmap.LANDMARK_WEIGHT` of the fit), and every point map also
        matches the vertices' distances to the landmarks and their biharmonic coordinates
        (:data:`~o3d_ofp.core.fmap.LANDMARK_DISTANCES`):
        the landmarks then drive the refinement instead of only its start (a spectral map
        alone drifts from them, most between shapes that are not near-isometric).

    Returns
    -------
    (k_final+1, k_final+1) ndarray

    Examples
    --------
    >>> import numpy as np
    >>> import open3d as o3d
    >>> import o3d_ofp as ofp
    >>> sphere = o3d.geometry.TriangleMesh.create_sphere(radius=1.0, resolution=10)
    >>> xyz = np.asarray(sphere.vertices)
    >>> shape = o3d.geometry.TriangleMesh(sphere)  # a bumpy ellipsoid with no symmetry
    >>> bumps = 0.2 * xyz[:, [1, 2, 0]] ** 2
    >>> shape.vertices = o3d.utility.Vector3dVector(xyz * [1.0, 0.7, 0.5] + bumps)
    >>> moved = o3d.geometry.TriangleMesh(shape)
    >>> _ = moved.rotate(moved.get_rotation_matrix_from_xyz((0.3, 0.2, 0.1)), center=(0, 0, 0))
    >>> eig_1, eig_2 = ofp.eigenbasis(shape, k=10), ofp.eigenbasis(moved, k=10)
    >>> C = ofp.estimate_fmap(eig_1, eig_2, k1=4, k2=4, refine=None)  # a small map
    >>> C.shape
    (5, 5)
    >>> big = ofp.zoomout_refine(C, eig_1, eig_2, k_final=10)
    >>> big.shape
    (11, 11)
    >>> p2p = ofp.p2p_from_fmap(big, eig_1, eig_2)
    >>> bool((p2p == np.arange(182)).mean() > 0.9)
    True
    """
    scale = math.sqrt(eig_2.area / eig_1.area)
    C = np.array(fmap_12, dtype=np.float64) / scale  # between the unit-area bases
    k_final = check_int(k_final, name="k_final", minimum=1, maximum=min(eig_1.k, eig_2.k))
    eig_1, eig_2 = unit_area(eig_1), unit_area(eig_2)
    step = check_int(step, name="step", minimum=1)
    k = min(C.shape) - 1
    C = C[: k + 1, : k + 1]
    if samples is not None:
        s1, s2 = (np.asarray(s, dtype=np.int64) for s in samples)
        for name, s_, eig in (("source", s1, eig_1), ("target", s2, eig_2)):
            if s_.ndim != 1 or s_.size <= k_final or s_.min() < 0 or s_.max() >= eig.n_vertices:
                raise ValueError(
                    f"samples: the {name} samples must be more than k_final = {k_final} vertex "
                    f"indices in [0, {eig.n_vertices})"
                )
        subsample = s1.size
    elif subsample is not None and subsample >= min(eig_1.n_vertices, eig_2.n_vertices):
        subsample = None  # small shapes: the full-resolution iteration is exact and cheap
    if subsample is not None:
        subsample = check_int(subsample, name="subsample", minimum=k_final + 1)
        if samples is None:
            s1 = farthest_points(eig_1.vertices, subsample)
            s2 = farthest_points(eig_2.vertices, subsample)
    if anchors is not None:
        sampled = None if subsample is None else (s1, s2)
        return scale * _anchored_zoomout(C, eig_1, eig_2, k, k_final, step, sampled, anchors)
    if subsample is not None:
        phi1, psi2 = eig_1.evecs[s1, : k_final + 1], eig_2.evecs[s2, : k_final + 1]
        # The fits min ‖Ψ_s[:, :k+1] C − Φ_s[p2p, :k+1]‖ all use leading columns of Ψ_s.
        fits = _LeadingFits(psi2)
    while k < k_final:
        k = min(k + step, k_final)
        if subsample is None:
            p2p = p2p_from_fmap(C, eig_1, eig_2)
            C = fmap_from_p2p(p2p, eig_1, eig_2, k1=k, k2=k)
            continue
        kc = C.shape[0]
        p2p_sub = nearest_neighbors(phi1[:, :kc] @ C.T, psi2[:, :kc])
        C = fits.solve(k + 1, phi1[p2p_sub, : k + 1])
    return C * scale


def _anchored_zoomout(
    C: np.ndarray, eig_1: EigenBasis, eig_2: EigenBasis, k: int, k_final: int, step: int,
    samples: tuple[np.ndarray, np.ndarray] | None, anchors: Anchors,
) -> np.ndarray:  # fmt: skip
    """:func:`zoomout_refine` with known pairs (unit-area bases, the samples or None for all)."""
    n1, n2 = eig_1.n_vertices, eig_2.n_vertices
    if anchors.source.max() >= n1 or anchors.target.max() >= n2:
        raise ValueError("anchors: landmark vertices outside the shapes (made for other shapes?)")
    if samples is not None:
        s1, s2 = samples
        # Every sample weighs 1: the landmarks' rows weigh LANDMARK_WEIGHT of their count.
        weights = np.ones(s2.size)
        total = float(s2.size)
    else:
        s1, s2 = np.arange(n1), np.arange(n2)
        weights = np.asarray(eig_2.mass, dtype=np.float64)  # unit area: they sum to 1
        total = float(weights.sum())
    phi1, psi2 = eig_1.evecs[s1, : k_final + 1], eig_2.evecs[s2, : k_final + 1]
    d1 = None if anchors.distances_1 is None else anchors.distances_1[s1]
    d2 = None if anchors.distances_2 is None else anchors.distances_2[s2]
    share = math.sqrt(LANDMARK_WEIGHT * total / anchors.source.size)
    # min Σ_i w_i ‖Ψ_i C − Φ_p(i)‖² + share² Σ_l ‖Ψ_l C − Φ_l‖², one system of leading columns
    root = np.sqrt(weights)[:, None]
    landmark_rows = share * eig_2.evecs[anchors.target, : k_final + 1]
    fits = _LeadingFits(np.vstack([root * psi2, landmark_rows]))
    known = share * eig_1.evecs[anchors.source, : k_final + 1]
    while k < k_final:
        kc = C.shape[0]
        p2p = nearest_neighbors(
            landmark_embedding(phi1[:, :kc] @ C.T, d1), landmark_embedding(psi2[:, :kc], d2)
        )
        k = min(k + step, k_final)
        C = fits.solve(k + 1, np.vstack([root * phi1[p2p, : k + 1], known[:, : k + 1]]))
    return C


class _LeadingFits:
    """Least-squares fits ``X[:, :m] C ≈ Y`` on leading columns of one matrix ``X``.

    The QR factors of leading columns are nested: ``X`` is factored once, and each fit is a
    GEMM and a triangular solve; when ``X`` does not have full column rank, each fit is a
    ``lstsq`` instead.
    """

    def __init__(self, X: np.ndarray) -> None:
        self.X = X
        self.Q, self.R = np.linalg.qr(X)
        diag = np.abs(np.diag(self.R))
        self.nested = bool(diag.min() > 1e-10 * diag.max())

    def solve(self, m: int, Y: np.ndarray) -> np.ndarray:
        """Return the least-squares solution C of ``X[:, :m] C ≈ Y``."""
        if self.nested:
            return scipy.linalg.solve_triangular(self.R[:m, :m], self.Q[:, :m].T @ Y)
        return np.linalg.lstsq(self.X[:, :m], Y, rcond=None)[0]


def lift_fmap(
    fmap_12: Any, order: int, *, target_area: float, k1: int | None = None, k2: int | None = None
) -> np.ndarray:
    """Lift a functional map to eigenproducts (the paper's C̃, Eq. 16), for any order.

    Each source eigenproduct φ_{i1}···φ_{id} is mapped to ∏_m (Σ_h C_{h,i_m} ψ_h) expanded in the
    target eigenproducts of order ≤ d; a factor ψ0 (the constant 1/√area₂) merges into the
    other factors, and the constant source candidate φ0 maps to column 0 of C.

    Parameters
    ----------
    fmap_12 : (k2+1, k1+1) array_like
        Functional map between the eigenbases (constant first).
    order : int
        Product order N (as in :func:`o3d_ofp.eigenproduct_indices`).
    target_area : float
        Area of the target shape (sets the constant ψ0 = 1/√area).
    k1, k2 : int, optional
        Non-constant eigenfunctions used (default: from the map's shape).

    Returns
    -------
    (C(k2+N, N), C(k1+N, N)) ndarray
        C̃ in the graded-lexicographic order of the candidates on each shape.

    References
    ----------
    .. [1] F. Maggioli et al., "Orthogonalized Fourier Polynomials for Signal Approximation
       and Transfer", Computer Graphics Forum 40(2), 2021, Sec. 3.3. doi:10.1111/cgf.142645

    Examples
    --------
    The identity map between eigenbases lifts to the identity between eigenproducts:

    >>> import numpy as np
    >>> import o3d_ofp as ofp
    >>> C_tilde = ofp.lift_fmap(np.eye(4), 2, target_area=4 * np.pi)  # k = 3, order 2
    >>> C_tilde.shape, bool(np.allclose(C_tilde, np.eye(10)))
    ((10, 10), True)
    """
    C0 = np.asarray(fmap_12, dtype=np.float64)
    if C0.ndim != 2:
        raise ValueError(f"fmap_12 must be a 2-D matrix; got shape {C0.shape}")
    k1 = C0.shape[1] - 1 if k1 is None else k1
    k2 = C0.shape[0] - 1 if k2 is None else k2
    C = check_fmap(C0, k2 + 1, k1 + 1)
    order = check_int(order, name="order", minimum=1)
    if not (target_area > 0 and math.isfinite(target_area)):
        raise ValueError(f"target_area must be positive and finite; got {target_area}")
    c2 = 1.0 / math.sqrt(target_area)
    src = eigenproduct_indices(k1, order)
    tgt = eigenproduct_indices(k2, order)
    index = {t: i for i, t in enumerate(tgt)}
    # mult[d][j, h-1] = index of the target candidate tgt[j] · ψ_h, for tgt[j] of degree < d
    n_upto = [math.comb(k2 + d, d) for d in range(order + 1)]
    mult = [None] + [
        np.array(
            [
                [index[tuple(sorted((*tgt[j], h)))] for h in range(1, k2 + 1)]
                for j in range(n_upto[d - 1])
            ]
        )
        for d in range(1, order + 1)
    ]
    out = np.zeros((len(tgt), len(src)))
    out[: k2 + 1, 0] = C[:, 0]
    # raw[I]: expansion of source candidate I in monomials of ψ1..ψk2, index 0 = the function 1
    raw: dict[tuple[int, ...], np.ndarray] = {(): np.array([1.0])}
    for col, tup in enumerate(src[1:], start=1):
        parent, i = raw[tup[:-1]], tup[-1]
        d = len(tup)
        lin = C[:, i]
        v = np.zeros(n_upto[d])
        v[: parent.shape[0]] += parent * (lin[0] * c2)
        v += np.bincount(
            mult[d][: parent.shape[0]].ravel(),
            weights=np.outer(parent, lin[1:]).ravel(),
            minlength=n_upto[d],
        )
        if d < order:
            raw[tup] = v
        out[: n_upto[d], col] = v
        out[0, col] = v[0] / c2  # the function 1 is √area₂ · ψ0
    return out
