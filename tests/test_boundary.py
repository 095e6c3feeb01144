import subprocess
import sys

import numpy as np
import pytest

import o3d_ofp as ofp
from o3d_ofp.boundary import convert as adapters
from o3d_ofp.core.shapes import icosphere

o3d = pytest.importorskip("open3d", reason="adapter tests need Open3D (pip install 'o3d_ofp[cpu]')")


@pytest.fixture
def legacy_mesh():
    V, F = icosphere(2)
    mesh = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(V), o3d.utility.Vector3iVector(F))
    mesh.vertex_colors = o3d.utility.Vector3dVector(np.full((len(V), 3), 0.25))
    return mesh


def test_import_does_not_import_open3d():
    code = "import sys, o3d_ofp; assert 'open3d' not in sys.modules, 'open3d imported'"
    subprocess.run([sys.executable, "-c", code], check=True)


def test_missing_open3d_gives_install_hint(monkeypatch):
    monkeypatch.setitem(sys.modules, "open3d", None)  # makes `import open3d` raise ImportError
    with pytest.raises(ImportError, match=r"pip install open3d-cpu"):
        adapters.triangle_mesh_from_arrays(*icosphere(1))


def test_legacy_mesh_to_arrays_is_a_copy(legacy_mesh):
    before = np.asarray(legacy_mesh.vertices).copy()
    V, F = adapters.geometry_to_arrays(legacy_mesh)
    assert V.dtype == np.float64 and F.dtype == np.int64 and F.shape == (320, 3)
    V[:] = 0.0
    F[:] = 0
    np.testing.assert_array_equal(np.asarray(legacy_mesh.vertices), before)
    colors = adapters.vertex_colors(legacy_mesh)
    colors[:] = 1.0
    np.testing.assert_array_equal(np.asarray(legacy_mesh.vertex_colors), 0.25)


def test_tensor_and_point_cloud_inputs(legacy_mesh):
    V, F = adapters.geometry_to_arrays(legacy_mesh)
    tmesh = o3d.t.geometry.TriangleMesh.from_legacy(legacy_mesh)
    V2, F2 = adapters.geometry_to_arrays(tmesh)
    assert V2.dtype == np.float64
    np.testing.assert_allclose(V2, V, atol=1e-7)  # from_legacy stores float32 by default
    np.testing.assert_array_equal(F2, F)
    np.testing.assert_allclose(adapters.vertex_colors(tmesh), 0.25, atol=1e-6)
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(V))
    P, none = adapters.geometry_to_arrays(cloud)
    assert none is None and np.array_equal(P, V)
    assert adapters.vertex_colors(cloud) is None
    tcloud = o3d.t.geometry.PointCloud(o3d.core.Tensor(V))
    tcloud.point.colors = o3d.core.Tensor(np.full((len(V), 3), 255, np.uint8))
    P2, none = adapters.geometry_to_arrays(tcloud)
    assert none is None and np.array_equal(P2, V)
    np.testing.assert_allclose(adapters.vertex_colors(tcloud), 1.0)


def test_eigenbasis_accepts_open3d_geometries(legacy_mesh):
    V, F = adapters.geometry_to_arrays(legacy_mesh)
    ref = ofp.eigenbasis(V, F, k=5)
    for geom in (legacy_mesh, o3d.t.geometry.TriangleMesh.from_legacy(legacy_mesh)):
        eig = ofp.eigenbasis(geom, k=5)
        # the tensor mesh holds float32 positions: eigenvalues agree to ~1e-8 relative
        np.testing.assert_allclose(eig.evals, ref.evals, rtol=1e-6)
    with pytest.raises(ValueError, match="faces must be None"):
        ofp.eigenbasis(legacy_mesh, F, k=5)
    np.testing.assert_array_equal(np.asarray(legacy_mesh.vertices), V)


def test_arrays_to_geometries_validate_and_clip():
    V, F = icosphere(1)
    colors = np.linspace(-1, 2, len(V) * 3).reshape(-1, 3)
    mesh = adapters.triangle_mesh_from_arrays(V, F, colors=colors)
    got = np.asarray(mesh.vertex_colors)
    assert got.min() == 0.0 and got.max() == 1.0
    assert mesh.has_vertex_normals()
    V[0] = 9.0  # the mesh owns its memory
    assert np.asarray(mesh.vertices)[0, 0] != 9.0
    with pytest.raises(ValueError, match="faces index out of range"):
        adapters.triangle_mesh_from_arrays(V, np.array([[0, 1, len(V)]]))
    with pytest.raises(ValueError, match="colors has 3 values but the shape has 42"):
        adapters.triangle_mesh_from_arrays(V, F, colors=np.ones((3, 3)))
    with pytest.raises(ValueError, match=r"colors must have shape \(n, 3\)"):
        adapters.triangle_mesh_from_arrays(V, F, colors=np.ones(len(V)))
    cloud = adapters.point_cloud_from_arrays(V, colors=np.ones((len(V), 3)), normals=V)
    assert cloud.has_colors() and cloud.has_normals()
    with pytest.raises(ValueError, match="points holds NaN"):
        adapters.point_cloud_from_arrays(np.full((3, 3), np.nan))


