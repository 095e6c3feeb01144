"""Judging a map without ground truth: the measures, the verdict and its reasons, as data.

:func:`map_quality` judges a full-shape map, :func:`partial_quality` a part matched onto a
whole; both return a :class:`~o3d_ofp.workflows.maps.MapQuality` whose reasons and notes are
:class:`~o3d_ofp.core.wording.Said` (a code, the values, the fixes advised). :func:`say` is
the one place a verdict is logged and warned about.
"""

from __future__ import annotations

import dataclasses
import logging
import math

import numpy as np
from scipy.spatial import cKDTree

from ..core._warnings import warn
from ..core.correspondence import fmap_from_p2p
from ..core.fmap import Anchors, unit_area
from ..core.geometry import (
    POINT_NEIGHBOURS,
    outward_sign,
    point_neighbours,
    point_normals,
    tangent_frames,
    turned_fraction,
    units_change,
    vertex_normals,
)
from ..core.partial import boundary_length, geodesic_distortion, map_stretch, rescaled
from ..core.spectrum import EigenBasis
from ..core.wording import Said
from .maps import MapQuality

__all__ = [
    "AREA_RATIO_NOTE",
    "MAX_DISTORTION",
    "MAX_INCONSISTENCY",
    "MAX_JUMP",
    "MAX_MEAN_DISTANCE",
    "MAX_ORTHOGONALITY",
    "MAX_REVERSED",
    "MAX_STRETCH",
    "MIN_COVERAGE",
    "PARTIAL_MAX_AREA_RATIO",
    "QUALITY_RECORD",
    "SMALL_PART",
    "flipped_what",
    "landmark_offsets",
    "landmarks_advice",
    "landmarks_apart",
    "landmarks_extent",
    "landmarks_kept",
    "landmarks_mirrored",
    "map_quality",
    "partial_quality",
    "reversed_fraction",
    "say",
    "small_part_note",
]

logger = logging.getLogger(__name__)

#: ``extra=`` of the log records that give a map's quality report (its summary and notes): a
#: front end that prints the report itself (the command line) leaves these records out.
QUALITY_RECORD = {"quality_report": True}

#: A map is suspect when fewer distinct source vertices than this fraction of the smaller
#: shape's vertex count are hit. Measured on correct maps between the shared data's pairs:
#: 0.45-0.65 (a nearest-neighbour map is never a bijection); a collapsed map: < 0.01.
MIN_COVERAGE = 0.2
#: ... or when the unit-area functional map is this far from orthogonal (‖CᵀC − I‖_F / √k):
#: the shapes are not near-isometric. Measured (``python scripts/eval_matching.py --all-pairs
#: --variants --unrelated``): the 32 FAUST and FAUST-remeshed pairs 0.11-0.29 (wrong maps
#: with parts swapped included); decimated, subdivided, point-cloud and other-resolution
#: copies of FAUST, TOSCA and the models 0.05-0.37; shapes of other kinds 0.39-0.45; the
#: failed SHREC'19 map 0.43 (its ground truth's own is 0.50: those scans are far from
#: isometric); targets with 0.3 % or 1 % noise 0.44 (wrong maps). A right map between scans
#: as far from isometric as the SHREC'19 pair is flagged too: a spectral map is not to be
#: trusted there without a look or landmarks.
MAX_ORTHOGONALITY = 0.4
#: ... or when the point map and the functional map disagree by this much
#: (‖C − C(p2p)‖_F / ‖C‖_F): measured 0.1-0.35 on correct maps, above 0.6 on failed ones.
MAX_INCONSISTENCY = 0.55
#: ... or when more than this fraction of the target's triangles, carried to the source by the
#: map, are turned over (a reflection there: a left/right symmetry flip). With a point cloud,
#: the fraction of target neighbourhoods where the map is a reflection (the same bound):
#: measured by ``python scripts/eval_cloud.py --estimate``, right maps 0.18-0.28 (errors
#: 0.035-0.095), flipped ones 0.365-0.442 (errors 0.12-0.17).
MAX_REVERSED = 0.35
#: Areas that differ by more than this factor are noted (different units or a partial shape);
#: the estimated map does not depend on the units.
AREA_RATIO_NOTE = 1.5
#: A closest-point map is suspect when the mean closest-point distance exceeds this fraction
#: of the source's bounding-box diagonal: the shapes are not aligned. Measured (closest target
#: vertex -> source surface): a decimated copy of the bunny 2e-7; the paper's detail-transfer
#: pair (models/t1_donut -> t0_donut, aligned, with large bumps) 0.029-0.032; the same shape
#: turned by 90° 0.03-0.26 (bunny 0.06-0.09, FAUST 0.04-0.26); two different shapes normalized
#: to the same box 0.034-0.15. A doubtful spectral map advises closest points below it.
MAX_MEAN_DISTANCE = 0.05
#: Target vertices (evenly strided) whose distance to the source tells whether to advise
#: closest points: the mean is read to two digits.
SAME_PLACE_SAMPLES = 20_000
#: A full-shape map is suspect as a part when the smaller shape has less than
#: 1 / PARTIAL_AREA_RATIO of the larger's area AND its boundary length / sqrt(area) exceeds
#: the larger's by EXTRA_BOUNDARY: area alone cannot tell a part from other units. Correct
#: pairs differ by up to 1.30 in area (FAUST remeshed 002 -> 007); extra boundary of the cuts
#: of scripts/eval_partial.py (50-80 % kept) 1.0-5.8, of the shared data's pairs 0-0.04.
PARTIAL_AREA_RATIO = 1.2
EXTRA_BOUNDARY = 0.4
#: From this area ratio the units surely differ (inches and centimetres: 6.45 in area, times a
#: part's 0.5-0.8): the longest boundary curves are compared (a scan's holes are short), and a
#: larger shape with the longer curve is a part in other units.
UNITS_AREA_RATIO = 3.0
#: With partial=True, a target larger than the source by this factor cannot be a part of it.
PARTIAL_MAX_AREA_RATIO = 1.1

