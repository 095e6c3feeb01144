"""Transfer of signals between shapes through their orthonormal eigenproduct bases.

Given bases B₁ (source) and B₂ (target) and a functional map C between their first eigen-
functions, the transfer matrix O (q₂, q₁) maps source coefficients to target coefficients:
``g = Q₂ O Q₁ᵀ M₁ f``.
"""

from __future__ import annotations

import logging
from typing import Any

import numpy as np

from ._validation import as_signal
from .basis import OFPBasis
from .correspondence import check_fmap, check_p2p, p2p_from_fmap
from .fmap import lift_fmap

__all__ = ["transfer_matrix", "transfer_signal"]

logger = logging.getLogger(__name__)


def _check_bases(B_1: Any, B_2: Any) -> None:
    for name, B in (("B_1", B_1), ("B_2", B_2)):
        if not isinstance(B, OFPBasis):
            raise TypeError(
                f"{name} must be an OFPBasis (from o3d_ofp.ofp_basis); got {type(B).__name__}"
            )


def transfer_matrix(
    B_1: OFPBasis,
    B_2: OFPBasis,
    fmap_12: Any = None,
    *,
    method: str = "p2p",
    p2p_21: Any = None,
) -> np.ndarray:
    """Transfer matrix O between two orthonormal eigenproduct bases.

    Parameters
    ----------
    B_1, B_2 : OFPBasis
        Source and target bases.
    fmap_12 : (k2+1, k1+1) array_like, optional
        Functional map between the eigenbases the bases were built from (a larger map is cut
        to its top-left block). Required unless ``p2p_21`` is given with ``method="p2p"``.
    method : {"p2p", "analytic"}, default "p2p"
        "p2p" (Sec. 3.4): the point-to-point map Π (nearest neighbours of the target
        eigenfunctions among the mapped source ones, or ``p2p_21``) gives
        ``O = Q₂ᵀ M₂ Π Q₁``, the least-squares solution of ``Q₂ O = Π Q₁``. Robust; the default.
        "analytic" (Eq. 20): ``O = R₂ C̃ R₁ᵀ (R₁ R₁ᵀ)⁻¹`` from the lifted map C̃ alone. Exact
        when C maps the eigenfunctions exactly, but it degrades quickly with map noise and
        with k (the paper's Fig. 10): use it for analysis, not for real pairs.
    p2p_21 : (n2,) array_like of int, optional
        A known point-to-point map (target vertex → source vertex) to use instead of the one
        extracted from ``fmap_12`` (method "p2p" only).

    Returns
    -------
    (q2, q1) ndarray
        ``transfer_12``.

    Raises
    ------
    ValueError
        On shape mismatches (e.g. source and target swapped), out-of-range maps or an
        unknown method.

    References
    ----------
    .. [1] F. Maggioli et al., "Orthogonalized Fourier Polynomials for Signal Approximation
       and Transfer", Computer Graphics Forum 40(2), 2021, Sec. 3.3-3.4. doi:10.1111/cgf.142645

    Examples
    --------
    >>> import numpy as np
    >>> import open3d as o3d
    >>> import o3d_ofp as ofp
    >>> sphere = o3d.geometry.TriangleMesh.create_sphere(radius=1.0, resolution=10)
    >>> B = ofp.ofp_basis(ofp.eigenbasis(sphere, k=8), order=2)
    >>> T = ofp.transfer_matrix(B, B, p2p_21=np.arange(182))
    >>> T.shape == (B.size, B.size), bool(np.allclose(T, np.eye(B.size)))
    (True, True)
    """
    _check_bases(B_1, B_2)
    if method not in ("p2p", "analytic"):
        raise ValueError(f"method must be 'p2p' or 'analytic'; got {method!r}")
    if method == "p2p":
        if p2p_21 is None:
            if fmap_12 is None:
                raise ValueError("transfer_matrix needs fmap_12 or p2p_21")
            C = check_fmap(fmap_12, B_2.k + 1, B_1.k + 1)
            p2p = p2p_from_fmap(C, B_1.eig, B_2.eig)
        else:
            p2p = check_p2p(p2p_21, B_2.n_vertices, B_1.n_vertices)
        return B_2.Q.T @ (B_2.mass[:, None] * B_1.Q[p2p])
    if fmap_12 is None:
        raise ValueError("method='analytic' needs fmap_12")
    if B_1.order != B_2.order:
        raise ValueError(
            f"method='analytic' needs bases of the same order; got {B_1.order} and {B_2.order}"
        )
    C = check_fmap(fmap_12, B_2.k + 1, B_1.k + 1)
    lifted = lift_fmap(C, B_1.order, target_area=B_2.eig.area)
    X = B_2.R @ lifted @ B_1.R.T  # (q2, q1)
    gram = B_1.R @ B_1.R.T  # (q1, q1), symmetric positive definite (R₁ has full row rank)
    return np.linalg.solve(gram, X.T).T


def transfer_signal(f_1: Any, B_1: OFPBasis, B_2: OFPBasis, transfer_12: Any) -> np.ndarray:
    """Transfer a source signal to the target: ``g = Q₂ O Q₁ᵀ M₁ f``.

    Parameters
    ----------
    f_1 : (n1,) or (n1, d) array_like of float
        Signal on the source vertices.
    B_1, B_2 : OFPBasis
        Source and target bases.
    transfer_12 : (q2, q1) array_like
        Transfer matrix from :func:`transfer_matrix`.

    Returns
    -------
    (n2,) or (n2, d) ndarray
        The transferred signal on the target vertices.

    Examples
    --------
    >>> import numpy as np
    >>> import open3d as o3d
    >>> import o3d_ofp as ofp
    >>> sphere = o3d.geometry.TriangleMesh.create_sphere(radius=1.0, resolution=10)
    >>> B = ofp.ofp_basis(ofp.eigenbasis(sphere, k=8), order=2)
    >>> T = ofp.transfer_matrix(B, B, p2p_21=np.arange(182))  # the identity map
    >>> f = np.asarray(sphere.vertices)[:, 2] ** 2
    >>> g = ofp.transfer_signal(f, B, B, T)
    >>> g.shape, ofp.approximation_error(f, g, B.mass) < 0.01
    ((182,), True)
    """
    _check_bases(B_1, B_2)
    transfer = np.asarray(transfer_12, dtype=np.float64)
    if transfer.shape != (B_2.size, B_1.size):
        raise ValueError(
            f"transfer_12 has shape {transfer.shape} but the bases need (q2, q1) = "
            f"({B_2.size}, {B_1.size}) "
            "(are source and target swapped?)"
        )
    f = as_signal(f_1, B_1.n_vertices, name="f_1")
    return B_2.reconstruct(transfer @ B_1.project(f))
