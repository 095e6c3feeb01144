"""The full-shape match: descriptor fits, ZoomOut, the choice among the starts, a geodesic check.

:class:`FullMatch` is the strategy :func:`o3d_ofp.workflows.estimate.estimate` runs for two
whole shapes: four starts (two fit sizes, each with and without the descriptor-commutativity
term: each helps on some pairs and hurts on others) refined by ZoomOut to :data:`SELECT_K`, the
one whose spectral embeddings align best refined to ``zoomout_to`` (the next one when its map
is a mirror image), its point map at full resolution, its quality report, and a geodesic check
that re-estimates a map wrong on a region. Everything runs on unit-area copies of the
eigenbases, so the result does not depend on the units, position or orientation of either
shape.
"""

from __future__ import annotations

import dataclasses
import logging
import math
from concurrent.futures import ThreadPoolExecutor
from typing import Any

import numpy as np

from ..core.correspondence import fmap_from_p2p, nearest_neighbors
from ..core.fmap import (
    Anchors,
    estimate_fmaps,
    farthest_points,
    landmark_anchors,
    unit_area,
    zoomout_refine,
)
from ..core.multiscale import anchored_p2p_from_fmap, dirichlet_p2p, extend_p2p
from ..core.partial import geodesic_distortion, geodesic_refine
from ..core.shells import COARSE_SHELLS, Registration, shell_match
from ..core.spectrum import EigenBasis
from ..core.wording import Said
from .dense import EXTENSION_K
from .maps import Correspondence, MapQuality
from .quality import (
    MAX_JUMP,
    MAX_REVERSED,
    flipped_what,
    landmark_offsets,
    landmarks_advice,
    landmarks_apart,
    landmarks_mirrored,
    map_quality,
    reversed_fraction,
)
from .strategy import Run, Settled, Strategy

__all__ = [
    "DCOMM_WEIGHTS",
    "LANDMARK_SHELLS_GAIN",
    "MIRROR_RESIDUAL",
    "REPAIR_FIT_K",
    "REPAIR_GAIN",
    "REPAIR_MAX_SHARE",
    "REPAIR_SHARE",
    "SELECT_K",
    "SHELLS_JUMP",
    "WIDE_FIT_K",
    "ZOOMOUT_STEP",
    "FullMatch",
    "alignment_residual",
    "geodesic_repair",
    "mend_jumps",
    "repair_doubt",
]

logger = logging.getLogger(__name__)

#: Above this many (source x target) vertex pairs the final point map is found by the
#: cell-pruned exact search of :func:`o3d_ofp.core.multiscale.local_p2p_from_fmap` (measured,
#: FAUST subdivided: 110k x 110k in 2.7 s instead of 98 s, the same map) rather than a scan.
DENSE_PAIRS = 2e8

#: Weights of the descriptor-commutativity term of the starts.
DCOMM_WEIGHTS = (0.1, 0.0)
#: Size of the second descriptor fit (beside ``k_fit``, the
#: paper's 29). Measured on the 6 ground-truth pairs of ../shared/data (eigenbases of 99
#: functions, fits of 20, 29, 39 and 49, each weight, ZoomOut to 99): the fit of 39 gives the
#: better map on FAUST 093 -> 087 (0.0143 against 0.0253 from the fits of 29 alone, operators
#: of 20 descriptors) and FAUST remeshed 002 -> 007 (0.0212 against 0.0317; pyFM 0.0229), 29
#: on the centaurs (0.0149 against 0.088) and no size is best everywhere, so both are starts.
#: A third fit of 49, compared at 99, was kept only on 093 -> 087 (by 0.0003).
WIDE_FIT_K = 39
#: The starts (each fit size with each weight) are compared by :func:`alignment_residual`
#: after ZoomOut to this size, and only the best one is refined further. Measured on the 6
#: pairs above, comparing after ZoomOut to 39 (where the fit of 39 is not refined yet) keeps
#: the fit of 29 on every pair (093 -> 087 0.0253, 002 -> 007 0.0317); after ZoomOut to 49
#: and to 99 the same starts win except on the SHREC'19 pair (0.324 at 49, 0.524 at 99 with
#: operators of 100 descriptors: both wrong maps), and comparing at 49 took 2.0-3.1 s per
#: 5-10k pair against 4.3-5.5 s at 99.
SELECT_K = 49
#: Eigenfunctions the best start's ZoomOut adds per iteration from :data:`SELECT_K` to
#: ``zoomout_to`` (pyFM's usual setting). The starts' ZoomOut to SELECT_K and a geodesic
#: re-estimate's ZoomOut (:func:`geodesic_repair`) add one at a time. Measured against one at a
#: time, each map against its dataset's truth: the 32 FAUST and remeshed-FAUST pairs
#: (``scripts/eval_matching.py --all-pairs``) mean 0.0171 against 0.0175 sqrt(area), worst
#: 0.0267 against 0.0275; FAUST 093 -> 087 (``scripts/bench_match.py``) 0.0131 against 0.0143
#: at 6.9k vertices (the match 2.2 s against 2.5 s), on the dense path 0.0155 against 0.0174 at
#: 110k and 0.0214 against 0.0210 at 440k; TOSCA people onto one another
#: (``scripts/eval_nonisometric.py --datasets humans``, mean geodesic error x100) 1.8 against
#: 1.9, worst 3.9 against 7.5; TOSCA animals 3.0 against 2.9, worst 7.6 against 7.3; gorilla
#: -> human with 6 landmarks 8.4 against 8.7, worst 11.8 against 10.1 (before the landmarks'
#: distances became the fits' descriptors, ``core.fmap.LANDMARK_SCALES``); the failed SHREC'19
#: pair 0.329 against 0.302. The starts' ZoomOut in steps of five too was tried: FAUST 0.0168,
#: but TOSCA cat1 -> cat7 18.5 and horse14 -> horse15 23.0 (against 7.6 and 3.2). The numbers
#: quoted by the other constants of this module were measured with one at a time.
ZOOMOUT_STEP = 5
#: When the best aligned start's map is a mirror image, the starts whose alignment residual is
#: within this factor of the best are tried in turn (a mirror image aligns about as well as
#: the right map). Measured: FAUST 093 -> 087 onto a target barely smoothed by Open3D's Taubin
#: filter, the mirror image 2.555 and the right start 2.568 (1.005x; 0.054 -> 0.0186); FAUST
#: 019 -> 094 onto a brush-smoothed target, every start wrong, the two turned ones within
#: 1.003x and the two others 1.19x and 1.24x (a map of 0.53 sqrt(area) instead of 0.33).
MIRROR_RESIDUAL = 1.1


