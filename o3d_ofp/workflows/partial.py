"""Matching a part of a shape (a cut, a one-sided scan) onto the whole shape.

``PartialMatch`` is the strategy ``o3d_ofp.workflows.estimate.estimate`` runs for a part (the
target) of a whole (the source), in the same units: partial functional maps (Rodolà et al.
2017 [1]_) with a partial ZoomOut [2]_ in place of the membership alternation. Both
eigenbases are expressed in the *source's* units (the source scaled to unit area, the target
by the same factor, so the area ratio, which sets the slant of the restriction map, is kept).
The steps:

1. *starts*: slanted restriction maps fitted to local descriptors (diffused curvatures, wave
   kernels at common energies) with the Laplacian, descriptor-commutativity, orientation and
   row-orthonormality terms, several sizes and two solvers;
2. *refine*: each start grown by a partial ZoomOut, its point map read at full resolution;
3. *settle*: orientation-preserving starts first, then the least geodesic distortion; the
   chosen start refined by geodesic distances and a second partial ZoomOut (where its image
   jumps more than ``MAX_JUMP`` the geodesic one is kept); a refinement that turns the map
   over tries the next starts (at most ``NEXT_STARTS``), else the start is kept unrefined
   and flagged;
4. *judge*: ``o3d_ofp.workflows.quality.partial_quality`` (distortion, stretch, ...: see
   :class:`o3d_ofp.MapQuality`);
5. *review*: a map that passes is compared with the refinements of the next starts (a rival
   as good that sends most of the part elsewhere makes it suspect; a less distorted one is
   returned instead, suspect too); the checked map is polished; landmarks the map does not
   keep make it suspect.

On the dense path the match runs between coarse copies, its checked map is polished as it is
extended, and a map that passes gets a second opinion from smaller copies (``PartialMatch.dense``).
Known limit: a near-spherical part (or any shape with a continuous symmetry) can be matched
rotated with little distortion, which the check does not see.

References
----------
.. [1] E. Rodolà, L. Cosmo, M. M. Bronstein, A. Torsello, D. Cremers, "Partial Functional
   Correspondence", Computer Graphics Forum 36(1), 2017.
.. [2] S. Melzi et al., "ZoomOut: Spectral Upsampling for Efficient Shape Correspondence",
   ACM TOG 38(6), 2019.
"""

from __future__ import annotations

import dataclasses
import logging
import math
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from typing import Any

import numpy as np

from ..core._warnings import warn
from ..core.correspondence import fmap_from_p2p
from ..core.geometry import face_areas_normals, units_change, vertex_areas
from ..core.multiscale import extend_p2p
from ..core.partial import (
    distortion_probe,
    fit_partial_fmaps,
    geodesic_refine,
    map_stretch,
    membership,
    partial_descriptors,
    partial_p2p,
    partial_polish,
    partial_polish_fit,
    partial_zoomout,
    rescaled,
    slant,
)
from ..core.shells import part_maps
from ..core.spectrum import EigenBasis
from ..core.wording import AdvisedError, OptionError, Said
from .maps import Correspondence, MapQuality
from .matching import DCOMM_WEIGHTS
from .options import MatchOptions, required_k
from .quality import (
    MAX_DISTORTION,
    MAX_JUMP,
    MAX_REVERSED,
    MAX_STRETCH,
    PARTIAL_MAX_AREA_RATIO,
    landmarks_advice,
    landmarks_extent,
    landmarks_kept,
    partial_quality,
    reversed_fraction,
)
from .strategy import Run, Settled, Strategy

__all__ = [
    "DISAGREEMENT",
    "MAX_DISAGREEMENT",
    "MIN_AREA_RATIO",
    "NEXT_STARTS",
    "RIVAL_MARGIN",
    "RIVAL_SHARE",
    "RIVAL_STARTS",
    "SECOND_OPINION_SIZE",
    "THIRD_OPINION_SIZE",
    "PartialMatch",
    "check_partial_areas",
    "refuse_clouds",
]

logger = logging.getLogger(__name__)

#: Target sizes of the fitted starts (each with every weight of DCOMM_WEIGHTS), capped by
#: ``k_fit``; the start whose ZoomOut aligns best is kept. Measured (FAUST 093 -> 087, legs
#: cut): fits of 9, 16 and 30 functions end at errors 0.065, 0.092 and 0.064-0.15 (wave
#: kernel alone: 0.074, 0.18, 0.17): no size is best on every cut, and small fits have fewer
#: unknowns for the descriptors, which differ near the cut, to mislead.
FIT_SIZES = (8, 15)
#: Target sizes of further starts fitted by the exact (direct) solve of the energy without the
#: row-orthonormality term (:func:`o3d_ofp.core.partial.fit_partial_fmap`, ``solver="direct"``:
#: one linear solve each), each with every weight of DCOMM_WEIGHTS. A different energy gives
#: different starts: measured on the 8 cuts of scripts/eval_partial.py, ranked with the others
#: by geodesic distortion, they are chosen on 2 cuts (FAUST head+arms cut: error 0.117 ->
#: 0.032; 019 -> 094 legs removed: 0.275 -> 0.245, still flagged) and leave the other 6 as
#: they were. 12 and 20 fill the gaps between FIT_SIZES and FIT_K.
DIRECT_FIT_SIZES = (12, 20)

#: When the chosen start's refinement turns the map over, at most this many further
#: orientation-preserving starts (in the ranking's order) are refined, and the first whose
#: refinement keeps the orientation, with a lower geodesic distortion than the chosen start's,
#: is kept (remeshed FAUST 002 -> 004 needs the second of them).
NEXT_STARTS = 3

#: Membership level above which a source vertex counts as covered by the target (the
#: membership is a band-limited indicator: about 1 inside the part, 0 outside).
COVERED_LEVEL = 0.5

