"""Geometric detail transfer in local frames, on arrays.

The *detail* a target lacks is the source's coordinates minus the source's low-pass shape that
the target resembles: ``D = X − P X``, ``P`` a low-pass of the source *calibrated* to how
smooth the target is (:func:`calibrate_detail`), or, with a ``band`` given, the projection on
the first ``band`` Laplace-Beltrami eigenfunctions (an expert's override). It is carried from
a source to a target through a map and re-applied in the target's local frames:

* **Calibration.** Whatever tool smoothed the target (a fairing, Open3D's filters, a sculpting
  brush, a decimation), the target resembles one of the source's heat low-passes more than
  the others: the one compared best with it, neighbourhood by neighbourhood up to a rotation
  and a scale, through the map. Its detail is what the smoothing removed. Where the target
  lacks it is told by the converse test (``CONVERSE``): a target that lacks the detail
  fits the source worse when it is smoothed further, while two shapes equally detailed (two
  people, a target barely touched) both fit better when either is smoothed. Where the target
  fits the source itself as well (a part left detailed, a target as detailed as the source),
  nothing is added there. A region smoothed more than the whole (a sculpting brush on part of
  the shape) gets the detail above the longer low-pass it fits (``LACKING``). Measured
  (``scripts/eval_detail.py``: five pairs, targets made by seven smoothers the library does
  not own, true maps): surface distance to the truth 0.77x doing nothing on average, at most
  1.00x; a fixed band of 30 eigenfunctions added its detail on top of what the smoothing
  left: 5.3x on average, 36.4x at worst.
* **Local frames.** At every target vertex ``i`` the frame of the source's low-pass surface at
  the corresponding point is turned into the target's by ``R_i``, the rotation that best aligns
  the source's low-pass surface and the target around ``i`` (weighted Procrustes over a
  heat-kernel neighbourhood): the normal goes to the normal and the tangent plane to the tangent
  plane, so the detail keeps its orientation relative to the surface whatever the two poses.
  A detail vector with frame coordinates ``c`` (normal height and two tangent offsets) at the
  source becomes ``R_i (E₁ c) = E₂ c`` at the target. Between meshes, where the fitted
  rotation turns the normals over, the two surfaces' normals take part in the fit
  (``NORMAL_WEIGHT``): a neighbourhood along a thinned limb leaves the turn about its axis
  undetermined. The fitted rotation (on neighbourhoods
  of ``ROTATION_TIME``) needs no normals (point clouds work) and never degenerates where
  a low-pass collapses a limb into a ribbon (frames from the low-pass surface's own normals
  were 43° off on FAUST and made every result worse than doing nothing).
* **Carrying.** The detail vectors and the low-pass coordinates are carried to the target
  either by pulling them back through the point map (``carry="p2p"``) or with the OFP transfer
  of the paper (``carry="ofp"``, :func:`o3d_ofp.transfer_function`).
  Measured with the true map on the former benchmark (targets projected on 30
  eigenfunctions, band 30): the OFP transfer loses most of the detail (distance 0.79-0.97x
  doing nothing, normal angle 0.98-1.16x; pulled back 0.57-0.78x and 0.45-0.59x).
  With a wrong map both are the same (the map is not trusted).
* **Trust in the map.** Where the map is wrong the two low-pass neighbourhoods do not match:
  the fitted rotation then leaves a poor fit (see ``local_rotations``). The detail is
  weighted by ``clip((fit − 0.7) / (0.9 − 0.7), 0, 1)``; where it is not trusted, the target
  gets instead the source's mean detail height along its normals, the one part of the detail
  no map is needed for (a functional map always takes constants to constants). Measured on
  the former benchmark (band 30): a wrong map then leaves the target where it was (distance
  0.89-0.93x doing nothing, against 1.4-1.7x without the weights), and the weights also help
  with the true map (0.67x against 0.70x on average).
* **Scale.** The detail is scaled by ``sqrt(area(base) / area(P X₁))``: the ratio of the areas
  of the surface it is added to and of the surface it was measured from (for point clouds, the
  total vertex masses of the two shapes), so it follows the sizes of the two shapes and
  not their units.

The result keeps the target's pose and low-frequency shape. Modes
(``o3d_ofp.workflows.options.DETAIL_MODES``):

* ``"add"`` (default): the target keeps its own detail and gains what it lacks of the
  source's (with a ``band``: all of the source's detail above it, on top of its own).
* ``"replace-detail"``: the target's own detail is removed by the same low-pass (its own
  operators) and the source's put in its place everywhere (a shape given itself as source
  comes back unchanged).
* ``"coordinates"``: the paper's Fig. 13, the source's coordinates transferred with OFP bases
  replace the target's (the target's pose is lost); ``"replace"`` is its former, deprecated
  name.
"""

from __future__ import annotations

import dataclasses
import functools
import logging
import math
import numbers
from typing import Any

import numpy as np
import scipy.sparse as sp

from ..core._threads import blas_threads
from ..core._warnings import warn
from ..core.correspondence import check_p2p, nearest_neighbors
from ..core.filtering import spread_scale
from ..core.geometry import (
    edge_graph,
    face_areas_normals,
    fold_cosines,
    interior_edges,
    outward_sign,
    vertex_normals,
)
from ..core.spectrum import EigenBasis, check_eigenbasis, factorize_spd
from ..core.wording import OptionError, Said
from .eigenbases import eigenbasis_bytes, run_per_shape
from .maps import Correspondence, check_correspondence
from .options import BasisOptions, DetailOptions, check_number, moved_keywords
from .pipeline import transfer_function

__all__ = [
    "COMPARE_TIME",
    "CONVERSE",
    "COORDINATES_AREA_RATIO",
    "ESTIMATED_SEEN",
    "FIT_RANGE",
    "GATE_TIME",
    "LACKING",
    "LADDER",
    "NORMAL_WEIGHT",
    "NOTHING_ADDED",
    "PART_COVERAGE",
    "ROTATION_TIME",
    "ROTATION_WIDER",
    "STEPS",
    "DetailCalibration",
    "calibrate_detail",
    "check_coordinates_area",
    "detail_vectors",
    "local_rotations",
    "lowpass_coordinates",
    "transfer_detail_frames",
]

logger = logging.getLogger(__name__)

#: Fit (see :func:`local_rotations`) below which the map is not trusted at a vertex, and above
#: which it is fully trusted. Measured with neighbourhoods of ``1/λ_10`` (before
#: :data:`ROTATION_TIME`; not measured again) between 30-eigenfunction low-passes: true maps
#: 0.70-0.83 at the 5th percentile, median 0.91-0.94; failed estimated maps median 0.40-0.48,
#: 95th percentile 0.65-0.77. (0.6, 0.85) and (0.75, 0.95) give within 0.03 the same distances.
FIT_RANGE = (0.7, 0.9)
_CARRIES = ("p2p", "ofp")

