"""Partial shapes: a target cut by a plane, matched onto the whole source (ground truth known).

    python scripts/eval_partial.py [--only NAME ...] [--remeshed | --robustness | --from-truth
                                   | --baseline | --landmarks N [N ...]
                                   | --dense LEVEL [--direct] [--loop] [--resolutions N,N,...]]

For each cut (a plane keeping 55-80 % of the target's area): the map error (mean distance
between the matched and the true source vertex, divided by sqrt(source area)) of
``ofp.match(..., partial=True)``, of the full-shape map of the uncut pair and of
``partial=False`` on the cut; the verdict of each; the estimated overlap against the kept
area fraction; the geodesic distortion and the stretch the suspect flag reads (against
``MAX_DISTORTION`` and ``MAX_STRETCH``: those of the refined map, before its polish); the
seconds of the partial match (given the eigenbases; the eigensolves are shared and timed
apart) and the load average. Then targets that are NOT a part of the source (a cut of another
kind of body, scaled to a plausible 70 % of the source's area): their maps must be suspect.
With ``--remeshed``, also cuts of independently remeshed FAUST bodies (~5k vertices, other
connectivity than the source's; truth from ``faust_remeshed/corres``, measured on the listed
vertices the cut keeps). ``--only`` selects among all three lists by name (a remeshed cut is
named like ``tr_reg_007 -> tr_reg_000``).
With ``--robustness``, instead, each cut with the target rescaled by 3.5 % either way (as
a scan's calibration or a smoothing that shrinks it would), smoothed (the whole target by
``smooth_coordinates(smooth=0.02)``, then cut), or cut smaller (0.45, 0.35, 0.25 of the area;
the largest piece is kept, which can be smaller still).
With ``--from-truth``, instead, the refinements alone from each cut's true map: the partial
ZoomOut (from the true map's restriction at 29 target functions to the match's final size)
and the polish (``partial_polish``) of its map and of the true map.
With ``--baseline``, instead, each cut's error for a partial functional map fit alone (the
method of Rodolà et al. 2017, one fit), the same grown by a partial ZoomOut, and ours.
With ``--landmarks N [N ...]``, instead, each cut matched with N known pairs (the true
source vertices of N farthest-point target vertices; 0: none): the error, the verdict and the
landmarks' own offsets in the map (how far each landmark's target vertex lands from its given
source vertex) and, for a suspect map, the opening words of its first reason.
With ``--dense LEVEL``, instead, the cuts with both shapes midpoint-subdivided LEVEL times
(FAUST at 2: 110k vertices, the TOSCA centaurs at 1: 63k; the same truth, the new vertices'
included): ``ofp.match(..., partial=True)`` from the arrays (above 50 000 vertices: on coarse
copies, the map extended to every vertex, and checked by a second opinion on smaller coarse
copies: the fraction of the target's area where the two disagree), with its whole time
(eigenbases included); ``--direct`` also runs the direct match on full-resolution eigenbases
(minutes per cut at 110k vertices); ``--loop`` subdivides by Loop's scheme instead (a smooth
surface, as a scan's, where midpoint subdivision leaves flat triangles); ``--resolutions``
matches each cut on coarse copies of each of the given sizes instead, with no opinion, and
prints each map's error and verdict and the share of the target's area on which each two of
them are more than ``DISAGREEMENT`` apart (what the second and third opinions read).
"""

from __future__ import annotations

import argparse
import os
import re
import sys
import textwrap
import time
import warnings
from pathlib import Path

import numpy as np

import o3d_ofp as ofp
from o3d_ofp.boundary.convert import geometry_to_arrays
from o3d_ofp.core.geometry import vertex_areas

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"

