import subprocess
import sys
import warnings

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
    with pytest.raises(ValueError, match="mesh_or_vertices vertices is empty"):
        ofp.eigenbasis(o3d.geometry.PointCloud(), k=3)
    assert not adapters.is_open3d_geometry(np.zeros(3))


def test_a_bad_geometry_of_a_pair_is_named_by_its_keyword():
    """Found by a trial: a NaN or empty target was called "geometry", not "target"."""
    from o3d_ofp.core.shapes import icosphere

    V, F = icosphere(2)
    good = adapters.triangle_mesh_from_arrays(V, F)
    bad = V.copy()
    bad[3] = np.nan
    nan_mesh = adapters.triangle_mesh_from_arrays(V, F)
    nan_mesh.vertices = o3d.utility.Vector3dVector(bad)
    with pytest.raises(ValueError, match=r"^target vertices holds NaN or inf coordinates in 1 of"):
        ofp.transfer_detail(good, nan_mesh)
    with pytest.raises(ValueError, match=r"^target vertices is empty"):
        ofp.match(good, o3d.geometry.TriangleMesh())
    with pytest.raises(ValueError, match=r"^source vertices holds NaN"):
        ofp.transfer_colors(nan_mesh, good)


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


def _textured_obj(folder):
    """Write an OBJ naming its material and image (Open3D reads an empty default image first)."""
    from o3d_ofp.render.panel import write_png

    V, F = icosphere(1)
    image = np.zeros((8, 8, 3), dtype=np.uint8)
    image[:, :4] = [255, 0, 0]
    write_png(folder / "tex.png", image)
    (folder / "m.mtl").write_text("newmtl mat\nmap_Kd tex.png\n")
    u = 0.5 + 0.4 * V[:, 0]
    lines = ["mtllib m.mtl", "usemtl mat", *(f"v {x} {y} {z}" for x, y, z in V)]
    lines += [f"vt {a} 0.5" for a in u]
    lines += [f"f {a}/{a} {b}/{b} {c}/{c}" for a, b, c in F + 1]
    (folder / "s.obj").write_text("\n".join(lines) + "\n")
    return folder / "s.obj", image


def test_an_obj_read_with_its_texture_is_written_with_it(tmp_path):
    """An OBJ read with its texture is written with it.

    Open3D's reader gives the default material an empty image (the file's is image 1) and its
    writer stops at an image it cannot write: the MTL lost its map_Kd and no PNG was written.
    """
    from o3d_ofp import read_geometry, write_geometry

    path, image = _textured_obj(tmp_path)
    mesh = read_geometry(path)
    assert [t.is_empty() for t in mesh.textures] == [True, False]  # what the fix is about
    ids = np.asarray(mesh.triangle_material_ids).copy()
    (tmp_path / "out").mkdir()
    write_geometry(tmp_path / "out" / "w.obj", mesh)
    assert "map_Kd" in (tmp_path / "out" / "w.mtl").read_text()
    back = read_geometry(tmp_path / "out" / "w.obj")
    loaded = [np.asarray(t)[::-1] for t in back.textures if not t.is_empty()]  # legacy: bottom-up
    assert len(loaded) == 1 and np.array_equal(loaded[0], image)
    assert len(mesh.textures) == 2 and np.array_equal(np.asarray(mesh.triangle_material_ids), ids)
    # triangles on the empty default image get a plain white one, the others keep theirs
    mixed = o3d.geometry.TriangleMesh(mesh)
    ids[:5] = 0
    mixed.triangle_material_ids = o3d.utility.IntVector(ids.astype(np.int32))
    write_geometry(tmp_path / "out" / "m.obj", mixed)
    assert (tmp_path / "out" / "m.mtl").read_text().count("map_Kd") == 2
    back = read_geometry(tmp_path / "out" / "m.obj")
    images = [np.asarray(t) for t in back.textures if not t.is_empty()]
    assert sorted(i.shape[:2] for i in images) == [(1, 1), (8, 8)]


def test_a_format_that_cannot_hold_the_texture_or_the_colors_says_so(tmp_path):
    """Open3D's writers leave a texture out of a PLY and colors out of an STL without a word."""
    from o3d_ofp import OFPWarning, read_geometry, write_geometry

    path, _ = _textured_obj(tmp_path)
    mesh = read_geometry(path)
    with pytest.warns(OFPWarning, match=r"t\.ply: \.ply holds no texture .*\.obj, \.gltf, \.glb"):
        write_geometry(tmp_path / "t.ply", mesh)
    colored = o3d.geometry.TriangleMesh(mesh)
    colored.vertex_colors = o3d.utility.Vector3dVector(np.full((len(mesh.vertices), 3), 0.5))
    with pytest.warns(OFPWarning, match=r"c\.stl: \.stl holds no vertex colors"):
        write_geometry(tmp_path / "c.stl", colored)
    with warnings.catch_warnings():  # formats that hold them: nothing said
        warnings.simplefilter("error")
        write_geometry(tmp_path / "t.obj", colored)
        write_geometry(tmp_path / "c.ply", o3d.geometry.TriangleMesh(colored.vertices,
                                                                     colored.triangles))


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


