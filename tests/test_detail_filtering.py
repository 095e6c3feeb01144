import numpy as np
import pytest

import o3d_ofp as ofp
from o3d_ofp.core.filtering import edit_coefficient, sharpen_gains, smooth_gains, spectral_filter

from .conftest import load_shared_mesh

o3d = pytest.importorskip("open3d", reason="Open3D-level functions")
from o3d_ofp.boundary import convert as adapters  # noqa: E402


def willmore(V, F):
    """∫|ΔX|² (scale-invariant): grows with geometric detail."""
    L, m = ofp.laplacian(V, F)
    LX = L @ V
    return float(np.sum(LX**2 / m[:, None]))


def test_filtering_identity_smooth_sharpen(blob_mesh):
    V, F = blob_mesh
    B = ofp.ofp_basis(ofp.eigenbasis(V, F, k=14), order=3, preset="ours*")
    np.testing.assert_allclose(spectral_filter(B, V, np.ones(B.size)), V, atol=1e-12)
    smooth = spectral_filter(B, V, smooth_gains(8.0))
    sharp = spectral_filter(B, V, sharpen_gains(2.0))
    assert willmore(smooth, F) < willmore(V, F) < willmore(sharp, F)
    in_span = spectral_filter(B, V, np.ones(B.size), keep_residual=False)
    np.testing.assert_allclose(in_span, B.approximate(V), atol=1e-12)
    edited = edit_coefficient(B, V, 5, [0.0, 0.0, 0.1])
    diff = B.project(edited) - B.project(V)
    assert np.count_nonzero(np.abs(diff) > 1e-12) == 1 and diff[
        B.energy_order[5], 2
    ] == pytest.approx(0.1)
    with pytest.raises(ValueError, match="gains must have shape"):
        spectral_filter(B, V, np.ones(3))
    with pytest.raises(ValueError, match="strength must be >= 0"):
        smooth_gains(-1)


@pytest.fixture(scope="module")
def donuts():
    V1, F1 = load_shared_mesh("models/t1_donut.obj")
    V2, F2 = load_shared_mesh("models/t0_donut.obj")
    # the two are spatially aligned with unit area: the ground truth is the nearest point
    return (V1, F1), (V2, F2), ofp.nearest_neighbors(V1, V2)


@pytest.mark.parametrize("mode", ["add", "coordinates"])
def test_detail_transfer_donut(donuts, mode):
    """The paper's Fig. 13 pair with its closest-point map.

    The smooth torus is no low-pass of the bumpy one (it is larger, the bumps sit inside it):
    the calibration finds nothing it lacks, says so and advises mode "coordinates", which
    moves it onto the source's surface; a band adds the detail above it everywhere.
    """
    (V1, F1), (V2, F2), p2p = donuts
    source = adapters.triangle_mesh_from_arrays(V1, F1)
    target = adapters.triangle_mesh_from_arrays(V2, F2)
    before = np.asarray(target.vertices).copy()
    corr = ofp.Correspondence.from_p2p(p2p, source, target)
    if mode == "add":
        lacks = r"no detail the target lacks was found.*'coordinates'"
        with pytest.warns(ofp.OFPWarning, match=lacks):
            out = ofp.transfer_detail(source, target, mode=mode, correspondence=corr)
        np.testing.assert_allclose(np.asarray(out.vertices), V2, atol=1e-12)
        out = ofp.transfer_detail(source, target, mode=mode, correspondence=corr, band=30)
    else:
        out = ofp.transfer_detail(source, target, mode=mode, correspondence=corr)
    np.testing.assert_array_equal(np.asarray(target.vertices), before)  # input untouched
    X = np.asarray(out.vertices)
    assert X.shape == V2.shape and np.asarray(out.triangles).shape == F2.shape
    # measured ∫|ΔX|²: smooth target 95, add with band 30: 3129, coordinates 6944 (source
    # 9408); add moves vertices by at most 0.037 of the extent
    assert willmore(X, F2) > 4 * willmore(V2, F2)
    if mode == "add":  # the target keeps its shape: only small, detail-sized displacements
        assert np.abs(X - V2).max() < 0.05 * np.ptp(V2, axis=0).max()


def test_detail_transfer_to_point_cloud(donuts):
    (V1, F1), (V2, _), p2p = donuts
    source = adapters.triangle_mesh_from_arrays(V1, F1)
    cloud = adapters.point_cloud_from_arrays(V2)
    corr = ofp.Correspondence.from_p2p(p2p, source, cloud)
    # mode "add" builds no OFP basis: its sizes (k2=29 here before) are refused, not ignored
    with pytest.raises(ValueError, match=r"options .* does not apply: mode 'add'") as info:
        ofp.transfer_detail(source, cloud, mode="add", correspondence=corr,
                            options=ofp.BasisOptions(k2=29))  # fmt: skip
    assert info.value.option == "options"
    out = ofp.transfer_detail(source, cloud, mode="add", correspondence=corr, band=30)
    assert isinstance(out, o3d.geometry.PointCloud) and len(out.points) == len(V2)
    moved = np.linalg.norm(np.asarray(out.points) - V2, axis=1)
    assert 0 < moved.max() < 0.05


