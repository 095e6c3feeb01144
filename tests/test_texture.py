"""UV textures: bilinear sampling, corner averaging, textured OBJ files, seams."""

from __future__ import annotations

import numpy as np
import pytest

import o3d_ofp as ofp
from o3d_ofp.core.shapes import icosphere
from o3d_ofp.core.texture import corner_colors_to_vertices, sample_texture
from o3d_ofp.render.panel import write_png

from .conftest import shared_path


def test_bilinear_sampling_is_exact_at_centres_and_midpoints():
    img = np.array([[[255, 0, 0], [0, 255, 0]], [[0, 0, 255], [255, 255, 255]]], dtype=np.uint8)
    # Pixel centres (v up: the first image row is the top, v = 0.75).
    uv = np.array([[0.25, 0.75], [0.75, 0.75], [0.25, 0.25], [0.75, 0.25], [0.5, 0.75]])
    out = sample_texture(img, uv)
    np.testing.assert_allclose(out[:4], img.reshape(-1, 3) / 255.0)
    np.testing.assert_allclose(out[4], [0.5, 0.5, 0.0])  # halfway between red and green
    # Wrapping (GL_REPEAT): u + 1 samples the same place.
    np.testing.assert_allclose(sample_texture(img, uv + 1.0), out)
    with pytest.raises(ValueError, match="uv must have shape"):
        sample_texture(img, np.zeros((3, 3)))
    with pytest.raises(ValueError, match="NaN"):
        sample_texture(img, np.full((1, 2), np.nan))


def test_corner_colors_average_at_shared_vertices():
    F = np.array([[0, 1, 2], [2, 1, 3]])
    corners = np.array([[1.0], [0], [0], [1], [1], [0]])
    out = corner_colors_to_vertices(F, corners, 5)
    np.testing.assert_allclose(out[:, 0], [1.0, 0.5, 0.5, 0.0, 0.0])


def test_textured_obj_with_material_and_seams(tmp_path):
    """A cube-like strip with a UV seam: Open3D splits it, the basis welds it back."""
    o3d = pytest.importorskip("open3d")
    from o3d_ofp import read_geometry, texture_colors

    img = np.zeros((8, 8, 3), dtype=np.uint8)
    img[:, :4] = [255, 0, 0]  # left half red, right half blue
    img[:, 4:] = [0, 0, 255]
    write_png(tmp_path / "tex.png", img)
    (tmp_path / "m.mtl").write_text("newmtl mat\nmap_Kd tex.png\n")
    V, F = icosphere(2)
    u = 0.5 + np.arctan2(V[:, 1], V[:, 0]) / (2 * np.pi)  # longitude: seam at u = 0 / 1
    v = 0.5 + np.arcsin(np.clip(V[:, 2], -1, 1)) / np.pi
    lines = ["mtllib m.mtl", "usemtl mat"]
    lines += [f"v {x} {y} {z}" for x, y, z in V]
    lines += [f"vt {a} {b}" for a, b in zip(u, v, strict=True)]
    lines += [f"f {a}/{a} {b}/{b} {c}/{c}" for a, b, c in F + 1]
    (tmp_path / "s.obj").write_text("\n".join(lines) + "\n")
    mesh = read_geometry(tmp_path / "s.obj")
    colors = texture_colors(mesh)  # the texture from the material file
    assert colors.shape == (len(np.asarray(mesh.vertices)), 3)
    Vm = np.asarray(mesh.vertices)
    um = 0.5 + np.arctan2(Vm[:, 1], Vm[:, 0]) / (2 * np.pi)
    inner = (np.abs(um - 0.25) < 0.15) | (np.abs(um - 0.75) < 0.15)  # away from color edges
    expected_red = um < 0.5
    assert np.all((colors[inner, 0] > 0.9) == expected_red[inner])
    assert np.all((colors[inner, 2] > 0.9) == ~expected_red[inner])
    # Same image passed explicitly, as a path or an array.
    np.testing.assert_allclose(texture_colors(mesh, tmp_path / "tex.png"), colors)
    np.testing.assert_allclose(texture_colors(mesh, img), colors)
    eig = ofp.eigenbasis(mesh, k=8)  # seam copies welded: one surface
    assert eig.evals[1] > 1e-6 * eig.evals[-1]
    plain = o3d.geometry.TriangleMesh(mesh.vertices, mesh.triangles)
    with pytest.raises(ValueError, match="no per-corner texture coordinates"):
        texture_colors(plain)
    with pytest.raises(FileNotFoundError, match="no such texture"):
        texture_colors(mesh, tmp_path / "missing.png")


def test_spot_texture_to_vertex_colors_and_cli_transfer(tmp_path):
    obj = shared_path("models/spot_triangulated.obj")
    png = shared_path("models/spot_texture.png")
    pytest.importorskip("open3d")
    from o3d_ofp import read_geometry, texture_colors
    from o3d_ofp.cli import main

    mesh = read_geometry(obj)
    colors = texture_colors(mesh, png)
    # Spot is white with black patches and orange horns and nose: mostly bright, some dark.
    brightness = colors.mean(axis=1)
    assert 0.6 < np.median(brightness) and (brightness < 0.3).mean() > 0.03
    eig = ofp.eigenbasis(mesh, k=10)
    assert eig.cleaning.report.merged_vertices == 3225 - 2930  # UV seams welded
    out = tmp_path / "spot.ply"
    code = main(["transfer", str(obj), str(obj), "--signal", "texture", "--texture", str(png),
                 "--map", "identity", "--k1", "20", "--k2", "20", "-o", str(out)])  # fmt: skip
    assert code == 0
    import open3d as o3d

    g = np.asarray(o3d.io.read_triangle_mesh(str(out)).vertex_colors)
    err = np.linalg.norm(g - colors) / np.linalg.norm(colors)
    assert err < 0.25  # identity map: the basis approximation of the texture (measured 16 %)


