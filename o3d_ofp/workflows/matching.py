"""Matching two shapes: one call from eigenbases to a checked point-to-point map.

The rules of a whole match live here, once: how many eigenfunctions the estimation needs
(:data:`ESTIMATION_K`, :data:`FIT_K`, :data:`WIDE_FIT_K`), the order of the steps (descriptor
fits with the orientation term, ZoomOut, the choice among the starts, the final point map),
and the quality report that says when a map is doubtful. Everything runs on unit-area copies
of the eigenbases, so the result does not depend on the units, position or orientation of
either shape.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import math
import os
from collections.abc import Callable, Mapping
from concurrent.futures import ThreadPoolExecutor, as_completed
from typing import Any

import numpy as np

from ..core._atomic import atomic_path
from ..core._progress import StageProgress
from ..core._warnings import warn
from ..core.correspondence import check_p2p, fmap_from_p2p, nearest_neighbors, p2p_from_fmap
from ..core.fmap import estimate_fmaps, farthest_points, unit_area, zoomout_refine
from ..core.geometry import (
    POINT_NEIGHBOURS,
    outward_sign,
    point_neighbours,
    point_normals,
    tangent_frames,
    vertex_normals,
)
from ..core.multiscale import local_p2p_from_fmap
from ..core.partial import boundary_length, geodesic_features
from ..core.spectrum import EigenBasis, check_eigenbasis, on_cleaned_vertices
from .dense import COARSE_VERTICES, DENSE_VERTICES, match_dense
from .eigenbases import eigenbases as eigenbases_of

__all__ = [
    "ESTIMATION_K",
    "FIT_K",
    "GIVEN_MAP_COLLAPSE",
    "QUALITY_RECORD",
    "Correspondence",
    "MapQuality",
    "alignment_residual",
    "check_landmarks",
    "check_match_options",
    "given_map_collapse",
    "map_quality",
    "match_arrays",
    "match_eigenbases",
    "on_surfaces",
    "required_k",
    "uses_dense_path",
]

logger = logging.getLogger(__name__)

#: ``extra=`` of the log records that give a map's quality report (its summary and notes): a
#: front end that prints the report itself (the command line) leaves these records out.
QUALITY_RECORD = {"quality_report": True}

#: Non-constant eigenfunctions an estimated map is refined to by ZoomOut (pyFM's standard
#: pipeline refines 30 -> 100 with the constant).
ESTIMATION_K = 99
#: Size of the map optimized from descriptors before ZoomOut (the paper's K = 30).
FIT_K = 29

#: A map is suspect when fewer distinct source vertices than this fraction of the smaller
#: shape's vertex count are hit. Measured on correct maps between the shared data's pairs:
#: 0.45-0.65 (a nearest-neighbour map is never a bijection); a collapsed map: < 0.01.
MIN_COVERAGE = 0.2
#: A map given by the caller (a file, an array) is said to collapse when it hits fewer distinct
#: source vertices than this fraction of the smaller shape's vertex count. Lower than the
#: estimated maps' bound (``MIN_COVERAGE``): a right map through a coarser template (scans of
#: 50k vertices, a 6890-vertex template) hits at most the template's vertices, 0.13 of them.
GIVEN_MAP_COLLAPSE = 0.02
#: ... or when the unit-area functional map is this far from orthogonal (‖CᵀC − I‖_F / √k):
#: the shapes are not near-isometric. Measured (``python scripts/eval_matching.py --all-pairs
#: --variants --unrelated``): the 32 FAUST and FAUST-remeshed pairs 0.11-0.29 (the wrong maps
#: among them, errors 0.12-0.19 with parts swapped, included); decimated (down to 479 or 1000
#: vertices), subdivided, point-cloud and other-resolution copies of FAUST, TOSCA and the
#: models 0.05-0.37; shapes of other kinds (a human onto a bunny, a teddy, a centaur or a dog;
#: a centaur or a cow onto a human) 0.42-0.45, a bunny onto a cow and a dog onto a centaur
#: 0.39; the failed SHREC'19 map (error 0.30) 0.43 (its ground-truth map's own is 0.50: those
#: scans are far from isometric); targets with 0.3 % or 1 % noise 0.44 (wrong maps: errors
#: 0.24-0.58; 0.1 % noise gives a right map, 0.27). A right map between real scans as far
#: from isometric as the SHREC'19 pair would be flagged too: a spectral map is not to be
#: trusted there without a look or landmarks.
MAX_ORTHOGONALITY = 0.4
#: ... or when the point map and the functional map disagree by this much
#: (‖C − C(p2p)‖_F / ‖C‖_F): measured 0.1-0.35 on correct maps, above 0.6 on failed ones.
MAX_INCONSISTENCY = 0.55
#: ... or when more than this fraction of the target's triangles, carried to the source by the
#: map, are turned over (the map is a reflection there: a left/right symmetry flip). With a
#: point cloud, the fraction of target neighbourhoods where the map is a reflection (the same
#: bound, not refitted): measured by ``python scripts/eval_cloud.py --estimate``, right maps
#: 0.18-0.28 (errors 0.035-0.095), the flipped ones 0.365-0.442 (errors 0.12-0.17).
MAX_REVERSED = 0.35
#: Areas that differ by more than this factor are reported (different units or a partial
#: shape); the map itself does not depend on the units.
AREA_RATIO_NOTE = 1.5
#: A full-shape map is suspect as a partial shape when the smaller shape has less than
#: 1 / PARTIAL_AREA_RATIO of the larger's area AND more boundary: its boundary length / sqrt(area)
#: exceeds the larger's by EXTRA_BOUNDARY. Area alone cannot tell a part from other units
#: (the estimation normalizes areas: a scaled copy maps correctly), and correct pairs differ
#: by up to 1.30 in area (FAUST remeshed 002 -> 007, both closed). Measured
#: on the cuts of scripts/eval_partial.py (50-80 % kept): 1.0-5.8; on the pairs of the shared
#: data: 0 (closed shapes) and 0.04 (SHREC'19 scans, both with holes).
PARTIAL_AREA_RATIO = 1.2
EXTRA_BOUNDARY = 0.4
#: From this area ratio the units surely differ (the smallest change of units, inches and
#: centimetres, is 6.45 in area, times a part's 0.5-0.8; correct pairs of whole shapes differ
#: by up to 1.30, see above): the longest boundary curves are compared (a scan's holes are
#: short), and a larger shape with the longer curve is said to be a part in other units.
UNITS_AREA_RATIO = 3.0
#: With partial=True, a target larger than the source by this factor cannot be a part of it.
PARTIAL_MAX_AREA_RATIO = 1.1

_FORMAT_VERSION = 1

#: Above this many (source x target) vertex pairs the final point map is found by the
#: cell-pruned exact search of :func:`o3d_ofp.core.multiscale.local_p2p_from_fmap` (measured,
#: FAUST subdivided: 110k x 110k in 2.7 s instead of 98 s, the same map) rather than a scan.
DENSE_PAIRS = 2e8

#: Weights of the descriptor-commutativity term tried by :func:`match_eigenbases`.
DCOMM_WEIGHTS = (0.1, 0.0)
#: Size of the second descriptor fit of :func:`match_eigenbases` (beside ``k_fit``, the
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


def alignment_residual(
    fmap_12: np.ndarray,
    eig_1: EigenBasis,
    eig_2: EigenBasis,
    *,
    samples: int = 2000,
    sample_indices: tuple[np.ndarray, np.ndarray] | None = None,
) -> float:
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
    if sample_indices is None:
        sample_indices = (
            farthest_points(eig_1.vertices, samples),
            farthest_points(eig_2.vertices, samples),
        )
    s1, s2 = sample_indices
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
#: The check runs when n1 · n2 is at most this: the dense path's coarse copies (20 000
#: vertices) are under it. Its cost is mostly its Dijkstra runs (100 on the target, 100-300 on
#: the source): measured 0.3 s at 6.9k vertices and 1.8 s at 27.5k (FAUST 093, subdivided once;
#: scipy's Dijkstra holds the GIL, so they run one after the other); a re-estimate adds a
#: nearest-neighbour search over every target vertex, quadratic in the sizes.
REPAIR_MAX_PAIRS = 1e9


def geodesic_repair(
    p2p_21: np.ndarray,
    eig_1: EigenBasis,
    eig_2: EigenBasis,
    *,
    k_fit: int,
    k_final: int,
    subsample: int | None = None,
    samples: tuple[np.ndarray, np.ndarray] | None = None,
    share: float = REPAIR_SHARE,
    checked: np.ndarray | None = None,
) -> tuple[np.ndarray | None, float]:
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
    k_fit, k_final : int
        Size of the fit to the geodesic map and of the ZoomOut that follows.
    subsample, samples
        ZoomOut's farthest-point samples (as in :func:`~o3d_ofp.core.fmap.zoomout_refine`).
    share : float, default REPAIR_SHARE
        Disagreement (fraction of the target's area) above which the map is re-estimated.
    checked : (s,) ndarray of int, optional
        The target vertices the disagreement is measured on: farthest-point samples (default:
        :data:`REPAIR_SAMPLES` of them).

    Returns
    -------
    fmap_12 : (k_final+1, k_final+1) ndarray or None
        The re-estimated map between the unit-area bases, None when the map is kept.
    disagreement : float
        The share of the target's area where the map and its geodesic refinement disagree
        (the share of the samples ``checked``).
    """
    f1, f2 = geodesic_features(
        p2p_21, eig_1.vertices, eig_1.faces, eig_2.vertices, eig_2.faces,
        anchors=REPAIR_ANCHORS, iterations=REPAIR_ITERATIONS,
    )  # fmt: skip
    # The disagreement is measured on farthest-point samples of the target (about uniform in
    # area; 2000 samples: a share of 0.05 within about 0.005), the whole map only re-estimated.
    if checked is None:
        checked = farthest_points(eig_2.vertices, min(REPAIR_SAMPLES, eig_2.n_vertices))
    geodesic = nearest_neighbors(f1.T, f2[:, checked].T)
    apart = np.linalg.norm(eig_1.vertices[p2p_21[checked]] - eig_1.vertices[geodesic], axis=1)
    disagreement = float(np.mean(apart > REPAIR_JUMP))
    if disagreement <= share:
        return None, disagreement
    f1, f2 = geodesic_features(p2p_21, eig_1.vertices, eig_1.faces, eig_2.vertices, eig_2.faces)
    geodesic = nearest_neighbors(f1.T, f2.T)
    C = fmap_from_p2p(geodesic, eig_1, eig_2, k1=k_fit, k2=k_fit)
    C = zoomout_refine(C, eig_1, eig_2, k_final=k_final, subsample=subsample, samples=samples)
    return C, disagreement


