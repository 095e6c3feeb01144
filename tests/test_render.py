"""Headless rendering: PNG files, colormaps, color bars, framing, lighting, textures, show().

A renderer that crashes fails a test; a machine without an EGL context skips the render tests.
"""

from __future__ import annotations

import sys
import types

import numpy as np
import pytest

from o3d_ofp.boundary import pick
from o3d_ofp.core.shapes import icosphere
from o3d_ofp.render import panel as panel_mod
from o3d_ofp.render.panel import (
    RenderError,
    RenderUnavailable,
    View,
    colormap,
    read_png,
    render_images,
    render_panel,
    show,
    write_png,
)

pytest.importorskip("open3d", reason="rendering uses Open3D's legacy Visualizer")


def _render_or_skip(fn, *args, **kwargs):
    # Only "this machine cannot render" skips; a renderer that crashes raises plain
    # RenderError and fails the test.
    try:
        return fn(*args, **kwargs)
    except RenderUnavailable as exc:
        pytest.skip(f"no EGL/OpenGL context on this machine: {exc}")


def _drawn(img):
    return (img < 250).any(axis=2)


def test_png_round_trip(tmp_path):
    from PIL import Image

    rng = np.random.default_rng(0)
    img = rng.integers(0, 256, (17, 23, 3), dtype=np.uint8)
    write_png(tmp_path / "a.png", img)
    np.testing.assert_array_equal(read_png(tmp_path / "a.png"), img)
    with Image.open(tmp_path / "a.png") as im:  # a real PNG, as Pillow reads it
        assert im.format == "PNG" and im.mode == "RGB" and im.size == (23, 17)
    grey = img[:, :, 0]
    write_png(tmp_path / "g.png", grey)
    np.testing.assert_array_equal(read_png(tmp_path / "g.png"), grey)
    with pytest.raises(ValueError, match="uint8"):
        write_png(tmp_path / "b.png", img.astype(float))
    # Other PNG flavours come back as RGB.
    rgba = np.concatenate([img, np.full((17, 23, 1), 255, np.uint8)], axis=2)
    Image.fromarray(rgba).save(tmp_path / "rgba.png")
    np.testing.assert_array_equal(read_png(tmp_path / "rgba.png"), img)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.png", "g.png", "rgba.png"]


def test_colormap_is_matplotlibs():
    import matplotlib

    c = colormap(np.array([0.0, 0.5, 1.0]))
    viridis = matplotlib.colormaps["viridis"]
    np.testing.assert_allclose(c[0], viridis(0.0)[:3])
    np.testing.assert_allclose(c[2], viridis(1.0)[:3])
    np.testing.assert_allclose(c[0], [0.267, 0.005, 0.329], atol=1e-3)  # viridis' dark end
    for name in ("coolwarm", "magma", "RdBu_r"):
        ends = colormap(np.array([-3.0, 7.0]), name)
        np.testing.assert_allclose(ends[0], matplotlib.colormaps[name](0.0)[:3])
        np.testing.assert_allclose(ends[1], matplotlib.colormaps[name](1.0)[:3])
    np.testing.assert_allclose(colormap(np.array([5.0, 5.0])), colormap(np.array([0.5]))[[0, 0]])
    clipped = colormap(np.array([-1.0, 2.0]), vmin=0.0, vmax=1.0)
    np.testing.assert_allclose(clipped, colormap(np.array([0.0, 1.0])))
    with pytest.raises(ValueError, match="colormap must be one of"):
        colormap(np.zeros(3), "no_such_map")


