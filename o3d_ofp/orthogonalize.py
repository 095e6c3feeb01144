"""Mass-weighted Gram-Schmidt with a relative drop threshold.

Semantics (those of the plain column-by-column loop, which the tests use as the reference):
candidates are visited in their given order (no pivoting: the transfer relies on it); each is
orthogonalized against every function kept so far under ``<f, g> = fᵀ M g``; it is dropped when
its residual norm is below ``tol`` times its own norm, otherwise normalized and kept. The
threshold is relative, so the selection does not depend on the mesh's scale.

Implementation: in the √M-weighted space the inner product is Euclidean. Candidates are
processed in blocks: each block is projected against the kept basis with two (three when the
second pass still removes more than half the norm, Kahan's "twice is enough" test) BLAS-3
passes of classical Gram-Schmidt, then its columns are handled one by one against the
functions kept earlier in the same block, again twice. The kept functions are M-orthonormal
to round-off (‖QᵀMQ − I‖ ~ 1e-15) whatever ``tol``, where the paper's single-pass classical
Gram-Schmidt loses orthogonality.
"""

from __future__ import annotations

import logging
from collections.abc import Iterable, Iterator
from typing import Any, NamedTuple

import numpy as np

from ._validation import as_signal, check_int, check_tol

__all__ = ["PRESETS", "GramSchmidt", "gram_schmidt", "gram_schmidt_blocks", "resolve_tol"]

logger = logging.getLogger(__name__)

#: Named thresholds of the paper (Sec. 4): "ours" is permissive, "ours*" strict.
PRESETS: dict[str, float] = {"ours": 1e-2, "ours*": 1e-9}

#: A kept candidate whose residual after the in-block projection is below this fraction of its
#: norm before it gets one more sweep against the older basis (round-off left along it is
#: ~ε·norm, so its relative size stays below ~1e3·ε).
_DEEP_CANCELLATION = 1e-3


def resolve_tol(tol: Any = None, preset: Any = None) -> float:
    """Return the drop threshold given an explicit ``tol`` and/or a ``preset`` name.

    Parameters
    ----------
    tol : float, optional
        Explicit threshold in (0, 1).
    preset : {"ours", "ours*"}, optional
        Named threshold (1e-2 or 1e-9).

    Returns
    -------
    float
        ``tol`` if given, else the preset's value, else 1e-2 ("ours").

    Raises
    ------
    ValueError
        For an unknown preset, or ``tol`` outside (0, 1), or both given and different.
    """
    if preset is not None:
        if preset not in PRESETS:
            raise ValueError(f"preset must be one of {sorted(PRESETS)}; got {preset!r}")
        if tol is not None and check_tol(tol) != PRESETS[preset]:
            raise ValueError(f"tol={tol} contradicts preset={preset!r} (tol={PRESETS[preset]:g})")
        return PRESETS[preset]
    return PRESETS["ours"] if tol is None else check_tol(tol)


class GramSchmidt(NamedTuple):
    """Result of :func:`gram_schmidt`.

    Attributes
    ----------
    Q : (n, q) ndarray of float64
        M-orthonormal basis of the kept span.
    R : (q, P) ndarray of float64
        ``R[i, j] = <q_i, b_j>_M`` (Eq. 17), upper trapezoidal: zero where ``kept[i] > j``.
        ``Q @ R`` equals the candidates ``B`` on the kept columns (to round-off) and
        approximates each dropped column to within ``tol`` times its norm.
    kept : (q,) ndarray of int64
        Indices of the kept candidates, ascending.
    """

    Q: np.ndarray
    R: np.ndarray
    kept: np.ndarray


class _GrowingColumns:
    """A Fortran-ordered (n, capacity) buffer whose leading columns are in use."""

    def __init__(self, n: int, capacity: int) -> None:
        self.data = np.empty((n, max(capacity, 1)), order="F")
        self.size = 0

    @property
    def view(self) -> np.ndarray:
        return self.data[:, : self.size]

    def extend(self, cols: np.ndarray, limit: int) -> None:
        need = self.size + cols.shape[1]
        if need > self.data.shape[1]:
            grown = np.empty(
                (self.data.shape[0], min(max(need, 2 * self.data.shape[1]), limit)), order="F"
            )
            grown[:, : self.size] = self.view
            self.data = grown
        self.data[:, self.size : need] = cols
        self.size = need


def _project_out(Q: np.ndarray, W: np.ndarray, max_passes: int = 3) -> np.ndarray:
    """Remove from W (in place) its components along orthonormal Q; return the column norms."""
    norms = np.linalg.norm(W, axis=0)
    if Q.shape[1] == 0:
        return norms
    active = np.arange(W.shape[1])
    for passno in range(max_passes):
        sub = W[:, active]
        sub -= Q @ (Q.T @ sub)
        W[:, active] = sub
        new = np.linalg.norm(sub, axis=0)
        # After the mandatory second pass, repeat only where that pass still removed more than
        # half of the norm (Kahan / Parlett): there the previous pass was not yet accurate.
        again = new < 0.5 * norms[active] if passno >= 1 else np.ones(active.shape, bool)
        norms[active] = new
        active = active[again]
        if active.size == 0:
            break
    return norms


def _project_vector(Q: np.ndarray, w: np.ndarray) -> float:
    """Remove from vector w (in place) its components along orthonormal Q; return its norm.

    Two passes, a third when the second still removed more than half of the norm.
    """
    norm = float(np.linalg.norm(w))
    for passno in range(3):
        w -= Q @ (Q.T @ w)
        new = float(np.linalg.norm(w))
        if passno >= 1 and new >= 0.5 * norm:
            return new
        norm = new
    return norm