def test_scaled_copy_keeps_kind_attributes_and_normals(legacy_mesh):
    """``scaled_copy`` (``--target-scale``) scales positions only; the input is untouched.

    A file's own normals (here made not to be the computed ones) survive a scaling and its
    inverse; ``like_target`` with new positions would recompute them.
    """
    V, F = adapters.geometry_to_arrays(legacy_mesh)
    mesh = o3d.geometry.TriangleMesh(legacy_mesh)
    own = np.tile([0.0, 0.0, 1.0], (len(V), 1))
    mesh.vertex_normals = o3d.utility.Vector3dVector(own)
    mesh.triangle_uvs = o3d.utility.Vector2dVector(np.zeros((3 * len(F), 2)))
    tmesh = o3d.t.geometry.TriangleMesh.from_legacy(mesh)
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(V))
    tcloud = o3d.t.geometry.PointCloud(o3d.core.Tensor(V.astype(np.float32)))
    for target in (mesh, tmesh, cloud, tcloud):
        before = adapters.geometry_to_arrays(target)[0].copy()
        scaled = adapters.scaled_copy(target, 1e-3)
        assert type(scaled) is type(target)
        np.testing.assert_allclose(adapters.geometry_to_arrays(scaled)[0], 1e-3 * V, rtol=1e-6)
        np.testing.assert_array_equal(adapters.geometry_to_arrays(target)[0], before)
    back = adapters.scaled_copy(adapters.scaled_copy(mesh, 1e-3), 1e3)
    np.testing.assert_allclose(np.asarray(back.vertices), V, rtol=1e-12)
    np.testing.assert_array_equal(np.asarray(back.vertex_normals), own)
    assert back.has_triangle_uvs()
    assert tmesh.vertex.positions.dtype == adapters.scaled_copy(tmesh, 2.0).vertex.positions.dtype
    Vt, Ft = adapters.scaled_copy((V, F), 2.0)
    np.testing.assert_array_equal(Vt, 2 * V)
    assert Ft is F
    for bad in (0.0, -1.0, float("nan"), float("inf"), "2"):
        with pytest.raises(ValueError, match="factor must be a positive, finite number"):
            adapters.scaled_copy(mesh, bad)


def _sphere_uvs(V):
    u = 0.5 + np.arctan2(V[:, 1], V[:, 0]) / (2 * np.pi)
    v = 0.5 + np.arcsin(np.clip(V[:, 2], -1, 1)) / np.pi
    return np.stack([u, v], axis=1)


def _textured_sphere():
    """Build a legacy icosphere with sphere UVs and a texture: red top, blue bottom half."""
    from o3d_ofp.boundary.texture import legacy_texture_image

    V, F = icosphere(2)
    mesh = adapters.triangle_mesh_from_arrays(V, F, colors=0.5 + 0.5 * V)
    mesh.triangle_uvs = o3d.utility.Vector2dVector(_sphere_uvs(V)[F.reshape(-1)])
    img = np.zeros((64, 64, 3), dtype=np.uint8)
    img[:32] = [250, 20, 20]  # rows top-down: v > 0.5 (the north) is red
    img[32:] = [20, 20, 250]
    mesh.textures = [legacy_texture_image(img)]
    mesh.triangle_material_ids = o3d.utility.IntVector(np.zeros(len(F), dtype=np.int32))
    return mesh, V, F


def _match_vertices(V_back, V):
    """Index into V of each read-back vertex (Open3D's glTF reader may reorder them)."""
    from scipy.spatial import cKDTree

    dist, idx = cKDTree(V).query(V_back)
    # glTF stores float32: a unit sphere's coordinates round by <= 6e-8; 1e-6 leaves room.
    assert dist.max() < 1e-6
    assert len(np.unique(idx)) == len(V)  # one to one
    return idx