def _fit_sizes(run: Run) -> list[int]:
    """Return the descriptor fits' sizes: ``k_fit`` and :data:`WIDE_FIT_K` (within the bases)."""
    o, u1, u2 = run.options, run.u1, run.u2
    k_fit = min(o.k_fit, u1.k, u2.k)
    wide = min(WIDE_FIT_K, o.zoomout_to, u1.k, u2.k)
    return [k_fit, wide] if wide > k_fit else [k_fit]


def _local_search(run: Run) -> bool:
    """Return whether point maps take the exact cell-pruned search (above :data:`DENSE_PAIRS`)."""
    return run.eig_1.n_vertices * run.eig_2.n_vertices > DENSE_PAIRS


def alignment_residual(
    fmap_12: np.ndarray, eig_1: EigenBasis, eig_2: EigenBasis, *, samples: int = 2000,
    sample_indices: tuple[np.ndarray, np.ndarray] | None = None,
) -> float:  # fmt: skip
    """Mean distance between the target's spectral embedding and its nearest mapped source row.

    ``mean_i min_j ‖Ψ_i − (Φ Cᵀ)_j‖`` over farthest-point samples of both shapes, for unit-area
    bases: small when the map aligns the two spectral embeddings (ZoomOut's own energy).

    Parameters
    ----------
    fmap_12 : (K+1, K+1) ndarray
        Map between the unit-area eigenbases.
    eig_1, eig_2 : EigenBasis
        Unit-area source and target eigenbases.
    samples : int, default 2000
        Farthest-point samples per shape.
    sample_indices : tuple of two int arrays, optional
        Those samples, when the caller has them already.

    Returns
    -------
    float
    """
    k = min(fmap_12.shape) - 1
    s1, s2 = sample_indices or tuple(farthest_points(e.vertices, samples) for e in (eig_1, eig_2))
    mapped = eig_1.evecs[s1, : k + 1] @ fmap_12[: k + 1, : k + 1].T
    psi = eig_2.evecs[s2, : k + 1]
    nn = nearest_neighbors(mapped, psi)
    return float(np.linalg.norm(psi - mapped[nn], axis=1).mean())


