"""Procedural test shapes as plain arrays (no Open3D, no data files).

Every function returns ``(vertices, faces)``: ``(n, 3)`` float64 and ``(m, 3)`` int64, with
consistently oriented (outward) triangles.
"""

from __future__ import annotations

import numpy as np

from ._validation import check_int

__all__ = ["blob", "icosphere", "torus"]


def icosphere(subdivisions: int = 5, *, radius: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """Subdivided icosahedron projected on a sphere.

    Parameters
    ----------
    subdivisions : int, default 5
        Number of 1-to-4 subdivisions; ``10 * 4**s + 2`` vertices (s=5: 10242).
    radius : float, default 1.0
        Sphere radius.

    Returns
    -------
    vertices : (n, 3) ndarray of float64
    faces : (m, 3) ndarray of int64
    """
    s = check_int(subdivisions, name="subdivisions", minimum=0, maximum=9)
    t = (1.0 + 5.0**0.5) / 2.0
    v = np.array(
        [
            [-1, t, 0],
            [1, t, 0],
            [-1, -t, 0],
            [1, -t, 0],
            [0, -1, t],
            [0, 1, t],
            [0, -1, -t],
            [0, 1, -t],
            [t, 0, -1],
            [t, 0, 1],
            [-t, 0, -1],
            [-t, 0, 1],
        ],
        dtype=np.float64,
    )
    f = np.array(
        [
            [0, 11, 5],
            [0, 5, 1],
            [0, 1, 7],
            [0, 7, 10],
            [0, 10, 11],
            [1, 5, 9],
            [5, 11, 4],
            [11, 10, 2],
            [10, 7, 6],
            [7, 1, 8],
            [3, 9, 4],
            [3, 4, 2],
            [3, 2, 6],
            [3, 6, 8],
            [3, 8, 9],
            [4, 9, 5],
            [2, 4, 11],
            [6, 2, 10],
            [8, 6, 7],
            [9, 8, 1],
        ],
        dtype=np.int64,
    )
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    for _ in range(s):
        edges = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
        uniq, inverse = np.unique(edges, axis=0, return_inverse=True)
        mids = v[uniq[:, 0]] + v[uniq[:, 1]]
        mids /= np.linalg.norm(mids, axis=1, keepdims=True)
        mid_id = inverse.reshape(3, -1).T + v.shape[0]  # (m, 3): midpoints of edges 01, 12, 20
        a, b, c = f[:, 0], f[:, 1], f[:, 2]
        ab, bc, ca = mid_id[:, 0], mid_id[:, 1], mid_id[:, 2]
        f = np.concatenate(
            [np.stack(x, axis=1) for x in ((a, ab, ca), (b, bc, ab), (c, ca, bc), (ab, bc, ca))]
        )
        v = np.concatenate([v, mids])
    return v * float(radius), f


def torus(
    n_major: int = 128, n_minor: int = 64, *, major_radius: float = 1.0, minor_radius: float = 0.4
) -> tuple[np.ndarray, np.ndarray]:
    """Regular grid torus with ``n_major * n_minor`` vertices.

    Parameters
    ----------
    n_major, n_minor : int
        Samples around the main ring and around the tube (each >= 3).
    major_radius, minor_radius : float
        Ring radius and tube radius.

    Returns
    -------
    vertices : (n_major * n_minor, 3) ndarray of float64
    faces : (2 * n_major * n_minor, 3) ndarray of int64
    """
    nu = check_int(n_major, name="n_major", minimum=3)
    nv = check_int(n_minor, name="n_minor", minimum=3)
    u = 2 * np.pi * np.arange(nu) / nu
    w = 2 * np.pi * np.arange(nv) / nv
    uu, ww = np.meshgrid(u, w, indexing="ij")
    ring = major_radius + minor_radius * np.cos(ww)
    v = np.stack(
        [ring * np.cos(uu), ring * np.sin(uu), minor_radius * np.sin(ww)], axis=-1
    ).reshape(-1, 3)
    i, j = np.meshgrid(np.arange(nu), np.arange(nv), indexing="ij")
    a = i * nv + j
    b = ((i + 1) % nu) * nv + j
    c = ((i + 1) % nu) * nv + (j + 1) % nv
    d = i * nv + (j + 1) % nv
    f = np.concatenate(
        [np.stack([a, b, c], -1).reshape(-1, 3), np.stack([a, c, d], -1).reshape(-1, 3)]
    )
    return v, f


def blob(
    subdivisions: int = 5, *, seed: int = 0, amplitude: float = 0.25
) -> tuple[np.ndarray, np.ndarray]:
    """Make an irregular closed surface: an icosphere radially displaced by smooth random bumps.

    It has no symmetry, so its Laplacian spectrum is simple (unlike the sphere's).

    Parameters
    ----------
    subdivisions : int, default 5
        Icosphere subdivisions (s=5: 10242 vertices).
    seed : int, default 0
        Seed of the bumps.
    amplitude : float, default 0.25
        Relative size of the bumps.

    Returns
    -------
    vertices : (n, 3) ndarray of float64
    faces : (m, 3) ndarray of int64
    """
    v, f = icosphere(subdivisions)
    rng = np.random.default_rng(seed)
    centers = rng.standard_normal((7, 3))
    centers /= np.linalg.norm(centers, axis=1, keepdims=True)
    weights = rng.uniform(-1.0, 1.0, 7)
    widths = rng.uniform(0.3, 0.8, 7)
    d2 = ((v[:, None, :] - centers[None]) ** 2).sum(-1)
    r = 1.0 + amplitude * (np.exp(-d2 / widths**2) * weights).sum(1)
    stretch = np.array([1.3, 1.0, 0.8])
    return v * r[:, None] * stretch, f