@pytest.mark.parametrize("ext", [".glb", ".gltf"])
def test_textured_gltf_round_trip(tmp_path, ext):
    from o3d_ofp import read_geometry, texture_colors, write_geometry
    from o3d_ofp.boundary.texture import mesh_texture

    mesh, V, F = _textured_sphere()
    before = np.asarray(mesh.triangle_uvs).copy()
    write_geometry(tmp_path / f"out{ext}", mesh)
    np.testing.assert_array_equal(np.asarray(mesh.triangle_uvs), before)  # input untouched
    names = sorted(p.name for p in tmp_path.iterdir())
    assert not [n for n in names if n.startswith(".")], names
    if ext == ".gltf":  # the buffer and the image beside it, named after the output
        assert names == ["out.bin", "out.gltf", "out_albedo.png"]
    else:
        assert names == ["out.glb"]
    back = read_geometry(tmp_path / f"out{ext}")
    Vb, Fb = np.asarray(back.vertices), np.asarray(back.triangles)
    idx = _match_vertices(Vb, V)
    # The same triangles (as vertex sets), each with the same UVs at the same corners.
    original = {tuple(sorted(t)): i for i, t in enumerate(F)}
    uv_back = np.asarray(back.triangle_uvs).reshape(-1, 3, 2)
    uv_orig = before.reshape(-1, 3, 2)
    assert len(Fb) == len(F)
    for j, t in enumerate(idx[Fb]):
        i = original[tuple(sorted(t))]
        for corner in range(3):
            c = list(F[i]).index(t[corner])
            # float32 UVs: 1e-6 covers their rounding.
            np.testing.assert_allclose(uv_back[j, corner], uv_orig[i, c], atol=1e-6)
    # The texture came back the right way up: the per-vertex colors equal the original's.
    expected = texture_colors(mesh)[idx]
    np.testing.assert_allclose(texture_colors(back), expected, atol=1.5 / 255)
    assert expected[Vb[:, 2] > 0.5, 0].mean() > 0.9  # and they are not trivially equal
    image = [im for im in mesh_texture(back).images if im.size]
    assert len(image) == 1 and image[0].shape == (64, 64, 3)
    # vertex colors are kept too (8 bits or float32 in the file)
    np.testing.assert_allclose(
        np.asarray(back.vertex_colors), np.asarray(mesh.vertex_colors)[idx], atol=1.0 / 255
    )


@pytest.mark.parametrize("ext", [".glb", ".gltf"])
def test_gltf_of_a_mesh_with_texture_seams(tmp_path, ext):
    """UVs with seams (a vertex with other UVs on other corners) are written and read back.

    glTF has one UV per vertex: the writer splits the vertices along the seams. Found by a
    trial: ``--uv-atlas -o out.glb`` failed after the work ("cannot read back, 1516 of 1252
    vertices") because the check wanted the mesh's own vertex count.
    """
    from o3d_ofp import read_geometry, texture_colors, write_geometry

    mesh, V, F = _textured_sphere()
    uv = _sphere_uvs(V)[F.reshape(-1)].reshape(-1, 3, 2)
    uv[::2] = 1.0 - uv[::2]  # every other triangle mirrored in the atlas: seams everywhere
    mesh.triangle_uvs = o3d.utility.Vector2dVector(uv.reshape(-1, 2))
    write_geometry(tmp_path / f"out{ext}", mesh)
    back = read_geometry(tmp_path / f"out{ext}")
    Vb, Fb = np.asarray(back.vertices), np.asarray(back.triangles)
    assert len(Fb) == len(F) and len(Vb) > len(V)  # split along the seams
    # every read-back vertex is one of the mesh's, and all of them are there
    from scipy.spatial import cKDTree

    dist, idx = cKDTree(V).query(Vb)
    assert dist.max() < 1e-6 and np.unique(idx).size == len(V)
    # the texture is kept and each triangle samples the same colors as before
    colors = np.asarray(texture_colors(back))
    uv_back = np.asarray(back.triangle_uvs).reshape(-1, 3, 2)
    original = {tuple(sorted(t)): i for i, t in enumerate(F)}
    for j, t in enumerate(idx[Fb]):
        i = original[tuple(sorted(t))]
        for corner in range(3):
            c = list(F[i]).index(t[corner])
            np.testing.assert_allclose(uv_back[j, corner], uv[i, c], atol=1e-6)
    assert colors.shape == (len(Vb), 3)


def test_plain_glb_is_readable(tmp_path):
    # Open3D's legacy writer produces .glb files that no reader accepts; ours go through the
    # tensor writer and are read back before they are moved into place.
    from o3d_ofp import read_geometry, write_geometry

    V, F = icosphere(2)
    write_geometry(tmp_path / "plain.glb", adapters.triangle_mesh_from_arrays(V, F))
    back = read_geometry(tmp_path / "plain.glb")
    _match_vertices(np.asarray(back.vertices), V)
    assert len(back.triangles) == len(F)


