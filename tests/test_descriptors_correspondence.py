import numpy as np
import pytest

import o3d_ofp as ofp
from o3d_ofp.core import correspondence
from o3d_ofp.core.correspondence import fmap_from_p2p, nearest_neighbors, p2p_from_fmap
from o3d_ofp.core.descriptors import hks, wks


@pytest.fixture(scope="module")
def blob_eig(blob_mesh):
    return ofp.eigenbasis(*blob_mesh, k=20)


@pytest.mark.parametrize("fn", [hks, wks])
def test_descriptors_shape_scale_and_landmarks(fn, blob_mesh, blob_eig):
    D = fn(blob_eig, **({"n_times": 16} if fn is hks else {"n_energies": 16}))
    assert D.shape == (blob_eig.n_vertices, 16) and np.all(np.isfinite(D)) and np.all(D >= 0)
    V, F = blob_mesh
    scaled = ofp.eigenbasis(V * 10.0, F, k=20)
    D10 = fn(scaled, **({"n_times": 16} if fn is hks else {"n_energies": 16}))
    # times/energies follow the eigenvalues, φ² scales as 1/s²: D · s² is scale-invariant
    np.testing.assert_allclose(D10 * 100.0, D, rtol=1e-6, atol=1e-12 * D.max())
    lm = np.array([3, 500])
    K = fn(blob_eig, landmarks=lm, **({"n_times": 16} if fn is hks else {"n_energies": 16}))
    assert K.shape == (blob_eig.n_vertices, 32)
    # the kernel map of a landmark evaluated at the landmark is the signature there
    np.testing.assert_allclose(K[3, :16], D[3], rtol=1e-10)
    np.testing.assert_allclose(K[500, 16:], D[500], rtol=1e-10)
    with pytest.raises(ValueError, match="landmarks must be vertex indices"):
        fn(blob_eig, landmarks=np.array([blob_eig.n_vertices]))


@pytest.mark.parametrize("dim", [3, 12, 40])
def test_nearest_neighbors_methods_agree_with_naive(dim, monkeypatch):
    rng = np.random.default_rng(dim)
    data, queries = rng.standard_normal((700, dim)), rng.standard_normal((300, dim))
    naive = np.argmin(((queries[:, None, :] - data[None]) ** 2).sum(-1), axis=1)
    for method in ("brute", "kdtree", "auto"):
        np.testing.assert_array_equal(nearest_neighbors(data, queries, method=method), naive)
    monkeypatch.setattr(correspondence, "_BRUTE_MAX_PAIRS", 10)  # force the timed choice
    np.testing.assert_array_equal(nearest_neighbors(data, queries), naive)
    with pytest.raises(ValueError, match="method must be one of"):
        nearest_neighbors(data, queries, method="faiss")
    with pytest.raises(ValueError, match=r"data and queries must be \(n, d\) and \(m, d\)"):
        nearest_neighbors(data, queries[:, :2])


def test_identity_maps_round_trip(blob_eig):
    n = blob_eig.n_vertices
    C = fmap_from_p2p(np.arange(n), blob_eig, blob_eig)
    np.testing.assert_allclose(C, np.eye(21), atol=1e-10)  # Φᵀ M Φ = I
    np.testing.assert_array_equal(p2p_from_fmap(C, blob_eig, blob_eig), np.arange(n))
    C_small = fmap_from_p2p(np.arange(n), blob_eig, blob_eig, k1=5, k2=8)
    assert C_small.shape == (9, 6)


def test_map_errors(blob_eig):
    n = blob_eig.n_vertices
    with pytest.raises(ValueError, match=r"p2p_21 values must be source vertex indices in \[0, "):
        fmap_from_p2p(np.full(n, n), blob_eig, blob_eig)
    with pytest.raises(ValueError, match="p2p_21 has 5 entries but the target has"):
        fmap_from_p2p(np.arange(5), blob_eig, blob_eig)
    with pytest.raises(TypeError, match="p2p_21 must be a 1-D integer array"):
        fmap_from_p2p(np.zeros(n), blob_eig, blob_eig)
    with pytest.raises(ValueError, match="the eigenbases allow at most"):
        p2p_from_fmap(np.eye(30), blob_eig, blob_eig)


def test_read_vts(tmp_path):
    from o3d_ofp.core.io import read_vts

    (tmp_path / "a.vts").write_text("3\n1\n2\n")
    np.testing.assert_array_equal(read_vts(tmp_path / "a.vts"), [2, 0, 1])
    (tmp_path / "b.vts").write_text("0\n1\n")
    with pytest.raises(ValueError, match="must be positive integers"):
        read_vts(tmp_path / "b.vts")
    (tmp_path / "c.vts").write_text("x\n")
    with pytest.raises(ValueError, match=r"not a \.vts file"):
        read_vts(tmp_path / "c.vts")
    with pytest.raises(FileNotFoundError, match="no such file"):
        read_vts(tmp_path / "missing.vts")


