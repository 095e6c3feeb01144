"""Geometric detail transfer in local frames, on arrays.

The *detail* of a shape is what its coordinates have above a low band of its spectrum:
``D = X − P X`` with ``P`` the projection on the first ``band`` Laplace-Beltrami
eigenfunctions (the *low-pass shape* ``P X``). It is carried from a source to a target through
a map and re-applied in the target's local frames:

* **Local frames.** At every target vertex ``i`` the frame of the source's low-pass surface at
  the corresponding point is turned into the target's by ``R_i``, the rotation that best aligns
  the two low-pass surfaces around ``i`` (weighted Procrustes over a heat-kernel neighbourhood
  of time ``1/λ_rotation_k``): the normal goes to the normal and the tangent plane to the tangent
  plane, so the detail keeps its orientation relative to the surface whatever the two poses.
  A detail vector with frame coordinates ``c`` (normal height and two tangent offsets) at the
  source becomes ``R_i (E₁ c) = E₂ c`` at the target. Frames built separately on each low-pass
  surface (its vertex normals plus a tangent from the gradient of a low eigenfunction) were
  measured and rejected: at ``band = 30`` the low-pass surface collapses limbs, fingers and
  tails into ribbons whose normals are meaningless (43° from the true normals on FAUST), and
  such frames made every result farther from the truth than doing nothing (see
  ``scripts/eval_detail.py``). The fitted rotation looks at a neighbourhood wider than a
  ribbon, needs no normals (point clouds work) and never degenerates on a surface.
* **Carrying.** The detail vectors and the low-pass coordinates are carried to the target
  either by pulling them back through the point map (``carry="p2p"``) or with the OFP transfer
  of the paper (``carry="ofp"``, :func:`o3d_ofp.workflows.pipeline.transfer_function`).
  Measured with the true map: the OFP transfer loses most of the detail (distance 0.79-0.97x
  doing nothing and normal angle 0.98-1.16x, against 0.57-0.78x and 0.45-0.59x pulled back).
  With a wrong map both are the same (the map is not trusted).
* **Trust in the map.** Where the map is wrong the two low-pass neighbourhoods do not match:
  the fitted rotation then leaves a poor fit (see :func:`local_rotations`). The detail is
  weighted by ``clip((fit − 0.7) / (0.9 − 0.7), 0, 1)``; where it is not trusted, the target
  gets instead the source's mean detail height along its normals, the one part of the detail
  no map is needed for (a functional map always takes constants to constants). Measured: a
  wrong map then leaves the target where it was (distance 0.89-0.93x doing nothing, against
  1.4-1.7x without the weights), and the weights also help with the true map (0.67x against
  0.70x on average).
* **Scale.** The detail is scaled by ``sqrt(area(base) / area(P X₁))``: the ratio of the areas
  of the surface it is added to and of the surface it was measured from (for point clouds, the
  total vertex masses of the two shapes), so it follows the sizes of the two shapes and
  not their units.

The result keeps the target's pose and low-frequency shape. Modes
(:data:`o3d_ofp.workflows.options.DETAIL_MODES`):

* ``"add"`` (default): the target keeps its own detail and gains the source's on top (right
  for a smooth target, which is taken as its own low-pass shape).
* ``"replace-detail"``: the target's own detail above ``band`` is removed and the source's
  put in its place (a shape given itself as source comes back unchanged). Measured on
  smoothed targets: 1.18-1.31x doing nothing, as re-projecting an already smoothed target on
  the eigenfunctions of its own (smoothed) surface removes more of it.
* ``"coordinates"``: the paper's Fig. 13, the source's coordinates transferred with OFP bases
  replace the target's (the target's pose is lost); ``"replace"`` is its former, deprecated
  name.
"""

from __future__ import annotations

import logging
import math
import numbers
from typing import Any

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as sla

from ..core._threads import blas_threads
from ..core._validation import check_int
from ..core._warnings import warn
from ..core.correspondence import check_p2p
from ..core.geometry import face_areas_normals, vertex_normals
from ..core.spectrum import EigenBasis, check_eigenbasis
from ..core.wording import OptionError, Said
from .maps import Correspondence, check_correspondence
from .options import DETAIL_BAND, BasisOptions, DetailOptions
from .pipeline import transfer_function
from .plan import ROTATION_K