#: The source's low-pass shapes the calibration chooses among: the source's coordinates after
#: :data:`STEPS` implicit heat steps ``(M + (t / STEPS) L)⁻¹ M`` of total time ``t = c · area``
#: for each ``c`` here, a factor 2 apart, from no visible change (1e-6) to limbs thinned
#: (4e-3). Several steps fall off like the iterated filters of other tools (umbrella,
#: Laplacian, brush) and stay close to a single implicit fairing step: measured
#: (``scripts/eval_detail.py``, true maps, before :data:`CONVERSE`) one step against three,
#: mean distance 0.88 and 0.87x doing nothing, the worst 1.31 and 1.04x (a 30-eigenfunction
#: projection). Each level
#: is scaled back to the source's spread (RMS distance from the centroid): a low-pass shrinks
#: a compact shape as a whole, and a smooth sphere or torus target, which fits every shrunk
#: level alike, got that shrinking as detail (a bumpy sphere onto a smooth one: 13 times the
#: bumps' height off, 0.13 with the spread kept; on bodies, whose limbs thin while the whole
#: keeps its extent, it changes nothing measurable).
LADDER = tuple(float(c) for c in np.geomspace(1e-6, 4e-3, 13))
STEPS = 3
#: Neighbourhoods (heat time / the target's area) on which the calibration compares the
#: target with the source's low-passes: a few edge lengths of a 5-10k vertex body, the scale
#: of its detail. Measured on FAUST and TOSCA targets faired by a known step: the level it
#: chooses is the one closest to the truth (neighbourhoods of ``1/λ_100``, ten times wider,
#: fit every level alike).
COMPARE_TIME = 1e-4
#: Neighbourhoods of the local rotations (heat time / area): about ``1/λ_100`` on FAUST,
#: TOSCA and the bunny (measured 8.7e-4, 8.0e-4, 8.1e-4). Measured on TOSCA centaur2 → 4
#: (true map, the target faired, the source's low-pass the same fairing): the distance to the
#: truth 0.32-0.34x doing nothing against 0.36-0.38x at ``1/λ_10`` (neighbourhoods wider than
#: a limb blur the rotations at joints).
ROTATION_TIME = 8e-4
#: The rotations' neighbourhoods are at least this many times as wide (in heat time) as the
#: low-pass's own blur: a strong low-pass collapses limbs and fingers into ribbons, whose
#: neighbourhoods of :data:`ROTATION_TIME` give tilted rotations. With a band of 30, three
#: times its blur ``1/λ_30`` is about ``1/λ_10`` (Weyl's law), the neighbourhood measured
#: right for it (10 and 20 gave the same results, 3 blurred neighbouring parts).
ROTATION_WIDER = 3.0
#: Where the rotation fitted to a neighbourhood's positions turns the source's normals over
#: (their heat-weighted mean cosine with the target's is negative after it), the normals take
#: part in the fit: the cross-covariance gains this times ``sqrt(var_s var_t)`` (the
#: positions' spreads) times the heat-weighted mean of ``n_s n_tᵀ``, as if each point came
#: with two more one spread away along its normal. Positions leave the rotation undetermined
#: on a limb the low-pass thinned (spreads 1 : 0.06 : 0.01: any turn about its axis fits).
#: Measured (``scripts/eval_detail.py``, true maps): on TOSCA centaur2 → 4 faired at 5e-4 of
#: its area, 151 vertices of a leg got their detail inside out (normal angle 1.00x doing
#: nothing; 0.83x with this). Steering every rotation by the normals gained 0.01-0.05 more on
#: the fairings but moved a band-30 transfer onto a smoothed part away from the truth (the
#: normals of a 30-eigenfunction low-pass are off where it makes limbs ribbons), at weights
#: 0.1-1 alike.
NORMAL_WEIGHT = 1.0
#: Where the target matches the source's calibrated low-pass better than the source itself,
#: it lacks the detail between them: all of it once its misfit to the source is this much
#: reduced (share of ``1 − fit``, both averaged over neighbourhoods of :data:`GATE_TIME`),
#: none where it is not reduced. Without it, a target smoothed in one region only (a brush)
#: got the detail everywhere (1.4-1.8x doing nothing); 0.25 and 0.5 give the same mean
#: distance (0.84 and 0.88x), the worst 1.20 and 1.04x (before :data:`CONVERSE`).
#: A region where a longer low-pass removes this share of the misfit the calibrated one
#: leaves there is smoothed more than the whole (a brush on part of the shape): it gets the
#: detail above that longer low-pass. Measured (``scripts/eval_detail.py``, true maps, the 35
#: targets, surface distance): the five brushed targets 0.72-1.00x doing nothing against
#: 0.93-1.02x with the whole's level alone (one, the centaur, 0.94 against 0.93), the other
#: targets no farther than 0.01 (FAUST 019 -> 094's fairings and Open3D filters 0.53-0.74x
#: against 0.57-0.76x); with estimated maps the same; onto the centaur's faired parts 0.54
#: and 0.58x against 0.48 and 0.56x (a region of centaur 4 fits the longest low-pass better
#: even unsmoothed). A share of 0.4 gained more on the brushes but lost up to 0.17 on the
#: fairings (0.46 -> 0.63x); 0.6 gained less.
LACKING = 0.5
#: Neighbourhoods (heat time / the target's area) over which the gain in fit is averaged: a
#: region a brush smooths (a tenth of a body), wider than the comparison's.
GATE_TIME = 1e-3
#: The converse test. Two shapes equally detailed but with different detail (two people) both
#: fit each other better when either is smoothed: the detail that does not correspond goes. A
#: target that lacks the source's detail fits the source worse when it is smoothed further.
#: When smoothing the target by the calibrated low-pass (on its own operators) loses, on
#: average, at least this share of what smoothing the source gains, the target lacks the
#: detail wherever the source's low-pass fits it better and its own fits the source worse;
#: otherwise the :data:`LACKING` rule says where (in a region smoothed more than the whole,
#: the larger of the two). The target's low-pass has the same heat time
#: per area as the source's (onto a part, less than the source's in absolute terms, by the
#: part's share of its area). Measured (``scripts/eval_detail.py``, true maps, five pairs, the
#: loss over the gain): the targets smoothed all over by the fairings and Open3D's Laplacian
#: and simple filters -0.82 to -7.5, the projection on 30 eigenfunctions -1.1 to -2.4;
#: Open3D's Taubin filter, which barely touches the shapes, -0.08 to +12; the brush -2.6 to
#: +5.6. Estimated maps, whose images of neighbouring vertices are not neighbours at the
#: detail's scale, gain wherever a low-pass is chosen (0.9 to 33 times the source's gain; none
#: is chosen on the projections) and keep the :data:`LACKING` rule. Mean surface distance to
#: the truth 0.79x doing nothing against 0.89x with the :data:`LACKING` rule alone, the worst
#: the same (1.02x); the fairings 0.36-0.85x against 0.55-0.99x.
CONVERSE = 0.5
#: A calibrated transfer that adds less than this share of the detail says so.
NOTHING_ADDED = 0.05
#: Through an estimated map (``match``'s, whose images are an edge or two off) the calibration
#: does not see what a smoothed target lacks: a calibrated transfer through one that finds
#: less than this share lacking says so, and advises a map given rather than another mode.
#: Measured (``calibrate_detail``, FAUST 093 -> 087, 019 -> 094, TOSCA centaur2 -> 4; the
#: targets smoothed by the seven smoothers of ``scripts/eval_detail.py`` and unsmoothed):
#: through the estimated maps 0.00-0.17 found lacking, unsmoothed targets 0.03-0.08 alike;
#: through the true maps 0.39-0.94 on the targets smoothed all over (fairings, Open3D's
#: Laplacian and simple filters, the 30-eigenfunction projection), 0.02-0.04 on the unsmoothed
#: ones and Open3D's Taubin filter, 0.04-0.50 on the brushed ones.
ESTIMATED_SEEN = 0.25
#: A fold: an edge across which the two triangles' normals are more than 120° apart (the
#: cosine below this). Where the detail carried through the map folds the result, the
#: surface it is added to does not fold there and the source does not bend near the map's
#: images (no edge of more than 90°, the cosine below :data:`SOURCE_BEND`, within
#: :data:`FOLD_RINGS` edges: added onto a smoother surface, a sharp bend of the source may
#: become a fold), the detail jumps between neighbouring vertices: the map crowds many target
#: vertices onto a few source ones (a map wrong at the detail's scale, a source coarser than
#: the target), or the target's smoothing collapsed a part (hands as spikes). At such a
#: fold's vertices and their neighbours the detail is replaced by its mean over each vertex
#: and its neighbours, at most :data:`FOLD_AVERAGINGS` times, then halved until no such fold is
#: left, at most :data:`FOLD_HALVINGS` times (to a millionth), then removed there (the surface
#: it is added to does not fold there). Measured (scratch): FAUST 093 onto the upper body of
#: 087, cut, then smoothed by Open3D's Laplacian filter (10 iterations), through the map
#: ``match(partial=True)`` estimates (0.049 sqrt(area) off): 116 folds at a raised hand and
#: the head, none after (314 vertices averaged, 69 lowered), the distance to 087 0.99x ->
#: 0.98x doing nothing; through the true map 6 folds, all near the source's bends.
#: ``scripts/eval_detail.py``'s 35 targets, true maps: surface distance 0.7672 -> 0.7683
#: doing nothing on average, normal angle 0.8088 -> 0.8065 (FAUST 093 -> 087's
#: 30-eigenfunction projection 0.693 -> 0.705 and 0.775 -> 0.769; the remeshed horse faired
#: 0.583 -> 0.562 in angle). Halving alone, without averaging first: 0.97x on the partial map
#: above, but the remeshed cat's and horse's projections, whose true maps are many-to-one,
#: went from 0.67x and 0.73x doing nothing to 0.85x and 0.95x; 20 averagings gave what 5 do.
#: TOSCA centaur2 -> 4 faired (true map): its 147 folds are the source's, none touched (with
#: the source's bends within one edge, 83 vertices lowered and the normal angle 0.83x ->
#: 0.84x doing nothing; with its folds of 120° in place of its bends of 90°, 225).
FOLD_COSINE = -0.5
SOURCE_BEND = 0.0
FOLD_RINGS = 2
FOLD_AVERAGINGS = 5
FOLD_HALVINGS = 20
#: Lowered at this share of the target or more, it is said; less is logged. Measured: the
#: estimated partial map above 1.2 %, the map of ``tests/test_detail.py`` that crowds FAUST
#: onto every sixth vertex 1.6 %; true maps onto the 35 targets of ``eval_detail.py`` none
#: but onto the 30-eigenfunction projections (FAUST 093 -> 087 6.6 %, the centaur 2.4 %, the
#: horse 2.7 %), whose hands and hooves are spikes.
FOLDS_TOLD = 0.01


