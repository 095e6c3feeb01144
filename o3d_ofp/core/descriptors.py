"""Spectral point descriptors: heat and wave kernel signatures, and their landmark variants.

All are computed from an :class:`~o3d_ofp.EigenBasis` (the constant eigenpair is
ignored) and are invariant to the mesh's scale: times and energies are chosen from the
eigenvalues themselves.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from ._validation import check_int
from .spectrum import EigenBasis, check_eigenbasis

__all__ = ["hks", "hks_times", "wks", "wks_energies"]


def _nonconstant(eig: EigenBasis, k: int | None) -> tuple[np.ndarray, np.ndarray]:
    check_eigenbasis(eig, "eig")
    k = eig.k if k is None else check_int(k, name="k", minimum=1, maximum=eig.k)
    return eig.evals[1 : k + 1], eig.evecs[:, 1 : k + 1]


def _landmarks(landmarks: Any, n: int) -> np.ndarray:
    lm = np.asarray(landmarks)
    if lm.ndim != 1 or not np.issubdtype(lm.dtype, np.integer):
        raise TypeError(
            f"landmarks must be a 1-D array of vertex indices; got {lm.dtype}{lm.shape}"
        )
    if lm.size == 0 or lm.min() < 0 or lm.max() >= n:
        raise ValueError(
            f"landmarks must be vertex indices in [0, {n}); "
            f"got range [{lm.min(initial=0)}, {lm.max(initial=0)}]"
        )
    return lm.astype(np.int64)


def hks_times(evals: np.ndarray, n_times: int) -> np.ndarray:
    """Log-spaced diffusion times from 4 ln10 / λ_max to 4 ln10 / λ_1 (Sun et al. 2009).

    Parameters
    ----------
    evals : (k,) ndarray
        Non-constant eigenvalues, ascending.
    n_times : int
        Number of times.

    Returns
    -------
    (n_times,) ndarray
    """
    return np.geomspace(4 * math.log(10) / evals[-1], 4 * math.log(10) / evals[0], n_times)


def wks_energies(evals: np.ndarray, n_energies: int) -> tuple[np.ndarray, float]:
    """Log-energies and bandwidth of the WKS (Aubry et al. 2011).

    Energies are evenly spaced in ``[log λ_1 + 2σ, log λ_k − 2σ]`` with
    ``σ = 7 (log λ_k − log λ_1) / n_energies``.

    Returns
    -------
    energies : (n_energies,) ndarray
    sigma : float
    """
    lo, hi = math.log(evals[0]), math.log(evals[-1])
    sigma = 7.0 * (hi - lo) / n_energies
    return np.linspace(lo + 2 * sigma, hi - 2 * sigma, n_energies), sigma


def hks(
    eig: EigenBasis,
    *,
    n_times: int = 100,
    times: Any = None,
    k: int | None = None,
    landmarks: Any = None,
    scaled: bool = True,
) -> np.ndarray:
    """Heat kernel signature ``Σ_i exp(−λ_i t) φ_i(x)²`` (or heat kernel maps at landmarks).

    Parameters
    ----------
    eig : EigenBasis
        The shape's eigenbasis.
    n_times : int, default 100
        Number of log-spaced times (ignored if ``times`` is given).
    times : (T,) array_like of float, optional
        Explicit diffusion times.
    k : int, optional
        Use the first ``k`` non-constant eigenpairs (default: all).
    landmarks : (p,) array_like of int, optional
        Vertex indices: return the heat kernel maps ``Σ_i exp(−λ_i t) φ_i(l) φ_i(x)`` instead.
    scaled : bool, default True
        Divide each time's column by the heat trace ``Σ_i exp(−λ_i t)``.

    Returns
    -------
    (n, T) or (n, p·T) ndarray
        One column per time (per landmark and time, landmark-major).

    References
    ----------
    .. [1] J. Sun, M. Ovsjanikov, L. Guibas, "A Concise and Provably Informative
       Multi-Scale Signature Based on Heat Diffusion", Computer Graphics Forum 28(5), 2009.

    Examples
    --------
    >>> import open3d as o3d
    >>> import o3d_ofp as ofp
    >>> sphere = o3d.geometry.TriangleMesh.create_sphere(radius=1.0, resolution=10)
    >>> eig = ofp.eigenbasis(sphere, k=8)
    >>> ofp.hks(eig, n_times=5).shape  # one column per time
    (182, 5)
    >>> ofp.hks(eig, n_times=5, landmarks=[0, 1]).shape  # heat kernel maps at 2 vertices
    (182, 10)
    """
    evals, phi = _nonconstant(eig, k)
    if times is None:
        t = hks_times(evals, check_int(n_times, name="n_times", minimum=1))
    else:
        t = np.asarray(times, dtype=np.float64).ravel()
        if t.size == 0 or not np.all(np.isfinite(t)) or np.any(t <= 0):
            raise ValueError("times must be a non-empty list of positive, finite diffusion times")
    coefs = np.exp(-np.outer(t, evals))  # (T, k)
    return _kernel_signature(phi, coefs, landmarks, scaled)


def wks(
    eig: EigenBasis,
    *,
    n_energies: int = 100,
    k: int | None = None,
    landmarks: Any = None,
    scaled: bool = True,
) -> np.ndarray:
    """Wave kernel signature ``Σ_i exp(−(e − log λ_i)² / 2σ²) φ_i(x)²`` (or maps at landmarks).

    Parameters
    ----------
    eig : EigenBasis
        The shape's eigenbasis.
    n_energies : int, default 100
        Number of log-energies ``e``, evenly spaced in ``[log λ_1 + 2σ, log λ_k − 2σ]``
        with the bandwidth ``σ = 7 (log λ_k − log λ_1) / n_energies``.
    k : int, optional
        Use the first ``k`` non-constant eigenpairs (default: all).
    landmarks : (p,) array_like of int, optional
        Vertex indices: return the wave kernel maps at those vertices instead.
    scaled : bool, default True
        Divide each energy's column by ``Σ_i exp(−(e − log λ_i)² / 2σ²)``.

    Returns
    -------
    (n, E) or (n, p·E) ndarray

    References
    ----------
    .. [1] M. Aubry, U. Schlickewei, D. Cremers, "The Wave Kernel Signature: A Quantum
       Mechanical Approach to Shape Analysis", ICCV Workshops, 2011.

    Examples
    --------
    >>> import open3d as o3d
    >>> import o3d_ofp as ofp
    >>> sphere = o3d.geometry.TriangleMesh.create_sphere(radius=1.0, resolution=10)
    >>> eig = ofp.eigenbasis(sphere, k=8)
    >>> ofp.wks(eig, n_energies=6).shape  # one column per energy
    (182, 6)
    """
    evals, phi = _nonconstant(eig, k)
    energies, sigma = wks_energies(evals, check_int(n_energies, name="n_energies", minimum=1))
    coefs = np.exp(-((energies[:, None] - np.log(evals)[None, :]) ** 2) / (2 * sigma**2))
    return _kernel_signature(phi, coefs, landmarks, scaled)


def _kernel_signature(
    phi: np.ndarray, coefs: np.ndarray, landmarks: Any, scaled: bool
) -> np.ndarray:
    scale = coefs.sum(axis=1) if scaled else np.ones(coefs.shape[0])
    if landmarks is None:
        return (phi**2 @ coefs.T) / scale[None, :]
    lm = _landmarks(landmarks, phi.shape[0])
    # (n, k) @ (k, p·T): column (l, t) = Σ_i c_ti φ_i(l) φ_i(x)
    weights = (phi[lm][:, None, :] * coefs[None, :, :]).reshape(-1, phi.shape[1])  # (p·T, k)
    return (phi @ weights.T) / np.tile(scale, lm.size)[None, :]