__all__ = [
    "COORDINATES_AREA_RATIO",
    "FIT_RANGE",
    "PART_COVERAGE",
    "check_coordinates_area",
    "detail_vectors",
    "local_rotations",
    "lowpass_coordinates",
    "transfer_detail_frames",
]

logger = logging.getLogger(__name__)

#: Fit (see :func:`local_rotations`) below which the map is not trusted at a vertex, and above
#: which it is fully trusted. Measured at the defaults: true maps 0.70-0.83 at the 5th
#: percentile, median 0.91-0.94; failed estimated maps median 0.40-0.48, 95th percentile
#: 0.65-0.77. (0.6, 0.85) and (0.75, 0.95) give within 0.03 the same distances.
FIT_RANGE = (0.7, 0.9)
_CARRIES = ("p2p", "ofp")


def lowpass_coordinates(eig: EigenBasis, band: int = DETAIL_BAND) -> np.ndarray:
    """Return the low-pass shape: the coordinates projected on the first ``band`` eigenfunctions.

    Parameters
    ----------
    eig : EigenBasis
        The shape's eigenbasis (its ``vertices`` are the coordinates), with ``k >= band``.
    band : int, default 30
        Non-constant eigenfunctions kept.

    Returns
    -------
    (n, 3) ndarray
        ``Φ Φᵀ M X`` over the first ``band + 1`` eigenfunctions.
    """
    band = _check_band(band, eig, "eig")
    low = eig.truncate(band)
    return low.reconstruct(low.project(eig.vertices))


def detail_vectors(eig: EigenBasis, band: int = DETAIL_BAND) -> np.ndarray:
    """Return the detail of a shape: its coordinates minus their low-pass, ``X − P X``.

    Parameters
    ----------
    eig : EigenBasis
        The shape's eigenbasis, with ``k >= band``.
    band : int, default 30
        Non-constant eigenfunctions of the low-pass.

    Returns
    -------
    (n, 3) ndarray
        One displacement per vertex (in the shape's own coordinates).
    """
    return eig.vertices - lowpass_coordinates(eig, band)


def _heat_operator(eig: EigenBasis, k: int) -> Any:
    """Return ``f ↦ (M + L/λ_k)⁻¹ M f``: one implicit heat step of time ``1/λ_k``.

    Rows of the operator sum to one (constants are kept). Vertices without mass (removed by
    the cleaning) take the value of the kept vertex standing for them.
    """
    lam = float(eig.evals[k])
    if not lam > 0:
        raise ValueError(f"eigenvalue {k} of the shape is {lam:g}: the shape has no scale")
    mass = np.asarray(eig.mass, dtype=np.float64)
    empty = mass <= 0
    diag = np.where(empty, 1.0, mass)
    A = (sp.diags(diag) + eig.stiffness / lam).tocsc()
    # SuperLU's supernodal updates call the BLAS, whose threads only spin on this size of
    # problem (measured with another process busy: 14-20x slower with them)
    with blas_threads(1):
        solve = sla.factorized(A)
    stand_in = None
    if np.any(empty):
        c = eig.cleaning
        stand_in = (
            c.representative[c.index] if c is not None else np.arange(mass.shape[0], dtype=int)
        )

    def apply(f: np.ndarray) -> np.ndarray:
        flat = np.asarray(f, dtype=np.float64).reshape(f.shape[0], -1)
        rhs = mass[:, None] * flat
        with blas_threads(1):
            out = np.column_stack([solve(rhs[:, j]) for j in range(flat.shape[1])])
        if stand_in is not None:
            out[empty] = out[stand_in[empty]]
        return out.reshape(f.shape)

    return apply