def lowpass_coordinates(eig: EigenBasis, band: int) -> np.ndarray:
    """Return the low-pass shape: the coordinates projected on the first ``band`` eigenfunctions.

    Parameters
    ----------
    eig : EigenBasis
        The shape's eigenbasis (its ``vertices`` are the coordinates), with ``k >= band``.
    band : int
        Non-constant eigenfunctions kept.

    Returns
    -------
    (n, 3) ndarray
        ``Φ Φᵀ M X`` over the first ``band + 1`` eigenfunctions.
    """
    band = _check_band(band, eig, "eig")
    low = eig.truncate(band)
    return low.reconstruct(low.project(eig.vertices))


def detail_vectors(eig: EigenBasis, band: int) -> np.ndarray:
    """Return the detail of a shape: its coordinates minus their low-pass, ``X − P X``.

    Parameters
    ----------
    eig : EigenBasis
        The shape's eigenbasis, with ``k >= band``.
    band : int
        Non-constant eigenfunctions of the low-pass.

    Returns
    -------
    (n, 3) ndarray
        One displacement per vertex (in the shape's own coordinates).
    """
    return eig.vertices - lowpass_coordinates(eig, band)


def _heat_operator(eig: EigenBasis, time: float) -> Any:
    """Return ``f ↦ (M + t L)⁻¹ M f``: one implicit heat step of time ``t = time``.

    Rows of the operator sum to one (constants are kept). Vertices without mass (removed by
    the cleaning) take the value of the kept vertex standing for them.
    """
    if not time > 0 or not math.isfinite(time):
        raise ValueError(f"the heat time must be positive; got {time:g} (the shape has no scale)")
    mass = np.asarray(eig.mass, dtype=np.float64)
    empty = mass <= 0
    diag = np.where(empty, 1.0, mass)
    A = (sp.diags(diag) + time * eig.stiffness).tocsc()
    # SuperLU's supernodal updates call the BLAS, whose threads only spin on this size of
    # problem (measured with another process busy: 14-20x slower with them); cholespy's
    # CHOLMOD brings its own single-threaded BLAS, which this leaves alone
    with blas_threads(1):
        solve, _ = factorize_spd(A, what=f"the heat step M + tL (t={time:.3g})")
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
            out = solve.matmat(rhs)  # every column in one pass over the factor
        if stand_in is not None:
            out[empty] = out[stand_in[empty]]
        return out.reshape(f.shape)

    return apply