def test_gltf_refuses_several_texture_images(tmp_path):
    from o3d_ofp import write_geometry

    mesh, _, F = _textured_sphere()
    mesh.textures = [mesh.textures[0], mesh.textures[0]]
    ids = np.zeros(len(F), dtype=np.int32)
    ids[: len(F) // 2] = 1
    mesh.triangle_material_ids = o3d.utility.IntVector(ids)
    with pytest.raises(ValueError, match=r"2 texture images.*write an \.obj"):
        write_geometry(tmp_path / "two.glb", mesh)
    assert list(tmp_path.iterdir()) == []


def test_gltf_that_open3d_cannot_read_back_is_refused(tmp_path, monkeypatch):
    # Simulate the writer producing a file without the texture: the check catches it and
    # nothing is left behind.
    from o3d_ofp import write_geometry

    mesh, _, _ = _textured_sphere()
    real = o3d.t.io.write_triangle_mesh

    def untextured(path, m, *args, **kwargs):
        m = m.clone()
        m.material = o3d.visualization.Material("defaultLit")  # no albedo map
        return real(path, m, *args, **kwargs)

    monkeypatch.setattr(o3d.t.io, "write_triangle_mesh", untextured)
    with pytest.raises(OSError, match="did not write the texture"):
        write_geometry(tmp_path / "x.glb", mesh)
    assert list(tmp_path.iterdir()) == []


# --------------------------------------------------------------------------- landmark picking


def test_pick_landmarks_pairs_the_two_windows_in_order(legacy_mesh, monkeypatch):
    from o3d_ofp.boundary.pick import pick_landmarks

    calls = []

    def picker(geometry, title):
        calls.append((geometry, title))
        return [3, 7, 11] if len(calls) == 1 else [30, 70, 110]

    target = o3d.t.geometry.TriangleMesh.from_legacy(legacy_mesh)
    pairs = pick_landmarks(legacy_mesh, target, picker=picker)
    np.testing.assert_array_equal(pairs, [[3, 30], [7, 70], [11, 110]])
    assert pairs.dtype == np.int64
    assert calls[0][0] is legacy_mesh and calls[1][0] is target  # source first
    assert "3 matching vertices" in calls[1][1]
    with pytest.raises(ValueError, match="count=2 pairs were asked for; 3 were picked"):
        pick_landmarks(legacy_mesh, target, count=2, picker=_picker_from([[1, 2, 3], [4, 5, 6]]))
    with pytest.raises(ValueError, match="count must be >= 1"):
        pick_landmarks(legacy_mesh, target, count=0, picker=picker)


def _picker_from(answers):
    answers = list(answers)
    return lambda geometry, title: answers.pop(0)


@pytest.mark.parametrize(
    ("a", "b", "message"),
    [
        ([1, 2], [1], "picked 2 vertices on the source but 1 on the target"),
        ([], [1], "no vertex was picked on the source"),
        ([1], [], "no vertex was picked on the target"),
        ([1, 1], [2, 3], "source vertex 1 was picked twice"),
        ([1, 2], [3, 3], "target vertex 3 was picked twice"),
        ([-1], [0], r"source vertices must lie in \[0, 162\)"),
        ([0], [162], r"target vertices must lie in \[0, 162\)"),
    ],
)
def test_picks_that_do_not_pair_up_are_refused(legacy_mesh, a, b, message):
    from o3d_ofp.boundary.pick import pick_landmarks

    with pytest.raises(ValueError, match=message):
        pick_landmarks(legacy_mesh, legacy_mesh, picker=_picker_from([a, b]))


def test_pick_landmarks_without_display_refuses_before_opening(legacy_mesh, monkeypatch):
    from o3d_ofp.boundary import pick

    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    monkeypatch.setattr(pick.sys, "platform", "linux")
    monkeypatch.setattr(pick, "_pick_in_window", lambda *a: pytest.fail("a window was opened"))
    assert not pick.has_display()
    with pytest.raises(RuntimeError, match="needs a display"):
        pick.pick_landmarks(legacy_mesh, legacy_mesh)


def test_a_display_counts_only_when_its_server_answers(tmp_path, monkeypatch):
    """A DISPLAY with no X server behind it made Open3D wait for a window forever (a trial)."""
    import socket

    from o3d_ofp.boundary import pick

    monkeypatch.setattr(pick.sys, "platform", "linux")
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    monkeypatch.setenv("DISPLAY", ":987")  # no server: neither its socket file nor abstract one
    assert not pick.has_display()
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as server:  # an X server over TCP
        for number in range(50, 200):
            try:
                server.bind(("127.0.0.1", 6000 + number))
                break
            except OSError:
                continue
        server.listen(1)
        monkeypatch.setenv("DISPLAY", f"127.0.0.1:{number}.0")
        assert pick.has_display()
    assert not pick.has_display()  # closed
    monkeypatch.delenv("DISPLAY")
    monkeypatch.setenv("XDG_RUNTIME_DIR", str(tmp_path))
    monkeypatch.setenv("WAYLAND_DISPLAY", "wayland-0")
    assert not pick.has_display()  # set, but nothing listens there
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as server:
        server.bind(str(tmp_path / "wayland-0"))
        server.listen(1)
        assert pick.has_display()


def test_the_picking_window_shows_vertices_in_the_arrays_order(legacy_mesh):
    # The window shows a copy built from geometry_to_arrays, so a picked index is an index
    # into the arrays the eigenbasis uses, for every kind of input.
    from o3d_ofp.boundary.pick import _viewable

    V, _ = icosphere(2)
    cloud = adapters.point_cloud_from_arrays(V[::-1])
    for geometry in (legacy_mesh, o3d.t.geometry.TriangleMesh.from_legacy(legacy_mesh), cloud):
        shown = _viewable(geometry)
        points = shown.vertices if hasattr(shown, "vertices") else shown.points
        np.testing.assert_array_equal(np.asarray(points), adapters.geometry_to_arrays(geometry)[0])
    assert _viewable(legacy_mesh).has_vertex_colors()  # the shape's own colors are shown


def test_tensor_textured_mesh_to_glb(tmp_path):
    from o3d_ofp import read_geometry, texture_colors, write_geometry

    mesh, V, _ = _textured_sphere()
    tmesh = o3d.t.geometry.TriangleMesh()
    tmesh.vertex.positions = o3d.core.Tensor(V.astype(np.float32))
    tmesh.triangle.indices = o3d.core.Tensor(np.asarray(mesh.triangles, dtype=np.int64))
    tmesh.triangle.texture_uvs = o3d.core.Tensor(
        np.asarray(mesh.triangle_uvs, dtype=np.float32).reshape(-1, 3, 2)
    )
    img = np.zeros((64, 64, 3), dtype=np.uint8)
    img[:32], img[32:] = [250, 20, 20], [20, 20, 250]
    tmesh.material.set_default_properties()
    tmesh.material.texture_maps["albedo"] = o3d.t.geometry.Image(o3d.core.Tensor(img))
    write_geometry(tmp_path / "t.glb", tmesh)
    back = read_geometry(tmp_path / "t.glb")
    idx = _match_vertices(np.asarray(back.vertices), V)
    np.testing.assert_allclose(texture_colors(back), texture_colors(mesh)[idx], atol=1.5 / 255)


def test_picking_window_wiring_with_a_stand_in_visualizer(legacy_mesh, monkeypatch):
    # The real window cannot open on a machine without a display; a stand-in with the same
    # methods checks the calls: the copy shown, the window closed even on error, the indices.
    from o3d_ofp.boundary import pick

    log = []

    class StandIn:
        opens = True

        def create_window(self, window_name, width, height):
            log.append(("create", window_name))
            return self.opens

        def add_geometry(self, geometry):
            log.append(("add", len(geometry.vertices)))

        def run(self):
            log.append(("run",))

        def destroy_window(self):
            log.append(("destroy",))

        def get_picked_points(self):
            return [np.int64(4), 9]

    for name in ("create_window", "add_geometry", "run", "destroy_window", "get_picked_points"):
        assert hasattr(o3d.visualization.VisualizerWithEditing, name)  # the real API has them
    monkeypatch.setattr(o3d.visualization, "VisualizerWithEditing", StandIn)
    assert pick._pick_in_window(legacy_mesh, "source") == [4, 9]
    assert log == [("create", "source"), ("add", 162), ("run",), ("destroy",)]
    StandIn.opens = False
    with pytest.raises(RuntimeError, match="could not open a window"):
        pick._pick_in_window(legacy_mesh, "source")


def test_a_file_that_may_not_be_read_is_named_so(tmp_path, monkeypatch):
    """A file this process may not read is refused as such.

    Found by a trial: an unreadable file was "a file Open3D could not read any vertices
    from" (RPly printed twice). Root reads every file: the open is made to fail here.
    """
    import builtins
    import os

    from o3d_ofp import read_geometry, write_geometry

    path = tmp_path / "locked.ply"
    write_geometry(path, adapters.triangle_mesh_from_arrays(*icosphere(1)))
    real_open = builtins.open

    def refuse(file, *args, **kwargs):
        if os.fspath(file) == str(path):
            raise PermissionError(13, "Permission denied", str(path))
        return real_open(file, *args, **kwargs)

    monkeypatch.setattr(builtins, "open", refuse)
    with pytest.raises(PermissionError, match=r"locked\.ply: cannot be read \(permission denied\)"):
        read_geometry(path)


def test_open3d_level_findings_of_a_python_trial():
    """Findings of a Python API trial, each fixed.

    Integer tensor colors keep their scale (uint16 came out as 0 or 1), RGBA sources give
    their RGB, options are named, filter_geometry takes a (vertices, faces) tuple.
    """
    import o3d_ofp as ofp

    V, F = icosphere(2)
    n = len(V)
    mesh = o3d.t.geometry.TriangleMesh()
    mesh.vertex.positions = o3d.core.Tensor(V.astype(np.float32))
    mesh.triangle.indices = o3d.core.Tensor(F.astype(np.int64))
    rng = np.random.default_rng(0)
    identity = ofp.Correspondence.from_p2p(np.arange(n), n, n)
    for dtype in (np.uint8, np.uint16):
        top = np.iinfo(dtype).max
        src, tgt = mesh.clone(), mesh.clone()
        src.vertex.colors = o3d.core.Tensor((rng.random((n, 3)) * top).astype(dtype))
        tgt.vertex.colors = o3d.core.Tensor(np.zeros((n, 3), dtype))
        out = ofp.transfer_colors(src, tgt, correspondence=identity, via_basis=False)
        got = out.vertex.colors.numpy()  # the target's dtype, on its full scale
        assert got.dtype == dtype
        assert np.abs(got.astype(float) - src.vertex.colors.numpy()).max() <= 1
    rgba = mesh.clone()
    rgba.vertex.colors = o3d.core.Tensor(rng.random((n, 4)).astype(np.float32))
    out = ofp.transfer_colors(rgba, mesh.clone(), correspondence=identity, via_basis=False)
    rgb = rgba.vertex.colors.numpy()[:, :3]
    np.testing.assert_allclose(out.vertex.colors.numpy(), rgb, atol=1e-6)
    two = mesh.clone()
    two.vertex.colors = o3d.core.Tensor(rng.random((n, 2)).astype(np.float32))
    with pytest.raises(ValueError, match=r"colors have shape \(162, 2\)"):
        ofp.transfer_colors(two, mesh.clone(), correspondence=identity)
    with pytest.raises(TypeError, match="via_basis must be True, False or None"):
        ofp.transfer_colors(rgba, mesh.clone(), correspondence=identity, via_basis="no")
    with pytest.raises(TypeError, match="bases must be a pair"):
        ofp.transfer_colors(rgba, mesh.clone(), correspondence=identity, bases=(None,))
    with pytest.raises(TypeError, match="keep_volume must be True or False"):
        ofp.filter_geometry(mesh, smooth=0.01, keep_volume="no")


def test_exact_pull_back_refuses_the_basis_options_it_would_ignore():
    """OFP basis options an exact pull-back would ignore are refused by name.

    The defaults (given or not) and via_basis=True are not refused.
    """
    import o3d_ofp as ofp

    V, F = icosphere(2)
    mesh = o3d.geometry.TriangleMesh(
        o3d.utility.Vector3dVector(V), o3d.utility.Vector3iVector(F)
    )
    colors = np.random.default_rng(1).random((len(V), 3))
    mesh.vertex_colors = o3d.utility.Vector3dVector(colors)
    target = o3d.geometry.TriangleMesh(mesh)
    closest = ofp.match(mesh, target, method="closest")
    refused = r"options .*does not apply: the exact pull-back .*closest-point map.*via_basis=True"
    with pytest.raises(ValueError, match=refused) as info:
        ofp.transfer_colors(
            mesh, target, correspondence=closest, options=ofp.BasisOptions(k1=20, order=3)
        )
    assert info.value.option == "options"
    given = ofp.Correspondence.from_p2p(np.arange(len(V)), mesh, target)
    with pytest.raises(ValueError, match=r"options .*does not apply: .*via_basis=False"):
        ofp.transfer_colors(mesh, target, correspondence=given, via_basis=False,
                            options=ofp.BasisOptions(preset="ours*"))  # fmt: skip
    # landmarks belong to the map's estimation: a transfer does not take them
    with pytest.raises(TypeError, match="landmarks"):
        ofp.transfer_colors(mesh, target, correspondence=closest, landmarks=[[0, 0]])
    # The defaults, given or not (numpy integers too), are the exact pull-back's.
    for options in (None, ofp.BasisOptions(k1=29, order=np.int64(2), preset="ours")):
        out = ofp.transfer_colors(mesh, target, correspondence=closest, options=options)
        np.testing.assert_allclose(np.asarray(out.vertex_colors), colors, atol=1e-12)
    out = ofp.transfer_colors(
        mesh, target, correspondence=closest, options=ofp.BasisOptions(k1=20), via_basis=True
    )
    assert np.abs(np.asarray(out.vertex_colors) - colors).mean() > 1e-3  # through the bases
    smoothed = ofp.filter_geometry((V, F), smooth=0.01)  # the README's tuple input
    assert np.asarray(smoothed.vertices).shape == V.shape
    from o3d_ofp.boundary.bake import with_uv_atlas

    with pytest.raises(ValueError, match=r"size=3: Open3D could not lay out a UV atlas"):
        with_uv_atlas(mesh, size=3)  # was Open3D's RuntimeError, no word of the size


def test_an_obj_is_read_with_its_vertices_in_the_order_of_its_v_lines(tmp_path):
    """Open3D's reader numbers an OBJ's vertices by first use in the faces: put back.

    A trial's OBJ outputs were renumbered (per-vertex data kept beside the file no longer
    lined up); per-corner UVs and vertex normals follow their vertices.
    """
    from o3d_ofp.core.shapes import blob

    V, F = blob(3)
    F = F[np.random.default_rng(0).permutation(len(F))]  # first use in faces != v order
    mesh = adapters.triangle_mesh_from_arrays(V, F)
    uv = 0.5 + 0.4 * V[:, :2] / np.abs(V[:, :2]).max()
    mesh.triangle_uvs = o3d.utility.Vector2dVector(uv[F.ravel()])
    mesh.compute_vertex_normals()
    normals = np.asarray(mesh.vertex_normals).copy()
    path = tmp_path / "b.obj"
    o3d.io.write_triangle_mesh(str(path), mesh)
    as_open3d = np.asarray(o3d.io.read_triangle_mesh(str(path)).vertices)
    assert not np.allclose(as_open3d, V, atol=1e-5)  # what Open3D gives: renumbered
    read = ofp.read_geometry(path)
    np.testing.assert_allclose(np.asarray(read.vertices), V, atol=1e-5)
    np.testing.assert_array_equal(np.asarray(read.triangles), F)
    np.testing.assert_allclose(np.asarray(read.triangle_uvs), uv[F.ravel()], atol=1e-5)
    np.testing.assert_allclose(np.asarray(read.vertex_normals), normals, atol=1e-4)
    # written back: the same v lines, in the same order
    ofp.write_geometry(tmp_path / "c.obj", read)
    first, second = ([x for x in f.read_text().splitlines() if x.startswith("v ")]
                     for f in (path, tmp_path / "c.obj"))  # fmt: skip
    assert first == second


def _no_eigensolve(monkeypatch):
    """Make every eigensolve of a transfer fail, so an error raised first is raised before it."""
    from o3d_ofp.workflows import plan

    def refuse(*args, **kwargs):
        raise AssertionError("an eigenbasis was computed before the bad input was refused")

    monkeypatch.setattr(plan, "_eigenbases", refuse)
    monkeypatch.setattr(plan, "estimate_dense", refuse)


def test_transfers_refuse_a_bad_map_or_bad_colors_before_any_eigensolve(monkeypatch):
    """A trial's p2p_21 of 100 entries (and NaN colors) were refused after both eigenbases."""
    V, F = icosphere(2)
    mesh = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(V), o3d.utility.Vector3iVector(F))
    colors = np.random.default_rng(2).random((len(V), 3))
    mesh.vertex_colors = o3d.utility.Vector3dVector(colors)
    target = o3d.geometry.TriangleMesh(mesh.vertices, mesh.triangles)
    before = np.asarray(mesh.vertex_colors).copy()
    _no_eigensolve(monkeypatch)
    n = len(V)
    bad_maps = [
        (np.arange(100), ValueError, "p2p_21 has 100 entries but the target has"),
        (np.arange(n) + 5, ValueError, r"source vertex indices in \[0, "),
        (np.zeros(n), TypeError, "1-D integer array"),
    ]
    for p2p, kind, message in bad_maps:  # refused as the map is made, before any transfer
        with pytest.raises(kind, match=message):
            ofp.Correspondence.from_p2p(p2p, mesh, target)
    other = ofp.Correspondence(p2p_21=np.zeros(n - 1, dtype=np.int64), n_source=n)
    for transfer in (ofp.transfer_colors, ofp.transfer_detail, ofp.transfer_texture):
        with pytest.raises(ValueError, match=f"but the target has {n} and the source {n}"):
            transfer(mesh, target, correspondence=other)
    with_nan = o3d.geometry.TriangleMesh(mesh)
    nan_colors = colors.copy()
    nan_colors[5] = np.nan
    with_nan.vertex_colors = o3d.utility.Vector3dVector(nan_colors)
    with pytest.raises(ValueError, match="the source's vertex color array holds NaN"):
        ofp.transfer_colors(with_nan, target)
    few = o3d.geometry.TriangleMesh(mesh)
    few.vertex_colors = o3d.utility.Vector3dVector(colors[:100])  # Open3D: "no colors"
    with pytest.raises(ValueError, match=f"not one per vertex: it has 100 colors for its {n} vert"):
        ofp.transfer_colors(few, target)
    np.testing.assert_array_equal(np.asarray(mesh.vertex_colors), before)