def test_transfer_colors_open3d_level():
    V1, F1 = load_shared_mesh("faust/tr_reg_093.ply")
    V2, F2 = load_shared_mesh("faust/tr_reg_087.ply")
    colors = 0.5 + 0.5 * np.sin(6 * V1)
    source = adapters.triangle_mesh_from_arrays(V1, F1, colors=colors)
    target = adapters.triangle_mesh_from_arrays(V2, F2)
    identity = ofp.Correspondence.from_p2p(np.arange(len(V2)), source, target)
    out = ofp.transfer_colors(source, target, correspondence=identity)
    assert isinstance(out, o3d.geometry.TriangleMesh) and not target.has_vertex_colors()
    got = np.asarray(out.vertex_colors)
    m = ofp.laplacian(V2, F2)[1]
    assert ofp.approximation_error(colors, got, m) < 0.05
    # a given functional map larger than the bases (60 × 60 > (k2+1, k1+1)) is used whole
    e1, e2 = ofp.eigenbasis(V1, F1, k=59), ofp.eigenbasis(V2, F2, k=59)
    C = ofp.fmap_from_p2p(np.arange(len(V2)), e1, e2)
    fmap = ofp.Correspondence.from_fmap(C, e1, e2)
    via_fmap = ofp.transfer_colors(source, target, correspondence=fmap)
    assert isinstance(via_fmap, type(target)) and len(via_fmap.vertices) == len(V2)
    assert ofp.approximation_error(colors, np.asarray(via_fmap.vertex_colors), m) < 0.1
    with pytest.raises(ValueError, match="source has neither vertex colors nor a texture"):
        ofp.transfer_colors(
            target, source, correspondence=ofp.Correspondence.from_p2p(
                np.arange(len(V1)), target, source
            ),
        )  # fmt: skip


# --- smoothing that is a low-pass (issue 13) -------------------------------------------------


def _volume(V, F):
    return float(np.einsum("ij,ij->i", V[F[:, 0]], np.cross(V[F[:, 1]], V[F[:, 2]])).sum() / 6)


@pytest.fixture(scope="module")
def noisy_sphere():
    from o3d_ofp.core.shapes import icosphere

    V, F = icosphere(5)  # 10242 vertices, unit sphere
    diag = 2 * np.sqrt(3)
    noisy = V + np.random.default_rng(0).normal(0, 0.005 * diag, len(V))[:, None] * V
    return V, F, noisy, ofp.eigenbasis(noisy, F, k=14)


def _sphere_distance(X):
    return float(np.abs(np.linalg.norm(X, axis=1) - 1).mean())


def test_smooth_coordinates_denoises_without_shrinking(noisy_sphere):
    from o3d_ofp.core.filtering import DEFAULT_SMOOTH, smooth_coordinates

    V, F, noisy, eig = noisy_sphere
    d_noisy = _sphere_distance(noisy)
    X = smooth_coordinates(eig, noisy)  # default smooth = 0.01
    assert DEFAULT_SMOOTH == 0.01
    assert _sphere_distance(X) < 0.4 * d_noisy  # measured 0.30
    assert _volume(X, F) == pytest.approx(_volume(V, F), rel=0.02)
    B = ofp.ofp_basis(eig, order=3, preset="ours*")
    stronger = smooth_coordinates(B, noisy, smooth=0.02)
    assert _sphere_distance(stronger) < 0.2 * d_noisy  # an OFPBasis works as well (0.14)
    # the OFP-basis filter keeps everything above the basis' span, noise included
    assert _sphere_distance(spectral_filter(B, noisy, smooth_gains(5.0))) > 0.9 * d_noisy


def test_smoothing_means_the_same_at_every_scale_and_resolution():
    from numpy.polynomial import legendre

    from o3d_ofp.core.filtering import smooth_coordinates
    from o3d_ofp.core.shapes import icosphere

    gains = []
    for sub in (4, 5):  # 2562 and 10242 vertices
        V, F = icosphere(sub)
        h = 0.05 * legendre.legval(V[:, 2], [0] * 8 + [1])  # a degree-8 bump, λ = 72
        X = (1 + h)[:, None] * V
        for s in (1e-3, 1e3):
            eig = ofp.eigenbasis(s * X, F, k=5)
            Y = smooth_coordinates(eig, s * X, smooth=0.04, keep_volume=False) / s
            gains.append(np.polyfit(h, np.linalg.norm(Y, axis=1), 1)[0])
    # The coordinates h·n hold degrees 7 and 9 (λ = 56, 90): Butterworth gains
    # 1 / (1 + (t λ)⁴), t = 0.04² · 4π, of 0.38 and 0.09; measured with the umbrella weights
    # 0.244 (2562 vertices) and 0.233 (10242), the same at both scales (cotangent: 0.251, 0.239).
    np.testing.assert_allclose(gains, 0.24, atol=0.015)
    assert np.ptp(gains) < 0.02