def _spot_with_material(folder):
    """Spot as an OBJ with a material file naming its texture, so Open3D loads the image."""
    import shutil

    obj = shared_path("models/spot_triangulated.obj")
    png = shared_path("models/spot_texture.png")
    shutil.copy(png, folder / "spot_texture.png")
    (folder / "spot.mtl").write_text("newmtl spot\nmap_Kd spot_texture.png\n")
    (folder / "spot.obj").write_text("mtllib spot.mtl\nusemtl spot\n" + obj.read_text())
    return folder / "spot.obj", png


def test_own_texture_read_by_open3d_gives_the_file_colors(tmp_path):
    """Legacy meshes keep their images bottom-up; tensor meshes keep them as in the file."""
    o3d = pytest.importorskip("open3d")
    from o3d_ofp import texture_colors

    obj, png = _spot_with_material(tmp_path)
    expected = texture_colors(o3d.io.read_triangle_mesh(str(obj)), png)
    legacy = o3d.io.read_triangle_mesh(str(obj))
    file_image = np.asarray(o3d.io.read_image(str(png)))
    # What Open3D 0.20's legacy OBJ reader does: an empty default image first, the file's
    # material numbered 1, and its image flipped upside down.
    loaded = [np.asarray(t) for t in legacy.textures if not t.is_empty()]
    assert len(loaded) == 1 and np.array_equal(loaded[0][::-1], file_image)
    assert np.all(np.asarray(legacy.triangle_material_ids) == len(legacy.textures) - 1)
    assert np.abs(texture_colors(legacy) - expected).mean() < 0.01  # was 0.18 (upside down)
    # Material ids that name the empty default image, or no ids at all: the one real image.
    for ids in (np.zeros(len(legacy.triangles), dtype=np.int32), np.zeros(0, dtype=np.int32)):
        other = o3d.geometry.TriangleMesh(legacy)
        other.triangle_material_ids = o3d.utility.IntVector(ids)
        assert np.abs(texture_colors(other) - expected).mean() < 0.01
    # The tensor reader: UVs per triangle, the image as the material's albedo map.
    tensor = o3d.t.io.read_triangle_mesh(str(obj))
    assert "texture_uvs" in tensor.triangle and "albedo" in tensor.material.texture_maps
    assert np.abs(texture_colors(tensor) - expected).mean() < 0.01
    assert np.abs(texture_colors(tensor, png) - expected).mean() < 0.01
    # Per-vertex UVs on a tensor mesh (as glTF files give them) work too.
    V, F = icosphere(1)
    uv = np.column_stack([0.5 + 0.4 * V[:, 0], 0.5 + 0.4 * V[:, 1]])
    flat = o3d.t.geometry.TriangleMesh(o3d.core.Tensor(V), o3d.core.Tensor(F))
    flat.vertex["texture_uvs"] = o3d.core.Tensor(uv)
    np.testing.assert_allclose(
        texture_colors(flat, file_image), np.clip(sample_texture(file_image, uv), 0, 1)
    )


def test_written_legacy_texture_is_the_right_way_up(tmp_path):
    """legacy_texture_image stores a top-down array bottom-up; the OBJ writer restores it."""
    o3d = pytest.importorskip("open3d")
    from o3d_ofp.boundary.texture import legacy_texture_image, mesh_texture

    img = np.zeros((4, 4, 3), dtype=np.uint8)
    img[:2] = [255, 0, 0]  # top half red, bottom half blue
    img[2:] = [0, 0, 255]
    V = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], dtype=np.float64)
    F = np.array([[0, 1, 2], [0, 2, 3]])
    mesh = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(V), o3d.utility.Vector3iVector(F))
    mesh.triangle_uvs = o3d.utility.Vector2dVector(V[F.reshape(-1), :2])  # u = x, v = y
    mesh.textures = [legacy_texture_image(img)]
    mesh.triangle_material_ids = o3d.utility.IntVector([0, 0])
    assert np.array_equal(np.asarray(mesh.textures[0]), img[::-1])
    np.testing.assert_array_equal(mesh_texture(mesh).images[0], img)
    top = mesh_texture(mesh).sample([1], [[0.25, 0.25, 0.5]])  # the point (0.25, 0.75): v up
    np.testing.assert_allclose(top, [[1.0, 0.0, 0.0]])
    path = tmp_path / "square.obj"
    assert o3d.io.write_triangle_mesh(str(path), mesh)
    (png,) = tmp_path.glob("*.png")
    np.testing.assert_array_equal(np.asarray(o3d.io.read_image(str(png))), img)
    back = o3d.io.read_triangle_mesh(str(path))
    np.testing.assert_allclose(
        mesh_texture(back).corner_colors(), mesh_texture(mesh).corner_colors(), atol=1e-6
    )
