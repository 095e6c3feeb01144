"""Partial maps: wrong maps and non-parts are flagged; landmarks; point clouds refused."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

import o3d_ofp as ofp
from o3d_ofp.core.correspondence import fmap_from_p2p, nearest_neighbors
from o3d_ofp.core.partial import (
    geodesic_distortion,
    geodesic_refine,
    map_stretch,
    rescaled,
    slant,
)
from o3d_ofp.core.shapes import blob
from o3d_ofp.workflows.estimate import match_eigenbases
from o3d_ofp.workflows.options import MatchOptions
from o3d_ofp.workflows.quality import MAX_DISTORTION, MAX_STRETCH, partial_quality

DATA = Path(__file__).resolve().parents[2] / "shared" / "data"


def plane_cut(V, F, *, axis, fraction):
    """Keep the faces with the largest ``V[:, axis]`` (all corners) up to ``fraction`` of the area.

    Returns the part's vertices and faces and the original index of each kept vertex.
    """
    areas = 0.5 * np.linalg.norm(np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]]), axis=1)
    order = np.argsort(-V[F, axis].min(axis=1))
    count = int(np.searchsorted(np.cumsum(areas[order]) / areas.sum(), fraction)) + 1
    kept = F[order[:count]]
    keep = np.unique(kept)
    index = np.full(len(V), -1)
    index[keep] = np.arange(keep.size)
    return V[keep], index[kept], keep


def _error(V, p2p, truth, area):
    return np.linalg.norm(V[p2p] - V[truth], axis=1).mean() / math.sqrt(area)


@pytest.fixture(scope="module")
def pair():
    V, F = blob(4)  # 2562 vertices, no symmetry
    bent = V.copy()
    bent[:, 1] += 0.15 * bent[:, 0] ** 2  # a bent copy: not an exact part
    Vc, Fc, truth = plane_cut(bent, F, axis=0, fraction=0.65)
    return V, F, ofp.eigenbasis(V, F, k=99), Vc, Fc, truth, ofp.eigenbasis(Vc, Fc, k=99)


def _restriction(p2p, e1, ec, k2=20):
    u1, u2 = rescaled(e1, e1.area), rescaled(ec, e1.area)
    return fmap_from_p2p(p2p, u1, u2, k1=slant(u1.evals, u2.evals, k2), k2=k2)


def _torn(V, Vc, truth):
    """Return the true map with the top 30 % of the part sent to the other side of the source."""
    wrong = truth.copy()
    region = Vc[:, 1] > np.quantile(Vc[:, 1], 0.7)
    wrong[region] = nearest_neighbors(V, 2 * V.mean(axis=0) - V[truth[region]])
    return wrong


def test_true_map_passes_and_a_torn_map_is_flagged(pair):
    V, F, e1, Vc, Fc, truth, ec = pair
    d_true = geodesic_distortion(truth, V, F, Vc, Fc)
    # the bent copy changes distances a little
    assert d_true < 0.5 * MAX_DISTORTION
    assert map_stretch(truth, V, Vc, Fc) < MAX_STRETCH  # measured 0.99
    q = partial_quality(truth, e1, ec, _restriction(truth, e1, ec), overlap=0.65)
    assert not {"distorted", "stretched"} & q.codes()
    assert not any("geodesic" in str(r) or "stretches" in str(r) for r in q.reasons)
    # the measures behind the verdict are printed with their bounds (a map that only just
    # passes can be seen)
    measures = q.notes[0]
    assert measures.code == "partial_measures"
    assert f"geodesic distortion {d_true:.3f} (limit for a part matched right:" in str(measures)
    assert f"stretch {map_stretch(truth, V, Vc, Fc):.2f} (limit {MAX_STRETCH})" in str(measures)
    # A torn map: the top 30 % of the part sent to the opposite side of the source (the
    # image of each of its vertices reflected through the centre): a region in the wrong place.
    wrong = _torn(V, Vc, truth)
    # measured 0.29 (the true map: 0.02); a region of 30 % torn off must exceed the bound
    assert geodesic_distortion(wrong, V, F, Vc, Fc) > MAX_DISTORTION
    assert map_stretch(wrong, V, Vc, Fc) > map_stretch(truth, V, Vc, Fc) + 0.2
    q = partial_quality(wrong, e1, ec, _restriction(wrong, e1, ec), overlap=0.65)
    assert q.suspect
    reasons = {r.code: r for r in q.reasons}
    assert {"distorted", "stretched", "causes_partial"} <= set(reasons)
    assert "geodesic distances" in str(reasons["distorted"])
    assert "not a part" in str(reasons["distorted"])
    assert "stretches the target's edges" in str(reasons["stretched"])
    causes = reasons["causes_partial"]
    assert "give a few known vertex pairs" in str(causes) and "landmarks" in causes.fixes
    # a noisy scan is among the causes, with its fix (a trial's noisy cut: error 0.42; 0.032
    # once smoothed), worded for Python and for the command line
    assert "smooth" in causes.fixes
    assert "a noisy scan" in str(causes) and "filter_geometry(smooth=0.01)" in str(causes)
    assert "o3d-ofp filter --smooth" in causes.text(cli=True)
    q = partial_quality(wrong, e1, ec, _restriction(wrong, e1, ec), overlap=0.65, landmarks=True)
    (causes,) = [r for r in q.reasons if r.code == "causes_partial"]
    assert "give more known vertex pairs" in str(causes) and "landmarks_check" in causes.fixes


def test_restriction_orthogonality_is_reported_not_judged(pair):
    """A right partial map whose restriction map is far from orthonormal rows is not flagged.

    A trial's right map of the front half of FAUST 093 (error 0.025) was flagged by its
    orthogonality alone (0.44 > the full-shape bound 0.4), with advice to rescale its units.
    """
    from o3d_ofp.workflows.quality import MAX_ORTHOGONALITY

    _, _, e1, _, _, truth, ec = pair
    C = 1.6 * _restriction(truth, e1, ec)  # rows of norm 1.6: ‖C Cᵀ − I‖ / √(k2+1) ≈ 1.56
    q = partial_quality(truth, e1, ec, C, overlap=0.65)
    assert q.orthogonality > MAX_ORTHOGONALITY
    assert "not_isometric" not in q.codes()
    assert not any("orthogonality" in str(r) for r in q.reasons)
    assert not any("rescale the target" in str(r) for r in q.reasons)
    assert q.notes[0].code == "partial_measures"
    assert f"restriction map orthogonality {q.orthogonality:.2f} (not judged)" in str(q.notes[0])


def test_stretch_alone_flags_a_torn_map(pair):
    V, _, e1, Vc, Fc, truth, ec = pair
    wrong = _torn(V, Vc, truth)
    # Measured stretch 1.55 (the true map 0.99); the right final maps of
    # scripts/eval_partial.py 1.03-1.23, the wrong ones 1.55-1.88. With the distortion given
    # as 0, the stretch alone must make the torn map suspect, and not the true one.
    assert map_stretch(wrong, V, Vc, Fc) > MAX_STRETCH
    C = _restriction(wrong, e1, ec)
    q = partial_quality(wrong, e1, ec, C, overlap=0.65, distortion=0.0)
    assert q.suspect
    (stretched,) = [r for r in q.reasons if r.code == "stretched"]
    assert "stretches the target's edges" in str(stretched)
    assert "distorted" not in q.codes()
    assert not any("geodesic distances" in str(r) for r in q.reasons)
    q = partial_quality(truth, e1, ec, _restriction(truth, e1, ec), overlap=0.65, distortion=0.0)
    assert "stretched" not in q.codes()
    assert not any("stretches" in str(r) for r in q.reasons)


def test_geodesic_refine_pulls_a_torn_region_back(pair):
    V, F, e1, Vc, Fc, truth, _ = pair
    wrong = _torn(V, Vc, truth)
    spacing = np.linalg.norm(V[F[:, 0]] - V[F[:, 1]], axis=1).mean() / math.sqrt(e1.area)
    before = [a.copy() for a in (wrong, V, F, Vc, Fc)]
    fixed = geodesic_refine(wrong, V, F, Vc, Fc)
    for a, b in zip((wrong, V, F, Vc, Fc), before, strict=True):  # inputs not modified
        np.testing.assert_array_equal(a, b)
    # Measured: the torn map 0.176, refined 0.006; the true map refined: 0.007 (the bent copy
    # is no exact part, and the result is a nearest vertex). Half a vertex spacing (0.011)
    # bounds both: the torn region (30 % of the part) must come back, the rest stay.
    assert _error(V, wrong, truth, e1.area) > 5 * spacing
    assert _error(V, fixed, truth, e1.area) < 0.5 * spacing
    assert _error(V, geodesic_refine(truth, V, F, Vc, Fc), truth, e1.area) < 0.5 * spacing
    with pytest.raises(ValueError, match="keep must be in"):
        geodesic_refine(truth, V, F, Vc, Fc, keep=0.0)
    with pytest.raises(ValueError, match="anchors"):
        geodesic_refine(truth, V, F, Vc, Fc, anchors=1)


def _geodesic_refine_reference(p2p, V1, F1, V2, F2, anchors=100, keep=0.5, iterations=3):
    """Refine as first written: every vertex re-mapped at every iteration."""
    import scipy.sparse.csgraph as csgraph

    from o3d_ofp.core.fmap import farthest_points
    from o3d_ofp.core.geometry import edge_graph

    p2p = np.array(p2p)
    s2 = farthest_points(V2, anchors)
    d2 = csgraph.dijkstra(edge_graph(V2, F2), directed=False, indices=s2)
    far = 10.0 * float(np.max(d2[np.isfinite(d2)]))
    for _ in range(iterations):
        d1 = csgraph.dijkstra(edge_graph(V1, F1), directed=False, indices=p2p[s2])
        change = np.abs(d1[:, p2p[s2]] - d2[:, s2]).sum(axis=1) / d2[:, s2].sum(axis=1)
        trusted = np.argsort(change, kind="stable")[: math.ceil(keep * s2.size)]
        f1 = np.where(np.isfinite(d1[trusted]), d1[trusted], far)
        f2 = np.where(np.isfinite(d2[trusted]), d2[trusted], far)
        p2p = nearest_neighbors(f1.T, f2.T)
    return p2p


def test_geodesic_refine_matches_the_plain_algorithm_and_answers_queries(pair):
    """Re-mapping only the anchors in the iterations gives the plain algorithm's maps.

    Its iterations also reuse the distances from a source vertex; ``queries`` gives those
    vertices' rows of the whole map.
    """
    V, F, _e1, Vc, Fc, truth, _ = pair
    wrong = _torn(V, Vc, truth)
    fixed = geodesic_refine(wrong, V, F, Vc, Fc)
    np.testing.assert_array_equal(fixed, _geodesic_refine_reference(wrong, V, F, Vc, Fc))
    queries = np.arange(0, len(Vc), 7)
    np.testing.assert_array_equal(
        geodesic_refine(wrong, V, F, Vc, Fc, queries=queries), fixed[queries]
    )


def test_distortion_does_not_depend_on_units(pair):
    V, F, _, Vc, Fc, truth, _ = pair
    a = geodesic_distortion(truth, V, F, Vc, Fc)
    b = geodesic_distortion(truth, 1e3 * V, F, 1e3 * Vc, Fc)
    assert b == pytest.approx(a, rel=1e-9)
    assert math.isnan(geodesic_distortion(truth, V, None, Vc, Fc))  # a point cloud: unknown


def test_target_that_is_not_a_part_is_flagged(pair):
    e1 = pair[2]
    # An elongated body (the blob stretched 3 x 0.6 x 0.6), 65 % of it kept and scaled to 0.65
    # of the source's area: same units, plausible size, but no part of the round source.
    Vo, Fo = blob(4, seed=3)
    Vo = Vo * np.array([3.0, 0.6, 0.6])
    Vp, Fp, _ = plane_cut(Vo, Fo, axis=0, fraction=0.65)
    ep = ofp.eigenbasis(Vp, Fp, k=99)
    Vp = Vp * math.sqrt(0.65 * e1.area / ep.area)
    ep = ofp.eigenbasis(Vp, Fp, k=99)
    corr = match_eigenbases(e1, ep, options=MatchOptions(partial=True, k_fit=15))
    assert corr.quality.suspect  # measured distortion 0.38
    (distorted,) = [r for r in corr.quality.reasons if r.code == "distorted"]
    assert "geodesic distances" in str(distorted)


def test_landmarks_are_passed_through_and_fix_a_failed_map(pair):
    V, F, e1, Vc, Fc, truth, ec = pair
    # Three true pairs far apart on the part.
    from o3d_ofp.core.fmap import farthest_points

    picks = farthest_points(Vc, 3)
    landmarks = np.stack([truth[picks], picks], axis=1)
    # k_fit 15: fast
    options = {"partial": True, "eigenbases": (e1, ec), "options": MatchOptions(k_fit=15)}
    plain = ofp.match((V, F), (Vc, Fc), **options)
    corr = ofp.match((V, F), (Vc, Fc), landmarks=landmarks, **options)
    assert corr.options["landmarks"] == landmarks.tolist()
    assert plain.options["landmarks"] is None
    # Measured: 0.46 without landmarks at this fit size (a turned map of the near-spherical
    # blob), 0.014 with them (0.025 at the default fit size without). 0.05: two vertex
    # spacings; the landmarks must never make the map worse.
    error = _error(V, corr.p2p_21, truth, e1.area)
    assert error < 0.05
    assert error <= _error(V, plain.p2p_21, truth, e1.area)
    assert not corr.quality.suspect


@pytest.fixture(scope="module")
def cloud(pair):
    """Return the eigenbasis of the part's vertices as a point cloud."""
    return ofp.eigenbasis(pair[3], None, k=99)


