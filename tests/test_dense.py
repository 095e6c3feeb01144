"""Matching dense meshes on coarse copies (``o3d_ofp.workflows.dense``, ``core.multiscale``).

The dense path must give maps as good as right maps between differently triangulated shapes
(its coarse copies are triangulated independently), not depend on the units, pose or vertex
order, and never build anything quadratic in the vertex count.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import tracemalloc

import numpy as np
import pytest
import scipy.sparse as sp
from scipy.spatial import cKDTree

from o3d_ofp.core.fmap import farthest_points, grid_samples
from o3d_ofp.core.multiscale import coarse_mesh
from o3d_ofp.core.shapes import blob
from o3d_ofp.workflows import estimate as estimate_module
from o3d_ofp.workflows import plan as plan_module
from o3d_ofp.workflows.estimate import estimate_dense
from o3d_ofp.workflows.options import MatchOptions

from .conftest import load_shared_mesh


def _direct(V1, F1, V2, F2):
    """Match two meshes directly (below the dense threshold: full-resolution eigenbases)."""
    plan = plan_module.plan_pair(V1, F1, V2, F2, task="map")
    assert not plan.dense
    return plan_module.prepare(plan, V1, F1, V2, F2).correspondence


def _twisted(V: np.ndarray) -> np.ndarray:
    """Twist about the x axis (angle proportional to x): a non-rigid copy.

    0.3 rad per unit: the direct match finds it (error 0.036); a twist of 0.8 is too far from
    an isometry for any spectral map (0.37, direct and dense alike).
    """
    a = 0.3 * V[:, 0]
    c, s = np.cos(a), np.sin(a)
    return np.stack([V[:, 0], c * V[:, 1] - s * V[:, 2], s * V[:, 1] + c * V[:, 2]], axis=1)


def _rotation(seed: int) -> np.ndarray:
    q, r = np.linalg.qr(np.random.default_rng(seed).standard_normal((3, 3)))
    q *= np.sign(np.diag(r))
    return q if np.linalg.det(q) > 0 else -q


def _area(V: np.ndarray, F: np.ndarray) -> float:
    e1, e2 = V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]]
    return float(np.linalg.norm(np.cross(e1, e2), axis=1).sum() / 2.0)


def _error(p2p: np.ndarray, V1: np.ndarray, F1: np.ndarray, truth: np.ndarray) -> float:
    """Mean distance to the true source vertex / sqrt(source area) (the benchmarks' measure)."""
    return float(np.linalg.norm(V1[p2p] - V1[truth], axis=1).mean() / math.sqrt(_area(V1, F1)))


def _midpoint(V: np.ndarray, F: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Midpoint subdivision (every triangle into four): the same numbering for the same F."""
    E = np.sort(np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]]), axis=1)
    edges, inverse = np.unique(E, axis=0, return_inverse=True)
    mid = V.shape[0] + inverse.reshape(3, -1).T  # (m, 3): midpoints of edges 01, 12, 20
    a, b, c = F.T
    ab, bc, ca = mid.T
    faces = np.concatenate(
        [np.stack(t, axis=1) for t in ((a, ab, ca), (ab, b, bc), (ca, bc, c), (ab, bc, ca))]
    )
    return np.concatenate([V, 0.5 * (V[edges[:, 0]] + V[edges[:, 1]])]), faces


@pytest.fixture(scope="module")
def blob5():
    return blob(5)  # 10242 vertices


# --- coarse meshes -------------------------------------------------------------------------


def test_coarse_mesh_is_a_closed_surface(blob5):
    V, F = blob5
    Vc, Fc, samples, cell = coarse_mesh(V, F, 1000)
    s = Vc.shape[0]
    assert abs(s - 1000) <= 100  # documented: count ± 10 %
    np.testing.assert_array_equal(Vc, V[samples])
    np.testing.assert_array_equal(cell[samples], np.arange(s))  # each sample heads its cell
    assert cell.min() == 0 and cell.max() == s - 1
    assert np.unique(Fc).size == s  # every coarse vertex is used
    E = np.sort(np.concatenate([Fc[:, [0, 1]], Fc[:, [1, 2]], Fc[:, [2, 0]]]), axis=1)
    _, count = np.unique(E, axis=0, return_counts=True)
    # The dual of the Voronoi cells of a closed surface: (nearly) every edge between two
    # triangles, Euler characteristic 2 (a few non-manifold spots where 4 cells meet).
    assert np.mean(count == 2) >= 0.99
    assert abs(s - count.size + Fc.shape[0] - 2) <= 6
    # Orientation kept: coarse normals point outwards like the blob's (star-shaped about 0).
    n = np.cross(Vc[Fc[:, 1]] - Vc[Fc[:, 0]], Vc[Fc[:, 2]] - Vc[Fc[:, 0]])
    assert np.mean(np.einsum("ij,ij->i", n, Vc[Fc].mean(axis=1)) > 0) >= 0.99


def test_coarse_mesh_independent_of_units_pose_and_order(blob5):
    V, F = blob5
    _, _, ref, _ = coarse_mesh(V, F, 1000)
    ref = set(ref.tolist())
    perm = np.random.default_rng(0).permutation(V.shape[0])
    inv = np.argsort(perm)
    moved = [
        (V * 1e-3, F, np.arange(V.shape[0])),
        (V * 1e3 @ _rotation(1).T + [5.0, -3.0, 40.0], F, np.arange(V.shape[0])),
        (V[perm], inv[F], perm),  # vertex i of the permuted shape is vertex perm[i]
    ]
    for Vm, Fm, back in moved:
        samples = set(back[coarse_mesh(Vm, Fm, 1000)[2]].tolist())
        # The same samples, to round-off (a vertex exactly between two cubes may differ).
        assert len(samples & ref) >= 0.99 * len(ref)


def test_coarse_mesh_on_given_samples(blob5):
    V, F = blob5
    _, Fc_ref, ref, cell = coarse_mesh(V, F, 500)
    Vc, Fc, samples, cell_given = coarse_mesh(V, F, samples=ref.astype(np.int32))
    np.testing.assert_array_equal(samples, ref)
    np.testing.assert_array_equal(Fc, Fc_ref)
    np.testing.assert_array_equal(cell_given, cell)
    np.testing.assert_array_equal(Vc, V[ref])
    with pytest.raises(TypeError, match="either count or samples"):
        coarse_mesh(V, F, 500, samples=ref)
    with pytest.raises(TypeError, match="either count or samples"):
        coarse_mesh(V, F)
    for bad in (ref[:3], np.append(ref, ref[0]), np.append(ref, V.shape[0]), ref + 0.5,
                ref[:, None]):  # fmt: skip
        with pytest.raises(ValueError, match=r"samples must be at least 4 distinct vertex"):
            coarse_mesh(V, F, samples=bad)


def test_coarse_mesh_welds_repeated_positions(blob5):
    """An STL file: every triangle with its own three vertices (no shared vertex at all).

    Unwelded, every face would be a component of its own and no cell would cross an edge;
    the coarse mesh is the welded mesh's, on the given vertices.
    """
    from scipy.sparse.csgraph import connected_components

    V, F = blob5
    Vs, Fs = V[F.reshape(-1)], np.arange(3 * F.shape[0]).reshape(-1, 3)
    Vc, Fc, samples, cell = coarse_mesh(Vs, Fs, 1000)
    ref_Vc, ref_Fc, _, ref_cell = coarse_mesh(V, F, 1000)
    np.testing.assert_array_equal(Vc, Vs[samples])
    assert Fc.shape == ref_Fc.shape
    np.testing.assert_array_equal(np.sort(Vc, axis=0), np.sort(ref_Vc, axis=0))
    E = np.concatenate([Fc[:, [0, 1]], Fc[:, [1, 2]], Fc[:, [2, 0]]])
    graph = sp.coo_matrix((np.ones(E.shape[0]), (E[:, 0], E[:, 1])), shape=(Vc.shape[0],) * 2)
    assert connected_components(graph, directed=False)[0] == 1
    # the copies of one vertex share its cell: the same partition as the welded mesh's
    copies = F.reshape(-1)
    pairs = np.unique(np.stack([cell, ref_cell[copies]], axis=1), axis=0)
    assert pairs.shape[0] == Vc.shape[0]  # one welded cell for every cell, and back
    # given samples (the welded mesh's, as indices of its copies) are taken once each
    first = np.unique(copies, return_index=True)[1]  # a copy of every vertex
    _, _, again, _ = coarse_mesh(Vs, Fs, samples=np.concatenate([first[:500], first[:500]]))
    assert again.size == 500


def test_a_mesh_asked_for_all_its_vertices_is_its_own_coarse_copy(blob5):
    """A shape no larger than the coarse size (a 6.9k source onto a 110k target) is kept as is.

    A grid of n cubes would keep ~0.9 n vertices and re-triangulate the shape.
    """
    from o3d_ofp.workflows.dense import coarse_shape

    V, F = blob5
    n = V.shape[0]
    Vc, Fc, samples, cell = coarse_mesh(V, F, n)
    np.testing.assert_array_equal(samples, np.arange(n))
    np.testing.assert_array_equal(cell, np.arange(n))
    np.testing.assert_array_equal(Vc, V)
    assert set(map(tuple, np.sort(Fc, axis=1))) == set(map(tuple, np.sort(F, axis=1)))
    copy = coarse_shape(V, F, k=5, coarse_vertices=3 * n)  # asked for more than it has
    np.testing.assert_array_equal(copy.samples, np.arange(n))
    assert copy.faces.shape == F.shape
    # split along every edge (an STL file): its welded vertices, one copy of each
    Vs, Fs = V[F.reshape(-1)], np.arange(3 * F.shape[0]).reshape(-1, 3)
    Vw, Fw, samples, cell = coarse_mesh(Vs, Fs, 3 * n)
    assert Vw.shape[0] == n and Fw.shape == F.shape
    np.testing.assert_array_equal(Vs[samples[cell]], Vs)  # each copy in its own vertex's cell
    assert coarse_mesh(V, F, n - 1)[2].size < n  # below n: well-spread samples
    # two such STL files of one triangulation share every welded vertex as their samples
    from o3d_ofp.workflows.dense import shared_samples

    bent = Vs.copy()
    bent[:, 1] += 0.1 * bent[:, 0] ** 2
    shared = shared_samples([(Vs, Fs), (bent, Fs)], coarse_vertices=n + 100)  # < 3 n copies
    assert shared is not None and shared.size == n
    np.testing.assert_array_equal(np.unique(cell[shared]), np.arange(n))  # one per vertex


def test_coarse_mesh_rejects_bad_input(blob5):
    V, F = blob5
    with pytest.raises(ValueError, match="count"):
        coarse_mesh(V, F, 2)
    with pytest.raises(ValueError, match="faces"):
        coarse_mesh(V, F[:, :2], 100)
    with pytest.raises(ValueError, match="faces"):
        coarse_mesh(V, F + V.shape[0], 100)


def test_pooled_farthest_points_spread_like_exact():
    V, _ = _midpoint(*blob(5))  # 40962 vertices > FPS_POOL · 500 = 16000: the pooled sampling
    count = 500
    pooled = farthest_points(V, count)
    assert pooled.shape == (count,) and np.unique(pooled).size == count

    def covering(samples: np.ndarray) -> float:
        return float(cKDTree(V[samples]).query(V)[0].max())

    # exact FPS, from the same start rule (the pooled path is taken only without ``start``)
    X = V - V.mean(axis=0)
    exact = farthest_points(V, count, start=int(np.argmax(np.einsum("ij,ij->i", X, X))))
    # FPS is a 2-approximation of the best covering radius; the pooled sampling must stay
    # close to the exact one (measured: 1.05x).
    assert covering(pooled) <= 1.3 * covering(exact)
    perm = np.random.default_rng(1).permutation(V.shape[0])
    assert set(perm[farthest_points(V[perm], count)].tolist()) == set(pooled.tolist())
    g = grid_samples(V, 4000)
    assert abs(g.size - 4000) <= 400 and np.unique(g).size == g.size


# --- the dense match -----------------------------------------------------------------------


@pytest.fixture(scope="module")
def twisted_pair(blob5):
    V, F = blob5
    return V, F, _twisted(V) * 1.7, F  # the truth: the identity


@pytest.fixture(scope="module")
def direct_and_dense(twisted_pair):
    V1, F1, V2, F2 = twisted_pair
    direct = _direct(V1, F1, V2, F2)
    dense = estimate_dense(V1, F1, V2, F2, coarse_vertices=3000)
    return direct, dense


def test_dense_path_as_good_as_direct(twisted_pair, direct_and_dense):
    V1, F1, V2, _ = twisted_pair
    direct, dense = direct_and_dense
    assert direct.options.get("dense") is None and dense.options["dense"] is True
    truth = np.arange(V2.shape[0])
    e_direct = _error(direct.p2p_21, V1, F1, truth)
    e_dense = _error(dense.p2p_21, V1, F1, truth)
    # Measured: direct 0.0363, dense (3000 coarse vertices, one triangulation: the copies on
    # the same samples) 0.0367, each copy on its own grid 0.0381. The dense path
    # interpolates eigenfunctions of a coarser mesh: allowed 1.25x the direct error plus a
    # quarter of the coarse spacing (sqrt(area / 3000) / sqrt(area) / 4 = 0.0046).
    assert e_dense <= 1.25 * e_direct + 0.25 / math.sqrt(3000)
    assert dense.fmap_12 is None and dense.quality is not None and not dense.quality.suspect
    assert dense.quality.coverage == np.unique(dense.p2p_21).size / V1.shape[0]


def test_dense_path_invariant_to_units_pose_and_order(twisted_pair):
    V1, F1, V2, F2 = twisted_pair
    # The reference has its target's vertices in another order too: a pair with one
    # triangulation has its coarse copies sampled alike (test_one_triangulation_...).
    perm_0 = np.random.default_rng(4).permutation(V2.shape[0])
    inv_0 = np.argsort(perm_0)
    ref = estimate_dense(V1, F1, V2[perm_0], inv_0[F2], coarse_vertices=3000)
    ref = dataclasses.replace(ref, p2p_21=ref.p2p_21[inv_0])
    perm = np.random.default_rng(2).permutation(V2.shape[0])
    inv = np.argsort(perm)
    # All at once (any one breaking fails the test): the source in other units, the target
    # shrunk, rotated, moved and with its vertices in another order.
    V2m = (1e-3 * V2 @ _rotation(3).T + [0.2, 0.0, -1.0])[perm]
    moved = estimate_dense(1e3 * V1, F1, V2m, inv[F2], coarse_vertices=3000)
    p2p = moved.p2p_21[inv]
    # The same coarse meshes (to round-off), hence the same map but for round-off, which the
    # fit's optimizer and ZoomOut amplify into moves to neighbouring vertices (permuting the
    # vertices reorders every sum). Measured at commit a38f308: every vertex identical, each
    # change alone and all at once (before, 95.6 % with the pose and units changed and 86.2 %
    # with the order, mean moves 0.05 and 0.15 edge lengths): the bounds leave that room.
    spacing = math.sqrt(_area(V1, F1) / V1.shape[0])
    truth = np.arange(V2.shape[0])
    assert np.mean(p2p == ref.p2p_21) >= 0.8
    assert np.linalg.norm(V1[p2p] - V1[ref.p2p_21], axis=1).mean() <= 0.3 * spacing
    assert _error(p2p, V1, F1, truth) <= 1.05 * _error(ref.p2p_21, V1, F1, truth)


def test_dense_path_has_no_quadratic_memory(monkeypatch):
    # 40962 vertices per shape: an (n1 x n2) float32 array alone is 6.7 GB; the dense path
    # must stay far below (its largest arrays are (n, 100) embeddings, 33 MB each).
    import o3d_ofp as ofp

    V, F = _midpoint(*blob(5))
    V2 = _twisted(V) * 1.7
    monkeypatch.setattr(plan_module, "DENSE_VERTICES", 20_000)
    monkeypatch.setattr(estimate_module, "COARSE_VERTICES", 2500)
    tracemalloc.start()
    try:
        corr = ofp.match((V, F), (V2, F))
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert corr.options["dense"] is True  # the size alone chose the dense path
    assert peak < 0.6e9, peak / 1e9
    # and it is a right map (measured 0.03; a failed one: 0.37)
    assert _error(corr.p2p_21, V, F, np.arange(V.shape[0])) < 0.06


def test_a_given_coarse_source_gives_the_same_map(twisted_pair, direct_and_dense):
    from o3d_ofp.workflows.dense import coarse_shape

    V1, F1, V2, F2 = twisted_pair
    _, ref = direct_and_dense
    coarse = coarse_shape(V1, F1, k=99, coarse_vertices=3000)
    given = estimate_dense(V1, F1, V2, F2, coarse_vertices=3000, coarse_source=coarse)
    # The same coarse mesh and eigenbasis as the pair's own: the same map, to the vertex.
    np.testing.assert_array_equal(given.p2p_21, ref.p2p_21)
    with pytest.raises(ValueError, match="copy of the source was built for a shape of 10242 "
                       "vertices; it has 10241"):
        estimate_dense(V1[:-1], F1, V2, F2, coarse_vertices=3000, coarse_source=coarse)


def test_dense_path_takes_landmarks_closer_than_a_coarse_cell(twisted_pair):
    """Two landmarks in one coarse cell of the source, in two of the target: not an error.

    They used to reach the coarse estimate as one coarse source vertex paired with two coarse
    target vertices, which it refused, naming coarse vertices the caller never gave.
    """
    from o3d_ofp.core._warnings import OFPWarning
    from o3d_ofp.workflows.dense import coarse_shape

    V1, F1, V2, F2 = twisted_pair
    # the copies the dense path makes of this pair (one triangulation: the same samples)
    c1 = coarse_shape(V1, F1, k=99, coarse_vertices=3000)
    c2 = coarse_shape(V2, F2, k=99, samples=c1.samples)
    # a source cell holding two vertices whose true target vertices (the same indices) lie in
    # two target cells
    a, b = next(
        (a, int(b))
        for a in range(V1.shape[0])
        for b in np.flatnonzero(c1.cell == c1.cell[a])
        if c2.cell[a] != c2.cell[b]
    )
    far = int(np.argmax(np.linalg.norm(V1 - V1[a], axis=1)))
    # and two vertices that share a cell on both shapes (away from the others): merged
    c, d = next(
        (c, int(d))
        for c in range(V1.shape[0])
        if c1.cell[c] not in c1.cell[[a, far]]
        for d in np.flatnonzero(c1.cell == c1.cell[c])
        if d != c and c2.cell[c] == c2.cell[d]
    )
    given = [[a, a], [b, b], [far, far], [c, c], [d, d], [a, a]]  # the first pair twice, too
    options = MatchOptions(landmarks=given)
    np.testing.assert_array_equal(options.landmarks, given[:5])  # the repeated pair once
    with pytest.warns(OFPWarning, match=r"landmarks \[") as said:
        corr = estimate_dense(V1, F1, V2, F2, options=options, coarse_vertices=3000)
    # one warning, naming the left-out pair alone, as given; the quality keeps it as a note
    (message,) = [str(w.message) for w in said if "on the coarse copies" in str(w.message)]
    assert message.startswith(f"landmarks [{b}, {b}]: on the coarse copies")
    assert message.endswith("match at full resolution (from Python: eigenbases=, slow)")
    (note,) = [n for n in corr.quality.notes if n.code == "landmarks_dropped"]
    assert str(note) == message
    assert not corr.quality.suspect
    assert corr.options["landmarks"] == given[:5]  # the pairs as given, the repeated one once
    # every pair is kept at full resolution, the one left out of the coarse copies too
    kept = np.array(given[:5])
    np.testing.assert_array_equal(corr.p2p_21[kept[:, 1]], kept[:, 0])
    # the map is the pair's (the dense map without landmarks: 0.037)
    assert _error(corr.p2p_21, V1, F1, np.arange(V2.shape[0])) < 0.06


def test_dense_path_matches_a_target_split_along_seams(twisted_pair):
    # The target in eight pieces that meet along seams, each with its own copies of the
    # seams' vertices (an STL file as Open3D reads it, a mesh split along its UV seams). The
    # cleaning welds it into one surface, but its coarse copy was made unwelded: eight coarse
    # pieces, refused as "the shape has 8 connected components" (FAUST subdivided to 110k
    # vertices, from an STL: 2189). Measured now: 0.038, as the pair's own map (0.037).
    V1, F1, V2, F2 = twisted_pair
    piece = (V2[F2].mean(axis=1) > 0) @ np.array([1, 2, 4])  # the octant of every face
    copy = piece[:, None] * V2.shape[0] + F2  # a vertex of each piece: its own copy
    used, F2s = np.unique(copy, return_inverse=True)
    V2s, F2s = V2[used % V2.shape[0]], F2s.reshape(-1, 3)
    assert V2s.shape[0] > V2.shape[0]
    corr = estimate_dense(V1, F1, V2s, F2s, coarse_vertices=3000)
    assert _error(corr.p2p_21, V1, F1, used % V2.shape[0]) < 0.06


def test_dense_path_rejects_bad_input(twisted_pair):
    V1, F1, V2, F2 = twisted_pair
    with pytest.raises(ValueError, match="landmarks") as info:
        estimate_dense(V1, F1, V2, F2, options=MatchOptions(landmarks=[[0, V2.shape[0]]]))
    assert info.value.option == "landmarks" and "target vertex indices" in str(info.value)
    with pytest.raises(ValueError, match="landmarks") as info:  # refused by the options
        MatchOptions(landmarks=[[0, -1]])
    assert info.value.option == "landmarks"
    with pytest.raises(ValueError, match="coarse_vertices"):
        estimate_dense(V1, F1, V2, F2, coarse_vertices=10)
    with pytest.raises(TypeError, match="coarse_vertices"):
        estimate_dense(V1, F1, V2, F2, coarse_vertices=2500.5)


def test_dense_path_refuses_point_clouds(twisted_pair):
    V1, _, V2, F2 = twisted_pair
    with pytest.raises(ValueError, match="faces"):
        estimate_dense(V1, None, V2, F2)


def test_dense_path_refuses_a_target_in_pieces_before_any_coarse_copy(twisted_pair, monkeypatch):
    """Two comparable components are refused before either coarse copy is built and solved."""
    V1, F1, V2, F2 = twisted_pair
    Vp = np.concatenate([V2, V2 + np.array([10.0, 0.0, 0.0])])
    Fp = np.concatenate([F2, F2 + V2.shape[0]])
    fail = lambda *a, **k: pytest.fail("coarse copy built")  # noqa: E731
    monkeypatch.setattr(estimate_module, "coarse_shape", fail)
    with pytest.raises(ValueError, match=r"^the target: the shape has 2 connected components"):
        estimate_dense(V1, F1, Vp, Fp)


@pytest.mark.slow
def test_dense_path_on_a_subdivided_human():
    # FAUST 093 -> 087 midpoint-subdivided (27554 vertices, one triangulation: the truth is
    # the identity). With the target's vertices in another order the dense path matches
    # coarse copies sampled one independently of the other, i.e. two differently
    # triangulated shapes: it is held to the errors of the right maps among the 32 FAUST and
    # remeshed-FAUST pairs (at most 0.0267 sqrt(area), scripts/eval_matching.py --all-pairs)
    # and to twice the direct map's. Measured: direct 0.0131, dense 0.0191 (20000 coarse
    # vertices); maps wrong on a region (a limb on the other, measured on those pairs) are
    # 0.039-0.187. In the given order the copies share their samples (one triangulation,
    # dense.shared_samples) and the map is held to 1.25x the direct one's, the aim of the
    # dense path: measured 0.0148 (1.13x), where independent copies give 1.46x.
    V1, F1 = _midpoint(*load_shared_mesh("faust/tr_reg_093.ply"))
    V2, F2 = _midpoint(*load_shared_mesh("faust/tr_reg_087.ply"))
    truth = np.arange(V2.shape[0])
    perm = np.random.default_rng(5).permutation(V2.shape[0])
    inv = np.argsort(perm)
    direct = _direct(V1, F1, V2, F2)
    shared = estimate_dense(V1, F1, V2, F2)
    apart = estimate_dense(V1, F1, V2[perm], inv[F2])
    e_direct, e_shared = (_error(c.p2p_21, V1, F1, truth) for c in (direct, shared))
    e_apart = _error(apart.p2p_21[inv], V1, F1, truth)
    assert e_apart <= min(0.0267, 2 * e_direct), (e_apart, e_direct)
    assert e_shared <= 1.25 * e_direct, (e_shared, e_direct)


def test_one_triangulation_gives_coarse_copies_the_same_samples(twisted_pair):
    from o3d_ofp.workflows.dense import coarse_shape, shared_samples
    from o3d_ofp.workflows.estimate import coarse_copies

    V1, F1, V2, F2 = twisted_pair
    c1, c2 = coarse_copies([(V1, F1), (V2, F2)], k=[20, 20], size=1500)
    np.testing.assert_array_equal(c1.samples, c2.samples)
    # each on its own (the target's vertices in another order: other faces) the twist moves
    # the target's grid: most samples differ
    perm = np.random.default_rng(6).permutation(V2.shape[0])
    inv = np.argsort(perm)
    _, c3 = coarse_copies([(V1, F1), (V2[perm], inv[F2])], k=[20, 20], size=1500)
    assert np.mean(np.isin(perm[c3.samples], c1.samples)) < 0.5  # measured 0.21
    # the same faces in another integer type, the target moved, turned and in other units,
    # the source too: still one triangulation, the same samples as the source's own grid
    moved = 1e-3 * V2 @ _rotation(7).T + [3.0, 0.0, 1.0]
    c5, c6 = coarse_copies([(1e3 * V1, F1), (moved, F2.astype(np.int32))], k=[20, 20],
                           size=1500)  # fmt: skip
    np.testing.assert_array_equal(c5.samples, c1.samples)
    np.testing.assert_array_equal(c6.samples, c1.samples)
    # other faces or vertex counts, or a point cloud: no shared samples
    assert shared_samples([(V1, F1), (V2, F2[::-1])]) is None
    assert shared_samples([(V1, F1), (V2[:-1], F2)]) is None
    assert shared_samples([(V1, None), (V2, None)]) is None
    assert shared_samples([(V1, F1)]) is None
    # as STL files (each triangle its own vertices): the same faces whatever the shapes; one
    # template's two poses are shared, a mesh whose triangles come in another order (another
    # triangulation, as far as the files tell) is not
    def stl(V, F):
        return V[F.reshape(-1)], np.arange(F.size).reshape(-1, 3)

    shuffled = F2[np.random.default_rng(8).permutation(F2.shape[0])]
    assert shared_samples([stl(V1, F1), stl(V2, F2)]) is not None
    assert shared_samples([stl(V1, F1), stl(V2, shuffled)]) is None
    # a given copy (a collection's shared source) lends its samples, whatever its size
    given = coarse_shape(V1, F1, k=20, coarse_vertices=1000)
    _, c4 = coarse_copies([(V1, F1), (V2, F2)], k=[20, 20], size=1500, given=(given, None))
    np.testing.assert_array_equal(c4.samples, given.samples)
    assert abs(c4.samples.size - 1000) <= 100


# --- transfers route large pairs through the dense path ------------------------------------


@pytest.fixture
def small_threshold(monkeypatch):
    """Make 10k-vertex shapes 'dense' (threshold 5000, coarse meshes of 3000 vertices)."""
    monkeypatch.setattr(plan_module, "DENSE_VERTICES", 5000)
    monkeypatch.setattr(estimate_module, "COARSE_VERTICES", 3000)


def _spy_eigenbasis(monkeypatch) -> list[int]:
    """Record the size of every full-resolution eigenbasis the planner's jobs compute."""
    # One process: a spy called in a side-by-side child would record there.
    monkeypatch.setenv("O3D_OFP_PROCESSES", "1")
    sizes: list[int] = []
    real = plan_module.eigenbasis

    def spy(V, F, *, k, **options):
        sizes.append(k)
        return real(V, F, k=k, **options)

    monkeypatch.setattr(plan_module, "eigenbasis", spy)
    return sizes


def _prepared_transfer(V1, F1, V2, F2):
    """Plan and prepare a color transfer with the default bases (29 / 39)."""
    plan = plan_module.plan_pair(V1, F1, V2, F2, task="colors")
    return plan, plan_module.prepare(plan, V1, F1, V2, F2)


def test_a_cache_the_dense_path_does_not_use_is_said(
    small_threshold, twisted_pair, direct_and_dense, tmp_path, caplog
):
    """The cache holds full-resolution eigenbases and bases: coarse copies are not in it.

    A new user's second run with --cache on 110k-vertex meshes took as long as the first, and
    the folder was never made, without a word.
    """
    from o3d_ofp.core._warnings import OFPWarning

    V1, F1, V2, F2 = twisted_pair
    _, dense = direct_and_dense
    cache = tmp_path / "cache"
    plan = plan_module.plan_pair(V1, F1, V2, F2, task="colors", given=dense)
    assert plan.coarse_bases == (True, True)
    with caplog.at_level(logging.DEBUG, logger="o3d_ofp.workflows.plan"):
        with pytest.warns(OFPWarning, match=r"^cache_dir= holds full-resolution"):
            plan_module.prepare(plan, V1, F1, V2, F2, given=dense, cache_dir=cache)
    (said,) = [r.said for r in caplog.records if getattr(r, "said", None)]
    assert said.code == "cache_unused"
    assert said.text(cli=True).startswith("--cache holds full-resolution")  # the CLI's words
    assert not cache.exists()


def test_colors_of_a_dense_pair_go_through_bases_on_the_coarse_copies(
    monkeypatch, small_threshold, twisted_pair
):
    from o3d_ofp.workflows.pipeline import carry

    V1, F1, V2, F2 = twisted_pair
    sizes = _spy_eigenbasis(monkeypatch)
    plan, prepared = _prepared_transfer(V1, F1, V2, F2)
    corr = prepared.correspondence
    assert plan.dense and corr.options["dense"] is True and plan.coarse_bases == (True, True)
    assert sizes == [] and prepared.eig_1 is None  # no full-resolution eigenpair at all
    c1, c2 = prepared.coarse
    B1, B2 = prepared.bases
    assert (B1.n_vertices, B2.n_vertices) == (len(c1.vertices), len(c2.vertices))
    assert (B1.k, B2.k) == (29, 39)  # the plan's sizes, on the copies the match used
    # the coarse map is right (measured 0.03 at 3000 coarse vertices; a failed map: > 0.3)
    assert _error(corr.p2p_21, V1, F1, np.arange(V2.shape[0])) < 0.06
    # Colors come back as the full-resolution bases carry them. Measured here: 2.5 % apart
    # (relative L2), 13.2 % from the truth against their 12.3 % (the truth: the source's own
    # values, the pair sharing its numbering; both bases are low-passes). A wrong restriction,
    # map or interpolation (the cells of the other shape, say) puts them tens of per cent
    # apart.
    f = np.stack([np.sin(3 * V1[:, 0] / np.ptp(V1)), np.cos(4 * V1[:, 1] / np.ptp(V1))], axis=1)
    g = carry(f, plan, prepared)
    monkeypatch.setattr(plan_module, "DENSE_VERTICES", 10**9)
    full_plan = plan_module.plan_pair(V1, F1, V2, F2, task="colors")
    assert full_plan.coarse_bases == (False, False)
    full = carry(f, full_plan, plan_module.prepare(full_plan, V1, F1, V2, F2, given=corr))

    def rel(a, b):
        return np.linalg.norm(a - b) / np.linalg.norm(b - b.mean(axis=0))

    assert rel(g, full) < 0.05, rel(g, full)
    assert rel(g, f) < 1.2 * rel(full, f), (rel(g, f), rel(full, f))


def test_colors_from_a_small_source_onto_a_dense_target(monkeypatch, small_threshold, twisted_pair):
    """Only the side above the threshold has its basis on its coarse copy, and both work."""
    from o3d_ofp.workflows.maps import Correspondence
    from o3d_ofp.workflows.pipeline import carry

    V1, _, V2, F2 = twisted_pair
    small, F_small = blob(4)  # 2562 vertices: below the threshold; the same sphere as blob(5)
    p2p = cKDTree(small).query(V1)[1]  # the target is V1 twisted: its points on the source
    corr = Correspondence.from_p2p(p2p, (small, F_small), (V2, F2))
    plan = plan_module.plan_pair(small, F_small, V2, F2, task="colors", given=corr)
    assert plan.coarse_bases == (False, True) and plan.eig_k == (29, 0)
    prepared = plan_module.prepare(plan, small, F_small, V2, F2, given=corr)
    assert prepared.coarse[0] is None and prepared.restrict_1 is None
    assert prepared.prolong_2.shape == (V2.shape[0], len(prepared.coarse[1].vertices))
    f = np.cos(3 * small[:, 2] / np.ptp(small))
    truth = np.cos(3 * V1[:, 2] / np.ptp(small))
    g = carry(f, plan, prepared)
    # measured 3.4 % (relative L2; full-resolution bases 3.1 %, the nearest source vertex's
    # value 5.8 %): the interpolation along the surface adds little
    assert np.linalg.norm(g - truth) / np.linalg.norm(truth - truth.mean()) < 0.05
    back = plan_module.plan_pair(V2, F2, small, F_small, task="colors")
    assert back.coarse_bases == (True, False) and back.eig_k == (0, 39)  # map: dense path


def test_only_colors_with_no_given_basis_have_their_bases_on_coarse_copies(
    small_threshold, twisted_pair
):
    import o3d_ofp as ofp
    from o3d_ofp.workflows.options import DetailOptions

    V1, F1, V2, F2 = twisted_pair
    B = ofp.ofp_basis(ofp.eigenbasis(V1, F1, k=29))
    e = ofp.eigenbasis(V2, F2, k=39)

    def coarse(**options):
        return plan_module.plan_pair(V1, F1, V2, F2, **options).coarse_bases

    assert coarse(task="colors") == (True, True)
    assert coarse(task="colors", given_bases=(B, None)) == (False, True)
    assert coarse(task="colors", eigenbases=(None, e)) == (True, False)
    assert coarse(task="detail", detail=DetailOptions(mode="coordinates")) == (False, False)
    assert coarse(task="texture") == (False, False)
    assert coarse(task="map") == (False, False)


def test_memory_of_bases_on_coarse_copies_is_counted_at_their_size(
    monkeypatch, small_threshold, twisted_pair
):
    """A 440k-vertex side whose basis is on its coarse copy is not refused for the full size."""
    import dataclasses

    from o3d_ofp.core.wording import AdvisedError

    V1, F1, V2, F2 = twisted_pair
    plan = plan_module.plan_pair(V1, F1, V2, F2, task="colors")
    assert plan.coarse_bases == (True, True)
    big = np.zeros((440_000, 3))
    shapes = ((big, F1), (big, F2))
    names = ("the source", "the target")
    # measured: about 14 GB estimated for two full-size k = 29 / 39 bases, 0.65 GB for two of
    # 20 000 vertices
    monkeypatch.setattr(plan_module, "available_memory", lambda: 4e9)
    plan_module._check_memory(plan, shapes, [], (None, None), names)
    full = dataclasses.replace(plan, coarse_bases=(False, False))
    with pytest.raises(AdvisedError, match="memory"):
        plan_module._check_memory(full, shapes, [], (None, None), names)


def test_transfer_below_the_threshold_shares_one_eigensolve(monkeypatch, twisted_pair):
    V1, F1, V2, F2 = twisted_pair
    sizes = _spy_eigenbasis(monkeypatch)
    plan, prepared = _prepared_transfer(V1, F1, V2, F2)
    e1, e2, corr = prepared.eig_1, prepared.eig_2, prepared.correspondence
    assert not plan.dense and corr.options.get("dense") is None
    assert sizes == [99, 99]  # one basis per shape serves the estimation and the transfer
    assert (e1.k, e2.k) == (99, 99)
    assert prepared.bases is not None  # and the OFP bases were built on them


def test_given_eigenbases_are_matched_at_full_resolution(small_threshold, twisted_pair):
    """Both eigenbases given: the map is estimated from them, not on coarse copies."""
    import o3d_ofp as ofp

    V1, F1, V2, F2 = twisted_pair
    assert plan_module.plan_pair(V1, F1, V2, F2, task="map").dense  # above the threshold
    e1, e2 = ofp.eigenbasis(V1, F1, k=99), ofp.eigenbasis(V2, F2, k=99)
    one = plan_module.plan_pair(V1, F1, V2, F2, task="map", eigenbases=(e1, None))
    assert one.dense  # one side's eigenbasis alone: still coarse copies
    both = plan_module.plan_pair(V1, F1, V2, F2, task="map", eigenbases=(e1, e2))
    assert not both.dense
    corr = ofp.match((V1, F1), (V2, F2), eigenbases=(e1, e2))
    assert corr.options.get("dense") is None and corr.eigenbases == (e1, e2)
    assert _error(corr.p2p_21, V1, F1, np.arange(V2.shape[0])) < 0.06
