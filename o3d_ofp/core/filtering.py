"""Spectral filtering in an orthonormal eigenproduct basis (the paper's Sec. 4.2, Figs. 14-15).

A signal's coefficients ``c = Qᵀ M f`` are scaled by gains that depend on each basis function's
Dirichlet energy (its "frequency"), then the signal is rebuilt. Because Q is orthonormal the
coefficients are unique and the edit is stable, unlike with raw eigenproducts.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from ._validation import as_signal, check_int
from .basis import OFPBasis

__all__ = ["edit_coefficient", "sharpen_gains", "smooth_gains", "spectral_filter"]


def smooth_gains(strength: float = 5.0) -> Callable[[np.ndarray], np.ndarray]:
    """Low-pass gains ``exp(−strength · e)``, ``e`` the energy scaled to [0, 1].

    Parameters
    ----------
    strength : float, default 5.0
        Larger removes more high-frequency content; 0 is the identity.

    Returns
    -------
    callable
        Maps normalized energies (q,) to gains (q,).
    """
    if not strength >= 0:
        raise ValueError(f"strength must be >= 0; got {strength}")
    return lambda e: np.exp(-strength * e)


def sharpen_gains(amount: float = 2.0) -> Callable[[np.ndarray], np.ndarray]:
    """Enhancement gains ``1 + amount · e``, ``e`` the energy scaled to [0, 1].

    Parameters
    ----------
    amount : float, default 2.0
        Boost of the highest frequency relative to the lowest; 0 is the identity.

    Returns
    -------
    callable
    """
    if not amount >= 0:
        raise ValueError(f"amount must be >= 0; got {amount}")
    return lambda e: 1.0 + amount * e


def _gains_per_function(B: OFPBasis, gains: Any) -> np.ndarray:
    energies = B.dirichlet_energies
    if callable(gains):
        span = float(energies.max() - energies.min())
        e = (energies - energies.min()) / span if span > 0 else np.zeros_like(energies)
        g = np.asarray(gains(e), dtype=np.float64)
        if g.shape != (B.size,):
            raise ValueError(f"the gains function must return shape ({B.size},); got {g.shape}")
    else:
        g_sorted = np.asarray(gains, dtype=np.float64)
        if g_sorted.shape != (B.size,):
            raise ValueError(
                f"gains must have shape ({B.size},) (one per basis function, in increasing "
                f"energy order); got {g_sorted.shape}"
            )
        g = np.empty(B.size)
        g[B.energy_order] = g_sorted
    if not np.all(np.isfinite(g)):
        raise ValueError("gains hold NaN or inf")
    return g


def spectral_filter(B: OFPBasis, f: Any, gains: Any, *, keep_residual: bool = True) -> np.ndarray:
    """Filter a signal by scaling its coefficients according to frequency.

    Parameters
    ----------
    B : OFPBasis
        The basis (its Dirichlet energies order the functions).
    f : (n,) or (n, d) array_like of float
        Signal, e.g. vertex coordinates or colors.
    gains : callable or (q,) array_like
        A function of the normalized energies in [0, 1] returning one gain per basis function
        (see :func:`smooth_gains`, :func:`sharpen_gains`), or the gains themselves listed in
        increasing energy order.
    keep_residual : bool, default True
        Keep the part of ``f`` outside the span unchanged (unit gains then return ``f``
        exactly); with False the result lies in the span.

    Returns
    -------
    ndarray, shape of ``f``
        The filtered signal.
    """
    x = as_signal(f, B.n_vertices)
    g = _gains_per_function(B, gains)
    c = B.project(x)
    scaled = c * (g[:, None] if c.ndim == 2 else g)
    if keep_residual:
        return x + B.reconstruct(scaled - c)
    return B.reconstruct(scaled)


def edit_coefficient(B: OFPBasis, f: Any, rank: int, delta: Any) -> np.ndarray:
    """Add ``delta`` to one coefficient of ``f`` (the paper's Fig. 15).

    Parameters
    ----------
    B : OFPBasis
        The basis.
    f : (n,) or (n, d) array_like of float
        Signal (e.g. coordinates).
    rank : int
        Which basis function, by increasing Dirichlet energy (0 = the constant).
    delta : float or (d,) array_like
        Added to that coefficient (per channel).

    Returns
    -------
    ndarray, shape of ``f``
        ``f + delta · q_rank``.
    """
    x = as_signal(f, B.n_vertices)
    rank = check_int(rank, name="rank", minimum=0, maximum=B.size - 1)
    q = B.Q[:, B.energy_order[rank]]
    d = np.asarray(delta, dtype=np.float64)
    if x.ndim == 2 and d.ndim == 1 and d.shape[0] != x.shape[1]:
        raise ValueError(f"delta must be a scalar or have {x.shape[1]} values; got {d.shape}")
    return x + (
        np.outer(q, d) if x.ndim == 2 and d.ndim == 1 else q[:, None] * d if x.ndim == 2 else q * d
    )
