"""Point maps of functional maps by local search (``o3d_ofp.core.multiscale``).

The local search must give the brute force's answer: the exact nearest neighbour in the
unit-area spectral embeddings, whatever the map, the units, pose or vertex order.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from scipy.spatial import cKDTree

from o3d_ofp.core import multiscale
from o3d_ofp.core.correspondence import fmap_from_p2p, nearest_neighbors, p2p_from_fmap
from o3d_ofp.core.fmap import unit_area
from o3d_ofp.core.multiscale import (
    _interpolation,
    cell_restriction,
    coarse_eigenbasis,
    coarse_mesh,
    extend_fmap,
    extend_p2p,
    local_p2p_from_fmap,
    surface_prolongation,
)
from o3d_ofp.core.spectrum import EigenBasis, eigenbasis

from .conftest import load_shared_mesh


def _twisted(V: np.ndarray) -> np.ndarray:
    """Twist about the x axis (angle proportional to x): a non-rigid, isometric-ish copy."""
    a = 0.8 * V[:, 0]
    c, s = np.cos(a), np.sin(a)
    return np.stack([V[:, 0], c * V[:, 1] - s * V[:, 2], s * V[:, 1] + c * V[:, 2]], axis=1)


def _exact(C, e1, e2):
    """Run the brute force on the unit-area bases (the reference the local search must match)."""
    return p2p_from_fmap(C * math.sqrt(e1.area / e2.area), unit_area(e1), unit_area(e2))


def _rotation(seed: int) -> np.ndarray:
    q, r = np.linalg.qr(np.random.default_rng(seed).standard_normal((3, 3)))
    q *= np.sign(np.diag(r))
    return q if np.linalg.det(q) > 0 else -q


def _moved(eig: EigenBasis, scale: float, rotation: np.ndarray, shift) -> EigenBasis:
    """Move and scale the shape of a basis: the exact transform of every array."""
    return dataclasses.replace(
        eig,
        evals=eig.evals / scale**2,
        evecs=eig.evecs / scale,
        mass=eig.mass * scale**2,
        vertices=scale * eig.vertices @ rotation.T + np.asarray(shift, dtype=float),
    )


@pytest.fixture(scope="module")
def blob_pair(blob_mesh):
    V, F = blob_mesh
    e1 = eigenbasis(V, F, k=49)
    e2 = eigenbasis(_twisted(V) * 1.7, F, k=49)
    C = fmap_from_p2p(np.arange(V.shape[0]), e1, e2)  # the true map: same triangulation
    return e1, e2, C


@pytest.fixture(scope="module")
def coarse_blob(blob_mesh, blob_pair):
    """700-point farthest-point coarse bases of the blob pair, and the true coarse map.

    Returns ``(b1, s1, b2, s2, truth)``: each shape's coarse eigenbasis (29 functions) and
    samples, and for every target sample its nearest source sample.
    """
    V, _ = blob_mesh
    V2 = blob_pair[1].vertices
    b1, s1 = coarse_eigenbasis(V, 700, k=29)
    b2, s2 = coarse_eigenbasis(V2, 700, k=29)
    return b1, s1, b2, s2, cKDTree(V[s1]).query(V[s2])[1]


@pytest.fixture(scope="module")
def blob_reference(blob_pair):
    e1, e2, C = blob_pair
    return local_p2p_from_fmap(C, e1, e2)


def test_matches_the_exact_search(blob_pair, blob_reference):
    e1, e2, C = blob_pair
    exact = _exact(C, e1, e2)
    assert blob_reference.dtype == np.int64
    assert blob_reference.shape == (e2.n_vertices,)
    assert np.mean(blob_reference == exact) >= 0.999
    # the number of cells changes the work, not the answer (1 cell: the brute force;
    # one vertex per cell: every cell is a point)
    for n_samples in (1, 7, 300, e1.n_vertices):
        p2p = local_p2p_from_fmap(C, e1, e2, n_samples=n_samples)
        assert np.mean(p2p == exact) >= 0.999, n_samples


def test_exact_for_poor_and_rectangular_maps(blob_pair):
    # A random orthogonal map: no locality for the bounds to use, the answer is still exact.
    e1, e2, _ = blob_pair
    q = np.linalg.qr(np.random.default_rng(3).standard_normal((20, 20)))[0]
    C = np.zeros((21, 21))
    C[0, 0] = math.sqrt(e2.area / e1.area)
    C[1:, 1:] = q * math.sqrt(e2.area / e1.area)
    assert np.mean(local_p2p_from_fmap(C, e1, e2) == _exact(C, e1, e2)) >= 0.999
    # fewer target rows than source columns
    C = fmap_from_p2p(np.arange(e1.n_vertices), e1, e2, k1=30, k2=20)
    assert np.mean(local_p2p_from_fmap(C, e1, e2) == _exact(C, e1, e2)) >= 0.999


@pytest.mark.parametrize(
    ("scale", "shift", "seed"),
    [(1e-3, (0.0, 0.0, 0.0), None), (1e3, (0.0, 0.0, 0.0), None), (1.0, (5.0, -2.0, 40.0), 1)],
)
def test_invariant_to_units_pose_of_either_shape(blob_pair, blob_reference, scale, shift, seed):
    e1, e2, C = blob_pair
    rot = np.eye(3) if seed is None else _rotation(seed)
    # fmap_from_p2p scales with √area2 / √area1
    moved_2 = local_p2p_from_fmap(C * scale, e1, _moved(e2, scale, rot, shift))
    assert np.mean(moved_2 == blob_reference) >= 0.999
    moved_1 = local_p2p_from_fmap(C / scale, _moved(e1, scale, rot, shift), e2)
    assert np.mean(moved_1 == blob_reference) >= 0.999


def test_invariant_to_a_recomputed_moved_target(blob_mesh, blob_pair, blob_reference):
    # The eigenbasis recomputed on a rotated, shrunk and shifted target (round-off differs).
    V, F = blob_mesh
    e1, _, C = blob_pair
    scale = 1e-3
    V2 = scale * (_twisted(V) * 1.7) @ _rotation(2).T + np.array([3.0, 1.0, -7.0])
    p2p = local_p2p_from_fmap(C * scale, e1, eigenbasis(V2, F, k=49))
    assert np.mean(p2p == blob_reference) >= 0.995


def test_target_vertex_order(blob_pair, blob_reference):
    e1, e2, C = blob_pair
    perm = np.random.default_rng(5).permutation(e2.n_vertices)
    inverse = np.argsort(perm)
    permuted = EigenBasis(
        evals=e2.evals.copy(),
        evecs=e2.evecs[perm],
        mass=e2.mass[perm],
        stiffness=e2.stiffness[perm][:, perm].tocsr(),
        vertices=e2.vertices[perm],
        faces=inverse[e2.faces],
    )
    assert np.array_equal(local_p2p_from_fmap(C, e1, permuted), blob_reference[perm])


def test_bad_inputs_name_the_argument(blob_pair):
    e1, e2, C = blob_pair
    for bad in (C[0], C[None], np.zeros((e2.k + 2, 10)), np.zeros((10, e1.k + 2)), C[:0]):
        with pytest.raises(ValueError, match="fmap_12"):
            local_p2p_from_fmap(bad, e1, e2)
    nan = C.copy()
    nan[3, 4] = np.nan
    with pytest.raises(ValueError, match="fmap_12"):
        local_p2p_from_fmap(nan, e1, e2)
    with pytest.raises(TypeError, match="eig_1"):
        local_p2p_from_fmap(C, e1.evecs, e2)
    with pytest.raises(TypeError, match="eig_2"):
        local_p2p_from_fmap(C, e1, None)
    with pytest.raises(ValueError, match="n_samples"):
        local_p2p_from_fmap(C, e1, e2, n_samples=0)
    with pytest.raises(TypeError, match="n_samples"):
        local_p2p_from_fmap(C, e1, e2, n_samples=2.5)


def test_queries_split_in_halves_give_the_same_answers(blob_pair, blob_reference, monkeypatch):
    # Above SPLIT_QUERIES target vertices the search runs two halves of the target side by
    # side (forked processes where they can be made): every answer must stay the same.
    e1, e2, C = blob_pair
    jobs = []

    def spy(work, **options):
        jobs.append(len(work))
        return real(work, **options)

    real = multiscale.side_by_side
    monkeypatch.setattr(multiscale, "side_by_side", spy)
    monkeypatch.setattr(multiscale, "processes_available", lambda: 2)
    monkeypatch.setattr(multiscale, "SPLIT_QUERIES", e2.n_vertices - 1)
    assert np.array_equal(local_p2p_from_fmap(C, e1, e2), blob_reference)
    assert jobs == [2]
    monkeypatch.setattr(multiscale, "SPLIT_QUERIES", e2.n_vertices)
    assert np.array_equal(local_p2p_from_fmap(C, e1, e2), blob_reference)
    assert jobs == [2]  # not split at the bound itself


def _error(p2p, V1, area1, rows=None):
    # same triangulation: the true match of target vertex i is source vertex i
    rows = np.arange(V1.shape[0]) if rows is None else rows
    return float(np.linalg.norm(V1[p2p] - V1[rows], axis=1).mean() / math.sqrt(area1))


def test_faust_100x100_map_matches_the_exact_search():
    V1, F1 = load_shared_mesh("faust/tr_reg_093.ply")
    V2, F2 = load_shared_mesh("faust/tr_reg_087.ply")
    e1, e2 = eigenbasis(V1, F1, k=99), eigenbasis(V2, F2, k=99)
    C = fmap_from_p2p(np.arange(V1.shape[0]), e1, e2)
    local = local_p2p_from_fmap(C, e1, e2)
    # the brute force on 2000 target vertices (all of them: 4 s more)
    rows = np.sort(np.random.default_rng(1).choice(V2.shape[0], 2000, replace=False))
    u1, u2 = unit_area(e1), unit_area(e2)
    X = u1.evecs @ (C * math.sqrt(e1.area / e2.area)).T
    exact = nearest_neighbors(X, u2.evecs[rows])
    assert np.mean(local[rows] == exact) >= 0.99
    assert _error(local[rows], V1, e1.area, rows) <= 1.02 * _error(exact, V1, e1.area, rows)


@pytest.mark.slow
def test_subdivided_faust_matches_the_exact_search():
    # 27.5k and 110k vertices (midpoint subdivisions: the identity is still the truth); the
    # brute force on 5000 random target vertices (on all of them: 1 and 10 minutes).
    o3d = pytest.importorskip("open3d")
    from .conftest import shared_path

    for level in (1, 2):
        meshes = [
            o3d.io.read_triangle_mesh(str(shared_path(f"faust/tr_reg_{i}.ply"))).subdivide_midpoint(
                level
            )
            for i in ("093", "087")
        ]
        (V1, F1), (V2, F2) = ((np.asarray(m.vertices), np.asarray(m.triangles)) for m in meshes)
        e1, e2 = eigenbasis(V1, F1, k=99), eigenbasis(V2, F2, k=99)
        C = fmap_from_p2p(np.arange(V1.shape[0]), e1, e2)
        local = local_p2p_from_fmap(C, e1, e2)
        u1, u2 = unit_area(e1), unit_area(e2)
        X = u1.evecs @ (C * math.sqrt(e1.area / e2.area)).T
        rows = np.sort(np.random.default_rng(0).choice(V2.shape[0], 5000, replace=False))
        exact = nearest_neighbors(X, u2.evecs[rows])
        assert np.mean(local[rows] == exact) >= 0.99, level
        err_local = _error(local[rows], V1, e1.area, rows)
        assert err_local <= 1.02 * _error(exact, V1, e1.area, rows), level


def test_adjoint_extension_is_the_read_off_of_a_fit(
    blob_mesh, blob_pair, blob_reference, coarse_blob
):
    # extend_p2p(adjoint=True) compares the full source's interpolated rows of Φ with the full
    # target's rows of Ψ C, for a least-squares fit Ψ C ≈ Φ[π] with more target functions than
    # source ones: the brute-force read-off of the same interpolated embeddings (the slow
    # reference), and as precise as the usual extension.
    from o3d_ofp.core.multiscale import _interpolation

    V, _ = blob_mesh
    e1, e2, _ = blob_pair
    V2 = e2.vertices
    b1, _, b2, _, truth = coarse_blob
    fit = np.linalg.lstsq(b2.evecs[:, :30], b1.evecs[truth, :21], rcond=None)[0]  # (30, 21)
    p2p = extend_p2p(fit, b1, b2, V, V2, adjoint=True)
    assert p2p.shape == (V2.shape[0],) and p2p.dtype == np.int64
    phi = _interpolation(b1.vertices, V, 4) @ b1.evecs[:, :21]
    psi = _interpolation(b2.vertices, V2, 4) @ (b2.evecs[:, :30] @ fit)
    exact = nearest_neighbors(np.asarray(phi), np.asarray(psi))
    assert np.mean(p2p == exact) >= 0.999  # exact search; ties of round-off aside
    spacing = math.sqrt(e1.area / V.shape[0])
    err = np.linalg.norm(V[p2p] - V, axis=1).mean()
    err_full = np.linalg.norm(V[blob_reference] - V, axis=1).mean()
    assert err < max(2.0 * err_full, spacing)
    # read the usual way, the same fit is another map (the transpose is no inverse here)
    assert np.mean(extend_p2p(fit[:21, :21], b1, b2, V, V2) == p2p) < 0.999
    with pytest.raises(TypeError, match="adjoint"):
        extend_p2p(fit, b1, b2, V, V2, adjoint="yes")


def test_coarse_map_extends_to_the_full_shapes(blob_mesh, blob_pair, blob_reference, coarse_blob):
    # A map between 700-point farthest-point subsamples (point-cloud Laplacians), carried to
    # the full 2562-vertex shapes: about as accurate as the full-resolution map, and its
    # projection on small full-resolution bases close to the true one.
    V, _ = blob_mesh
    e1, e2, _ = blob_pair
    V2 = e2.vertices
    b1, s1, b2, _, truth = coarse_blob  # truth: the true coarse map, nearest source sample
    assert b1.n_vertices == 700 and b1.faces is None and s1.shape == (700,)
    C = fmap_from_p2p(truth, b1, b2)
    p2p = extend_p2p(C, b1, b2, V, V2)
    assert p2p.shape == (V.shape[0],) and p2p.dtype == np.int64
    spacing = math.sqrt(e1.area / V.shape[0])
    err = np.linalg.norm(V[p2p] - V, axis=1).mean()
    err_full = np.linalg.norm(V[blob_reference] - V, axis=1).mean()
    assert err < max(2.0 * err_full, spacing)
    small_1, small_2 = e1.truncate(15), e2.truncate(15)
    C_small, p2p_2 = extend_fmap(C, b1, b2, small_1, small_2)
    assert C_small.shape == (16, 16)
    assert np.array_equal(p2p_2, p2p)
    true_small = fmap_from_p2p(np.arange(V.shape[0]), small_1, small_2)
    assert np.linalg.norm(C_small - true_small) < 0.15 * np.linalg.norm(true_small)
    with pytest.raises(ValueError, match="fmap_coarse"):
        extend_p2p(np.zeros((31, 40)), b1, b2, V, V2)
    with pytest.raises(ValueError, match="vertices_2"):
        extend_p2p(C, b1, b2, V, V2[:, :2])
    with pytest.raises(TypeError, match="coarse_1"):
        extend_p2p(C, None, b2, V, V2)
    with pytest.raises(ValueError, match="count"):
        coarse_eigenbasis(V, 10, k=29)


def test_images_steer_the_extension_within_a_coarse_cell(blob_mesh, blob_pair, coarse_blob):
    """Where the coarse point map sends the target decides between a cell's source vertices.

    The interpolated coarse eigenfunctions barely tell apart the full vertices of one coarse
    cell; given where each target vertex should go (here the true positions, the source
    shape's units), the extension follows them, whatever either shape's units.
    """
    V, _ = blob_mesh
    _, e2, _ = blob_pair
    V2 = e2.vertices
    b1, _, b2, _, truth = coarse_blob
    C = fmap_from_p2p(truth, b1, b2)

    def err(p2p):
        return np.linalg.norm(V[p2p] - V, axis=1).mean()

    spectral = extend_p2p(C, b1, b2, V, V2)
    steered = extend_p2p(C, b1, b2, V, V2, images=V)
    # measured: 0.0098 against 0.067 (the true map is the identity), 86 % of the vertices
    # exactly right against 27 % (the spectral rows still weigh in, as they should: they
    # tell touching parts apart)
    assert err(steered) < 0.25 * err(spectral)
    assert np.mean(steered == np.arange(V.shape[0])) > 0.75
    # units: a target in other units changes nothing (the images are in the source's)
    moved_2 = _moved(b2, 3.0, _rotation(1), [1.0, 2.0, 3.0])
    C_moved = fmap_from_p2p(truth, b1, moved_2)  # the same map between the moved bases
    V2_moved = 3.0 * V2 @ _rotation(1).T + [1.0, 2.0, 3.0]
    again = extend_p2p(C_moved, b1, moved_2, V, V2_moved, images=V)
    assert np.mean(again == steered) > 0.99
    with pytest.raises(ValueError, match="images"):
        extend_p2p(C, b1, b2, V, V2, images=V[:-1])
    with pytest.raises(ValueError, match="images"):
        extend_p2p(C, b1, b2, V, V2, images=V, adjoint=True)


# --- moving values between a mesh and its coarse copy ---------------------------------------


def _folded_strip(r: float = 0.004) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Make a strip 2.1 long and 0.3 wide folded in two around a half circle of radius r.

    The two arms lie 2r apart in space, much closer than the coarse copy's spacing, and 1.0
    apart on the surface at the tips. Returns vertices, faces and each vertex's arc length s
    along the strip (arm one: s < 1; the fold; arm two: s > 1 + πr).
    """
    fold = math.pi * r
    s = np.linspace(0.0, 2.0 + fold, 421)
    w = np.linspace(0.0, 0.3, 31)
    S, W = np.meshgrid(s, w, indexing="ij")
    S, W = S.ravel(), W.ravel()
    theta = np.clip((S - 1.0) / r, 0.0, math.pi)
    x = np.where(
        S < 1.0, S, np.where(S > 1.0 + fold, 1.0 - (S - 1.0 - fold), 1.0 + r * np.sin(theta))
    )
    z = np.where(S < 1.0, -r, np.where(S > 1.0 + fold, r, -r * np.cos(theta)))
    V = np.stack([x, W, z], axis=1)
    i, j = np.meshgrid(np.arange(len(s) - 1), np.arange(len(w) - 1), indexing="ij")
    a = (i * len(w) + j).ravel()
    F = np.concatenate(
        [np.stack([a, a + len(w), a + 1], 1), np.stack([a + 1, a + len(w), a + len(w) + 1], 1)]
    )
    return V, F, S


@pytest.fixture(scope="module")
def folded():
    V, F, S = _folded_strip()
    Vc, Fc, samples, cell = coarse_mesh(V, F, 700)
    return V, F, S, Vc, Fc, samples, cell


def test_surface_prolongation_reads_its_own_side_of_a_fold(folded):
    V, _, S, Vc, Fc, samples, cell = folded
    P = surface_prolongation(Vc, Fc, cell, V)
    assert P.shape == (len(V), len(Vc))
    assert P.data.min() >= 0.0
    np.testing.assert_allclose(np.asarray(P.sum(axis=1)).ravel(), 1.0, atol=1e-12)
    np.testing.assert_allclose(P[samples].toarray(), np.eye(len(Vc)), atol=1e-12)  # exact there
    arm = np.where(S < 1.0, 0, np.where(S > 1.0 + math.pi * 0.004, 1, -1))
    away = np.flatnonzero(np.abs(S - (1.0 + math.pi * 0.002)) > 0.1)  # away from the fold
    # every weight comes from a coarse vertex on the vertex's own arm ...
    rows = np.repeat(np.arange(len(V)), np.diff(P.indptr))
    live = P.data > 0
    crossing = arm[samples[P.indices[live]]] != arm[rows[live]]
    assert not np.any(crossing & np.isin(rows[live], away))
    # ... where the nearest coarse points in space cross to the other arm (the test's teeth)
    E = _interpolation(Vc, V, 4)
    rows_e = np.repeat(np.arange(len(V)), np.diff(E.indptr))
    crossing_e = arm[samples[E.indices]] != arm[rows_e]
    assert np.count_nonzero(crossing_e & np.isin(rows_e, away) & (E.data > 0.05)) > 1000
    # A smooth function of the arc length comes back: measured 1.3 % off (relative L2; most
    # of it at the strip's open ends, beyond the coarse triangles: the median vertex is off
    # by 0.1 % of the range) through the surface, 113 % through the nearest points in space.
    f = np.sin(2.0 * math.pi * S / S.max())
    back = P @ f[samples]
    assert np.linalg.norm(back - f) / np.linalg.norm(f) < 0.03
    assert np.linalg.norm(E @ f[samples] - f) / np.linalg.norm(f) > 0.3


def test_cell_restriction_is_the_weighted_mean_of_each_cell(folded):
    V, _, _, Vc, _, _, cell = folded
    rng = np.random.default_rng(0)
    weights = rng.random(len(V))
    values = rng.standard_normal((len(V), 2))
    R = cell_restriction(cell, weights, len(Vc))
    got = R @ values
    for c in rng.choice(len(Vc), 20, replace=False):  # the obvious loop, on some cells
        members = cell == c
        expected = (weights[members, None] * values[members]).sum(0) / weights[members].sum()
        np.testing.assert_allclose(got[c], expected, rtol=1e-12)
    np.testing.assert_allclose(R @ np.ones(len(V)), 1.0, rtol=1e-12)  # constants kept
    empty = cell_restriction(np.array([0, 0, 2]), np.array([1.0, 1.0, 0.0]), 4)
    np.testing.assert_array_equal(empty @ np.array([1.0, 3.0, 5.0]), [2.0, 0.0, 0.0, 0.0])