#: Geodesic repair of an estimated map: where the map and its geodesic refinement
#: (:func:`~o3d_ofp.core.partial.geodesic_refine`) send a target vertex more than this far apart
#: (unit-area shapes), the two disagree there.
REPAIR_JUMP = 0.15
#: When they disagree on more than this share of the target's area, the map is replaced by the
#: ZoomOut of the geodesic one (see :func:`geodesic_repair`). Measured on the 32 ordered FAUST
#: and remeshed-FAUST pairs (``python scripts/eval_matching.py --all-pairs --repair``): the 25
#: right maps (errors up to 0.028) disagree on at most 0.017, and re-estimating them would
#: change their errors by -0.009 to +0.012; the 7 maps wrong on a region (errors 0.039-0.187,
#: all passed as ok) disagree on 0.048-0.184, and their re-estimates have errors 0.014-0.025.
#: Low in the gap: a needless re-estimate costs little, a missed one leaves a wrong map.
REPAIR_SHARE = 0.03
#: Above this disagreement the map is wrong on most of the target, or the shapes are of other
#: kinds: it is flagged, not re-estimated (the anchors it maps right are too few to trust the
#: geodesic map). Measured: maps wrong on a region 0.048-0.184 (above); maps between shapes of
#: other kinds (``python scripts/eval_matching.py --repair --unrelated``) 0.49-0.83,
#: among them a dog onto a centaur (0.545) that passed every other check.
REPAIR_MAX_SHARE = 0.35
#: Target samples (farthest points) the disagreement is measured on.
REPAIR_SAMPLES = 2000
#: Anchors and iterations of the check's geodesic refinement (fewer than the partial match's
#: 100 and 3: the check needs where the map jumps, not the refinement's last precision, and its
#: Dijkstra runs are its cost; the same 32 pairs fall on the same sides). A re-estimate starts
#: from the full refinement (with these, remeshed 007 -> 000 came out 0.042 instead of 0.025).
REPAIR_ANCHORS = 50
REPAIR_ITERATIONS = 2
#: Non-constant eigenfunctions a re-estimate fits to the geodesic map before its ZoomOut (at
#: most the ZoomOut's final size). Fewer than the descriptor fits' 29 or 39: the geodesic map
#: is precise to the edges only, and from the smoother fit ZoomOut finds a better map.
#: Measured on the 13 maps re-estimated among the 32 FAUST and remeshed-FAUST pairs
#: (``scripts/eval_matching.py --all-pairs``, map error x100 / sqrt(area)), the 30 TOSCA people
#: and the 10 TOSCA animal pairs (``scripts/eval_nonisometric.py``'s geodesic error x100, on
#: 300 points; one scratch run each), against the chosen start's fit size (29 or 39): mean
#: 2.63 against 2.90; 10 better (remeshed 001 -> 007 2.72 -> 2.17, cat1 -> cat7 6.54 -> 4.74,
#: woman_03 -> man_05 3.76, flagged, -> 3.14, not flagged), one the same, two worse (remeshed
#: 007 -> 000 2.41 -> 2.43, cat2 -> cat3 6.02 -> 6.16, flagged either way); 20 eigenfunctions
#: gave 6.30 on cat1 -> cat7 and 10 gave 8.90 on woman_03 -> man_05. The other maps are not
#: re-estimated: the same.
REPAIR_FIT_K = 15
#: A re-estimate must earn its place: when it changes the map (on more than
#: :data:`REPAIR_SHARE` of the target) but its geodesic distortion
#: (:func:`~o3d_ofp.core.partial.geodesic_distortion`, :data:`REPAIR_DISTORTION_SAMPLES` target
#: samples) is not below this fraction of the spectral map's, nothing says which of the two is
#: right, and the map is flagged. Measured (``scripts/eval_matching.py --all-pairs``,
#: ``scripts/eval_nonisometric.py --datasets TOSCA_Isometric humans``): the 10 re-estimates
#: that lowered the error (9 from 0.039-0.187 to 0.014-0.029 / sqrt(area), TOSCA cat1 -> cat7
#: 0.081 to 0.078) lowered the distortion to 0.58-0.84 of the spectral map's; the two that
#: left a wrong map, one of them worse than the spectral map (TOSCA cat2 -> cat3, 0.032 to
#: 0.064; woman_03 -> man_05, 0.185 to 0.071), to 0.94 and 1.00 (re-estimates then fitted on
#: the chosen start's 29 or 39 eigenfunctions; see :data:`REPAIR_FIT_K`).
REPAIR_GAIN = 0.9
REPAIR_DISTORTION_SAMPLES = 100
#: The check runs when n1 · n2 is at most this: the dense path's coarse copies (20 000
#: vertices) are under it. Its cost is mostly its Dijkstra runs (100 on the target, 100-300 on
#: the source): measured 0.3 s at 6.9k vertices and 1.8 s at 27.5k (FAUST 093, subdivided once;
#: scipy's Dijkstra holds the GIL, so they run one after the other); a re-estimate adds a
#: nearest-neighbour search over every target vertex, quadratic in the sizes.
REPAIR_MAX_PAIRS = 1e9
#: With landmarks, the shells' registration (the one the landmarks choose) replaces the
#: landmark-driven map only when its geodesic distortion is below this fraction of the map's:
#: a map the pairs drive keeps them exactly, the registration only near them. Measured
#: (2026-12-03, the 12 gorilla -> human pairs of ``scripts/eval_nonisometric.py`` both ways,
#: human onto gorilla as the script and gorilla onto human, with 2, 3 and 6 farthest-point
#: landmarks, mean geodesic error x100 / sqrt(area) on 1000 points): every registration
#: distorting less than 0.80 times as much lowered the error or left it (e.g. 38.8 -> 10.3,
#: 29.1 -> 6.3, 24.1 -> 10.2 at 0.79); from 0.80 to 0.93 half of them raised it (at 0.815,
#: 6 landmarks, 5.6 -> 9.7; 6.8 -> 11.0, 17.0 -> 24.9, 20.2 -> 25.5) and half lowered it (at
#: 0.800, 27.0 -> 10.9; 29.4 -> 10.5 at 0.813). At 0.8 gorilla onto human with 2 landmarks
#: 20.9 -> 11.3 against 0.7, the bound before (measured on the script's way only), and with 3
#: 14.2 -> 11.7; human onto gorilla unchanged (12.5, 7.9; 6 landmarks 5.9 and 6.0 both
#: ways). One registration with 2 landmarks on the plane of symmetry distorted 0.49 times as
#: much and raised the error (19.4 -> 49.4, left and right swapped: two pairs there cannot
#: tell them).
LANDMARK_SHELLS_GAIN = 0.8
#: From this many landmark pairs a doubtful landmark map is not estimated again without them
#: (:meth:`FullMatch.rival_without_landmarks`). Measured (2026-12-03, the 12 gorilla -> human
#: pairs both ways, farthest-point landmarks): with 6 pairs no map estimated without them was
#: kept (24 maps: each moved some pair 0.11-0.34 of sqrt(source area) away, or distorted more),
#: with 2 and 3 pairs 2 of 48 were, while the second estimation made a match about 2.3 times as
#: long (6.8 -> 15.7 s a pair of 5k vertices).
LANDMARKS_ENOUGH = 6
#: Reasons of a doubtful spectral map that speak of the shapes rather than of the map: kept
#: in the report of a map re-estimated by the shells' registration.
_SHAPE_CODES = frozenset({"not_isometric", "geodesic_disagrees"})
#: Reasons that point at a part of the other shape: the partial match is the fix there, not
#: the registration of two whole shapes.
_PART_CODES = frozenset({"looks_partial", "part_larger"})
#: The shells' registered map is mended (:func:`mend_jumps`) where its geodesic refinement
#: sends a target vertex more than this far (unit-area shapes; a region sent onto another limb
#: is 0.3-1 away), then smoothed by a Dirichlet step. Measured (2026-12-02, the 12 gorilla ->
#: human pairs of ``scripts/eval_nonisometric.py``, mean geodesic error x100 / sqrt(area) on
#: 300 ground-truth points, the registered map 14.9): 0.15 13.1, 0.2 12.9, 0.25 12.5, 0.3
#: 12.6, 0.35 13.0; at 0.3 the four pairs with a region sent astray 16.2 -> 8.8, 19.6 ->
#: 12.3, 15.1 -> 10.3, 18.4 -> 12.1, and the right maps no worse (within +0.1 of 5.7-7.7;
#: at 0.25 up to 2.2 worse). The geodesic map alone 14.1, the Dirichlet step alone 14.6.
SHELLS_JUMP = 0.3


def _moved(eig_1: EigenBasis, images_a: np.ndarray, images_b: np.ndarray) -> np.ndarray:
    """Distance between two source images of each target vertex (the source's units)."""
    return np.linalg.norm(eig_1.vertices[images_a] - eig_1.vertices[images_b], axis=1)


def _apart(eig_1: EigenBasis, images_a: np.ndarray, images_b: np.ndarray) -> float:
    """Share of target samples whose two source images lie over :data:`REPAIR_JUMP` apart."""
    return float(np.mean(_moved(eig_1, images_a, images_b) > REPAIR_JUMP))