def test_smoothing_a_split_mesh_is_smoothing_the_welded_one():
    """Split vertices (UV seams, a triangle soup) are smoothed as the welded mesh.

    The umbrella weights count neighbours: each copy of a welded vertex weighs one share of
    it (a review found a soup's result 0.025 of the extent off with a weight of 1 each).
    """
    from o3d_ofp.core.filtering import smooth_coordinates
    from o3d_ofp.core.shapes import icosphere

    V, F = icosphere(3)
    rng = np.random.default_rng(1)
    X = V + 0.02 * rng.standard_normal(V.shape)
    welded = smooth_coordinates(ofp.eigenbasis(X, F, k=3), X, smooth=0.05)
    soup_V, soup_F = X[F.ravel()], np.arange(F.size).reshape(-1, 3)  # every corner its own
    soup = smooth_coordinates(ofp.eigenbasis(soup_V, soup_F, k=3), soup_V, smooth=0.05)
    # the same up to the solver's round-off (cotangent weights: 3e-16)
    np.testing.assert_allclose(soup, welded[F.ravel()], atol=1e-10 * np.ptp(X))


def test_sharpen_and_refused_strengths(blob_mesh):
    from o3d_ofp.core.filtering import MAX_SHARPEN, sharpen_coordinates, smooth_coordinates

    V, F = blob_mesh
    eig = ofp.eigenbasis(V, F, k=5)
    sharp = sharpen_coordinates(eig, V, sharpen=1.0, smooth=0.1)  # the blob is smooth
    assert willmore(sharp, F) > 1.1 * willmore(V, F)  # measured 1.11
    assert _volume(sharp, F) == pytest.approx(_volume(V, F), rel=1e-9)
    np.testing.assert_allclose(sharpen_coordinates(eig, V, sharpen=0.0), V)
    assert MAX_SHARPEN == 2.0
    for bad in (-0.5, 2.5, float("nan")):
        with pytest.raises(ValueError, match="sharpen"):
            sharpen_coordinates(eig, V, sharpen=bad)
    for bad in (-0.01, 0.3, float("inf")):
        with pytest.raises(ValueError, match="smooth"):
            smooth_coordinates(eig, V, smooth=bad)
    with pytest.raises(TypeError, match="B must be"):
        smooth_coordinates(V, V)


def test_smooth_point_cloud_keeps_its_spread(noisy_sphere):
    from o3d_ofp.core.filtering import smooth_coordinates

    _, _, noisy, _ = noisy_sphere
    sub = noisy[::4]
    eig = ofp.eigenbasis(sub, None, k=5)
    X = smooth_coordinates(eig, sub, smooth=0.02)
    assert _sphere_distance(X) < 0.6 * _sphere_distance(sub)
    w = eig.mass / eig.area
    rms = lambda P: np.sqrt(w @ ((P - w @ P) ** 2).sum(1))  # noqa: E731
    assert rms(X) == pytest.approx(rms(sub), rel=1e-9)


