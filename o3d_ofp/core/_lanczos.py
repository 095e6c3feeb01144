"""Block Lanczos for the largest eigenpairs of a symmetric positive operator.

The eigensolver's first attempt (see :mod:`o3d_ofp.core.spectrum`): shift-invert turns the
smallest eigenvalues of ``L φ = λ M φ`` into the largest of ``A = M^½ (L − σM)⁻¹ M^½``, and
this routine finds those with a block Krylov space, fully re-orthogonalized, without restarts.
Against ARPACK's single-vector implicitly restarted Lanczos (``eigsh``), which spends most of
its time re-orthogonalizing one vector at a time (BLAS-2, memory-bound) and solves with one
right-hand side at a time, a block of ``BLOCK`` vectors makes both BLAS-3 and multi-right-hand
side solves. Measured on FAUST subdivided to 27.5k vertices, 100 eigenpairs, the whole
eigenbasis: 1.65 s against 2.49 s (``python scripts/bench_eigensolve.py``, which prints both);
eigenvalues equal to 4e-15 relative.

Algorithm (Golub & Underwood's block Lanczos, with full re-orthogonalization as in Grimes,
Lewis & Simon 1994): ``Q₀`` random orthonormal (n, b); at step j, ``W = A Q_j`` minus the
three-term recurrence (``Q_{j−1} B_{j−1}ᵀ`` and ``Q_j A_j``, ``A_j = Q_jᵀ W``), then one
classical Gram-Schmidt pass against every earlier block (a second where a column lost more
than 1 − 1/√2 of its norm in it: Daniel, Gragg, Kaufman & Stewart's criterion, as ARPACK), then
``W = Q_{j+1} B_j`` (QR). The projected matrix ``T`` is block tridiagonal; its leading
eigenpairs ``(θ, s)`` give Ritz pairs ``(θ, V s)`` whose residual norm ‖A V s − θ V s‖ is
‖B_j s_last‖ (the last block of rows of s), known without touching ``A``. The run stops when
every wanted pair has ‖B_j s_last‖ <= ``tol`` θ. Back in ``L φ = λ M φ`` that residual is
multiplied by up to ‖M^-½ L M^-½‖ / λ, large on fine or flattened meshes: ``tol = 1e-14`` gives
relative residuals ‖Lφ − λMφ‖_{M⁻¹} / λ_k of 4e-11 on FAUST at 27.5k vertices (ARPACK at machine
precision: ~3e-12) and 1e-8 on an icosphere flattened 1000-fold (1.6e-10), for 6 % more vectors
than 1e-12 (which gave 9e-10 and 5e-7).

Repeated eigenvalues: a block of b vectors holds up to b copies of an eigenvalue from the
start, and the rounding errors bring in the others as the run goes on, as in ARPACK (measured
on the 10k-vertex icosphere: every one of the 19 and 21 copies of l = 9 and 10 found, to
1e-13 of ARPACK's eigenvalues, with b = 8). The caller checks every returned pair's residual
and falls back to ARPACK when this routine gives up.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable

import numpy as np
import scipy.linalg
from scipy.linalg.blas import dgemm

__all__ = [
    "BLOCK",
    "MIN_PAIRS",
    "MIN_VERTICES",
    "LanczosNoConvergence",
    "block_lanczos",
    "dense_bytes",
    "fits",
    "krylov_dim",
]

logger = logging.getLogger(__name__)

#: Vectors per block. Measured at 27.5k vertices, 100 eigenpairs (Krylov dimension, seconds):
#: b = 8: 384, 1.06 s; 12: 456, 1.31 s; 16: 512, 1.53 s; 24: 528, 1.52 s. Larger blocks make
#: faster BLAS and solves per vector but need larger spaces. 8 also holds every copy of the
#: exact multiplicities of symmetric meshes seen (5 for an icosphere, 8 for a square flat torus)
#: from the start; larger ones (48 on a periodic 3D grid) were found through rounding.
BLOCK = 8

#: Block Lanczos is the first attempt from this many eigenpairs on shapes of at least
#: :data:`MIN_VERTICES` vertices. Elsewhere ARPACK's small restarted space is as fast or faster:
#: its re-orthogonalization, which block Lanczos saves, grows with n and k, while block
#: Lanczos' own overhead (the projected problem's eigensolves) does not grow with n. Measured
#: (``python scripts/bench_eigensolve.py --levels 0 1``, whole eigenbasis, ARPACK / block
#: seconds, tol 1e-14): 6890 vertices 0.77x for 30 pairs, 0.76x for 60, 0.84x for 100; 27.5k
#: 0.77x for 30, 0.89x for 40, 0.96x for 60, 1.22x for 70, 1.34x for 80, 1.51x for 100 (at
#: tol 1e-12: 110k 0.98x for 40, 1.8x for 100).
MIN_PAIRS = 60
MIN_VERTICES = 10_000

#: Below this share of its norm left after the Gram-Schmidt pass, a column gets a second pass.
_DGKS = 1.0 / math.sqrt(2.0)


class LanczosNoConvergence(RuntimeError):
    """The Krylov space reached its largest allowed size before every pair converged."""


def fits(n: int, count: int) -> bool:
    """Whether the Krylov space of ``count`` pairs is small beside ``n`` (a quarter at most).

    Beyond, the projected problem's eigensolves (``krylov_dim``³ each) outgrow the work
    Lanczos saves (3100 pairs on 12100 vertices would make 9600² ones).
    """
    return 4 * krylov_dim(n, count) <= n


def dense_bytes(n: int, count: int) -> float:
    """Peak bytes of :func:`block_lanczos` for ``count`` pairs of an operator of size ``n``.

    The Krylov space (n × krylov_dim), the returned vectors, the projected matrix T and the
    copies and workspace of its eigensolves (about three T's).
    """
    m = krylov_dim(n, count)
    return 8.0 * (n * (m + count) + 4 * m * m)


def krylov_dim(n: int, k: int) -> int:
    """Largest Krylov space :func:`block_lanczos` builds for ``k`` eigenpairs of size ``n``.

    Measured needs (b = 8): 240 for 40 pairs (110k vertices), 384-408 for 100 (6.9k and 27.5k
    vertices), 400-512 for 100-131 on the icosphere: about 2k + 200. The bound leaves half as
    much again.
    """
    return min(n, 3 * k + 300)


def block_lanczos(
    apply: Callable[[np.ndarray], np.ndarray],
    n: int,
    count: int,
    *,
    tol: float = 1e-14,
    max_dim: int | None = None,
    block: int = BLOCK,
    seed: int = 0,
    progress: Callable[[int], None] | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Largest ``count`` eigenpairs of the symmetric positive semi-definite operator ``apply``.

    Parameters
    ----------
    apply : callable
        ``apply(X)``, X (n, b) float64: ``A X``, (n, b).
    n : int
        Size of the operator.
    count : int
        Eigenpairs wanted.
    tol : float, default 1e-14
        A pair has converged when its residual norm is at most ``tol θ``.
    max_dim : int, optional
        Largest Krylov space; default :func:`krylov_dim` (n, count).
    block : int, default :data:`BLOCK`
        Vectors per block.
    seed : int, default 0
        Seed of the random start (fixed: reproducible runs).
    progress : callable, optional
        ``progress(vectors)``: the Krylov space's size after each step.

    Returns
    -------
    theta : (count,) ndarray
        Eigenvalues, descending.
    vectors : (n, count) ndarray
        Orthonormal eigenvectors.

    Raises
    ------
    LanczosNoConvergence
        When the space reaches ``max_dim`` vectors, or the Krylov space becomes invariant
        (a breakdown), before every pair has converged.
    """
    max_dim = min(n, max_dim or krylov_dim(n, count))
    if count + block > max_dim:
        raise LanczosNoConvergence(f"{count} pairs need more than {max_dim} Krylov vectors")
    V = np.empty((n, max_dim), order="F")
    T = np.zeros((max_dim, max_dim))
    V[:, :block] = np.linalg.qr(np.random.default_rng(seed).standard_normal((n, block)))[0]
    cur = 0
    B_prev: np.ndarray | None = None
    check = count + block  # Krylov size of the next convergence check
    last: tuple[int, float] | None = None  # (size, worst residual / (tol θ)) at the last check
    while True:
        top = cur + block
        Q = V[:, cur:top]
        W = np.asfortranarray(apply(Q))
        if B_prev is not None:
            W = dgemm(-1.0, V[:, cur - block : cur], B_prev, 1.0, W, trans_b=True, overwrite_c=True)
        A_j = dgemm(1.0, Q, W, trans_a=True)
        A_j = 0.5 * (A_j + A_j.T)
        W = dgemm(-1.0, Q, A_j, 1.0, W, overwrite_c=True)
        T[cur:top, cur:top] = A_j
        W = _orthogonalize(V[:, :top], W)
        Q_next, B = scipy.linalg.qr(W, mode="economic", overwrite_a=True, check_finite=False)
        if progress is not None:
            progress(top)
        if top >= check or top + block > max_dim:
            theta, S = scipy.linalg.eigh(
                T[:top, :top], subset_by_index=[top - count, top - 1], check_finite=False
            )
            theta, S = theta[::-1], S[:, ::-1]
            residual = np.linalg.norm(B @ S[cur:top], axis=0)
            worst = float(np.max(residual / (tol * theta)))
            if worst <= 1.0:
                logger.debug(
                    "block Lanczos: %d pairs in %d vectors, worst residual/θ %.2e",
                    count,
                    top,
                    float(np.max(residual / theta)),
                )
                return theta, V[:, :top] @ S
            if top + block > max_dim:
                raise LanczosNoConvergence(
                    f"{int(np.sum(residual <= tol * theta))} of {count} pairs converged in "
                    f"{top} vectors (worst residual/θ {worst * tol:.1e})"
                )
            check = top + _ahead(top, worst, last, block)
            last = (top, worst)
        diagonal = np.abs(np.diag(B))
        if diagonal.min() <= 1e-10 * max(float(np.abs(T[:top, :top]).max()), 1e-300):
            raise LanczosNoConvergence(f"the Krylov space became invariant at {top} vectors")
        V[:, top : top + block] = Q_next
        T[top : top + block, cur:top] = B
        T[cur:top, top : top + block] = B.T
        B_prev = B
        cur = top


def _ahead(top: int, worst: float, last: tuple[int, float] | None, block: int) -> int:
    """Vectors to add before the next convergence check (a multiple of ``block``).

    Each check costs an eigensolve of T (~15 ms at 400 vectors), more than a step on a mesh
    of 10k vertices. The worst residual falls about geometrically with the space's size (faster
    towards the end), so the vectors still needed are extrapolated from the last two checks;
    the next check comes at 80 % of that, at least one block and at most a quarter of the
    space ahead (a quarter of a block step's cost wasted at most).
    """
    ahead = top / 4.0
    if last is not None and worst < last[1]:
        rate = math.log(last[1] / worst) / (top - last[0])  # log-residual decrease per vector
        ahead = min(ahead, 0.8 * math.log(worst) / rate)
    return block * max(1, int(ahead // block))


def _orthogonalize(V: np.ndarray, W: np.ndarray) -> np.ndarray:
    """Remove from W its components along the orthonormal columns of V (one or two passes)."""
    before = np.linalg.norm(W, axis=0)
    W = dgemm(-1.0, V, dgemm(1.0, V, W, trans_a=True), 1.0, W, overwrite_c=True)
    again = np.flatnonzero(np.linalg.norm(W, axis=0) < _DGKS * before)
    if again.size:
        sub = np.asfortranarray(W[:, again])
        W[:, again] = dgemm(-1.0, V, dgemm(1.0, V, sub, trans_a=True), 1.0, sub, overwrite_c=True)
    return W