def required_k(n_vertices: int, wanted: int = ESTIMATION_K) -> int:
    """Eigenfunctions a shape of ``n_vertices`` vertices gives the estimation (``wanted`` at most).

    Parameters
    ----------
    n_vertices : int
        Vertices of the shape (after cleaning, when known).
    wanted : int, default :data:`ESTIMATION_K`
        The size asked for.

    Returns
    -------
    int
        ``min(wanted, n_vertices - 1)``: a shape cannot hold more non-constant eigenfunctions.
    """
    return max(1, min(wanted, n_vertices - 1))


@dataclasses.dataclass(frozen=True)
class MapQuality:
    """Measures of a point-to-point map that need no ground truth.

    Attributes
    ----------
    coverage : float
        Fraction of the source vertices that some target vertex maps to.
    coverage_ratio : float
        Distinct source vertices hit / min(n1, n2): about 0.5 for a correct nearest-neighbour
        map, near 0 for a collapse.
    orthogonality : float
        ‖ĈᵀĈ − I‖_F / √(k+1) of the functional map Ĉ between the unit-area eigenbases (an
        isometry gives an orthogonal map); NaN when no functional map is known.
    inconsistency : float
        ‖Ĉ − Ĉ(p2p)‖_F / ‖Ĉ‖_F: how much the point map disagrees with the functional map it
        came from; NaN when no functional map is known.
    reversed_fraction : float
        Fraction of the target's triangles whose image on the source is turned over (its
        normal against the source surface's): near 0 for an orientation-preserving map, near
        1 for a mirror-image (left/right flipped) one. When either shape is a point cloud:
        the fraction of target points where the map, fitted on the point's neighbourhood, is
        a reflection (normals estimated: 0.07-0.15 for the true maps of FAUST and TOSCA
        clouds, up to 0.28 for right estimated maps).
    area_ratio : float
        Target area / source area.
    suspect : bool
        Whether the map is doubtful (see ``reasons``).
    reasons : tuple of str
        Why it is doubtful, with the likely causes and the fix; empty when it is not.
    notes : tuple of str
        Remarks that do not make the map suspect (e.g. very different areas).
    overlap : float or None
        For a partial map: estimated fraction of the source's area the target covers; None
        otherwise.
    reversed_of : {"triangles", "neighbourhoods"}
        What ``reversed_fraction`` counts: the target's triangles, or its points'
        neighbourhoods when either shape is a point cloud.
    distortion, stretch : float or None
        For a partial map: the geodesic distortion and the stretch its check read
        (:func:`o3d_ofp.core.partial.geodesic_distortion`,
        :func:`o3d_ofp.core.partial.map_stretch`; those of the checked map, before its
        polish; on the dense path, of the coarse copies' map); None otherwise.
    """

    coverage: float
    coverage_ratio: float
    orthogonality: float
    inconsistency: float
    reversed_fraction: float
    area_ratio: float
    suspect: bool
    reasons: tuple[str, ...] = ()
    notes: tuple[str, ...] = ()
    overlap: float | None = None
    reversed_of: str = "triangles"
    distortion: float | None = None
    stretch: float | None = None

    def summary(self) -> str:
        """One line: the measures and the verdict."""
        verdict = "SUSPECT" if self.suspect else "ok"
        # Each fraction says of what: the vertices hit, of the source's vertices and of the
        # smaller shape's count; the overlap, of the source's area.
        parts = [
            f"coverage {self.coverage:.3f} of the source's vertices ({self.coverage_ratio:.2f} "
            "of the smaller shape's count)"
        ]
        for name, value in (
            ("orthogonality", self.orthogonality),
            ("inconsistency", self.inconsistency),
            (f"reversed {self.reversed_of}", self.reversed_fraction),
        ):
            if not math.isnan(value):  # measures a map of this kind does not have are left out
                parts.append(f"{name} {value:.3f}")
        if not math.isnan(self.area_ratio):
            parts.append(f"area ratio {self.area_ratio:.3g}")
        if self.overlap is not None:
            parts.append(f"overlap {self.overlap:.2f} of the source's area")
        return f"map quality {verdict}: " + ", ".join(parts)

    def suspect_message(self, what: str) -> str:
        """Return ``"<what> is suspect:"`` and each reason on its own indented line."""
        return f"{what} is suspect:" + "".join(f"\n  - {reason}" for reason in self.reasons)