def geodesic_repair(
    p2p_21: np.ndarray, eig_1: EigenBasis, eig_2: EigenBasis, *, k_final: int,
    k_fit: int = REPAIR_FIT_K, subsample: int | None = None,
    samples: tuple[np.ndarray, np.ndarray] | None = None, share: float = REPAIR_SHARE,
    checked: np.ndarray | None = None, anchors: Anchors | None = None,
) -> tuple[np.ndarray | None, float]:  # fmt: skip
    """Re-estimate a map that is wrong on a region from its geodesic refinement.

    The geodesic refinement re-maps every target vertex by its distances to the anchors the
    map keeps best: a region sent to the wrong place (a limb onto the other, a piece turned
    over) is pulled back by the anchors mapped right, at the precision of the distances along
    the edges (0.02-0.05 of sqrt(area)). Where the map is right everywhere the two agree (the
    check: :data:`REPAIR_ANCHORS` anchors, :data:`REPAIR_ITERATIONS` iterations); where they
    disagree on more than ``share`` of the target's area (over :data:`REPAIR_JUMP` apart), a
    functional map is fitted to the full geodesic refinement (:func:`geodesic_refine`'s
    defaults) on ``k_fit`` eigenfunctions and refined by ZoomOut to ``k_final``, which restores
    the spectral precision.

    Parameters
    ----------
    p2p_21 : (n2,) ndarray of int
        The estimated map: source vertex of every target vertex.
    eig_1, eig_2 : EigenBasis
        Unit-area source and target eigenbases of triangle meshes (``faces`` set).
    k_final : int
        Size of the ZoomOut that ends a re-estimate.
    k_fit : int, default REPAIR_FIT_K
        Size of the fit to the geodesic map that the ZoomOut starts from (at most
        ``k_final``).
    subsample, samples
        ZoomOut's farthest-point samples (as in :func:`~o3d_ofp.core.fmap.zoomout_refine`).
    share : float, default REPAIR_SHARE
        Disagreement (fraction of the target's area) above which the map is re-estimated.
    checked : (s,) ndarray of int, optional
        The target vertices the disagreement is measured on: farthest-point samples (default:
        :data:`REPAIR_SAMPLES` of them).
    anchors : Anchors, optional
        Known pairs, kept by the ZoomOut of a re-estimated map (see
        :func:`~o3d_ofp.core.fmap.zoomout_refine`).

    Returns
    -------
    fmap_12 : (k_final+1, k_final+1) ndarray or None
        The re-estimated map between the unit-area bases, None when the map is kept.
    disagreement : float
        The share of the target's area where the map and its geodesic refinement disagree
        (the share of the samples ``checked``).
    """
    surfaces = eig_1.vertices, eig_1.faces, eig_2.vertices, eig_2.faces
    # The disagreement is measured on farthest-point samples of the target (about uniform in
    # area; 2000 samples: a share of 0.05 within about 0.005), the whole map only re-estimated.
    if checked is None:
        checked = farthest_points(eig_2.vertices, min(REPAIR_SAMPLES, eig_2.n_vertices))
    geodesic = geodesic_refine(p2p_21, *surfaces, anchors=REPAIR_ANCHORS,
                               iterations=REPAIR_ITERATIONS, queries=checked)  # fmt: skip
    disagreement = _apart(eig_1, p2p_21[checked], geodesic)
    if disagreement <= share:
        return None, disagreement
    geodesic = geodesic_refine(p2p_21, *surfaces)
    k_fit = min(k_fit, k_final)
    C = fmap_from_p2p(geodesic, eig_1, eig_2, k1=k_fit, k2=k_fit)
    C = zoomout_refine(
        C, eig_1, eig_2, k_final=k_final, subsample=subsample, samples=samples, anchors=anchors
    )
    return C, disagreement


def mend_jumps(
    p2p_21: np.ndarray, eig_1: EigenBasis, eig_2: EigenBasis, *, k: int, local: bool = False
) -> tuple[np.ndarray, float]:  # fmt: skip
    """Mend a map between shapes of other kinds where whole regions jump, then smooth it.

    A registration between shapes of other kinds can send a region onto another limb (a
    gorilla's hand onto a person's foot) while the rest is right. The geodesic refinement
    (:func:`~o3d_ofp.core.partial.geodesic_refine`) re-maps every target vertex by its
    distances to the anchors the map keeps best: imprecise between shapes of other kinds (its
    distances differ), but it sends such a region back. Its images replace the map's where the
    two lie over :data:`SHELLS_JUMP` apart; one Dirichlet step
    (:func:`~o3d_ofp.core.multiscale.dirichlet_p2p`) then smooths the seams.

    Parameters
    ----------
    p2p_21 : (n2,) ndarray of int
        The map: source vertex of every target vertex.
    eig_1, eig_2 : EigenBasis
        Unit-area source and target eigenbases of triangle meshes.
    k : int
        Eigenfunctions of the Dirichlet step's functional map.
    local : bool, default False
        The Dirichlet step's search is the cell-pruned exact one (large shapes).

    Returns
    -------
    p2p_21 : (n2,) ndarray of int64
        The mended map.
    share : float
        The share of the target's vertices whose images were replaced.
    """
    geodesic = geodesic_refine(p2p_21, eig_1.vertices, eig_1.faces, eig_2.vertices, eig_2.faces)
    jumped = _moved(eig_1, p2p_21, geodesic) > SHELLS_JUMP
    mended = np.where(jumped, geodesic, p2p_21)
    return dirichlet_p2p(mended, eig_1, eig_2, None, k=k, local=local), float(jumped.mean())


def repair_doubt(
    spectral: np.ndarray, repaired: np.ndarray, eig_1: EigenBasis, eig_2: EigenBasis, *,
    checked: np.ndarray,
) -> dict[str, float] | None:  # fmt: skip
    """Say whether a re-estimated map is not clearly better than the spectral map it replaces.

    Parameters
    ----------
    spectral, repaired : (n2,) ndarray of int
        The two maps (source vertex of every target vertex).
    eig_1, eig_2 : EigenBasis
        Unit-area source and target eigenbases of triangle meshes.
    checked : (s,) ndarray of int
        Target samples on which the two maps are compared.

    Returns
    -------
    dict or None
        None when the re-estimate keeps the map (it moves at most :data:`REPAIR_SHARE` of the
        samples over :data:`REPAIR_JUMP`) or lowers its geodesic distortion below
        :data:`REPAIR_GAIN` of the spectral map's; else ``{"before": ..., "after": ...}``,
        the two distortions.
    """
    if _apart(eig_1, spectral[checked], repaired[checked]) <= REPAIR_SHARE:
        return None
    surfaces = eig_1.vertices, eig_1.faces, eig_2.vertices, eig_2.faces
    before, after = (geodesic_distortion(p2p, *surfaces, samples=REPAIR_DISTORTION_SAMPLES)
                     for p2p in (spectral, repaired))  # fmt: skip
    if after < REPAIR_GAIN * before:
        return None
    return {"before": before, "after": after}


def _frame_notes(registered: Registration, same_frame: bool) -> list[Said]:
    """Return the report's notes on the shapes' given frame (``MatchOptions.same_frame``)."""
    if registered.frame_other is None:
        return []
    if same_frame:
        code, template = "frame_kept", (
            "the shapes given in one frame: the registration that keeps their orientation (the "
            "source turned {turn:.0f}°, score {score:.4f}) was kept over one that fits the shells "
            "better (score {other:.4f}) but turns the source by {other_turn:.0f}° (a front / "
            "back swap)"
        )
    else:
        code, template = "frame_swap", (
            "the registration kept turns the source by {turn:.0f}° (score {score:.4f}); one that "
            "keeps the shapes' given orientation (turned {other_turn:.0f}°) fits nearly as well "
            "(score {other:.4f}): two upright shapes can fit with front and back swapped; if "
            "the shapes are given in one frame, facing the same way, {same_frame} keeps it"
        )
    _, score, turn = registered.frame_other
    values = {"turn": registered.turn, "score": registered.score, "other": score,
              "other_turn": turn}  # fmt: skip
    return [Said(template, values, code)]