def gram_schmidt_blocks(
    blocks: Iterable[tuple[int, np.ndarray]],
    mass: np.ndarray,
    n_candidates: int,
    *,
    tol: float = 1e-2,
    block_size: int = 64,
) -> GramSchmidt:
    """Gram-Schmidt over candidates delivered in column blocks (see :func:`gram_schmidt`).

    Parameters
    ----------
    blocks : iterable of (start, (n, b) ndarray)
        Consecutive column blocks of the candidate matrix, starting at column 0; they may be
        modified in place.
    mass : (n,) ndarray of float64
        Positive lumped mass.
    n_candidates : int
        Total number of candidate columns ``P``.
    tol : float, default 1e-2
        Relative drop threshold in (0, 1).
    block_size : int, default 64
        Columns processed per BLAS-3 step (incoming blocks are re-cut to this size).

    Returns
    -------
    GramSchmidt
        ``(Q, R, kept)``.
    """
    tol = check_tol(tol)
    block_size = check_int(block_size, name="block_size", minimum=1)
    n = mass.shape[0]
    sqrt_m = np.sqrt(mass)
    basis = _GrowingColumns(n, min(n_candidates, n, 4 * block_size))
    kept: list[int] = []
    r_blocks: list[tuple[int, np.ndarray]] = []
    expected = 0
    for start, raw in _recut(blocks, block_size):
        if start != expected:
            raise ValueError(
                f"candidate blocks must be consecutive; expected column {expected}, got {start}"
            )
        b = raw.shape[1]
        expected += b
        if not np.all(np.isfinite(raw)):
            raise ValueError(f"candidates {start}..{start + b - 1} hold NaN or inf values")
        W = np.asfortranarray(raw * sqrt_m[:, None])
        original = W.copy(order="F")
        norm0 = np.linalg.norm(W, axis=0)
        n1 = _project_out(basis.view, W)
        new_cols = np.empty((n, b), order="F")
        t = 0
        for j in range(b):
            w = W[:, j]
            res = _project_vector(new_cols[:, :t], w) if t else float(n1[j])
            if norm0[j] == 0.0 or res < tol * norm0[j]:
                continue
            if t and res < _DEEP_CANCELLATION * n1[j]:
                # The in-block projection removed almost all of w: the round-off it left along
                # the older basis (~ε·n1) is no longer negligible next to the residual. Rare.
                w -= basis.view @ (basis.view.T @ w)
                res = _project_vector(new_cols[:, :t], w)
                if res < tol * norm0[j]:
                    continue
            new_cols[:, t] = w / res
            kept.append(start + j)
            t += 1
        if t:
            basis.extend(new_cols[:, :t], limit=min(n_candidates, n))
        # Eq. (17): R[i, j] = <q_i, b_j> for every function kept so far; later ones give 0.
        r_blocks.append((start, basis.view.T @ original))
    if expected != n_candidates:
        raise ValueError(f"blocks delivered {expected} candidates; expected {n_candidates}")
    q = basis.size
    kept_arr = np.asarray(kept, dtype=np.int64)
    R = np.zeros((q, n_candidates))
    for start, block in r_blocks:
        R[: block.shape[0], start : start + block.shape[1]] = block
    R[kept_arr[:, None] > np.arange(n_candidates)[None, :]] = 0.0
    Q = basis.view if basis.data.shape[1] == q else basis.view.copy(order="F")
    Q /= sqrt_m[:, None]
    return GramSchmidt(Q=Q, R=R, kept=kept_arr)


def _recut(blocks: Iterable[tuple[int, np.ndarray]], size: int) -> Iterator[tuple[int, np.ndarray]]:
    for start, block in blocks:
        for off in range(0, block.shape[1], size):
            yield start + off, block[:, off : off + size]


def gram_schmidt(
    candidates: Any,
    mass: Any,
    *,
    tol: float = 1e-2,
    block_size: int = 64,
) -> GramSchmidt:
    """Orthonormalize candidates under the mass inner product, dropping dependent ones.

    Parameters
    ----------
    candidates : (n, P) array_like of float
        Candidate functions as columns, in the order they are to be visited.
    mass : (n,) array_like of float
        Positive lumped mass (the diagonal of M).
    tol : float, default 1e-2
        Relative drop threshold in (0, 1): candidate j is dropped when its residual after
        projection on the functions kept so far is below ``tol * ‖b_j‖_M``.
    block_size : int, default 64
        Columns per BLAS-3 step; any value gives the same selection.

    Returns
    -------
    GramSchmidt
        ``Q`` (n, q) M-orthonormal, ``R`` (q, P) with ``Q R = B`` on the kept columns, and the
        kept indices (q,).

    Raises
    ------
    ValueError
        On shape mismatch, non-positive mass, non-finite values or ``tol`` outside (0, 1).

    References
    ----------
    .. [1] G. Maggioli et al., "Orthogonalized Fourier Polynomials for Signal Approximation
       and Transfer", Computer Graphics Forum 40(2), 2021, Sec. 3.3 (Eq. 15, 17).
       doi:10.1111/cgf.142645
    .. [2] L. Giraud, J. Langou, M. Rozložník, "The loss of orthogonality in the Gram-Schmidt
       orthogonalization process", Computers & Mathematics with Applications 50, 2005.
    """
    m = np.asarray(mass)
    if m.ndim != 1:
        raise ValueError(f"mass must have shape (n,); got {m.shape}")
    m = as_signal(m, m.shape[0], name="mass")
    if np.any(m <= 0):
        raise ValueError("mass must be positive everywhere")
    B = as_signal(candidates, m.shape[0], name="candidates")
    if B.ndim == 1:
        B = B[:, None]
    return gram_schmidt_blocks([(0, B)], m, B.shape[1], tol=tol, block_size=block_size)