def test_colorbar_has_tick_values_and_its_label():
    # Drawn by matplotlib: no renderer needed.
    plain = panel_mod._colorbar(800, 400, "viridis", -1.0, 1.0, None)
    labelled = panel_mod._colorbar(800, 400, "viridis", -1.0, 1.0, "relative error")
    assert plain.dtype == np.uint8 and plain.shape[1] == labelled.shape[1] == 800
    assert labelled.shape[0] > plain.shape[0]  # room for the label
    # The bar: viridis' ends at its left and right.
    dark = np.abs(labelled.astype(int) - [68, 1, 84]).sum(axis=2) < 30
    yellow = np.abs(labelled.astype(int) - [253, 231, 37]).sum(axis=2) < 30
    assert dark.any() and yellow.any()
    bar_rows = np.nonzero(dark.any(axis=1))[0]
    assert np.nonzero(dark.any(axis=0))[0].mean() < np.nonzero(yellow.any(axis=0))[0].mean()
    # Tick values: dark grey text pixels just below the bar, spread along it.
    below = labelled[bar_rows.max() + 2 :]
    text = (below.max(axis=2) < 110) & (np.ptp(below.astype(int), axis=2) < 30)
    assert text.sum() > 200
    cols = np.nonzero(text.any(axis=0))[0]
    assert cols.max() - cols.min() > 400  # labels at both ends of the bar
    # The label: text rows in the extra height the label added, centred.
    extra = labelled[plain.shape[0] - 4 :]
    label_text = (extra.max(axis=2) < 110).any(axis=0)
    assert label_text.sum() > 40
    centre = np.nonzero(label_text)[0].mean()
    assert abs(centre - 400) < 40


def test_render_shows_each_mesh_in_its_own_colors(tmp_path):
    V, F = icosphere(3)
    red, green = np.tile([0.9, 0.1, 0.1], (len(V), 1)), np.tile([0.1, 0.8, 0.2], (len(V), 1))
    points = V[::2]
    path = tmp_path / "panel.png"
    panel = _render_or_skip(
        render_panel,
        [(V, F, red), (V, F, green), (points, None, np.tile([0.1, 0.2, 0.9], (len(points), 1)))],
        path,
        titles=["Red", "Green", "Blue points"],
        width=200,
        height=160,
    )
    img = read_png(path)
    np.testing.assert_array_equal(img, panel)
    title_h = img.shape[0] - 160
    assert img.shape == (160 + title_h, 600, 3) and 0 < title_h < 40
    # Sample around each tile's centre (the sphere's middle): the lit color keeps its hue.
    for i, channel in enumerate((0, 1, 2)):
        patch = img[title_h + 70 : title_h + 90, 200 * i + 90 : 200 * i + 110].reshape(-1, 3)
        patch = patch[(patch < 250).any(axis=1)].astype(float)  # drawn pixels
        assert len(patch) > 20, i  # points cover less of the patch than a surface
        dominant = np.argmax(patch.mean(axis=0))
        assert dominant == channel, (i, patch.mean(axis=0))
    # Corners are background (white); the titles are dark pixels in the title band.
    assert (img[title_h + 2, 2] == 255).all()
    assert (img[:title_h] < 100).any()


def test_scalar_items_get_a_color_bar():
    V, F = icosphere(3)
    images = _render_or_skip(render_images, [(V, F, V[:, 1])], width=64, height=48)
    assert images[0].shape == (48, 64, 3) and images[0].dtype == np.uint8
    panel = _render_or_skip(
        render_panel, [(V, F, V[:, 1]), (V, F, None)], None, width=120, height=100,
        view=View(front=(1.0, 0.0, 0.0)), colorbar_label="height",
    )  # fmt: skip
    assert panel.shape[0] > 100 and panel.shape[1] == 240  # the bar adds rows
    bar = panel[100:]
    assert (np.abs(bar.astype(int) - [68, 1, 84]).sum(axis=2) < 20).any()  # viridis' dark end
    assert (bar.max(axis=2) < 110).sum() > 30  # tick values and the label


def test_each_tile_is_framed_on_its_own_shape():
    # A big shape first, then a tiny one, one far from the origin, one at the origin: every
    # tile shows its whole shape, centred, at the same size (one shared view would lose the
    # tiny and the far ones).
    V, F = icosphere(3)
    far, up_z = np.array([1000.0, 0.0, 0.0]), np.array([0.0, 0.0, 50.0])
    shapes = [V * 100.0, V * 1e-3, V + far, V, V * 1e-3 + up_z]
    w = h = 120
    tiles = _render_or_skip(render_images, [(S, F, None) for S in shapes], width=w, height=h)
    fractions = []
    for i, tile in enumerate(tiles):
        drawn = _drawn(tile)
        fractions.append(drawn.mean())
        ys, xs = np.nonzero(drawn)
        assert len(xs) > 0, f"tile {i}: nothing drawn"
        # Centred, and nothing cut at the border.
        assert abs(xs.mean() - (w - 1) / 2) < 2 and abs(ys.mean() - (h - 1) / 2) < 2, i
        assert xs.min() > 0 and ys.min() > 0 and xs.max() < w - 1 and ys.max() < h - 1, i
    # A sphere filling 90% of the tile's side covers about pi/4 * 0.9^2 = 0.64 of it.
    assert np.ptp(fractions) < 0.02, fractions
    assert 0.5 < np.mean(fractions) < 0.75, fractions


