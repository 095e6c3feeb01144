"""Slow, obvious reference implementations the fast code is tested against."""

from __future__ import annotations

import itertools

import numpy as np


def gram_schmidt_loop(B: np.ndarray, mass: np.ndarray, tol: float):
    """Column-by-column modified Gram-Schmidt, applied twice, with the relative drop test.

    Returns (Q, kept): Q (n, q) M-orthonormal, kept the indices of the kept columns.
    """
    kept, qs = [], []
    for j in range(B.shape[1]):
        b = B[:, j].astype(np.float64)
        norm0 = np.sqrt(b @ (mass * b))
        v = b.copy()
        for _ in range(2):
            for q in qs:
                v -= (q @ (mass * v)) * q
        res = np.sqrt(v @ (mass * v))
        if norm0 == 0 or res < tol * norm0:
            continue
        qs.append(v / res)
        kept.append(j)
    Q = np.stack(qs, axis=1) if qs else np.zeros((B.shape[0], 0))
    return Q, np.asarray(kept)


def eigenproducts_naive(evecs: np.ndarray, order: int):
    """Every product by explicit enumeration (graded lex) and np.prod."""
    k = evecs.shape[1] - 1
    cols, idx = [evecs[:, 0]], [()]
    for degree in range(1, order + 1):
        for tup in itertools.combinations_with_replacement(range(1, k + 1), degree):
            cols.append(np.prod(evecs[:, list(tup)], axis=1))
            idx.append(tup)
    return np.stack(cols, axis=1), idx


def projector(Q: np.ndarray, mass: np.ndarray) -> np.ndarray:
    """M-orthogonal projector Q Qᵀ M as a dense matrix (small n only)."""
    return Q @ (Q.T * mass[None, :])


def descriptor_op_loop(eig, k, D):
    """One multiplication operator Φᵀ M diag(d) Φ per descriptor column, by a plain loop."""
    phi = eig.evecs[:, : k + 1]
    proj = (phi * eig.mass[:, None]).T
    return np.stack([proj @ (D[:, [i]] * phi) for i in range(D.shape[1])])


def orientation_op_loop(eig, k, D):
    """Operators g ↦ <n × ∇d, ∇g>: per face, averaged to the vertices by area, projected."""
    import scipy.sparse as sp

    from o3d_ofp.core.geometry import face_areas_normals, face_gradient_operator

    V, F = eig.vertices, eig.faces
    areas, normals = face_areas_normals(V, F)
    grads = face_gradient_operator(V, F)
    phi = eig.evecs[:, : k + 1]
    proj = (phi * eig.mass[:, None]).T
    grad_phi = np.stack([g @ phi for g in grads], axis=-1)  # (m, k+1, 3)
    m = F.shape[0]
    to_vertex = sp.csr_matrix(
        (np.repeat(areas / 3.0, 3), (F.reshape(-1), np.repeat(np.arange(m), 3))),
        shape=(V.shape[0], m),
    )
    out = []
    for j in range(D.shape[1]):
        gd = np.stack([g @ D[:, j] for g in grads], axis=-1)
        rot = np.cross(normals, gd)
        per_face = np.einsum("fc,fkc->fk", rot, grad_phi)
        out.append(proj @ ((to_vertex @ per_face) / eig.mass[:, None]))
    return np.stack(out)