def _procrustes(
    heat: Any, source: np.ndarray, target: np.ndarray,
    normals: tuple[np.ndarray, np.ndarray] | None = None,
) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """Weighted Procrustes of every neighbourhood (``heat``'s rows): rotations and fits.

    With ``normals`` (the source's and the target's unit normals at the same vertices), where
    the rotation turns the normals over, the cross-covariance also takes the normals' (see
    ``NORMAL_WEIGHT``); the fit is that of the positions alone.
    """
    n = source.shape[0]
    # Centre and normalize both embeddings first: the covariances then have entries of order
    # 1 whatever the units (neither the rotation nor the fit depends on them).
    P = source - source.mean(axis=0)
    Q = target - target.mean(axis=0)
    P /= max(float(np.abs(P).max()), np.finfo(float).tiny)
    Q /= max(float(np.abs(Q).max()), np.finfo(float).tiny)
    outer = (P[:, :, None] * Q[:, None, :]).reshape(n, 9)
    moments = heat(
        np.hstack([P, Q, outer, (P**2).sum(1, keepdims=True), (Q**2).sum(1, keepdims=True)])
    )
    mean_p, mean_q = moments[:, :3], moments[:, 3:6]
    cov = moments[:, 6:15].reshape(n, 3, 3) - mean_p[:, :, None] * mean_q[:, None, :]
    var_p = moments[:, 15] - (mean_p**2).sum(1)
    var_q = moments[:, 16] - (mean_q**2).sum(1)
    spread = np.sqrt(np.clip(var_p, 0.0, None) * np.clip(var_q, 0.0, None))
    rotations = _polar(cov)
    if normals is not None:
        n_p, n_q = normals
        along = heat((n_p[:, :, None] * n_q[:, None, :]).reshape(n, 9)).reshape(n, 3, 3)
        # where the positions' rotation turns the normals over (their mean cosine after it
        # is negative), the normals take part in the fit
        over = np.einsum("nij,nji->n", rotations, along) < 0.0
        if np.any(over):
            steer = cov[over] + NORMAL_WEIGHT * spread[over, None, None] * along[over]
            rotations[over] = _polar(steer)
    agree = np.einsum("nij,nji->n", rotations, cov)  # tr(R C)
    fit = np.divide(agree, spread, out=np.zeros(n), where=spread > 0)
    return rotations, np.clip(fit, -1.0, 1.0)


def _polar(cov: np.ndarray) -> np.ndarray:
    """(n, 3, 3) rotations ``R`` maximizing ``tr(R C)`` for each cross-covariance ``C``."""
    U, _, Vt = np.linalg.svd(cov)
    d = np.sign(np.linalg.det(U) * np.linalg.det(Vt))
    d[d == 0] = 1.0
    U[:, :, 2] *= d[:, None]
    # C = U S Vᵀ: the rotation taking s to t is V Uᵀ (with the reflection removed).
    return np.einsum("nji,nkj->nik", Vt, U)


@moved_keywords(rotation_k="rotation_time= (a heat time, as a fraction of the area)")
def local_rotations(
    eig: EigenBasis, source: Any, target: Any, *, rotation_time: float = ROTATION_TIME,
    normals: tuple[Any, Any] | None = None,
) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """Rotation at every vertex that best turns a neighbourhood of ``source`` into ``target``.

    ``R_i = argmin_R Σ_j K_ij ‖R (s_j − s̄_i) − (t_j − t̄_i)‖²`` over rotations, ``K`` the
    implicit heat kernel of ``eig`` at time ``rotation_time · area`` and ``s̄_i``, ``t̄_i`` the
    ``K``-weighted means: the polar factor (with determinant +1) of the weighted
    cross-covariance ``C_i``. With ``normals``, where that rotation turns the source's normals
    over, the normals take part in the fit (:data:`NORMAL_WEIGHT`): a neighbourhood stretched
    along a thin limb fits any turn about the limb's axis, and on a smoothed leg one turned
    the detail inside out.

    Parameters
    ----------
    eig : EigenBasis
        Eigenbasis of the shape both point sets live on (its operators define the
        neighbourhoods; no eigenfunction is used).
    source, target : (n, 3) array_like of float
        Two embeddings of the same vertices (e.g. the source's low-pass shape pulled back
        through a map, and the target's).
    rotation_time : float, default 8e-4
        Heat time of the neighbourhoods, as a fraction of the shape's area, in (0, 1].
    normals : ((n, 3) array_like, (n, 3) array_like), optional
        Unit normals of ``source`` and of ``target`` at the same vertices, oriented alike
        (both outward).

    Returns
    -------
    rotations : (n, 3, 3) ndarray
        ``rotations[i] @ v`` turns a vector ``v`` of the source's frame at ``i`` into the
        target's.
    fit : (n,) ndarray
        How well the rotated neighbourhoods agree, ``tr(R_i C_i) / sqrt(var_s var_t)`` in
        [−1, 1]: 1 when they are congruent up to a rotation and a scale.
    """
    n = eig.n_vertices
    rotation_time = _positive(rotation_time, "rotation_time")
    P = np.asarray(source, dtype=np.float64)
    Q = np.asarray(target, dtype=np.float64)
    for name, arr in (("source", P), ("target", Q)):
        if arr.shape != (n, 3):
            raise ValueError(f"{name} must have shape ({n}, 3); got {arr.shape}")
    if normals is not None:
        normals = tuple(np.asarray(a, dtype=np.float64) for a in normals)
        if len(normals) != 2 or any(a.shape != (n, 3) for a in normals):
            raise ValueError(f"normals must be two arrays of shape ({n}, 3)")
        if not all(np.all(np.isfinite(a)) for a in normals):
            raise ValueError("normals must be finite")
    return _procrustes(_heat_operator(eig, rotation_time * eig.area), P, Q, normals)


@dataclasses.dataclass(frozen=True, eq=False)
class DetailCalibration:
    """What detail of the source a target lacks (made by :func:`calibrate_detail`).

    Attributes
    ----------
    time : float
        Heat time of the source's calibrated low-pass, as a fraction of the source's area
        (0: the target is as detailed as the source).
    fits : (len(LADDER) + 1,) ndarray
        Mean fit (see :func:`local_rotations`) of the target with the source itself and with
        each of its low-passes in :data:`LADDER`, through the map.
    lacking : (n2,) ndarray
        Share of the calibrated detail (above each vertex's own level, see ``times``) each
        target vertex lacks, in [0, 1].
    share : float
        The area-weighted mean of ``lacking``.
    target_lowpass : (n2, 3) ndarray
        The target's own low-passes at the same heat times per area as the source's, blended
        as the source's are (the target itself where the time is 0): mode "replace-detail"'s
        base.
    times : (n2,) ndarray
        Heat time of the source's low-pass each target vertex lacks the detail above, as a
        fraction of the source's area: ``time``, except in regions that lack more than the
        whole (a region a brush smoothed, see :func:`calibrate_detail`), before the levels
        are blended across the regions' borders.
    """

    time: float
    fits: np.ndarray
    lacking: np.ndarray
    share: float
    target_lowpass: np.ndarray
    times: np.ndarray


def _heat_lowpass(eig: EigenBasis, time: float) -> np.ndarray:
    """Return one level of :data:`LADDER`: the coordinates after heat steps, spread kept.

    :data:`STEPS` implicit steps of total time ``time · area``, then the result scaled back
    to the coordinates' spread (RMS distance from the centroid); 0 returns the coordinates.
    """
    X = np.asarray(eig.vertices, dtype=np.float64)
    if time == 0.0:
        return X
    step = _heat_operator(eig, time * eig.area / STEPS)
    Y = X
    for _ in range(STEPS):
        Y = step(Y)
    return _same_spread(eig, X, Y)