def local_rotations(
    eig: EigenBasis, source: Any, target: Any, *, rotation_k: int = ROTATION_K
) -> tuple[np.ndarray, np.ndarray]:
    """Rotation at every vertex that best turns a neighbourhood of ``source`` into ``target``.

    ``R_i = argmin_R Σ_j K_ij ‖R (s_j − s̄_i) − (t_j − t̄_i)‖²`` over rotations, ``K`` the
    implicit heat kernel of ``eig`` at time ``1/λ_rotation_k`` and ``s̄_i``, ``t̄_i`` the
    ``K``-weighted means: the polar factor (with determinant +1) of the weighted
    cross-covariance ``C_i``.

    Parameters
    ----------
    eig : EigenBasis
        Eigenbasis of the shape both point sets live on (its operators define the
        neighbourhoods), with ``k >= rotation_k``.
    source, target : (n, 3) array_like of float
        Two embeddings of the same vertices (e.g. the source's low-pass shape pulled back
        through a map, and the target's).
    rotation_k : int, default 10
        Eigenvalue index setting the neighbourhood size.

    Returns
    -------
    rotations : (n, 3, 3) ndarray
        ``rotations[i] @ v`` turns a vector ``v`` of the source's frame at ``i`` into the
        target's.
    fit : (n,) ndarray
        How well the rotated neighbourhoods agree, ``tr(R_i C_i) / sqrt(var_s var_t)`` in
        [−1, 1]: 1 when they are congruent up to a rotation and a scale. Measured at
        ``rotation_k = 10`` between 30-eigenfunction low-pass shapes: true maps give a median
        0.91-0.94 (5th percentile 0.70-0.83) on FAUST and TOSCA pairs, failed maps (flipped or
        scrambled) a median 0.40-0.48 (95th percentile 0.65-0.77).
    """
    n = eig.n_vertices
    rotation_k = check_int(rotation_k, name="rotation_k", minimum=1, maximum=eig.k)
    P = np.asarray(source, dtype=np.float64)
    Q = np.asarray(target, dtype=np.float64)
    for name, arr in (("source", P), ("target", Q)):
        if arr.shape != (n, 3):
            raise ValueError(f"{name} must have shape ({n}, 3); got {arr.shape}")
    # Centre and normalize both embeddings first: the covariances then have entries of order
    # 1 whatever the units (neither the rotation nor the fit depends on them).
    P = P - P.mean(axis=0)
    Q = Q - Q.mean(axis=0)
    P /= max(float(np.abs(P).max()), np.finfo(float).tiny)
    Q /= max(float(np.abs(Q).max()), np.finfo(float).tiny)
    heat = _heat_operator(eig, rotation_k)
    outer = (P[:, :, None] * Q[:, None, :]).reshape(n, 9)
    moments = heat(
        np.hstack([P, Q, outer, (P**2).sum(1, keepdims=True), (Q**2).sum(1, keepdims=True)])
    )
    mean_p, mean_q = moments[:, :3], moments[:, 3:6]
    cov = moments[:, 6:15].reshape(n, 3, 3) - mean_p[:, :, None] * mean_q[:, None, :]
    var_p = moments[:, 15] - (mean_p**2).sum(1)
    var_q = moments[:, 16] - (mean_q**2).sum(1)
    U, sigma, Vt = np.linalg.svd(cov)
    d = np.sign(np.linalg.det(U) * np.linalg.det(Vt))
    d[d == 0] = 1.0
    U[:, :, 2] *= d[:, None]
    # cov = U S Vᵀ: the rotation taking s to t is V Uᵀ (with the reflection removed).
    rotations = np.einsum("nji,nkj->nik", Vt, U)
    agree = sigma[:, 0] + sigma[:, 1] + d * sigma[:, 2]
    spread = np.sqrt(np.clip(var_p, 0.0, None) * np.clip(var_q, 0.0, None))
    fit = np.divide(agree, spread, out=np.zeros(n), where=spread > 0)
    return rotations, np.clip(fit, -1.0, 1.0)


def _check_band(band: Any, eig: EigenBasis, name: str) -> int:
    if isinstance(band, bool) or not isinstance(band, numbers.Integral):
        raise TypeError(f"band must be an integer number of eigenfunctions; got {band!r}")
    if not 1 <= band <= eig.k:
        raise ValueError(
            f"band must be >= 1 and <= the {eig.k} eigenfunctions of {name}; got {band} "
            "(compute the eigenbasis with k >= band)"
        )
    return int(band)


def _normals(eig: EigenBasis, surface: np.ndarray, given: Any, name: str) -> np.ndarray | None:
    if given is not None:
        arr = np.asarray(given, dtype=np.float64)
        if arr.shape != (eig.n_vertices, 3) or not np.all(np.isfinite(arr)):
            raise ValueError(f"{name} must be finite with shape ({eig.n_vertices}, 3)")
        norm = np.linalg.norm(arr, axis=1, keepdims=True)
        return np.divide(arr, norm, out=np.zeros_like(arr), where=norm > 0)
    return None if eig.faces is None else vertex_normals(surface, eig.faces)


