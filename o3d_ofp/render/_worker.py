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
fell outside the clipping range) and the camera is placed by :func:`fit_camera` so that every
vertex projects inside the tile, whatever the shape's position and size.
"""

from __future__ import annotations

import json
import logging
import math
import os
import sys
from typing import Any

import numpy as np

NO_CONTEXT = 3
NO_OPEN3D = 4

logger = logging.getLogger(__name__)

#: Lights of Open3D's Phong shader, positions relative to the view (right, up, front) in units of
#: the shape's largest extent from its centre. Open3D's defaults (two head-on lights with diffuse
#: power 0.66 each plus specular 0.2 each, no ambient) push anything lighter than mid grey to
#: white; these add up to about 1 where a surface faces the key light.
LIGHTS: tuple[dict[str, Any], ...] = (
    # key: upper left, in front
    {"position": [-1.0, 1.2, 2.0], "diffuse": 0.62, "specular": 0.06, "shininess": 30.0},
    # fill: right, slightly below
    {"position": [1.5, -0.3, 1.5], "diffuse": 0.2, "specular": 0.0, "shininess": 30.0},
    # two from behind, for the inside of open surfaces (back faces are drawn)
    {"position": [0.0, 1.0, -2.0], "diffuse": 0.35, "specular": 0.0, "shininess": 30.0},
    {"position": [0.0, -1.0, -2.0], "diffuse": 0.25, "specular": 0.0, "shininess": 30.0},
)
AMBIENT = 0.3


def fit_camera(
    vertices: np.ndarray,
    front: Any,
    up: Any,
    *,
    aspect: float,
    fill: float,
    fov_deg: float = 60.0,
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
    f = np.asarray(front, dtype=np.float64)
    f = f / np.linalg.norm(f)
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
    cx, cy = 0.5 * (x.max() + x.min()), 0.5 * (y.max() + y.min())
    dist = 0.0
    for _ in range(4):
        xs, ys = x - cx, y - cy
        dist = float(max(np.max(z + np.abs(xs) / tx), np.max(z + np.abs(ys) / ty)))
        dist = max(dist, float(z.max()) + 0.05 * extent)
        depth = dist - z
        sx, sy = xs / depth, ys / depth
        cx += 0.5 * (sx.max() + sx.min()) * dist
        cy += 0.5 * (sy.max() + sy.min()) * dist
    xs, ys = x - cx, y - cy
    dist = float(max(np.max(z + np.abs(xs) / tx), np.max(z + np.abs(ys) / ty)))
    dist = max(dist, float(z.max()) + 0.05 * extent)
    return center + cx * r + cy * u, u, dist


def _lighting(vis: Any, scratch: str) -> None:
    opt = vis.get_render_option()
    path = os.path.join(scratch, "render_option.json")
    opt.save_to_json(path)
    with open(path) as fh:
        cfg = json.load(fh)
    cfg["light_ambient_color"] = [AMBIENT] * 3
    cfg["mesh_shade_option"] = 1  # smooth (Gouraud) shading; 0, the default, is flat
    for i, light in enumerate(LIGHTS):
        cfg[f"light{i}_position"] = light["position"]
        cfg[f"light{i}_color"] = [1.0, 1.0, 1.0]
        cfg[f"light{i}_diffuse_power"] = light["diffuse"]
        cfg[f"light{i}_specular_power"] = light["specular"]
        cfg[f"light{i}_specular_shininess"] = light["shininess"]
    with open(path, "w") as fh:
        json.dump(cfg, fh)
    opt.load_from_json(path)
    opt.background_color = np.array([1.0, 1.0, 1.0])
    opt.mesh_show_back_face = True
    opt.light_on = True


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
        uv = np.array(data[f"uv{i}"], dtype=np.float64)
        uv[:, 1] = 1.0 - uv[:, 1]  # ours: v up (OBJ); Open3D's shader: v down the image rows
        geom.triangle_uvs = o3d.utility.Vector2dVector(uv)
        geom.textures = [o3d.geometry.Image(np.ascontiguousarray(data[f"tex{i}"]))]
        geom.triangle_material_ids = o3d.utility.IntVector(np.zeros(F.shape[0], dtype=np.int32))
    geom.compute_vertex_normals()
    return geom


def _set_camera(vis: Any, V: np.ndarray, front: Any, up: Any, aspect: float, fill: float) -> None:
    # The view control is fetched and dropped here: a Python handle on it that outlives the
    # next Open3D call on the window was seen to break later renders.
    ctrl = vis.get_view_control()
    lookat, up_vec, dist = fit_camera(
        V, front, up, aspect=aspect, fill=fill, fov_deg=ctrl.get_field_of_view()
    )
    extent = float(np.max(V.max(axis=0) - V.min(axis=0)))
    if extent <= 0.0:
        extent = 1.0
    f = np.asarray(front, dtype=np.float64)
    ctrl.set_front((f / np.linalg.norm(f)).tolist())
    ctrl.set_up(up_vec.tolist())
    ctrl.set_lookat(lookat.tolist())
    # Open3D: distance = zoom * (largest extent of the view's box) / tan(fov / 2).
    ctrl.set_zoom(dist * math.tan(math.radians(ctrl.get_field_of_view()) / 2.0) / extent)


def _check_box(vis: Any, V: np.ndarray) -> None:
    status = json.loads(vis.get_view_status())["trajectory"][0]
    lo, hi = np.array(status["boundingbox_min"]), np.array(status["boundingbox_max"])
    scale = max(float(np.max(V.max(axis=0) - V.min(axis=0))), 1e-300)
    if (
        np.max(np.abs(lo - V.min(axis=0))) > 1e-6 * scale + 1e-12
        or np.max(np.abs(hi - V.max(axis=0))) > 1e-6 * scale + 1e-12
    ):
        raise RuntimeError(f"the view's bounding box {lo}..{hi} is not the tile's geometry's")


def render(inp: str, out: str) -> int:
    """Render the items of ``inp`` into ``out``; return the exit status."""
    try:
        import open3d as o3d
    except ImportError as exc:
        sys.stderr.write(f"open3d cannot be imported: {exc}\n")
        return NO_OPEN3D
    with np.load(inp, allow_pickle=False) as npz:
        data = {k: npz[k] for k in npz.files}
    count = int(data["count"])
    width, height, ss = int(data["width"]), int(data["height"]), int(data["supersample"])
    front, up = data["front"], data["up"]
    fill, point_size = float(data["fill"]), float(data["point_size"])
    vis = o3d.visualization.Visualizer()
    if not vis.create_window(visible=False, width=width * ss, height=height * ss):
        return NO_CONTEXT
    try:
        _lighting(vis, os.path.dirname(os.path.abspath(out)))
        vis.get_render_option().point_size = point_size * ss
        images = {}
        for i in range(count):
            V = data[f"v{i}"]
            vis.clear_geometries()
            vis.add_geometry(_geometry(o3d, data, i), reset_bounding_box=True)
            vis.reset_view_point(True)  # the box of this geometry alone
            _check_box(vis, V)
            _set_camera(vis, V, front, up, width / height, fill)
            buf = np.asarray(vis.capture_screen_float_buffer(do_render=True), dtype=np.float32)
            if ss > 1:  # box-filter the supersampled image: smooth edges
                buf = buf.reshape(height, ss, width, ss, 3).mean(axis=(1, 3))
            images[f"img{i}"] = (np.clip(buf, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)
    finally:
        vis.destroy_window()
    np.savez(out, **images)
    return 0


if __name__ == "__main__":
    sys.exit(render(sys.argv[1], sys.argv[2]))