def _ladder(eig: EigenBasis) -> list[np.ndarray]:
    """Return the coordinates, then their heat low-passes at the :data:`LADDER` times.

    The levels are independent (a factorization each): side by side on the free cores, as
    are their fits to the target (:func:`calibrate_detail`). Measured on a quiet 2-core
    machine, ``transfer_detail`` with a given map, the same result to the last bit: FAUST 093
    -> 087 subdivided twice (110k vertices) 57.8 s one after the other, 47.4 s with the levels
    side by side, 41.1 s with their fits too; at 6890 vertices (the target smoothed by Open3D's
    Taubin filter, the true map) 2.5-2.7 s before, 1.9-2.0 s.
    """
    jobs = [functools.partial(_heat_lowpass, eig, c) for c in LADDER]
    n = eig.n_vertices
    # each job: one factorization and an (n, 3) answer, taken as an eigensolve of two pairs
    # (generous: measured at 110k vertices, 25 MB of arrays beside the factor's ~100 MB,
    # against 615 MB estimated)
    levels = run_per_shape(jobs, [n] * len(jobs), [eigenbasis_bytes(n, 2)] * len(jobs),
                           what="detail low-passes")  # fmt: skip
    return [np.asarray(eig.vertices, dtype=np.float64), *levels]


#: Peak bytes per target vertex of one :func:`_level_fit` (:func:`_procrustes`' 17 moment
#: columns, its (n, 3, 3) covariances and rotations, their SVD's copies): measured 75 floats
#: (tracemalloc's peak at 110k vertices).
_FIT_BYTES = 8.0 * 80


def _level_fit(compare: Any, source: np.ndarray, target: np.ndarray) -> np.ndarray:
    """Return the fit of a low-pass level to the target at every target vertex (``_procrustes``)."""
    return _procrustes(compare, source, target)[1]


def _same_spread(eig: EigenBasis, X: np.ndarray, Y: np.ndarray) -> np.ndarray:
    """Y scaled about its centroid to X's mass-weighted RMS distance from its own centroid."""
    w = eig.mass / eig.area
    centre = w @ Y
    return centre + spread_scale(w, X, Y, centre) * (Y - centre)


def _steady_map(eig_1: EigenBasis, compare: Any, p2p_21: np.ndarray) -> np.ndarray:
    """Return the map with its jitter averaged out.

    Each target vertex goes to the source vertex nearest the mean of its neighbourhood's
    images (neighbourhoods of :data:`COMPARE_TIME`). An estimated map sends neighbouring
    vertices a vertex or two apart at random; compared through it, the source's detail looks
    scrambled and its low-passes fit the target better than it whatever the target lacks.
    Measured (``scripts/eval_detail.py``, estimated maps): detail added to barely smoothed
    targets 1.25-1.39x doing nothing with the map as it is, at most 1.07x with it steadied;
    true maps unchanged (0.89x on average, before :data:`CONVERSE`).
    """
    S = np.asarray(eig_1.vertices, dtype=np.float64)
    kept = np.flatnonzero(eig_1.mass > 0)  # vertices left out of the surface are no images
    return kept[nearest_neighbors(S[kept], compare(S[p2p_21]))]


def calibrate_detail(
    eig_1: EigenBasis, eig_2: EigenBasis, p2p_21: np.ndarray
) -> tuple[DetailCalibration, np.ndarray]:
    """Choose the source's low-pass whose detail the target lacks, and where it lacks it.

    The target is compared, through the map (its jitter averaged out first), with the source
    and with each of its heat low-passes (``LADDER``): at every target vertex, the fit of
    the two neighbourhoods up to a rotation (``local_rotations`` on neighbourhoods of
    ``COMPARE_TIME``).
    The low-pass the whole target fits best is the calibrated one: the target was smoothed
    about that much, by whatever tool. When the target smoothed by the same low-pass (its own
    operators) fits the source worse, by at least ``CONVERSE`` of what the source's low-pass
    gains, the target lacks the detail wherever both say so (the source's low-pass fits it
    better, its own fits the source worse). Otherwise the share it lacks is how much of its
    misfit to the source the low-pass removes (see ``LACKING``): nothing where it does not
    fit that low-pass better than the source itself (a region left detailed, a target as
    detailed as the source). In a target found smoothed (the calibrated low-pass is not the
    source itself), a region smoothed more than the whole (a sculpting brush on part of the
    shape) is compared with the longer low-passes too: where the one it fits best removes at
    least ``LACKING`` of the misfit the calibrated low-pass leaves there (fits averaged over
    neighbourhoods of ``GATE_TIME``), the region has that level, blended with its
    neighbours' over the same neighbourhoods, and lacks the detail above it by the
    ``LACKING`` rule (in proportion to the longer levels' share of the blend). The source's
    shape, pose and units need not be the target's: fits compare neighbourhoods up to a
    rotation and a scale.

    Parameters
    ----------
    eig_1, eig_2 : EigenBasis
        Source and target (their operators; no eigenfunction is used).
    p2p_21 : (n2,) ndarray of int
        The source vertex of every target vertex.

    Returns
    -------
    calibration : DetailCalibration
    lowpass : (n1, 3) ndarray
        The source's calibrated low-pass shape (the source itself when ``time`` is 0), in a
        region that lacks more than the whole the longer low-pass (blended across borders).
    """
    check_eigenbasis(eig_1, "eig_1")
    check_eigenbasis(eig_2, "eig_2")
    p2p_21 = check_p2p(p2p_21, eig_2.n_vertices, eig_1.n_vertices)
    levels = _ladder(eig_1)
    compare = _heat_operator(eig_2, COMPARE_TIME * eig_2.area)
    steady = _steady_map(eig_1, compare, p2p_21)
    T = np.asarray(eig_2.vertices, dtype=np.float64)
    # each level's fit to the target: independent, side by side as the levels themselves
    jobs = [functools.partial(_level_fit, compare, X[steady], T) for X in levels]
    n2 = eig_2.n_vertices
    fits = np.array(run_per_shape(jobs, [n2] * len(jobs), [_FIT_BYTES * n2] * len(jobs),
                                  what="detail fits"))  # fmt: skip
    weight = eig_2.mass / eig_2.area
    mean = fits @ weight
    best = int(np.argmax(mean))
    times = np.array((0.0, *LADDER))
    time = float(times[best])
    own = {best: _heat_lowpass(eig_2, time)}  # the target's own low-passes (itself at 0)
    level = np.full(eig_2.n_vertices, best)
    if best == 0:  # as detailed as the source: nothing lacking, no region (below)
        lacking = np.zeros(eig_2.n_vertices)
    else:
        around = _heat_operator(eig_2, GATE_TIME * eig_2.area)
        local = around(fits.T)  # (n2, levels): each level's fit averaged over a region
        misfit = 1.0 - local[:, 0]  # the source itself
        gained = local[:, best] - local[:, 0]
        # the converse: the target smoothed by the same low-pass, compared with the source
        smoother = _procrustes(compare, levels[0][steady], own[best])[1]
        lost = around(smoother - fits[0])
        if float(weight @ lost) <= -CONVERSE * float(weight @ gained):
            lacking = np.clip(around(((lost < 0) & (gained > 0)).astype(np.float64)), 0.0, 1.0)
        else:
            lacking = _lacking(gained, misfit)
        # Regions that lack more than the whole (a brush smoothed them): where a longer
        # low-pass removes at least LACKING of the misfit the calibrated one leaves there,
        # it is theirs. Only in a target found smoothed: a smooth source's bent copy, which
        # fits the source itself best, fits the longest low-passes better in places (their
        # shrinking, not detail).
        top = np.argmax(local, axis=1)
        left = 1.0 - local[:, best]
        won = local[np.arange(eig_2.n_vertices), top] - local[:, best]
        excess = np.divide(won, left, out=np.zeros_like(left), where=left > 0)
        level = np.where((top > best) & (excess >= LACKING), top, best)
    present = [int(i) for i in np.unique(level)]
    if present == [best]:
        lowpass, target_lowpass = levels[best], own[best]
    else:  # regions exist only where best > 0, so around, local and misfit are set
        # each level's share at every vertex, over the regions' neighbourhoods (once on each
        # shape: the target's here, the source's in _on_source)
        marks = (level[:, None] == np.array(present)).astype(np.float64)
        blend = np.clip(around(marks), 0.0, None)
        blend /= np.maximum(blend.sum(axis=1, keepdims=True), np.finfo(float).tiny)
        longer = 1.0 - (blend[:, present.index(best)] if best in present else 0.0)
        # where the blended low-passes remove enough of the misfit, the target lacks their
        # detail (by the LACKING rule), in proportion to the longer levels' share
        blended = _lacking((blend * local[:, present]).sum(axis=1) - local[:, 0], misfit)
        lacking = np.maximum(lacking, longer * blended)
        lowpass = _on_source(eig_1, p2p_21, marks, [levels[i] for i in present])
        own.update({i: _heat_lowpass(eig_2, float(times[i])) for i in present if i not in own})
        target_lowpass = sum(blend[:, [j]] * own[i] for j, i in enumerate(present))
    share = float(eig_2.mass @ lacking) / eig_2.area
    regional = level != best
    logger.info("detail calibration: low-pass at heat time %.3g of the source's area (fit "
                "%.3f, the source itself %.3f); the target lacks %.0f %% of its detail",
                time, float(mean[best]), mean[0], 100.0 * share)  # fmt: skip
    if np.any(regional):
        logger.info(
            "a region of %.2g %% of the target (%s) lacks more: low-passes up to heat time %.3g "
            "there", 100.0 * float(weight @ regional),
            "1 vertex" if (count := int(np.count_nonzero(regional))) == 1 else f"{count} vertices",
            float(times[level].max()),
        )  # fmt: skip
    mean.setflags(write=False)
    lacking.setflags(write=False)
    if target_lowpass is not own.get(0):  # the target's own array is not this function's
        target_lowpass.setflags(write=False)
    level_times = times[level]
    level_times.setflags(write=False)
    calibration = DetailCalibration(
        time=time, fits=mean, lacking=lacking, share=share, target_lowpass=target_lowpass,
        times=level_times,
    )  # fmt: skip
    return calibration, lowpass