#: A map whose image covers less than this fraction of the source's area (the vertices within
#: two mean edge lengths of an image vertex), onto a target whose area is also below this
#: fraction of the source's, maps the target onto a part of the source; a partial map from
#: ``match(partial=True)`` always does, an estimated full-shape map never. Right full maps
#: leave no gap that wide (measured 0.99-1.0: estimated maps crowd by single vertices); the
#: cuts of scripts/eval_partial.py keep 0.55-0.8 of the area.
PART_COVERAGE = 0.9


def _mean_edge(eig: EigenBasis) -> float:
    V, F = eig.vertices, eig.faces
    assert F is not None
    return float(np.linalg.norm(V[F[:, 0]] - V[F[:, 1]], axis=1).mean())


def _covered(eig_1: EigenBasis, eig_2: EigenBasis, p2p: np.ndarray) -> np.ndarray | None:
    """Source vertices within two mean edge lengths of the map's image (None for a cloud).

    The edge length is the larger of the source's and the target's (in the source's units
    as if the target were whole): a coarse target's images are that far apart on a fine
    source.
    """
    from scipy.spatial import cKDTree

    if eig_1.faces is None or eig_2.faces is None:
        return None  # no edge length to measure the gaps with: a cloud is taken as covered
    edge = max(_mean_edge(eig_1), _mean_edge(eig_2) * math.sqrt(eig_1.area / eig_2.area))
    # The images of the target's vertices its eigenbasis keeps (mass > 0): pieces it leaves
    # out (components="largest") are not in its area, and would make a part in pieces look
    # larger than the piece its detail is measured on.
    images = eig_1.vertices[np.unique(p2p[eig_2.mass > 0])]
    distance, _ = cKDTree(images).query(eig_1.vertices, distance_upper_bound=2 * edge)
    return np.isfinite(distance)


def _part_band(eig_1: EigenBasis, eig_2: EigenBasis, band: int, sigma: float) -> int:
    """Target eigenfunctions not above the source's ``band``-th eigenvalue.

    ``sigma``: the source's area per target area along the map (1 in the same units); a
    target eigenvalue in the source's units is ``1 / sigma`` of its own.
    """
    top = eig_1.evals[band] * sigma
    count = int(np.searchsorted(eig_2.evals, top, side="right")) - 1
    return max(1, min(count, eig_2.k))


#: In mode "add", a warning says the target already has detail when its detail (RMS of the
#: coordinates above ``band``, per sqrt(area)) exceeds this fraction of the source's. Measured
#: with band 30: detailed targets 0.93-1.13 (FAUST 087, 094, TOSCA centaur4 against their
#: sources), the same targets smoothed to their first 30 eigenfunctions 0.44-0.72 (re-projected
#: on the smoothed surface's own eigenfunctions, a smooth target keeps some), the paper's
#: smooth donut 0.08.
DETAILED_TARGET = 0.8


def _detail_rms(eig: EigenBasis, low: np.ndarray, *, region: np.ndarray | None = None) -> float:
    """RMS length of the detail ``vertices - low``, per sqrt(area) (scale-free), on ``region``."""
    d = eig.vertices - low
    mass = eig.mass if region is None else np.where(region, eig.mass, 0.0)
    area = float(mass.sum())
    if not area > 0:
        return 0.0
    return math.sqrt(float(mass @ np.einsum("ij,ij->i", d, d)) / area / area)


#: Mode "coordinates" gives the target the source's shape (smoothed by the bases): a result
#: whose area differs from the source's by more than this factor (either way) comes from a
#: wrong map. Measured (area of the result over the source's): FAUST 093 -> 087 0.949 (true
#: map), 0.946 (estimated); onto 087's 30-eigenfunction low-pass 0.77 (true map) and 6.5 with
#: an estimated map that failed there (error 0.49) but stayed under every bound of its
#: quality report; the bunny onto itself 0.97.
COORDINATES_AREA_RATIO = 2.0