def map_quality(
    p2p_21: np.ndarray,
    eig_1: EigenBasis,
    eig_2: EigenBasis,
    fmap_12: np.ndarray | None = None,
    *,
    partial: bool = False,
    overlap: float | None = None,
    landmarks_given: bool = False,
) -> MapQuality:
    """Judge a point map (and the functional map it came from) without ground truth.

    Parameters
    ----------
    p2p_21 : (n2,) ndarray of int
        For every target vertex, its source vertex.
    eig_1, eig_2 : EigenBasis
        Source and target eigenbases.
    fmap_12 : (K+1, K+1) ndarray, optional
        The functional map the point map was extracted from (same convention as
        :func:`o3d_ofp.fmap_from_p2p`).
    partial : bool, default False
        The map was made for a part (the target) of the source: areas may differ, but a
        target larger than the source is suspect. Without it, a shape that looks like a part
        of the other (smaller, with more boundary) makes the map suspect.
    overlap : float, optional
        Estimated fraction of the source covered (partial maps), kept in the report.
    landmarks_given : bool, default False
        The map was estimated with landmarks: a doubtful map then points at them first.

    Returns
    -------
    MapQuality
    """
    n1, n2 = eig_1.n_vertices, eig_2.n_vertices
    hit = np.unique(p2p_21).size
    coverage = hit / n1
    ratio = hit / min(n1, n2)
    area_ratio = eig_2.area / eig_1.area
    ortho = incons = math.nan
    if fmap_12 is not None:
        C = np.asarray(fmap_12) * math.sqrt(eig_1.area / eig_2.area)  # between unit-area bases
        k = min(C.shape) - 1
        C = C[: k + 1, : k + 1]
        ortho = float(np.linalg.norm(C.T @ C - np.eye(k + 1)) / math.sqrt(k + 1))
        u1, u2 = unit_area(eig_1), unit_area(eig_2)
        C_p2p = fmap_from_p2p(p2p_21, u1, u2, k1=k, k2=k)
        incons = float(np.linalg.norm(C - C_p2p) / max(np.linalg.norm(C), 1e-300))
    reversed_fraction = _reversed_fraction(p2p_21, eig_1, eig_2)
    clouds = eig_1.faces is None or eig_2.faces is None
    reasons = []
    far = ortho > MAX_ORTHOGONALITY  # no near-isometric map: no "right map" to be mirrored
    if reversed_fraction > MAX_REVERSED:
        turned = "of the target's neighbourhoods" if clouds else "of the triangles"
        why = (
            "" if far else ": a mirror image of the right map (left/right symmetry flip), or a "
            "map too rough to keep the triangles' orientation (a very coarse or noisy shape)"
        )
        reasons.append(f"the map turns {100 * reversed_fraction:.0f} % {turned} over{why}")
    if ratio < MIN_COVERAGE:
        reasons.append(
            f"the map collapses: only {hit} distinct source vertices are hit by {n2} target "
            "vertices"
        )
    if far:
        reasons.append(
            f"the functional map is far from an isometry (orthogonality {ortho:.2f} > "
            f"{MAX_ORTHOGONALITY:g}): the shapes are not near-isometric (shapes of other kinds, "
            "a noisy scan, or a part of the other shape)"
        )
    if incons > MAX_INCONSISTENCY:
        reasons.append(
            f"the point map disagrees with the functional map (inconsistency {incons:.2f})"
        )
    reasons.extend(_area_reasons(eig_1, eig_2, area_ratio, partial))
    suspect = bool(reasons)
    notes = []
    if clouds:
        # No advice to mesh the cloud: Open3D's Poisson reconstruction of FAUST 087's and
        # centaur4's clouds (depth 7-8) gave maps of 0.11-0.20 and 0.025-0.46
        # (``python scripts/eval_cloud.py --poisson``).
        notes.append(
            "a point cloud has no faces: its normals are estimated (the flip check is less "
            "sure than on meshes) and its Laplacian can join parts that touch (measured on "
            "FAUST 093 -> 087: error 0.063 with the target as points, 0.121 with both, against "
            "0.014 for the meshes); match the mesh the cloud was made from when there is one, "
            "or give a few landmarks, and check the result"
        )
    cloud_part = None if partial else cloud_part_note(eig_1, eig_2, area_ratio)
    if cloud_part is not None:
        notes.append(cloud_part)
    elif not partial and not (1 / AREA_RATIO_NOTE <= area_ratio <= AREA_RATIO_NOTE):
        notes.append(
            f"the target's area is {area_ratio:.3g} times the source's (different units? a "
            "partial shape?); the estimated map does not depend on the units"
        )
    if far:
        reasons.append(
            "likely causes: shapes of other kinds (a spectral map needs near-isometric shapes, "
            "and landmarks do not make them so: check the result by eye), a noisy scan, or a "
            "part of the other shape (partial=True / --partial); aligned copies of one shape "
            "match by closest points (method='closest' / --map closest)"
        )
    elif reasons and landmarks_given:
        reasons.append(
            "likely causes: a wrong landmark pair (a pair swapped or on the mirrored side "
            "turns the map over), very different shapes, or a partial shape; fix: check the "
            "landmarks given (landmarks= / --landmarks; pick them with --landmarks pick)"
        )
    elif reasons:
        reasons.append(
            "likely causes: very different shapes, a partial shape, a symmetry flip, or "
            "descriptors that cannot tell the parts apart; fix: give a few known vertex pairs "
            "(landmarks=[[source, target], ...] / --landmarks 12:40,500:611)"
        )
    return MapQuality(
        coverage=float(coverage),
        coverage_ratio=float(ratio),
        orthogonality=ortho,
        inconsistency=incons,
        reversed_fraction=reversed_fraction,
        area_ratio=float(area_ratio),
        suspect=suspect,
        reasons=tuple(reasons),
        notes=tuple(notes),
        overlap=None if overlap is None else float(overlap),
        reversed_of="neighbourhoods" if clouds else "triangles",
    )


def _area_reasons(
    eig_1: EigenBasis, eig_2: EigenBasis, area_ratio: float, partial: bool
) -> list[str]:
    """Why the areas make a map doubtful: a part matched as a whole, or a partial map onto less."""
    if partial:
        if area_ratio <= PARTIAL_MAX_AREA_RATIO:
            return []
        return [
            f"partial=True but the target's area is {area_ratio:.3g} times the source's: it "
            "cannot be a part of the source; fix: make the whole shape the source (swap them) "
            "and give both in the same units (rescale)"
        ]
    factor = max(area_ratio, 1 / area_ratio)
    if factor <= PARTIAL_AREA_RATIO:
        return []
    small, large = (eig_2, eig_1) if area_ratio < 1 else (eig_1, eig_2)
    # In units that may be the same, the total boundary; where the units surely differ, the
    # longest boundary curve: a whole scan with holes, in other units, is no part (a review's
    # FAUST body with three holes was flagged by its total), and a cut leaves a long curve
    # (0.52-4.0 per sqrt(area) on the cuts of scripts/eval_partial.py).
    longest = factor >= UNITS_AREA_RATIO

    def boundary(eig: EigenBasis) -> float:
        return boundary_length(eig.vertices, eig.faces, longest=longest) / math.sqrt(eig.area)

    extra = boundary(small) - boundary(large)
    if extra > EXTRA_BOUNDARY:
        part = "target" if area_ratio < 1 else "source"
        return [
            f"the {part} looks like a part of the other shape ({1 / factor:.2g} of its area, "
            f"{extra:.2f} more boundary per sqrt(area)): a full-shape map cannot match a "
            "part; fix: partial=True / --partial with the whole shape as the source"
            + (" (swap source and target)" if part == "source" else "")
            + ", in the same units (rescale first if they differ)"
        ]
    if longest and -extra > EXTRA_BOUNDARY:
        # The larger shape has the longer cut: a part can only be larger in other units (a
        # trial's cut in millimetres onto a whole in metres was told only "not
        # near-isometric").
        part = "target" if area_ratio > 1 else "source"
        return [
            f"the {part} looks like a part of the other shape in other units ({factor:.3g} "
            f"times its area, a boundary curve {-extra:.2f} longer per sqrt(area)): a "
            "full-shape map cannot match a part; fix: rescale the part to the whole shape's "
            "units, then partial=True / --partial with the whole shape as the source"
            + (" (swap source and target)" if part == "source" else "")
        ]
    return []  # a scaled shape (other units) keeps its boundary: its map is right


def cloud_part_note(eig_1: EigenBasis, eig_2: EigenBasis, area_ratio: float) -> str | None:
    """Say that a cloud of a smaller area may be a part, which a full-shape map cannot match.

    A point cloud's boundary is not measured, so a cloud that is a part of the other shape is
    not told from another body (:func:`_area_reasons` needs faces). None unless either shape
    is a point cloud and the areas differ by a factor between :data:`PARTIAL_AREA_RATIO` and
    :data:`UNITS_AREA_RATIO` (beyond: other units, whose map is right; a trial's one-sided
    cloud of 0.76 times the source's area was matched wrong, error 0.22, with no word).
    """
    if eig_1.faces is not None and eig_2.faces is not None:
        return None
    if not PARTIAL_AREA_RATIO < max(area_ratio, 1 / area_ratio) < UNITS_AREA_RATIO:
        return None
    small = "target" if area_ratio < 1 else "source"
    return (
        f"the target's area is {area_ratio:.3g} times the source's and a point cloud's "
        f"boundary is not measured: if the {small} is a part of the other shape (a one-sided "
        "scan, a cut), a full-shape map cannot match it (fix: mesh both and match with "
        "partial=True / --partial, the whole shape as the source, in the same units); if "
        "they are two whole shapes, check the result"
    )