#: A partial map whose geodesic distortion (:func:`o3d_ofp.core.partial.geodesic_distortion`
#: of the final map, before its polish) exceeds this is suspect. Measured on the 8 cuts and 4
#: remeshed cuts of scripts/eval_partial.py and the blob cut of the tests: right final maps
#: (errors 0.017-0.044) 0.029-0.081; wrong ones 0.132-0.344; targets that are no part of the
#: source 0.137-0.249; the true maps of the 8 cuts 0.056-0.096. The starts' distortion (which
#: ranks them) does not separate right from wrong, and the geodesic refinement makes wrong
#: starts look right too: the check holds because one start is refined.
MAX_DISTORTION = 0.115
#: A partial map whose stretch (:func:`o3d_ofp.core.partial.map_stretch`: mapped target edge
#: lengths over their lengths) exceeds this is suspect: torn at the seams of a misplaced
#: region. Measured on the same final maps: right 1.03-1.23, wrong 1.55-1.88.
MAX_STRETCH = 1.4
#: Largest distance (units of sqrt(source area)) a partial map's image may move from a
#: reference and still count as the same place: the geodesic map's (the refinement), the
#: checked map's (the polish, the dense extension) or a landmark's given source vertex.
#: Measured on the 8 cuts of scripts/eval_partial.py: the geodesic map's mean error is
#: 0.04-0.05, the spectral refinement's 0.02 where it does not jump; images differ by more than
#: 0.15 at 0-2 % of the vertices, at 9 % where the spectral refinement sent a region astray.
MAX_JUMP = 0.15
#: A target below this fraction of the source's area is smaller than the parts the partial
#: match was measured on (cuts keeping 0.55-0.8): without spread landmarks its map is suspect,
#: with them it gets a note (:func:`small_part_note`).
SMALL_PART = 0.5

#: The likely causes said after a suspect map's reasons ("far": no near-isometric map; the
#: ``_landmarks`` variant when landmarks were given). Known pairs are advised between shapes of
#: other kinds too: measured (``scripts/eval_nonisometric.py
#: --landmarks 6``, mean geodesic error x100 / sqrt(area)) gorilla -> human 5.9 with 6 spread
#: landmarks against 14.6 without (BCICP's published maps 10.0).
_LIKELY_CAUSES = {
    # "far" causes: {rest}, the part and the aligned copies where they can be (_far_causes)
    "far": Said(
        "likely causes: shapes of other kinds (a spectral map needs near-isometric shapes; "
        "where their parts correspond, as a gorilla's and a person's, a few known vertex pairs "
        "spread over them drive the map ({landmarks}); check the result by eye){rest}", {},
        "causes_far",
    ),
    "far_landmarks": Said(
        "likely causes: shapes of other kinds (a spectral map needs near-isometric shapes; the "
        "landmarks given drive it where the shapes' parts correspond: check the pairs, and "
        "spread more over the shapes ({landmarks_check}); check the result by eye){rest}", {},
        "causes_far",
    ),
    "landmarks": Said(
        "likely causes: a wrong landmark pair (a pair swapped or on the mirrored side turns the "
        "map over), very different shapes, or a partial shape; fix: check the landmarks given "
        "({landmarks_check})", {}, "causes_landmarks",
    ),
    "other": Said(
        "likely causes: very different shapes, a partial shape, a symmetry flip, or "
        "descriptors that cannot tell the parts apart; fix: give a few known vertex pairs "
        "({landmarks})", {}, "causes",
    ),
}  # fmt: skip