def check_coordinates_area(
    V1: np.ndarray, F1: Any, moved: np.ndarray, F2: Any, *, part: np.ndarray | None = None,
    target: np.ndarray | None = None,
) -> None:  # fmt: skip
    """Warn (OFPWarning) when transferred coordinates do not have the source's area.

    ``V1``, ``F1``: the source; ``moved``: the target's new vertices, ``F2`` its faces (either
    faces None: a point cloud, not checked). ``part``: the target's own (n2, 3) vertices when
    it is a part of the source (a partial map, same units): the result should then have the
    area of the region it covers, which is the part's own. ``target``: the target's own
    vertices when the map may be onto a part (a map given as an array, an identity or a
    closest-point map; not an estimated full-shape map): a result with the source's area,
    or with the target's own area when that is smaller (a part of the source in its units),
    passes.
    """
    if F1 is None or F2 is None:
        return
    a2 = float(face_areas_normals(moved, F2)[0].sum())

    def within(a1: float) -> bool:
        return a1 > 0 and 1 / COORDINATES_AREA_RATIO <= a2 / a1 <= COORDINATES_AREA_RATIO

    if part is not None:
        a1, whose = float(face_areas_normals(part, F2)[0].sum()), "the part's own"
    else:
        a1, whose = float(face_areas_normals(V1, F1)[0].sum()), "the source's"
    if within(a1):
        return
    if part is None and target is not None:
        own = float(face_areas_normals(target, F2)[0].sum())
        if own < a1 and within(own):  # the shape of the region a partial map covers
            logger.debug("the transferred coordinates have about the target's own area")
            return
    ratio = a2 / a1 if a1 > 0 else math.inf
    warn(logger, Said(
        "the transferred coordinates give the target {ratio:.3g} times {whose} area (the "
        "source's shape should come back): the map is wrong in places; check "
        "correspondence.quality, give landmarks ({landmarks_check}), or a known map",
        {"ratio": ratio, "whose": whose}, "coordinates_area",
    ))  # fmt: skip