def test_wide_and_tall_tiles_fit_a_long_shape():
    V, F = icosphere(2)
    rod = V * [4.0, 0.5, 0.5]
    wide, tall = _render_or_skip(
        render_images, [(rod, F, None), (rod[:, [1, 0, 2]], F, None)], width=200, height=80
    )
    ys, xs = np.nonzero(_drawn(wide))
    assert xs.min() > 0 and xs.max() < 199 and xs.max() - xs.min() > 150  # fills the width
    ys, xs = np.nonzero(_drawn(tall))
    assert ys.min() > 0 and ys.max() < 79 and ys.max() - ys.min() > 60  # fills the height


def test_lighting_is_not_blown_out():
    V, F = icosphere(4)
    mid = np.full((len(V), 3), 0.5)
    light = np.full((len(V), 3), 0.8)
    tiles = _render_or_skip(render_images, [(V, F, mid), (V, F, light)], width=160, height=160)
    grey = tiles[0][_drawn(tiles[0])]
    assert 60 < np.median(grey) < 180, np.median(grey)  # mid grey stays mid grey
    # Inside the silhouette of the light-grey sphere nothing is saturated to white.
    yy, xx = np.mgrid[:160, :160]
    inside = (yy - 79.5) ** 2 + (xx - 79.5) ** 2 < (0.8 * 0.45 * 160) ** 2
    disc = tiles[1][inside]
    assert disc.max(axis=1).max() < 245, disc.max()
    assert np.percentile(disc, 99) < 235
    assert np.ptp(disc.mean(axis=1)) > 40  # shaded, not flat


def _quad_with_texture():
    V = np.array([[-1.0, -1.0, 0.0], [1.0, -1.0, 0.0], [1.0, 1.0, 0.0], [-1.0, 1.0, 0.0]])
    F = np.array([[0, 1, 2], [0, 2, 3]])
    uv = (V[F.reshape(-1), :2] + 1.0) / 2.0  # u along x, v along y (up)
    img = np.zeros((8, 8, 3), dtype=np.uint8)
    img[:4, :4] = [220, 30, 30]  # first rows: top of the image (v near 1); left: u near 0
    img[:4, 4:] = [30, 200, 30]
    img[4:, :4] = [30, 30, 220]
    img[4:, 4:] = [230, 220, 30]
    return V, F, uv, img


def test_textured_mesh_is_drawn_with_its_texture():
    V, F, uv, img = _quad_with_texture()
    (tile,) = _render_or_skip(
        render_images, [(V, F, None)], textures=[(uv, img)], width=120, height=120
    )
    q = 120 // 4  # quadrant centres of the (centred, 90%-wide) square
    expect = {(q, q): 0, (q, 3 * q): 1, (3 * q, q): 2}  # top left red, top right green, ...
    for (y, x), channel in expect.items():
        pix = tile[y - 3 : y + 3, x - 3 : x + 3].reshape(-1, 3).mean(axis=0)
        assert np.argmax(pix) == channel, ((y, x), pix)
    yellow = tile[3 * q - 3 : 3 * q + 3, 3 * q - 3 : 3 * q + 3].reshape(-1, 3).mean(axis=0)
    assert yellow[0] > 2 * yellow[2] and yellow[1] > 2 * yellow[2], yellow
    with pytest.raises(ValueError, match=r"texture uv must have shape \(3m, 2\)"):
        render_images([(V, F, None)], textures=[(uv[:-1], img)])
    with pytest.raises(ValueError, match="textures has 2 entries"):
        render_images([(V, F, None)], textures=[None, None])
    with pytest.raises(ValueError, match="needs a mesh"):
        render_images([(V, None, None)], textures=[(uv, img)])