def _outward_normals(eig: EigenBasis) -> np.ndarray:
    """(n, 3) unit normals of every vertex, outward: the mesh's, or estimated for a cloud."""
    if eig.faces is None:
        return point_normals(eig.vertices)
    normals = vertex_normals(eig.vertices, eig.faces) * outward_sign(eig.vertices, eig.faces)
    if eig.cleaning is not None:  # normals of removed / duplicated vertices
        c = eig.cleaning
        normals = normals[c.representative[c.index]]
    return normals


def _reversed_fraction(p2p_21: np.ndarray, eig_1: EigenBasis, eig_2: EigenBasis) -> float:
    """Fraction of target triangles (clouds: neighbourhoods) whose image is turned over."""
    if eig_1.faces is None or eig_2.faces is None:
        return _reversed_neighbourhoods(p2p_21, eig_1, eig_2)
    normals_1 = _outward_normals(eig_1)
    F = eig_2.faces
    image = p2p_21[F]  # (m, 3) source vertices
    distinct = (image[:, 0] != image[:, 1]) & (image[:, 1] != image[:, 2])
    distinct &= image[:, 0] != image[:, 2]
    if not np.any(distinct):
        return math.nan
    image = image[distinct]
    P = eig_1.vertices[image]
    tri_normal = np.cross(P[:, 1] - P[:, 0], P[:, 2] - P[:, 0])
    surface = normals_1[image].sum(axis=1)  # outward
    # A target whose faces are oriented inwards (negative enclosed volume) would count as
    # turned over as a whole: its triangles' orientation is compared with its outward one.
    side = np.sign(np.einsum("ij,ij->i", tri_normal, surface)) * outward_sign(eig_2.vertices, F)
    counted = side != 0
    return float(np.mean(side[counted] < 0)) if np.any(counted) else math.nan


def _reversed_neighbourhoods(p2p_21: np.ndarray, eig_1: EigenBasis, eig_2: EigenBasis) -> float:
    """Fraction of target points where the map, fitted on their neighbourhood, is a reflection.

    A point cloud has no triangles to turn over. At each target point, the linear map ``A``
    (2 x 2) that best carries its :data:`POINT_NEIGHBOURS` nearest points (tangent coordinates
    in the frame of its outward normal) to their images (tangent coordinates at the image
    point, in the frame of the source's outward normal there) is fitted by least squares;
    ``det A < 0`` is a local mirror image, the cloud's analogue of a turned triangle. Frames
    follow the normals' signs, so the estimated normals' sign errors (3.6 % of FAUST 093's
    points, see :func:`o3d_ofp.core.geometry.point_normals`) add to it: measured with the true
    maps, FAUST 093 -> 087 and TOSCA centaur2 -> 4 with the target as the cloud of its
    vertices 0.071 / 0.155 (their meshes' normals: 0.018 / 0.011), sampled on its surface with
    0.5 % noise 0.11 / 0.15; the same maps onto the mirror image of the target 0.93 / 0.85.
    Neighbourhoods whose image is (nearly) one point are not counted.
    """
    V1, V2 = eig_1.vertices, eig_2.vertices
    n1, n2 = _outward_normals(eig_1), _outward_normals(eig_2)
    q = min(POINT_NEIGHBOURS + 1, V2.shape[0])
    if q < 4:
        return math.nan
    nb = point_neighbours(V2, q)[:, 1:]  # (n2, q-1) without the point itself
    s1, s2 = tangent_frames(n2)
    d = V2[nb] - V2[:, None, :]
    U = np.stack([np.einsum("nqi,ni->nq", d, s1), np.einsum("nqi,ni->nq", d, s2)], axis=2)
    r1, r2 = tangent_frames(n1[p2p_21])
    e = V1[p2p_21[nb]] - V1[p2p_21][:, None, :]
    E = np.stack([np.einsum("nqi,ni->nq", e, r1), np.einsum("nqi,ni->nq", e, r2)], axis=2)
    # det(A) of A = (UᵀU)⁻¹ UᵀE has the sign of det(UᵀE) when UᵀU is positive definite
    UtU = np.einsum("nqa,nqb->nab", U, U)
    UtE = np.einsum("nqa,nqb->nab", U, E)
    fit = np.linalg.det(UtU)
    det = np.linalg.det(UtE)
    size = np.einsum("nab,nab->n", UtE, UtE)  # ‖UᵀE‖², det scales like it
    counted = (fit > 1e-12 * np.einsum("nab,nab->n", UtU, UtU)) & (np.abs(det) > 1e-6 * size)
    return float(np.mean(det[counted] < 0)) if np.any(counted) else math.nan