def test_shapes_that_are_no_shapes_and_meshes_given_as_bases_are_named():
    """A trial's match(5, target) said "vertices must have shape (n, 3); got ()"."""
    V, F = icosphere(1)
    for wrong in (5, None, {"v": V}):
        with pytest.raises(TypeError, match=r"source must be an Open3D TriangleMesh or Point"):
            ofp.match(wrong, (V, F))
    mesh = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(V), o3d.utility.Vector3iVector(F))
    with pytest.raises(TypeError, match=r"eig_1 must be an EigenBasis .*transfer_colors"):
        ofp.transfer_function(V[:, 0], mesh, mesh)


@pytest.mark.parametrize(
    ("function", "keyword", "use"),
    [
        ("transfer_colors", "p2p_21", "correspondence=o3d_ofp.Correspondence.from_p2p("),
        ("transfer_colors", "partial", "correspondence=o3d_ofp.match(source, target, partial="),
        ("transfer_colors", "k1", "options=o3d_ofp.BasisOptions(k1="),
        ("transfer_colors", "method", "options=o3d_ofp.BasisOptions(matrix="),
        ("transfer_detail", "k_low", "band="),
        ("transfer_detail", "eigenbases", "bases=(eig_1, eig_2)"),
        ("transfer_texture", "p2p_21", "Correspondence.from_p2p("),
        ("texture_pullback", "partial", "o3d_ofp.match(source, target, partial="),
        ("match", "k_fit", "options=o3d_ofp.MatchOptions(k_fit="),
        ("match_eigenbases", "landmarks", "options=o3d_ofp.MatchOptions(landmarks="),
        ("transfer_function", "fmap_12", "Correspondence.from_fmap(fmap_12, eig_1, eig_2)"),
    ],
)
def test_a_former_keyword_is_refused_with_what_replaces_it(function, keyword, use):
    """Keywords the options objects replaced: a TypeError naming the new way, before any work."""
    import inspect

    fn = getattr(ofp, function)
    assert keyword not in inspect.signature(fn).parameters  # the signature is the new one
    with pytest.raises(TypeError, match=rf"{function}\(\) no longer takes {keyword}=: use ") as e:
        fn(None, None, None, **{keyword: 1})
    assert use in str(e.value), str(e.value)