def transfer_detail_frames(
    eig_1: EigenBasis, eig_2: EigenBasis, *, p2p_21: Any = None,
    correspondence: Correspondence | None = None, mode: str = "add", band: int = DETAIL_BAND,
    amount: float = 1.0, carry: str = "p2p", rotation_k: int = ROTATION_K,
    fit_range: tuple[float, float] | None = FIT_RANGE, normals_1: Any = None, normals_2: Any = None,
) -> np.ndarray:  # fmt: skip
    """Give the target the source's geometric detail, in local frames; return new positions.

    Parameters
    ----------
    eig_1, eig_2 : EigenBasis
        Source (with the detail) and target eigenbases, each with ``k >= band`` and
        ``k >= rotation_k`` (and the OFP bases' 29 / 39 for ``carry="ofp"``). Their
        ``vertices`` are the two shapes.
    p2p_21 : (n2,) array_like of int, optional
        Point map: the source vertex of every target vertex.
    correspondence : Correspondence, optional
        A map from :func:`o3d_ofp.match` (its point map is used). Give exactly one of the two.
    mode : {"add", "replace-detail"}, default "add"
        "add": the target keeps its own detail and the source's is added on top (right for a
        smooth target: it is taken as its own low-pass shape). "replace-detail": the
        target's own detail above ``band`` is replaced by the source's (added to the target's
        low-pass shape; a shape given itself as source then comes back unchanged; on a smoothed
        target, see the module notes). (Mode "coordinates" moves the target through the OFP
        bases: :func:`o3d_ofp.transfer_detail`.)
    band : int, default 30
        Low band, in eigenfunctions: the detail is the part of the coordinates above the
        first ``band`` eigenfunctions. Lower takes more of the source's shape (and of its
        pose), higher only its finer detail. Onto a part (a partial map, or a given or
        closest-point map whose image covers less than :data:`PART_COVERAGE` of the source,
        onto a target of less than that area), the target's low band is its
        eigenfunctions up to the source's ``band``-th eigenvalue (about the area ratio times
        ``band``), and its detail and size are compared with the region the part covers.
    amount : float, default 1.0
        Multiplies the transferred detail, in [0, 10] (0 returns the base surface).
    carry : {"p2p", "ofp"}, default "p2p"
        How the detail reaches the target: pulled back through the point map, or transferred
        with the OFP bases (order 2 on 29 / 39 eigenfunctions, "ours*"; measured: see the
        module notes).
    rotation_k : int, default 10
        Size of the neighbourhood the local rotations are fitted on (heat kernel at time
        ``1/λ_rotation_k``).
    fit_range : (float, float) or None, default (0.7, 0.9)
        Fits (see :func:`local_rotations`) between which the trust in the map goes from none
        to full, ``0 <= lo < hi <= 1``; ``None`` trusts the map everywhere.
    normals_1, normals_2 : (n, 3) array_like, optional
        Normals for the mean detail height used where the map is not trusted (default: vertex
        normals of the source's low-pass shape and of the surface the detail is added to).
        Needed for point clouds; without them a cloud gets nothing where the map is not
        trusted.

    Returns
    -------
    (n2, 3) ndarray
        New target vertex positions (the target's vertex order).

    Raises
    ------
    ValueError
        For a value outside its range, or no / two maps; each message names the keyword.
    """
    options = DetailOptions(mode=mode, band=band, amount=amount)
    correspondence = _checked(eig_1, eig_2, p2p_21, correspondence, options.mode, carry)
    mode, amount, p2p = options.mode, options.amount, np.asarray(correspondence.p2p_21)
    band_1 = _check_band(band, eig_1, "eig_1")
    _check_band(band, eig_2, "eig_2")
    rotation_k = check_int(rotation_k, name="rotation_k", minimum=1, maximum=eig_2.k)
    if fit_range is not None:
        lo, hi = (float(v) for v in fit_range)
        if not 0.0 <= lo < hi <= 1.0:
            raise ValueError(f"fit_range must be (lo, hi) with 0 <= lo < hi <= 1; got {fit_range}")
    low_1 = lowpass_coordinates(eig_1, band_1)
    detail_1 = eig_1.vertices - low_1
    region, band_2 = _onto_part(eig_1, eig_2, correspondence, band_1)
    base = np.array(eig_2.vertices) if mode == "add" else lowpass_coordinates(eig_2, band_2)
    if mode == "add" and amount > 0:
        _warn_detailed_target(eig_1, eig_2, low_1, region, band_1, band_2)
    if carry == "p2p":
        low_at_2, detail_at_2 = low_1[p2p], detail_1[p2p]
    else:
        ours = BasisOptions(preset="ours*")
        both = transfer_function(np.hstack([low_1, detail_1]), eig_1, eig_2,
                                 correspondence=correspondence, options=ours)  # fmt: skip
        low_at_2, detail_at_2 = both[:, :3], both[:, 3:]
    R, fit = local_rotations(eig_2, low_at_2, base, rotation_k=rotation_k)
    moved = np.einsum("nij,nj->ni", R, detail_at_2)
    if fit_range is not None:
        w = np.clip((fit - lo) / (hi - lo), 0.0, 1.0)
        moved *= w[:, None]
        n1 = _normals(eig_1, low_1, normals_1, "normals_1")
        n2 = _normals(eig_2, base, normals_2, "normals_2")
        if n1 is not None and n2 is not None:
            mean_height = float(eig_1.mass @ np.einsum("ij,ij->i", detail_1, n1)) / eig_1.area
            moved += ((1.0 - w) * mean_height)[:, None] * n2
        logger.debug("map trusted at %.1f %% of the target", 100.0 * float(w.mean()))
    scale = _detail_scale(eig_1, eig_2, base, low_1, region)
    logger.debug("detail transfer: band %d, scale %.4g, carry %s", band_1, scale, carry)
    return base + (amount * scale) * moved


def _checked(
    eig_1: EigenBasis, eig_2: EigenBasis, p2p_21: Any, correspondence: Any, mode: str, carry: str
) -> Correspondence:
    """Refuse what :func:`transfer_detail_frames` cannot do; return its map, checked."""
    if mode == "coordinates":
        raise OptionError("mode", "'coordinates' moves the target through the OFP bases: "
                          "o3d_ofp.transfer_detail(..., mode='coordinates')")  # fmt: skip
    if carry not in _CARRIES:
        raise OptionError("carry", f"must be 'p2p' or 'ofp'; got {carry!r}")
    check_eigenbasis(eig_1, "eig_1")
    check_eigenbasis(eig_2, "eig_2")
    if (p2p_21 is None) == (correspondence is None):
        raise OptionError("p2p_21", "and correspondence: give exactly one of them")
    n1, n2 = eig_1.n_vertices, eig_2.n_vertices
    if check_correspondence(correspondence) is None:
        correspondence = Correspondence(p2p_21=check_p2p(p2p_21, n2, n1), n_source=n1)
    correspondence.check(n1, n2, source=eig_1.vertices, target=eig_2.vertices)
    return correspondence


