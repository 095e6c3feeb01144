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


@pytest.mark.parametrize("mode", ["add", "replace"])
def test_detail_transfer_donut(donuts, mode):
    (V1, F1), (V2, F2), p2p = donuts
    source = adapters.triangle_mesh_from_arrays(V1, F1)
    target = adapters.triangle_mesh_from_arrays(V2, F2)
    before = np.asarray(target.vertices).copy()
    out = ofp.transfer_detail(source, target, mode=mode, p2p_21=p2p)
    np.testing.assert_array_equal(np.asarray(target.vertices), before)  # input untouched
    X = np.asarray(out.vertices)
    assert X.shape == V2.shape and np.asarray(out.triangles).shape == F2.shape
    # measured ∫|ΔX|²: smooth target 95, add 510, replace 6944 (source 9408)
    assert willmore(X, F2) > 4 * willmore(V2, F2)
    if mode == "add":  # the target keeps its shape: only small, detail-sized displacements
        assert np.abs(X - V2).max() < 0.05 * np.ptp(V2, axis=0).max()


def test_detail_transfer_to_point_cloud(donuts):
    (V1, F1), (V2, _), p2p = donuts
    source = adapters.triangle_mesh_from_arrays(V1, F1)
    cloud = adapters.point_cloud_from_arrays(V2)
    out = ofp.transfer_detail(source, cloud, mode="add", p2p_21=p2p, k2=29)
    assert isinstance(out, o3d.geometry.PointCloud) and len(out.points) == len(V2)
    moved = np.linalg.norm(np.asarray(out.points) - V2, axis=1)
    assert 0 < moved.max() < 0.05


def test_transfer_colors_open3d_level():
    V1, F1 = load_shared_mesh("faust/tr_reg_093.ply")
    V2, F2 = load_shared_mesh("faust/tr_reg_087.ply")
    colors = 0.5 + 0.5 * np.sin(6 * V1)
    source = adapters.triangle_mesh_from_arrays(V1, F1, colors=colors)
    target = adapters.triangle_mesh_from_arrays(V2, F2)
    out = ofp.transfer_colors(source, target, p2p_21=np.arange(len(V2)))
    assert isinstance(out, o3d.geometry.TriangleMesh) and not target.has_vertex_colors()
    got = np.asarray(out.vertex_colors)
    m = ofp.laplacian(V2, F2)[1]
    assert ofp.approximation_error(colors, got, m) < 0.05
    # a given functional map larger than the bases (60 × 60 > (k2+1, k1+1)) is used whole
    e1, e2 = ofp.eigenbasis(V1, F1, k=59), ofp.eigenbasis(V2, F2, k=59)
    C = ofp.fmap_from_p2p(np.arange(len(V2)), e1, e2)
    via_fmap = np.asarray(ofp.transfer_colors(source, target, fmap_12=C).vertex_colors)
    assert ofp.approximation_error(colors, via_fmap, m) < 0.1
    assert isinstance(via_fmap := ofp.transfer_colors(source, target, fmap_12=C), type(target))
    assert len(via_fmap.vertices) == len(V2)
    with pytest.raises(ValueError, match="source has no vertex colors"):
        ofp.transfer_colors(target, source, p2p_21=np.arange(len(V1)))