def test_point_clouds_are_refused_naming_partial(pair, cloud):
    V, F, e1, Vc, _, _, _ = pair
    # (the words "partial=True" themselves: test_point_cloud_refusals_word_the_keyword_as_written)
    with pytest.raises(ValueError, match=r"needs triangle meshes: the target") as e:
        match_eigenbases(e1, cloud, options=MatchOptions(partial=True))
    assert e.value.option == "partial"
    with pytest.raises(ValueError, match=r"needs triangle meshes: the target") as e:
        ofp.match((V, F), (Vc, None), partial=True, eigenbases=(e1, cloud))
    assert e.value.option == "partial"
    # a mesher that keeps the part's border (a trial: the advice was Poisson, which closes it)
    assert "ball_pivoting" in str(e.value) and "poisson" not in str(e.value).replace(
        "a Poisson surface closes", "")  # fmt: skip


@pytest.mark.slow
@pytest.mark.skipif(not DATA.is_dir(), reason="needs the shared data at ../shared/data")
def test_centaur_part_onto_a_human_is_flagged():
    from o3d_ofp.boundary.convert import geometry_to_arrays

    V1, F1 = geometry_to_arrays(ofp.read_geometry(DATA / "faust/tr_reg_093.ply"))
    V2, F2 = geometry_to_arrays(ofp.read_geometry(DATA / "tosca/centaur4.off"))
    Vc, Fc, _ = plane_cut(V2, F2, axis=0, fraction=0.7)
    e1 = ofp.eigenbasis(V1, F1, k=99)
    ec = ofp.eigenbasis(Vc, Fc, k=99)
    Vc = Vc * math.sqrt(0.7 * e1.area / ec.area)  # in the human's units, 70 % of its area
    corr = ofp.match(
        (V1, F1), (Vc, Fc), partial=True, eigenbases=(e1, ofp.eigenbasis(Vc, Fc, k=99))
    )
    assert corr.quality.suspect  # measured distortion 0.34-0.47 over all starts
    # The doubtful map then registers the part onto the whole, whose map distorts less
    # (scripts/eval_partial.py: 0.116 against 0.191): returned, and flagged as registered.
    (registered,) = [r for r in corr.quality.reasons if r.code == "part_registered"]
    assert registered.values["after"] < registered.values["before"]
    assert "check the result by eye" in str(registered)