def test_a_crashing_renderer_is_an_error_not_unavailable(tmp_path, monkeypatch):
    V, F = icosphere(1)
    fake = tmp_path / "fake_worker.py"
    for status, expected in ((1, RenderError), (3, RenderUnavailable), (4, RenderUnavailable)):
        fake.write_text(f"import sys\nsys.stderr.write('boom {status}\\n')\nsys.exit({status})\n")
        monkeypatch.setattr(panel_mod, "_WORKER", str(fake))
        with pytest.raises(expected) as info:
            render_images([(V, F, None)])
        assert (type(info.value) is RenderError) == (status == 1)
        if status == 1:
            assert "(exit status 1): boom 1" in str(info.value)


def test_timeout_and_bad_items():
    V, F = icosphere(1)
    with pytest.raises(RenderError, match="did not answer"):
        render_images([(V, F, None)], timeout=0.001)
    with pytest.raises(ValueError, match="items is empty"):
        render_images([])
    with pytest.raises(ValueError, match="width must be"):
        render_images([(V, F, None)], width=5)
    with pytest.raises(ValueError, match="index out of range"):
        render_images([(V, F + 100, None)])
    with pytest.raises(ValueError, match="parallel"):
        render_images([(V, F, None)], view=View(front=(0, 1, 0), up=(0, 2, 0)))
    with pytest.raises(ValueError, match="zoom"):
        render_images([(V, F, None)], view=View(zoom=0.0))
    with pytest.raises(ValueError, match="colormap must be one of"):
        render_panel([(V, F, V[:, 0])], cmap="no_such_map")
    with pytest.raises(ValueError, match="colors holds NaN"):  # said of the colors themselves
        render_panel([(V, F, np.full(len(V), np.nan))])


def _open3d_quad():
    import open3d as o3d

    V, F, uv, img = _quad_with_texture()
    mesh = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(V), o3d.utility.Vector3iVector(F))
    mesh.triangle_uvs = o3d.utility.Vector2dVector(uv)
    # Legacy textures are stored bottom-up (see o3d_ofp.boundary.texture): made from the
    # top-down array the way Open3D's own readers store a file's image.
    from o3d_ofp.boundary.texture import legacy_texture_image

    mesh.textures = [legacy_texture_image(img)]
    mesh.triangle_material_ids = o3d.utility.IntVector([0, 0])
    return mesh


def test_show_in_a_notebook_displays_inline(tmp_path, monkeypatch):
    import open3d as o3d

    shown = []
    kernel_shell = types.SimpleNamespace(kernel=object())
    ipython = types.ModuleType("IPython")
    ipython.get_ipython = lambda: kernel_shell
    display_mod = types.ModuleType("IPython.display")
    display_mod.Image = lambda data, format: ("image", format, data)
    display_mod.display = shown.append
    ipython.display = display_mod
    monkeypatch.setitem(sys.modules, "IPython", ipython)
    monkeypatch.setitem(sys.modules, "IPython.display", display_mod)
    monkeypatch.setenv("DISPLAY", ":0")  # a display, but a notebook shows inline
    monkeypatch.setattr(pick, "_x11_answers", lambda display: True)

    def no_window(*args, **kwargs):
        raise AssertionError("no window in a notebook")

    monkeypatch.setattr(o3d.visualization, "draw_geometries", no_window)
    monkeypatch.chdir(tmp_path)
    assert _render_or_skip(show, _open3d_quad(), width=120, height=120) is None
    assert list(tmp_path.iterdir()) == []  # nothing written
    (kind, fmt, data), = shown  # fmt: skip
    assert kind == "image" and fmt == "png" and data[:8] == b"\x89PNG\r\n\x1a\n"
    (tmp_path / "shown.png").write_bytes(data)
    img = read_png(tmp_path / "shown.png")
    assert img.shape == (120, 120, 3)
    assert np.argmax(img[30, 30]) == 0 and np.argmax(img[30, 90]) == 1  # the texture


