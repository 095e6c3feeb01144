"""Aligned shapes: a dense scan onto its decimated copy by closest surface points.

    python scripts/bench_closest.py [--source-level 3] [--target 10000] [--check 2000]

The source is FAUST tr_reg_093 midpoint-subdivided ``--source-level`` times (3: 440k
vertices, 880k triangles); the target is a remeshed copy: the original Loop-subdivided once
(its vertices leave the source's flat triangles) and decimated by Open3D's quadric
decimation to about ``--target`` vertices (same coordinates, another triangulation). Rows:

- ``ofp.match(method="closest")``: seconds, peak memory (resident set sampled every 5 ms),
  the mean distance of the matched surface points to their target vertices (relative to the
  source's bounding-box diagonal), and its largest difference from the exact nearest-point
  distance, computed for ``--check`` random target vertices by brute force over every source
  triangle (numpy, the textbook closest-point-on-triangle regions);
- the same after a small rigid motion with ``align=True`` (ICP pre-alignment): the distance
  must come back to the aligned one;
- the baseline users write by hand: a k-d tree to the nearest source *vertex*
  (``scipy.spatial.cKDTree``), timed in the same run.

The load average is printed: the seconds are evidence only on a quiet machine.
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

import numpy as np

import o3d_ofp as ofp

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from bench_match import Peak

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"


def closest_on_triangles(p: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Closest points of the triangles (a, b, c) (m, 3) to one point p (3,): (m, 3).

    The Voronoi-region case analysis of Ericson, "Real-Time Collision Detection", 5.1.5,
    written independently of the library's version (which this checks).
    """
    ab, ac, ap = b - a, c - a, p - a
    d1, d2 = np.einsum("ij,ij->i", ab, ap), np.einsum("ij,ij->i", ac, ap)
    bp = p - b
    d3, d4 = np.einsum("ij,ij->i", ab, bp), np.einsum("ij,ij->i", ac, bp)
    cp = p - c
    d5, d6 = np.einsum("ij,ij->i", ab, cp), np.einsum("ij,ij->i", ac, cp)
    va, vb, vc = d3 * d6 - d5 * d4, d5 * d2 - d1 * d6, d1 * d4 - d3 * d2
    with np.errstate(divide="ignore", invalid="ignore"):
        denom = va + vb + vc
        v, w = vb / denom, vc / denom
        out = a + ab * v[:, None] + ac * w[:, None]  # inside the face
        t_ab = d1 / (d1 - d3)
        t_ac = d2 / (d2 - d6)
        t_bc = (d4 - d3) / ((d4 - d3) + (d5 - d6))
    cases = [
        ((d1 <= 0) & (d2 <= 0), a),
        ((d3 >= 0) & (d4 <= d3), b),
        ((d6 >= 0) & (d5 <= d6), c),
        ((vc <= 0) & (d1 >= 0) & (d3 <= 0), a + ab * t_ab[:, None]),
        ((vb <= 0) & (d2 >= 0) & (d6 <= 0), a + ac * t_ac[:, None]),
        ((va <= 0) & (d4 - d3 >= 0) & (d5 - d6 >= 0), b + (c - b) * t_bc[:, None]),
    ]
    done = np.zeros(len(a), dtype=bool)
    for mask, point in cases:
        take = mask & ~done
        out[take] = point[take]
        done |= take
    return out


def exact_distances(V: np.ndarray, F: np.ndarray, P: np.ndarray) -> np.ndarray:
    """Distance of each point of P to the mesh (V, F), by brute force over every triangle."""
    a, b, c = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    return np.array([np.linalg.norm(closest_on_triangles(p, a, b, c) - p, axis=1).min() for p in P])


def rotation(degrees: float) -> np.ndarray:
    t = np.radians(degrees)
    return np.array([[np.cos(t), 0.0, np.sin(t)], [0.0, 1.0, 0.0], [-np.sin(t), 0.0, np.cos(t)]])


def main(argv: list[str] | None = None) -> int:
    import open3d as o3d

    from o3d_ofp.boundary.convert import geometry_to_arrays, triangle_mesh_from_arrays

    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--source-level", type=int, default=3)
    parser.add_argument("--target", type=int, default=10000, help="target vertices (about)")
    parser.add_argument("--check", type=int, default=2000, help="vertices checked exactly")
    args = parser.parse_args(argv)
    path = DATA / "faust" / "tr_reg_093.ply"
    if not path.is_file():
        sys.stderr.write(f"needs the shared data at {DATA}\n")
        return 2
    mesh = o3d.io.read_triangle_mesh(str(path))
    source = mesh.subdivide_midpoint(args.source_level)
    # Loop subdivision moves the vertices off the source's (piecewise flat) surface, and the
    # decimation re-triangulates: a remeshed copy whose vertices are on no source triangle.
    target = mesh.subdivide_loop(1).simplify_quadric_decimation(2 * args.target)
    V1, F1 = geometry_to_arrays(source)
    V2, F2 = geometry_to_arrays(target)
    diag = float(np.linalg.norm(np.ptp(V1, axis=0)))
    print(f"load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores")
    print(f"source {len(V1)} vertices, {len(F1)} triangles; target {len(V2)} vertices")
    print(
        "| method | seconds | peak GB | mean distance / diagonal | max error vs exact / diagonal |"
    )
    print("|---|---|---|---|---|")
    rng = np.random.default_rng(0)
    check = rng.choice(len(V2), size=min(args.check, len(V2)), replace=False)
    exact = exact_distances(V1, F1, V2[check])

    def matched_points(corr) -> np.ndarray:
        corners = V1[F1[corr.faces_21]]
        return np.einsum("qi,qij->qj", corr.barycentric_21, corners)

    with Peak() as m:
        corr = ofp.match(source, target, method="closest")
    d = np.linalg.norm(matched_points(corr) - V2, axis=1)
    gap = np.abs(d[check] - exact).max()
    print(f"| ofp.match closest | {m.seconds:.2f} | {m.peak / 1e9:.2f} | {d.mean() / diag:.2e} | "
          f"{gap / diag:.1e} |")  # fmt: skip

    R, shift = rotation(3.0), 0.01 * diag
    moved = triangle_mesh_from_arrays(V2 @ R.T + shift, F2)
    with Peak() as m:
        corr_a = ofp.match(source, moved, method="closest", align=True)
    d_a = np.linalg.norm(matched_points(corr_a) - V2, axis=1)  # against the unmoved target
    same = np.mean(corr_a.p2p_21 == corr.p2p_21)
    print(f"| closest, align=True (3°, 1 % moved) | {m.seconds:.2f} | {m.peak / 1e9:.2f} | "
          f"{d_a.mean() / diag:.2e} | same vertex for {same:.1%} |")  # fmt: skip

    from scipy.spatial import cKDTree

    with Peak() as m:
        nearest = cKDTree(V1).query(V2)[1]
    d_v = np.linalg.norm(V1[nearest] - V2, axis=1)
    print(f"| k-d tree, nearest vertex (baseline) | {m.seconds:.2f} | {m.peak / 1e9:.2f} | "
          f"{d_v.mean() / diag:.2e} | {np.abs(d_v[check] - exact).max() / diag:.1e} |")  # fmt: skip
    print(f"load average {os.getloadavg()[0]:.1f} at the end")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