#: A map that passes its checks is compared with the refinements of this many further
#: orientation-preserving starts (in the ranking's order): see :data:`RIVAL_MARGIN`.
RIVAL_STARTS = 3
#: A further start whose refinement also keeps the orientation and the distortion and stretch
#: bounds, changes geodesic distances at most this fraction more than the returned map, and
#: sends more than :data:`RIVAL_SHARE` of the target's area more than :data:`DISAGREEMENT`
#: away from the returned map's images (and, with landmarks, keeps them about as well), is a
#: *rival*: the part is ambiguous and the map suspect. Measured by
#: ``python scripts/eval_partial_rivals.py`` (the 60 cuts of ``scripts/eval_partial.py
#: --remeshed`` and ``--robustness``, on the 48 maps that pass the other checks: 34 right,
#: 14 wrong): this margin flags 6 of the 14 wrong maps (their rivals 0.78-1.04 times as
#: distorted, apart on 80-99 % of the part) and none of the right ones (rivals 1.19-1.94 times
#: as distorted, or apart on 11-48 %); a margin of 0 flags 3 of the 14.
RIVAL_MARGIN = 0.05
#: See :data:`RIVAL_MARGIN`: a rival differs from the map on most of the part (a region turned
#: about its axis), not on a limb (two maps of about the same precision).
RIVAL_SHARE = 0.5
# Of those further starts' refinements that keep the orientation and the bounds and send more
# than RIVAL_SHARE of the part elsewhere, the least distorted one is returned instead of the
# map when it changes geodesic distances less (the rule of the starts' ranking, applied after
# their refinements); the map it replaces is then its rival, and the verdict is suspect as it
# was (such a refinement is a rival of the map). Measured (``python
# scripts/eval_partial_rivals.py`` before the rule, the 48 maps that pass the other checks;
# error / sqrt(source area) of the map and of the refinement): four such refinements, FAUST
# legs removed at 0.93 of the area 0.180 -> 0.035, head+arms kept 0.35 0.180 -> 0.046,
# remeshed 007 -> 000 0.269 -> 0.078, the centaur's rear kept 0.45 0.129 -> 0.133. Taking
# also less distorted refinements that stay near the map (apart on 11-46 % of the part) moved
# maps near the truth both ways (one side removed at 0.93 0.057 -> 0.032, but the cuts of
# ``eval_partial.py --remeshed`` one side removed 0.0195 -> 0.0225 and head+arms 0.0350 ->
# 0.0460 after the polish): between two maps near the truth the distortion is no guide.
#: A "part" below this fraction of the source's area is refused (:func:`check_partial_areas`):
#: by Weyl's law its first non-zero eigenvalue is above the source's 100th, so the two spectra
#: the descriptors are computed from do not overlap (a FAUST cut at 1/1000 of the source's
#: units, area ratio 6.5e-07, is refused by the descriptors after both eigensolves).
MIN_AREA_RATIO = 0.01
#: On the dense path, the second opinion's coarse copies have this fraction of the first's
#: vertices (14 000 for the default 20 000; see :meth:`PartialMatch.dense`).
SECOND_OPINION_SIZE = 0.7
#: Distance (in units of sqrt(source area)) beyond which two maps' images of a target vertex
#: disagree: about twice the error of a right map.
DISAGREEMENT = 0.1
#: Fraction of the target's area on which the first map and the second opinion may disagree
#: before a third opinion is asked. Measured (``python scripts/eval_partial.py --dense 2``: the
#: FAUST cuts at 110k vertices, the centaurs' at 160k; coarse copies of 20 000 and 14 000) on
#: the maps that passed their own checks: right maps 0.1-14.2 % (the 14 %: the centaur's rear
#: removed, where the second opinion is the wrong one), wrong maps 5.7-63.7 %. A round bound
#: below most wrong ones; the margin is these cuts', no more.
MAX_DISAGREEMENT = 0.1
#: When the first map and the second opinion disagree, a third opinion on coarse copies of
#: this fraction of the first's vertices (8 000 for the default 20 000) tells which of the two
#: it agrees with. Measured (``python scripts/eval_partial.py --dense 2 --resolutions
#: 20000,14000,8000``, with and without ``--loop``): of 16 maps the two opinions disagreed on
#: 7; where the first passed its own checks (4) the third agreed with the right one each time.
#: Two coarse matches can also agree on a wrong map.
THIRD_OPINION_SIZE = 0.4


def _surfaces(run: Run) -> tuple[np.ndarray, ...]:
    """Return the source's and the target's vertices and faces in the source's units."""
    return run.u1.vertices, run.u1.faces, run.u2.vertices, run.u2.faces


def _distortions(run: Run, p2ps_21: Sequence[np.ndarray]) -> list[float]:
    """:func:`~o3d_ofp.core.partial.geodesic_distortion` of each point map of the run.

    The starts, their refinements, the rivals and the part's registration are all measured
    against one :func:`~o3d_ofp.core.partial.distortion_probe` of the run's shapes (the
    target's samples and their distances, the source's edge graph), made at the first call.
    """
    if "probe" not in run.state:
        run.state["probe"] = distortion_probe(*_surfaces(run))
    probe = run.state["probe"]
    return [math.nan] * len(p2ps_21) if probe is None else probe.distortions(p2ps_21)


def _disagreement(run: Run, p2p_21: np.ndarray) -> float:
    """How far a point map sends each part vertex from its descriptors, on average.

    The mass-weighted mean over the target of ``|d2 - d1∘p2p| / (|d2| + |d1∘p2p|)`` with the
    partial fit's descriptors (:func:`~o3d_ofp.core.partial.partial_descriptors`: wave kernels
    and curvatures, equal on a part and on the whole). It tells a back shell registered onto
    the back from one turned onto the front, which the geodesic distortion does not (both
    shells are about the same shape).
    """
    D1, D2 = run.state["descriptors"]
    a, b = D2, D1[p2p_21]
    scale = np.maximum(np.linalg.norm(a, axis=1) + np.linalg.norm(b, axis=1), 1e-300)
    mass = run.u2.mass
    return float(mass @ (np.linalg.norm(a - b, axis=1) / scale) / mass.sum())


def _refine(
    p2p: np.ndarray, u1: EigenBasis, u2: EigenBasis, *, k2_fit: int, k2_final: int,
    subsample: int | None,
) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """Geodesic refinement, then a partial ZoomOut from its map; a jump keeps the geodesic map.

    Measured on the 8 cuts of scripts/eval_partial.py, the chosen start's map after ZoomOut is
    right on most of the part but sends 3-40 % of it to the wrong place (errors above 0.1
    there, 0.02-0.03 elsewhere): the geodesic refinement (:func:`geodesic_refine`) pulls those
    regions back (errors 0.037-0.053 from 0.03-0.25), and the partial ZoomOut restarted from
    its map at ``k2_fit`` target eigenfunctions restores the spectral precision (0.019-0.042),
    except where it jumps (:data:`MAX_JUMP`). ``u1``, ``u2`` are in the source's units (unit
    source area). Returns the restriction map and the point map.
    """
    geodesic = geodesic_refine(p2p, u1.vertices, u1.faces, u2.vertices, u2.faces)
    k1 = slant(u1.evals, u2.evals, k2_fit)
    C = fmap_from_p2p(geodesic, u1, u2, k1=k1, k2=k2_fit)
    if k2_final > k2_fit:
        C = partial_zoomout(C, u1, u2, k2_final=k2_final, subsample=subsample)
    return C, _keep_geodesic_at_jumps(partial_p2p(C, u1, u2), geodesic, u1.vertices)