def test_show_without_notebook(tmp_path, monkeypatch):
    import open3d as o3d

    monkeypatch.delitem(sys.modules, "IPython", raising=False)
    opened = []
    monkeypatch.setattr(o3d.visualization, "draw_geometries", lambda geoms: opened.append(geoms))
    monkeypatch.setenv("DISPLAY", ":0")
    monkeypatch.setattr(pick, "_x11_answers", lambda display: True)  # an X server answers
    mesh = _open3d_quad()
    assert show([mesh]) is None and len(opened) == 1  # a window
    monkeypatch.delenv("DISPLAY")
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    target = tmp_path / "view.png"
    path = _render_or_skip(
        show, [mesh, mesh], titles=["A", "B"], fallback_path=target, width=100, height=100
    )
    assert path == str(target) and len(opened) == 1
    assert read_png(target).shape[1] == 200
    rendered = []
    monkeypatch.setattr(panel_mod, "render_panel", lambda *a, **k: rendered.append(a))
    with pytest.raises(ValueError, match="written as PNG"):  # said before any rendering
        show([mesh], fallback_path=tmp_path / "view.jpg")
    assert not rendered and not (tmp_path / "view.jpg").exists()


def test_cli_render_draws_an_obj_with_its_own_texture(tmp_path, capsys):
    from PIL import Image

    from o3d_ofp.cli.main import main
    from o3d_ofp.render.panel import read_png

    # Written by hand, so the truth is the OBJ convention: the image file's first row at v = 1.
    _, _, _, img = _quad_with_texture()  # top-left red, top-right green, bottom-left blue
    Image.fromarray(img).resize((64, 64), Image.NEAREST).save(tmp_path / "quad.png")
    (tmp_path / "quad.mtl").write_text("newmtl m\nmap_Kd quad.png\n")
    (tmp_path / "quad.obj").write_text(
        "mtllib quad.mtl\nusemtl m\n"
        "v -1 -1 0\nv 1 -1 0\nv 1 1 0\nv -1 1 0\n"
        "vt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\n"
        "f 1/1 2/2 3/3\nf 1/1 3/3 4/4\n"
    )
    out = tmp_path / "panel.png"
    argv = ["render", str(tmp_path / "quad.obj"), "-o", str(out), "--width", "120",
            "--height", "120"]  # fmt: skip
    _cli_render_or_skip(main, argv, capsys)
    _assert_quad_texture(read_png(out).astype(int))


def _cli_render_or_skip(main, argv, capsys):
    # As _render_or_skip, for the command: only "this machine cannot render" skips.
    if main(argv) != 0:
        err = capsys.readouterr().err
        if "EGL" in err or "OpenGL" in err or "unavailable" in err.lower():
            pytest.skip(f"no EGL/OpenGL context on this machine: {err}")
        pytest.fail(err)


def _assert_quad_texture(panel):
    # Each texture color covers a large area (an untextured or averaged quad has none of them),
    # red above blue and left of green: the image is not drawn upside down or mirrored.
    masks = {
        "red": (panel[..., 0] > 150) & (panel[..., 1] < 90) & (panel[..., 2] < 90),
        "green": (panel[..., 1] > 150) & (panel[..., 0] < 90) & (panel[..., 2] < 90),
        "blue": (panel[..., 2] > 150) & (panel[..., 0] < 90) & (panel[..., 1] < 90),
    }
    centre = {}
    for name, mask in masks.items():
        assert mask.sum() > 0.05 * 120 * 120, name
        ys, xs = np.nonzero(mask)
        centre[name] = (ys.mean(), xs.mean())
    assert centre["red"][0] < centre["blue"][0] - 20
    assert centre["red"][1] < centre["green"][1] - 20