@pytest.mark.slow
@pytest.mark.skipif(not DATA.is_dir(), reason="needs the shared data at ../shared/data")
@pytest.mark.parametrize(("axis", "side"), [(2, -1), (0, 1)])  # front removed, one side removed
def test_faust_cut_verdict_agrees_with_the_error(axis, side):
    from o3d_ofp.boundary.convert import geometry_to_arrays

    V1, F1 = geometry_to_arrays(ofp.read_geometry(DATA / "faust/tr_reg_093.ply"))
    V2, F2 = geometry_to_arrays(ofp.read_geometry(DATA / "faust/tr_reg_087.ply"))
    Vc, Fc, truth = plane_cut(side * V2, F2, axis=axis, fraction=0.6)
    corr = ofp.match((V1, F1), (Vc * side, Fc), partial=True)
    error = _error(V1, corr.p2p_21, truth, ofp.laplacian(V1, F1)[1].sum())
    # scripts/eval_partial.py: front removed 0.19 (flagged: the start the geodesic refinement
    # began from, error 0.29, changed distances by 33 %), one side removed 0.021 (not).
    # Maps with errors 0.07-0.1 may fall on either side of MAX_DISTORTION: no claim there.
    # The flagged map of the front removed is then replaced by the registration of the part
    # onto the whole (0.042), flagged as such whatever its error.
    if "part_registered" in corr.quality.codes():
        assert corr.quality.suspect and axis == 2 and error < 0.07
    elif error > 0.1:
        assert corr.quality.suspect
        (distorted,) = [r for r in corr.quality.reasons if r.code == "distorted"]
        assert "geodesic distances" in str(distorted)
    elif error < 0.07:
        assert not corr.quality.suspect
    else:
        pytest.fail(f"error {error:.3f}: between the measured failures and the right maps")