def _lacking(gained: np.ndarray, misfit: np.ndarray) -> np.ndarray:
    """Return the :data:`LACKING` rule's share of the detail lacking where a low-pass gained."""
    reduced = np.divide(gained, misfit, out=np.zeros_like(gained), where=misfit > 0)
    return np.clip(reduced / LACKING, 0.0, 1.0)


def _on_source(
    eig_1: EigenBasis, p2p_21: np.ndarray, marks: np.ndarray, levels: list[np.ndarray]
) -> np.ndarray:
    """Return the source's low-pass blended as the target's vertices choose the levels.

    ``marks`` (n2, len(levels)): which level each target vertex has. Each source vertex takes
    the share of each level among the target vertices mapped onto it and onto its
    neighbourhood of :data:`GATE_TIME` (a normalized convolution, one smoothing as the
    target's blend has: source vertices no target vertex maps to take their neighbours'; with
    none near, the level most target vertices have).
    """
    n1 = eig_1.n_vertices
    pulled = np.zeros((n1, marks.shape[1]))
    np.add.at(pulled, p2p_21, marks)
    count = np.bincount(p2p_21, minlength=n1).astype(np.float64)
    spread = _heat_operator(eig_1, GATE_TIME * eig_1.area)
    pulled, count = spread(pulled), spread(count)
    # "none near": less than a millionth of a target vertex's image within reach
    near = count > 1e-6
    weights = np.divide(pulled, count[:, None], out=np.zeros_like(pulled), where=near[:, None])
    weights[~near, int(np.argmax(marks.sum(axis=0)))] = 1.0
    weights = np.clip(weights, 0.0, None)
    weights /= np.maximum(weights.sum(axis=1, keepdims=True), np.finfo(float).tiny)
    return sum(weights[:, [j]] * level for j, level in enumerate(levels))


def _positive(value: Any, name: str) -> float:
    """Return a fraction of the area in (0, 1] (a heat time per area)."""
    x = check_number(value, name, 0.0, 1.0)
    if x == 0.0:
        raise OptionError(name, "must be > 0 (a heat time, as a fraction of the area); got 0")
    return x


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
    if eig.faces is None:
        return None
    # outward (the two meshes may be wound in opposite senses)
    return vertex_normals(surface, eig.faces) * outward_sign(surface, eig.faces)


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