def test_vertices_left_out_of_the_surface_are_not_filtered():
    """A dropped component and an unreferenced vertex keep their input values, in every filter.

    They used to take the filtered value of their stand-in (the nearest kept vertex): the
    dropped parts of a mesh filtered with components="largest" collapsed onto the body.
    """
    from o3d_ofp.core.filtering import lowpass, sharpen_coordinates, smooth_coordinates
    from o3d_ofp.core.shapes import icosphere

    V, F = icosphere(3)
    rng = np.random.default_rng(0)
    V = V * (1.0 + 0.02 * rng.standard_normal((len(V), 1)))  # something to smooth
    small = 0.3 * V[:42] + [3.0, 0.0, 0.0]  # a second, smaller piece (an icosphere(1))
    _, F_small = icosphere(1)
    V2 = np.concatenate([V, small, [[5.0, 5.0, 5.0]]])  # and one unreferenced vertex
    F2 = np.concatenate([F, F_small + len(V)])
    outside = np.arange(len(V), len(V2))
    eig = ofp.eigenbasis(V2, F2, k=12, components="largest")
    assert np.all(eig.mass[outside] == 0)
    B = ofp.ofp_basis(eig, order=2)
    colors = 0.5 + 0.3 * np.sin(4 * V2)
    results = {
        "lowpass": (lowpass(eig, colors, smooth=0.05), colors),
        "smooth": (smooth_coordinates(eig, V2, smooth=0.05), V2),
        "sharpen": (sharpen_coordinates(eig, V2, sharpen=1.0, smooth=0.05), V2),
        "spectral": (spectral_filter(B, V2, smooth_gains()), V2),
        "in span": (spectral_filter(B, colors, smooth_gains(), keep_residual=False), colors),
        "edit": (edit_coefficient(B, V2, 3, [0.1, 0.0, 0.0]), V2),
    }
    for name, (out, x) in results.items():
        np.testing.assert_array_equal(out[outside], x[outside], err_msg=name)
        assert np.abs(out[: len(V)] - x[: len(V)]).max() > 1e-3, name  # the surface is filtered
    # Through the Open3D front end (what the CLI's filter runs).
    mesh = adapters.triangle_mesh_from_arrays(V2, F2)
    out = ofp.filter_geometry(mesh, smooth=0.05)  # "auto": the small piece is left out
    np.testing.assert_array_equal(np.asarray(out.vertices)[outside], V2[outside])


def test_the_sparse_factorizations_run_with_one_blas_thread(monkeypatch):
    """SuperLU's supernodal updates call the BLAS, whose threads only spin on these solves.

    Measured (50k-vertex raw bunny scan, smooth=0.01, another process multiplying matrices
    on both cores): 5.2 s with the BLAS threads, 3.8 s with one (2.3 s on a quiet machine).
    """
    threadpoolctl = pytest.importorskip("threadpoolctl")
    import scipy.sparse.linalg as sla

    from o3d_ofp.core import filtering
    from o3d_ofp.core.shapes import icosphere
    from o3d_ofp.workflows import detail

    seen = []

    def blas_threads():
        info = threadpoolctl.threadpool_info()
        return [i["num_threads"] for i in info if i["user_api"] == "blas"]

    def recording(real):
        def call(*args, **kwargs):
            seen.append(blas_threads())
            return real(*args, **kwargs)

        return call

    monkeypatch.setattr(filtering.sla, "splu", recording(sla.splu))
    monkeypatch.setattr(detail, "factorize_spd", recording(detail.factorize_spd))
    V, F = icosphere(3)
    eig = ofp.eigenbasis(V, F, k=5)
    filtering.lowpass(eig, V[:, 0], smooth=0.05)
    detail._heat_operator(eig, 3)
    # two filtering solves and the detail's factorization (SuperLU's own call inside it too
    # where cholespy is missing: the same module's splu)
    assert len(seen) >= 3 and all(t == [1] * len(t) for t in seen), seen


def test_edit_coefficient_refuses_a_non_finite_delta():
    from o3d_ofp.core.shapes import blob

    V, F = blob(2)
    B = ofp.ofp_basis(ofp.eigenbasis(V, F, k=6), order=2)
    for bad in (np.nan, np.inf, [0.0, np.nan, 1.0]):
        with pytest.raises(ValueError, match="delta must be finite"):
            edit_coefficient(B, V, 3, bad)


def test_strong_smoothing_keeps_the_extent_not_a_vanished_volume():
    """A low-pass that thins a part away is not blown up to the old volume, and says so.

    Found by a trial: ``filter --smooth 0.1`` made a 1.8 m human a 4.9 m spindle (the volume
    kept: 2.85 times its size). A thin torus (tube radius 0.4, 0.2 √area at smooth 0.1)
    collapses the same way; at smooth <= 0.05 its tube survives and the volume is kept.
    """
    import warnings

    from o3d_ofp.core.filtering import KEEP_SIZE_EXTENT, smooth_coordinates
    from o3d_ofp.core.shapes import torus

    V, F = torus(64, 16)
    eig = ofp.eigenbasis(V, F, k=10)
    with warnings.catch_warnings():
        warnings.simplefilter("error", ofp.OFPWarning)  # no warning while the volume is kept
        mild = smooth_coordinates(eig, V, smooth=0.02)
    assert _volume(mild, F) == pytest.approx(_volume(V, F), rel=1e-6)
    for smooth in (0.1, 0.25):
        with pytest.warns(ofp.OFPWarning, match="kept by its extent"):
            X = smooth_coordinates(eig, V, smooth=smooth)
        # at most KEEP_SIZE_EXTENT beyond the input's size (measured: 0.96 and 0.90 across)
        assert np.ptp(X, axis=0).max() <= KEEP_SIZE_EXTENT * np.ptp(V, axis=0).max()
        assert _volume(X, F) < 0.9 * _volume(V, F)  # not restored: the tube thinned away