def _detail_scale(
    eig_1: EigenBasis, eig_2: EigenBasis, base: np.ndarray, low_1: np.ndarray, region: Any
) -> float:
    """``sqrt(area(base) / area(P X₁))``, ``P X₁`` on ``region`` (clouds: their total masses)."""
    if eig_1.faces is None or eig_2.faces is None:
        return math.sqrt(eig_2.area / eig_1.area)
    area_base = float(face_areas_normals(base, eig_2.faces)[0].sum())
    areas = face_areas_normals(low_1, eig_1.faces)[0]
    inside = slice(None) if region is None else region[eig_1.faces].all(axis=1)
    area_low = float(areas[inside].sum())
    return math.sqrt(area_base / area_low) if area_low > 0 else math.sqrt(eig_2.area / eig_1.area)


def _onto_part(
    eig_1: EigenBasis, eig_2: EigenBasis, correspondence: Correspondence, band_1: int
) -> tuple[np.ndarray | None, int]:
    """Return the source region a part covers (None: not a part) and the part's own band.

    Onto a part of the source (a partial map), the part's eigenfunctions have higher
    frequencies than the whole's at the same count, so its low band is the one below the
    source's band-th eigenvalue; the source's detail and low-pass area are those of the
    region the part covers.
    """
    # Measured with the true maps on the 8 cuts of
    # scripts/eval_detail.py --only parts (smooth parts): no "already has detail" warning,
    # where comparing the part above its own first 30 eigenfunctions with the whole source
    # warned on 3; the result's area 0.77-1.01 of the truth's (0.70-0.98 with the whole's
    # low-pass area), its distance 0.52-0.71 of doing nothing (0.52-0.70). Cuts of FAUST 093
    # that kept their detail, or were smoothed a little (smooth 0.02): 0.82-1.08 of the
    # covered region's detail, like whole bodies (0.96-1.0).
    # An estimated full-shape map is never taken for a part (its coverage is not measured):
    # it crowds when it is wrong, and a smoothed whole target has less area than its source.
    method = correspondence.method
    p2p = np.asarray(correspondence.p2p_21)
    region = None if method == "estimate" else _covered(eig_1, eig_2, p2p)
    covered = 0.0 if region is None else float(eig_1.mass[region].sum())
    part = region is not None and (
        method == "partial"
        or (covered < PART_COVERAGE * eig_1.area and eig_2.area < PART_COVERAGE * eig_1.area)
    )
    if not part:
        return None, band_1
    band_2 = _part_band(eig_1, eig_2, band_1, covered / eig_2.area)
    logger.info("detail transfer onto a part (%.2f of the source covered): target band %d",
                covered / eig_1.area, band_2)  # fmt: skip
    return region, band_2


def _warn_detailed_target(
    eig_1: EigenBasis, eig_2: EigenBasis, low_1: np.ndarray, region: np.ndarray | None,
    band_1: int, band_2: int,
) -> None:  # fmt: skip
    """Warn (mode "add") when the target already has detail: the source's would go on top."""
    own = _detail_rms(eig_2, lowpass_coordinates(eig_2, band_2))
    theirs = _detail_rms(eig_1, low_1, region=region)
    on_part = "" if region is None else f" (on this part: above its first {band_2} eigenfunctions)"
    if theirs > 0 and own > DETAILED_TARGET * theirs:
        warn(logger, Said(
            "the target already has detail above band {band}{on_part} ({share:.3g} of the "
            "source's, above {bound:g}): mode 'add' keeps it and adds the source's on top, which "
            "exaggerates it; {replace_detail} replaces it instead",
            {"band": band_1, "on_part": on_part, "share": own / theirs, "bound": DETAILED_TARGET},
            "detailed_target",
        ))  # fmt: skip