def _keep_geodesic_at_jumps(
    spectral: np.ndarray, geodesic: np.ndarray, vertices_1: np.ndarray
) -> np.ndarray:
    """Keep the spectral point map except where its image is over MAX_JUMP from the geodesic.

    ``vertices_1`` are the source's, scaled to unit area.
    """
    jump = np.linalg.norm(vertices_1[spectral] - vertices_1[geodesic], axis=1) > MAX_JUMP
    logger.debug("partial match: %.1f %% of the spectral refinement jumped", 100 * jump.mean())
    return np.where(jump, geodesic, spectral)


def _polish(
    p2p: np.ndarray, k1: int, u1: EigenBasis, u2: EigenBasis, *, subsample: int | None
) -> tuple[np.ndarray, float]:
    """Polish the final point map; where an image would move over MAX_JUMP, it stays.

    :func:`o3d_ofp.core.partial.partial_polish` up to ``k1`` source functions; ``u1``, ``u2``
    in the source's units. Returns the point map and the mean move of the images (in units
    of sqrt(source area)).
    """
    polished = partial_polish(p2p, u1, u2, k1_final=k1, subsample=subsample)[0]
    move = np.linalg.norm(u1.vertices[polished] - u1.vertices[p2p], axis=1)
    kept = np.where(move > MAX_JUMP, p2p, polished)  # the checks' bounds hold for every image
    return kept, float(np.where(move > MAX_JUMP, 0.0, move).mean())


def check_partial_areas(
    vertices_1: np.ndarray, faces_1: np.ndarray, vertices_2: np.ndarray, faces_2: np.ndarray, *,
    names: tuple[str, str] = ("the source", "the target"),
) -> None:  # fmt: skip
    """Refuse, before any eigensolve, a "part" larger than the whole, or far too small.

    Raises :class:`~o3d_ofp.core.wording.AdvisedError` when the target's surface area exceeds
    :data:`~o3d_ofp.workflows.quality.PARTIAL_MAX_AREA_RATIO` times the source's (the shapes are
    swapped, or in other units) or is below :data:`MIN_AREA_RATIO` times it (other units: such
    a part shares no frequencies with the whole). ``names`` name the two shapes in the message
    (file names from the command line); the advised factor is Open3D's ``target.scale`` (the
    command line's ``--target-scale``).
    """
    a1 = float(face_areas_normals(vertices_1, faces_1)[0].sum())
    a2 = float(face_areas_normals(vertices_2, faces_2)[0].sum())
    larger = a1 > 0 and a2 > PARTIAL_MAX_AREA_RATIO * a1
    if not (larger or (a1 > 0 and a2 < MIN_AREA_RATIO * a1)):
        return
    why = (
        "it cannot be a part of it. Swap source and target, or rescale the target to the "
        "source's units" if larger else
        "a part below {bound:g} of the whole shares no frequencies with it (other units, e.g. "
        "millimetres and metres?). Rescale the target to the source's units"
    )  # fmt: skip
    raise AdvisedError(Said(
        "{partial} matches a part (the target) onto the whole shape (the source), in the same "
        "units; but {target} has {ratio:.3g} times the area of {source}: " + why + "{hint}",
        {"target": names[1], "source": names[0], "ratio": a2 / a1, "bound": MIN_AREA_RATIO,
         "hint": _units_hint(a2 / a1)}, "part_larger" if larger else "part_too_small",
    ))  # fmt: skip


def refuse_clouds(faces: tuple[Any, ...], names: Any = ("the source", "the target")) -> None:
    """Refuse a partial match of a point cloud (faces None), naming it (``names``).

    A point cloud's cut boundary, orientation and geodesic distances, which the partial match
    and its check read, are unknown.
    """
    for F, name in zip(faces, names, strict=False):
        if F is None:
            raise OptionError("partial", Said(
                "=True needs triangle meshes: {name} is a point cloud (no faces), whose cut "
                "boundary, orientation and geodesic distances, which the partial match and its "
                "check read, are unknown; mesh it first, keeping its open border (e.g. Open3D's "
                "create_from_point_cloud_ball_pivoting: a Poisson surface closes the part into "
                "a whole), or {no_partial}", {"name": name},
            ))  # fmt: skip


def _units_hint(ratio: float) -> Said | str:
    """Suggest a scale factor for a target whose area is ``ratio`` times the source's.

    The power of ten nearest to the linear scale that would give both the same area, when it
    is not 1 (areas within a factor of about 10: not a units mix-up) and the scaled target
    would be admitted as a part; else "".
    """
    found = units_change(math.sqrt(ratio)) if ratio > 0 else None
    if found is None:
        return ""
    factor, change = found
    if not MIN_AREA_RATIO <= ratio * factor**2 <= PARTIAL_MAX_AREA_RATIO:
        return ""
    return Said(
        ": multiply its coordinates by {factor:g} ({change}{target_scale}), which makes its "
        "area {scaled:.3g} times the source's",
        {"factor": factor, "change": f"{change}: " if change else "", "scaled": ratio * factor**2},
    )


def _final_target_size(u1: EigenBasis, u2: EigenBasis, *, k2_fit: int, k1_max: int) -> int:
    """Return the target size whose slant reaches the source size ``k1_max`` (about r · k1_max).

    ``u1``, ``u2``: the bases in the source's units; at least ``k2_fit``, at most ``u2.k``.
    """
    k2_final = k2_fit
    while k2_final < u2.k and slant(u1.evals, u2.evals, k2_final + 1) < k1_max:
        k2_final += 1
    return k2_final


def _start_fits(k2_fit: int) -> list[tuple[int, str]]:
    """List the (target size, solver) of each descriptor fit, in order.

    L-BFGS fits of :data:`FIT_SIZES` and ``k2_fit`` functions, then exact fits of the
    :data:`DIRECT_FIT_SIZES` not among them (each size at most ``k2_fit``).
    """
    sizes = sorted({min(k, k2_fit) for k in (*FIT_SIZES, k2_fit)})
    direct = sorted({min(k, k2_fit) for k in DIRECT_FIT_SIZES} - set(sizes))
    return [(k, "lbfgs") for k in sizes] + [(k, "direct") for k in direct]