@pytest.mark.parametrize("name", ["x.ply", "x.obj"])
def test_write_geometry_refuses_arrays_with_the_function_that_makes_a_mesh(tmp_path, name):
    V, F = icosphere(1)
    with pytest.raises(TypeError, match=r"x\.(ply|obj): the geometry to write must be an Open3D "
                       r"TriangleMesh or PointCloud .* got tuple .*triangle_mesh_from_arrays"):
        ofp.write_geometry(str(tmp_path / name), (V, F))
    assert list(tmp_path.iterdir()) == []  # nothing written, no temporary folder left


def test_common_python_mistakes_get_messages_that_name_the_fix(legacy_mesh, tmp_path):
    """Common mistakes are told with their fix.

    A trial's: k given by position, options as a dict, a folder as a shape, an Open3D object of
    another kind as the target.
    """
    colored = o3d.geometry.TriangleMesh(legacy_mesh)
    colored.vertex_colors = o3d.utility.Vector3dVector(np.full((len(colored.vertices), 3), 0.5))
    with pytest.raises(ValueError, match=r"keyword-only, k=29"):
        ofp.eigenbasis(legacy_mesh, 29)
    corr = ofp.Correspondence.from_p2p(np.arange(len(colored.vertices)), colored, colored)
    with pytest.raises(TypeError, match=r"options must be an o3d_ofp\.BasisOptions.*dict"):
        ofp.transfer_colors(colored, colored, correspondence=corr, options={"k1": 14})
    with pytest.raises(ValueError, match=r"source: .*: a folder, not a mesh"):
        ofp.match(str(tmp_path), legacy_mesh)
    with pytest.raises(TypeError, match=r"^target must be an Open3D TriangleMesh"):
        ofp.transfer_colors(colored, o3d.geometry.Image(), correspondence=corr)


def test_a_cloud_file_is_said_as_one_and_a_1_based_point_map_gets_the_hint(tmp_path, caplog):
    """A ``.xyz`` file is said as a point cloud; a point map counting from 1 gets a hint.

    A trial: every ``.pcd`` / ``.xyz`` file logged "no triangles Open3D can read (..., e.g.
    PLY triangle strips)"; ``Correspondence.from_p2p(np.arange(1, n + 1), ...)`` gave no hint.
    """
    import logging

    V, _ = icosphere(2)
    path = tmp_path / "c.xyz"
    np.savetxt(path, V)
    with caplog.at_level(logging.INFO, logger="o3d_ofp.boundary.io"):
        ofp.read_geometry(path)
    assert f"{path}: a point cloud of {len(V)} points" in caplog.text
    assert "no triangles" not in caplog.text
    n = len(V)
    with pytest.raises(ValueError, match=r"got range \[1, 162\] \(1-based indices\? they count"):
        ofp.Correspondence.from_p2p(np.arange(1, n + 1), n, n)
    with pytest.raises(ValueError) as e:
        ofp.Correspondence.from_p2p(np.arange(n) + 5, n, n)  # out of range, not 1-based
    assert "1-based" not in str(e.value)