@moved_keywords(rotation_k="rotation_time= (a heat time, as a fraction of the area)")
def transfer_detail_frames(
    eig_1: EigenBasis, eig_2: EigenBasis, *, p2p_21: Any = None,
    correspondence: Correspondence | None = None, mode: str = "add", band: int | None = None,
    amount: float = 1.0, carry: str = "p2p", rotation_time: float | None = None,
    fit_range: tuple[float, float] | None = FIT_RANGE, normals_1: Any = None, normals_2: Any = None,
) -> np.ndarray:  # fmt: skip
    """Give the target the source's geometric detail, in local frames; return new positions.

    Parameters
    ----------
    eig_1, eig_2 : EigenBasis
        Source (with the detail) and target eigenbases. Their ``vertices`` are the two shapes;
        with ``band`` given each needs ``k >= band`` (and the OFP bases' 29 / 39 for
        ``carry="ofp"``).
    p2p_21 : (n2,) array_like of int, optional
        Point map: the source vertex of every target vertex.
    correspondence : Correspondence, optional
        A map from :func:`o3d_ofp.match` (its point map is used). Give exactly one of the two.
    mode : {"add", "replace-detail"}, default "add"
        "add": the target keeps its own detail and gains what it lacks of the source's (with
        ``band`` given: all of the source's detail above ``band``, on top of its own).
        "replace-detail": the target's own detail is removed (the same low-pass) and the
        source's put in its place everywhere (a shape given itself as source then comes back
        unchanged). (Mode "coordinates" moves the target through the OFP bases:
        :func:`o3d_ofp.transfer_detail`.)
    band : int, optional
        None (default): the detail is calibrated on the two shapes (:func:`calibrate_detail`):
        the source's low-pass is the one the target fits best, and the target gains the
        detail above it where it lacks it. An int: the detail is what the coordinates have
        above the first ``band`` eigenfunctions, added everywhere (an expert's override).
        Onto a part (a partial map, or a given or closest-point map whose image covers less
        than :data:`PART_COVERAGE` of the source, onto a target of less than that area), the
        target's band is its eigenfunctions up to the source's ``band``-th eigenvalue, and the
        detail's size is compared with the region the part covers.
    amount : float, default 1.0
        Multiplies the transferred detail, in [0, 10] (0 returns the base surface).
    carry : {"p2p", "ofp"}, default "p2p"
        How the detail reaches the target: pulled back through the point map, or transferred
        with the OFP bases (order 2 on 29 / 39 eigenfunctions, "ours*"; measured: see the
        module notes).
    rotation_time : float, optional
        Neighbourhoods of the local rotations (heat time / area, see :func:`local_rotations`);
        default :data:`ROTATION_TIME`, or :data:`ROTATION_WIDER` times the low-pass's own time
        when that is longer.
    fit_range : (float, float) or None, default (0.7, 0.9)
        Fits (see :func:`local_rotations`) between which the trust in the map goes from none
        to full, ``0 <= lo < hi <= 1``; ``None`` trusts the map everywhere.
    normals_1, normals_2 : (n, 3) array_like, optional
        Normals of the source's low-pass shape and of the surface the detail is added to
        (default: their outward vertex normals). Between two meshes they keep the local
        rotations from turning the detail over (:data:`NORMAL_WEIGHT`); they carry the mean
        detail height used where the map is not trusted. Needed for point clouds; without
        them a cloud gets nothing where the map is not trusted.

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
    if options.band is not None:
        _check_band(options.band, eig_1, "eig_1")
        _check_band(options.band, eig_2, "eig_2")
    if rotation_time is not None:
        rotation_time = _positive(rotation_time, "rotation_time")
    if fit_range is not None:
        lo, hi = (float(v) for v in fit_range)
        if not 0.0 <= lo < hi <= 1.0:
            raise ValueError(f"fit_range must be (lo, hi) with 0 <= lo < hi <= 1; got {fit_range}")
    region = _part_region(eig_1, eig_2, correspondence)
    T = np.asarray(eig_2.vertices, dtype=np.float64)
    estimated = correspondence.method in ("estimate", "partial")  # made here, not given
    detailed = None  # (band given, mode "add") the target's own detail, said with the result
    if options.band is None:
        calibration, low_1 = calibrate_detail(eig_1, eig_2, p2p)
        lacking = calibration.lacking if mode == "add" else np.ones(eig_2.n_vertices)
        # replace-detail: the target's own detail goes by the same low-pass, on its own shape
        base = T if mode == "add" else calibration.target_lowpass
        share = calibration.share if mode == "add" else float(calibration.time > 0)
        if amount > 0 and mode == "add" and estimated and share < ESTIMATED_SEEN:
            _warn_unseen(calibration, eig_1.n_vertices == eig_2.n_vertices)
        elif amount > 0 and share < NOTHING_ADDED:
            _warn_nothing_added(calibration)
        # the rotations' neighbourhoods follow the low-passes where the detail is added
        added = eig_2.mass * lacking
        total = float(added.sum())
        blurred = float(added @ calibration.times) / total if total > 0 else calibration.time
    else:
        low_1 = lowpass_coordinates(eig_1, options.band)
        band_2 = options.band if region is None else _part_band(
            eig_1, eig_2, options.band, float(eig_1.mass[region].sum()) / eig_2.area
        )  # fmt: skip
        base = T if mode == "add" else lowpass_coordinates(eig_2, band_2)
        if mode == "add" and amount > 0:
            detailed = _detailed_target(eig_1, eig_2, low_1, region, options.band, band_2)
        lacking = np.ones(eig_2.n_vertices)
        blurred = 1.0 / (float(eig_1.evals[options.band]) * eig_1.area)
    if rotation_time is None:
        rotation_time = min(1.0, max(ROTATION_TIME, ROTATION_WIDER * blurred))
    detail_1 = eig_1.vertices - low_1
    if carry == "p2p":
        low_at_2, detail_at_2 = low_1[p2p], detail_1[p2p]
    else:
        ours = BasisOptions(preset="ours*")
        both = transfer_function(np.hstack([low_1, detail_1]), eig_1, eig_2,
                                 correspondence=correspondence, options=ours)  # fmt: skip
        low_at_2, detail_at_2 = both[:, :3], both[:, 3:]
    n1 = _normals(eig_1, low_1, normals_1, "normals_1")
    n2 = _normals(eig_2, base, normals_2, "normals_2")
    # Meshes' normals steer the rotations; a cloud's fitted normals do not (their signs are
    # wrong at 4-8 % of the points, see core.geometry.point_normals: turned rotations there)
    meshes = eig_1.faces is not None and eig_2.faces is not None
    steer = (n1[p2p], n2) if meshes and n1 is not None and n2 is not None else None
    R, fit = local_rotations(eig_2, low_at_2, base, rotation_time=rotation_time, normals=steer)
    moved = np.einsum("nij,nj->ni", R, detail_at_2)
    if fit_range is not None:
        w = np.clip((fit - lo) / (hi - lo), 0.0, 1.0)
        moved *= w[:, None]
        if n1 is not None and n2 is not None:
            mean_height = float(eig_1.mass @ np.einsum("ij,ij->i", detail_1, n1)) / eig_1.area
            moved += ((1.0 - w) * mean_height)[:, None] * n2
        logger.debug("map trusted at %.1f %% of the target", 100.0 * float(w.mean()))
    scale = _detail_scale(eig_1, eig_2, base, low_1, region)
    logger.debug("detail transfer: scale %.4g, carry %s", scale, carry)
    added = (amount * scale) * lacking[:, None] * moved
    if meshes and amount > 0:
        added = _unfold(eig_1, eig_2, base, added, p2p, estimated=estimated)
    if detailed is not None:
        grown = ""
        if meshes:
            faces = np.asarray(eig_2.faces)
            ratio = face_areas_normals(base + added, faces)[0].sum() / face_areas_normals(
                base, faces)[0].sum()  # fmt: skip
            grown = f" (here the result's area is {ratio:.2f} times the target's)"
        warn(logger, detailed.replace(grown=grown))
    return base + added


def _near_bends(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(n,) bool: the vertices within :data:`FOLD_RINGS` edges of a bend (:data:`SOURCE_BEND`)."""
    edges, sides = interior_edges(faces)
    near = np.zeros(len(vertices), dtype=bool)
    near[edges[fold_cosines(vertices, faces, sides) < SOURCE_BEND].ravel()] = True
    return _grown((edge_graph(vertices, faces) > 0).astype(np.float64), near, FOLD_RINGS)


def _grown(adjacency: sp.csr_matrix, mask: np.ndarray, rings: int) -> np.ndarray:
    """``mask`` and the vertices within ``rings`` edges of it (``adjacency``: the edges)."""
    grown = mask.astype(np.float64)
    for _ in range(rings):
        grown += adjacency @ grown
    return grown > 0