@dataclasses.dataclass(frozen=True, eq=False)
class Correspondence:
    """A map between two shapes: for every target vertex, a source vertex.

    Attributes
    ----------
    p2p_21 : (n2,) ndarray of int64
        Source vertex of every target vertex, in the callers' vertex numbering (read-only).
    n_source : int
        Number of source vertices (the map's indices lie in ``[0, n_source)``).
    fmap_12 : (K+1, K+1) ndarray or None
        The functional map between the eigenbases (convention of :func:`o3d_ofp.fmap_from_p2p`),
        when the map was estimated.
    method : str
        How the map was made: ``"estimate"``, ``"partial"`` (the target a part of the
        source, :mod:`o3d_ofp.workflows.partial`), ``"closest"``, ``"given"``, ``"identity"``,
        ``"template"``.
    options : mapping
        The options used (JSON-serializable).
    quality : MapQuality or None
        The quality report (``None`` for a map given by the caller).
    faces_21 : (n2,) ndarray of int64 or None
        For a precise (surface) map: the source triangle each target vertex maps into.
    barycentric_21 : (n2, 3) ndarray of float64 or None
        Its barycentric coordinates in that triangle (rows sum to 1).
    signatures : ((s,), (s,)) ndarrays or None
        :func:`shape_signature` of the source and the target the map was made for (set by
        the estimation and the closest-point map): :meth:`check` warns when it is used on
        other shapes with the same vertex counts.
    """

    p2p_21: np.ndarray
    n_source: int
    fmap_12: np.ndarray | None = None
    method: str = "given"
    options: Mapping[str, Any] = dataclasses.field(default_factory=dict)
    quality: MapQuality | None = None
    faces_21: np.ndarray | None = None
    barycentric_21: np.ndarray | None = None
    signatures: tuple[np.ndarray, np.ndarray] | None = None

    def __post_init__(self) -> None:
        p2p = check_p2p(self.p2p_21, np.shape(self.p2p_21)[0], self.n_source)
        object.__setattr__(self, "p2p_21", p2p)
        p2p.setflags(write=False)
        if self.fmap_12 is not None:
            C = np.array(self.fmap_12, dtype=np.float64)
            C.setflags(write=False)
            object.__setattr__(self, "fmap_12", C)
        if (self.faces_21 is None) != (self.barycentric_21 is None):
            raise ValueError("faces_21 and barycentric_21 go together")
        if self.faces_21 is not None:
            n2 = p2p.shape[0]
            faces = np.array(self.faces_21, dtype=np.int64)
            bary = np.array(self.barycentric_21, dtype=np.float64)
            if faces.shape != (n2,) or bary.shape != (n2, 3):
                raise ValueError(
                    f"faces_21 and barycentric_21 must have shapes ({n2},) and ({n2}, 3); got "
                    f"{faces.shape} and {bary.shape}"
                )
            if not np.all(np.isfinite(bary)) or np.abs(bary.sum(axis=1) - 1).max() > 1e-6:
                raise ValueError("barycentric_21 rows must be finite and sum to 1")
            for arr, name in ((faces, "faces_21"), (bary, "barycentric_21")):
                arr.setflags(write=False)
                object.__setattr__(self, name, arr)
        if self.signatures is not None:
            pair = tuple(np.array(s, dtype=np.float64).ravel() for s in self.signatures)
            if len(pair) != 2:
                raise ValueError("signatures must be (source signature, target signature)")
            for s in pair:
                s.setflags(write=False)
            object.__setattr__(self, "signatures", pair)

    @property
    def n_target(self) -> int:
        """Number of target vertices."""
        return self.p2p_21.shape[0]

    def check(
        self,
        n_source: int,
        n_target: int,
        *,
        name: str = "correspondence",
        source: Any = None,
        target: Any = None,
    ) -> None:
        """Raise ``ValueError`` unless the map goes from ``n_source`` to ``n_target`` vertices.

        With the shapes' vertices (``source``, ``target``: (n, 3) arrays) and
        :attr:`signatures`, also warn (:class:`~o3d_ofp.OFPWarning`) when they are not the
        shapes the map was made for, up to a move, a rotation and a uniform scaling: source
        and target swapped, or another pair with the same vertex counts (all FAUST shapes
        have 6890 vertices).
        """
        if (self.n_source, self.n_target) != (n_source, n_target):
            raise ValueError(
                f"{name} maps {self.n_target} target vertices to {self.n_source} source "
                f"vertices, but the target has {n_target} and the source {n_source}: it "
                "belongs to "
                "other shapes, or to these read otherwise (a map saved by o3d-ofp indexes the "
                "vertices as o3d_ofp.read_geometry reads them; Open3D's reader with "
                "enable_post_processing=True splits an OBJ's vertices, along its UV seams or at "
                "every corner)"
            )
        said = self.mismatch(source, target, name=name)
        if said is not None:
            warn(logger, said + ". The map is used as it is")

    def mismatch(
        self, source: Any = None, target: Any = None, *, name: str = "correspondence"
    ) -> str | None:
        """Say why the map was made for other shapes than these, or None when it was not.

        Parameters
        ----------
        source, target : (n, 3) array_like, optional
            The shapes' vertices, compared with :attr:`signatures` up to a move, a rotation
            and a uniform scaling (a shape left out, or a map without signatures, is not
            compared).
        name : str
            How the message names the map.

        Returns
        -------
        str or None
        """
        if self.signatures is None:
            return None
        for shape, signature, side in zip(
            (source, target), self.signatures, ("source", "target"), strict=True
        ):
            if shape is None:
                continue
            if not _same_signature(shape_signature(shape), signature):
                return (
                    f"{name} was made for another {side} with {np.shape(shape)[0]} vertices "
                    "(its vertices are not where they were, even up to a move, a rotation or "
                    "a scaling): source and target swapped, another pair, a changed shape, or "
                    "the same shape with its vertices in another order (an OBJ read again)"
                )
        return None

    def save(self, path: str | os.PathLike[str]) -> None:
        """Write the correspondence to a ``.npz`` file (atomically).

        Parameters
        ----------
        path : str or os.PathLike
            Destination (``.npz`` is appended when missing).

        Raises
        ------
        FileNotFoundError
            If the destination's folder does not exist.
        """
        payload: dict[str, Any] = {
            "format_version": np.int64(_FORMAT_VERSION),
            "kind": np.array("o3d_ofp.Correspondence"),
            "p2p_21": self.p2p_21,
            "n_source": np.int64(self.n_source),
            "method": np.array(self.method),
            "options": np.array(json.dumps(dict(self.options), sort_keys=True, default=str)),
        }
        if self.fmap_12 is not None:
            payload["fmap_12"] = self.fmap_12
        if self.quality is not None:
            payload["quality"] = np.array(json.dumps(dataclasses.asdict(self.quality)))
        if self.faces_21 is not None:
            payload["faces_21"] = self.faces_21
            payload["barycentric_21"] = self.barycentric_21
        if self.signatures is not None:
            payload["signature_1"], payload["signature_2"] = self.signatures
        path = os.fspath(path)
        if not path.endswith(".npz"):
            path += ".npz"
        folder = os.path.dirname(os.path.abspath(path))
        if not os.path.isdir(folder):  # said of the file asked for, not of a temporary one
            raise FileNotFoundError(f"{path}: the folder {folder} does not exist")
        with atomic_path(path, suffix=".npz") as tmp:
            np.savez(tmp, **payload)

    @classmethod
    def load(cls, path: str | os.PathLike[str]) -> Correspondence:
        """Read a correspondence written by :meth:`save`.

        Raises
        ------
        FileNotFoundError
            If there is no such file.
        ValueError
            If the file cannot be read or is not a correspondence file (the message names it).
        """
        import zipfile

        name = os.fspath(path)
        if not os.path.isfile(name):
            raise FileNotFoundError(f"{name}: no such correspondence file")
        try:
            if not zipfile.is_zipfile(name):  # np.load would speak of pickles
                raise ValueError(
                    "not an .npz archive (maps are written by Correspondence.save or --save-map)"
                )
            data = np.load(name, allow_pickle=False)
        except (OSError, ValueError) as exc:
            raise ValueError(f"{name}: cannot read a correspondence file ({exc})") from exc
        with data:
            if "kind" not in data or str(data["kind"]) != "o3d_ofp.Correspondence":
                raise ValueError(f"{name}: not an o3d_ofp correspondence file")
            if int(data["format_version"]) != _FORMAT_VERSION:
                raise ValueError(f"{name}: unknown correspondence format version")
            try:
                quality = None
                if "quality" in data:
                    fields = json.loads(str(data["quality"]))
                    fields["reasons"] = tuple(fields.get("reasons", ()))
                    fields["notes"] = tuple(fields.get("notes", ()))
                    quality = MapQuality(**fields)
                return cls(
                    p2p_21=data["p2p_21"],
                    n_source=int(data["n_source"]),
                    fmap_12=data["fmap_12"] if "fmap_12" in data else None,
                    method=str(data["method"]),
                    options=json.loads(str(data["options"])),
                    quality=quality,
                    faces_21=data["faces_21"] if "faces_21" in data else None,
                    barycentric_21=data["barycentric_21"] if "barycentric_21" in data else None,
                    signatures=(data["signature_1"], data["signature_2"])
                    if "signature_1" in data
                    else None,
                )
            except (TypeError, ValueError, KeyError) as exc:
                raise ValueError(f"{name}: damaged correspondence file ({exc})") from exc


#: Vertices (evenly spaced in the vertex order) whose distances to the centroid make a shape's
#: signature.
SIGNATURE_POINTS = 32
#: Relative tolerance of a signature comparison: float32 copies of the vertices (tensor
#: meshes) differ by ~1e-7; a moved, turned or scaled copy by round-off.
SIGNATURE_RTOL = 1e-5


def shape_signature(vertices: Any) -> np.ndarray:
    """Distances of a few vertices to the centroid, over the RMS radius: (SIGNATURE_POINTS,).

    The same for a moved, rotated or uniformly scaled copy with the same vertex order; other
    shapes (another pose, source and target swapped) differ.
    """
    V = np.asarray(vertices, dtype=np.float64)
    centred = V - V.mean(axis=0)
    rms = math.sqrt(float(np.mean(np.einsum("ij,ij->i", centred, centred))))
    picks = np.linspace(0, V.shape[0] - 1, min(SIGNATURE_POINTS, V.shape[0])).astype(np.int64)
    return np.linalg.norm(centred[picks], axis=1) / max(rms, np.finfo(float).tiny)


def same_shape(vertices_a: Any, vertices_b: Any) -> bool:
    """Whether two vertex arrays are one shape up to a move, a rotation and a scaling.

    Compares their :func:`shape_signature` (same vertex counts needed); a basis computed on
    one shape and used on another with the same vertex count (source and target swapped,
    another FAUST pose) is told apart this way.
    """
    return _same_signature(shape_signature(vertices_a), shape_signature(vertices_b))


def _same_signature(a: np.ndarray, b: np.ndarray) -> bool:
    """Whether two :func:`shape_signature` values are one shape's (to :data:`SIGNATURE_RTOL`)."""
    return a.shape == b.shape and bool(np.allclose(a, b, rtol=SIGNATURE_RTOL, atol=SIGNATURE_RTOL))