def _largest_piece(V, F, keep):
    """Restrict a cut to its largest connected piece (a plane can leave islands, e.g. hands)."""
    import scipy.sparse as sp
    import scipy.sparse.csgraph as csgraph

    n = len(V)
    adj = sp.coo_matrix((np.ones(F.size), (F.ravel(), np.roll(F, 1, axis=1).ravel())), (n, n))
    labels = csgraph.connected_components(adj, directed=False)[1]
    big = labels == np.bincount(labels).argmax()
    F = F[big[F[:, 0]]]
    used = np.unique(F)
    index = np.full(n, -1)
    index[used] = np.arange(used.size)
    return V[used], index[F], keep[used]


@pytest.mark.slow
@pytest.mark.skipif(not DATA.is_dir(), reason="needs the shared data at ../shared/data")
@pytest.mark.parametrize(
    ("source", "target", "axis", "side", "fraction"),
    [
        pytest.param(
            "faust_remeshed/tr_reg_007.off",
            "faust_remeshed/tr_reg_000.off",
            1,
            -1,
            0.75,
            # A silent failure from stop 28 to 31: on the welded surface (007 has one
            # duplicated vertex) this wrong map (0.269) passed every bound (distortion 0.076,
            # stretch 1.06). Since stop 32 a rival start is refined to the right map (0.077,
            # distortion 0.070), which flags it (RIVAL_MARGIN).
            id="remeshed 007->000 -y kept",
        ),
        pytest.param(
            "faust/tr_reg_019.ply", "faust/tr_reg_094.ply", 1, 1, 0.7, id="019->094 legs removed"
        ),
    ],
)
def test_verdict_of_the_final_map_agrees_with_the_error(source, target, axis, side, fraction):
    from o3d_ofp.boundary.convert import geometry_to_arrays

    V1, F1 = geometry_to_arrays(ofp.read_geometry(DATA / source))
    V2, F2 = geometry_to_arrays(ofp.read_geometry(DATA / target))
    Vc, Fc, keep = _largest_piece(*plane_cut(side * V2, F2, axis=axis, fraction=fraction))
    Vc = side * Vc
    e1 = ofp.eigenbasis(V1, F1, k=99)
    ec = ofp.eigenbasis(Vc, Fc, k=99)
    corr = ofp.match((V1, F1), (Vc, Fc), partial=True, eigenbases=(e1, ec))
    if source.startswith("faust_remeshed"):
        corres = [
            np.loadtxt(DATA / "faust_remeshed" / "corres" / f"{Path(n).stem}.vts", dtype=np.int64)
            - 1
            for n in (source, target)
        ]  # line i of one <-> line i of the other
        index = np.full(len(V2), -1)
        index[keep] = np.arange(keep.size)
        rows = index[corres[1]] >= 0
        error = _error(V1, corr.p2p_21[index[corres[1][rows]]], corres[0][rows], e1.area)
    else:
        error = _error(V1, corr.p2p_21, keep, e1.area)
    # scripts/eval_partial.py: 007 -> 000 error 0.32 (the lower body turned 180 degrees about
    # the vertical; final distortion 0.159, stretch 1.88: flagged; 0.269 and not flagged on the
    # welded surface, stop 28), 019 -> 094 legs removed
    # 0.028 (final distortion 0.081, stretch 1.12: not flagged, though its start's distortion,
    # 0.206, was above the former bound on the start, 0.2).
    if source.startswith("faust_remeshed"):
        # Since 491bade that rival, less distorted and elsewhere on most of the part, is
        # returned instead (0.074 in scripts/eval_partial.py --remeshed), said in a note, and
        # the wrong map it replaced flags it: two maps that pass every other bound.
        assert error < 0.1
        assert [n for n in corr.quality.notes if n.code == "rival_taken"]
        (rival,) = [r for r in corr.quality.reasons if r.code == "rival"]
        assert str(rival).startswith("another start of the fit")
    elif error > 0.1:
        assert corr.quality.suspect
    elif error < 0.07:
        assert not corr.quality.suspect, corr.quality.reasons
    else:
        pytest.fail(f"error {error:.3f}: between the measured failures and the right maps")