#: (name, source, target, axis, side, kept area fraction): the cut keeps the target's
#: vertices with ``side * (x[axis] - offset) >= 0``, the offset set so that the kept faces
#: have the given fraction of the area. FAUST: y up, x left-right, z front-back.
_A, _B = "faust/tr_reg_093.ply", "faust/tr_reg_087.ply"
_C, _D = "faust/tr_reg_019.ply", "faust/tr_reg_094.ply"
_E, _F = "tosca/centaur2.off", "tosca/centaur4.off"
CUTS = [
    ("faust 093->087 legs removed", _A, _B, 1, 1, 0.65),
    ("faust 093->087 one side removed", _A, _B, 0, 1, 0.6),
    ("faust 093->087 front removed", _A, _B, 2, -1, 0.6),
    ("faust 093->087 head+arms cut", _A, _B, 1, -1, 0.8),
    ("faust 019->094 legs removed", _C, _D, 1, 1, 0.7),
    ("faust 019->094 one side removed", _C, _D, 0, -1, 0.55),
    ("tosca centaur2->4 rear removed", _E, _F, 0, 1, 0.7),
    ("tosca centaur2->4 top kept", _E, _F, 1, 1, 0.72),
]
#: (source, target, axis, side, kept fraction) in faust_remeshed/ (not used to set constants).
REMESHED = [
    ("tr_reg_000", "tr_reg_001", 1, 1, 0.65),
    ("tr_reg_002", "tr_reg_004", 0, 1, 0.6),
    ("tr_reg_007", "tr_reg_000", 1, -1, 0.75),
    ("tr_reg_001", "tr_reg_007", 0, -1, 0.6),
]
#: (name, source, other shape, axis, side, kept fraction): the cut of the other shape, scaled to
#: 70 % of the source's area, is no part of the source.
NOT_PARTS = [
    ("centaur rear removed -> faust 093", _A, _F, 0, 1, 0.7),
    ("faust legs removed -> centaur 2", _E, _B, 1, 1, 0.65),
]


def load(rel: str) -> tuple[np.ndarray, np.ndarray]:
    return geometry_to_arrays(ofp.read_geometry(DATA / rel))


def _areas(V: np.ndarray, F: np.ndarray) -> np.ndarray:
    return 0.5 * np.linalg.norm(np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]]), axis=1)