class FullMatch(Strategy):
    """The steps of a full-shape match (see the module notes)."""

    def scaled(self, eig_1: EigenBasis, eig_2: EigenBasis) -> tuple[EigenBasis, EigenBasis]:
        """Return unit-area copies: the map does not depend on the units."""
        return unit_area(eig_1), unit_area(eig_2)

    def starts(self, run: Run) -> list[Any]:
        """Fit the starts: each fit size with each weight, as ``(k, w_dcomm, C)``."""
        o, u1, u2 = run.options, run.u1, run.u2
        final = min(o.zoomout_to, u1.k, u2.k)
        sizes = _fit_sizes(run)
        logger.debug("match: descriptor fits (sizes %s, commutativity weights %s)", sizes,
                     DCOMM_WEIGHTS)  # fmt: skip
        run.report("descriptor fit", 0.0)
        # The farthest-point samples of both shapes, drawn once for every ZoomOut and the
        # comparison of the starts, while the fits run (the sampling is mostly Python steps,
        # the fits mostly BLAS).
        n_samples = o.zoomout_subsample or 2000
        # Known pairs drive every ZoomOut, not only the fits' starts (measured: see
        # o3d_ofp.core.fmap.LANDMARK_DISTANCES); their functions are computed once, for both.
        anchors = None if run.landmarks is None else landmark_anchors(u1, u2, run.landmarks)
        with ThreadPoolExecutor(max_workers=1) as sampler:
            sampled = sampler.submit(
                lambda: tuple(farthest_points(u.vertices, n_samples) for u in (u1, u2))
            )
            starts = estimate_fmaps(
                u1, u2, sizes=sizes, w_dcomm=DCOMM_WEIGHTS,
                landmarks=run.landmarks if anchors is None else anchors,
                descriptors=o.descriptors, w_orient=o.w_orient,
            )  # fmt: skip
            samples = sampled.result()
        subsampled = o.zoomout_subsample is not None and o.zoomout_subsample < min(
            u1.n_vertices, u2.n_vertices)  # fmt: skip
        run.state.update(
            samples=samples, zoom=samples if subsampled else None, final=final,
            select=min(final, max(sizes[-1], SELECT_K)), anchors=anchors,
        )  # fmt: skip
        return list(starts)

    def _free_map(self, run: Run) -> np.ndarray:
        """Return the point map the landmarks drive without the orientation term.

        One start (the fit of ``k_fit`` with the first commutativity weight, ``w_orient=0``;
        the match's samples and landmark functions reused), ZoomOut-ed to ``select``, and its
        point map at that size. For :meth:`review`'s
        :func:`~o3d_ofp.workflows.quality.landmarks_mirrored`. Measured (6 TOSCA people
        pairs, landmarks right, mirrored and on the plane of symmetry, another run on the
        second core): the same verdicts as the best aligned of the four starts (turned
        shares within 0.08, gains within 0.01), in 1.0-1.9 s instead of about 3 s a pair of
        5k vertices.
        """
        ((k, _, C),) = estimate_fmaps(
            run.u1, run.u2, sizes=_fit_sizes(run)[:1], w_dcomm=DCOMM_WEIGHTS[:1],
            landmarks=run.state["anchors"], descriptors=run.options.descriptors, w_orient=0.0,
        )  # fmt: skip
        select = run.state["select"]
        if select > k:  # as refine() does, without the alignment residual it would compare
            C = self._zoomout(run, C, select)
        return anchored_p2p_from_fmap(C, run.u1, run.u2, run.state["anchors"],
                                      local=_local_search(run))  # fmt: skip

    def _zoomout(self, run: Run, C: np.ndarray, k: int, step: int = 1) -> np.ndarray:
        return zoomout_refine(
            C, run.u1, run.u2, k_final=k, step=step, subsample=run.options.zoomout_subsample,
            samples=run.state["zoom"], anchors=run.state["anchors"],
        )  # fmt: skip

    def refine(self, run: Run, index: int, start: Any) -> Any:
        """ZoomOut a start to :data:`SELECT_K`; return it and its :func:`alignment_residual`."""
        k, _, C = start
        select = run.state["select"]
        if select > k:
            logger.debug("match: ZoomOut %d -> %d (start %d)", k, select, index + 1)
            C = self._zoomout(run, C, select)
        residual = alignment_residual(C, run.u1, run.u2, sample_indices=run.state["samples"])
        logger.debug("match: start %d alignment residual %.4g", index + 1, residual)
        return C, residual

    def settle(self, run: Run, starts: list[Any], refined: list[Any]) -> Settled:
        """Keep the start that aligns best, ZoomOut it to ``zoomout_to``, read its point map.

        A map that turns more than :data:`~o3d_ofp.workflows.quality.MAX_REVERSED` of the
        triangles over is a mirror image, which aligns the spectral embeddings about as well
        as the right map: the next start by alignment is taken instead, and so on among the
        starts that align within :data:`MIRROR_RESIDUAL` of the best; when every one of their
        maps is turned over, the best aligned one is kept (and flagged by the quality report).
        """
        order = sorted(range(len(starts)), key=lambda i: refined[i][1])
        best = refined[order[0]][1]
        order = [i for i in order if refined[i][1] <= MIRROR_RESIDUAL * best]
        first = None
        for rank, index in enumerate(order):
            settled = self._final(run, starts, refined, index, report=first is None)
            first = settled if first is None else first
            turned = reversed_fraction(settled.p2p_21, run.eig_1, run.eig_2)
            if not turned > MAX_REVERSED:  # NaN (nothing to tell) keeps the map too
                return settled
            if rank + 1 < len(order):
                then = "trying the next start"
            elif len(order) == 1:
                then = "no other start aligns as well: its map is kept"
            else:
                then = (f"every start that aligns as well turns it over: start {order[0] + 1}'s "
                        "map, the best aligned, is kept")  # fmt: skip
            logger.info("match: start %d's map turns %.2f of the target's %s over (a mirror "
                        "image): %s",
                        index + 1, turned, flipped_what(run.eig_1, run.eig_2), then)  # fmt: skip
        return first

    def _final(
        self, run: Run, starts: list[Any], refined: list[Any], index: int, *, report: bool
    ) -> Settled:
        """ZoomOut start ``index`` to ``zoomout_to`` and read its point map."""
        C = refined[index][0]
        final, select = run.state["final"], run.state["select"]
        if final > select:  # only the chosen start goes on
            logger.debug("match: ZoomOut %d -> %d (start %d)", select, final, index + 1)
            if report:
                run.report("ZoomOut", 0.6)
            C = self._zoomout(run, C, final, ZOOMOUT_STEP)
        logger.debug("match: point map at full resolution (%d target vertices)",
                     run.eig_2.n_vertices)  # fmt: skip
        if report:
            run.report("point map", 0.7)
        info = {"k_fit": starts[index][0], "w_dcomm": starts[index][1]}
        return self._settled(run, C, info)

    def _settled(self, run: Run, C: np.ndarray, info: dict[str, Any]) -> Settled:
        """Return the map ``C`` between the unit-area bases, its point map and its own-units map.

        With landmarks the point map compares their functions too, as each ZoomOut step does
        (:func:`~o3d_ofp.core.multiscale.anchored_p2p_from_fmap`). Measured
        (``scripts/eval_nonisometric.py``-style, 6 well-spread landmarks, 300 points, mean
        geodesic error x100): gorilla -> human 6.15 against 6.36 (4 landmarks 6.22 against
        6.30, 10: 5.81 against 5.99), TOSCA animals 2.16 against 2.32 (worst 4.3 against
        5.3), 10 of the 30 pairs of TOSCA people 1.56 against 1.57.

        That point map then takes one Dirichlet step
        (:func:`~o3d_ofp.core.multiscale.dirichlet_p2p`: its images smoothed on the target,
        then snapped to the source). Measured (``scripts/eval_nonisometric.py --pyfm``, 1000
        points): gorilla -> human with 6 landmarks 5.9 against 6.2, TOSCA animals 2.7 against
        3.0 (worst 6.3 against 7.6), TOSCA people 1.74 against 1.77; FAUST and remeshed FAUST
        (``scripts/eval_matching.py --all-pairs``) the same mean error; with a point cloud
        (``scripts/eval_cloud.py --estimate``) 7 of the 8 maps gain (0.068 -> 0.062 onto FAUST
        087's vertices, 0.145 -> 0.138 from the centaur's), one flagged map loses (onto a cloud
        sampled on FAUST 087, 0.170 -> 0.221).
        """
        local = _local_search(run)
        anchors = run.state["anchors"]
        spectral = anchored_p2p_from_fmap(C, run.u1, run.u2, anchors, local=local)
        p2p = dirichlet_p2p(spectral, run.u1, run.u2, anchors, k=min(C.shape) - 1, local=local)
        if logger.isEnabledFor(logging.DEBUG):
            moved = np.linalg.norm(run.u1.vertices[p2p] - run.u1.vertices[spectral], axis=1)
            logger.debug(
                "match: the Dirichlet step moved %.1f %% of the images, by %.4f sqrt(area) on "
                "average", 100.0 * np.mean(moved > 0), moved.mean(),
            )  # fmt: skip
        fmap_12 = C * math.sqrt(run.eig_2.area / run.eig_1.area)  # the shapes' own areas
        return Settled(fmap_12, p2p, {**info, "C": C})

    def judge(self, run: Run, settled: Settled) -> MapQuality:
        """:func:`~o3d_ofp.workflows.quality.map_quality` of the map."""
        run.report("quality", 0.75)
        return map_quality(
            settled.p2p_21, run.eig_1, run.eig_2, settled.fmap_12,
            landmarks_given=_given(run),
        )  # fmt: skip

    def review(self, run: Run, settled: Settled, quality: MapQuality) -> tuple[Settled, MapQuality]:
        """Run the geodesic check (:meth:`_geodesic_review`), then check the landmarks' pairs.

        Pairs that disagree on how far apart they lie are doubted
        (:func:`~o3d_ofp.workflows.quality.landmarks_apart`): the map follows a wrong pair.
        Between meshes, landmarks whose map estimated without the orientation term
        (:meth:`_free_map`) turns the target over are taken for mirror images of the right
        pairs (:func:`~o3d_ofp.workflows.quality.landmarks_mirrored`), unless the map itself
        already does (``reversed``) or has no orientation term.
        """
        settled, quality = self._geodesic_review(run, settled, quality)
        settled, quality = self._escalate(run, settled, quality)
        anchors = run.state["anchors"]
        quality = landmarks_apart(quality, anchors)
        if (anchors is None or anchors.distances_1 is None or run.options.w_orient == 0.0
                or "reversed" in quality.codes()):  # fmt: skip
            return settled, quality
        run.report("landmarks' orientation", 0.85)
        free = self._free_map(run)
        turned = reversed_fraction(free, run.eig_1, run.eig_2)
        return settled, landmarks_mirrored(quality, anchors, settled.p2p_21, free, turned)

    def _escalate(
        self, run: Run, settled: Settled, quality: MapQuality
    ) -> tuple[Settled, MapQuality]:  # fmt: skip
        """Register the shapes' smooth shells when the spectral map is doubtful.

        A suspect map between two meshes is re-estimated by
        :func:`~o3d_ofp.core.shells.shell_match`, which needs no isometry (with landmarks,
        the registration they choose). The registered map replaces the spectral one when its
        geodesic distortion (:func:`~o3d_ofp.core.partial.geodesic_distortion`,
        :data:`REPAIR_DISTORTION_SAMPLES` target samples) is lower (with landmarks, below
        :data:`LANDMARK_SHELLS_GAIN` of it). Measured (2026-12-01, the 12 gorilla -> human pairs of
        ``scripts/eval_nonisometric.py``): the registered maps 0.16-0.26, the spectral ones
        0.36-0.42; on TOSCA cat2 -> cat3, the one flagged map among the dataset's ten pairs of
        one animal, 0.115 against 0.107 (geodesic errors x100 8.4 and 6.4): the spectral map is
        kept. The registered map stays flagged: between shapes of other kinds it is right on
        most pairs, not on all. ``MatchOptions(shells=False)`` keeps the spectral map.
        """
        u1, u2 = run.u1, run.u2
        if (not run.options.shells or not quality.suspect
                or u1.faces is None or u2.faces is None or min(u1.k, u2.k) < COARSE_SHELLS[-1]
                or quality.codes() & _PART_CODES):  # fmt: skip
            return settled, quality
        run.report("shells registration", 0.8)
        logger.info("match: the map is doubtful: registering the shapes' smooth shells")
        registered = shell_match(
            u1, u2, same_frame=run.options.same_frame, landmarks=run.landmarks,
            report=lambda stage, done: run.report(stage, 0.8 + 0.1 * done),
        )  # fmt: skip
        final = run.state["final"]
        run.report("shells: mending jumps", 0.9)
        p2p, share = mend_jumps(registered.p2p_21, u1, u2, k=final, local=_local_search(run))
        logger.info("match: the registered map mended where it jumped from its geodesic "
                    "refinement (%.1f %% of the target's vertices), then smoothed", 100 * share)
        before, after = _distortion(run, settled), _map_distortion(run, p2p)
        logger.info("match: geodesic distortion %.3f (spectral) and %.3f (shells' registration, "
                    "from %s)", before, after, registered.label)  # fmt: skip
        landmarks = run.landmarks is not None
        gain = LANDMARK_SHELLS_GAIN if landmarks else 1.0
        if not after < gain * before:
            more = ("more" if not landmarks else
                    "not enough less than the map the landmark pairs drive (below {gain:g} "
                    "times its distortion)")  # fmt: skip
            return settled, quality.noted(Said(
                "the shapes' smooth shells were registered too (the map is doubtful), but "
                "their map changes geodesic distances " + more + " ({after:.3f} against "
                "{before:.3f}): the spectral map is kept",
                {"before": before, "after": after, "gain": gain}, "shells_kept",
            ))  # fmt: skip
        C = fmap_from_p2p(p2p, u1, u2, k1=final, k2=final)
        fmap_12 = C * math.sqrt(run.eig_2.area / run.eig_1.area)  # the shapes' own areas
        settled = Settled(fmap_12, p2p, {**settled.info, "C": C, "shells": True,
                                         "geodesic_distortion": (p2p, after)})  # fmt: skip
        chosen = ("" if not landmarks else
                  ", the registration that puts the landmark pairs nearest each other")
        found = Said(
            "the spectral map was doubtful: the map comes from registering the shapes' smooth "
            "shells (an extrinsic alignment that needs no isometry{chosen}; geodesic "
            "distortion {after:.3f} against the spectral map's {before:.3f}); such maps "
            "between shapes of other kinds are right on most pairs, not all: check the result "
            "by eye", {"before": before, "after": after, "chosen": chosen}, "shells",
        )  # fmt: skip
        notes = [found, *_frame_notes(registered, run.options.same_frame)]
        # The registered map is judged as a point map (its functional map is read off it, not
        # what made it); what the spectral map said of the shapes themselves, and its likely
        # causes, still hold.
        judged = map_quality(settled.p2p_21, run.eig_1, run.eig_2, landmarks_given=_given(run))
        kept = [Said("the spectral map's check: {reason}", {"reason": r}, r.code)
                for r in quality.reasons if r.code in _SHAPE_CODES]
        causes = [r for r in judged.reasons if r.code.startswith("causes")] or [
            r for r in quality.reasons if r.code.startswith("causes")]  # fmt: skip
        reasons = [r for r in judged.reasons if not r.code.startswith("causes")]
        return settled, dataclasses.replace(
            judged, suspect=True, reasons=(*notes, *kept, *reasons, *causes)
        )  # fmt: skip

    @staticmethod
    def _advice(run: Run) -> Said:
        """Return the landmarks a doubtful map advises: a few, or more when some were given."""
        return landmarks_advice(_given(run), where="both shapes")

    def rival_without_landmarks(self, run: Run, quality: MapQuality) -> bool:
        """Whether to estimate the map without the landmarks too: theirs is doubtful, on meshes.

        See :meth:`against_free`. A map the landmarks drive and the checks pass is kept as it
        is (no second estimation), as is one of :data:`LANDMARKS_ENOUGH` pairs or more.
        """
        few = run.landmarks is not None and len(run.landmarks) < LANDMARKS_ENOUGH
        return few and quality.suspect and run.u1.faces is not None and run.u2.faces is not None

    def against_free(
        self, run: Run, settled: Settled, quality: MapQuality, free: Settled,
        free_quality: MapQuality,
    ) -> tuple[Settled, MapQuality]:  # fmt: skip
        """Keep the map estimated without the landmarks where it keeps them and distorts less.

        The rule that lets the shells' registration replace a map the landmarks drive
        (:data:`LANDMARK_SHELLS_GAIN`), with the landmarks kept as
        :func:`~o3d_ofp.workflows.quality.landmarks_kept` reads it (every pair within
        :data:`~o3d_ofp.workflows.quality.MAX_JUMP` of sqrt(source area)): a few pairs can
        pull a map between shapes of other kinds away from the one the shapes themselves
        give, which often keeps them as well. Measured (2026-12-03, the 12 gorilla -> human
        pairs of ``scripts/eval_nonisometric.py`` both ways, 2, 3 and 6 farthest-point
        landmarks, mean geodesic error x100 / sqrt(area) on 1000 points): see the CHANGELOG.
        """
        if free_quality.suspect is None:
            return settled, quality
        off = float(landmark_offsets(free.p2p_21, run.landmarks, run.u1.vertices).max())
        before, after = _distortion(run, settled), _distortion(run, free)
        logger.info("match: without the landmarks the map keeps them within %.3f of sqrt(source "
                    "area) and changes geodesic distances by %.3f (the landmarks' map %.3f)",
                    off, after, before)  # fmt: skip
        if off > MAX_JUMP or not after < LANDMARK_SHELLS_GAIN * before:
            return settled, quality
        return free, free_quality.noted(Said(
            "the map estimated without the landmarks is kept: it keeps them (within {off:.3f} "
            "of sqrt(source area)) and changes geodesic distances less ({after:.3f} against "
            "{before:.3f} for the map they drive, below {gain:g} times)",
            {"off": off, "after": after, "before": before, "gain": LANDMARK_SHELLS_GAIN},
            "free_kept",
        ))  # fmt: skip

    def _geodesic_review(
        self, run: Run, settled: Settled, quality: MapQuality
    ) -> tuple[Settled, MapQuality]:  # fmt: skip
        """Check a map that passes against its geodesic refinement (:func:`geodesic_repair`).

        Only a map that passes is checked: a suspect one (shapes of other kinds, a collapse) is
        said as it is, not re-estimated into one that looks right (measured: a blob onto a
        sphere, flagged, came out ok re-estimated).
        """
        eig_1, eig_2 = run.eig_1, run.eig_2
        if quality.suspect or eig_1.faces is None or eig_2.faces is None:
            return settled, quality
        if eig_1.n_vertices * eig_2.n_vertices > REPAIR_MAX_PAIRS:
            logger.info("match: no geodesic check (%d x %d vertices: its search is quadratic)",
                        eig_1.n_vertices, eig_2.n_vertices)  # fmt: skip
            return settled, quality
        run.report("geodesic check", 0.8)
        repaired, disagreement = geodesic_repair(
            settled.p2p_21, run.u1, run.u2, k_final=run.state["final"],
            subsample=run.options.zoomout_subsample, samples=run.state["zoom"], share=REPAIR_SHARE,
            checked=run.state["samples"][1], anchors=run.state["anchors"],
        )  # fmt: skip
        redo = f" (> {REPAIR_SHARE:g}): re-estimated from the geodesic map"
        logger.debug("match: the map and its geodesic refinement disagree on %.3f of the target's "
                     "area%s", disagreement,
                     redo if REPAIR_SHARE < disagreement <= REPAIR_MAX_SHARE else "")  # fmt: skip
        if disagreement > REPAIR_MAX_SHARE:
            found = Said(
                "the map and its geodesic refinement disagree on {share:.2f} of the target's "
                "area (> {bound:g}): the map is wrong on most of it, or the shapes are not "
                "near-isometric", {"share": disagreement, "bound": REPAIR_MAX_SHARE},
                "geodesic_disagrees",
            )  # fmt: skip
            causes = Said(
                "likely causes: shapes of other kinds (a spectral map needs near-isometric "
                "shapes: check the result by eye), or descriptors that cannot tell the parts "
                "apart; fix: {advice}", {"advice": self._advice(run)}, "causes",
            )  # fmt: skip
            return settled, quality.flagged(found).flagged(causes, first=False)
        if repaired is None:
            return settled, quality
        spectral = settled
        settled = self._settled(run, repaired, settled.info)
        quality = self.judge(run, settled).noted(Said(
            "the spectral map disagreed with its geodesic refinement on {share:.3f} of the "
            "target's area (a region sent to the wrong place): re-estimated from the geodesic "
            "map", {"share": disagreement}, "repaired",
        ))  # fmt: skip
        doubt = repair_doubt(spectral.p2p_21, settled.p2p_21, run.u1, run.u2,
                             checked=run.state["samples"][1])  # fmt: skip
        if doubt is None or quality.suspect:
            return settled, quality
        found = Said(
            "the map was re-estimated from its geodesic refinement, but the re-estimate changes "
            "geodesic distances about as much as the spectral map did ({after:.3f} against "
            "{before:.3f}): which of the two is right is not known", doubt, "repair_doubtful",
        )  # fmt: skip
        causes = Said(
            "likely causes: parts the descriptors cannot tell apart (limbs, a tail), or shapes "
            "that are not near-isometric; fix: {advice}", {"advice": self._advice(run)}, "causes",
        )  # fmt: skip
        return settled, quality.flagged(found).flagged(causes, first=False)

    def options(self, run: Run, settled: Settled) -> dict[str, Any]:
        """Return the options, with the fit the map came from and the size it ends at."""
        return {
            **super().options(run, settled),
            "k_fit": settled.info["k_fit"],
            "zoomout_to": run.state["final"],
            "w_dcomm": settled.info["w_dcomm"],
        }

    def extend(
        self, corr: Correspondence, coarse_1: Any, coarse_2: Any, V1: Any, V2: Any
    ) -> tuple[np.ndarray, Correspondence]:
        """Extend a coarse map to every vertex: its functional map's, steered by its point map.

        The coarse point map's images, interpolated along the target, join the search
        (``extend_p2p(images=...)``) beside the first ``dense.EXTENSION_K`` eigenfunctions of
        the functional map. Measured (``scripts/bench_match.py``, FAUST 093 → 087
        subdivided, map error / sqrt(area)): 110k vertices 0.0155 → 0.0142, 440k 0.0214 →
        0.0197 with all 99 eigenfunctions (the coarse map itself 0.0184 and 0.0244 at its
        vertices).
        """
        assert corr.fmap_12 is not None
        fmap = np.asarray(corr.fmap_12)
        size = min(EXTENSION_K + 1, *fmap.shape)
        fmap = fmap[:size, :size]
        images = coarse_2.prolongation(V2) @ coarse_1.vertices[np.asarray(corr.p2p_21)]
        p2p = extend_p2p(fmap, coarse_1.eig, coarse_2.eig, V1, V2, images=images)
        return p2p, corr


