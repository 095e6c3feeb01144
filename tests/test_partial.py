"""Partial shapes: a part of a shape matched onto the whole (``ofp.match(..., partial=True)``)."""

from __future__ import annotations

import dataclasses
import math
import re
from pathlib import Path

import numpy as np
import pytest

import o3d_ofp as ofp
from o3d_ofp.core._warnings import warnings_logged
from o3d_ofp.core.correspondence import fmap_from_p2p, nearest_neighbors
from o3d_ofp.core.partial import (
    boundary_length,
    curvature_descriptors,
    fit_partial_fmap,
    fit_partial_fmaps,
    geodesic_distortion,
    partial_descriptors,
    partial_p2p,
    partial_polish,
    partial_polish_fit,
    partial_zoomout,
    polish_target_size,
    rescaled,
    slant,
)
from o3d_ofp.core.shapes import blob, icosphere
from o3d_ofp.core.wording import Said
from o3d_ofp.workflows import estimate as estimate_module
from o3d_ofp.workflows import plan as plan_module
from o3d_ofp.workflows.estimate import estimate, estimate_dense, match_eigenbases
from o3d_ofp.workflows.maps import Correspondence
from o3d_ofp.workflows.options import MatchOptions
from o3d_ofp.workflows.partial import PartialMatch, _keep_geodesic_at_jumps, _refine
from o3d_ofp.workflows.quality import MAX_JUMP, map_quality, partial_quality

DATA = Path(__file__).resolve().parents[2] / "shared" / "data"


def plane_cut(V, F, *, axis, fraction):
    """Keep the faces with the largest ``V[:, axis]`` (all corners) up to ``fraction`` of the area.

    Returns the part's vertices and faces and the original index of each kept vertex (the
    ground truth of a map from the part onto the whole).
    """
    areas = 0.5 * np.linalg.norm(np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]]), axis=1)
    order = np.argsort(-V[F, axis].min(axis=1))
    count = int(np.searchsorted(np.cumsum(areas[order]) / areas.sum(), fraction)) + 1
    kept = F[order[:count]]
    keep = np.unique(kept)
    index = np.full(len(V), -1)
    index[keep] = np.arange(keep.size)
    return V[keep], index[kept], keep


@pytest.fixture(scope="module")
def whole():
    V, F = blob(4)  # 2562 vertices, no symmetry
    return V, F, ofp.eigenbasis(V, F, k=99)


@pytest.fixture(scope="module")
def cut(whole):
    V, F, _ = whole
    bent = V.copy()
    bent[:, 1] += 0.15 * bent[:, 0] ** 2  # a bent copy: not an exact part
    Vc, Fc, truth = plane_cut(bent, F, axis=0, fraction=0.65)
    return Vc, Fc, truth, ofp.eigenbasis(Vc, Fc, k=99)


@pytest.fixture(scope="module")
def partial_map(whole, cut):
    V, F, e1 = whole
    Vc, Fc, _, ec = cut
    before = [a.copy() for a in (V, F, Vc, Fc)]
    corr = ofp.match((V, F), (Vc, Fc), partial=True, eigenbases=(e1, ec))
    for a, b in zip((V, F, Vc, Fc), before, strict=True):  # the inputs are not modified
        np.testing.assert_array_equal(a, b)
    return corr


def _error(V, p2p, truth, area):
    return np.linalg.norm(V[p2p] - V[truth], axis=1).mean() / math.sqrt(area)


def _partial(**options):
    """Return the options of a partial match (``MatchOptions(partial=True, ...)``)."""
    return MatchOptions(partial=True, **options)


def _said(items, code):
    """Return the findings of ``items`` (reasons or notes) with this code."""
    return [s for s in items if s.code == code]


def test_cut_of_a_bent_copy_maps_accurately_with_its_overlap(whole, cut, partial_map):
    V, _, e1 = whole
    Vc, _, truth, _ = cut
    corr = partial_map
    assert corr.method == "partial" and corr.options["partial"] is True
    # it never registers the shapes' smooth shells; shells says whether a doubtful map would
    # register the part onto the whole
    assert "same_frame" not in corr.options and corr.options["shells"] is True
    assert corr.p2p_21.shape == (len(Vc),)
    # Measured 0.025 (the vertex spacing is 1/sqrt(2562) = 0.020 of sqrt(area)); the
    # full-shape map on the same cut: 0.35-0.42, the partial fit without its ZoomOut or with
    # the wave kernel alone: 0.3-0.4. 0.05 is two vertex spacings.
    assert _error(V, corr.p2p_21, truth, e1.area) < 0.05
    q = corr.quality
    assert not q.suspect and q.reasons == ()
    # The part keeps 65 % of the (bent, slightly larger) area; its image on the source: the
    # overlap read off the map must be within 0.1 of the true fraction of the source covered.
    covered = e1.mass[np.unique(truth)].sum() / e1.area
    assert abs(q.overlap - covered) < 0.1
    # The report's three fractions each say of what (they read alike: "coverage 0.450 (0.80
    # of the smaller shape)" beside "overlap 0.62").
    summary = q.summary()
    assert f"coverage {q.coverage:.3f} of the source's vertices (" in summary
    assert f"{q.coverage_ratio:.2f} of the smaller shape's count)" in summary
    assert f"overlap {q.overlap:.2f} of the source's area" in summary
    # A restriction map: (k2+1, k1+1) with more source functions than target ones (slant).
    rows, cols = corr.fmap_12.shape
    assert cols > rows


def test_a_part_smaller_than_those_measured_is_suspect_without_landmarks(whole, partial_map):
    """Below half the source's area the map is suspect, unless landmarks were given.

    Measured (scripts/eval_partial.py --robustness): on its cuts kept at 0.25-0.45 of the
    area, 9 of 24 maps were wrong at stop 31, 4 of them passing every check; new-user trials
    of one-sided scans of a body (0.26-0.50 of it): 5 wrong, 3 of them reported ok. With
    landmarks (the trial's front view with five: 0.043) it is a note and a warning.
    """
    import warnings

    from o3d_ofp.workflows.quality import SMALL_PART, small_part_note

    V, F, e1 = whole
    q = partial_map.quality  # 0.65 of the area
    assert "small_part" not in q.codes()
    assert not any("smaller part" in str(t) for t in (*q.notes, *q.reasons))
    Vc, Fc, truth = plane_cut(V, F, axis=0, fraction=0.35)
    ec = ofp.eigenbasis(Vc, Fc, k=99)
    with warnings.catch_warnings(record=True) as said:
        warnings.simplefilter("always")
        corr = ofp.match((V, F), (Vc, Fc), partial=True, eigenbases=(e1, ec))
    assert corr.quality.suspect
    [reason] = _said(corr.quality.reasons, "small_part")
    assert "smaller part" in str(reason)
    assert "0.35 of the source's area" in str(reason) or "0.34 of the source's area" in str(reason)
    assert "give a few known vertex pairs" in str(reason) and "landmarks" in reason.fixes
    assert not _said(corr.quality.notes, "small_part")
    # said once, in the suspect warning
    assert sum("smaller part" in str(w.message) for w in said) == 1
    # with landmarks: a note, the reason gone (the true map here, so no other reason)
    quality = partial_quality(truth, e1, ec, corr.fmap_12, overlap=0.35, landmarks=True)
    assert not quality.suspect, quality.reasons
    [note] = _said(quality.notes, "small_part")
    assert "smaller part" in str(note) and "give more known vertex pairs" in str(note)
    assert partial_quality(truth, e1, ec, corr.fmap_12, overlap=0.35).suspect  # without
    # clustered landmarks (a trial's three pairs around one vertex: 0.089, reported ok) hold
    # the map near them only: they do not lift the flag
    clustered = partial_quality(
        truth, e1, ec, corr.fmap_12, overlap=0.35, landmarks=True, landmarks_spread=False
    )
    assert clustered.suspect and _said(clustered.reasons, "small_part")
    assert small_part_note(SMALL_PART) is None and small_part_note(0.49).code == "small_part"


