"""Per-face and per-vertex geometry of triangle meshes (pure NumPy/SciPy)."""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

__all__ = [
    "edge_graph",
    "face_areas_normals",
    "face_gradient_operator",
    "outward_sign",
    "vertex_normals",
]


def face_areas_normals(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Face areas and unit normals.

    Parameters
    ----------
    vertices : (n, 3) ndarray of float
    faces : (m, 3) ndarray of int

    Returns
    -------
    areas : (m,) ndarray
        Triangle areas (0 for degenerate triangles).
    normals : (m, 3) ndarray
        Unit normals following the face orientation (zero for degenerate triangles).
    """
    e1 = vertices[faces[:, 1]] - vertices[faces[:, 0]]
    e2 = vertices[faces[:, 2]] - vertices[faces[:, 0]]
    cross = np.cross(e1, e2)
    norm = np.linalg.norm(cross, axis=1)
    normals = np.divide(cross, norm[:, None], out=np.zeros_like(cross), where=norm[:, None] > 0)
    return 0.5 * norm, normals


def vertex_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Area-weighted vertex normals, unit length (zero where undefined).

    Parameters
    ----------
    vertices : (n, 3) ndarray of float
    faces : (m, 3) ndarray of int

    Returns
    -------
    (n, 3) ndarray
    """
    areas, normals = face_areas_normals(vertices, faces)
    acc = np.zeros_like(vertices)
    weighted = normals * areas[:, None]
    for c in range(3):
        np.add.at(acc, faces[:, c], weighted)
    norm = np.linalg.norm(acc, axis=1, keepdims=True)
    return np.divide(acc, norm, out=np.zeros_like(acc), where=norm > 0)


def hat_gradients(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Gradient of each corner's hat function on each face.

    Parameters
    ----------
    vertices : (n, 3) ndarray of float
    faces : (m, 3) ndarray of int

    Returns
    -------
    (m, 3, 3) ndarray
        ``[t, c]`` is ∇ of the hat function of corner c on face t, so that the gradient of a
        piecewise-linear f on face t is ``Σ_c f[faces[t, c]] · [t, c]`` (zero on degenerate
        faces).
    """
    areas, normals = face_areas_normals(vertices, faces)
    inv2a = np.divide(1.0, 2.0 * areas, out=np.zeros_like(areas), where=areas > 0)
    grads = []
    # ∇ of the hat function of corner c is N × e_c / (2A), e_c the edge opposite c (oriented).
    for c in range(3):
        a, b = faces[:, (c + 1) % 3], faces[:, (c + 2) % 3]
        edge = vertices[b] - vertices[a]
        grads.append(np.cross(normals, edge) * inv2a[:, None])
    return np.stack(grads, axis=1)


def face_gradient_operator(vertices: np.ndarray, faces: np.ndarray) -> tuple[sp.csr_matrix, ...]:
    """Sparse operators giving the (constant) gradient of a piecewise-linear function per face.

    Parameters
    ----------
    vertices : (n, 3) ndarray of float
    faces : (m, 3) ndarray of int

    Returns
    -------
    gx, gy, gz : (m, n) scipy.sparse.csr_matrix
        ``(gx @ f)[t]`` is the x component of ∇f on face t (zero on degenerate faces).
    """
    n, m = vertices.shape[0], faces.shape[0]
    grads = hat_gradients(vertices, faces)  # (m, 3 corners, 3 coords)
    rows = np.repeat(np.arange(m), 3)
    cols = faces.reshape(-1)
    return tuple(
        sp.csr_matrix((grads[:, :, d].reshape(-1), (rows, cols)), shape=(m, n)) for d in range(3)
    )


def edge_graph(vertices: np.ndarray, faces: np.ndarray) -> sp.csr_matrix:
    """(n, n) symmetric sparse matrix of the mesh's edge lengths (shortest paths run on it).

    Each edge once, whatever the faces' orientation; a zero-length edge (welded-but-distinct
    vertices) is kept with a tiny positive length, so that it does not read as "no edge".
    """
    n = vertices.shape[0]
    F = np.asarray(faces, dtype=np.int64)
    E = np.unique(
        np.sort(np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]]), axis=1), axis=0
    )
    length = np.linalg.norm(vertices[E[:, 0]] - vertices[E[:, 1]], axis=1)
    length = np.maximum(length, 1e-12 * max(float(length.max(initial=0.0)), 1e-300))
    i, j = np.concatenate([E[:, 0], E[:, 1]]), np.concatenate([E[:, 1], E[:, 0]])
    return sp.coo_matrix((np.concatenate([length, length]), (i, j)), shape=(n, n)).tocsr()


def outward_sign(vertices: np.ndarray, faces: np.ndarray) -> float:
    """-1.0 when the faces are wound inwards (they enclose a negative volume), else +1.0.

    The signed volume of the cones from the centroid to the triangles: a closed surface
    wound inwards encloses minus its volume; so does, about as clearly, an open scan of one
    side. Below 1e-3 of the bounding box's cube (a flat patch, an undecided surface) the
    faces are taken as they are (+1).
    """
    a, b, c = (vertices[faces[:, i]] - vertices.mean(axis=0) for i in range(3))
    volume = np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0
    scale = np.ptp(vertices, axis=0).max() ** 3
    return -1.0 if volume < -1e-3 * scale else 1.0