def test_bad_geometries():
    with pytest.raises(TypeError, match="geometry must be an Open3D TriangleMesh or PointCloud"):
        adapters.geometry_to_arrays(o3d.geometry.LineSet())
    with pytest.raises(ValueError, match="geometry vertices is empty"):
        adapters.geometry_to_arrays(o3d.geometry.TriangleMesh())
    with pytest.raises(ValueError, match="geometry vertices is empty"):
        ofp.eigenbasis(o3d.geometry.PointCloud(), k=3)
    assert not adapters.is_open3d_geometry(np.zeros(3))


@pytest.mark.parametrize("ascii_ply", [False, True])
def test_a_ply_cut_short_is_refused(tmp_path, ascii_ply):
    from o3d_ofp import read_geometry

    V, F = icosphere(2)
    mesh = adapters.triangle_mesh_from_arrays(V, F)
    path = tmp_path / "whole.ply"
    o3d.io.write_triangle_mesh(str(path), mesh, write_ascii=ascii_ply)
    assert len(read_geometry(path).vertices) == len(V)
    data = path.read_bytes()
    cut = tmp_path / "cut.ply"
    cut.write_bytes(data[: len(data) // 2])  # header intact, body cut short
    with pytest.raises(ValueError, match=r"cut\.ply: .*cut short|cut\.ply: Open3D read"):
        read_geometry(cut)
    (tmp_path / "empty.ply").write_bytes(b"")
    with pytest.raises(ValueError, match="empty"):
        read_geometry(tmp_path / "empty.ply")


def test_textured_obj_written_with_its_material_and_no_temporary_files(tmp_path):
    from o3d_ofp import read_geometry, write_geometry

    V, F = icosphere(1)
    mesh = adapters.triangle_mesh_from_arrays(V, F)
    mesh.triangle_uvs = o3d.utility.Vector2dVector(np.random.default_rng(0).random((3 * len(F), 2)))
    mesh.textures = [o3d.geometry.Image(np.full((8, 8, 3), 200, dtype=np.uint8))]
    mesh.triangle_material_ids = o3d.utility.IntVector(np.zeros(len(F), dtype=np.int32))
    write_geometry(tmp_path / "out.obj", mesh)
    names = sorted(p.name for p in tmp_path.iterdir())
    assert "out.obj" in names and "out.mtl" in names
    assert not [n for n in names if n.startswith(".")], names  # nothing hidden left behind
    mtl = (tmp_path / "out.mtl").read_text()
    assert "map_Kd" in mtl and "/" not in mtl.split("map_Kd")[1].split()[0]  # relative name
    back = read_geometry(tmp_path / "out.obj")
    assert back.has_triangle_uvs() and any(np.asarray(t).size > 1 for t in back.textures)


def test_results_keep_the_targets_kind_and_attributes(legacy_mesh):
    """Every kind in, the same kind out; attributes the operation does not replace are kept."""
    V, F = adapters.geometry_to_arrays(legacy_mesh)
    legacy_mesh.compute_vertex_normals()
    legacy_mesh.triangle_uvs = o3d.utility.Vector2dVector(np.zeros((3 * len(F), 2)))
    tmesh = o3d.t.geometry.TriangleMesh.from_legacy(legacy_mesh)
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(V))
    cloud.normals = o3d.utility.Vector3dVector(V)
    tcloud = o3d.t.geometry.PointCloud(o3d.core.Tensor(V.astype(np.float32)))
    tcloud.point.colors = o3d.core.Tensor(np.zeros((len(V), 3), np.uint8))
    new = np.full((len(V), 3), 0.5)
    for target in (legacy_mesh, tmesh, cloud, tcloud):
        before = adapters.geometry_to_arrays(target)[0].copy()
        colored = adapters.like_target(target, colors=new)
        assert type(colored) is type(target)
        np.testing.assert_allclose(adapters.vertex_colors(colored), new, atol=1 / 255)
        moved = adapters.like_target(target, vertices=2 * V)
        assert type(moved) is type(target)
        np.testing.assert_allclose(adapters.geometry_to_arrays(moved)[0], 2 * V, rtol=1e-6)
        np.testing.assert_array_equal(adapters.geometry_to_arrays(target)[0], before)  # untouched
    kept = adapters.like_target(legacy_mesh, colors=new)
    assert kept.has_triangle_uvs() and kept.has_vertex_normals()
    np.testing.assert_allclose(
        np.asarray(kept.vertex_normals), np.asarray(legacy_mesh.vertex_normals)
    )
    assert "normals" in adapters.like_target(tmesh, vertices=2 * V).vertex
    assert adapters.like_target(tcloud, colors=new).point.colors.dtype == o3d.core.uint8
