"""Render worker, run as ``python .../o3d_ofp/render/_worker.py IN.npz OUT.npz`` by :mod:`.panel`.

A separate interpreter: Open3D's hidden-window ``Visualizer`` may crash the process when no
OpenGL/EGL context exists, and that must not take the caller down. The file is run by path,
not as ``-m o3d_ofp...``, so that the child imports only NumPy and Open3D (not the package and
SciPy): it must not import anything from the package at module level.

Exit status 0: images written to OUT.npz; 3: no OpenGL context; 4: Open3D cannot be imported;
anything else: a crash.

Each tile gets its own view: one hidden window is reused, but after the tile's geometry is added
the view is reset to that geometry's bounding box alone (``add_geometry(reset_bounding_box=True)``
after ``clear_geometries`` *grows* the previous box instead, so a shape far from an earlier one
would fall outside the clipping range) and the camera is placed by :func:`fit_camera` so that every
vertex projects inside the tile, whatever the shape's position and size.
"""

from __future__ import annotations

import json
import math
import os
import sys
from typing import Any

import numpy as np

NO_CONTEXT = 3
NO_OPEN3D = 4

#: Lights of Open3D's Phong shader (white, shininess 30): position relative to the view (right,
#: up, front) in units of the shape's largest extent from its centre, diffuse and specular power.
#: Open3D's defaults (two head-on lights with diffuse power 0.66 each plus specular 0.2 each, no
#: ambient) push anything lighter than mid grey to white; these add up to about 1 where a
#: surface faces the key light.
LIGHTS = (
    ([-1.0, 1.2, 2.0], 0.62, 0.06),  # key: upper left, in front
    ([1.5, -0.3, 1.5], 0.2, 0.0),  # fill: right, slightly below
    # two from behind, for the inside of open surfaces (back faces are drawn)
    ([0.0, 1.0, -2.0], 0.35, 0.0),
    ([0.0, -1.0, -2.0], 0.25, 0.0),
)
AMBIENT = 0.3


def fit_camera(
    vertices: np.ndarray, front: Any, up: Any, *, aspect: float, fill: float, fov_deg: float = 60.0
) -> tuple[np.ndarray, np.ndarray, float]:
    """Place a perspective camera so that every vertex is seen inside the image.

    Parameters
    ----------
    vertices : (n, 3) ndarray
        The points to frame.
    front, up : (3,) array_like
        Direction from the shape towards the camera, and the screen's up (made orthogonal to
        ``front``).
    aspect : float
        Image width / height.
    fill : float
        Fraction of the image's half-width / half-height the shape may use (0.9: a 5% margin on
        each side where the shape is widest).
    fov_deg : float, default 60
        Vertical field of view.

    Returns
    -------
    lookat : (3,) ndarray
        Point at the image centre.
    up : (3,) ndarray
        Unit up vector orthogonal to ``front``.
    distance : float
        Camera distance from ``lookat`` along ``front``.
    """
    P = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(front, dtype=np.float64) / np.linalg.norm(front)
    u = np.asarray(up, dtype=np.float64)
    u = u - f * (u @ f)
    u = u / np.linalg.norm(u)
    r = np.cross(u, f)
    lo, hi = P.min(axis=0), P.max(axis=0)
    extent = float(np.max(hi - lo))
    if extent <= 0.0 or not math.isfinite(extent):
        extent = max(1.0, float(np.abs(lo).max()) * 1e-6)
    center = 0.5 * (lo + hi)
    Q = P - center
    x, y, z = Q @ r, Q @ u, Q @ f
    ty = math.tan(math.radians(fov_deg) / 2.0) * fill
    tx = ty * aspect
    # Centre the orthographic outline first, then refine for perspective (points nearer the
    # camera look bigger): shift the look-at point in the image plane by the projected offset.
    # Four refinements, then the distance for the final look-at point.
    cx, cy = 0.5 * (x.max() + x.min()), 0.5 * (y.max() + y.min())
    for step in range(5):
        xs, ys = x - cx, y - cy
        dist = float(max(np.max(z + np.abs(xs) / tx), np.max(z + np.abs(ys) / ty)))
        dist = max(dist, float(z.max()) + 0.05 * extent)
        if step < 4:
            sx, sy = xs / (dist - z), ys / (dist - z)
            cx += 0.5 * (sx.max() + sx.min()) * dist
            cy += 0.5 * (sy.max() + sy.min()) * dist
    return center + cx * r + cy * u, u, dist