def _unfold(
    eig_1: EigenBasis, eig_2: EigenBasis, base: np.ndarray, added: np.ndarray, p2p: np.ndarray,
    *, estimated: bool,
) -> np.ndarray:  # fmt: skip
    """Average, then lower, the detail where it folds the result and neither shape folds.

    See :data:`FOLD_COSINE`. Returns the detail to add, ``added`` where nothing folds.
    ``estimated``: the map was estimated here (its cause and fix are said so).
    """
    faces = np.asarray(eig_2.faces)
    edges, sides = interior_edges(faces)
    free = fold_cosines(base, faces, sides) >= FOLD_COSINE  # (the target's own folds stay)
    folded = fold_cosines(base + added, faces, sides) < FOLD_COSINE
    if not (free & folded).any():
        return added
    bends = _near_bends(np.asarray(eig_1.vertices), np.asarray(eig_1.faces))
    free &= ~(bends[p2p[edges[:, 0]]] | bends[p2p[edges[:, 1]]])
    n = len(base)
    adjacency = (edge_graph(base, faces) > 0).astype(np.float64)
    degree = np.asarray(adjacency.sum(axis=1)).ravel() + 1.0
    added = added.copy()
    averaged, lowered = np.zeros(n, dtype=bool), np.zeros(n, dtype=bool)
    first = left = where = 0
    for step in range(FOLD_AVERAGINGS + FOLD_HALVINGS + 1):
        new = free & folded
        if not new.any():
            break
        first = first or int(new.sum())
        at = np.zeros(n, dtype=bool)
        at[edges[new].ravel()] = True
        at = _grown(adjacency, at, 1)
        if step < FOLD_AVERAGINGS:  # the mean over the vertex and its neighbours
            added[at] = ((adjacency @ added + added) / degree[:, None])[at]
            averaged |= at
        else:
            if not left:
                left, where = int(new.sum()), int(edges[new][0, 0])
            added[at] *= 0.5 if step < FOLD_AVERAGINGS + FOLD_HALVINGS else 0.0
            lowered |= at
        folded = fold_cosines(base + added, faces, sides) < FOLD_COSINE
    if not first:  # the folds are the source's or the target's own
        return added
    share = float(lowered.mean())
    logger.info(
        "detail folded the surface at %d edges: averaged at %d vertices, lowered at %d",
        first, int(averaged.sum()), int(lowered.sum()),
    )  # fmt: skip
    if share >= FOLDS_TOLD:
        if estimated:
            cause = Said(
                "most often the estimated map crowds the target onto a few source points there, "
                "wrong at the detail's scale; landmark pairs near that vertex make it closer: "
                "{landmarks}"
            )  # fmt: skip
        else:
            cause = Said(
                "with a map given, most often the target's smoothing collapsed a part there "
                "that the detail cannot fit (a hand into a spike), or the map crowds the target "
                "onto a few source points"
            )  # fmt: skip
        warn(logger, Said(
            "the detail folded the surface at {folds} edges where neither shape folds; where "
            "averaging it over neighbouring vertices did not undo a fold ({left} edges, the "
            "first at target vertex {vertex}) it was lowered, at {count} vertices ({share:.1%} "
            "of the target): {cause}",
            {"folds": first, "left": left, "vertex": where, "count": int(lowered.sum()),
             "share": share, "cause": cause},
            "detail_folds",
        ))  # fmt: skip
    return added


def _warn_nothing_added(calibration: DetailCalibration) -> None:
    warn(logger, Said(
        "no detail the target lacks was found (it fits the source's low-passes no better than "
        "the source itself; {share:.1%} of it lacking, below {bound:.0%}): little was "
        "changed. To put the source's detail in place of the target's own anyway: "
        "{replace_detail}; aligned copies take the source's surface with "
        "{coordinates_closest}",
        {"share": calibration.share, "bound": NOTHING_ADDED}, "nothing_added",
    ))  # fmt: skip


def _warn_unseen(calibration: DetailCalibration, same_count: bool) -> None:
    """Say that an estimated map hid what the target lacks; ``same_count``: as many vertices.

    Shapes with as many vertices may share their vertex order (registrations of one template,
    as FAUST's): the identity is then the true map, which is advised first.
    """
    shared = ("shapes that share their vertex order (registrations of one template) take the "
              "identity, {same_vertices}; otherwise ") if same_count else ""  # fmt: skip
    warn(logger, Said(
        "through the estimated map only {share:.1%} of the target was found lacking the "
        "source's detail, so little was added: an estimated map, an edge or two off, hides "
        "what a smoothed target lacks (measured on bodies smoothed by seven smoothers: 0-17 % "
        "found through estimated maps, 39-94 % through the true maps). Detail needs a map "
        "you trust, a source vertex for every target vertex: " + shared + "{give_map}; "
        "aligned copies take the source's surface with {coordinates_closest}",
        {"share": calibration.share, "n": calibration.lacking.size}, "detail_unseen",
    ))  # fmt: skip


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


def _part_region(
    eig_1: EigenBasis, eig_2: EigenBasis, correspondence: Correspondence
) -> np.ndarray | None:
    """Return the source region a part covers (None: the target is no part of the source).

    Onto a part of the source (a partial map), the source's detail and low-pass area are
    those of the region the part covers; with a band, the part's eigenfunctions have higher
    frequencies than the whole's at the same count, so its low band is the one below the
    source's band-th eigenvalue (:func:`_part_band`).
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
        return None
    # (not the map report's "overlap": that one is the functional map's estimate)
    logger.info("detail transfer onto a part: the map's images lie on %.2f of the source's area "
                "(within two edges)", covered / eig_1.area)  # fmt: skip
    return region


def _detailed_target(
    eig_1: EigenBasis, eig_2: EigenBasis, low_1: np.ndarray, region: np.ndarray | None,
    band_1: int, band_2: int,
) -> Said | None:  # fmt: skip
    """Return the warning (mode "add") that the target already has detail, or None.

    The source's would go on top; the warning is said once the result exists, its
    ``{grown}`` filled with the area the result gained. Measured (``band=30`` and 20, the true
    maps, onto FAUST 087, TOSCA centaur4 and horse6 smoothed by the six tools of
    ``scripts/eval_detail.py`` but the 30-eigenfunction projection): 1.59-2.12 times the
    target's area, where the truth has 0.98-1.36 times it and the calibrated default 1.00-1.35.
    """
    own = _detail_rms(eig_2, lowpass_coordinates(eig_2, band_2))
    theirs = _detail_rms(eig_1, low_1, region=region)
    on_part = "" if region is None else f" (on this part: above its first {band_2} eigenfunctions)"
    if theirs > 0 and own > DETAILED_TARGET * theirs:
        return Said(
            "the target already has detail above band {band}{on_part} ({share:.3g} of the "
            "source's, above {bound:g}): mode 'add' keeps it and adds the source's on top, which "
            "exaggerates it{grown}; {replace_detail} replaces it instead",
            {"band": band_1, "on_part": on_part, "share": own / theirs, "bound": DETAILED_TARGET,
             "grown": ""},
            "detailed_target",
        )  # fmt: skip
    return None