@pytest.fixture
def no_eigensolve(monkeypatch):
    from o3d_ofp.core import spectrum

    def refuse(*args, **kwargs):
        raise AssertionError("an eigensolve ran before the refusal")

    monkeypatch.setattr(spectrum, "_solve", refuse)


def test_point_clouds_are_refused_before_any_eigensolve(pair, no_eigensolve):
    V, F, _, Vc, _, _, _ = pair
    with pytest.raises(ValueError, match=r"needs triangle meshes: the target") as e:
        ofp.match((V, F), (Vc, None), partial=True)
    assert e.value.option == "partial"


@pytest.mark.parametrize("where", ["eigenbases", "shapes"])
def test_point_cloud_refusals_word_the_keyword_as_written(pair, cloud, where):
    V, F, e1, Vc, _, _, _ = pair
    with pytest.raises(ValueError) as e:
        if where == "eigenbases":  # the estimation's own check (the point cloud's basis given)
            match_eigenbases(e1, cloud, options=MatchOptions(partial=True))
        else:  # the planner's, from the shapes
            ofp.match((V, F), (Vc, None), partial=True)
    assert str(e.value).startswith("partial=True needs triangle meshes: the target")


def test_point_clouds_are_refused_by_the_command_line_before_any_eigensolve(
    pair, no_eigensolve, tmp_path, capsys
):
    from o3d_ofp.cli import main

    V, F, _, Vc, _, _, _ = pair
    o3d = pytest.importorskip("open3d")
    from o3d_ofp.boundary.convert import triangle_mesh_from_arrays

    src, cloud = tmp_path / "src.ply", tmp_path / "cloud.ply"
    ofp.write_geometry(src, triangle_mesh_from_arrays(V, F, colors=0.5 + 0.0 * V))
    o3d.io.write_point_cloud(str(cloud), o3d.geometry.PointCloud(o3d.utility.Vector3dVector(Vc)))
    out = tmp_path / "out.ply"
    assert main(["transfer", str(src), str(cloud), "--partial", "-o", str(out)]) == 2
    assert "--partial needs triangle meshes" in capsys.readouterr().err
    assert not out.exists()