def with_signatures(corr: Correspondence, source: Any, target: Any) -> Correspondence:
    """``corr`` with the :func:`shape_signature` of the shapes it was made for."""
    return dataclasses.replace(
        corr, signatures=(shape_signature(source), shape_signature(target))
    )


def check_correspondence(obj: Any, name: str = "correspondence") -> Correspondence | None:
    """Return ``obj`` if it is a :class:`Correspondence` or None; else raise a TypeError.

    A bare array passed as ``correspondence=`` is the usual mistake: the message says where a
    vertex map goes instead.
    """
    if obj is not None and not isinstance(obj, Correspondence):
        raise TypeError(
            f"{name} must be an o3d_ofp Correspondence (from ofp.match or "
            f"ofp.Correspondence.load); got {type(obj).__name__} (a vertex map goes in p2p_21=)"
        )
    return obj


def check_landmarks(landmarks: Any, n_source: int, n_target: int) -> np.ndarray | None:
    """Return landmarks as a (p, 2) int64 array after checking their shape and range.

    A pair given more than once is returned once (the pairs keep their order).

    Raises
    ------
    ValueError
        When they are not (source, target) integer pairs within both shapes' vertices, or
        contradict each other (one vertex paired with two different vertices).
    """
    if landmarks is None:
        return None
    lm = np.asarray(landmarks)
    if (
        lm.ndim != 2
        or lm.shape[1] != 2
        or lm.shape[0] == 0
        or not np.issubdtype(lm.dtype, np.integer)
    ):
        raise ValueError(
            "landmarks must be a (p, 2) integer array of (source, target) vertex pairs; "
            f"got {lm.dtype}{lm.shape}"
        )
    for col, (n, side) in enumerate(((n_source, "source"), (n_target, "target"))):
        if lm[:, col].min() < 0 or lm[:, col].max() >= n:
            raise ValueError(
                f"landmarks: {side} vertex indices must lie in [0, {n}); got "
                f"[{lm[:, col].min()}, {lm[:, col].max()}]"
            )
    pairs = np.unique(lm.astype(np.int64), axis=0)  # a pair given twice is harmless
    for col, side, other in ((0, "source", "target"), (1, "target", "source")):
        values, counts = np.unique(pairs[:, col], return_counts=True)
        if np.any(counts > 1):
            v = int(values[np.argmax(counts > 1)])
            partners = sorted(int(x) for x in pairs[pairs[:, col] == v, 1 - col])
            raise ValueError(
                f"landmarks: {side} vertex {v} is paired with several {other} vertices "
                f"({', '.join(map(str, partners))}): give one pair per vertex"
            )
    # A pair given twice is used once (it would weigh twice in a fit and count twice in checks).
    first = np.sort(np.unique(lm.astype(np.int64), axis=0, return_index=True)[1])
    return lm[first].astype(np.int64)


def given_map_collapse(p2p_21: np.ndarray, n_source: int, n_target: int) -> str | None:
    """Why a map given by the caller is doubtful: it collapses (:data:`GIVEN_MAP_COLLAPSE`)."""
    hit = int(np.unique(p2p_21).size)
    if hit >= GIVEN_MAP_COLLAPSE * min(n_source, n_target):
        return None
    return (
        f"the map collapses: only {hit} distinct source vertices for {n_target} target "
        "vertices (a map of other shapes, or a broken one?): the result is a few flat values"
    )


def check_match_options(
    *,
    k_fit: Any = FIT_K,
    zoomout_to: Any = ESTIMATION_K,
    zoomout_subsample: Any = None,
    descriptors: Any = "wks",
    w_orient: Any = 1.0,
) -> None:
    """Raise ValueError naming the keyword when an option of a map estimation is invalid.

    Cheap: callers run it before any eigensolve (a trial's ``w_orient="1"`` failed deep in
    NumPy, ``zoomout_subsample=-5`` with "math domain error").
    """
    for name, value in (("k_fit", k_fit), ("zoomout_to", zoomout_to)):
        if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < 1:
            raise ValueError(f"{name} must be an integer >= 1; got {value!r}")
    if zoomout_to < k_fit:
        raise ValueError(
            f"zoomout_to ({zoomout_to}) must be >= k_fit ({k_fit}): ZoomOut refines the fitted "
            "map to more eigenfunctions"
        )
    if zoomout_subsample is not None and (
        isinstance(zoomout_subsample, bool)
        or not isinstance(zoomout_subsample, int | np.integer)
        or zoomout_subsample < 2
    ):
        raise ValueError(
            f"zoomout_subsample must be None or an integer >= 2; got {zoomout_subsample!r}"
        )
    if descriptors not in ("wks", "hks"):
        raise ValueError(f"descriptors must be 'wks' or 'hks'; got {descriptors!r}")
    if (
        isinstance(w_orient, bool)
        or not isinstance(w_orient, int | float | np.integer | np.floating)
        or not (math.isfinite(w_orient) and w_orient >= 0)
    ):
        raise ValueError(f"w_orient must be a finite number >= 0; got {w_orient!r}")


def _check_sizes(eig_1: EigenBasis, eig_2: EigenBasis, k_fit: int, zoomout_to: int) -> None:
    for name, eig in (("source", eig_1), ("target", eig_2)):
        for what, k in (("the descriptor fit", k_fit), ("ZoomOut", zoomout_to)):
            need = required_k(eig.n_vertices, k)
            if eig.k < need:
                raise ValueError(
                    f"the {name} eigenbasis has {eig.k} eigenfunctions but {what} needs {need}: "
                    f"compute it with eigenbasis(..., k={ESTIMATION_K}) (or pass a smaller "
                    "zoomout_to / k_fit knowingly)"
                )


def match_eigenbases(
    eig_1: EigenBasis,
    eig_2: EigenBasis,
    *,
    landmarks: Any = None,
    k_fit: int = FIT_K,
    zoomout_to: int = ESTIMATION_K,
    zoomout_subsample: int | None = 2000,
    descriptors: str = "wks",
    w_orient: float = 1.0,
    progress: Callable[[str, float], None] | None = None,
) -> Correspondence:
    """Estimate a map between two shapes from their eigenbases: fit, ZoomOut, point map.

    Parameters
    ----------
    eig_1, eig_2 : EigenBasis
        Source and target eigenbases, with at least ``zoomout_to`` non-constant
        eigenfunctions each (fewer only when a shape has fewer vertices): a smaller basis is
        an error, never a silent downgrade.
    landmarks : (p, 2) array_like of int, optional
        Known (source vertex, target vertex) pairs.
    k_fit : int, default 29
        Size of the map fitted to the descriptors (the paper's K = 30). A second fit of
        :data:`WIDE_FIT_K` (39) functions, when ``zoomout_to`` exceeds it, is a further start;
        ``options["k_fit"]`` of the result says which fit the kept map came from.
    zoomout_to : int, default 99
        Size ZoomOut refines the map to.
    zoomout_subsample : int or None, default 2000
        ZoomOut's iterations run on this many farthest-point samples of each shape; the
        final point map is computed at full resolution.
    descriptors : {"wks", "hks"}, default "wks"
        Descriptor family.
    w_orient : float, default 1.0
        Weight of the orientation-preserving term (0 disables it).
    progress : callable, optional
        Called as ``progress(stage, fraction_done)`` at each stage.

    Returns
    -------
    Correspondence
        ``p2p_21``, the functional map, the options and the quality report. A suspect map is
        warned about (:class:`o3d_ofp.OFPWarning`), naming the likely causes and the fix.

    Notes
    -----
    The estimation runs on each shape's cleaned surface (:func:`on_cleaned_vertices`: one
    vertex per welded group, e.g. the copies of an OBJ's vertices along its UV seams) and the
    point map is carried back to the input vertices; the quality report's counts (coverage)
    are those of the surfaces.

    References
    ----------
    .. [1] S. Melzi et al., "ZoomOut: Spectral Upsampling for Efficient Shape Correspondence",
       ACM TOG 38(6), 2019.
    .. [2] J. Ren et al., "Continuous and Orientation-preserving Correspondences via
       Functional Maps", ACM TOG 37(6), 2018.
    """
    check_eigenbasis(eig_1, "eig_1")
    check_eigenbasis(eig_2, "eig_2")
    _check_sizes(eig_1, eig_2, k_fit, zoomout_to)
    landmarks = check_landmarks(landmarks, eig_1.n_vertices, eig_2.n_vertices)
    return on_surfaces(
        eig_1,
        eig_2,
        _match_surfaces,
        landmarks=landmarks,
        k_fit=k_fit,
        zoomout_to=zoomout_to,
        zoomout_subsample=zoomout_subsample,
        descriptors=descriptors,
        w_orient=w_orient,
        progress=progress,
    )