def test_cli_render_takes_a_texture_its_material_does_not_name(tmp_path, capsys, caplog):
    """``--textures IMAGE`` draws a mesh whose OBJ names no image; without it, a warning.

    A trial: ``render`` had no way to show the data's Spot (UVs, no material), and drew it
    grey without a word, as it did a material naming a missing image.
    """
    import logging

    from PIL import Image

    from o3d_ofp.boundary.io import read_geometry
    from o3d_ofp.cli.main import main
    from o3d_ofp.cli.render import _say_missing_texture

    _, _, _, img = _quad_with_texture()
    Image.fromarray(img).resize((64, 64), Image.NEAREST).save(tmp_path / "quad.png")
    obj = tmp_path / "quad.obj"
    obj.write_text("v -1 -1 0\nv 1 -1 0\nv 1 1 0\nv -1 1 0\n"
                   "vt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\nf 1/1 2/2 3/3\nf 1/1 3/3 4/4\n")  # fmt: skip
    with caplog.at_level(logging.WARNING, logger="o3d_ofp.cli.render"):
        _say_missing_texture(read_geometry(obj), str(obj))
    assert "has texture coordinates but no texture image came with it" in caplog.text
    named = tmp_path / "named.obj"
    (tmp_path / "named.mtl").write_text("newmtl m\nmap_Kd gone.png\n")
    named.write_text("mtllib named.mtl\nusemtl m\n" + obj.read_text())
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="o3d_ofp.cli.render"):
        _say_missing_texture(read_geometry(named), str(named))
    assert "the files its material names are not there (gone.png)" in caplog.text
    out = tmp_path / "panel.png"
    base = ["render", str(obj), "-o", str(out), "--width", "120", "--height", "120"]
    assert main([*base, "--textures", str(tmp_path / "nosuch.png")]) == 2
    assert "--textures" in capsys.readouterr().err and not out.exists()
    _cli_render_or_skip(main, [*base, "--textures", str(tmp_path / "quad.png")], capsys)
    _assert_quad_texture(read_png(out).astype(int))


def test_render_items_take_open3d_geometries_and_8_bit_colors_and_refuse_0_255_floats(tmp_path):
    """Open3D geometries are drawn as ``show()`` draws them; 0-255 float colors are refused.

    A trial: ``render_panel([mesh])`` failed with "Value after * must be an iterable",
    0-255 colors were drawn white, and ``render_panel(items, "x.jpg")`` wrote PNG bytes.
    """
    import open3d as o3d

    V, F = icosphere(1)
    C = np.linspace(0.0, 1.0, 3 * len(V)).reshape(-1, 3)
    mesh = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(V), o3d.utility.Vector3iVector(F))
    mesh.vertex_colors = o3d.utility.Vector3dVector(C)
    (item,) = panel_mod._items([mesh], None)
    assert np.allclose(item["v"], V) and np.array_equal(item["f"], F) and np.allclose(item["c"], C)
    (quad,) = panel_mod._items([_open3d_quad()], None)
    assert "tex" in quad  # its own texture
    eight = (C * 255).round().astype(np.uint8)
    (item,) = panel_mod._items([(V, F, eight)], None)
    assert np.allclose(item["c"], C, atol=0.5 / 255)
    with pytest.raises(ValueError, match=r"up to 255: RGB colors are in \[0, 1\]"):
        render_panel([(V, F, C * 255)])
    with pytest.raises(TypeError, match=r"items\[0\] must be \(vertices, faces, colors\) or an"):
        render_panel([V])
    with pytest.raises(TypeError, match="3 entries"):
        render_panel([(V, F)])
    with pytest.raises(ValueError, match="written as PNG"):
        render_panel([(V, F, None)], tmp_path / "x.jpg")
    assert not (tmp_path / "x.jpg").exists()


def test_cli_render_refuses_nan_scalars_before_rendering(tmp_path, capsys):
    """``--scalars`` holding NaN is refused naming the file, before any rendering.

    A trial: "colors holds NaN or inf values", without the file, after rendering started.
    """
    from o3d_ofp.boundary.convert import triangle_mesh_from_arrays
    from o3d_ofp.boundary.io import write_geometry
    from o3d_ofp.cli.main import main

    V, F = icosphere(1)
    mesh = tmp_path / "m.ply"
    write_geometry(mesh, triangle_mesh_from_arrays(V, F))
    values = np.zeros(len(V))
    values[3] = np.nan
    npy = tmp_path / "s.npy"
    np.save(npy, values)
    out = tmp_path / "p.png"
    assert main(["render", str(mesh), "--scalars", str(npy), "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert f"--scalars {npy}: holds NaN or inf" in err and "rendering" not in err
    assert not out.exists()
