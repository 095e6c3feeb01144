"""Render worker, run as ``python -m o3d_ofp._render_worker IN.npz OUT.npz`` by :mod:`.render`.

A separate interpreter: Open3D's hidden-window ``Visualizer`` may crash the process when no
OpenGL/EGL context exists, and that must not take the caller down. Exit status 0: images
written to OUT.npz; 3: no OpenGL context; anything else: a crash.
"""

from __future__ import annotations

import sys

import numpy as np

NO_CONTEXT = 3


def render(inp: str, out: str) -> int:
    """Render the items of ``inp`` into ``out``; return the exit status."""
    from .adapters import require_open3d

    o3d = require_open3d()
    data = np.load(inp, allow_pickle=False)
    count = int(data["count"])
    width, height = int(data["width"]), int(data["height"])
    front, up, zoom = data["front"], data["up"], float(data["zoom"])
    vis = o3d.visualization.Visualizer()
    if not vis.create_window(visible=False, width=width, height=height):
        return NO_CONTEXT
    opt = vis.get_render_option()
    opt.background_color = np.array([1.0, 1.0, 1.0])
    opt.mesh_show_back_face = True
    opt.light_on = True
    opt.point_size = 3.0
    images = {}
    for i in range(count):
        V, C = data[f"v{i}"], data[f"c{i}"]
        F = data[f"f{i}"] if f"f{i}" in data else None
        if F is None:
            geom = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(V))
            geom.colors = o3d.utility.Vector3dVector(C)
        else:
            geom = o3d.geometry.TriangleMesh(
                o3d.utility.Vector3dVector(V), o3d.utility.Vector3iVector(F.astype(np.int32))
            )
            geom.vertex_colors = o3d.utility.Vector3dVector(C)
            geom.compute_vertex_normals()
        vis.clear_geometries()
        vis.add_geometry(geom, reset_bounding_box=True)
        ctrl = vis.get_view_control()
        ctrl.set_front(front.tolist())
        ctrl.set_up(up.tolist())
        ctrl.set_lookat((0.5 * (V.min(axis=0) + V.max(axis=0))).tolist())
        ctrl.set_zoom(zoom)
        buf = np.asarray(vis.capture_screen_float_buffer(do_render=True))
        images[f"img{i}"] = (np.clip(buf, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)
    vis.destroy_window()
    np.savez(out, **images)
    return 0


if __name__ == "__main__":
    sys.exit(render(sys.argv[1], sys.argv[2]))
