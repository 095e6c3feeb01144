"""Baselines the paper compares with: plain eigenfunctions and raw eigenproducts ("prods").

* K eigenfunctions with their map C: ``g = Ψ C Φᵀ M₁ f``. "NK eigenfunctions" is the same with
  larger eigenbases and their own map (e.g. from ZoomOut or a ground-truth correspondence).
* "prods" (Nogneng, Melzi, Rodolà, Castellani, Bronstein, Ovsjanikov 2018): a signal's
  coefficients on the raw eigenproducts come from a truncated-SVD least-squares fit (singular
  values kept while σᵢ/σ₁ > (k − 1)·2e-3), and are transferred with the lifted map C̃.
  Products of order d scale as area^−(d−1)/2, so that fixed threshold assumes unit-area
  shapes; the products are therefore formed from the eigenfunctions of the shape rescaled to
  unit area (φ̂ = √A φ), which makes the baseline independent of the shapes' scale.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ._validation import as_signal, check_int
from .correspondence import check_fmap
from .fmap import lift_fmap
from .products import eigenproducts
from .spectrum import EigenBasis

__all__ = ["approximate_eigs", "approximate_prods", "fit_prods", "transfer_eigs", "transfer_prods"]


def approximate_eigs(f: Any, eig: EigenBasis) -> np.ndarray:
    """Best approximation of ``f`` in the span of the eigenbasis: ``Φ Φᵀ M f``."""
    return eig.reconstruct(eig.project(f))


def transfer_eigs(f_1: Any, eig_1: EigenBasis, eig_2: EigenBasis, fmap_12: Any) -> np.ndarray:
    """Transfer with eigenfunctions only: ``g = Ψ C Φᵀ M₁ f``.

    Parameters
    ----------
    f_1 : (n1,) or (n1, d) array_like
        Source signal.
    eig_1, eig_2 : EigenBasis
        Source and target eigenbases.
    fmap_12 : (k2+1, k1+1) array_like
        Map between them (a larger map is cut to its top-left block).

    Returns
    -------
    (n2,) or (n2, d) ndarray
    """
    C = check_fmap(fmap_12, eig_2.k + 1, eig_1.k + 1)
    return eig_2.reconstruct(C @ eig_1.project(f_1))


def _rcond(k: int) -> float:
    return (k - 1) * 2e-3


def _unit_area(eig: EigenBasis) -> tuple[np.ndarray, np.ndarray]:
    """Eigenfunctions and mass of the shape rescaled to unit area."""
    return eig.evecs * np.sqrt(eig.area), eig.mass / eig.area


def fit_prods(f: Any, eig: EigenBasis, order: int) -> np.ndarray:
    """Coefficients of ``f`` on the raw eigenproducts by truncated-SVD least squares.

    Parameters
    ----------
    f : (n,) or (n, d) array_like
        Signal.
    eig : EigenBasis
        Eigenbasis; its k non-constant eigenfunctions are multiplied.
    order : int
        Product order N.

    Returns
    -------
    (C(k+N, N),) or (C(k+N, N), d) ndarray
        Coefficients on the products of the unit-area eigenfunctions, minimizing
        ‖Φ̃ a − f‖_M over the singular directions kept (σᵢ/σ₁ > (k − 1)·2e-3, Nogneng et al.
        2018).
    """
    order = check_int(order, name="order", minimum=1)
    x = as_signal(f, eig.n_vertices)
    phi, mass = _unit_area(eig)
    P, _ = eigenproducts(phi, order)
    w = np.sqrt(mass)
    U, s, Vt = np.linalg.svd(P * w[:, None], full_matrices=False)
    keep = s / s[0] > _rcond(eig.k)
    rhs = U[:, keep].T @ (x * (w[:, None] if x.ndim == 2 else w))
    scaled = rhs / (s[keep][:, None] if x.ndim == 2 else s[keep])
    return Vt[keep].T @ scaled


def approximate_prods(f: Any, eig: EigenBasis, order: int) -> np.ndarray:
    """Reconstruction of ``f`` from its "prods" coefficients (see :func:`fit_prods`)."""
    P, _ = eigenproducts(_unit_area(eig)[0], order)
    return P @ fit_prods(f, eig, order)


def transfer_prods(
    f_1: Any, eig_1: EigenBasis, eig_2: EigenBasis, fmap_12: Any, order: int
) -> np.ndarray:
    """Transfer with raw eigenproducts: ``g = Ψ̃ C̃ a``, ``a`` from :func:`fit_prods`.

    Returns
    -------
    (n2,) or (n2, d) ndarray
    """
    C = check_fmap(fmap_12, eig_2.k + 1, eig_1.k + 1)
    a = fit_prods(f_1, eig_1, order)
    # the same map between the unit-area eigenfunctions: Ĉ = √(A₁/A₂) C
    lifted = lift_fmap(C * np.sqrt(eig_1.area / eig_2.area), order, target_area=1.0)
    P2, _ = eigenproducts(_unit_area(eig_2)[0], order)
    return P2 @ (lifted @ a)
