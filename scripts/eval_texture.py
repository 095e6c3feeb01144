"""Texture transfer onto a differently meshed target with its own UVs: errors and pictures.

    python scripts/eval_texture.py [--size 1024] [--out docs]

Source: Spot (../shared/data/models), read by Open3D with its material and texture. Target:
Spot welded, decimated to 3000 triangles and given its own UV atlas (Open3D's UVAtlas), in
the same pose, so the true map is the closest source surface point. For each map (the true
surface map, its vertex-to-vertex version, and a map estimated by ``ofp.match``), the color
error of the baked texture (mean absolute difference per channel at 30 000 random target
surface points, against the source texture at the true corresponding point), of the UV
pull-back, and of the best any per-vertex coloring can do (the truth at the target's vertices,
interpolated over the triangles). Writes ``texture_transfer.png`` (source, target, per-vertex
best, baked result, and the baked result's error) into ``--out``.
"""

from __future__ import annotations

import argparse
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

import o3d_ofp as ofp
from o3d_ofp.boundary.bake import _Surface, source_colors_at, texture_error
from o3d_ofp.workflows.maps import Correspondence

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"


def spot(folder: Path):
    import open3d as o3d

    shutil.copy(DATA / "models/spot_texture.png", folder / "spot_texture.png")
    (folder / "spot.mtl").write_text("newmtl spot\nmap_Kd spot_texture.png\n")
    obj = (DATA / "models/spot_triangulated.obj").read_text()
    (folder / "spot.obj").write_text("mtllib spot.mtl\nusemtl spot\n" + obj)
    return o3d.io.read_triangle_mesh(str(folder / "spot.obj"))


def remeshed(mesh, triangles: int = 3000):
    import open3d as o3d

    welded = o3d.geometry.TriangleMesh(mesh.vertices, mesh.triangles)
    welded.remove_duplicated_vertices()
    small = o3d.t.geometry.TriangleMesh.from_legacy(welded.simplify_quadric_decimation(triangles))
    small.compute_uvatlas(size=1024, parallel_partitions=4)
    return small.to_legacy()


def surface_map(source, target) -> Correspondence:
    V1, F1 = np.asarray(source.vertices), np.asarray(source.triangles)
    tri, bary, _ = _Surface(V1, F1).closest(np.asarray(target.vertices))
    return Correspondence(
        p2p_21=F1[tri, np.argmax(bary, axis=1)],
        n_source=len(V1),
        faces_21=tri,
        barycentric_21=bary,
        method="closest",
    )


def per_vertex_best(source, target):
    import open3d as o3d

    best = o3d.geometry.TriangleMesh(target)
    best.vertex_colors = o3d.utility.Vector3dVector(
        source_colors_at(source, np.asarray(target.vertices))
    )
    return best


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--size", type=int, default=1024)
    parser.add_argument("--out", default=str(Path(__file__).resolve().parents[1] / "docs"))
    args = parser.parse_args(argv)
    if not DATA.is_dir():
        sys.stderr.write(f"needs the shared data at {DATA}\n")
        return 2
    with tempfile.TemporaryDirectory() as tmp:
        source = spot(Path(tmp))
        target = remeshed(source)
        best = per_vertex_best(source, target)
        e_best = texture_error(best, source, colors="vertex", samples=30000)
        true = surface_map(source, target)
        maps = {
            "true surface map": true,
            "true vertex map": Correspondence(p2p_21=true.p2p_21, n_source=true.n_source),
        }
        t0 = time.perf_counter()
        maps["estimated (ofp.match)"] = ofp.match(source, target)
        t_match = time.perf_counter() - t0
        print(
            f"Spot {len(source.vertices)} v -> remeshed {len(target.vertices)} v with its own "
            f"UV atlas; texture {args.size} px; estimated map in {t_match:.1f} s"
        )
        print("| map | baked | UV pull-back | best per-vertex | baked / per-vertex | bake s |")
        print("|---|---|---|---|---|---|")
        for name, corr in maps.items():
            t0 = time.perf_counter()
            baked = ofp.transfer_texture(source, target, correspondence=corr, size=args.size)
            seconds = time.perf_counter() - t0
            pulled = ofp.texture_pullback(source, target, correspondence=corr)
            e_bake = texture_error(baked, source, samples=30000)
            e_pull = texture_error(pulled, source, samples=30000)
            print(
                f"| {name} | {e_bake:.4f} | {e_pull:.4f} | {e_best:.4f} | "
                f"{e_bake / e_best:.2f} | {seconds:.1f} |"
            )
        out = Path(args.out)
        out.mkdir(parents=True, exist_ok=True)
        render(source, target, best, maps["estimated (ofp.match)"], out / "texture_transfer.png")
    return 0


def render(source, target, best, corr, path: Path) -> None:
    from o3d_ofp.boundary.texture import corner_uvs, mesh_texture
    from o3d_ofp.render.panel import View, render_panel

    baked = ofp.transfer_texture(source, target, correspondence=corr, size=1024)
    items, textures, titles = [], [], []
    for mesh, title in ((source, "source (UV texture)"), (baked, "result: baked texture")):
        V, F = np.asarray(mesh.vertices), np.asarray(mesh.triangles)
        tex = mesh_texture(mesh)
        items.append((V, F, None))
        image = next(im for im in tex.images if im.size)  # the legacy reader adds an empty one
        textures.append((corner_uvs(mesh).reshape(-1, 2), image))
        titles.append(title)
    Vt, Ft = np.asarray(target.vertices), np.asarray(target.triangles)
    items.insert(1, (Vt, Ft, np.full((len(Vt), 3), 0.75)))
    textures.insert(1, None)
    titles.insert(1, f"target ({len(Vt)} v, own UVs)")
    items.insert(2, (Vt, Ft, np.asarray(best.vertex_colors)))
    textures.insert(2, None)
    titles.insert(2, "best per-vertex colors")
    render_panel(
        items,
        path,
        titles=titles,
        textures=textures,
        view=View(front=(0.8, 0.35, -1.0)),
    )
    print(f"wrote {path}")


if __name__ == "__main__":
    raise SystemExit(main())