def _far_causes(said: Said, eig_1: EigenBasis, eig_2: EigenBasis, landmarks_given: bool) -> Said:
    """Return the "far" causes with the ones these shapes can have.

    A part of the other shape is said only when either shape has a boundary or is a point
    cloud (whose boundary is not measured): a cut or a one-sided scan leaves one, and two
    closed meshes are no part of each other (the 22 ``bcicp_dev`` pairs, gorillas and people
    among them, are all closed). Aligned copies (a closest-point map) are said only without
    landmarks and when the target lies where the source is: the mean distance from its
    vertices to the nearest source vertex within :data:`MAX_MEAN_DISTANCE` of the source's
    diagonal, the closest-point map's own bound (through vertices it is at least the surface
    distance that bound reads). TOSCA's gorilla -> human pairs, in one frame: 0.043-0.22.
    """

    def open_or_cloud(eig: EigenBasis) -> bool:
        return eig.faces is None or boundary_length(eig.vertices, eig.faces) > 0.0

    rest = Said(", or a noisy scan")
    if open_or_cloud(eig_1) or open_or_cloud(eig_2):
        rest = Said(", a noisy scan, or a part of the other shape ({part})",
                    {"part": _part_fix(eig_1, eig_2)})  # fmt: skip
    if not landmarks_given:
        V1, V2 = eig_1.vertices, eig_2.vertices
        step = max(1, len(V2) // SAME_PLACE_SAMPLES)
        diagonal = float(np.linalg.norm(V1.max(axis=0) - V1.min(axis=0)))
        mean = float(cKDTree(V1).query(V2[::step])[0].mean())
        if mean <= MAX_MEAN_DISTANCE * diagonal:
            rest = Said(rest.template + "; aligned copies of one shape match by closest points "
                        "({closest})", rest.values)  # fmt: skip
    return said.replace(rest=rest)


def _part_fix(eig_1: EigenBasis, eig_2: EigenBasis) -> Said:
    """Return the fix of a part: the partial match, or the mesh a cloud came from.

    The partial match refuses clouds; no advice to mesh one (see ``_notes``).
    """
    clouds = [name for name, eig in (("source", eig_1), ("target", eig_2)) if eig.faces is None]
    if not clouds:
        return Said("{partial}")
    which = (f"the mesh the {clouds[0]} cloud came from, when there is one" if len(clouds) == 1
             else "the meshes the two clouds came from, when there are")  # fmt: skip
    return Said("a partial match needs meshes: match {which}", {"which": which})


def flipped_what(eig_1: EigenBasis, eig_2: EigenBasis) -> str:
    """Return what a map's reversed fraction counts (``MapQuality.reversed_of``).

    ``"triangles"`` between meshes, ``"neighbourhoods"`` (the target's) where a shape is a cloud.
    """
    meshes = eig_1.faces is not None and eig_2.faces is not None
    return "triangles" if meshes else "neighbourhoods"


def map_quality(
    p2p_21: np.ndarray, eig_1: EigenBasis, eig_2: EigenBasis, fmap_12: np.ndarray | None = None,
    *, partial: bool = False, overlap: float | None = None, landmarks_given: bool = False,
) -> MapQuality:  # fmt: skip
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
    ratio = hit / min(n1, n2)
    area_ratio = eig_2.area / eig_1.area
    ortho = incons = math.nan
    if fmap_12 is not None:
        C = np.asarray(fmap_12) * math.sqrt(eig_1.area / eig_2.area)  # between unit-area bases
        k = min(C.shape) - 1
        C = C[: k + 1, : k + 1]
        ortho = float(np.linalg.norm(C.T @ C - np.eye(k + 1)) / math.sqrt(k + 1))
        incons = _inconsistency(C, p2p_21, unit_area(eig_1), unit_area(eig_2))
    turned = reversed_fraction(p2p_21, eig_1, eig_2)
    what = flipped_what(eig_1, eig_2)
    clouds = what == "neighbourhoods"
    far = ortho > MAX_ORTHOGONALITY  # no near-isometric map: no "right map" to be mirrored
    reasons = []
    if turned > MAX_REVERSED:
        reasons.append(Said(
            "the map turns {percent:.0f} % of the target's {what} over" + ("" if far else
            ": a mirror image of the right map (left/right symmetry flip), or a map too rough "
            "to keep the triangles' orientation (a very coarse or noisy shape)"),
            {"percent": 100 * turned, "what": what}, "reversed",
        ))  # fmt: skip
    if ratio < MIN_COVERAGE:
        reasons.append(Said(
            "the map collapses: only {hit} distinct source vertices are hit by {n} target "
            "vertices", {"hit": int(hit), "n": n2}, "collapse",
        ))  # fmt: skip
    if far:
        reasons.append(Said(
            "the functional map is far from an isometry (orthogonality {ortho:.3f} > {bound:g}): "
            "the shapes are not near-isometric (shapes of other kinds, a noisy scan, or a part "
            "of the other shape)", {"ortho": ortho, "bound": MAX_ORTHOGONALITY}, "not_isometric",
        ))  # fmt: skip
    reasons += _inconsistent(incons) + _area_reasons(eig_1, eig_2, area_ratio, partial)
    if far:
        cause = "far_landmarks" if landmarks_given else "far"
    else:
        cause = "landmarks" if landmarks_given else "other"
    said = _LIKELY_CAUSES[cause]
    said = _far_causes(said, eig_1, eig_2, landmarks_given) if far else said
    reasons += [said] if reasons else []
    return MapQuality(
        coverage=float(hit / n1), coverage_ratio=float(ratio), orthogonality=ortho,
        inconsistency=incons, reversed_fraction=turned, area_ratio=float(area_ratio),
        suspect=bool(reasons), reasons=tuple(reasons),
        notes=tuple(_notes(eig_1, eig_2, area_ratio, partial, clouds)),
        overlap=None if overlap is None else float(overlap),
        reversed_of=what,
    )  # fmt: skip


def _inconsistency(C: np.ndarray, p2p_21: np.ndarray, u1: EigenBasis, u2: EigenBasis) -> float:
    """‖C − C(p2p)‖_F / ‖C‖_F: how far the point map's functional map (bases u1, u2) is from C."""
    C_p2p = fmap_from_p2p(p2p_21, u1, u2, k1=C.shape[1] - 1, k2=C.shape[0] - 1)
    return float(np.linalg.norm(C - C_p2p) / max(np.linalg.norm(C), 1e-300))


def _inconsistent(incons: float) -> list[Said]:
    """Return why a point map disagrees with its functional map (above MAX_INCONSISTENCY)."""
    if not incons > MAX_INCONSISTENCY:
        return []
    return [Said("the point map disagrees with the functional map (inconsistency {incons:.2f})",
                 {"incons": incons}, "inconsistent")]  # fmt: skip


def _notes(
    eig_1: EigenBasis, eig_2: EigenBasis, area_ratio: float, partial: bool, clouds: bool
) -> list[Said]:
    """Remarks on a map that do not make it suspect: point clouds, very different areas."""
    notes = []
    if clouds:
        # No advice to mesh the cloud: Open3D's Poisson reconstruction of FAUST 087's and
        # centaur4's clouds (depth 7-8) gave maps of 0.11-0.20 and 0.025-0.46
        # (``python scripts/eval_cloud.py --poisson``). The errors quoted:
        # ``python scripts/eval_cloud.py --estimate`` (docs/benchmarks.md, point clouds).
        notes.append(Said(
            "a point cloud has no faces: the flip check estimates its normals from the points "
            "(normals the cloud carries are not read; the check is less sure than on meshes) "
            "and its Laplacian can join parts that touch (measured on FAUST 093 -> 087: error "
            "0.066 with the target as points, 0.145 with both, against 0.013 for the meshes; "
            "TOSCA centaur2 -> 4: 0.130 and 0.045, against 0.015); "
            "match the mesh the cloud was made from when there is one, or give a few landmarks, "
            "and check the result", {}, "cloud",
        ))  # fmt: skip
    cloud_part = None if partial else cloud_part_note(eig_1, eig_2, area_ratio)
    if cloud_part is not None:
        notes.append(cloud_part)
    elif not partial and not (1 / AREA_RATIO_NOTE <= area_ratio <= AREA_RATIO_NOTE):
        # Sizes a power of ten apart (units_change, the areas then within AREA_RATIO_NOTE):
        # the factor that gives the target the source's units, for results read in one set
        # of units (transferred coordinates).
        found = units_change(math.sqrt(area_ratio))
        rescale, values = "", {"ratio": area_ratio}
        scaled = math.nan if found is None else area_ratio * found[0] ** 2
        if 1 / AREA_RATIO_NOTE <= scaled <= AREA_RATIO_NOTE:
            rescale = ("; if the target is in other units{change}, {target_scale} gives it the "
                       "source's")  # fmt: skip
            values |= {"factor": found[0], "change": f" ({found[1]})" if found[1] else ""}
        notes.append(Said(
            "the target's area is {ratio:.3g} times the source's (different units? a partial "
            "shape?); the estimated map does not depend on the units" + rescale, values,
            "area_ratio",
        ))  # fmt: skip
    return notes


def _area_reasons(
    eig_1: EigenBasis, eig_2: EigenBasis, area_ratio: float, partial: bool
) -> list[Said]:
    """Why the areas make a map doubtful: a part matched as a whole, or a partial map onto less."""
    if partial:
        if area_ratio <= PARTIAL_MAX_AREA_RATIO:
            return []
        return [Said(
            "{partial} but the target's area is {ratio:.3g} times the source's: it cannot be a "
            "part of the source; fix: make the whole shape the source (swap them) and give both "
            "in the same units (rescale)", {"ratio": area_ratio}, "part_larger",
        )]  # fmt: skip
    factor = max(area_ratio, 1 / area_ratio)
    if factor <= PARTIAL_AREA_RATIO:
        return []
    small, large = (eig_2, eig_1) if area_ratio < 1 else (eig_1, eig_2)
    # Where the units may be the same, the total boundary; where they surely differ, the
    # longest boundary curve: a whole scan with holes in other units is no part, and a cut
    # leaves a long curve (0.52-4.0 per sqrt(area) on the cuts of scripts/eval_partial.py).
    longest = factor >= UNITS_AREA_RATIO

    def boundary(eig: EigenBasis) -> float:
        return boundary_length(eig.vertices, eig.faces, longest=longest) / math.sqrt(eig.area)

    extra = boundary(small) - boundary(large)
    swap = " (swap source and target)"
    if extra > EXTRA_BOUNDARY:
        part = "target" if area_ratio < 1 else "source"
        return [Said(
            "the {part} looks like a part of the other shape ({share:.2g} of its area, "
            "{extra:.2f} more boundary per sqrt(area)): a full-shape map cannot match a part; "
            "fix: {partial} with the whole shape as the source{swap}, in the same units "
            "(rescale first if they differ)",
            {"part": part, "share": 1 / factor, "extra": extra,
             "swap": swap if part == "source" else ""}, "looks_partial",
        )]  # fmt: skip
    if longest and -extra > EXTRA_BOUNDARY:  # the larger has the longer cut: other units
        part = "target" if area_ratio > 1 else "source"
        return [Said(
            "the {part} looks like a part of the other shape in other units ({factor:.3g} times "
            "its area, a boundary curve {extra:.2f} longer per sqrt(area)): a full-shape map "
            "cannot match a part; fix: rescale the part to the whole shape's units, then "
            "{partial} with the whole shape as the source{swap}",
            {"part": part, "factor": factor, "extra": -extra,
             "swap": swap if part == "source" else ""}, "looks_partial_units",
        )]  # fmt: skip
    return []  # a scaled shape (other units) keeps its boundary: its map is right


def cloud_part_note(eig_1: EigenBasis, eig_2: EigenBasis, area_ratio: float) -> Said | None:
    """Say that a cloud of a smaller area may be a part, which a full-shape map cannot match.

    A point cloud's boundary is not measured, so a cloud that is a part of the other shape is
    not told from another body. None unless either shape is a point cloud and the areas
    differ by a factor between :data:`PARTIAL_AREA_RATIO` and :data:`UNITS_AREA_RATIO`
    (beyond: other units, whose map is right).
    """
    if eig_1.faces is not None and eig_2.faces is not None:
        return None
    if not PARTIAL_AREA_RATIO < max(area_ratio, 1 / area_ratio) < UNITS_AREA_RATIO:
        return None
    return Said(
        "the target's area is {ratio:.3g} times the source's and a point cloud's boundary is "
        "not measured: if the {small} is a part of the other shape (a one-sided scan, a cut), "
        "a full-shape map cannot match it (fix: mesh both and match with {partial}, the whole "
        "shape as the source, in the same units); if they are two whole shapes, check the "
        "result", {"ratio": area_ratio, "small": "target" if area_ratio < 1 else "source"},
        "cloud_part",
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


def reversed_fraction(p2p_21: np.ndarray, eig_1: EigenBasis, eig_2: EigenBasis) -> float:
    """Fraction of target triangles (clouds: neighbourhoods) whose image is turned over."""
    if eig_1.faces is None or eig_2.faces is None:
        return _reversed_neighbourhoods(p2p_21, eig_1, eig_2)
    return turned_fraction(p2p_21, eig_1.vertices, _outward_normals(eig_1), eig_2.vertices,
                           eig_2.faces)  # fmt: skip


def _reversed_neighbourhoods(p2p_21: np.ndarray, eig_1: EigenBasis, eig_2: EigenBasis) -> float:
    """Fraction of target points where the map, fitted on their neighbourhood, is a reflection.

    At each target point, the linear map ``A`` (2 x 2) that best carries its
    :data:`POINT_NEIGHBOURS` nearest points (tangent coordinates in the frame of its outward
    normal) to their images (tangent coordinates at the image point, in the frame of the
    source's outward normal there) is fitted by least squares; ``det A < 0`` is a local mirror
    image, the cloud's analogue of a turned triangle. The estimated normals' sign errors add to
    it: measured with the true maps, FAUST 093 -> 087 and TOSCA centaur2 -> 4 with the target
    as the cloud of its vertices 0.071 / 0.155 (their meshes' normals: 0.018 / 0.011); the same
    maps onto the mirror image of the target 0.93 / 0.85. Neighbourhoods whose image is
    (nearly) one point are not counted.
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


def partial_quality(
    p2p_21: np.ndarray, eig_1: EigenBasis, eig_2: EigenBasis, fmap_12: np.ndarray, *,
    overlap: float, distortion: float | None = None, refinement_turned: float | None = None,
    landmarks: bool = False, landmarks_spread: bool = True,
) -> MapQuality:  # fmt: skip
    """Quality report of a partial map (target a part of the source, same units).

    The measures of :func:`map_quality`, except that the map is a restriction, not an
    isometry: ``orthogonality`` is ``‖C Cᵀ − I‖_F / √(k2+1)`` (its rows are orthonormal, its
    columns are not) and ``inconsistency`` compares C with the map of the point map, both
    between the bases in the source's units.

    Parameters
    ----------
    p2p_21 : (n2,) ndarray of int
    eig_1, eig_2 : EigenBasis
        Source and target eigenbases (their own units).
    fmap_12 : (k2+1, k1+1) ndarray
        The restriction map (the same in own units as in the source's units).
    overlap : float
        Estimated fraction of the source's area covered by the target.
    distortion : float, optional
        :func:`o3d_ofp.core.partial.geodesic_distortion` of ``p2p_21``, if already computed.
    refinement_turned : float, optional
        When ``p2p_21`` is a start kept because its geodesic refinement turned this fraction
        of the triangles over (above ``MAX_REVERSED``): the map is then suspect.
    landmarks : bool, default False
        Whether the map was fitted to landmarks: the advice then asks for more of them.
    landmarks_spread : bool, default True
        Whether those landmarks are spread (:func:`landmarks_extent` at least
        :data:`MAX_JUMP`): clustered ones do not lift the small-part flag.

    Returns
    -------
    MapQuality
        Suspect, besides the reasons of ``map_quality``, when the geodesic distortion exceeds
        :data:`MAX_DISTORTION`, the stretch :data:`MAX_STRETCH`, when its refinement turned it
        over (``refinement_turned``), when the point map disagrees with the restriction map
        (its orthogonality is reported, not judged: right partial maps reach 0.44), or when
        the target is below :data:`SMALL_PART` of the source's area without spread
        ``landmarks`` (:func:`small_part_note`; with them that is a note).
    """
    base = map_quality(
        p2p_21, eig_1, eig_2, None, partial=True, overlap=overlap, landmarks_given=landmarks
    )
    u1, u2 = rescaled(eig_1, eig_1.area), rescaled(eig_2, eig_1.area)
    C = np.asarray(fmap_12, dtype=np.float64)
    ortho = float(np.linalg.norm(C @ C.T - np.eye(C.shape[0])) / math.sqrt(C.shape[0]))
    incons = _inconsistency(C, p2p_21, u1, u2)
    if distortion is None:
        distortion = geodesic_distortion(
            p2p_21, eig_1.vertices, eig_1.faces, eig_2.vertices, eig_2.faces
        )
    stretch = map_stretch(p2p_21, eig_1.vertices, eig_2.vertices, eig_2.faces)
    reasons = _partial_reasons(distortion, stretch, refinement_turned) + _inconsistent(incons)
    measured_wrong = bool(reasons)
    small = small_part_note(eig_2.area / eig_1.area, landmarks=landmarks)
    lifted = landmarks and landmarks_spread
    if small is not None and not lifted:  # a reason: too often wrong unseen (small_part_note)
        reasons.append(small)
    if measured_wrong and not base.reasons:
        reasons.append(Said(
            "likely causes: a region of the target, or all of it, sent to the wrong place (a "
            "part with symmetric or featureless regions), a noisy scan (noise inflates its area "
            "and curvature, which the partial match reads), or a target that is not a part of the "
            "source (another shape, or in other units); fix: {advice}; if the scan is visibly "
            "noisy, smooth it lightly first ({smooth}: smoothing a clean part makes the match "
            "worse); rescale a target in other units to the source's",
            {"advice": landmarks_advice(landmarks)}, "causes_partial",
        ))  # fmt: skip
    measured = Said(
        "geodesic distortion {distortion:.3f} (limit for a part matched right: "
        "{max_distortion}), stretch {stretch:.2f} (limit {max_stretch}), inconsistency "
        "{incons:.2f} (limit {max_incons}), restriction map orthogonality {ortho:.2f} (not "
        "judged)",
        {"distortion": distortion, "max_distortion": MAX_DISTORTION, "stretch": stretch,
         "max_stretch": MAX_STRETCH, "incons": incons, "max_incons": MAX_INCONSISTENCY,
         "ortho": ortho}, "partial_measures",
    )  # fmt: skip
    all_reasons = (*reasons, *base.reasons)  # map_quality's advice, if any, stays last
    return dataclasses.replace(
        base, orthogonality=ortho, inconsistency=incons, suspect=bool(all_reasons),
        reasons=all_reasons, distortion=float(distortion), stretch=float(stretch),
        notes=(measured, *base.notes, *([small] if small is not None and lifted else [])),
    )  # fmt: skip


def _partial_reasons(distortion: float, stretch: float, turned: float | None) -> list[Said]:
    """Return why a partial map is measured wrong (its distortion, stretch, refinement).

    The restriction map's orthogonality is reported, not judged: right partial maps reach
    0.44 (above MAX_ORTHOGONALITY); wrong ones are flagged by these measures.
    """
    reasons = []
    if distortion > MAX_DISTORTION:
        reasons.append(Said(
            "the map changes geodesic distances by {percent:.0f} % on average (a part matched "
            "right keeps them within {bound:.0f} %): a region of the target, or all of it "
            "(turned or upside down), is sent to the wrong place, or the target is not a part "
            "of the source",
            {"percent": 100 * distortion, "bound": 100 * MAX_DISTORTION}, "distorted",
        ))  # fmt: skip
    if stretch > MAX_STRETCH:
        reasons.append(Said(
            "the map stretches the target's edges {stretch:.2f} times on average (a part matched "
            "right: at most {bound:.1f}): it tears the target apart where a region is sent to "
            "the wrong place", {"stretch": stretch, "bound": MAX_STRETCH}, "stretched",
        ))  # fmt: skip
    if turned is not None and turned > MAX_REVERSED:
        reasons.append(Said(
            "refining the map by geodesic distances turned {percent:.0f} % of the triangles "
            "over, so it was kept unrefined: a right start stays oriented when refined, this "
            "one is wrong on a large region", {"percent": 100 * turned},
            "refinement_turned",
        ))  # fmt: skip
    return reasons


def landmarks_advice(given: bool, *, where: str = "the part") -> Said:
    """Return the landmarks part of a map's advice: some, or more if some were given.

    ``where``: what the pairs are to be spread over (a partial map's part, both shapes).
    """
    if given:
        return Said("give more known vertex pairs, spread over {where} ({landmarks_check})",
                    {"where": where})  # fmt: skip
    return Said("give a few known vertex pairs ({landmarks})")


def landmarks_extent(landmarks: np.ndarray, vertices_1: np.ndarray) -> float:
    """Return how far apart landmarks lie: the diagonal of their source vertices' bounding box.

    ``landmarks``: (p, 2) source and target vertices; ``vertices_1``: the source's, scaled to
    unit area (the result is then in units of sqrt(source area)). Below :data:`MAX_JUMP` (a
    region) they hold the map near them only.
    """
    corners = vertices_1[landmarks[:, 0]]
    return float(np.linalg.norm(corners.max(axis=0) - corners.min(axis=0)))


def small_part_note(area_ratio: float, *, landmarks: bool = False) -> Said | None:
    """Return the note for a part below :data:`SMALL_PART` of the source's area, else None.

    Without spread landmarks it is a reason (the map is suspect: :func:`partial_quality`);
    with them, a note. Measured (``python scripts/eval_partial.py --robustness``: cuts keeping
    0.45, 0.35 and 0.25 of the area, their largest pieces 0.10-0.45): 5 of 21 maps wrong with
    no measure of the map separating them; one-sided scans of 0.26-0.49 of FAUST 093: wrong,
    some within every other bound. A map that wrong that often is not passed without them.
    """
    if not area_ratio < SMALL_PART:
        return None
    return Said(
        "the target is {ratio:.2f} of the source's area, a smaller part than those the partial "
        "match was measured on (0.55-0.8 of the area): on such parts the map is often wrong "
        "without its measures showing it (plane cuts of 0.10-0.45 of a body: 5 of 21 maps "
        "wrong; one-sided scans of 0.26-0.49: 5 of 5 wrong, 3 within every other bound); check "
        "the result (e.g. a colormap transferred from the source), or {advice}",
        {"ratio": area_ratio, "advice": landmarks_advice(landmarks)}, "small_part",
    )


def landmark_offsets(p2p: np.ndarray, landmarks: np.ndarray, vertices_1: np.ndarray) -> np.ndarray:
    """Return how far a map sends each landmark's target vertex from its given source vertex.

    ``p2p``: the source vertex of every target vertex; ``landmarks``: (p, 2) source and target
    vertices; ``vertices_1``: the source's, in the units of the result ((p,) distances).
    """
    return np.linalg.norm(vertices_1[p2p[landmarks[:, 1]]] - vertices_1[landmarks[:, 0]], axis=1)


def landmarks_kept(
    quality: MapQuality, p2p: np.ndarray, landmarks: np.ndarray, vertices_1: np.ndarray, *,
    subject: str = "the map", spread_note: bool = True,
) -> MapQuality:  # fmt: skip
    """Say how far the map sends the landmarks' target vertices from their given source vertices.

    The landmarks drive the fits and the refinements, which can still move them: measured
    (``python scripts/eval_partial.py --landmarks 0 3 5``, true pairs at extremities and the
    cut), partial maps right without landmarks keep them within 0.017-0.085 of sqrt(source
    area), but maps right by their mean error sent one 0.19-0.26 away: wrong at a pair the
    caller knows; full maps of the 22 pairs of ../shared/data/bcicp_dev with 6 true landmarks
    sent the farthest of the six 0.012-0.065 away (per pair of shapes). Beyond
    :data:`MAX_JUMP` the map is suspect (the reason goes first). The result keeps the pairs
    exactly (:func:`~o3d_ofp.workflows.maps.keeping_landmarks`, after this check).
    ``landmarks``: (p, 2) source and target vertices; ``vertices_1``: the source's, scaled to
    unit area; ``subject`` names the map; ``spread_note``: say when the landmarks are one or
    clustered.
    """
    off = landmark_offsets(p2p, landmarks, vertices_1)
    far = off > MAX_JUMP
    spread = landmarks_extent(landmarks, vertices_1) if spread_note else math.inf
    extra = ""
    if spread_note and len(landmarks) == 1:
        extra = "; one landmark holds the map near it only: give more, spread over the target"
    elif spread < MAX_JUMP:
        extra = (f"; they lie within {spread:.3f} of one another, so they hold the map near "
                 "them only: spread them over the target")  # fmt: skip
    quality = quality.noted(Said(
        "landmarks: {subject} sends their target vertices at most {off:.3f} of sqrt(source "
        "area) from the source vertices given for them (the result keeps the pairs "
        "exactly){extra}",
        {"subject": subject, "off": float(off.max()), "extra": extra}, "landmarks_offset",
    ))  # fmt: skip
    if not far.any():
        return quality
    rows = ", ".join(str(int(i) + 1) for i in np.flatnonzero(far)[:5])
    # Most pairs missed: the fit went where the others lead, and a wrong pair among those
    # would have pulled it there (a trial: the three right pairs of four were named, not the
    # left hand given for the right one, which the map followed)
    followed, near = "", np.flatnonzero(~far)
    if far.sum() > near.size >= 1:
        kept = ", ".join(str(int(i) + 1) for i in near)
        followed = (f"; it follows pair{'s' * int(near.size > 1)} {kept}: when most pairs are "
                    "missed, a wrong pair among those it follows may have pulled it there, so "
                    "check those first")  # fmt: skip
    return quality.flagged(Said(
        "{subject} sends {count} of the {total} landmarks' target vertices more than {bound} of "
        "sqrt(source area) from the source vertices given for them (the farthest {off:.2f} "
        "away; pairs {rows} of the landmarks, counting from 1): it does not follow them; check "
        "those pairs (a wrong pair pulls the fit astray), else the map is wrong near them (the "
        "result keeps the pairs themselves){followed}",
        {"subject": subject, "count": int(far.sum()), "total": int(off.size), "bound": MAX_JUMP,
         "off": float(off.max()), "rows": rows, "followed": followed}, "landmarks_far",
    ))  # fmt: skip


#: Largest difference between two landmarks' distance along the source and along the target
#: (edge paths, each in sqrt(area) of its own shape) before a full match doubts its pairs.
#: Measured on the 22 pairs of ../shared/data/bcicp_dev, with 6 true landmarks at the
#: farthest points of the truth and 30 random sets of 6 each: gorilla -> human at most 0.70,
#: one animal in two poses at most 0.37; one landmark moved to its mirror image (the
#: datasets' ``.sym.vts``) 0.06-1.0 (median 0.19-0.61 a pair: a mirrored pair is seen only
#: when another landmark lies on the side it was moved to); a new user's left hand paired with
#: the right one on FAUST 019 -> 094, beside 5 right pairs, 1.04 (the right pairs 0.15).
LANDMARKS_GAP = 0.8
#: The largest such difference of right pairs measured between different shapes (above).
LANDMARKS_GAP_SEEN = 0.70
#: A flagged pair is named as the likely wrong one when the sum of its distance differences to
#: the other pairs is at least this times any other pair's sum. Measured (scratch, 2026-12-03;
#: the 22 pairs of ../shared/data/bcicp_dev, 11 sets of 6 true landmarks each: the farthest
#: points of the truth and 10 random sets; each landmark in turn moved to its mirror image,
#: ``.sym.vts``): of the 85 sets :data:`LANDMARKS_GAP` flags, the largest sum was the moved
#: pair's on every one at ratios of 1.33 and above (20 sets), another pair's at up to 1.32.
WRONG_PAIR_RATIO = 1.4


def landmarks_apart(quality: MapQuality, anchors: Anchors | None) -> MapQuality:
    """Flag a map whose landmark pairs disagree on how far apart they lie (meshes only).

    Two right pairs lie about as far apart along both shapes, even between a gorilla and a
    human; a pair whose target vertex lies on the mirrored side of another pair's (a left hand
    given for a right one) does not, and the estimate follows it: a new user's trial got a map
    that passed its checks at 0.043 sqrt(area) off, the arms swapped (0.017 with the right
    pairs). ``anchors``: the match's :func:`~o3d_ofp.core.fmap.landmark_anchors`, whose
    distance functions (edge paths over sqrt(area), the first ``p`` columns) are read at the
    landmarks (None, or a point cloud's: nothing to check). See :data:`LANDMARKS_GAP`. Of
    three or more pairs, the one whose differences to the others sum to at least
    :data:`WRONG_PAIR_RATIO` times any other's is named as the likely wrong one (``wrong`` in
    the reason's values, counting from 1; None when no pair stands out).
    """
    if anchors is None or anchors.distances_1 is None or anchors.distances_2 is None:
        return quality
    p = anchors.source.size
    if p < 2:
        return quality
    d1 = anchors.distances_1[anchors.source, :p]
    d2 = anchors.distances_2[anchors.target, :p]
    gap = np.abs(d1 - d2)
    if not gap.max() > LANDMARKS_GAP:
        return quality
    i, j = sorted(np.unravel_index(int(np.argmax(gap)), gap.shape))
    sums = gap.sum(axis=1)
    first, second = np.argsort(-sums, kind="stable")[:2]
    ratio = float(sums[first] / max(float(sums[second]), 1e-12)) if p >= 3 else 1.0
    wrong = int(first) + 1 if ratio >= WRONG_PAIR_RATIO else None
    which = "one of them is likely wrong" if wrong is None else (
        f"pair {wrong} is likely the wrong one, its distances to the other pairs differing "
        f"between the shapes {ratio:.1f} times as much as any other pair's")  # fmt: skip
    return quality.flagged(Said(
        "landmark pairs {first} and {second} (rows, counting from 1) lie {source:.2f} of "
        "sqrt(area) apart along the source but {target:.2f} along the target: {which} (a pair "
        "on the mirrored side, a slip of the click), and the map follows it or is pulled "
        "astray by it; check them ({landmarks_check}). (Right pairs differ by at most {seen:g} "
        "between a gorilla and a human: shapes whose proportions differ more may also do "
        "this.)",
        {"first": int(i) + 1, "second": int(j) + 1, "source": float(d1[i, j]),
         "target": float(d2[i, j]), "which": which, "seen": LANDMARKS_GAP_SEEN,
         "wrong": wrong}, "landmarks_apart",
    ))  # fmt: skip


#: Share of the target's triangles a map estimated without the orientation term must turn
#: over for the landmarks to be doubted (:data:`MAX_REVERSED` is too near: such maps of right
#: landmarks turned 0.12-0.55, of mirrored ones that the map did not turn over 0.49-0.87).
#: Measured: see :func:`landmarks_mirrored`.
MIRRORED_TURNED = 0.6
#: How much more closely that mirror image must follow the landmarks' distances than the map
#: for the pairs to be taken for mirrored (flagged); from :data:`OPEN_GAIN` up to here they
#: may also all lie on the plane of symmetry (warned). Measured: see :func:`landmarks_mirrored`.
MIRRORED_GAIN = 1.1
#: Below this the mirror image follows the landmarks worse than the map: nothing is said.
OPEN_GAIN = 0.9


def landmarks_mirrored(
    quality: MapQuality, anchors: Anchors, p2p_21: np.ndarray, free_21: np.ndarray,
    turned: float,
) -> MapQuality:  # fmt: skip
    """Doubt a map whose landmarks pair each side of the target with the source's other side.

    Landmarks given with left and right swapped on every pair (shapes facing the viewer and
    facing away) are consistent with one another, so :func:`landmarks_apart` passes them, and
    the orientation term makes the estimate follow them by turning the shape about its axis:
    a map far off that can pass every other check. Estimated without that term (``free_21``)
    the landmarks drive a mirror image, which turns most of the target's triangles over
    (``turned``) and follows their distances more closely than the map (``p2p_21``) does:
    flagged (``landmarks_mirrored``). Landmarks that all lie on the plane of symmetry leave
    the orientation open: their free map may be a mirror image too, following them as
    closely as the (right) map; when the gain is within [:data:`OPEN_GAIN`,
    :data:`MIRRORED_GAIN`] the two cases are not told apart, and the map is only warned about
    (``landmarks_unoriented``, a note said as a warning).

    Measured (scratch, 2026-11-30, ``bcicp_dev``: maps ``ofp.match`` estimates, mean geodesic
    error x100 on 300 points; landmarks from the truth, 6 farthest-point, 5 random and 3
    farthest-point ones, or the same mirrored, from its ``.sym.vts``; "midline": 4 right ones
    whose truth and mirror image lie within 0.02 sqrt(area)):

    * 10 TOSCA people pairs (every third of 30): of 28 mirrored sets (maps 28-56 off), 23
      turned over by the map itself, 2 flagged (gains 1.19, 1.23) and 3 warned (1.01-1.03),
      where those 5 had passed silently before; 28 right sets, nothing said (free maps
      0.12-0.34 turned); 9 midline sets, 1 warned (0.86 turned, gain 1.08).
    * 10 TOSCA animal pairs: of 30 mirrored sets (3-28 off), 12 turned over, 17 flagged
      (gains 1.26-2.69), 1 passed (0.56 turned, the map 4.5 off); 30 right sets, nothing
      said (0.15-0.43); 10 midline sets, 3 warned (gains 0.97-1.05, maps right).
    * 6 gorilla -> human pairs: 12 mirrored sets (46-58 off) all flagged before (far from an
      isometry), 7 now also warned (0.93-1.05); 13 right sets, 0.20-0.55, nothing said.

    ``anchors``: the match's :func:`~o3d_ofp.core.fmap.landmark_anchors` (meshes).
    """
    p = anchors.source.size
    d1, d2 = anchors.distances_1[:, :p], anchors.distances_2[:, :p]
    # mean misfit of the landmarks' distances (sqrt(area) units; 1e-6 of it is nothing)
    given, free = (float(np.abs(d1[p2p] - d2).mean()) + 1e-6 for p2p in (p2p_21, free_21))
    gain = given / free
    values = {"turned": turned, "gain": gain}
    quality = quality.noted(Said(
        "landmarks' orientation: estimated without the orientation term, the map they drive "
        "turns {turned:.2f} of the target over and follows their distances {gain:.2f} times "
        "as closely as this map", values, "landmarks_orientation",
    ))  # fmt: skip
    if not (turned > MIRRORED_TURNED and gain >= OPEN_GAIN):
        return quality
    if gain > MIRRORED_GAIN:
        return quality.flagged(Said(
            "the landmarks pair mirror-image sides (the source's left with the target's "
            "right): estimated without the orientation term, the map they drive turns "
            "{turned:.0%} of the target's triangles over and follows their distances {gain:.2f} "
            "times as closely as this map, which turns the shape about its axis to follow "
            "them; check that each pair is on the same side of both shapes ({landmarks_check}). "
            "(Shapes that are mirror images of each other, a left hand and a right one, cannot "
            "be matched without turning one over.)", values, "landmarks_mirrored",
        ))  # fmt: skip
    return quality.noted(Said(
        "the landmarks leave left and right open: estimated without the orientation term, the "
        "map they drive is a mirror image ({turned:.0%} of the target's triangles turned over) "
        "that follows them about as closely as this map ({gain:.2f} times). Either they all "
        "lie on the plane of symmetry (nose, navel, spine: then the orientation term chose, "
        "and the map is likely right) or every pair has left and right swapped (then it is "
        "far off); check a colormap, or add a pair off the plane of symmetry "
        "({landmarks_check})", values, "landmarks_unoriented",
    ))  # fmt: skip


#: Notes said as warnings even when the map passes: doubtful, but not a reason.
_WARNED_NOTES = ("cloud_part", "small_part", "landmarks_unoriented")


def say(title: str, what: str, quality: MapQuality, *, warn_suspect: bool = True) -> None:
    """Log a map's quality report and warn about a suspect map (the one place that does).

    The summary and the notes are logged at INFO with :data:`QUALITY_RECORD` (``title``
    starts the lines); a suspect map is an :class:`~o3d_ofp.OFPWarning` with its reasons
    (``what`` names the map: "the estimated map"), and so is a doubtful note: a cloud that may
    be a part (always), a small part (when the map passes). ``warn_suspect`` False: only
    logged (a caller that judges the map again, e.g. a second opinion).
    """
    logger.info("%s: %s", title, quality.summary(), extra=QUALITY_RECORD)
    if warn_suspect and quality.suspect:
        warn(logger, quality.suspect_message(what))
    for note in quality.notes:
        doubtful = note.code == "cloud_part" or (note.code in _WARNED_NOTES and not quality.suspect)
        if doubtful and warn_suspect:
            warn(logger, Said("{title}: {note}", {"title": title, "note": note}, note.code))
        elif not doubtful:
            logger.info("%s: %s", title, note, extra=QUALITY_RECORD)