def on_surfaces(
    eig_1: EigenBasis,
    eig_2: EigenBasis,
    match: Callable[..., Correspondence],
    *,
    landmarks: np.ndarray | None,
    **options: Any,
) -> Correspondence:
    """Run an estimation on the shapes' cleaned surfaces; its map back on the input vertices.

    ``match(s1, s2, landmarks=..., **options)`` runs between :func:`on_cleaned_vertices` of
    both bases (one vertex per welded group: an OBJ's copies along its UV seams, an STL's
    triangle soup), the landmarks carried to the surfaces' vertices; the point map is returned
    on the input vertices, with the input's landmarks and signatures.

    Parameters
    ----------
    eig_1, eig_2 : EigenBasis
        Source and target bases (checked by the caller).
    match : callable
        The estimation between two bases.
    landmarks : (p, 2) ndarray of int or None
        Checked (source, target) pairs in the input numbering.
    **options
        Passed to ``match``.

    Returns
    -------
    Correspondence
    """
    s1, rep_1 = on_cleaned_vertices(eig_1)
    s2, rep_2 = on_cleaned_vertices(eig_2)
    if rep_1 is None and rep_2 is None:
        corr = match(eig_1, eig_2, landmarks=landmarks, **options)
        return with_signatures(corr, eig_1.vertices, eig_2.vertices)
    on_surface = landmarks
    if landmarks is not None:  # each input vertex stands for its surface vertex
        on_surface = landmarks.copy()
        for col, eig, rep in ((0, eig_1, rep_1), (1, eig_2, rep_2)):
            if rep is not None:
                on_surface[:, col] = eig.cleaning.index[landmarks[:, col]]
    logger.info(
        "match: on the cleaned surfaces (%d and %d of %d and %d vertices)",
        s1.n_vertices,
        s2.n_vertices,
        eig_1.n_vertices,
        eig_2.n_vertices,
    )
    corr = match(s1, s2, landmarks=on_surface, **options)
    p2p = corr.p2p_21 if rep_1 is None else rep_1[corr.p2p_21]
    if rep_2 is not None:
        p2p = p2p[eig_2.cleaning.index]
    corr = dataclasses.replace(
        corr,
        p2p_21=p2p,
        n_source=eig_1.n_vertices,
        options={
            **corr.options,
            "landmarks": None if landmarks is None else landmarks.tolist(),
        },
    )
    return with_signatures(corr, eig_1.vertices, eig_2.vertices)


def _match_surfaces(
    eig_1: EigenBasis,
    eig_2: EigenBasis,
    *,
    landmarks: np.ndarray | None,
    k_fit: int,
    zoomout_to: int,
    zoomout_subsample: int | None,
    descriptors: str,
    w_orient: float,
    progress: Callable[[str, float], None] | None,
) -> Correspondence:
    """:func:`match_eigenbases` on two bases without copies of vertices (checked inputs)."""
    k_fit = min(k_fit, eig_1.k, eig_2.k)
    final = min(zoomout_to, eig_1.k, eig_2.k)
    report = progress or StageProgress(logger, "match")
    u1, u2 = unit_area(eig_1), unit_area(eig_2)
    # Four starts: the descriptor-commutativity term helps on some pairs (FAUST: 0.026 with it,
    # 0.16 without) and hurts on others (TOSCA centaurs: 0.094 with, 0.015 without), and so
    # does the larger fit (WIDE_FIT_K); each is refined by ZoomOut and the map whose spectral
    # embeddings align best is kept.
    wide = min(WIDE_FIT_K, final)
    sizes = [k_fit, wide] if wide > k_fit else [k_fit]
    logger.debug(
        "match: descriptor fits (sizes %s, commutativity weights %s)", sizes, DCOMM_WEIGHTS
    )
    report("descriptor fit", 0.0)
    # The farthest-point samples of both shapes, drawn once for every ZoomOut below and the
    # comparison of the starts (they depend on the shapes only), while the fits run: the
    # sampling is mostly Python steps, the fits mostly BLAS (27.5k vertices: 0.17 s of sampling).
    n_samples = zoomout_subsample or 2000
    with ThreadPoolExecutor(max_workers=1) as sampler:
        sampled = sampler.submit(
            lambda: tuple(farthest_points(u.vertices, n_samples) for u in (u1, u2))
        )
        starts = estimate_fmaps(
            u1,
            u2,
            sizes=sizes,
            w_dcomm=DCOMM_WEIGHTS,
            landmarks=landmarks,
            descriptors=descriptors,
            w_orient=w_orient,
        )
        samples = sampled.result()
    select = min(final, max(sizes[-1], SELECT_K))
    zoom_samples = (
        samples
        if zoomout_subsample is not None
        and zoomout_subsample < min(eig_1.n_vertices, eig_2.n_vertices)
        else None
    )

    def refine(i: int, k: int, C: np.ndarray) -> tuple[np.ndarray, float]:
        if select > k:
            logger.debug("match: ZoomOut %d -> %d (start %d)", k, select, i + 1)
            C = zoomout_refine(
                C, u1, u2, k_final=select, subsample=zoomout_subsample, samples=zoom_samples
            )
        residual = alignment_residual(C, u1, u2, sample_indices=samples)
        logger.debug("match: start %d alignment residual %.4g", i + 1, residual)
        return C, residual

    # The starts are independent and their ZoomOut runs its BLAS on one thread: two at a time,
    # one per core (FAUST 27.5k vertices: the match 2.1 s instead of 2.7 s, with the
    # threads of estimate_fmaps).
    with ThreadPoolExecutor(max_workers=2) as pool:
        jobs = [pool.submit(refine, i, k, C) for i, (k, _, C) in enumerate(starts)]
        for done, _ in enumerate(as_completed(jobs)):
            report(f"ZoomOut {done + 1}/{len(jobs)}", 0.1 + 0.5 * done / len(jobs))
        refined = [job.result() for job in jobs]
    best: tuple[float, np.ndarray, int, float] | None = None
    for (C, residual), (k, w_dcomm, _) in zip(refined, starts, strict=True):
        if best is None or residual < best[0]:
            best = (residual, C, k, w_dcomm)
    assert best is not None
    _, C, k_fit, w_dcomm = best
    if final > select:  # only the best start goes on
        logger.debug("match: ZoomOut %d -> %d", select, final)
        report("ZoomOut", 0.6)
        C = zoomout_refine(
            C, u1, u2, k_final=final, subsample=zoomout_subsample, samples=zoom_samples
        )
    logger.debug("match: point map at full resolution (%d target vertices)", eig_2.n_vertices)
    report("point map", 0.7)

    def point_map(C: np.ndarray) -> np.ndarray:
        if eig_1.n_vertices * eig_2.n_vertices > DENSE_PAIRS:
            return local_p2p_from_fmap(C, u1, u2)  # exact, without the quadratic scan
        return p2p_from_fmap(C, u1, u2)

    p2p = point_map(C)

    def judged(C: np.ndarray, p2p: np.ndarray) -> tuple[np.ndarray, MapQuality]:
        fmap_12 = C * math.sqrt(eig_2.area / eig_1.area)  # back to the shapes' own areas
        landmarks_given = landmarks is not None
        return fmap_12, map_quality(p2p, eig_1, eig_2, fmap_12, landmarks_given=landmarks_given)

    report("quality", 0.75)
    fmap_12, quality = judged(C, p2p)
    # Only a map that passes its checks is repaired: a suspect one (shapes of other kinds, a
    # collapse) is said as it is, not re-estimated into one that looks right (measured: a blob
    # onto a sphere, flagged, came out ok re-estimated).
    if not quality.suspect and eig_1.faces is not None and eig_2.faces is not None:
        if eig_1.n_vertices * eig_2.n_vertices <= REPAIR_MAX_PAIRS:
            report("geodesic check", 0.8)
            repaired, disagreement = geodesic_repair(
                p2p, u1, u2, k_fit=k_fit, k_final=final, subsample=zoomout_subsample,
                samples=zoom_samples, share=REPAIR_SHARE, checked=samples[1],
            )  # fmt: skip
            redo = f" (> {REPAIR_SHARE:g}): re-estimated from the geodesic map"
            logger.debug(
                "match: the map and its geodesic refinement disagree on %.3f of the target's "
                "area%s",
                disagreement,
                redo if REPAIR_SHARE < disagreement <= REPAIR_MAX_SHARE else "",
            )
            if disagreement > REPAIR_MAX_SHARE:
                reasons = (
                    f"the map and its geodesic refinement disagree on {disagreement:.2f} of the "
                    f"target's area (> {REPAIR_MAX_SHARE:g}): the map is wrong on most of it, "
                    "or the shapes are not near-isometric",
                    "likely causes: shapes of other kinds (a spectral map needs near-isometric "
                    "shapes: check the result by eye), or descriptors that cannot tell the parts "
                    "apart; fix: give a few known vertex pairs (landmarks=[[source, target], "
                    "...] / --landmarks 12:40,500:611)",
                )
                quality = dataclasses.replace(quality, suspect=True, reasons=reasons)
            elif repaired is not None:
                C = repaired
                p2p = point_map(C)
                fmap_12, quality = judged(C, p2p)
                note = (
                    f"the spectral map disagreed with its geodesic refinement on "
                    f"{disagreement:.3f} of the target's area (a region sent to the wrong "
                    "place): re-estimated from the geodesic map"
                )
                quality = dataclasses.replace(quality, notes=(*quality.notes, note))
        else:
            logger.info(
                "match: no geodesic check (%d x %d vertices: its search is quadratic)",
                eig_1.n_vertices,
                eig_2.n_vertices,
            )
    logger.info("match: %s", quality.summary(), extra=QUALITY_RECORD)
    if quality.suspect:
        warn(logger, quality.suspect_message("the estimated map"))
    if (cloud_part := cloud_part_note(eig_1, eig_2, quality.area_ratio)) is not None:
        warn(logger, f"match: {cloud_part}")  # a note, but doubtful: said, suspect or not
    for note in quality.notes:
        if note != cloud_part:  # (said just above)
            logger.info("match: %s", note, extra=QUALITY_RECORD)
    report("done", 1.0)
    options = {
        "landmarks": None if landmarks is None else np.asarray(landmarks).tolist(),
        "k_fit": k_fit,
        "zoomout_to": final,
        "zoomout_subsample": zoomout_subsample,
        "descriptors": descriptors,
        "w_orient": w_orient,
        "w_dcomm": w_dcomm,
    }
    return Correspondence(
        p2p_21=p2p,
        n_source=eig_1.n_vertices,
        fmap_12=fmap_12,
        method="estimate",
        options=options,
        quality=quality,
    )