def _given(run: Run) -> bool:
    """Whether the caller gave landmarks (also for the estimation run without them)."""
    return run.landmarks is not None or bool(run.state.get("landmarks_given"))


def _distortion(run: Run, settled: Settled) -> float:
    """Return a settled map's :func:`_map_distortion`, computed once per point map.

    Kept in ``settled.info["geodesic_distortion"]`` with the point map it was computed for
    (a map whose ``info`` is handed on to another point map computes its own): the shells'
    comparison (:meth:`FullMatch._escalate`) and the one with the map estimated without the
    landmarks (:meth:`FullMatch.against_free`) read the same maps.
    """
    kept = settled.info.get("geodesic_distortion")
    if kept is None or kept[0] is not settled.p2p_21:
        kept = settled.info["geodesic_distortion"] = (
            settled.p2p_21, _map_distortion(run, settled.p2p_21))  # fmt: skip
    return kept[1]


def _map_distortion(run: Run, p2p: np.ndarray) -> float:
    """Return the geodesic distortion of a point map between the run's unit-area shapes.

    :func:`~o3d_ofp.core.partial.geodesic_distortion` on :data:`REPAIR_DISTORTION_SAMPLES`
    target samples.
    """
    surfaces = run.u1.vertices, run.u1.faces, run.u2.vertices, run.u2.faces
    return geodesic_distortion(p2p, *surfaces, samples=REPAIR_DISTORTION_SAMPLES)