def test_hks_explicit_times(blob_eig):
    D = hks(blob_eig, times=[0.1, 1.0])
    assert D.shape == (blob_eig.n_vertices, 2)
    with pytest.raises(ValueError, match="times must be a non-empty list of positive"):
        hks(blob_eig, times=[-1.0])


def _naive_nn(data, queries):
    """Exact reference: float64 distances, first minimal index."""
    return np.array([np.argmin(((data - q) ** 2).sum(axis=1)) for q in queries])


@pytest.mark.parametrize("seed", range(6))
def test_brute_force_with_single_precision_screening_is_exact(seed):
    """Any scale, offset, dimension, duplicates and near-ties: the float64 answer, always."""
    rng = np.random.default_rng(seed)
    n, m, dim = rng.integers(1, 400), rng.integers(1, 300), rng.integers(1, 130)
    scale, offset = 10.0 ** rng.uniform(-6, 6), 10.0 ** rng.uniform(-3, 4)
    data = rng.standard_normal((n, dim)) * scale + offset
    if n > 2:
        data[1] = data[0]  # an exact tie
    near = data[rng.integers(0, n, m // 2)] + 1e-9 * scale * rng.standard_normal((m // 2, dim))
    queries = np.concatenate([near, rng.standard_normal((m - m // 2, dim)) * scale + offset])
    got = nearest_neighbors(data, queries, method="brute")
    ref = _naive_nn(data, queries)
    # Ties may pick either of two equidistant points: compare distances, which must be equal
    # to the last bit of the reference computation's rounding.
    d_got = ((data[got] - queries) ** 2).sum(axis=1)
    d_ref = ((data[ref] - queries) ** 2).sum(axis=1)
    np.testing.assert_allclose(d_got, d_ref, rtol=1e-12, atol=0)
    assert np.mean(got == ref) > 0.98  # only ties may differ


def test_brute_force_equals_double_precision_on_a_spectral_embedding(blob_eig):
    from o3d_ofp.core.correspondence import _brute64

    X = blob_eig.evecs  # (2562, 30): the kind of data ZoomOut and p2p maps search
    Y = X[::-1] + 1e-7 * np.random.default_rng(0).standard_normal(X.shape)
    d2 = np.einsum("ij,ij->i", X, X)
    np.testing.assert_array_equal(nearest_neighbors(X, Y, method="brute"), _brute64(X, Y, d2))


@pytest.fixture(scope="module")
def embedding_with_near_ties():
    """Random 30-D embedding, 300 of whose queries are near-ties float32 cannot separate."""
    from scipy.spatial.distance import cdist

    rng = np.random.default_rng(7)
    data, queries = rng.standard_normal((1500, 30)), rng.standard_normal((1000, 30))
    d = cdist(data[:300], data, "sqeuclidean")
    d[np.arange(300), np.arange(300)] = np.inf
    a, b = data[:300], data[np.argmin(d, axis=1)]
    # Midpoint of a point and its nearest other point, moved 1e-9 of their gap toward the
    # first: the two squared distances differ by 8e-9 relative (float32 resolves 6e-8).
    queries[:300] = 0.5 * (a + b) + 1e-9 * (a - b)
    ref = np.argmin(cdist(queries, data, "sqeuclidean"), axis=1)  # plain float64, scale 1
    np.testing.assert_array_equal(ref[:300], np.arange(300))
    return data, queries, ref


@pytest.mark.parametrize("method", ["brute", "kdtree"])
@pytest.mark.parametrize("scale", [1e-200, 1e-30, 1e-22, 1e-21, 10**18.5, 1e30, 1e200])
def test_nearest_neighbors_exact_at_extreme_scales(embedding_with_near_ties, scale, method):
    """Nearest neighbours are scale-invariant: any scale gives the float64 answer at scale 1.

    Before the inputs were scaled by a power of two, 1e-22 and 1e-21 (squared norms in
    float32's subnormal range, below the rounding bound's assumptions) and 10^18.5 (float32
    overflow) gave hundreds of wrong indices, 1e±200 (float64 underflow / overflow of squared
    norms) nearly all wrong, in the brute force and in the k-d tree.
    """
    data, queries, ref = embedding_with_near_ties
    got = nearest_neighbors(data * scale, queries * scale, method=method)
    np.testing.assert_array_equal(got, ref)


def test_nearest_neighbors_degenerate_inputs():
    rng = np.random.default_rng(11)
    queries = rng.standard_normal((7, 4))
    for data in (np.zeros((3, 4)), np.tile([[0.1, 0.2, 0.3, 1e200]], (5, 1))):
        # every data point is the same point: all are nearest, the first is returned
        np.testing.assert_array_equal(nearest_neighbors(data, queries, method="brute"), 0)
    np.testing.assert_array_equal(nearest_neighbors(np.zeros((3, 4)), 1e300 * queries), 0)
    # Queries 1e250 times farther out than the data's spread: the nearest point is the one
    # furthest along the query's direction (‖d‖² is negligible next to q·d). The brute force
    # (‖d‖² − 2 q·d) finds it; a k-d tree, which subtracts coordinates, cannot (q − d = q).
    data = rng.standard_normal((50, 4))
    far = 1e250 * queries
    got = nearest_neighbors(data, far, method="brute")
    np.testing.assert_array_equal(got, np.argmax(queries @ data.T, axis=1))
    # a near and a far query in the same block: the far one does not upset the near one
    mixed = np.concatenate([queries[:1], far[1:2]])
    np.testing.assert_array_equal(
        nearest_neighbors(data, mixed, method="brute"),
        [np.argmin(((data - queries[0]) ** 2).sum(axis=1)), np.argmax(data @ queries[1])],
    )
    assert nearest_neighbors(data, np.zeros((0, 4)), method="brute").shape == (0,)
    bad = data.copy()
    bad[3, 1] = np.nan
    for d, q in ((bad, queries), (data, np.full((2, 4), np.inf))):
        with pytest.raises(ValueError, match="must be finite"):
            nearest_neighbors(d, q)


def test_p2p_from_fmap_holds_when_the_target_is_scaled(blob_mesh):
    """fmap_from_p2p's convention (C = s·I for a copy scaled by s) round-trips at any scale."""
    V, F = blob_mesh
    e1 = ofp.eigenbasis(V, F, k=12)
    for s in (1e-3, 1.0, 1e3):
        e2 = ofp.eigenbasis(V * s, F, k=12)
        C = ofp.fmap_from_p2p(np.arange(len(V)), e1, e2)
        np.testing.assert_allclose(C, s * np.eye(13), atol=1e-6 * s)
        np.testing.assert_array_equal(ofp.p2p_from_fmap(C, e1, e2), np.arange(len(V)))


def test_template_fill_follows_the_target_surface_not_space():
    """A hairpin strip whose arms lie 0.3 apart: an open end takes its own arm's answer.

    Vertex pairs listed at the strip's start (arm 1) and at the bend's far side (arm 2). Arm 2's
    open end lies 0.3 from the start in space but 9 edges from it along the strip, and 9 from
    the bend: with the faces it takes the bend's answer (its own arm); without, the start's.
    """
    from o3d_ofp import p2p_from_template

    h = 10  # columns per arm; column j of 2h, two vertices across the strip (z = 0, 1)
    j = np.arange(2 * h)
    x = np.where(j < h, j, 2 * h - 1 - j).astype(float)
    y = np.where(j < h, 0.0, 0.3)
    V = np.array([[xi, yi, z] for xi, yi in zip(x, y, strict=True) for z in (0.0, 1.0)])
    F = np.array([f for c in range(2 * h - 1) for f in
                  ((2 * c, 2 * c + 2, 2 * c + 1), (2 * c + 1, 2 * c + 2, 2 * c + 3))])  # fmt: skip
    start, bend = [0, 1], [2 * h, 2 * h + 1]  # column 0 and column h (arm 2's first)
    listed_target = np.array(start + bend)
    answers = np.array([100, 101, 200, 201])  # source vertices of the four template points
    end = [2 * (2 * h - 1), 2 * (2 * h - 1) + 1]  # arm 2's open end, above the start
    in_space = p2p_from_template(answers, listed_target, V)
    along = p2p_from_template(answers, listed_target, V, faces_2=F)
    assert in_space[end].tolist() == [100, 101] and along[end].tolist() == [200, 201]
    # the listed vertices keep their own answers; a mesh in two pieces, one without a listed
    # vertex, fills that piece in space
    assert along[listed_target].tolist() == answers.tolist()
    apart = np.vstack([V, V[:4] + np.array([0.0, 5.0, 0.0])])
    both = np.vstack([F, [[len(V), len(V) + 2, len(V) + 1], [len(V) + 1, len(V) + 2, len(V) + 3]]])
    filled = p2p_from_template(answers, listed_target, apart, faces_2=both)
    np.testing.assert_array_equal(filled[len(V):], p2p_from_template(answers, listed_target,
                                                                       apart)[len(V):])  # fmt: skip
    with pytest.raises(ValueError, match="faces_2"):
        p2p_from_template(answers, listed_target, V, faces_2=F + len(V))


def test_a_target_vertex_listed_twice_keeps_its_first_row():
    """A target vertex on several template rows takes its first row's source vertex.

    Template files may list one target vertex on several rows (a coarse target): the first
    row's source vertex is its answer, in the dense map and in the pairs the fit check reads.
    """
    from o3d_ofp.core.correspondence import template_pairs

    target = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [2.0, 0.0, 0.0]])
    rows_1, rows_2 = np.array([7, 8, 9, 4]), np.array([2, 0, 2, 1])
    listed, images = template_pairs(rows_1, rows_2)
    assert listed.tolist() == [0, 1, 2] and images.tolist() == [8, 4, 7]
    assert ofp.p2p_from_template(rows_1, rows_2, target).tolist() == [8, 4, 7]