def uses_dense_path(
    n_vertices_1: int, n_vertices_2: int, meshes: bool, dense_above: int | None = None
) -> bool:
    """Tell whether :func:`match_arrays` matches two shapes on coarse copies (the dense path).

    Parameters
    ----------
    n_vertices_1, n_vertices_2 : int
        Vertices of the source and the target.
    meshes : bool
        Whether both shapes are meshes (point clouds never take the dense path).
    dense_above : int, optional
        The threshold (default :data:`o3d_ofp.workflows.dense.DENSE_VERTICES`).

    Returns
    -------
    bool
    """
    if dense_above is None:
        dense_above = DENSE_VERTICES
    if isinstance(dense_above, bool) or not isinstance(dense_above, (int, np.integer)):
        raise TypeError(f"dense_above must be an int; got {type(dense_above).__name__}")
    return bool(meshes and max(n_vertices_1, n_vertices_2) > dense_above)


def match_arrays(
    vertices_1: np.ndarray,
    faces_1: np.ndarray | None,
    vertices_2: np.ndarray,
    faces_2: np.ndarray | None,
    *,
    components: str = "auto",
    dense_above: int | None = None,
    estimate: Callable[..., Correspondence] | None = None,
    coarse_estimate: Callable[..., Correspondence] | None = None,
    coarse_extend: Callable[..., tuple[np.ndarray, Correspondence]] | None = None,
    **options: Any,
) -> Correspondence:
    """Estimate a map between two shapes given as arrays: eigenbases, then :func:`match_eigenbases`.

    Two meshes of which one has more than ``dense_above`` vertices are matched on coarse
    copies and the map extended to every vertex (:func:`o3d_ofp.workflows.dense.match_dense`):
    no full-resolution eigenpair is computed.

    Parameters
    ----------
    vertices_1, faces_1 : (n1, 3) ndarray, (m1, 3) ndarray or None
        Source shape (faces None: a point cloud).
    vertices_2, faces_2 : (n2, 3) ndarray, (m2, 3) ndarray or None
        Target shape.
    components : {"auto", "largest", "error"}, default "auto"
        Policy for several connected components (see :func:`o3d_ofp.eigenbasis`).
    dense_above : int, optional
        Vertex count above which two meshes take the dense path (default
        :data:`o3d_ofp.workflows.dense.DENSE_VERTICES`, 50000; 0 always, a huge value never).
        ``coarse_vertices=`` (in ``options``) sets the coarse meshes' size there (default
        :data:`o3d_ofp.workflows.dense.COARSE_VERTICES`), and ``coarse_source=`` (a
        :class:`o3d_ofp.workflows.dense.CoarseShape` of the source, from
        :func:`o3d_ofp.workflows.dense.coarse_shape`) spares the source's reduction when a
        source is matched onto several targets.
    estimate : callable, optional
        ``estimate(eig_1, eig_2, **options)`` returning the Correspondence between the
        eigenbases (default :func:`match_eigenbases`; the partial match passes its own).
    coarse_estimate : callable, optional
        The same between the coarse copies of the dense path, its ``fmap_12`` in the terms
        :func:`o3d_ofp.core.multiscale.extend_p2p` reads (default ``estimate``).
    coarse_extend : callable, optional
        How the dense path extends the coarse map to every vertex (``extend`` of
        :func:`o3d_ofp.workflows.dense.match_dense`; default: ``extend_p2p`` of its
        ``fmap_12``).
    **options
        Keyword options of ``estimate`` (``landmarks``, ``k_fit``, ``zoomout_to``, ...).

    Returns
    -------
    Correspondence
    """
    landmarks = check_landmarks(
        options.get("landmarks"), vertices_1.shape[0], vertices_2.shape[0]
    )  # before any eigensolve
    estimate = match_eigenbases if estimate is None else estimate
    coarse_vertices = options.pop("coarse_vertices", COARSE_VERTICES)
    coarse_source = options.pop("coarse_source", None)
    n_max = max(vertices_1.shape[0], vertices_2.shape[0])
    meshes = faces_1 is not None and faces_2 is not None
    if uses_dense_path(vertices_1.shape[0], vertices_2.shape[0], meshes, dense_above):
        logger.info("match: %d vertices: dense path (coarse meshes)", n_max)
        corr = match_dense(
            vertices_1,
            faces_1,
            vertices_2,
            faces_2,
            estimate=estimate if coarse_estimate is None else coarse_estimate,
            k=options.get("zoomout_to", ESTIMATION_K),
            coarse_vertices=coarse_vertices,
            components=components,
            coarse_1=coarse_source,
            extend=coarse_extend,
            **{**options, "landmarks": landmarks},
        )
        return with_signatures(corr, vertices_1, vertices_2)  # not the coarse meshes'
    zoomout_to = options.get("zoomout_to", ESTIMATION_K)
    eigs = eigenbases_of(
        [
            (V, F, required_k(V.shape[0], zoomout_to))
            for V, F in ((vertices_1, faces_1), (vertices_2, faces_2))
        ],
        clamp_k=True,
        components=components,
        names=("the source", "the target"),
    )
    return estimate(eigs[0], eigs[1], **{**options, "landmarks": landmarks})