def plane_cut(
    V: np.ndarray, F: np.ndarray, *, axis: int, side: int, fraction: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """Keep the faces on one side of a plane (all three corners), ``fraction`` of the area.

    Returns the kept vertices, faces, the original index of each kept vertex, and the kept
    area fraction (faces, which is what the eigenbasis sees).
    """
    x = side * V[:, axis]
    corner = x[F].min(axis=1)  # a face is kept when all its corners are on the kept side
    areas = _areas(V, F)
    order = np.argsort(-corner)
    cum = np.cumsum(areas[order]) / areas.sum()
    kept_faces = F[order[: int(np.searchsorted(cum, fraction)) + 1]]
    keep = np.unique(kept_faces)
    index = np.full(V.shape[0], -1)
    index[keep] = np.arange(keep.size)
    # Only the largest connected piece is kept (a plane can leave islands, e.g. hands).
    import scipy.sparse as sp
    import scipy.sparse.csgraph as csgraph

    Fk = index[kept_faces]
    n = keep.size
    adj = sp.coo_matrix(
        (np.ones(3 * len(Fk)), (Fk.ravel(), np.roll(Fk, 1, axis=1).ravel())), shape=(n, n)
    )
    _, labels = csgraph.connected_components(adj, directed=False)
    big = labels == np.bincount(labels).argmax()
    Fk = Fk[big[Fk[:, 0]]]
    used = np.unique(Fk)
    remap = np.full(n, -1)
    remap[used] = np.arange(used.size)
    kept_fraction = _areas(V[keep][used], remap[Fk]).sum() / areas.sum()
    return V[keep][used], remap[Fk], keep[used], float(kept_fraction)


def subdivided(rel: str, level: int, *, loop: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Read a mesh and subdivide it ``level`` times (one numbering for shapes of one mesh).

    Midpoint subdivision keeps the surface (flat triangles, curvature only at the original
    vertices); Loop subdivision (``loop``) smooths it, as a scan's surface is smooth, and
    moves the original vertices (two shapes of one connectivity stay in correspondence).
    """
    mesh = ofp.read_geometry(DATA / rel)
    return geometry_to_arrays(
        mesh.subdivide_loop(level) if loop else mesh.subdivide_midpoint(level)
    )


def _dense_cuts(level: int, *, only: list[str] | None, loop: bool):
    """Yield (name, V1, F1, Vc, Fc, truth) of each cut, both shapes subdivided ``level`` times.

    Each mesh is subdivided once (shapes shared by several cuts are kept).
    """
    shapes: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    for name, a, b, axis, side, fraction in CUTS:
        if only and not any(o in name for o in only):
            continue
        for rel in (a, b):
            if rel not in shapes:
                shapes[rel] = subdivided(rel, level, loop=loop)
        (V1, F1), (V2, F2) = shapes[a], shapes[b]
        Vc, Fc, orig, _ = plane_cut(V2, F2, axis=axis, side=side, fraction=fraction)
        yield name, V1, F1, Vc, Fc, orig


def resolution_rows(
    level: int, sizes: list[int], *, only: list[str] | None, loop: bool = False
) -> None:
    """Print the table of ``--resolutions``: each cut matched on coarse copies of each size."""
    from o3d_ofp.workflows.estimate import estimate_dense
    from o3d_ofp.workflows.partial import DISAGREEMENT

    print("| cut | coarse copies | error | verdict | apart |\n|---|---|---|---|---|")
    for name, V1, F1, Vc, Fc, orig in _dense_cuts(level, only=only, loop=loop):
        scale = float(np.sqrt(_areas(V1, F1).sum()))
        weight = vertex_areas(Vc, Fc)
        weight /= weight.sum()
        maps = {}
        for n in sizes:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")  # the verdict is a column
                corr = estimate_dense(
                    V1, F1, Vc, Fc, options=ofp.MatchOptions(partial=True), coarse_vertices=n,
                    opinions=False,
                )  # fmt: skip
            maps[n] = corr.p2p_21
            q = corr.quality
            earlier = sizes[: sizes.index(n)]
            far = [
                np.linalg.norm(V1[maps[m]] - V1[corr.p2p_21], axis=1) > DISAGREEMENT * scale
                for m in earlier
            ]
            apart = ", ".join(
                f"{m}: {100 * float(weight @ f):.1f} %" for m, f in zip(earlier, far, strict=True)
            )
            print(
                f"| {name} | {n} | {error(V1, corr.p2p_21, orig, scale**2):.4f} | "
                f"{'suspect' if q.suspect else 'ok'} | {apart or '-'} |",
                flush=True,
            )


def dense_rows(level: int, *, only: list[str] | None, direct: bool, loop: bool = False) -> None:
    """Print the table of ``--dense``: every cut with both shapes subdivided ``level`` times."""
    from o3d_ofp.workflows import plan

    print(
        "| cut | vertices (source / target) | path | error | verdict | second opinion "
        "| overlap | s |\n|---|---|---|---|---|---|---|---|"
    )
    for name, V1, F1, Vc, Fc, orig in _dense_cuts(level, only=only, loop=loop):
        area = float(_areas(V1, F1).sum())
        dense = max(len(V1), len(Vc)) > plan.DENSE_VERTICES
        for dense_above in [None] + ([10**12] if direct and dense else []):
            saved = plan.DENSE_VERTICES
            if dense_above is not None:  # the direct path: the planner's threshold lifted
                plan.DENSE_VERTICES = dense_above
            try:
                t0 = time.perf_counter()
                corr = ofp.match((V1, F1), (Vc, Fc), partial=True)
                seconds = time.perf_counter() - t0
            finally:
                plan.DENSE_VERTICES = saved
            q = corr.quality
            label = "coarse copies" if corr.options.get("dense") else "direct"
            # the opinions' notes: "second opinion (...): ... images on 1.2 % of the target's
            # area ..."; a third is asked when the second disagrees: its share against the
            # first map, then (when it agrees with the second) against the second
            shares: dict[str, list[str]] = {"second": [], "third": []}
            for n in map(str, q.notes):
                if m := re.match(r"(second|third) opinion .* on ([\d.]+ %) of the target", n):
                    shares[m.group(1)].append(m.group(2))
            flagged = any(str(r).startswith(("the match on coarse copies", "the matches on "
                                             "coarse")) for r in q.reasons)  # fmt: skip
            opinion = "-" if not shares["second"] else shares["second"][0] + (
                f", third {' / '.join(shares['third'])}" if shares["third"] else "") + (
                " (flags it)" if flagged else "")  # fmt: skip
            print(
                f"| {name} | {len(V1)} / {len(Vc)} | {label} | "
                f"{error(V1, corr.p2p_21, orig, area):.4f} | {'suspect' if q.suspect else 'ok'} | "
                f"{opinion} | {q.overlap:.2f} | {seconds:.1f} |",
                flush=True,
            )


def error(V1: np.ndarray, p2p: np.ndarray, truth: np.ndarray, area: float) -> float:
    return float(np.linalg.norm(V1[p2p] - V1[truth], axis=1).mean() / np.sqrt(area))


#: (label, linear scale of the target, smoothing of the whole target before the cut, kept
#: fraction or None for the cut's own) of ``--robustness``.
ROBUSTNESS = [
    ("as listed", 1.0, 0.0, None),
    ("target x0.965 (area 0.93)", 0.965, 0.0, None),
    ("target x1.035 (area 1.07)", 1.035, 0.0, None),
    ("target smoothed 0.02", 1.0, 0.02, None),
    ("kept 0.45", 1.0, 0.0, 0.45),
    ("kept 0.35", 1.0, 0.0, 0.35),
    ("kept 0.25", 1.0, 0.0, 0.25),
]


def _cuts_and_sources(only: list[str] | None):
    """Yield (name, axis, side, fraction, V1, F1, e1, V2, F2) of the selected cuts.

    ``e1``: the source's eigenbasis (99 functions), computed once for all of its cuts.
    """
    sources: dict[str, tuple] = {}
    for name, a, b, axis, side, fraction in CUTS:
        if only and not any(o in name for o in only):
            continue
        if a not in sources:
            V1, F1 = load(a)
            sources[a] = (V1, F1, ofp.eigenbasis(V1, F1, k=99))
        yield (name, axis, side, fraction, *sources[a], *load(b))


def robustness_rows(only: list[str] | None) -> None:
    """Print the cuts with the target slightly rescaled, smoothed, or cut smaller (same truth)."""
    from o3d_ofp.core.filtering import smooth_coordinates

    print(
        "| cut | target | kept area | error | verdict | distortion | stretch |\n"
        "|---|---|---|---|---|---|---|"
    )
    for name, axis, side, fraction, V1, F1, e1, V2, F2 in _cuts_and_sources(only):
        smoothed: dict[float, np.ndarray] = {}
        for label, scale, smooth, kept_fraction in ROBUSTNESS:
            X = V2
            if smooth > 0:
                if smooth not in smoothed:
                    eig = ofp.eigenbasis(V2, F2, k=40)
                    smoothed[smooth] = smooth_coordinates(eig, V2, smooth=smooth)
                X = smoothed[smooth]
            Vc, Fc, orig, kept = plane_cut(
                X, F2, axis=axis, side=side, fraction=kept_fraction or fraction
            )
            Vc = scale * Vc
            ec = ofp.eigenbasis(Vc, Fc, k=99)
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")  # the verdict is in the table
                part = ofp.match((V1, F1), (Vc, Fc), partial=True, eigenbases=(e1, ec))
            print(
                f"| {name} | {label} | {kept:.2f} | {error(V1, part.p2p_21, orig, e1.area):.4f} "
                f"| {'suspect' if part.quality.suspect else 'ok'} | "
                f"{part.quality.distortion:.3f} | {part.quality.stretch:.2f} |",
                flush=True,
            )


def _rescaled_cuts(only: list[str] | None):
    """Yield (name, V1, F1, e1, Vc, Fc, orig, ec, u1, u2, k2_final) of the selected cuts.

    The cut (``plane_cut``), its eigenbasis (``ESTIMATION_K`` functions), both bases in the
    source's units (``rescaled``) and the partial match's final target size.
    """
    from o3d_ofp.core.partial import rescaled
    from o3d_ofp.workflows.options import ESTIMATION_K, FIT_K
    from o3d_ofp.workflows.partial import _final_target_size

    for name, axis, side, fraction, V1, F1, e1, V2, F2 in _cuts_and_sources(only):
        Vc, Fc, orig, _ = plane_cut(V2, F2, axis=axis, side=side, fraction=fraction)
        ec = ofp.eigenbasis(Vc, Fc, k=ESTIMATION_K)
        u1, u2 = rescaled(e1, e1.area), rescaled(ec, e1.area)
        k2_final = _final_target_size(u1, u2, k2_fit=FIT_K, k1_max=ESTIMATION_K)
        yield name, V1, F1, e1, Vc, Fc, orig, ec, u1, u2, k2_final


def truth_rows(only: list[str] | None) -> None:
    """Print the refinements' errors from the true map of each cut (the refinement alone).

    The true map's restriction map at FIT_K (29) target functions (``fmap_from_p2p``), read off as a
    point map, then grown by the partial ZoomOut to the partial match's final size, then
    the polish (``partial_polish``) of that ZoomOut's point map and of the true map itself.
    """
    from o3d_ofp.core.correspondence import fmap_from_p2p
    from o3d_ofp.core.partial import partial_p2p, partial_polish, partial_zoomout, slant
    from o3d_ofp.workflows.options import FIT_K

    print(
        "| cut | true map at 29 | partial ZoomOut | ZoomOut, polished | true map polished |\n"
        "|---|---|---|---|---|"
    )
    for name, V1, _, e1, _, _, orig, _, u1, u2, k2_final in _rescaled_cuts(only):
        C = fmap_from_p2p(orig, u1, u2, k1=slant(u1.evals, u2.evals, FIT_K), k2=FIT_K)
        zoomed = partial_zoomout(C, u1, u2, k2_final=k2_final, subsample=2000)
        k1 = zoomed.shape[1] - 1
        maps = [partial_p2p(C, u1, u2), partial_p2p(zoomed, u1, u2)]
        maps.append(partial_polish(maps[1], u1, u2, k1_final=k1)[0])
        maps.append(partial_polish(orig, u1, u2, k1_final=k1)[0])
        cells = " | ".join(f"{error(V1, m, orig, e1.area):.4f}" for m in maps)
        print(f"| {name} | {cells} |", flush=True)


def baseline_rows(only: list[str] | None) -> None:
    """Print each cut's error for a partial functional map fit alone, with ZoomOut, and ours.

    The fit is the one the issue names (Rodolà et al., "Partial Functional Correspondence",
    CGF 2017: the restriction map's slanted diagonal from the area ratio, descriptors, the
    Laplacian and orientation terms; here with our descriptors and without their alternating
    update of the part's indicator function, which the point map reads off instead), one
    L-BFGS fit of FIT_K (29) target functions without the descriptor-commutativity term, read
    off as a point map; then grown by the partial ZoomOut to the match's final size; then
    ``ofp.match(..., partial=True)`` (its ten starts, ranking, geodesic refinement, checks,
    polish). Seconds given both eigenbases.
    """
    from o3d_ofp.core.partial import fit_partial_fmap, partial_p2p, partial_zoomout
    from o3d_ofp.workflows.options import FIT_K

    print(
        "| cut | fit alone | s | fit + partial ZoomOut | s | ofp.match(partial=True) | verdict "
        "| s |\n|---|---|---|---|---|---|---|---|"
    )
    for name, V1, F1, e1, Vc, Fc, orig, ec, u1, u2, k2_final in _rescaled_cuts(only):
        t0 = time.perf_counter()
        (C,) = fit_partial_fmap(u1, u2, k2=FIT_K, w_dcomm=(0.0,))
        fitted = partial_p2p(C, u1, u2)
        t1 = time.perf_counter()
        zoomed = partial_p2p(partial_zoomout(C, u1, u2, k2_final=k2_final), u1, u2)
        t2 = time.perf_counter()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # the verdict is in the table
            part = ofp.match((V1, F1), (Vc, Fc), partial=True, eigenbases=(e1, ec))
        t3 = time.perf_counter()
        print(
            f"| {name} | {error(V1, fitted, orig, e1.area):.4f} | {t1 - t0:.1f} | "
            f"{error(V1, zoomed, orig, e1.area):.4f} | {t2 - t0:.1f} | "
            f"{error(V1, part.p2p_21, orig, e1.area):.4f} | "
            f"{'suspect' if part.quality.suspect else 'ok'} | {t3 - t2:.1f} |",
            flush=True,
        )


def landmark_rows(counts: list[int], only: list[str] | None) -> None:
    """Print the table of ``--landmarks``: every cut with N true landmarks, for each N."""
    from o3d_ofp.core.fmap import farthest_points

    print(
        "| cut | landmarks | error | verdict | landmarks' offsets (max) | s | first reason |\n"
        "|---|---|---|---|---|---|---|"
    )
    for name, axis, side, fraction, V1, F1, e1, V2, F2 in _cuts_and_sources(only):
        Vc, Fc, orig, _ = plane_cut(V2, F2, axis=axis, side=side, fraction=fraction)
        ec = ofp.eigenbasis(Vc, Fc, k=99)
        for count in counts:
            landmarks = None
            if count:
                rows = farthest_points(Vc, count)
                landmarks = np.stack([orig[rows], rows], axis=1)
            t0 = time.perf_counter()
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")  # the verdict is a column
                corr = ofp.match(
                    (V1, F1), (Vc, Fc), partial=True, landmarks=landmarks, eigenbases=(e1, ec)
                )
            seconds = time.perf_counter() - t0
            offsets = "-"
            if count:
                off = np.linalg.norm(V1[corr.p2p_21[rows]] - V1[orig[rows]], axis=1)
                offsets = f"{off.max() / np.sqrt(e1.area):.3f}"
            verdict = "suspect" if corr.quality.suspect else "ok"
            # why a map is suspect: the first reason's opening words
            why = "-"
            if corr.quality.suspect:
                why = textwrap.shorten(str(corr.quality.reasons[0]), 120)
            print(
                f"| {name} | {count} | {error(V1, corr.p2p_21, orig, e1.area):.4f} | {verdict} "
                f"| {offsets} | {seconds:.1f} | {why} |",
                flush=True,
            )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--only", nargs="*", help="run the cuts whose name contains one of these")
    parser.add_argument("--remeshed", action="store_true", help="also cuts of remeshed bodies")
    parser.add_argument(
        "--dense", type=int, metavar="LEVEL", help="only the cuts, subdivided LEVEL times"
    )
    parser.add_argument("--direct", action="store_true", help="with --dense: also the direct path")
    parser.add_argument(
        "--loop", action="store_true", help="with --dense: Loop subdivision instead of midpoint"
    )
    parser.add_argument(
        "--resolutions",
        metavar="N,N,...",
        help="with --dense: each cut on coarse copies of each of these sizes, no opinion",
    )
    parser.add_argument(
        "--robustness",
        action="store_true",
        help="only the cuts with the target rescaled by 3.5 %%, smoothed, or cut smaller",
    )
    parser.add_argument(
        "--from-truth",
        action="store_true",
        help="only the refinements (partial ZoomOut, polish) from each cut's true map",
    )
    parser.add_argument(
        "--baseline",
        action="store_true",
        help="only the cuts: a partial functional map fit alone, with ZoomOut, and ours",
    )
    parser.add_argument(
        "--landmarks",
        type=int,
        nargs="+",
        metavar="N",
        help="only the cuts, each with N true landmarks (farthest-point target vertices)",
    )
    args = parser.parse_args(argv)
    if not DATA.is_dir():
        sys.stderr.write(f"needs the shared data at {DATA}\n")
        return 2
    if args.from_truth:
        if args.remeshed or args.robustness or args.dense is not None or args.landmarks:
            parser.error("--from-truth runs alone (with --only)")
        truth_rows(args.only)
        return 0
    if args.baseline:
        if args.remeshed or args.robustness or args.dense is not None or args.landmarks:
            parser.error("--baseline runs alone (with --only)")
        print(f"load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores (start)")
        baseline_rows(args.only)
        print(f"load average {os.getloadavg()[0]:.1f} (end)")
        return 0
    if args.landmarks is not None:
        if args.remeshed or args.robustness or args.dense is not None:
            parser.error("--landmarks runs alone (with --only)")
        if any(n < 0 for n in args.landmarks):
            parser.error(f"--landmarks: counts must be >= 0; got {args.landmarks}")
        landmark_rows(args.landmarks, args.only)
        return 0
    if (args.loop or args.resolutions) and args.dense is None:
        parser.error("--loop and --resolutions go with --dense")
    if args.dense is not None:
        if args.dense < 0:
            parser.error(f"--dense: the subdivision level must be >= 0; got {args.dense}")
        print(f"load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores (start)")
        if args.resolutions:
            try:
                sizes = [int(n) for n in args.resolutions.split(",")]
            except ValueError:
                parser.error(f"--resolutions: sizes like 20000,14000,8000; got {args.resolutions}")
            resolution_rows(args.dense, sizes, only=args.only, loop=args.loop)
        else:
            dense_rows(args.dense, only=args.only, direct=args.direct, loop=args.loop)
        print(f"load average {os.getloadavg()[0]:.1f} (end)")
        return 0
    if args.robustness:
        print(f"load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores (start)")
        robustness_rows(args.only)
        print(f"load average {os.getloadavg()[0]:.1f} (end)")
        return 0
    cuts = [c for c in CUTS if not args.only or any(o in c[0] for o in args.only)]
    print(f"load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores (start)")
    print(
        "| cut | kept area | overlap | error partial | full pair | partial=False on cut | "
        "verdict partial / False | distortion (checked) | stretch | s |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|")
    cache: dict[str, tuple] = {}
    notes = []
    for name, a, b, axis, side, fraction in cuts:
        if a not in cache:
            V1, F1 = load(a)
            e1 = ofp.eigenbasis(V1, F1, k=99)
            V2, F2 = load(b)
            e2 = ofp.eigenbasis(V2, F2, k=99)
            full = ofp.match((V1, F1), (V2, F2), eigenbases=(e1, e2))
            cache[a] = (V1, F1, e1, error(V1, full.p2p_21, np.arange(len(V2)), e1.area))
        V1, F1, e1, full_error = cache[a]
        V2, F2 = load(b)
        Vc, Fc, orig, kept = plane_cut(V2, F2, axis=axis, side=side, fraction=fraction)
        ec = ofp.eigenbasis(Vc, Fc, k=99)
        t0 = time.perf_counter()
        part = ofp.match((V1, F1), (Vc, Fc), partial=True, eigenbases=(e1, ec))
        seconds = time.perf_counter() - t0
        whole = ofp.match((V1, F1), (Vc, Fc), eigenbases=(e1, ec))
        qp, qw = part.quality, whole.quality
        print(
            f"| {name} | {kept:.2f} | {qp.overlap:.2f} | "
            f"{error(V1, part.p2p_21, orig, e1.area):.4f} | {full_error:.4f} | "
            f"{error(V1, whole.p2p_21, orig, e1.area):.4f} | "
            f"{'suspect' if qp.suspect else 'ok'} / {'suspect' if qw.suspect else 'ok'} | "
            f"{part.quality.distortion:.3f} | {part.quality.stretch:.2f} | {seconds:.1f} |",
            flush=True,
        )
        notes += [f"{name}, partial=True: {r}" for r in qp.reasons]
        notes += [f"{name}, partial=False: {r}" for r in qw.reasons[:1]]
    others = [c for c in NOT_PARTS if not args.only or any(o in c[0] for o in args.only)]
    if others:
        print("\n| not a part | verdict partial | distortion | stretch |\n|---|---|---|---|")
    for name, a, b, axis, side, fraction in others:
        V1, F1 = load(a)
        e1 = ofp.eigenbasis(V1, F1, k=99)
        V2, F2 = load(b)
        Vc, Fc, _, _ = plane_cut(V2, F2, axis=axis, side=side, fraction=fraction)
        Vc = Vc * np.sqrt(0.7 * e1.area / _areas(Vc, Fc).sum())  # the source's units
        ec = ofp.eigenbasis(Vc, Fc, k=99)
        part = ofp.match((V1, F1), (Vc, Fc), partial=True, eigenbases=(e1, ec))
        print(
            f"| {name} | {'suspect' if part.quality.suspect else 'ok'} | "
            f"{part.quality.distortion:.3f} | {part.quality.stretch:.2f} |",
            flush=True,
        )
        notes += [f"{name}, partial=True: {r}" for r in part.quality.reasons[:1]]
    remeshed = [
        c
        for c in (REMESHED if args.remeshed else [])
        if not args.only or any(o in f"{c[0]} -> {c[1]}" for o in args.only)
    ]
    if remeshed:
        print(
            "\n| remeshed cut | kept area | error partial | verdict | distortion | stretch | s |"
            "\n|---|---|---|---|---|---|---|"
        )
    for a, b, axis, side, fraction in remeshed:
        V1, F1 = load(f"faust_remeshed/{a}.off")
        V2, F2 = load(f"faust_remeshed/{b}.off")
        corres = [
            np.loadtxt(DATA / "faust_remeshed" / "corres" / f"{n}.vts", dtype=np.int64) - 1
            for n in (a, b)
        ]  # 1-based vertex ids, line i of one <-> line i of the other
        Vc, Fc, orig, kept = plane_cut(V2, F2, axis=axis, side=side, fraction=fraction)
        e1 = ofp.eigenbasis(V1, F1, k=99)
        ec = ofp.eigenbasis(Vc, Fc, k=99)
        index = np.full(len(V2), -1)
        index[orig] = np.arange(orig.size)
        rows = index[corres[1]] >= 0
        t0 = time.perf_counter()
        part = ofp.match((V1, F1), (Vc, Fc), partial=True, eigenbases=(e1, ec))
        seconds = time.perf_counter() - t0
        err = error(V1, part.p2p_21[index[corres[1][rows]]], corres[0][rows], e1.area)
        print(
            f"| {a} -> {b} ({'+-'[side < 0]}{'xyz'[axis]} kept) | {kept:.2f} | {err:.4f} | "
            f"{'suspect' if part.quality.suspect else 'ok'} | "
            f"{part.quality.distortion:.3f} | {part.quality.stretch:.2f} | {seconds:.1f} |",
            flush=True,
        )
        notes += [f"{a} -> {b}: {r}" for r in part.quality.reasons[:1]]
    for line in notes:
        print(line)
    print(f"load average {os.getloadavg()[0]:.1f} (end)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