def _lighting(vis: Any, scratch: str) -> None:
    # Open3D takes its lights only from a JSON file: its own options, with ours written in.
    opt = vis.get_render_option()
    path = os.path.join(scratch, "render_option.json")
    opt.save_to_json(path)
    with open(path) as fh:
        cfg = json.load(fh)
    cfg.update(background_color=[1.0] * 3, light_on=True, light_ambient_color=[AMBIENT] * 3)
    cfg.update(mesh_show_back_face=True, mesh_shade_option=1)  # 1: smooth shading; 0 is flat
    for i, (position, diffuse, specular) in enumerate(LIGHTS):
        keys = ("position", "color", "diffuse_power", "specular_power", "specular_shininess")
        for key, value in zip(keys, (position, [1.0] * 3, diffuse, specular, 30.0), strict=True):
            cfg[f"light{i}_{key}"] = value
    with open(path, "w") as fh:
        json.dump(cfg, fh)
    opt.load_from_json(path)


def _geometry(o3d: Any, data: Any, i: int) -> Any:
    V, C = data[f"v{i}"], data[f"c{i}"]
    if f"f{i}" not in data:
        geom = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(V))
        geom.colors = o3d.utility.Vector3dVector(C)
        return geom
    F = data[f"f{i}"].astype(np.int32)
    geom = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(V), o3d.utility.Vector3iVector(F))
    geom.vertex_colors = o3d.utility.Vector3dVector(C)
    if f"tex{i}" in data:
        uv = data[f"uv{i}"] * [1.0, -1.0] + [0.0, 1.0]  # ours: v up (OBJ); Open3D: v down rows
        geom.triangle_uvs = o3d.utility.Vector2dVector(uv)
        geom.textures = [o3d.geometry.Image(data[f"tex{i}"])]
        geom.triangle_material_ids = o3d.utility.IntVector(np.zeros(F.shape[0], dtype=np.int32))
    geom.compute_vertex_normals()
    return geom


def _frame(vis: Any, V: np.ndarray, front: Any, up: Any, aspect: float, fill: float) -> None:
    """Check that the view's box is ``V``'s alone, then place the camera by :func:`fit_camera`."""
    lo, hi = V.min(axis=0), V.max(axis=0)
    extent = float(np.max(hi - lo))
    box = json.loads(vis.get_view_status())["trajectory"][0]
    got = np.array([box["boundingbox_min"], box["boundingbox_max"]])
    if np.max(np.abs(got - [lo, hi])) > 1e-6 * max(extent, 1e-300) + 1e-12:
        raise RuntimeError(f"the view's bounding box {got[0]}..{got[1]} is not the tile's shape's")
    # The view control is fetched and dropped here: a Python handle on it that outlives the
    # next Open3D call on the window breaks later renders.
    ctrl = vis.get_view_control()
    fov = ctrl.get_field_of_view()
    lookat, up_vec, dist = fit_camera(V, front, up, aspect=aspect, fill=fill, fov_deg=fov)
    ctrl.set_front((front / np.linalg.norm(front)).tolist())
    ctrl.set_up(up_vec.tolist())
    ctrl.set_lookat(lookat.tolist())
    # Open3D: distance = zoom * (largest extent of the view's box) / tan(fov / 2).
    ctrl.set_zoom(dist * math.tan(math.radians(fov) / 2.0) / (extent or 1.0))


def render(inp: str, out: str) -> int:
    """Render the items of ``inp`` into ``out``; return the exit status."""
    try:
        import open3d as o3d
    except ImportError as exc:
        sys.stderr.write(f"open3d cannot be imported: {exc}\n")
        return NO_OPEN3D
    with np.load(inp, allow_pickle=False) as npz:
        data = {k: npz[k] for k in npz.files}
    width, height = int(data["width"]), int(data["height"])
    # Rendered at twice the size and box-filtered down (smooth edges), up to 3200 x 3200 pixels.
    ss = 2 if max(width, height) <= 1600 else 1
    vis = o3d.visualization.Visualizer()
    if not vis.create_window(visible=False, width=width * ss, height=height * ss):
        return NO_CONTEXT
    try:
        _lighting(vis, os.path.dirname(os.path.abspath(out)))
        vis.get_render_option().point_size = float(data["point_size"]) * ss
        images = {}
        for i in range(int(data["count"])):
            vis.clear_geometries()
            vis.add_geometry(_geometry(o3d, data, i), reset_bounding_box=True)
            vis.reset_view_point(True)  # the box of this geometry alone
            _frame(vis, data[f"v{i}"], data["front"], data["up"], width / height, data["fill"])
            buf = np.asarray(vis.capture_screen_float_buffer(do_render=True), dtype=np.float32)
            buf = buf.reshape(height, ss, width, ss, 3).mean(axis=(1, 3))
            images[f"img{i}"] = (np.clip(buf, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)
    finally:
        vis.destroy_window()
    np.savez(out, **images)
    return 0


if __name__ == "__main__":
    sys.exit(render(sys.argv[1], sys.argv[2]))
