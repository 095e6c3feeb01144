"""Headless rendering: PNG size, non-blank, the mesh's colors at the right pixels."""

from __future__ import annotations

import numpy as np
import pytest

from o3d_ofp.render import (
    RenderError,
    View,
    colormap,
    read_png,
    render_images,
    render_panel,
    write_png,
)
from o3d_ofp.shapes import icosphere

pytest.importorskip("open3d", reason="rendering uses Open3D's legacy Visualizer")


def _render_or_skip(fn, *args, **kwargs):
    try:
        return fn(*args, **kwargs)
    except RenderError as exc:
        pytest.skip(f"no EGL/OpenGL context on this machine: {exc}")


def test_png_round_trip(tmp_path):
    rng = np.random.default_rng(0)
    img = rng.integers(0, 256, (17, 23, 3), dtype=np.uint8)
    write_png(tmp_path / "a.png", img)
    np.testing.assert_array_equal(read_png(tmp_path / "a.png"), img)
    grey = img[:, :, 0]
    write_png(tmp_path / "g.png", grey)
    np.testing.assert_array_equal(read_png(tmp_path / "g.png"), grey)
    with pytest.raises(ValueError, match="uint8"):
        write_png(tmp_path / "b.png", img.astype(float))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.png", "g.png"]


def test_colormap_ends_and_range():
    c = colormap(np.array([0.0, 0.5, 1.0]))
    np.testing.assert_allclose(c[0], [0.267, 0.005, 0.329])  # viridis ends
    np.testing.assert_allclose(c[2], [0.993, 0.906, 0.144])
    np.testing.assert_allclose(colormap(np.array([5.0, 5.0])), colormap(np.array([0.5]))[[0, 0]])
    clipped = colormap(np.array([-1.0, 2.0]), vmin=0.0, vmax=1.0)
    np.testing.assert_allclose(clipped, colormap(np.array([0.0, 1.0])))
    with pytest.raises(ValueError, match="colormap must be one of"):
        colormap(np.zeros(3), "jet")


def test_render_shows_each_mesh_in_its_own_colors(tmp_path):
    V, F = icosphere(3)
    red, green = np.tile([0.9, 0.1, 0.1], (len(V), 1)), np.tile([0.1, 0.8, 0.2], (len(V), 1))
    points = V[::2]
    path = tmp_path / "panel.png"
    panel = _render_or_skip(
        render_panel,
        [(V, F, red), (V, F, green), (points, None, np.tile([0.1, 0.2, 0.9], (len(points), 1)))],
        path,
        titles=["red", "green", "blue points"],
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


def test_scalar_items_get_a_color_bar(tmp_path):
    V, F = icosphere(3)
    images = _render_or_skip(render_images, [(V, F, V[:, 1])], width=64, height=48)
    assert images[0].shape == (48, 64, 3) and images[0].dtype == np.uint8
    panel = _render_or_skip(
        render_panel, [(V, F, V[:, 1]), (V, F, None)], None, width=120, height=100,
        view=View(front=(1.0, 0.0, 0.0)),
    )  # fmt: skip
    assert panel.shape[0] > 100 and panel.shape[1] == 240  # the bar adds rows
    bar = panel[100:]
    assert (np.abs(bar.astype(int) - [68, 1, 84]).sum(axis=2) < 20).any()  # viridis' dark end


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