@dataclasses.dataclass
class PartialMatch(Strategy):
    """The steps of a partial match (see the module notes).

    Attributes
    ----------
    polish : bool
        Polish the checked point map (:func:`o3d_ofp.core.partial.partial_polish`; each image
        moves at most ``MAX_JUMP``, a note gives the mean move).
    coarse : bool
        The match between a dense pair's coarse copies: not polished (the extension polishes
        it) and its ``fmap_12`` in :func:`o3d_ofp.core.multiscale.extend_p2p`'s terms.
    """

    polish: bool = True
    coarse: bool = False
    method = "partial"
    title = "partial match"
    what = "the partial map"
    refine_share = (0.2, 0.5)

    def least(self, n1: int, n2: int, options: MatchOptions) -> tuple[int, int]:
        """Return ``zoomout_to`` on the source, ``k_fit`` on the target.

        The target's ZoomOut follows the slant (about the area ratio times the source's), as
        far as its eigenbasis goes: :meth:`needs` gives it ``zoomout_to`` as well.
        """
        return required_k(n1, options.zoomout_to), required_k(n2, options.k_fit)

    def check(self, eig_1: EigenBasis, eig_2: EigenBasis) -> None:
        """Refuse a point cloud (:func:`refuse_clouds`)."""
        refuse_clouds((eig_1.faces, eig_2.faces))

    def scaled(self, eig_1: EigenBasis, eig_2: EigenBasis) -> tuple[EigenBasis, EigenBasis]:
        """Return both bases in the source's units (unit source area): the area ratio is kept."""
        return rescaled(eig_1, eig_1.area), rescaled(eig_2, eig_1.area)

    def starts(self, run: Run) -> list[Any]:
        """Fit the starts, each size and solver with each weight, as ``(C, w_dcomm)``."""
        u1, u2, o = run.u1, run.u2, run.options
        k2_fit = min(o.k_fit, run.eig_2.k)
        k2_final = _final_target_size(u1, u2, k2_fit=k2_fit, k1_max=min(o.zoomout_to, run.eig_1.k))
        logger.debug(
            "partial match: area ratio %.3g, fit %d target eigenfunctions, ZoomOut to %d "
            "(source %d)", u2.area / u1.area, k2_fit, k2_final, slant(u1.evals, u2.evals, k2_final),
        )  # fmt: skip
        run.state.update(k2_fit=k2_fit, k2_final=k2_final)
        _distortions(run, [])  # its probe made once, before the starts are refined side by side
        descriptors = partial_descriptors(u1, u2, landmarks=run.landmarks)  # one set for all
        run.state["descriptors"] = descriptors
        fits = _start_fits(k2_fit)
        # the operators first (most of the fits' time), then each fit: 0.2 of the time in all
        run.report(f"descriptor fits: operators for {len(fits)} fits", 0.0)

        def fitting(done: int) -> None:
            run.report(f"descriptor fit {done + 1}/{len(fits)} ({fits[done][0]} functions)",
                       0.1 + 0.1 * done / len(fits))  # fmt: skip

        found = fit_partial_fmaps(
            u1, u2, fits=fits, landmarks=run.landmarks, w_dcomm=DCOMM_WEIGHTS,
            w_orient=o.w_orient, descriptors=descriptors, report=fitting,
        )  # fmt: skip
        return [start for maps in found for start in zip(maps, DCOMM_WEIGHTS, strict=True)]

    def refine(self, run: Run, index: int, start: Any) -> Any:
        """Partial ZoomOut of a start; ``((turned over, distortion), C, p2p)``.

        The key ranks the starts: orientation-preserving maps first (a mirror image can align
        the spectral embeddings as well as the right map), then by the change of geodesic
        distances (a mirror image keeps them, hence the first key).
        """
        C, _ = start
        if run.state["k2_final"] > C.shape[0] - 1:
            C = partial_zoomout(
                C, run.u1, run.u2, k2_final=run.state["k2_final"],
                subsample=run.options.zoomout_subsample,
            )  # fmt: skip
        p2p = partial_p2p(C, run.u1, run.u2)
        turned = reversed_fraction(p2p, run.eig_1, run.eig_2)
        [distortion] = _distortions(run, [p2p])
        logger.debug("partial match: start %d geodesic distortion %.3f, reversed triangles %.3f",
                     index + 1, distortion, turned)  # fmt: skip
        return (bool(turned > MAX_REVERSED), distortion), C, p2p

    def _refined(self, run: Run, p2p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return _refine(
            p2p, run.u1, run.u2, k2_fit=run.state["k2_fit"], k2_final=run.state["k2_final"],
            subsample=run.options.zoomout_subsample,
        )  # fmt: skip

    def settle(self, run: Run, starts: list[Any], refined: list[Any]) -> Settled:
        """Refine the best-ranked start by geodesic distances; if that turns it over, the next.

        A start that keeps the orientation, refined, is kept only when it also changes
        geodesic distances less than the chosen start (else a wrong next start could pass).
        """
        run.state["refined"] = refined
        ranking = sorted(range(len(refined)), key=lambda i: refined[i][0])  # stable
        chosen = ranking[0]
        (chosen_turned, chosen_distortion), C, p2p = refined[chosen]
        run.report("geodesic refinement", 0.7)
        C_refined, p2p_refined = self._refined(run, p2p)
        # Distances do not see orientation: from a start wrong on most of the part the
        # refinement can end on a mirror image; a start that keeps the orientation is then
        # kept as it was.
        turned = reversed_fraction(p2p_refined, run.eig_1, run.eig_2)
        info: dict[str, Any] = {
            "ranking": ranking, "refinements": {chosen: (C_refined, p2p_refined)},
            "turned_over": set(), "rejected": None, "fallback": None, "distortion": None,
            "weights": [start[1] for start in starts],
        }  # fmt: skip

        def kept(i: int, C: np.ndarray, p2p: np.ndarray, **more: Any) -> Settled:
            info.update(chosen=i, w_dcomm=info["weights"][i], **more)
            return Settled(C, p2p, info)

        if turned <= MAX_REVERSED or chosen_turned:
            return kept(chosen, C_refined, p2p_refined)
        info["rejected"] = turned
        info["turned_over"].add(chosen)
        others = [i for i in ranking if not refined[i][0][0] and i != chosen]
        for rank, i in enumerate(others[:NEXT_STARTS], start=2):
            C_next, p2p_next = self._refined(run, refined[i][2])
            info["refinements"][i] = (C_next, p2p_next)
            turned_next = reversed_fraction(p2p_next, run.eig_1, run.eig_2)
            if turned_next > MAX_REVERSED:
                info["turned_over"].add(i)
            [distortion_next] = _distortions(run, [p2p_next])
            logger.debug("partial match: next start (distortion %.3f) refined: %.0f %% turned "
                         "over, distortion %.3f", refined[i][0][1], 100 * turned_next,
                         distortion_next)  # fmt: skip
            if turned_next <= MAX_REVERSED and distortion_next < chosen_distortion:
                fallback = Said(
                    "the best-ranked start's geodesic refinement turned {percent:.0f} % of the "
                    "triangles over; the start ranked {rank} (of the orientation-preserving "
                    "ones, by geodesic distortion), whose refinement keeps the orientation, is "
                    "kept instead", {"percent": 100 * turned, "rank": rank}, "next_start",
                )  # fmt: skip
                logger.info("partial match: %s", fallback)
                return kept(i, C_next, p2p_next, rejected=None, distortion=distortion_next,
                            fallback=fallback)  # fmt: skip
        logger.info("partial match: the refinement turned %.0f %% over; start kept", 100 * turned)
        return kept(chosen, C, p2p)

    def judge(self, run: Run, settled: Settled) -> MapQuality:
        """:func:`~o3d_ofp.workflows.quality.partial_quality` with the overlap it covers."""
        run.report("point map", 0.8)
        return self._judged(run, settled, report=True)

    def _judged(self, run: Run, settled: Settled, *, report: bool) -> MapQuality:
        """:meth:`judge`'s report (``report``: say its stages to the run's progress)."""
        C, p2p, info = settled.fmap_12, settled.p2p_21, settled.info
        v = membership(C, run.u1, run.u2)
        overlap = float(run.u1.mass @ (v > COVERED_LEVEL))  # the source has unit area here
        if report:
            run.report("quality", 0.85)
        if info["distortion"] is None:
            [info["distortion"]] = _distortions(run, [p2p])
        lm = run.landmarks
        quality = partial_quality(
            p2p, run.eig_1, run.eig_2, C, overlap=overlap, distortion=info["distortion"],
            refinement_turned=info["rejected"], landmarks=lm is not None,
            landmarks_spread=lm is None or landmarks_extent(lm, run.u1.vertices) >= MAX_JUMP,
        )  # fmt: skip
        return quality if info["fallback"] is None else quality.noted(info["fallback"])

    def review(self, run: Run, settled: Settled, quality: MapQuality) -> tuple[Settled, MapQuality]:
        """Rivals for a map that passes, the polish, the landmarks it keeps."""
        info, p2p = settled.info, settled.p2p_21
        if not quality.suspect:  # does another start end at another map as good?
            run.report("rival starts", 0.9)
            # The next orientation-preserving starts, but for those whose refinement is known
            # to turn the map over (no rivals); refinements made already are reused.
            candidates = [
                i for i in info["ranking"]
                if not run.state["refined"][i][0][0] and i != info["chosen"]
                and i not in info["turned_over"]
            ][:RIVAL_STARTS]  # fmt: skip
            passing = _rival_refinements(
                candidates, [r[2] for r in run.state["refined"]], info["refinements"], p2p, run,
                landmarks=run.landmarks,
            )  # fmt: skip
            others = [(p2p_i, d, False) for _, _, p2p_i, d in passing]
            # the least distorted one that sends most of the part elsewhere is taken when it
            # distorts less (the starts' ranking's rule; see the notes beside RIVAL_SHARE)
            elsewhere = [r for r in passing if _share_apart(run, p2p, r[2]) > RIVAL_SHARE]
            best = min(elsewhere, key=lambda r: r[3], default=None)
            if best is not None and best[3] < info["distortion"]:
                given = settled
                settled, quality = self._given_way(run, settled, quality, best)
                if settled is not given:
                    others = [o for o in others if o[0] is not best[2]]
                    others.append((given.p2p_21, given.info["distortion"], True))
                    info, p2p = settled.info, settled.p2p_21
            rival = _rival(p2p, info["distortion"], others, run, landmarks=run.landmarks)
            if rival is not None:
                quality = quality.flagged(rival)
        polish = self.polish and not self.coarse and info["rejected"] is None
        if polish:
            # The quality above is the refined map's, as its bounds were measured; the polish
            # moves each image at most MAX_JUMP (it would smooth the tears a wrong map's
            # stretch measures).
            run.report("polish", 0.95)
            p2p, move = _polish(
                p2p, settled.fmap_12.shape[1] - 1, run.u1, run.u2,
                subsample=run.options.zoomout_subsample,
            )  # fmt: skip
            quality = quality.noted(Said(
                "the point map is the checked map polished with more target eigenfunctions "
                "(images moved {move:.4f} of sqrt(source area) on average, at most {bound})",
                {"move": move, "bound": MAX_JUMP}, "polished",
            ))  # fmt: skip
        info["polish"] = polish
        settled, quality = self._registered(run, Settled(settled.fmap_12, p2p, info), quality)
        fmap_12, p2p = settled.fmap_12, settled.p2p_21
        if self.coarse:  # in extend_p2p's terms: (a1/a2) Φ Cᵀ against Ψ (own units)
            fmap_12 = fmap_12 * (run.eig_2.area / run.eig_1.area)
        return Settled(fmap_12, p2p, settled.info), quality

    def _registered(
        self, run: Run, settled: Settled, quality: MapQuality
    ) -> tuple[Settled, MapQuality]:  # fmt: skip
        """Register the part onto the whole when its map is doubtful (``shells``).

        A suspect map between meshes, without landmarks: of the maps
        :func:`~o3d_ofp.core.shells.part_maps` fits extrinsically (the whole deformed onto the
        part from several rigid starts), the one whose descriptors agree best
        (:func:`_disagreement`) is refined as a chosen start is (geodesic refinement and
        partial ZoomOut, then the polish); it replaces the map when it changes geodesic
        distances less than the map does, and stays flagged. The starts are not ranked by
        their geodesic distortion: a back shell turned onto the front changes distances as
        little as the right map (scratch, 2026-12-02, the 8 cuts of
        ``scripts/eval_partial.py`` and five back halves at 6.9k and 20k vertices: the
        descriptors ranked a right start first on all 11 cases that had one, the distortion
        on 10; after refinement the distortion picked a right map on 6 of 13).

        Measured (2026-12-02, ``scripts/eval_partial.py --remeshed``, error / sqrt(source
        area)): FAUST 093 -> 087 front removed 0.19 -> 0.042 (its checked distortion 0.074
        against 0.132); the two remeshed cuts whose maps are wrong (0.074, 0.18) keep them
        (the registration's refined maps distort more); the two targets that are no part of
        the source get registered maps, flagged as before; a map that passes is not
        registered. On the dense path the same runs on the coarse copies (unpolished: the
        extension polishes): ``--dense 2`` (110k-160k vertices) front removed 0.139 -> 0.042,
        the centaur's top kept 0.047 -> 0.025; a new user's back half of a body (0.48 of the
        area, 53k vertices) 0.71 (upside down) -> 0.084 (0.20, turned onto the front, when
        the least distorted start was refined). ``MatchOptions(shells=False)`` keeps the map.
        """
        if not run.options.shells or not quality.suspect or run.landmarks is not None:
            return settled, quality
        run.report("registering the part onto the whole", 0.96)
        logger.info("partial match: the map is doubtful: registering the part onto the whole")
        maps = part_maps(run.u1, run.u2)
        disagreements = [_disagreement(run, m) for m in maps]
        C, p2p = self._refined(run, maps[int(np.argmin(disagreements))])
        polish = self.polish and not self.coarse  # (coarse copies: the extension polishes)
        refined = p2p
        if polish:
            p2p, _ = _polish(p2p, C.shape[1] - 1, run.u1, run.u2,
                             subsample=run.options.zoomout_subsample)  # fmt: skip
        # the refined map's distortion (as the checks' bounds were measured), and the first
        # map's against the returned one's (the same map when it is not polished)
        before, checked, *polished = _distortions(
            run, [settled.p2p_21, refined, *([p2p] if polish else [])])
        after = polished[0] if polished else checked
        logger.info("partial match: geodesic distortion %.3f (the map) and %.3f (the part's "
                    "registration; its starts' descriptor disagreements %s)", before, after,
                    ", ".join(f"{d:.3f}" for d in disagreements))  # fmt: skip
        values = {"before": before, "after": after}
        if not after < before:
            return settled, quality.noted(Said(
                "the part was also registered onto the whole (the map is doubtful), but that "
                "map changes geodesic distances more ({after:.3f} against {before:.3f}): the "
                "map is kept", values, "part_kept",
            ))  # fmt: skip
        info = {**settled.info, "distortion": checked, "rejected": None, "fallback": None,
                "polish": polish, "registered": True}  # fmt: skip
        registered = Settled(C, p2p, info)
        judged = self._judged(run, registered, report=False)
        found = Said(
            "the partial map was doubtful: the map comes from registering the part onto the "
            "whole (an extrinsic fit refined by geodesic distances; geodesic distortion "
            "{after:.3f} against the first map's {before:.3f}): check the result by eye",
            values, "part_registered",
        )  # fmt: skip
        return registered, dataclasses.replace(judged, suspect=True,
                                               reasons=(found, *judged.reasons))  # fmt: skip

    def _given_way(
        self, run: Run, settled: Settled, quality: MapQuality,
        taken: tuple[int, np.ndarray, np.ndarray, float],
    ) -> tuple[Settled, MapQuality]:  # fmt: skip
        """Return the refinement ``taken`` (:func:`_rival_refinements`) judged, for the map.

        The map is kept when the refinement fails a check of its own (:meth:`judge`).
        """
        i, C, p2p, distortion = taken
        note = Said(
            "the refinement of another orientation-preserving start sends most of the part "
            "elsewhere and changes geodesic distances less than the best-ranked start's "
            "({d:.3f} against {mine:.3f}) within the same bounds: it is kept instead",
            {"d": distortion, "mine": settled.info["distortion"]},
            "rival_taken",
        )  # fmt: skip
        info = {**settled.info, "chosen": i, "w_dcomm": settled.info["weights"][i],
                "distortion": distortion, "fallback": note}  # fmt: skip
        other = Settled(C, p2p, info)
        judged = self._judged(run, other, report=False)  # the progress is past the quality
        if judged.suspect:
            logger.info("partial match: a less distorted refinement fails its checks; kept the map")
            return settled, quality
        logger.info("partial match: %s", note)
        return other, judged

    def options(self, run: Run, settled: Settled) -> dict[str, Any]:
        """Return the options, with what the map is: its fit, its size, polished or not.

        Without ``same_frame``: a partial match never registers the shapes' smooth shells
        (``shells`` decides whether a doubtful map registers the part onto the whole).
        """
        recorded = super().options(run, settled)
        recorded.pop("same_frame")
        return {
            **recorded,
            "partial": True,
            "k_fit": run.state["k2_fit"],
            "zoomout_to": int(settled.fmap_12.shape[1] - 1),
            "w_dcomm": settled.info["w_dcomm"],
            "polish": settled.info["polish"],
            "refined": settled.info["rejected"] is None,  # False: a start kept unrefined
        }

    def for_coarse(self) -> PartialMatch:
        """Return the match between coarse copies: unpolished, its map in ``extend_p2p``'s terms."""
        return PartialMatch(polish=self.polish, coarse=True)

    def extend(
        self, corr: Correspondence, coarse_1: Any, coarse_2: Any, V1: Any, V2: Any
    ) -> tuple[np.ndarray, Correspondence]:
        """:func:`_extend_partial` of the checked coarse map (polished with ``polish``)."""
        subsample = corr.options.get("zoomout_subsample", 2000)
        return _extend_partial(corr, coarse_1, coarse_2, V1, V2, polish=self.polish,
                               subsample=subsample)  # fmt: skip

    def dense(
        self, again: Callable[..., Correspondence], size: int, shapes: tuple[np.ndarray, ...],
        report: Callable[[str, float], None], *, opinions: bool = True,
    ) -> Correspondence:  # fmt: skip
        """Return the dense match, with a second and (when they disagree) a third opinion.

        Coarse copies are remeshings, and a partial match can go wrong on one remeshed pair
        where it is right on another, with nothing in the map to say so. A map that passed its
        checks is matched again on coarse copies of :data:`SECOND_OPINION_SIZE` times the
        size; a right map does not depend on the resolution. When the two send more than
        :data:`MAX_DISAGREEMENT` of the target's area more than :data:`DISAGREEMENT` apart, a
        third opinion (:data:`THIRD_OPINION_SIZE`) tells which to believe: agreeing with the
        first, the first is kept (a note); with the second (which passed its own checks), the
        second's map is returned, flagged; with neither, the first is flagged. With landmarks
        the full map is checked again (the coarse check read the coarse map).
        """
        return _with_opinions(again, size, shapes, report, opinions)


def _rival_refinements(
    indices: list[int], start_maps: list[np.ndarray],
    refinements: dict[int, tuple[np.ndarray, np.ndarray]], p2p: np.ndarray, run: Run, *,
    landmarks: np.ndarray | None,
) -> list[tuple[int, np.ndarray, np.ndarray, float]]:  # fmt: skip
    """Refine the starts ``indices``; return ``(start, fmap_12, p2p_21, distortion)`` that pass.

    A refinement passes when it keeps the orientation and the distortion and stretch bounds
    of a partial map and, with ``landmarks`` ((p, 2) source and target vertices), sends their
    target vertices on average no farther from their source vertices than the map ``p2p``
    does, plus :data:`DISAGREEMENT`. ``start_maps`` are the starts' point maps (all of them,
    indexed like the starts); ``refinements`` the ``(fmap_12, p2p_21)`` refinements of starts
    refined already (reused).
    """
    X, u2 = run.u1.vertices, run.u2

    def off_landmarks(q: np.ndarray) -> float:
        assert landmarks is not None
        return float(np.linalg.norm(X[q[landmarks[:, 1]]] - X[landmarks[:, 0]], axis=1).mean())

    def refined(i: int) -> tuple[int, np.ndarray, np.ndarray, float] | None:
        C_i, p2p_i = refinements.get(i) or PartialMatch()._refined(run, start_maps[i])
        if reversed_fraction(p2p_i, run.eig_1, run.eig_2) > MAX_REVERSED:
            return None
        if landmarks is not None and off_landmarks(p2p_i) > off_landmarks(p2p) + DISAGREEMENT:
            return None
        [d] = _distortions(run, [p2p_i])
        stretch = map_stretch(p2p_i, X, u2.vertices, u2.faces)
        logger.debug("partial match: rival start %d refined: distortion %.3f, stretch %.2f",
                     i + 1, d, stretch)  # fmt: skip
        return (i, C_i, p2p_i, d) if d <= MAX_DISTORTION and stretch <= MAX_STRETCH else None

    with ThreadPoolExecutor(max_workers=2) as pool:
        return [r for r in pool.map(refined, indices) if r is not None]


def _share_apart(run: Run, a: np.ndarray, b: np.ndarray) -> float:
    """Share of the target's area the point maps ``a`` and ``b`` send :data:`DISAGREEMENT` apart."""
    X, mass = run.u1.vertices, run.u2.mass
    apart = np.linalg.norm(X[a] - X[b], axis=1) > DISAGREEMENT
    return float(mass @ apart / max(float(mass.sum()), 1e-300))


def _rival(
    p2p: np.ndarray, distortion: float, others: list[tuple[np.ndarray, float, bool]], run: Run,
    *, landmarks: np.ndarray | None,
) -> Said | None:  # fmt: skip
    """Return the reason why the map ``p2p`` has a rival among ``others``, else None.

    ``others``: ``(p2p_21, distortion, given_way)`` of the refinements of further starts that
    pass (:func:`_rival_refinements`), ``given_way`` true for a map this one was taken instead
    of. One that changes geodesic distances at most ``1 + RIVAL_MARGIN`` times as much as the
    map (whose distortion is ``distortion``), or was given way to, and sends more than
    :data:`RIVAL_SHARE` of the target's area more than :data:`DISAGREEMENT` away from the
    map's images, is a rival (:data:`RIVAL_MARGIN`).
    """
    for p2p_i, d, given_way in others:
        share = _share_apart(run, p2p, p2p_i)
        if share > RIVAL_SHARE and (given_way or d <= (1.0 + RIVAL_MARGIN) * distortion):
            return Said(
                "another start of the fit ends, refined, at a map that keeps the orientation "
                "and the distortion and stretch bounds as well (geodesic distortion {d:.3f}, "
                "this map's {mine:.3f}) and sends {percent:.0f} % of the target's area more "
                "than {apart:g} of the source's size away from this map's images: the part is "
                "ambiguous (e.g. a region that fits turned about its axis) and this map may be "
                "the wrong one; fix: {advice}",
                {"d": d, "mine": distortion, "percent": 100 * share, "apart": DISAGREEMENT,
                 "advice": landmarks_advice(landmarks is not None)}, "rival",
            )  # fmt: skip
    return None


def _extend_partial(
    corr: Correspondence, coarse_1: Any, coarse_2: Any, vertices_1: np.ndarray,
    vertices_2: np.ndarray, *, polish: bool, subsample: int | None,
) -> tuple[np.ndarray, Correspondence]:  # fmt: skip
    """Extend the checked coarse partial map to every vertex (``extend`` of the dense path).

    The coarse point map is its restriction map's read-off except where that jumps more than
    :data:`MAX_JUMP` from the geodesic map (``_refine``), so the extension of ``fmap_12``
    alone loses what the point map keeps there (measured, ``scripts/eval_partial.py --dense
    2``, FAUST 019 -> 094 legs removed: the coarse point map 0.028, the extension of its
    restriction map 0.077, wrong on the 6 % of the target where it jumped). The full map is
    read off the polish's fit of the checked coarse point map
    (:func:`o3d_ofp.core.partial.partial_polish_fit`, ``extend_p2p(..., adjoint=True)``; with
    ``polish`` and a refined map), else off ``fmap_12``; where its image lies more than
    :data:`MAX_JUMP` (of sqrt(source area)) from the coarse map's own image of the vertex's
    cell, that image is kept (a source vertex: the coarse vertices are some of the source's).
    """
    eig_1, eig_2 = coarse_1.eig, coarse_2.eig
    assert corr.fmap_12 is not None
    polished = polish and bool(corr.options.get("refined", False))
    if polished:
        area = eig_1.area
        fit = partial_polish_fit(
            corr.p2p_21, rescaled(eig_1, area), rescaled(eig_2, area),
            k1_final=corr.fmap_12.shape[1] - 1, subsample=subsample,
        )  # fmt: skip
        p2p = extend_p2p(fit, eig_1, eig_2, vertices_1, vertices_2, adjoint=True)
    else:
        p2p = extend_p2p(corr.fmap_12, eig_1, eig_2, vertices_1, vertices_2)
    coarse_map = coarse_1.samples[corr.p2p_21[coarse_2.cell]]  # the coarse map, every vertex
    V1 = np.asarray(vertices_1, dtype=np.float64)
    jump = np.linalg.norm(V1[p2p] - V1[coarse_map], axis=1) > MAX_JUMP * math.sqrt(eig_1.area)
    logger.debug("partial match (dense): the extension jumped from the coarse map on %.1f %% "
                 "of the target's vertices", 100 * jump.mean())  # fmt: skip
    note = Said(
        "the full point map is the checked coarse map{polished}, extended to every vertex; on "
        "{percent:.1f} % of the target's vertices the extension lay more than {bound} of "
        "sqrt(source area) from the coarse map's image, which is kept there",
        {"polished": " polished" if polished else "", "percent": 100 * jump.mean(),
         "bound": MAX_JUMP}, "extended",
    )  # fmt: skip
    assert corr.quality is not None
    # The landmark check (landmarks_kept) read the coarse map: said so.
    coarse = "the coarse map (before its polish and extension)"

    def of_coarse(items: tuple[Said, ...]) -> tuple[Said, ...]:
        landmark = ("landmarks_offset", "landmarks_far")
        return tuple(s.replace(subject=coarse) if s.code in landmark else s for s in items)

    quality = dataclasses.replace(
        corr.quality, notes=(*of_coarse(corr.quality.notes), note),
        reasons=of_coarse(corr.quality.reasons),
    )  # fmt: skip
    corr = dataclasses.replace(corr, options={**corr.options, "polish": polished}, quality=quality)
    return np.where(jump, coarse_map, p2p), corr


def _full_landmarks_kept(corr: Correspondence, vertices_1: np.ndarray) -> Correspondence:
    """On the dense path, check the landmarks again on the full map (``landmarks_kept``).

    The coarse match checked them on the coarse map; the full map, polished and extended, lies
    within ``MAX_JUMP`` of that map's images, so it can send a landmark's target vertex farther
    (up to about twice the bound). The full map's note is added; a map the coarse check passed
    is made suspect here when the full map sends a landmark more than ``MAX_JUMP`` away.
    ``vertices_1``: the full source's, scaled to unit area.
    """
    assert corr.quality is not None
    landmarks = np.asarray(corr.options["landmarks"], dtype=np.int64).reshape(-1, 2)
    # the offsets only: how spread the landmarks are is the coarse note's (its verdict used it)
    checked = landmarks_kept(
        corr.quality, corr.p2p_21, landmarks, vertices_1, subject="the full map",
        spread_note=False,
    )  # fmt: skip
    quality = dataclasses.replace(corr.quality, notes=checked.notes)
    if checked.suspect and "landmarks_far" not in {r.code for r in corr.quality.reasons}:
        quality = quality.flagged(checked.reasons[0])
    return dataclasses.replace(corr, quality=quality)


def _with_opinions(
    again: Callable[..., Correspondence], size: int, shapes: tuple[np.ndarray, ...],
    report: Callable[[str, float], None], opinions: bool,
) -> Correspondence:  # fmt: skip
    """Return the dense partial match with its opinions (see :meth:`PartialMatch.dense`).

    ``again(size, share, prefix)`` matches on coarse copies of ``size`` vertices; ``shapes``
    are the full meshes' arrays; ``report`` the whole run's progress. Without ``opinions``
    the map is only checked on the landmarks at full resolution.
    """
    corr = again(size, (0.0, 0.55 if opinions else 1.0), "")
    assert corr.quality is not None
    warned = corr.quality.suspect  # (the first match said it)
    V1, F1, V2, F2 = (np.asarray(a) for a in shapes)
    V1 = V1.astype(np.float64)
    scale = math.sqrt(float(face_areas_normals(V1, F1)[0].sum()))  # sqrt(source area)
    landmarks_given = corr.options.get("landmarks") is not None

    def done(c: Correspondence, *notes: Said, reason: Said | None = None) -> Correspondence:
        assert c.quality is not None
        quality = c.quality.noted(*notes)
        quality = quality if reason is None else quality.flagged(reason)
        if quality.suspect and not warned:
            warn(logger, quality.suspect_message("the partial map"))
        report("done", 1.0)
        return dataclasses.replace(c, quality=quality)

    if landmarks_given:
        corr = _full_landmarks_kept(corr, V1 / scale)
    if corr.quality.suspect or not opinions:  # a second opinion would not change it
        return done(corr)
    sizes = (size, *(max(200, int(size * f)) for f in (SECOND_OPINION_SIZE, THIRD_OPINION_SIZE)))
    logger.info("partial match (dense): second opinion from coarse copies of ~%d vertices",
                sizes[1])  # fmt: skip
    second = again(sizes[1], (0.55, 0.3), "second opinion: ")
    weight = vertex_areas(V2, F2)

    def apart(a: Correspondence, b: Correspondence) -> float:
        """Return the share of the target's area whose images by a and b lie far apart."""
        far = np.linalg.norm(V1[a.p2p_21] - V1[b.p2p_21], axis=1) > DISAGREEMENT * scale
        return float(weight @ far / max(weight.sum(), 1e-300))

    disagreement = apart(corr, second)
    logger.info("partial match (dense): the second opinion disagrees on %.1f %% of the target's "
                "area", 100 * disagreement)  # fmt: skip
    second_note = _opinion("second", sizes[1], disagreement)
    if disagreement <= MAX_DISAGREEMENT:
        return done(corr, second_note)
    # One of the two is wrong on a region: a third match, on smaller copies still, tells which.
    logger.info("partial match (dense): they disagree; third opinion from coarse copies of ~%d "
                "vertices", sizes[2])  # fmt: skip
    third = again(sizes[2], (0.85, 0.15), "third opinion: ")
    with_first, with_second = apart(corr, third), apart(second, third)
    logger.info("partial match (dense): the third opinion disagrees with the first map on %.1f %% "
                "and with the second opinion on %.1f %% of the target's area", 100 * with_first,
                100 * with_second)  # fmt: skip
    third_note = _opinion("third", sizes[2], with_first)
    if with_first <= MAX_DISAGREEMENT:  # the second opinion was the odd one out
        return done(corr, second_note, third_note, Said(
            "the third opinion agrees with this map: the second opinion is set aside"))  # fmt: skip
    assert second.quality is not None
    shares = (disagreement, with_first, with_second)
    fix = Said("{advice}, or match at full resolution (from Python: eigenbases=, slow)",
               {"advice": landmarks_advice(landmarks_given)})  # fmt: skip
    if with_second <= MAX_DISAGREEMENT and not second.quality.suspect:
        # The first map is the odd one out: the map the other two agree on is returned (a right
        # map does not depend on the resolution), still flagged, as the three disagree.
        if landmarks_given:
            second = _full_landmarks_kept(second, V1 / scale)
        notes, reason = _second_kept(sizes, shares, fix)
        return done(second, *notes, reason=reason)
    return done(
        corr, second_note, third_note, reason=Said(
            "the match on coarse copies of about {second} vertices sends {percent:.0f} % of the "
            "target's area more than {apart:g} of the source's size away from this map's "
            "images, and the match on copies of about {third} agrees with neither (a right map "
            "does not depend on the resolution): a region may be sent to the wrong place; fix: "
            "{fix}", {"second": sizes[1], "percent": 100 * disagreement,
            "apart": DISAGREEMENT, "third": sizes[2], "fix": fix}, "opinions_disagree",
        ),
    )  # fmt: skip


def _opinion(which: str, n: int, share: float, whose: str = "this map's") -> Said:
    """Return the note of an opinion: how far its images lie from another map's."""
    return Said(
        "{which} opinion (coarse copies of about {n} vertices): its images are more than "
        "{apart:g} of the source's size away from {whose} images on {percent:.1f} % of the "
        "target's area (at most {bound:g} %)",
        {"which": which, "n": n, "apart": DISAGREEMENT, "whose": whose,
         "percent": 100 * share, "bound": 100 * MAX_DISAGREEMENT}, "opinion",
    )  # fmt: skip


def _second_kept(
    sizes: tuple[int, ...], shares: tuple[float, ...], fix: Said
) -> tuple[tuple[Said, ...], Said]:
    """Return the notes and the reason of a second opinion kept (the third agrees with it)."""
    first = f"the first map's (coarse copies of about {sizes[0]} vertices)"
    notes = (
        _opinion("second", sizes[1], shares[0], first),
        _opinion("third", sizes[2], shares[1], first),
        _opinion("third", sizes[2], shares[2]),
        Said("this map is the second opinion's, which the third agrees with; the first map is "
             "set aside"),
    )  # fmt: skip
    reason = Said(
        "the matches on coarse copies of about {second} and {third} vertices agree with each "
        "other, but send {percent:.0f} % of the target's area more than {apart:g} of the "
        "source's size away from the match on copies of about {first}: their map is returned "
        "(the second opinion's), and a region may still be wrong; fix: {fix}",
        {"second": sizes[1], "third": sizes[2], "percent": 100 * shares[0],
         "apart": DISAGREEMENT, "first": sizes[0], "fix": fix}, "opinions_disagree",
    )  # fmt: skip
    return notes, reason