@pytest.mark.slow  # two partial matches of a smaller cut (52 s)
def test_clustered_landmarks_are_said_and_do_not_lift_the_small_part_flag(whole):
    """Landmarks within a region of one another are said, and count as none for a small part."""
    import warnings

    import o3d_ofp.workflows.quality as workflow

    V, F, e1 = whole
    Vc, Fc, truth = plane_cut(V, F, axis=0, fraction=0.35)
    ec = ofp.eigenbasis(Vc, Fc, k=99)
    scale = np.sqrt(e1.area)
    # three landmarks about 0.1 of sqrt(area) apart: clustered in unit-area units, not in the
    # blob's own (its sqrt(area) is about 3.9), so a wiring without the scaling fails
    d = np.linalg.norm(Vc - Vc[0], axis=1) / scale
    near = np.array([0, np.argmin(np.abs(d - 0.06)), np.argmin(np.abs(d - 0.08))])
    clustered = np.stack([truth[near], near], axis=1)
    far = np.array([0, len(truth) // 2, len(truth) - 1])
    spread = np.stack([truth[far], far], axis=1)
    assert 0.04 < workflow.landmarks_extent(clustered, V / scale) < workflow.MAX_JUMP
    assert workflow.landmarks_extent(clustered, V) > workflow.MAX_JUMP
    assert workflow.landmarks_extent(spread, V / scale) > workflow.MAX_JUMP
    quality, said = {}, {}
    for name, landmarks in (("clustered", clustered), ("spread", spread)):
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            corr = match_eigenbases(e1, ec, options=_partial(landmarks=landmarks))
        quality[name] = corr.quality
        said[name] = [str(w.message) for w in caught if "smaller part" in str(w.message)]
    q = quality["clustered"]
    [note] = _said(q.notes, "landmarks_offset")
    assert str(note).startswith("landmarks:")
    assert "of one another, so they hold the map near them only: spread them" in str(note)
    [small] = [i for i, r in enumerate(q.reasons) if r.code == "small_part"]
    # the small part's reason comes before the advice on the map's own measures, if any
    causes = [i for i, r in enumerate(q.reasons) if str(r).startswith("likely causes")]
    assert all(i > small for i in causes)
    assert len(said["clustered"]) == 1 and "is suspect" in said["clustered"][0]
    q = quality["spread"]
    [note] = _said(q.notes, "landmarks_offset")
    assert str(note).startswith("landmarks:") and "one another" not in str(note)
    assert not _said(q.reasons, "small_part")
    assert _said(q.notes, "small_part")
    assert not q.suspect, q.reasons  # measured: it passes (the match is deterministic)
    # a note, and a warning of its own, once
    assert len(said["spread"]) == 1 and "is suspect" not in said["spread"][0]
    # one landmark holds the map near it only, whatever the size of the part
    one = workflow.landmarks_kept(q, truth, spread[:1], V / scale)
    assert one.notes[-1].code == "landmarks_offset"
    assert str(one.notes[-1]).endswith("one landmark holds the map near it only: give more, "
                                       "spread over the target")  # fmt: skip


@pytest.mark.slow  # a partial match (30 s)
def test_verdict_is_that_of_the_checked_map_and_the_polish_is_said(whole, cut, monkeypatch):
    # The check reads the refined map, not the start the refinement began from: measured on
    # scripts/eval_partial.py, a wrong start (remeshed 007 -> 000, error 0.32) had a lower
    # distortion (0.159) than the start of a right map (019 -> 094 legs removed: 0.206). The
    # map returned is that map polished, which moves no image more than MAX_JUMP and says so.
    import o3d_ofp.workflows.partial as workflow

    V, F, e1 = whole
    Vc, Fc, truth, ec = cut
    checked = []
    polish = workflow._polish

    def recording(p2p, *args, **kwargs):
        checked.append(p2p)
        return polish(p2p, *args, **kwargs)

    monkeypatch.setattr(workflow, "_polish", recording)
    corr = ofp.match((V, F), (Vc, Fc), partial=True, eigenbases=(e1, ec))
    (refined,) = checked
    u1, u2 = rescaled(e1, e1.area), rescaled(ec, e1.area)  # the match's units (round-off)
    again = partial_quality(
        refined, e1, ec, corr.fmap_12, overlap=corr.quality.overlap,
        distortion=geodesic_distortion(refined, u1.vertices, u1.faces, u2.vertices, u2.faces),
    )  # fmt: skip
    said = _said(corr.quality.notes, "polished")
    assert len(said) == 1 and "polished" in str(said[0]) and f"at most {MAX_JUMP}" in str(said[0])
    others = tuple(n for n in corr.quality.notes if n not in said)
    assert dataclasses.replace(corr.quality, notes=others) == again
    assert again.distortion is not None and again.stretch is not None
    root = math.sqrt(e1.area)
    move = np.linalg.norm(V[corr.p2p_21] - V[refined], axis=1) / root
    assert 0 < move.max() <= MAX_JUMP
    # Measured: 0.0233 checked, 0.0231 polished (the true map polished: 0.001, test above).
    assert _error(V, corr.p2p_21, truth, e1.area) < _error(V, refined, truth, e1.area)


@pytest.mark.slow  # a partial match (31 s)
def test_a_part_with_duplicated_vertices_is_matched_as_its_surface(whole, cut, partial_map):
    """A part read with copies of its vertices (an STL's triangle soup, an OBJ's UV seams).

    The partial match's geodesic graph was built on the input's vertices, whose faces name
    one copy of each welded vertex: the other copies were isolated (measured, a FAUST cut as
    a soup: error 0.43 against 0.033 welded). It now runs on the cleaned surface, as the
    full-shape match does.
    """
    V, F, e1 = whole
    Vc, Fc, truth, _ = cut
    soup_V, soup_F = Vc[Fc.ravel()], np.arange(Fc.size).reshape(-1, 3)
    corr = ofp.match((V, F), (soup_V, soup_F), partial=True)
    assert corr.p2p_21.shape == (len(soup_V),) and not corr.quality.suspect
    # the copies of a vertex go where the welded vertex goes (bound of the welded test above)
    assert _error(V, corr.p2p_21, truth[Fc.ravel()], e1.area) < 0.05
    same = corr.p2p_21 == partial_map.p2p_21[Fc.ravel()]
    assert same.mean() > 0.9  # the same surface (renumbered: equal up to round-off)
    # and the counts are the surface's, not the copies' (a soup has 6x the copies)
    ratio = partial_map.quality.coverage_ratio
    assert corr.quality.coverage_ratio == pytest.approx(ratio, abs=0.05)


def test_part_maps_finds_a_turned_part_by_the_least_geodesic_distortion(whole, cut):
    """The extrinsic registration of a part (turned, moved, bent) onto the whole finds it.

    Measured (this blob, its bent cut turned by (150, 40, -70) degrees): the map of least
    geodesic distortion (0.048) is 0.052 sqrt(area) from the truth, the 7 others' starts
    0.155-0.47 (distortions 0.058-0.080): a wrong choice or a lost start fails.
    """
    from scipy.spatial.transform import Rotation

    from o3d_ofp.core.shells import PART_STARTS, part_maps

    V, _, e1 = whole
    Vc, Fc, truth, _ = cut
    turn = Rotation.from_euler("xyz", [150, 40, -70], degrees=True).as_matrix()
    moved = Vc @ turn.T + np.array([3.0, -1.0, 2.0])
    u1, u2 = rescaled(e1, e1.area), rescaled(ofp.eigenbasis(moved, Fc, k=20), e1.area)
    maps = part_maps(u1, u2)
    assert len(maps) == PART_STARTS
    distortions = [geodesic_distortion(m, u1.vertices, u1.faces, u2.vertices, u2.faces)
                   for m in maps]  # fmt: skip
    errors = [_error(V, m, truth, e1.area) for m in maps]
    assert int(np.argmin(distortions)) == int(np.argmin(errors))
    assert min(errors) < 0.08  # four vertex spacings (1/sqrt(2562) = 0.020)


@pytest.mark.slow  # three partial matches (25 s)
def test_a_doubtful_partial_map_registers_the_part_unless_shells_is_false(whole, monkeypatch):
    """A suspect partial map (here a part under half the area) tries the part's registration.

    The registration (stubbed: it returns the true map) replaces the map when its refined map
    changes geodesic distances less (made so at the end; FAUST's back, in a slow test below,
    without stubs), the map flagged either way; without ``shells`` it is not tried.
    """
    import o3d_ofp.workflows.partial as workflow

    V, F, e1 = whole
    Vc, Fc, truth = plane_cut(V, F, axis=0, fraction=0.35)
    ec = ofp.eigenbasis(Vc, Fc, k=99)
    calls = []

    def registered(u1, u2):
        calls.append((u1.n_vertices, u2.n_vertices))
        return [truth.copy()]

    monkeypatch.setattr(workflow, "part_maps", registered)
    corr = ofp.match((V, F), (Vc, Fc), partial=True, eigenbases=(e1, ec))
    assert calls == [(len(V), len(Vc))] and corr.quality.suspect
    # The spectral map is right here (a small part is flagged for its size): the refined true
    # map is the same map (distortion 0.0254 both), and a tie keeps the map, said as such.
    [said] = _said(corr.quality.notes, "part_kept")
    assert said.values["after"] >= said.values["before"] and "is kept" in str(said)
    assert "part_registered" not in corr.quality.codes()
    assert _error(V, corr.p2p_21, truth, e1.area) < 0.05
    calls.clear()
    kept = ofp.match((V, F), (Vc, Fc), partial=True, eigenbases=(e1, ec),
                     options=MatchOptions(shells=False))  # fmt: skip
    assert not calls and kept.options["shells"] is False
    assert not {"part_registered", "part_kept"} & kept.quality.codes()
    # A registration whose refined map changes geodesic distances less replaces the map, and
    # the map stays suspect: here its refinement ends on the true map, made to distort least
    # (the polish left out, so that the refined map is returned as it is).
    real_refined, real_distortions = workflow.PartialMatch._refined, workflow._distortions

    def refined(self, run, p2p):
        C, out = real_refined(self, run, p2p)
        return (C, truth.copy()) if any(p2p is c for c in stub_maps) else (C, out)

    stub_maps = []
    monkeypatch.setattr(workflow, "part_maps", lambda u1, u2: stub_maps.append(truth.copy())
                        or stub_maps)  # fmt: skip
    monkeypatch.setattr(workflow.PartialMatch, "_refined", refined)
    monkeypatch.setattr(workflow, "_polish", lambda p2p, *a, **k: (p2p, 0.0))
    monkeypatch.setattr(workflow, "_distortions", lambda run, p2ps: [
        0.0 if np.array_equal(p2p, truth) else d
        for p2p, d in zip(p2ps, real_distortions(run, p2ps), strict=True)])
    taken = ofp.match((V, F), (Vc, Fc), partial=True, eigenbases=(e1, ec))
    assert len(stub_maps) == 1 and taken.quality.suspect
    [found] = _said(taken.quality.reasons, "part_registered")
    assert found.values["after"] == 0.0 < found.values["before"]
    np.testing.assert_array_equal(taken.p2p_21, truth)


def test_start_kept_when_the_refinement_turns_it_over_is_flagged(
    whole, cut, monkeypatch, caplog
):
    import logging

    import o3d_ofp.workflows.partial as workflow

    V, _, e1 = whole
    _, _, truth, ec = cut
    seen = {}

    def mirrored(p2p, *args, **kwargs):  # the refinement ends on a mirror image of the start
        seen.setdefault("start", p2p.copy())  # the chosen start (the next ones follow it)
        seen["calls"] = seen.get("calls", 0) + 1
        C, _ = _refine(p2p, *args, **kwargs)
        return C, nearest_neighbors(V, V[p2p] * np.array([-1.0, 1.0, 1.0]))

    monkeypatch.setattr(workflow, "_refine", mirrored)
    with caplog.at_level(logging.WARNING, logger="o3d_ofp"), warnings_logged():
        # (shells=False: the doubtful map's registration, which refines its map too, not here)
        corr = match_eigenbases(e1, ec, options=_partial(k_fit=15, shells=False))
    # The warning gives each reason on its own line (it was one line of ~600 characters).
    (warning,) = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    reasons = corr.quality.reasons
    assert warning.split("\n") == ["the partial map is suspect:", *(f"  - {r}" for r in reasons)]
    np.testing.assert_array_equal(corr.p2p_21, seen["start"])  # the start, unrefined
    assert corr.options["refined"] is False and corr.options["polish"] is False  # not polished
    # the next orientation-preserving starts were tried (all turned over), at most NEXT_STARTS
    assert 1 < seen["calls"] <= 1 + workflow.NEXT_STARTS
    # Measured on scripts/eval_partial.py: the refinement turned 56 % and 48 % of the
    # triangles of the two wrong remeshed maps over, 8-22 % of the right ones'.
    assert corr.quality.suspect
    (turned,) = _said(corr.quality.reasons, "refinement_turned")
    assert "turned" in str(turned) and "kept unrefined" in str(turned)
    C = corr.fmap_12
    q = partial_quality(truth, e1, ec, C, overlap=0.65, refinement_turned=0.2)
    assert "refinement_turned" not in q.codes()
    assert not any("kept unrefined" in str(r) for r in q.reasons)


@pytest.mark.slow  # two partial matches (34 s)
def test_next_start_needs_an_oriented_refinement_and_fewer_changed_distances(
    whole, cut, monkeypatch
):
    """The fallback of NEXT_STARTS keeps a next start only if it beats the chosen one.

    A review: with the chosen start's refinement made to turn over, the blob cut's next start
    refined to a wrong map (error 0.42, distortion 0.055) that passed every check. Its
    distortion is above the chosen start's: the flagged start stays. When the next start is
    the better one (its distortion lowered here), it is kept, with a note. Measured on
    eval_partial.py: remeshed 002 -> 004 (0.057, flagged) keeps its start ranked 3: 0.017, ok.
    (``shells=False`` throughout: a flagged map's registration of the part is another step.)
    """
    import o3d_ofp.workflows.partial as workflow
    from o3d_ofp.workflows.matching import DCOMM_WEIGHTS

    V, _, e1 = whole
    ec = cut[3]
    inputs, outputs = [], []

    def first_mirrored(p2p, *args, **kwargs):
        C, refined = _refine(p2p, *args, **kwargs)
        if not outputs:  # only the best-ranked start's refinement ends on a mirror image
            refined = nearest_neighbors(V, V[p2p] * np.array([-1.0, 1.0, 1.0]))
        inputs.append(p2p.copy())
        outputs.append(refined)
        return C, refined

    monkeypatch.setattr(workflow, "_refine", first_mirrored)
    corr = estimate(e1, ec, options=_partial(k_fit=15, shells=False), warn_suspect=False)
    assert 1 < len(outputs) <= 1 + workflow.NEXT_STARTS
    # the chosen start stays, unrefined and flagged (here wrong: measured 0.46; refined 0.04)
    np.testing.assert_array_equal(corr.p2p_21, inputs[0])
    assert "refinement_turned" in {r.code for r in corr.quality.reasons}
    # The next start made to look better: kept, its own weight, said in a note (the final
    # polish left out, so that the kept refinement is returned as it is)
    inputs.clear()
    outputs.clear()
    monkeypatch.setattr(workflow, "_polish", lambda p2p, *a, **k: (p2p, 0.0))
    real = workflow._distortions
    monkeypatch.setattr(workflow, "_distortions", lambda run, p2ps: [
        0.0 if len(outputs) == 2 and np.array_equal(p2p, outputs[1]) else d
        for p2p, d in zip(p2ps, real(run, p2ps), strict=True)])
    corr = estimate(e1, ec, options=_partial(k_fit=15, shells=False), warn_suspect=False)
    # the second refinement is kept; the rival starts' refinements come after it
    assert 2 <= len(outputs) <= 2 + workflow.RIVAL_STARTS
    np.testing.assert_array_equal(corr.p2p_21, outputs[1])
    assert corr.options["w_dcomm"] in DCOMM_WEIGHTS
    assert "refinement_turned" not in {r.code for r in corr.quality.reasons}
    (note,) = _said(corr.quality.notes, "next_start")
    assert "the start ranked 2" in str(note) and "is kept instead" in str(note)


def test_refinement_repairs_a_torn_map(whole, cut):
    V, _, e1 = whole
    Vc, _, truth, ec = cut
    u1, u2 = rescaled(e1, e1.area), rescaled(ec, e1.area)
    # The true map with the top 30 % of the part sent to the opposite side of the source.
    torn = truth.copy()
    region = Vc[:, 1] > np.quantile(Vc[:, 1], 0.7)
    torn[region] = nearest_neighbors(V, 2 * V.mean(axis=0) - V[truth[region]])
    k2_final = 40
    C, p2p = _refine(torn, u1, u2, k2_fit=15, k2_final=k2_final, subsample=None)
    assert C.shape == (k2_final + 1, slant(u1.evals, u2.evals, k2_final) + 1)
    # Measured: torn 0.18, refined 0.015. 0.05 is two vertex spacings (as for the full match).
    assert _error(V, torn, truth, e1.area) > 0.15
    assert _error(V, p2p, truth, e1.area) < 0.05


@pytest.mark.parametrize("subsample", [None, 1500])  # the cut has 1716 vertices, the whole 2562
def test_polish_keeps_the_true_map_and_sharpens_a_noisy_one(whole, cut, subsample):
    V, _, e1 = whole
    _, _, truth, ec = cut
    u1, u2 = rescaled(e1, e1.area), rescaled(ec, e1.area)
    # The partial ZoomOut drifts from the true map (the slanted fit represents the source's
    # functions only roughly near the cut): measured 0.015-0.017 at every final size.
    C = fmap_from_p2p(truth, u1, u2, k1=slant(u1.evals, u2.evals, 15), k2=15)
    C = partial_zoomout(C, u1, u2, k2_final=40, subsample=None)
    k1 = C.shape[1] - 1
    assert _error(V, partial_p2p(C, u1, u2), truth, e1.area) > 0.01
    # With twice the slant's target functions the fit holds the true map: measured 0.001 (a
    # tenth of a vertex spacing on average); a map with noise of 0.03 sqrt(area) (0.038): 0.001.
    kept, fmap = partial_polish(truth, u1, u2, k1_final=k1, subsample=subsample)
    assert fmap.shape == (polish_target_size(u1.evals, u2.evals, k1) + 1, k1 + 1)
    assert _error(V, kept, truth, e1.area) < 0.005
    rng = np.random.default_rng(0)
    noise = rng.normal(scale=0.03 * math.sqrt(e1.area), size=(truth.size, 3))
    noisy = nearest_neighbors(V, V[truth] + noise)
    assert _error(V, noisy, truth, e1.area) > 0.03
    polished, _ = partial_polish(noisy, u1, u2, k1_final=u1.k, subsample=subsample)
    assert _error(V, polished, truth, e1.area) < 0.005


def test_polish_nested_qr_fits_equal_least_squares(whole, cut, monkeypatch):
    """The polish factors the target basis once (nested QR); its fits are lstsq's.

    Forcing the fallback (a factor with a zero on R's diagonal: ``lstsq`` on every fit) must
    give the same point map and the same last fit.
    """
    V, _, e1 = whole
    _, _, truth, ec = cut
    u1, u2 = rescaled(e1, e1.area), rescaled(ec, e1.area)
    rng = np.random.default_rng(1)
    noise = rng.normal(scale=0.03 * math.sqrt(e1.area), size=(truth.size, 3))
    noisy = nearest_neighbors(V, V[truth] + noise)
    import scipy.linalg

    solves = []
    real_solve = scipy.linalg.solve_triangular
    monkeypatch.setattr(
        scipy.linalg, "solve_triangular", lambda *a, **k: solves.append(1) or real_solve(*a, **k)
    )
    nested, C_nested = partial_polish(noisy, u1, u2, k1_final=40, subsample=1500)
    assert len(solves) > 1  # the nested solves ran
    solves.clear()
    real_qr = np.linalg.qr

    def singular_qr(a):
        Q, R = real_qr(a)
        R = R.copy()
        R[-1, -1] = 0.0  # below the nested solve's rank test: lstsq on every fit
        return Q, R

    monkeypatch.setattr(np.linalg, "qr", singular_qr)
    fallback, C_fallback = partial_polish(noisy, u1, u2, k1_final=40, subsample=1500)
    assert not solves  # lstsq only
    np.testing.assert_array_equal(nested, fallback)
    # the same least-squares problems solved two ways: equal to round-off (the basis columns
    # are well conditioned: mass-orthonormal eigenfunctions on 1500 samples)
    np.testing.assert_allclose(C_nested, C_fallback, rtol=0, atol=1e-8 * np.abs(C_nested).max())


def test_geodesic_map_is_kept_where_the_spectral_map_jumps():
    line = np.zeros((5, 3))
    line[:, 0] = [0.0, 0.1, 0.2, 0.5, 1.0]  # source vertices (unit-area units) on a line
    geodesic = np.array([0, 1, 2, 3])
    spectral = np.array([1, 4, 2, 0])  # jumps of 0.1, 0.9, 0, 0.5
    assert 0.1 < MAX_JUMP < 0.5
    kept = _keep_geodesic_at_jumps(spectral, geodesic, line)
    np.testing.assert_array_equal(kept, [1, 1, 2, 3])


def test_full_shape_map_of_a_part_is_flagged_with_the_fix(whole, cut):
    V, F, e1 = whole
    Vc, Fc, _, ec = cut
    corr = ofp.match((V, F), (Vc, Fc), eigenbases=(e1, ec), options=MatchOptions(zoomout_to=30))
    assert corr.quality.suspect
    (reason,) = _said(corr.quality.reasons, "looks_partial")
    assert "looks like a part" in str(reason) and "partial" in reason.fixes
    assert "partial=True" in str(reason) and "--partial" in reason.text(cli=True)
    # The part as the source and the whole as the target: the fix says to swap them.
    q = map_quality(np.zeros(len(V), dtype=np.int64), ec, e1)
    (reason,) = _said(q.reasons, "looks_partial")
    assert "swap" in str(reason)


def test_a_part_in_other_units_is_told_to_be_rescaled(whole, cut):
    """A part in millimetres onto a whole in metres: larger, but with the more boundary.

    A trial's cut x1000, matched without partial=True, was told only "not near-isometric".
    """
    V, F, e1 = whole
    Vc, _, _, ec = cut
    for scale in (1000.0, 0.001):  # the part larger, then the whole larger, in area
        e2 = rescaled(ec, scale**-2)  # area x scale²
        q = map_quality(np.zeros(len(Vc), dtype=np.int64), e1, e2)
        [reason] = [r for r in q.reasons if r.code in ("looks_partial", "looks_partial_units")]
        assert reason.code == ("looks_partial_units" if scale > 1 else "looks_partial")
        assert "looks like a part" in str(reason)
        assert ("in other units" in str(reason)) == (scale > 1) and "partial=True" in str(reason)
        assert q.suspect
    # The whole as the target in other units: the part (the source) is named, swap said.
    q = map_quality(np.zeros(len(V), dtype=np.int64), ec, rescaled(e1, 1e-6))
    assert any(
        "the source looks like a part" in str(r) and "swap" in str(r)
        for r in q.reasons if r.code.startswith("looks_partial")
    )  # fmt: skip
    # A whole with small holes (a scan's) in other units is no part: its boundary is made of
    # short curves (a review: the total boundary flagged a FAUST body with three holes).
    centres = V[[0, len(V) // 3, 2 * len(V) // 3]]
    near = np.linalg.norm(V[F].mean(axis=1)[:, None] - centres, axis=2).min(axis=1) < 0.15
    assert 0 < near.sum() < 0.05 * len(F)
    holed = ofp.eigenbasis(V, F[~near], k=10)
    assert boundary_length(V, F[~near]) / math.sqrt(holed.area) > 0.6  # above the 0.4 bound
    for scale in (1000.0, 0.001):
        q = map_quality(np.arange(len(V)), e1, rescaled(holed, scale**-2))
        assert not {"looks_partial", "looks_partial_units"} & q.codes(), q.reasons
        assert not any("looks like a part" in str(r) for r in q.reasons), q.reasons


def test_a_cloud_of_another_area_is_said_to_be_perhaps_a_part(whole, cut):
    """A cloud's boundary is not measured: a smaller cloud gets a warned note, not a flag.

    A trial's one-sided cloud (0.76 of the source's area) was matched wrong (0.22) in silence.
    """
    V, _, e1 = whole
    Vc, _, _, _ = cut
    cloud = ofp.eigenbasis(Vc, None, k=99)
    with pytest.warns(ofp.OFPWarning, match="a point cloud's boundary is not measured"):
        corr = match_eigenbases(e1, cloud, options=MatchOptions(zoomout_to=30))
    (note,) = _said(corr.quality.notes, "cloud_part")
    assert "mesh both and match with o3d_ofp.match(..., partial=True)" in str(note)
    assert "partial" in note.fixes
    # A whole cloud of about the source's area, or one in other units (inches against
    # centimetres: 6.45 in area, the smallest change of units): no such note.
    for scale in (1.0, 2.54, 1000.0):
        whole_cloud = ofp.eigenbasis(V * scale, None, k=20)
        q = map_quality(np.arange(len(V)), e1, whole_cloud)
        assert "cloud_part" not in q.codes()
        assert not any("boundary is not measured" in str(n) for n in q.notes)


def test_scaled_whole_shape_is_not_flagged(whole):
    V, F, e1 = whole
    e2 = ofp.eigenbasis(V * 30.0, F, k=10)
    # other units, same shape: the identity is the right map and is not suspect; a note only
    q = map_quality(np.arange(len(V)), e1, e2)
    (note,) = _said(q.notes, "area_ratio")
    assert not q.suspect and "units" in str(note)
    assert q.overlap is None
    assert "target_scale" not in note.fixes  # 30 is no power of ten: no units change to advise


def test_a_target_in_millimetres_is_told_the_factor_that_gives_it_the_source_s_units(whole):
    """A trial: a target in millimetres got "different units?" without the flag that fixes it."""
    V, F, e1 = whole
    for scale, factor, change in ((1000.0, "0.001", "millimetres to metres"),
                                  (0.01, "100", "metres to centimetres")):  # fmt: skip
        (note,) = _said(map_quality(np.arange(len(V)), e1,
                                    ofp.eigenbasis(V * scale, F, k=10)).notes, "area_ratio")
        assert note.fixes == ("target_scale",)
        assert f"({change}), --target-scale {factor} gives it" in note.text(cli=True)
        assert f"target.scale({factor}, center=(0, 0, 0))" in note.text()


def test_target_larger_than_the_source_is_flagged(whole, cut):
    e1, ec = whole[2], cut[3]
    # The whole, twice as large as the source (the part): it cannot be a part of it.
    big = rescaled(e1, 0.25)  # coordinates x2 (area x4) in the part's units
    corr = match_eigenbases(ec, big, options=_partial(k_fit=8, zoomout_to=10, w_orient=0.0))
    assert corr.quality.suspect
    (reason,) = _said(corr.quality.reasons, "part_larger")
    assert "cannot be a part" in str(reason)


def test_save_load_keeps_partial(partial_map, tmp_path):
    path = tmp_path / "partial.npz"
    partial_map.save(path)
    back = Correspondence.load(path)
    assert back.method == "partial" and back.options["partial"] is True
    np.testing.assert_array_equal(back.p2p_21, partial_map.p2p_21)
    np.testing.assert_array_equal(back.fmap_12, partial_map.fmap_12)
    assert back.quality == partial_map.quality


@pytest.fixture
def no_eigensolve(monkeypatch):
    from o3d_ofp.core import spectrum

    def refuse(*args, **kwargs):
        raise AssertionError("an eigensolve ran before the refusal")

    monkeypatch.setattr(spectrum, "_solve", refuse)


@pytest.mark.parametrize(
    ("kwargs", "error", "match"),
    [
        ({"partial": "yes"}, TypeError, "partial must be True or False"),
        ({"partial": True, "method": "closest"}, ValueError, "partial applies to method='estim"),
        ({"partial": True, "k_fit": 0}, ValueError, "k_fit must be"),
        ({"partial": True, "zoomout_to": 2.5}, ValueError, "zoomout_to must be"),
        ({"partial": True, "descriptors": "hks"}, ValueError, "descriptors must be one of 'wks';"),
        ({"partial": True, "w_orient": -1.0}, ValueError, "w_orient must be"),
        ({"partial": True, "zoomout_subsample": 1}, ValueError, "zoomout_subsample"),
        ({"partial": True, "landmarks": [[0, 10**6]]}, ValueError, "target vertex indices"),
    ],
)
def test_bad_keywords_are_refused_before_any_eigensolve(no_eigensolve, kwargs, error, match):
    """Refused naming the keyword: match()'s own ones, and the estimation's (MatchOptions)."""
    V, F = icosphere(2)
    keywords = {k: v for k, v in kwargs.items() if k in ("partial", "method", "landmarks")}
    estimation = {k: v for k, v in kwargs.items() if k not in keywords}
    with pytest.raises(error, match=match) as info:
        options = MatchOptions(**estimation, partial=True) if estimation else None
        ofp.match((V, F), (V, F), options=options, **keywords)
    # the keyword refused (a partial match by closest points: partial, which needs an estimate)
    assert info.value.option == ("partial" if "method" in kwargs else list(kwargs)[-1])


def test_a_part_larger_than_the_whole_is_refused_before_any_eigensolve(no_eigensolve):
    """Source and target swapped (the whole given as the part): said at once, with the fix."""
    V, F = icosphere(2)
    half = F[(V[F].mean(axis=1)[:, 2] > 0)]
    with pytest.raises(ValueError, match="Swap source and target") as info:
        ofp.match((V, half), (V, F), partial=True)  # the cut as source: 2x smaller
    assert info.value.said.code == "part_larger"
    assert "the target has 2" in str(info.value)
    assert "times the area of the source" in str(info.value)


def test_a_part_larger_than_the_whole_is_refused_by_the_command_line(
    no_eigensolve, tmp_path, capsys
):
    """The command line says it with the files' names, before any eigensolve."""
    from o3d_ofp.boundary.convert import triangle_mesh_from_arrays
    from o3d_ofp.cli import main

    V, F = icosphere(2)
    half = F[(V[F].mean(axis=1)[:, 2] > 0)]
    paths = [str(tmp_path / "part.ply"), str(tmp_path / "whole.ply")]
    ofp.write_geometry(paths[0], triangle_mesh_from_arrays(V, half))
    ofp.write_geometry(paths[1], triangle_mesh_from_arrays(V, F))
    argv = ["transfer", *paths, "--partial", "--signal", "xyz", "-o", str(tmp_path / "o.ply")]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert "whole.ply has" in err and "times the area of" in err and "Swap" in err
    assert not (tmp_path / "o.ply").exists()


def test_a_part_in_much_smaller_units_names_the_area_ratio_and_the_fix(whole, cut, monkeypatch):
    from o3d_ofp.core import spectrum
    from o3d_ofp.workflows.partial import MIN_AREA_RATIO

    V, F, e1 = whole
    Vc, Fc, _, _ = cut
    tiny = ofp.eigenbasis(Vc / 1000, Fc, k=99)  # millimetres read as metres, say
    with pytest.raises(ValueError, match=r"spectra do not overlap.*6\.\d+e-07 times.*rescale"):
        match_eigenbases(e1, tiny, options=_partial())
    # From the shapes, before any eigensolve (it came after both).
    assert 6.5e-7 < MIN_AREA_RATIO <= 0.05  # the cuts of eval_partial keep 0.55-0.8
    monkeypatch.setattr(spectrum, "_solve", lambda *a, **k: pytest.fail("eigensolve"))
    with pytest.raises(ValueError, match=r"6\.\d+e-07 times the area.*Rescale the target") as info:
        ofp.match((V, F), (Vc / 1000, Fc), partial=True)
    said = info.value.said
    assert said.code == "part_too_small" and "target_scale" in said.fixes
    # the factor is given (a trial: the refusal did not say by how much), worded for Python
    # (Open3D's scale) and for the command line (its flag)
    assert "multiply its coordinates by 1000 (metres to millimetres: Open3D's target.scale(1000"\
        in str(info.value)  # fmt: skip
    assert "multiply its coordinates by 1000 (metres to millimetres: --target-scale 1000), which "\
        "makes its area 0.6" in said.text(cli=True)  # fmt: skip
    # a source and target swapped (area ratio 1.5): no units hint
    with pytest.raises(ValueError, match="Swap source and target") as info:
        ofp.match((Vc, Fc), (V, F), partial=True)
    assert info.value.said.code == "part_larger"
    assert "multiply its coordinates" not in str(info.value)
    assert "target_scale" not in info.value.said.fixes


def test_a_part_in_much_smaller_units_is_told_the_flag_by_the_command_line(
    whole, cut, tmp_path, capsys, monkeypatch
):
    """With the file names, before any eigensolve; with the flag it names, the run goes on."""
    from o3d_ofp.boundary.convert import triangle_mesh_from_arrays
    from o3d_ofp.cli import main
    from o3d_ofp.core import spectrum

    V, F, e1 = whole
    Vc, Fc, _, _ = cut
    monkeypatch.setattr(spectrum, "_solve", lambda *a, **k: pytest.fail("eigensolve"))
    paths = [tmp_path / "whole.ply", tmp_path / "part_mm.ply"]
    ofp.write_geometry(paths[0], triangle_mesh_from_arrays(V, F))
    ofp.write_geometry(paths[1], triangle_mesh_from_arrays(Vc / 1000, Fc))
    out = tmp_path / "o.ply"
    argv = ["transfer", *map(str, paths), "--partial", "--signal", "xyz", "-o", str(out)]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert f"{paths[1]} has 6." in err and "Rescale the target" in err and not out.exists()
    # the factor is given (a trial: the refusal did not say by how much)
    assert "multiply its coordinates by 1000 (metres to millimetres: --target-scale 1000), which "\
        "makes its area 0.6" in err
    # with the flag the CLI names, the run goes on (eigensolves allowed again): the source's
    # coordinates sent to the part land near the part's own places on the whole (a right map)
    monkeypatch.undo()
    assert main([*argv, "--target-scale", "1000", "--k1", "12", "--k2", "12"]) == 0
    # (written in the target's own units, as the flag says: a thousandth of the source's)
    sent = np.asarray(ofp.read_geometry(out).vertices)
    assert np.linalg.norm(1000 * sent - Vc, axis=1).mean() < 0.1 * np.sqrt(e1.area)


def test_match_eigenbases_checks_its_inputs_for_a_partial_match(whole):
    V, F, e1 = whole
    with pytest.raises(TypeError, match="eig_2 must be an EigenBasis"):
        match_eigenbases(e1, (V, F), options=_partial())
    small = ofp.eigenbasis(V, F, k=10)
    with pytest.raises(ValueError, match="source eigenbasis has 10 eigenfunctions") as info:
        match_eigenbases(small, e1, options=_partial())
    assert info.value.option == "eigenbases" and "the partial match needs 99" in str(info.value)
    with pytest.raises(ValueError, match="target eigenbasis has 10 eigenfunctions"):
        match_eigenbases(e1, small, options=_partial(k_fit=15))  # the target needs k_fit


def test_fits_sharing_the_descriptors_equal_the_fits_computing_them(whole, cut):
    _, _, e1 = whole
    _, _, _, ec = cut
    u1, u2 = rescaled(e1, e1.area), rescaled(ec, e1.area)
    shared = partial_descriptors(u1, u2)
    for solver in ("lbfgs", "direct"):
        alone = fit_partial_fmap(u1, u2, k2=8, solver=solver)
        given = fit_partial_fmap(u1, u2, k2=8, solver=solver, descriptors=shared)
        # the same computation on one BLAS thread: equal to the last bit
        for a, b in zip(alone, given, strict=True):
            np.testing.assert_array_equal(a, b)
    # the given descriptors are the ones used: scaled ones weigh the data term differently
    scaled = fit_partial_fmap(
        u1, u2, k2=8, solver="direct", descriptors=tuple(2 * D for D in shared)
    )
    assert not np.allclose(scaled[0], given[0])
    other = partial_descriptors(u1, u2, landmarks=np.array([[0, 0], [5, 7]]))
    assert other[0].shape[1] > shared[0].shape[1]  # the landmarks' columns: not the same set
    with pytest.raises(ValueError, match="descriptors must be"):
        fit_partial_fmap(u1, u2, k2=8, descriptors=(shared[1], shared[0]))  # swapped


def test_fits_of_several_sizes_equal_the_fits_built_at_their_own_sizes(whole, cut):
    _, _, e1 = whole
    _, _, _, ec = cut
    u1, u2 = rescaled(e1, e1.area), rescaled(ec, e1.area)
    shared = partial_descriptors(u1, u2)
    fits = [(5, "direct"), (12, "direct"), (8, "lbfgs")]
    reported: list[int] = []
    together = fit_partial_fmaps(u1, u2, fits=fits, descriptors=shared, report=reported.append)
    assert reported == [0, 1, 2]
    for (k2, solver), maps in zip(fits, together, strict=True):
        # the reference: the operators built at this fit's own sizes (a fit list of one)
        [alone] = fit_partial_fmaps(u1, u2, fits=[(k2, solver)], descriptors=shared)
        k1 = slant(u1.evals, u2.evals, k2)
        for a, b in zip(maps, alone, strict=True):
            assert a.shape == (k2 + 1, k1 + 1)
            # leading blocks of larger operators are the smaller operators up to the order
            # of the sums (1e-15 relative); the exact solves keep that, L-BFGS-B's stopping
            # test can amplify it: 1e-6 of the map's largest entry bounds both here
            np.testing.assert_allclose(a, b, atol=1e-6 * np.abs(b).max())
    # the one-fit function is the one-fit case: the same computation, to the last bit
    np.testing.assert_array_equal(
        fit_partial_fmap(u1, u2, k2=5, solver="direct", descriptors=shared)[0],
        fit_partial_fmaps(u1, u2, fits=[(5, "direct")], descriptors=shared)[0][0],
    )
    with pytest.raises(ValueError, match="solver must be"):
        fit_partial_fmaps(u1, u2, fits=[(5, "exact")], descriptors=shared)
    with pytest.raises(ValueError, match="at least one"):
        fit_partial_fmaps(u1, u2, fits=[], descriptors=shared)


def test_slant_follows_the_area_ratio(whole, cut):
    _, _, e1 = whole
    _, _, _, ec = cut
    u1, u2 = rescaled(e1, e1.area), rescaled(ec, e1.area)
    r = u2.area
    # Weyl's law: a part of area ratio r has 1/r times the eigenvalues below a frequency;
    # at k2 = 40 the slant must be within 25 % of 40 / r (low eigenvalues deviate from Weyl).
    k1 = slant(u1.evals, u2.evals, 40)
    assert abs(k1 - 40 / r) < 0.25 * 40 / r
    assert slant(u1.evals, u1.evals, 40) == 40  # the whole onto itself: the diagonal


def test_boundary_length_and_curvature_of_a_sphere():
    V, F = icosphere(4)
    assert boundary_length(V, F) == 0.0  # closed
    square = np.array([[0.0, 0, 0], [2, 0, 0], [2, 1, 0], [0, 1, 0]])
    assert boundary_length(square, np.array([[0, 1, 2], [0, 2, 3]])) == pytest.approx(6.0)
    eig = ofp.eigenbasis(V, F, k=5)
    D = curvature_descriptors(eig, scales=(1e-4,))
    # unit sphere: |H| = 1 and K = 1 everywhere; measured within 0.1 % at the regular
    # (valence-6) vertices and 13 % at the icosahedron's 12 valence-5 ones
    for col in (0, 1):
        assert np.median(D[:, col]) == pytest.approx(1.0, rel=0.01)
        assert np.abs(D[:, col] - 1).max() < 0.15


def test_dense_path_extends_the_restriction_map_as_its_own_point_map(whole, cut):
    from o3d_ofp.core.multiscale import extend_p2p

    V, _, e1 = whole
    Vc, _, _, ec = cut
    # the map handed to the extension: the coarse strategy's (unpolished, in extend_p2p's terms)
    given = estimate(e1, ec, options=_partial(k_fit=15), strategy=PartialMatch().for_coarse())
    assert given.options["polish"] is False
    C = given.fmap_12 * (e1.area / ec.area)  # the restriction map itself
    expected = partial_p2p(C, rescaled(e1, e1.area), rescaled(ec, e1.area))
    # coarse copies that are the shapes themselves: the extension is the point map
    np.testing.assert_array_equal(extend_p2p(given.fmap_12, e1, ec, V, Vc), expected)
    unscaled = extend_p2p(C, e1, ec, V, Vc)  # read as a map between own-unit bases: off
    assert np.mean(unscaled != expected) > 0.02
    # the polish's fit (made on bases in the source's units) read off by the adjoint extension
    # in the shapes' own units: the direct path's polished map
    u1, u2 = rescaled(e1, e1.area), rescaled(ec, e1.area)
    k1 = given.fmap_12.shape[1] - 1
    fit = partial_polish_fit(given.p2p_21, u1, u2, k1_final=k1)
    polished, last = partial_polish(given.p2p_21, u1, u2, k1_final=k1)
    np.testing.assert_array_equal(fit, last)
    np.testing.assert_array_equal(extend_p2p(fit, e1, ec, V, Vc, adjoint=True), polished)


@pytest.fixture
def blob_made_dense(monkeypatch):
    """Make the 2562-vertex blob "dense" (above 1000 vertices, coarse copies of 800)."""
    monkeypatch.setattr(plan_module, "DENSE_VERTICES", 1000)
    monkeypatch.setattr(estimate_module, "COARSE_VERTICES", 800)


def _dense_partial(V1, F1, V2, F2, *, polish=True, **keywords):
    """Run the dense partial match (``estimate_dense``), its strategy polished or not.

    ``PartialMatch(polish=False)`` is the unpolished strategy; ``estimate_dense`` takes its
    strategy from the options, so it is swapped in for the call.
    """
    with pytest.MonkeyPatch.context() as patch:
        if not polish:
            unpolished = lambda options: PartialMatch(polish=False)  # noqa: E731
            patch.setattr(estimate_module, "strategy_of", unpolished)
        return estimate_dense(V1, F1, V2, F2, **keywords)


def _counted_runs(monkeypatch, change=None):
    """Record the coarse size of every coarse match of the dense path (``change`` may alter it)."""
    runs, maps = [], []
    real = estimate_module._match_dense

    def counted(*args, **options):
        corr = real(*args, **options)
        runs.append(options["coarse_vertices"])
        if change is not None:
            corr = change(len(runs), corr)
        maps.append(corr.p2p_21)
        return corr

    monkeypatch.setattr(estimate_module, "_match_dense", counted)
    return runs, maps


def _kept(p2p, landmarks):
    """``p2p`` with the landmarks' pairs kept exactly, as the result of a match keeps them."""
    p2p = np.array(p2p)
    p2p[landmarks[:, 1]] = landmarks[:, 0]
    return p2p


def _send_a_landmark_far(monkeypatch, V, landmarks):
    """Make the full map send the second landmark's target vertex far; return where, and more.

    The target vertex goes to the source vertex farthest from the landmark's source vertex;
    the real extension is returned to be put back.
    """
    import o3d_ofp.workflows.partial as workflow

    source, target = landmarks[1]
    far = int(np.argmax(np.linalg.norm(V - V[source], axis=1)))
    real_extend = workflow._extend_partial

    def moving(corr, *args, **options):
        p2p, corr = real_extend(corr, *args, **options)
        p2p = p2p.copy()
        p2p[target] = far
        return p2p, corr

    monkeypatch.setattr(workflow, "_extend_partial", moving)
    return far, real_extend


def _three_landmarks(truth: np.ndarray) -> np.ndarray:
    """Three known (source, target) pairs of the cut: first, middle and last target vertex.

    A near-spherical blob's part can be matched turned (a known limit of the check);
    landmarks fix the turn, so the error measures the dense path itself.
    """
    rows = np.array([0, len(truth) // 2, len(truth) - 1])
    return np.stack([truth[rows], rows], axis=1)


@pytest.mark.slow  # partial matches with landmarks (49 s)
def test_a_partial_map_that_does_not_keep_the_landmarks_is_flagged(whole, cut):
    """The landmarks enter the fit only; a map that moves one over MAX_JUMP away is suspect.

    Measured (``eval_partial.py --landmarks 3 5``, true pairs): FAUST 019 -> 094 one side
    removed sent one 0.24 of sqrt(area) from its given source vertex, silently.
    """
    V, _, e1 = whole
    _, _, truth, ec = cut
    good = _three_landmarks(truth)
    corr = estimate(e1, ec, options=_partial(landmarks=good), warn_suspect=False)
    (note,) = _said(corr.quality.notes, "landmarks_offset")
    assert str(note).startswith("landmarks:")
    kept = float(re.search(r"at most ([0-9.]+) of sqrt", str(note)).group(1))
    assert kept <= MAX_JUMP and note.values["off"] <= MAX_JUMP
    assert "landmarks_far" not in corr.quality.codes()
    assert not any("landmarks' target vertices" in str(r) for r in corr.quality.reasons)
    # one pair wrong: its source vertex the farthest from the true one
    bad = good.copy()
    bad[1, 0] = int(np.argmax(np.linalg.norm(V - V[truth[bad[1, 1]]], axis=1)))
    corr = estimate(e1, ec, options=_partial(landmarks=bad), warn_suspect=False)
    assert corr.quality.suspect
    (reason,) = _said(corr.quality.reasons, "landmarks_far")
    assert "of the 3 landmarks' target vertices more than 0.15 of sqrt(source area)" in str(reason)
    far_rows = re.search(r"pairs ([0-9, ]+) of the landmarks, counting from 1", str(reason))
    assert "2" in far_rows.group(1).split(", ")  # the wrong pair is named
    assert "check those pairs" in str(reason)
    assert corr.quality.reasons[0] == reason  # first: map_quality's advice, if any, stays last


@pytest.mark.slow  # dense partial matches (28 s)
def test_large_shapes_are_matched_partially_on_coarse_copies(
    whole, cut, monkeypatch, blob_made_dense
):
    V, F, e1 = whole
    Vc, Fc, truth, _ = cut
    seen = []
    real = estimate_module.estimate

    def spy(eig_1, eig_2, **options):  # the estimations the dense path runs
        seen.append((eig_1.n_vertices, eig_2.n_vertices, options["options"].landmarks))
        assert options["strategy"].coarse  # the coarse copies' strategy (unpolished)
        return real(eig_1, eig_2, **options)

    monkeypatch.setattr(estimate_module, "estimate", spy)
    landmarks = _three_landmarks(truth)
    corr = ofp.match((V, F), (Vc, Fc), partial=True, landmarks=landmarks)
    # coarse only: the match, then its second opinion on copies of 0.7 times the size
    assert len(seen) == 2 and all(n1 < len(V) and n2 < len(Vc) for n1, n2, _ in seen)
    assert 700 < seen[0][0] < 900 and 480 < seen[1][0] < 640
    assert seen[0][2].shape == (3, 2)  # the landmarks, carried to the coarse cells
    assert seen[1][2].shape == (3, 2)
    assert corr.method == "partial" and corr.options["dense"] is True
    assert corr.fmap_12 is None and corr.p2p_21.shape == (len(Vc),)
    assert corr.options["landmarks"] == landmarks.tolist()  # the caller's numbering
    assert corr.mismatch(V, Vc) is None  # signatures of the full shapes
    assert 0.3 < corr.quality.overlap < 1.0
    # the direct match of this cut: 0.023 (test above); a coarse copy of 800 vertices is
    # coarser than FAUST's coarse copies at 110k (20000 vertices), so twice the bound there
    assert _error(V, corr.p2p_21, truth, e1.area) < 0.08
    assert corr.options["polish"] is True  # polished as it is extended
    # The unpolished strategy (PartialMatch(polish=False)) on the dense path: its coarse match
    # and its extension are not polished, and its map says so
    unpolished = _dense_partial(
        V, F, Vc, Fc, polish=False, options=_partial(landmarks=landmarks), opinions=False
    )
    assert unpolished.options["polish"] is False and unpolished.options["dense"] is True


def test_a_dense_partial_map_follows_the_checked_coarse_map(
    whole, cut, monkeypatch, blob_made_dense
):
    """The full map is the checked coarse point map extended to every vertex.

    The dense path extended the coarse restriction map alone, which does not know where the
    point map keeps the geodesic map (``_refine``): measured (``eval_partial.py --dense 2``),
    FAUST 019 -> 094 legs removed at 110k vertices, the coarse point map 0.028, the full map
    0.077. Here the restriction map's extension is made wrong everywhere (every target vertex
    onto source vertex 0): where it lies over MAX_JUMP from the coarse map's image, that image
    is kept. By default the extension is the polish's fit read the adjoint way: within
    MAX_JUMP of the coarse map's images everywhere, and more precise than they are.
    """
    import o3d_ofp.workflows.partial as workflow

    V, F, e1 = whole
    Vc, Fc, truth, _ = cut
    landmarks = _three_landmarks(truth)
    real = workflow.extend_p2p
    real_extend = workflow._extend_partial
    calls, seen = [], {}

    def broken(C, coarse_1, coarse_2, V1, V2, *, adjoint=False):
        calls.append(adjoint)
        if adjoint:
            return real(C, coarse_1, coarse_2, V1, V2, adjoint=True)
        return np.zeros(len(V2), dtype=np.int64)

    def spy(corr, coarse_1, coarse_2, V1, V2, **options):
        seen["args"] = (corr, coarse_1, coarse_2, V1, V2)
        seen["coarse"] = coarse_1.samples[corr.p2p_21[coarse_2.cell]]  # every target vertex
        seen["bound"] = MAX_JUMP * math.sqrt(coarse_1.eig.area)
        return real_extend(corr, coarse_1, coarse_2, V1, V2, **options)

    monkeypatch.setattr(workflow, "extend_p2p", broken)
    monkeypatch.setattr(workflow, "_extend_partial", spy)
    options = _partial(landmarks=landmarks)
    plain = _dense_partial(V, F, Vc, Fc, polish=False, options=options, opinions=False)
    assert calls == [False] and plain.options["polish"] is False
    assert plain.options["refined"] is True
    coarse_error = _error(V, seen["coarse"], truth, e1.area)  # measured 0.040
    assert coarse_error < 0.08  # the dense test above: 0.08 (coarse copies of 800 vertices)
    # the coarse map's images, but near source vertex 0 (where the broken extension lies)
    assert np.mean(plain.p2p_21 == seen["coarse"]) > 0.8
    (note,) = _said(plain.quality.notes, "extended")
    assert "extended to every vertex" in str(note) and "coarse map polished" not in str(note)
    share = float(re.search(r"; on ([0-9.]+) % of the target", str(note)).group(1))
    assert share > 80 and note.values["percent"] > 80
    calls.clear()
    polished = estimate_dense(V, F, Vc, Fc, options=options, opinions=False)
    assert calls == [True] and polished.options["polish"] is True
    moved = np.linalg.norm(V[polished.p2p_21] - V[seen["coarse"]], axis=1)
    assert moved.max() <= seen["bound"]
    # measured 0.036 against the coarse map's 0.040: the polish, at full resolution
    assert _error(V, polished.p2p_21, truth, e1.area) < 0.95 * coarse_error
    (note,) = _said(polished.quality.notes, "extended")
    assert "extended to every vertex" in str(note) and "coarse map polished" in str(note)
    # the landmark check read the coarse map: its note says so (the full map's check, which
    # follows: test_a_dense_partial_map_gets_no_opinion_when_suspect_or_not_asked and
    # test_a_dense_partial_map_without_opinions_still_checks_its_landmarks_on_the_full_map)
    coarse_note = str(_said(polished.quality.notes, "landmarks_offset")[0])
    assert coarse_note.startswith(
        "landmarks: the coarse map (before its polish and extension) sends"
    )
    # a coarse map kept unrefined (flagged) is not polished: its restriction map is extended
    corr, coarse_1, coarse_2, V1, V2 = seen["args"]
    calls.clear()
    unrefined = dataclasses.replace(corr, options={**corr.options, "refined": False})
    _, out = real_extend(unrefined, coarse_1, coarse_2, V1, V2, polish=True, subsample=2000)
    assert calls == [False] and out.options["polish"] is False


@pytest.mark.slow  # dense partial matches (35 s)
def test_a_dense_partial_map_is_checked_on_its_landmarks_at_full_resolution(
    whole, cut, monkeypatch, blob_made_dense
):
    """The full map, not only the coarse one, must keep the landmarks.

    The coarse check reads the coarse map; the full map may lie up to MAX_JUMP from it. Here
    the extension is made to send one landmark's target vertex to the farthest source vertex
    from its pair: the map is suspect with that reason, said once, and no second opinion is
    asked for (it would not change the verdict).
    """
    import o3d_ofp.workflows.partial as workflow
    from o3d_ofp.core._warnings import OFPWarning

    V, F, _ = whole
    Vc, Fc, truth, _ = cut
    landmarks = _three_landmarks(truth)
    far, real_extend = _send_a_landmark_far(monkeypatch, V, landmarks)
    target = landmarks[1, 1]
    runs, _ = _counted_runs(monkeypatch)
    options = _partial(landmarks=landmarks)
    with pytest.warns(OFPWarning, match="the full map sends 1 of the 3 landmarks") as said:
        corr = estimate_dense(V, F, Vc, Fc, options=options)
    assert len([w for w in said if "is suspect" in str(w.message)]) == 1
    assert corr.quality.suspect and far != landmarks[1, 0]
    assert corr.p2p_21[target] == landmarks[1, 0]  # the result keeps the pair all the same
    assert corr.quality.reasons[0].code == "landmarks_far"
    assert str(corr.quality.reasons[0]).startswith("the full map sends 1 of the 3 landmarks")
    assert len(runs) == 1  # no second opinion
    # unmoved, the same landmarks pass (the coarse check did, the full one does)
    monkeypatch.setattr(workflow, "_extend_partial", real_extend)
    kept = estimate_dense(V, F, Vc, Fc, options=options)
    full_notes = [n for n in _said(kept.quality.notes, "landmarks_offset")
                  if n.values["subject"] == "the full map"]  # fmt: skip
    assert len(full_notes) == 1  # the full map was checked
    assert "landmarks_far" not in kept.quality.codes()
    assert not any("landmarks' target vertices" in str(r) for r in kept.quality.reasons)


@pytest.mark.slow  # dense partial matches (27 s)
def test_a_dense_partial_map_without_opinions_still_checks_its_landmarks_on_the_full_map(
    whole, cut, monkeypatch, blob_made_dense
):
    """Without the opinions, the full map is still checked on the landmarks.

    The opinions are a second look at a map that passed; the landmark check at full
    resolution is the map's own (the coarse check read the coarse map).
    """
    V, F, e1 = whole
    Vc, Fc, truth, _ = cut
    landmarks = _three_landmarks(truth)
    options = _partial(landmarks=landmarks)
    import o3d_ofp.workflows.estimate as estimation

    before = []  # the full map as estimated, before the pairs are kept exactly

    def keeping(corr, given):
        before.append(np.array(corr.p2p_21))
        return real_keeping(corr, given)

    real_keeping = estimation.keeping_landmarks
    monkeypatch.setattr(estimation, "keeping_landmarks", keeping)
    kept = estimate_dense(V, F, Vc, Fc, options=options, opinions=False)
    np.testing.assert_array_equal(kept.p2p_21[landmarks[:, 1]], landmarks[:, 0])
    notes = [str(n) for n in _said(kept.quality.notes, "landmarks_offset")]
    assert len(notes) == 2, notes  # the coarse map's, then the full map's
    coarse_note, full_note = notes
    assert coarse_note.startswith("landmarks: the coarse map (before its polish and extension)")
    assert full_note.startswith("landmarks: the full map sends their target vertices at most")
    off = np.linalg.norm(V[before[-1][landmarks[:, 1]]] - V[landmarks[:, 0]], axis=1)
    assert off.max() > 0 and f"at most {off.max() / math.sqrt(e1.area):.3f} of" in full_note
    # a full map that sends a landmark far is flagged, without opinions too
    _send_a_landmark_far(monkeypatch, V, landmarks)
    moved = estimate_dense(V, F, Vc, Fc, options=options, opinions=False)
    assert moved.quality.suspect and "landmarks_far" in moved.quality.codes()


def test_a_landmark_left_out_on_dense_copies_is_said_once(whole, cut, blob_made_dense):
    """A pair closer than a coarse cell to another is said once, not again by the second opinion.

    The second opinion runs the coarse match again on smaller copies: it used to warn again
    (with other vertex counts, possibly naming other pairs).
    """
    from o3d_ofp.core._warnings import OFPWarning
    from o3d_ofp.workflows.dense import coarse_shape

    V, F, _ = whole
    Vc, Fc, truth, _ = cut
    landmarks = _three_landmarks(truth)
    c1 = coarse_shape(V, F, k=99, coarse_vertices=800)
    c2 = coarse_shape(Vc, Fc, k=99, coarse_vertices=800)
    (s0, t0) = landmarks[0]
    t = next(  # a target vertex whose true source shares the first landmark's source cell
        t
        for t in range(len(truth))
        if c1.cell[truth[t]] == c1.cell[s0] and c2.cell[t] != c2.cell[t0] and truth[t] != s0
    )
    given = np.vstack([landmarks, [[truth[t], t]]])
    with pytest.warns(OFPWarning) as said:
        corr = estimate_dense(V, F, Vc, Fc, options=_partial(landmarks=given))
    # it ran
    assert any(str(n).startswith("second opinion") for n in _said(corr.quality.notes, "opinion"))
    left_out = [str(w.message) for w in said if "on the coarse copies" in str(w.message)]
    assert len(left_out) == 1 and left_out[0].startswith(f"landmarks [{truth[t]}, {t}]:")
    (note,) = _said(corr.quality.notes, "landmarks_dropped")  # the first match's, once
    assert str(note) == left_out[0]


def test_a_dense_partial_match_reports_its_progress_forward(whole, cut, caplog, blob_made_dense):
    """A caller's progress goes forward only, and the log lines give no shares of their own.

    A trial's dense partial match printed the caller's shares ("matching: ... (32%)") and
    the dense run's own ("match (dense): extension ... (80%)", then "(15%)" again for the
    second opinion), so the percentages went backwards; the first match's end was
    reported as "done" at 60 %.
    """
    import logging
    import re

    V, F, _ = whole
    Vc, Fc, truth, _ = cut
    seen = []
    with caplog.at_level(logging.INFO, logger="o3d_ofp"):
        corr = estimate_dense(
            V, F, Vc, Fc, options=_partial(landmarks=_three_landmarks(truth)),
            progress=lambda stage, done: seen.append((stage, done)),
        )  # fmt: skip
    # both runs ran
    assert any(str(n).startswith("second opinion") for n in _said(corr.quality.notes, "opinion"))
    fractions = [done for _, done in seen]
    assert fractions == sorted(fractions) and fractions[-1] == 1.0, seen
    assert [stage for stage, _ in seen].count("done") == 1  # the run's end only
    assert "first match done" in [stage for stage, _ in seen]
    shares = [r.getMessage() for r in caplog.records if re.search(r"\(\d+%\)", r.getMessage())]
    assert shares == [], shares
    # a dense run that reports its own progress (no callback) keeps its shares
    caplog.clear()
    with caplog.at_level(logging.INFO, logger="o3d_ofp"):
        corr = ofp.match((V, F), (V, F))
    assert corr.options["dense"] is True
    assert any(r.getMessage().endswith("(80%)") for r in caplog.records)


def _turned_map(V: np.ndarray, p2p: np.ndarray, how: str) -> np.ndarray:
    """Return a map far from ``p2p``: its images mirrored or turned about the centre."""
    c = V.mean(axis=0)
    if how == "mirrored":
        return nearest_neighbors(V, 2 * c - V[p2p])
    a = V[p2p] - c  # a quarter turn about the z axis
    return nearest_neighbors(V, np.stack([-a[:, 1], a[:, 0], a[:, 2]], axis=1) + c)


@pytest.mark.slow  # a dense partial match each (21 s)
@pytest.mark.parametrize(
    "opinions",
    [
        ("mirrored", None),  # the third agrees with the first: the second is set aside
        ("mirrored", "mirrored"),  # the second and third agree: their map, flagged
        ("mirrored", "turned"),  # all three disagree: the first map, flagged
    ],
)
def test_a_dense_partial_map_the_second_opinion_contradicts_gets_a_third(
    whole, cut, monkeypatch, caplog, blob_made_dense, opinions
):
    """The dense path's map is checked against matches on smaller coarse copies.

    Measured at 110k vertices: a map wrong on a region (error 0.085) passed every check of
    its own; the match on copies of 14 000 vertices (0.030) disagreed on 31 % of the target.
    Right maps were flagged by a wrong second opinion too (stop 36's Loop-subdivided one side
    removed, 0.028): when the two disagree, a third opinion tells which one it agrees with.
    """
    import logging

    V, F, _ = whole
    Vc, Fc, truth, _ = cut

    def contradicted(run, corr):  # the opinions send the part across the source
        how = (None, *opinions)[run - 1]
        if how is None:
            return corr
        return dataclasses.replace(corr, p2p_21=_turned_map(V, corr.p2p_21, how))

    calls, maps = _counted_runs(monkeypatch, contradicted)
    landmarks = _three_landmarks(truth)
    with caplog.at_level(logging.WARNING, logger="o3d_ofp"), warnings_logged():
        corr = ofp.match((V, F), (Vc, Fc), partial=True, landmarks=landmarks)
    assert calls == [800, 560, 320]
    q = corr.quality
    said = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    notes = [str(n) for n in _said(q.notes, "opinion")]
    assert notes[0].startswith("second opinion (coarse copies of about 560 vertices)")
    assert notes[1].startswith("third opinion (coarse copies of about 320 vertices)")
    words = [str(n) for n in q.notes]
    error = _error(V, corr.p2p_21, truth, whole[2].area)
    if opinions[1] is None:
        assert not q.suspect and said == [] and error < 0.08  # the first map, as it was
        assert "the third opinion agrees with this map: the second opinion is set aside" in words
    elif opinions[1] == "mirrored":
        # the map returned is the one the other two agree on (here a wrong one: a test of the
        # rule, not of the match), flagged, said once, with that reason
        assert q.suspect and error > 0.5
        assert q.reasons[0].code == "opinions_disagree"
        assert str(q.reasons[0]).startswith(
            "the matches on coarse copies of about 560 and 320 vertices agree with each other, "
            "but send 100 %"
        )
        np.testing.assert_array_equal(corr.p2p_21, _kept(maps[1], landmarks))  # the second's
        assert "the first map's (coarse copies of about" in notes[0]
        assert "away from this map's images on" in notes[2]  # the third against the second's
        assert "this map is the second opinion's, which the third agrees with" in words[-1]
        (warning,) = said
        assert warning.startswith("the partial map is suspect:\n  - the matches on coarse")
    else:
        assert q.suspect and error < 0.08  # the first map, flagged
        np.testing.assert_array_equal(corr.p2p_21, _kept(maps[0], landmarks))
        assert q.reasons[0].code == "opinions_disagree"
        reason = str(q.reasons[0])
        assert reason.startswith("the match on coarse copies of about 560 vertices sends")
        assert "and the match on copies of about 320 agrees with neither" in reason
        (warning,) = said
        assert warning.startswith("the partial map is suspect:\n  - the match on coarse copies")


@pytest.mark.slow  # dense partial matches (35 s)
def test_a_dense_partial_map_gets_no_opinion_when_suspect_or_not_asked(
    whole, cut, monkeypatch, blob_made_dense
):
    """No second opinion for a suspect map, nor unasked; no third when the two agree.

    A suspect map could not be made less so; opinions that agree leave the map as it is.
    """
    V, F, _ = whole
    Vc, Fc, truth, _ = cut
    options = _partial(landmarks=_three_landmarks(truth))
    suspect = {}

    def made_suspect(run, corr):  # once asked: the coarse match's quality made suspect
        if not suspect:
            return corr
        reason = Said("x", {}, "test")
        return dataclasses.replace(
            corr, quality=dataclasses.replace(corr.quality, suspect=True, reasons=(reason,))
        )

    calls, maps = _counted_runs(monkeypatch, made_suspect)
    agreed = estimate_dense(V, F, Vc, Fc, options=options)
    assert calls == [800, 560] and not agreed.quality.suspect
    assert _said(agreed.quality.notes, "opinion")  # the second's
    # the landmark check read the coarse map, and then the full map: their notes say so
    coarse_note, full_note = map(str, _said(agreed.quality.notes, "landmarks_offset"))
    assert coarse_note.startswith(
        "landmarks: the coarse map (before its polish and extension) sends"
    )
    assert full_note.startswith("landmarks: the full map sends their target vertices at most")
    V1, lm = V / math.sqrt(whole[2].area), options.landmarks
    # the first map as estimated (the result keeps the pairs exactly)
    np.testing.assert_array_equal(agreed.p2p_21, _kept(maps[0], lm))
    off = np.linalg.norm(V1[maps[0][lm[:, 1]]] - V1[lm[:, 0]], axis=1)
    assert f"at most {off.max():.3f} of" in full_note
    assert not any(str(n).startswith("third opinion") for n in agreed.quality.notes)
    calls.clear()
    plain = estimate_dense(V, F, Vc, Fc, options=options, opinions=False)
    assert calls == [800] and not plain.quality.suspect
    assert not _said(plain.quality.notes, "opinion")
    suspect["yes"] = True
    calls.clear()
    flagged = ofp.match((V, F), (Vc, Fc), partial=True, landmarks=options.landmarks)
    assert calls == [800] and flagged.quality.suspect
    assert not _said(flagged.quality.notes, "opinion")


def test_a_dense_partial_match_refuses_opinions_that_are_not_true_or_false(
    whole, cut, monkeypatch, blob_made_dense
):
    V, F, _ = whole
    Vc, Fc, _, _ = cut
    monkeypatch.setattr(estimate_module, "_match_dense", lambda *a, **k: pytest.fail("matched"))
    with pytest.raises(TypeError, match="opinions must be True or False"):
        estimate_dense(V, F, Vc, Fc, options=_partial(), opinions="yes")


def _colored_blob_and_part(folder: Path) -> tuple[Path, Path]:
    """Write a colored 642-vertex blob and its 70 % cut as PLY files: (source, target)."""
    import open3d as o3d

    from o3d_ofp import write_geometry
    from o3d_ofp.boundary.convert import triangle_mesh_from_arrays

    V, F = blob(3)
    Vc, Fc, _ = plane_cut(V, F, axis=0, fraction=0.7)
    src, tgt = folder / "src.ply", folder / "part.ply"
    mesh = triangle_mesh_from_arrays(V, F)
    mesh.vertex_colors = o3d.utility.Vector3dVector(0.5 + 0.5 * np.sin(3 * V))
    write_geometry(src, mesh)
    write_geometry(tgt, triangle_mesh_from_arrays(Vc, Fc))
    return src, tgt


def test_cli_partial_flag_on_a_dense_pair(tmp_path, capsys, monkeypatch):
    from o3d_ofp.cli.main import main

    monkeypatch.setattr(plan_module, "DENSE_VERTICES", 500)  # the 642-vertex blob is "dense"
    monkeypatch.setattr(estimate_module, "COARSE_VERTICES", 400)
    src, tgt = _colored_blob_and_part(tmp_path)
    saved = tmp_path / "map.npz"
    args = ["transfer", str(src), str(tgt), "--k1", "12", "--k2", "12", "--partial"]
    assert main([*args, "--save-map", str(saved), "-o", str(tmp_path / "out.ply")]) == 0
    assert "dense path" in capsys.readouterr().err
    corr = Correspondence.load(saved)
    assert corr.method == "partial" and corr.options["dense"] is True


def test_cli_partial_flag(tmp_path, capsys):
    from o3d_ofp.cli.main import main

    src, tgt = _colored_blob_and_part(tmp_path)  # 642 vertices: fast
    out, saved = tmp_path / "out.ply", tmp_path / "map.npz"
    args = ["transfer", str(src), str(tgt), "--k1", "12", "--k2", "12"]
    assert main([*args, "--partial", "--save-map", str(saved), "-o", str(out)]) == 0
    assert "overlap" in capsys.readouterr().out
    assert out.exists() and Correspondence.load(saved).method == "partial"
    assert main([*args, "--partial", "--map", "closest", "-o", str(tmp_path / "x.ply")]) == 2
    assert "--partial applies to --map estimate" in capsys.readouterr().err


def test_cli_target_scale_runs_as_on_a_rescaled_file(tmp_path, capsys):
    """``--target-scale`` matches as if the target file were in the source's units.

    A trial: a part in millimetres onto a whole in metres was told to multiply its
    coordinates by 0.001, which the command line had no way to do. The map is the one of a
    file written in metres; the colors written sit on the target's own (millimetre)
    coordinates; a detail transfer is written in millimetres too; a collection refuses the
    flag; a bad factor is refused by the parser.
    """
    from o3d_ofp.cli.main import main

    src, tgt = _colored_blob_and_part(tmp_path)  # 642 vertices: fast
    part = ofp.read_geometry(tgt)
    Vm = np.asarray(part.vertices)
    mm = tmp_path / "part_mm.ply"
    mm_mesh = ofp.read_geometry(tgt)
    mm_mesh.scale(1000.0, center=(0.0, 0.0, 0.0))
    ofp.write_geometry(mm, mm_mesh)
    Vmm = np.asarray(ofp.read_geometry(mm).vertices)
    common = ["--k1", "12", "--k2", "12", "--partial"]
    maps = [tmp_path / "m.npz", tmp_path / "mm.npz"]
    outs = [tmp_path / "m.ply", tmp_path / "mm.ply"]
    assert main(["transfer", str(src), str(tgt), *common, "--save-map", str(maps[0]),
                 "-o", str(outs[0])]) == 0  # fmt: skip
    assert main(["transfer", str(src), str(mm), *common, "--target-scale", "0.001",
                 "--save-map", str(maps[1]), "-o", str(outs[1])]) == 0  # fmt: skip
    corr_m, corr_mm = (Correspondence.load(m) for m in maps)
    # the same map: the scaled file's coordinates differ from the metre file's by round-off
    # only (float32 PLY), which may move a few near-ties of the nearest-neighbour read-offs
    assert np.mean(corr_m.p2p_21 == corr_mm.p2p_21) > 0.98
    written = [ofp.read_geometry(o) for o in outs]
    np.testing.assert_allclose(np.asarray(written[1].vertices), Vmm, rtol=1e-6)
    np.testing.assert_allclose(np.asarray(written[0].vertices), Vm, rtol=1e-6)
    assert np.asarray(written[1].vertex_colors).shape == (len(Vm), 3)
    capsys.readouterr()
    # detail: written in the target's own units (the source's detail, scaled back; the part
    # is as smooth as the source, so a band is given for the detail to move it)
    details = [tmp_path / "dm.ply", tmp_path / "dmm.ply"]
    scale = ["--target-scale", "0.001"]
    for target, out, extra in ((tgt, details[0], []), (mm, details[1], scale)):
        assert main(["detail", str(src), str(target), "--map", str(maps[0]), "--band", "30",
                     *extra, "-o", str(out)]) == 0  # fmt: skip
    moved_m, moved_mm = (np.asarray(ofp.read_geometry(d).vertices) for d in details)
    assert np.abs(moved_m - Vm).max() > 1e-4  # the detail moved the part
    np.testing.assert_allclose(moved_mm / 1000, moved_m, atol=1e-5 * np.ptp(Vm))
    # a factor that does not fix the units: the advice is the factor for the file itself
    capsys.readouterr()
    x = str(tmp_path / "x.ply")
    assert main(["transfer", str(src), str(mm), *common, "--target-scale", "0.01", "-o", x]) == 2
    err = capsys.readouterr().err
    assert "--target-scale 0.01 does not fix the units:" in err
    assert f"{mm} has 7" in err and "(millimetres to metres: --target-scale 0.001)" in err
    assert main(["transfer", str(src), str(tgt), *common, "--target-scale", "1000", "-o", x]) == 2
    err = capsys.readouterr().err
    assert f"{tgt} scaled by 1000 has" in err and f"{tgt} as it is would be admitted" in err
    # a basis file of the target in its own units cannot serve the scaled target
    basis = tmp_path / "b.npz"
    assert main(["basis", str(mm), "-k", "12", "-o", str(basis)]) == 0
    assert main(["transfer", str(src), str(mm), *common, "--target-scale", "0.001",
                 "--basis-2", str(basis), "-o", x]) == 2  # fmt: skip
    assert "--target-scale changes them: drop --basis-2" in capsys.readouterr().err
    # refused: a collection, a factor that is not a positive number
    assert main(["transfer", str(src), str(mm), str(tgt), "--target-scale", "0.001",
                 "-o", str(tmp_path / "many")]) == 2  # fmt: skip
    assert "--target-scale (for one pair of shapes) does not apply" in capsys.readouterr().err
    for bad in ("0", "-1", "nan", "inf", "mm"):
        assert main(["transfer", str(src), str(mm), f"--target-scale={bad}",
                     "-o", str(tmp_path / "x.ply")]) == 2  # fmt: skip
        assert "--target-scale: expected a finite number > 0" in capsys.readouterr().err


@pytest.mark.slow
@pytest.mark.skipif(not DATA.is_dir(), reason="needs the shared data at ../shared/data")
def test_faust_cut_onto_another_body():
    from o3d_ofp.boundary.convert import geometry_to_arrays

    V1, F1 = geometry_to_arrays(ofp.read_geometry(DATA / "faust/tr_reg_093.ply"))
    V2, F2 = geometry_to_arrays(ofp.read_geometry(DATA / "faust/tr_reg_087.ply"))
    Vc, Fc, truth = plane_cut(V2, F2, axis=0, fraction=0.6)  # one side removed
    corr = ofp.match((V1, F1), (Vc, Fc), partial=True)
    area = ofp.laplacian(V1, F1)[1].sum()
    # scripts/eval_partial.py measures this cut; the bound leaves room for round-off-driven
    # changes of the chosen start but fails on a flipped or collapsed map (> 0.15).
    assert _error(V1, corr.p2p_21, truth, area) < 0.1


@pytest.mark.slow
@pytest.mark.skipif(not DATA.is_dir(), reason="needs the shared data at ../shared/data")
def test_faust_back_only_is_matched_by_registering_the_part():
    """A body seen from the back only is matched by registering the part onto the whole.

    Every spectral start is wrong on it; the registration is right, and the map stays flagged
    (``scripts/eval_partial.py``'s front removed cut: 0.19 sqrt(area) before, 0.042 now).
    """
    from o3d_ofp.boundary.convert import geometry_to_arrays

    V1, F1 = geometry_to_arrays(ofp.read_geometry(DATA / "faust/tr_reg_093.ply"))
    V2, F2 = geometry_to_arrays(ofp.read_geometry(DATA / "faust/tr_reg_087.ply"))
    Vc, Fc, truth = plane_cut(-V2, F2, axis=2, fraction=0.6)  # the back kept (FAUST: z front)
    Vc = -Vc
    corr = ofp.match((V1, F1), (Vc, Fc), partial=True)
    area = ofp.laplacian(V1, F1)[1].sum()
    assert corr.quality.suspect and "part_registered" in corr.quality.codes()
    assert _error(V1, corr.p2p_21, truth, area) < 0.08  # a wrong map: 0.19 and more


@pytest.fixture(scope="module")
def colored_blob_and_part():
    """Return a colored 642-vertex blob (legacy Open3D mesh) and its 70 % cut with UVs."""
    import open3d as o3d

    from o3d_ofp.boundary.convert import triangle_mesh_from_arrays

    V, F = blob(3)
    Vc, Fc, truth = plane_cut(V, F, axis=0, fraction=0.7)
    source = triangle_mesh_from_arrays(V, F)
    source.vertex_colors = o3d.utility.Vector3dVector(0.5 + 0.5 * np.sin(3 * V))
    part = triangle_mesh_from_arrays(Vc, Fc)
    uv = (Vc[:, 1:] - Vc[:, 1:].min(0)) / np.ptp(Vc[:, 1:], axis=0)  # a planar projection
    part.triangle_uvs = o3d.utility.Vector2dVector(uv[Fc.reshape(-1)])
    return source, part, truth


def test_transfers_take_the_partial_map_of_match(colored_blob_and_part):
    """A part's map is ``match(partial=True)``, handed to the transfers as ``correspondence=``.

    A trial's ``transfer_colors(..., partial=True)`` was a TypeError: only the command line
    had the flag. ``partial`` belongs to :func:`o3d_ofp.match` (a transfer refuses it); its map
    serves the three transfers, and gives better colors than the full-shape map of the part.
    """
    from o3d_ofp.core import spectrum

    source, part, truth = colored_blob_and_part
    colors = np.asarray(source.vertex_colors)
    corr = ofp.match(source, part, partial=True)
    assert corr.method == "partial"
    for transfer in (ofp.transfer_colors, ofp.transfer_detail, ofp.transfer_texture):
        with pytest.raises(TypeError, match="partial"):
            transfer(source, part, partial=True)
    options = ofp.BasisOptions(k1=12, k2=12)
    by_map = ofp.transfer_colors(source, part, correspondence=corr, options=options)
    by_map = np.asarray(by_map.vertex_colors)
    full = np.asarray(ofp.transfer_colors(source, part, options=options).vertex_colors)
    # The exact pull-back (via_basis=False, the CLI's --pull-back) reads the colors through it.
    pulled = ofp.transfer_colors(source, part, correspondence=corr, via_basis=False)
    np.testing.assert_array_equal(np.asarray(pulled.vertex_colors), colors[corr.p2p_21])
    # ... the partial map from given eigenbases too, with no eigensolve
    bases = tuple(ofp.eigenbasis(g, k=99) for g in (source, part))
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(spectrum, "_solve", lambda *a, **k: pytest.fail("an eigensolve ran"))
        given = ofp.match(source, part, partial=True, eigenbases=bases)
        pulled = ofp.transfer_colors(source, part, correspondence=given, via_basis=False)
    np.testing.assert_array_equal(given.p2p_21, corr.p2p_21)
    np.testing.assert_array_equal(np.asarray(pulled.vertex_colors), colors[corr.p2p_21])
    error = np.abs(by_map - colors[truth]).mean()
    assert error < 0.5 * np.abs(full - colors[truth]).mean()

    Vp = np.asarray(part.vertices)
    moved = np.asarray(ofp.transfer_detail(source, part, correspondence=corr).vertices)
    assert moved.shape == Vp.shape and np.abs(moved - Vp).max() > 0  # the detail moved it

    baked = ofp.transfer_texture(source, part, correspondence=corr, size=64)
    assert np.asarray(baked.textures[0]).shape[:2] == (64, 64)
    # texture_pullback needs a textured source: the baked part is one (its own layout)
    identity = Correspondence.from_p2p(np.arange(len(part.vertices)), baked, part)
    pulled = ofp.texture_pullback(baked, part, correspondence=identity)
    assert len(pulled.triangle_uvs) == 3 * len(part.triangles)


def test_coordinates_onto_a_part_are_checked_against_the_parts_area(whole, cut, caplog):
    """Mode "coordinates" onto a part gives it the covered region's shape, not the whole's.

    The area check compared the result with the whole source's area: a part of less than half
    of it was always told its map was wrong.
    """
    V, F, _ = whole
    Vc, Fc, truth, _ = cut
    part = np.isin(np.arange(len(Vc)), np.flatnonzero(Vc[:, 0] > np.quantile(Vc[:, 0], 0.4)))
    small_F = Fc[part[Fc].all(axis=1)]
    keep = np.unique(small_F)
    index = np.full(len(Vc), -1)
    index[keep] = np.arange(keep.size)
    Vs, Fs = Vc[keep], index[small_F]
    area = lambda X, T: 0.5 * np.linalg.norm(  # noqa: E731
        np.cross(X[T[:, 1]] - X[T[:, 0]], X[T[:, 2]] - X[T[:, 0]]), axis=1
    ).sum()
    assert area(Vs, Fs) < 0.45 * area(V, F)  # below the factor 2 of the check
    corr = Correspondence(p2p_21=truth[keep], n_source=len(V), method="partial")
    sizes = ofp.BasisOptions(k1=20, k2=20)
    with caplog.at_level("WARNING", logger="o3d_ofp"):
        moved = ofp.transfer_detail((V, F), (Vs, Fs), mode="coordinates", correspondence=corr,
                                    options=sizes)  # fmt: skip
    assert not [r for r in caplog.records if "area" in r.getMessage()]
    assert 0.5 < area(np.asarray(moved.vertices), Fs) / area(Vs, Fs) < 2.0
    # The same map given by the caller (Correspondence.from_p2p), or a Correspondence of
    # unknown kind: the result has the part's own area, which passes too (it was told its map
    # was wrong).
    import warnings

    for given in (Correspondence.from_p2p(truth[keep], (V, F), (Vs, Fs)),
                  dataclasses.replace(corr, method="given")):  # fmt: skip
        assert given.method == "given"
        with warnings.catch_warnings():
            warnings.simplefilter("error", ofp.OFPWarning)
            ofp.transfer_detail((V, F), (Vs, Fs), mode="coordinates", correspondence=given,
                                options=sizes)  # fmt: skip
    # An estimated full-shape map must give the source's area: the same map marked so is said
    # (a review: the target's own area let every map pass).
    with pytest.warns(ofp.OFPWarning, match="times the source's area"):
        estimated = dataclasses.replace(corr, method="estimate")
        ofp.transfer_detail((V, F), (Vs, Fs), mode="coordinates", options=sizes,
                            correspondence=estimated)  # fmt: skip
    # A wrong map onto the part is still said (a map with no structure: far from both areas).
    wrong = Correspondence.from_p2p(
        np.random.default_rng(0).integers(0, len(V), len(Vs)), (V, F), (Vs, Fs)
    )
    with pytest.warns(ofp.OFPWarning, match="times the source's area"):
        ofp.transfer_detail((V, F), (Vs, Fs), mode="coordinates", options=sizes,
                            correspondence=wrong)  # fmt: skip


@pytest.mark.parametrize(
    ("call", "kwargs", "error", "match"),
    [
        ("match", {"partial": "yes"}, TypeError, "partial must be True or False"),
        ("match", {"partial": 1}, TypeError, "partial must be True or False"),
        ("colors", {"given": True}, ValueError, "the given map is used as it is"),
        ("texture", {"given": True}, ValueError, "the given map is used as it is"),
        ("colors", {"given": True, "via_basis": False}, ValueError, "the given map is used as"),
        ("detail", {"given": True}, ValueError, "the given map is used as it is"),
        ("match", {"cloud": True}, ValueError, "needs triangle meshes: the target is a point"),
        ("match", {"swap": True}, ValueError, "cannot be a part of it"),
    ],
)
def test_partial_matches_refuse_what_cannot_apply_before_any_eigensolve(
    colored_blob_and_part, no_eigensolve, call, kwargs, error, match
):
    """Refuse what a partial match cannot apply to before any work.

    A bad flag, a point cloud, a part larger than the whole, and (planning a transfer) a map
    given by the caller, which is used as it is.
    """
    import open3d as o3d

    from o3d_ofp.boundary.api import as_arrays

    source, part, _ = colored_blob_and_part
    if kwargs.pop("cloud", False):
        part = o3d.geometry.PointCloud(part.vertices)
    if kwargs.pop("swap", False):
        source, part = o3d.geometry.TriangleMesh(part), source  # the whole given as the part
    with pytest.raises(error, match=match) as info:
        if call == "match":
            ofp.match(source, part, partial=kwargs.get("partial", True))
        else:
            given = Correspondence.from_p2p(np.zeros(len(part.vertices), dtype=int), source, part)
            plan_module.plan_pair(
                *as_arrays(source), *as_arrays(part), task=call, match=_partial(), given=given,
                via_basis=kwargs.get("via_basis"),
            )  # fmt: skip
    refused = getattr(info.value, "option", None) or info.value.said.code
    assert refused == ("part_larger" if "part of it" in match else "partial")


def test_colors_of_an_array_source_are_a_type_error(colored_blob_and_part, no_eigensolve):
    """A trial's array source was told it had "neither vertex colors nor a texture"."""
    _, part, _ = colored_blob_and_part
    with pytest.raises(TypeError, match=r"must be an Open3D geometry .* got ndarray") as info:
        ofp.transfer_colors(np.zeros((3, 3)), part)
    assert info.value.option == "source"


@pytest.mark.parametrize(
    ("distortion", "elsewhere", "turned", "stretch", "rival"),
    [
        (0.070, 1.0, 0.1, 1.1, True),  # remeshed 007 -> 000: a nearly right map (0.077)
        (0.079, 1.0, 0.1, 1.1, True),  # at most 5 % more distortion
        (0.098, 1.0, 0.1, 1.1, False),  # 093 -> 087 one side: a worse rival (0.058)
        (0.070, 0.3, 0.1, 1.1, False),  # another map of a part cut smaller, off on a limb only
        (0.070, 0.05, 0.1, 1.1, False),  # the same map, up to a few vertices
        (0.070, 1.0, 0.5, 1.1, False),  # a rival that turns the part over is no rival
        (0.130, 1.0, 0.1, 1.1, False),  # nor one that fails the distortion bound
        (0.070, 1.0, 0.1, 1.5, False),  # nor the stretch bound
    ],
)
def test_a_rival_start_that_passes_as_well_and_disagrees_flags_the_map(
    whole, cut, monkeypatch, distortion, elsewhere, turned, stretch, rival
):
    """``_rival``'s rule (RIVAL_MARGIN) on designed refinements of a further start.

    The refinement of the further start is replaced: it sends the first ``elsewhere`` share of
    the target's vertices to the far side of the source from the map's image, with the given
    distortion and reversed fraction; the returned map's distortion is 0.076.
    """
    from o3d_ofp.workflows import partial as workflow
    from o3d_ofp.workflows.strategy import Run

    _, _, e1 = whole
    _, _, truth, ec = cut
    u1, u2 = rescaled(e1, e1.area), rescaled(ec, e1.area)
    # the run the partial match carries (its refinement sizes; ZoomOut subsample 2000)
    run = Run(e1, ec, u1, u2, None, _partial(), lambda *a: None, {"k2_fit": 29, "k2_final": 40})
    assert run.options.zoomout_subsample == 2000
    moved = truth.copy()
    count = int(elsewhere * len(moved))
    X = u1.vertices - u1.vertices.mean(axis=0)
    moved[:count] = np.argmin(X[truth[:count]] @ X.T, axis=1)  # the far side of the blob
    monkeypatch.setattr(workflow, "_refine", lambda p2p, *a, **k: (None, moved))
    monkeypatch.setattr(workflow, "_distortions", lambda run, p2ps: [distortion] * len(p2ps))
    monkeypatch.setattr(workflow, "map_stretch", lambda *a, **k: stretch)
    monkeypatch.setattr(workflow, "reversed_fraction", lambda *a, **k: turned)

    def found(landmarks=None, refinements=None):
        passing = workflow._rival_refinements(
            [1], [truth, truth], refinements or {}, truth, run, landmarks=landmarks
        )  # fmt: skip
        others = [(p2p, d, False) for _, _, p2p, d in passing]
        return workflow._rival(truth, 0.076, others, run, landmarks=landmarks)

    reason = found()
    assert (reason is not None) == rival
    if rival:
        assert reason.code == "rival" and "landmarks" in reason.fixes
        assert "another start of the fit" in str(reason)
        assert "give a few known vertex" in str(reason)
        # With landmarks the rival must keep them about as well as the map: a pair the rival
        # keeps (and the map does not) leaves it a rival; a pair the map keeps and the rival
        # sends to the far side does not.
        kept = np.array([[moved[0], 0]])
        moved_pair = np.array([[truth[0], 0]])
        for pairs, still in ((kept, True), (moved_pair, False)):
            again = found(landmarks=pairs)
            assert (again is not None) == still
            assert again is None or "give more known vertex pairs" in str(again)
    # A refinement made already is reused, not made again.
    monkeypatch.setattr(workflow, "_refine", lambda *a, **k: pytest.fail("refined again"))
    again = found(refinements={1: (None, moved)})
    assert (again is not None) == rival
    # The map given way to is a rival when it sends most of the part elsewhere, whatever its
    # distortion (it passed its checks too).
    far = workflow._rival(truth, 0.076, [(moved, 0.2, True)], run, landmarks=None)
    assert (far is not None) == (elsewhere > workflow.RIVAL_SHARE)


@pytest.mark.slow  # three partial matches (about 45 s on one core)
def test_a_further_start_that_distorts_less_is_taken_instead(whole, cut, monkeypatch):
    """A further start's refinement that sends the part elsewhere and distorts less is returned.

    Measured (``scripts/eval_partial_rivals.py``): such a refinement is the right map where
    the best-ranked start's is wrong (FAUST legs removed at 0.93 of the area, 0.180 -> 0.035).
    Here the best-ranked start's refinement is made to look 1.05 times as distorted as it is
    (the bent blob's rival, a map elsewhere, has 1.08 times its distortion: not taken), and
    then every further refinement to send the whole part elsewhere: the least distorted
    one is returned, said in a note, and the map it replaced is its rival (suspect, as such a
    refinement made the map before). Refinements near the map are not taken (between maps
    near the truth the distortion is no guide), nor one that fails a check of its own.
    """
    from o3d_ofp.workflows import partial as workflow

    _, _, e1 = whole
    _, _, _, ec = cut
    outputs, distortions = [], {}
    real_refine, real_distortions = workflow._refine, workflow._distortions

    def refine(p2p, *args, **kwargs):
        C, refined = real_refine(p2p, *args, **kwargs)
        outputs.append(refined)
        return C, refined

    def measured(run, p2ps):
        found = []
        for p2p, d in zip(p2ps, real_distortions(run, p2ps), strict=True):
            d = 1.05 * d if outputs and np.array_equal(p2p, outputs[0]) else d
            distortions[len(distortions)] = (p2p, d)
            found.append(d)
        return found

    monkeypatch.setattr(workflow, "_refine", refine)
    monkeypatch.setattr(workflow, "_distortions", measured)
    monkeypatch.setattr(workflow, "_polish", lambda p2p, *a, **k: (p2p, 0.0))
    near = estimate(e1, ec, options=_partial(shells=False), warn_suspect=False)
    np.testing.assert_array_equal(near.p2p_21, outputs[0])  # its rival (1.08x) stays one
    assert not _said(near.quality.notes, "rival_taken")
    outputs.clear()
    distortions.clear()
    monkeypatch.setattr(workflow, "_share_apart", lambda *a: 1.0)
    corr = estimate(e1, ec, options=_partial(shells=False), warn_suspect=False)
    further = [(d, p2p) for p2p, d in distortions.values()
               if any(np.array_equal(p2p, out) for out in outputs[1:])]  # fmt: skip
    assert len(outputs) >= 2 and further
    np.testing.assert_array_equal(corr.p2p_21, min(further, key=lambda f: f[0])[1])
    (note,) = _said(corr.quality.notes, "rival_taken")
    assert "is kept instead" in str(note)
    assert corr.quality.suspect and corr.quality.reasons[0].code == "rival"
    # A refinement that would fail its own checks is not taken.
    outputs.clear()
    distortions.clear()
    real = workflow.PartialMatch._judged
    monkeypatch.setattr(workflow.PartialMatch, "_judged", lambda self, run, settled, **kw: (
        real(self, run, settled, **kw) if np.array_equal(settled.p2p_21, outputs[0]) else
        real(self, run, settled, **kw).flagged(Said("made to fail", {}, "test"))))
    kept = estimate(e1, ec, options=_partial(shells=False), warn_suspect=False)
    np.testing.assert_array_equal(kept.p2p_21, outputs[0])
    assert not _said(kept.quality.notes, "rival_taken")


@pytest.mark.slow  # two partial matches (40 s)
def test_a_rival_makes_a_passing_map_suspect_and_is_said_first(whole, cut, monkeypatch):
    """The wiring of the rival check in the partial match; a flagged map is not checked."""
    from o3d_ofp.workflows import partial as workflow
    from o3d_ofp.workflows import quality

    _, _, e1 = whole
    ec = cut[3]
    calls = []
    found = Said("another start of the fit ends (test)", {}, "rival")

    def refinements(indices, *args, **kwargs):
        calls.append(list(indices))
        return []

    monkeypatch.setattr(workflow, "_rival_refinements", refinements)
    monkeypatch.setattr(workflow, "_rival", lambda *args, **kwargs: found)
    with pytest.warns(ofp.OFPWarning, match="another start of the fit ends"):
        corr = match_eigenbases(e1, ec, options=_partial())
    assert corr.quality.suspect
    assert corr.quality.reasons[0] == found
    assert len(calls) == 1 and 0 < len(calls[0]) <= workflow.RIVAL_STARTS
    # A map that fails its own checks gets no rival check.
    calls.clear()
    monkeypatch.setattr(quality, "MAX_DISTORTION", 0.0)
    corr = estimate(e1, ec, options=_partial(), warn_suspect=False)
    assert corr.quality.suspect and "distorted" in corr.quality.codes() and calls == []


def test_estimations_log_their_stages_without_a_progress_callback(whole, cut, monkeypatch, caplog):
    """From Python (no progress= given), a long estimation logs its stages at INFO.

    A trial's 44 s partial transfer, logging at INFO, said one line, at its end; the command
    line passes its own reporter. Short runs say nothing (as the other long loops).
    """
    import logging

    from o3d_ofp.core import _progress

    V, F, e1 = whole
    Vc, Fc, _, ec = cut
    with caplog.at_level(logging.INFO, logger="o3d_ofp"):
        short = MatchOptions(zoomout_to=30)
        ofp.match((V, F), (Vc, Fc), eigenbases=(e1, ec), options=short)  # short: quiet
    assert "descriptor fit" not in caplog.text and "(100%" not in caplog.text
    monkeypatch.setattr(_progress, "PROGRESS_SECONDS", 0.0)  # every stage is "late" now
    for partial, name in ((False, "match"), (True, "partial match")):
        caplog.clear()
        with caplog.at_level(logging.INFO, logger="o3d_ofp"):
            options = MatchOptions(zoomout_to=40)
            ofp.match((V, F), (Vc, Fc), eigenbases=(e1, ec), options=options, partial=partial)
        said = [r.getMessage() for r in caplog.records if r.getMessage().startswith(name + ":")]
        assert said[0].startswith(f"{name}: descriptor fit"), said
        assert any(m.startswith(f"{name}: done (100%") for m in said), said


def test_a_partial_match_measures_every_map_against_one_probe(whole, cut, monkeypatch):
    """The starts, refinements and rivals of a match share one distortion probe.

    The target's samples and their distances (``core.partial.distortion_probe``) are made once
    a match, before the starts are refined side by side, and every map's distortion read
    against it is the one ``geodesic_distortion`` computes for that map alone.
    """
    import o3d_ofp.core.partial as core
    import o3d_ofp.workflows.partial as workflow
    from o3d_ofp.workflows.matching import DCOMM_WEIGHTS

    _, _, e1 = whole
    _, _, _, ec = cut
    made, measured = [], []
    real_probe, real_distortions = workflow.distortion_probe, core.DistortionProbe.distortions
    monkeypatch.setattr(workflow, "distortion_probe",
                        lambda *a, **k: made.append(real_probe(*a, **k)) or made[-1])  # fmt: skip

    def distortions(self, p2ps):
        found = real_distortions(self, p2ps)
        measured.extend(zip((np.array(p) for p in p2ps), found, strict=True))
        return found

    monkeypatch.setattr(core.DistortionProbe, "distortions", distortions)
    estimate(e1, ec, options=_partial(k_fit=15, shells=False), warn_suspect=False)
    assert len(made) == 1 and len(measured) >= len(DCOMM_WEIGHTS)
    monkeypatch.undo()
    u1, u2 = rescaled(e1, e1.area), rescaled(ec, e1.area)  # the match's units
    for p2p, d in measured:
        # the same Dijkstra runs on the same samples: equal to rounding
        assert d == pytest.approx(
            geodesic_distortion(p2p, u1.vertices, u1.faces, u2.vertices, u2.faces), rel=1e-12
        )


def test_the_parts_registration_refines_the_start_whose_descriptors_agree_best(
    whole, cut, monkeypatch
):
    """Of the registration's starts, the one that keeps the descriptors best is refined.

    A part turned half a turn onto the whole (a back shell onto the front) can change geodesic
    distances less than the right map: here the turned map is made to distort least, and the
    start refined must still be the true map, whose descriptors (``partial_descriptors``)
    agree best. The disagreement itself tells the true map from the turned one.
    """
    from o3d_ofp.workflows import partial as workflow
    from o3d_ofp.workflows.strategy import Run, Settled

    V, _, e1 = whole
    _, _, truth, ec = cut
    u1, u2 = rescaled(e1, e1.area), rescaled(ec, e1.area)
    run = Run(e1, ec, u1, u2, None, _partial(), lambda *a: None,
              {"descriptors": partial_descriptors(u1, u2)})  # fmt: skip
    X = u1.vertices - u1.vertices.mean(axis=0)
    turned = nearest_neighbors(X, X[truth] * [-1.0, 1.0, -1.0])  # half a turn about y
    assert _error(V, turned, truth, e1.area) > 0.3
    # measured 0.196 against 0.303 (0.65 times): 0.8 leaves room for other BLAS and solvers
    assert workflow._disagreement(run, truth) < 0.8 * workflow._disagreement(run, turned)
    refined = []
    monkeypatch.setattr(workflow, "part_maps", lambda a, b: [turned, truth])
    monkeypatch.setattr(workflow, "_distortions", lambda run, p2ps: [
        0.01 if p2p is turned else 0.1 for p2p in p2ps])  # fmt: skip
    monkeypatch.setattr(workflow.PartialMatch, "_refined", lambda self, run, p2p: (
        refined.append(p2p) or (np.eye(31), p2p)))  # fmt: skip
    monkeypatch.setattr(workflow, "_polish", lambda p2p, *a, **k: (p2p, 0.0))
    monkeypatch.setattr(workflow.PartialMatch, "_judged", lambda self, run, s, **k: quality)
    quality = map_quality(truth, e1, ec, None, partial=True, overlap=0.6).flagged(
        Said("made suspect", {}, "test"))  # fmt: skip
    workflow.PartialMatch()._registered(run, Settled(None, turned, {}), quality)
    assert len(refined) == 1 and refined[0] is truth
