"""Mass-weighted Gram-Schmidt with a relative drop threshold.

Semantics (those of the plain column-by-column loop, which the tests use as the reference):
candidates are visited in their given order (no pivoting: the transfer relies on it); each is
orthogonalized against every function kept so far under ``<f, g> = fᵀ M g``; it is dropped when
its residual norm is below ``tol`` times its own norm, otherwise normalized and kept. The
threshold is relative, so the selection does not depend on the mesh's scale.

Implementation: in the √M-weighted space the inner product is Euclidean. Candidates are
processed in blocks of ``block_size`` columns. Each block is projected on the kept basis with
two in-place BLAS-3 passes of classical Gram-Schmidt (a third on the columns where the second
still removed more than half of the norm: Kahan's "twice is enough" test). Inside the block the
per-column drop test then runs

* for ``tol >= 1e-4``, on the block's Gram matrix (a Cholesky factorization that skips dropped
  columns), the kept columns being orthonormalized by Cholesky-QR applied twice. Residuals
  taken from a Gram matrix carry errors that grow with the square of the block's condition
  number, so every decision is checked against a first-order bound of that error (see
  `_select_by_gram`); a block with any residual within the bound of the threshold, or too
  ill-conditioned for the bound to hold (graded, Kahan-like columns), is handed to the
  recursive path below. On eigenproducts at ``tol = 1e-2`` every block passes; at 1e-3 and
  1e-4 the first one (the nearly collinear low-degree products) usually does not.
* for smaller ``tol`` (and for the blocks above), by recursive halving: the left half is
  processed, the right half is projected twice on what it kept, and so on down to single
  columns; a column whose in-block projections removed all but 1e-3 of its norm is projected
  once more on everything kept before its test.

Either way each candidate meets every function kept before it before its drop test, and the
selection is that of the column loop (modified Gram-Schmidt applied twice; the tests compare
both, on eigenproducts and on Kahan-like candidates) except for a residual within rounding
distance of ``tol`` times its norm: in the recursive path that distance is the loss of
orthogonality accumulated inside the block (before the repair below) times the column's norm,
~1e-14 relative on most blocks, up to a few 1e-10 seen (order-3 FAUST products at 1e-9,
Kahan-like candidates). At ``tol = 1e-9`` real meshes do have residuals that close, and
algorithms equal in exact arithmetic keep slightly different sets.

Orthonormality: after each block, the loss of orthogonality of its new functions (to each other
and to the older ones) is estimated with random probes, and if it exceeds 1e-12 they are
projected once more on the older ones and orthonormalized by Cholesky-QR (rare on eigenproducts:
a few blocks at ``tol = 1e-9``; without it the losses compound from block to block, up to a
complete loss on order-3 products at 1e-9). The kept functions are M-orthonormal to
‖QᵀMQ − I‖ ≲ 1e-12 (the probes' threshold), ~1e-14 in practice (measured <= 7e-14 on FAUST,
TOSCA and bunny eigenproducts of order 2 and 3 at 1e-2 .. 1e-9, and on Kahan-like
candidates), whatever ``tol``, where the paper's single-pass classical Gram-Schmidt loses
orthogonality. ``R`` is computed from the final functions: ``Q R`` reproduces the kept
candidates to round-off.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Iterable, Iterator
from typing import Any, NamedTuple

import numpy as np
import scipy.linalg
from scipy.linalg.blas import dgemm, dnrm2, dtrsm

from ._progress import Progress
from ._threads import PARALLEL_ROWS
from ._validation import as_signal, check_int, check_tol
from .wording import OptionError

__all__ = ["PRESETS", "GramSchmidt", "gram_schmidt", "gram_schmidt_blocks", "resolve_tol"]

logger = logging.getLogger(__name__)

#: Named thresholds of the paper (Sec. 4): "ours" is permissive, "ours*" strict.
PRESETS: dict[str, float] = {"ours": 1e-2, "ours*": 1e-9}

#: A kept candidate whose residual after the in-block projection is below this fraction of its
#: norm before it gets one more sweep against the older basis (round-off left along it is
#: ~ε·norm, so its relative size stays below ~1e3·ε).
_DEEP_CANCELLATION = 1e-3

#: Thresholds at least this large try the Gram-matrix selection inside a block (accepted only
#: where its error bound certifies every decision: see `_select_by_gram`); smaller ones use the
#: recursive projections directly (at tol < 1e-4 the bound would rarely certify anything).
_GRAM_MIN_TOL = 1e-4

#: Random probes of a block's loss of orthogonality (see `_reorthogonalize`), and the loss (an
#: estimate of the Frobenius norm of the block's columns of QᵀQ − I) above which its new
#: functions are re-orthogonalized. Round-off alone gives ~1e-14; with 8 probes, a loss 100
#: times the threshold goes unnoticed with probability ~1e-15 (χ² with 8 degrees of freedom).
_N_PROBES = 8
_REORTH_TOL = 1e-12


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
            raise OptionError("preset", f"must be one of {sorted(PRESETS)}; got {preset!r}")
        if tol is not None and check_tol(tol) != PRESETS[preset]:
            given = PRESETS[preset]
            raise OptionError("tol", f"{tol} contradicts preset={preset!r} (tol={given:g})")
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
    """A growing set of columns stored Fortran-ordered, without copies when it grows or shrinks.

    The storage is a C-ordered (capacity, n) array whose transpose is the (n, capacity)
    Fortran-ordered matrix; ``ndarray.resize`` reallocates it in place (on Linux, large
    blocks are remapped rather than copied). No view of the storage may be held across a
    call to :meth:`extend` or :meth:`finish`.
    """

    def __init__(self, n: int, capacity: int) -> None:
        self._rows = np.empty((max(capacity, 1), n))
        self.size = 0

    @property
    def view(self) -> np.ndarray:
        return self._rows[: self.size].T

    def extend(self, cols: np.ndarray, limit: int) -> None:
        need = self.size + cols.shape[1]
        capacity = self._rows.shape[0]
        if need > capacity:
            self._rows.resize(
                (min(max(need, 2 * capacity), limit), self._rows.shape[1]), refcheck=False
            )
        self._rows[self.size : need] = cols.T
        self.size = need

    def finish(self) -> np.ndarray:
        """Trim the storage to the columns in use and return them as an (n, size) matrix."""
        self._rows.resize((self.size, self._rows.shape[1]), refcheck=False)
        return self._rows.T


#: Below :data:`~o3d_ofp.core._threads.PARALLEL_ROWS` rows the products go through NumPy's
#: matmul, which releases the GIL during BLAS, where SciPy's ``dgemm`` wrapper holds it: two
#: bases built in two threads (a transfer's source and target, one BLAS thread each) then run
#: at once (FAUST 27.5k, k = 39: 2.0-2.3 s each side by side with dgemm, as long as one after
#: the other; the same speed alone, 45-53 ms per product). ``W -= Q C`` then writes Q C to a
#: scratch buffer first: the one :func:`gram_schmidt_blocks` keeps per thread for its run.
#: From that size on, bases are built one after the other with BLAS on every core, and
#: ``dgemm`` in place is faster (110k, k = 39: 3.5-4.6 s against 5.0-5.9 s).
_SCRATCH = threading.local()


def _inner(Q: np.ndarray, W: np.ndarray) -> np.ndarray:
    """Qᵀ W."""
    if Q.shape[0] >= PARALLEL_ROWS:
        return dgemm(1.0, Q, W, trans_a=True)
    return Q.T @ W


def _subtract_product(W: np.ndarray, Q: np.ndarray, C: np.ndarray) -> None:
    """W -= Q C in place."""
    if W.shape[0] >= PARALLEL_ROWS:
        out = dgemm(-1.0, Q, C, 1.0, W, overwrite_c=True)
        if not np.shares_memory(out, W):  # W was not Fortran-contiguous: BLAS worked on a copy
            W[...] = out
        return
    buf = getattr(_SCRATCH, "buf", None)
    size = W.shape[0] * W.shape[1]
    if buf is None or buf.size < size:
        buf = np.empty(size)
    # in W's own layout (the blocks are Fortran-ordered): the subtraction then streams both
    fortran = W.flags.f_contiguous and not W.flags.c_contiguous
    tmp = buf[:size].reshape(W.shape[::-1]).T if fortran else buf[:size].reshape(W.shape)
    np.matmul(Q, C, out=tmp)
    np.subtract(W, tmp, out=W)


def _column_norms(W: np.ndarray) -> np.ndarray:
    """Euclidean norms of the columns (BLAS nrm2: scaled, no overflow)."""
    return np.array([dnrm2(W[:, j]) for j in range(W.shape[1])])


def _project_out(Q: np.ndarray, W: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Remove from W (in place) its components along orthonormal Q.

    Two BLAS-3 passes of classical Gram-Schmidt; a third, on the columns where the second
    still removed more than half of the norm (Kahan / Parlett: the previous pass was not yet
    accurate there).

    Returns
    -------
    norms : (b,) ndarray
        Column norms of W afterwards.
    coefficients : (q, b) ndarray
        Accumulated coefficients: on entry, W = Q @ coefficients + W_after.
    """
    if Q.shape[1] == 0:
        return _column_norms(W), np.zeros((0, W.shape[1]))
    coefficients = _inner(Q, W)
    _subtract_product(W, Q, coefficients)
    before = _column_norms(W)
    c2 = _inner(Q, W)
    _subtract_product(W, Q, c2)
    coefficients += c2
    norms = _column_norms(W)
    again = np.flatnonzero(norms < 0.5 * before)
    if again.size:
        sub = np.asfortranarray(W[:, again])
        c3 = _inner(Q, sub)
        _subtract_product(sub, Q, c3)
        W[:, again] = sub
        coefficients[:, again] += c3
        norms[again] = _column_norms(sub)
    return norms, coefficients


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


def _select_in_block(
    W: np.ndarray,
    out: np.ndarray,
    norm0: np.ndarray,
    n1: np.ndarray,
    older: np.ndarray,
    tol: float,
    start: int,
    kept: list[int],
) -> int:
    """Column-by-column selection inside one block, with BLAS-3 projections.

    W's columns are already orthogonal to ``older``. The block is halved recursively: the
    left half is processed, the right half is projected (twice) on the functions the left
    half kept, then processed. Every column thus meets all functions kept before it before
    its drop test, as in the column loop, but the work is matrix-matrix products instead of
    one matrix-vector product per pair of columns. Kept functions, normalized, go to ``out``;
    their global indices are appended to ``kept``. Returns how many were kept.
    """
    count = 0

    def visit(lo: int, hi: int) -> None:
        nonlocal count
        if hi - lo == 1:
            w = W[:, lo]
            res = float(dnrm2(w))
            if norm0[lo] == 0.0 or res < tol * norm0[lo]:
                return
            if count and res < _DEEP_CANCELLATION * n1[lo]:
                # In-block projections removed almost all of w: the round-off they left along
                # the older basis (~ε·n1) is no longer negligible next to the residual. Rare.
                w -= older @ (older.T @ w)
                res = _project_vector(out[:, :count], w)
                if res < tol * norm0[lo]:
                    return
            out[:, count] = w / res
            kept.append(start + lo)
            count += 1
            return
        mid = (lo + hi) // 2
        before = count
        visit(lo, mid)
        if count > before:
            _project_out(out[:, before:count], W[:, mid:hi])
        visit(mid, hi)

    visit(0, W.shape[1])
    return count


def _select_by_gram(
    W: np.ndarray,
    out: np.ndarray,
    norm0: np.ndarray,
    tol: float,
    start: int,
    kept: list[int],
) -> int:
    """Select as :func:`_select_in_block` does, but from the Gram matrix WᵀW, when provably safe.

    The residual of column j against the columns kept before it in the block is the Schur
    complement ``G_jj − ‖L⁻¹ G_Kj‖²`` of a Cholesky factorization that skips dropped columns.
    Its rounding error is not small in general: with ``x = G_KK⁻¹ G_Kj`` (the coefficients of
    ``w_j``'s projection on the kept columns) and ``d = sqrt(diag G)``, a componentwise backward
    error ``|ΔG| ≤ γ d dᵀ`` of the Gram matrix and of the factorization moves it by up to
    ``γ (d_j + Σ_i |x_i| d_i)²`` to first order. That is ~γ‖w_j‖² for well-conditioned blocks
    but grows with the square of the block's condition number: on graded, Kahan-like columns
    it exceeds the residuals themselves, and decisions taken from it are wrong. So the bound is
    evaluated for every column once the selection is done (one triangular solve for all of
    them), and the selection is accepted only if no residual lies within it of the threshold
    and the first-order expansion is valid (``γ · t · ‖L̃⁻¹‖_F² ≤ 0.1`` for the kept block's
    Cholesky factor scaled to a unit diagonal). The kept vectors are then formed by
    Cholesky-QR applied twice, accurate to round-off because the same condition bounds their
    condition number by ~(0.1/γ)^½.

    Returns
    -------
    int
        How many were kept, or -1 when the selection cannot be certified (the caller uses the
        recursive projections; ``kept`` is then untouched).

    Raises
    ------
    numpy.linalg.LinAlgError
        If the Cholesky factorization of the second pass fails (the caller falls back; ``kept``
        is untouched).
    """
    n, b = W.shape
    G = _inner(W, W)
    d = np.sqrt(np.maximum(np.diag(G), 0.0))
    chol = np.zeros((b, b))  # lower-triangular factor of the kept columns' Gram matrix
    proj = np.zeros((b, b))  # column j: L⁻¹ G[sel, j] over the columns kept before j
    res2 = np.zeros(b)
    thr2 = (tol * norm0) ** 2
    sel: list[int] = []
    for j in range(b):
        if norm0[j] == 0.0:
            continue
        m = len(sel)
        res2[j] = G[j, j]
        if m:
            r = scipy.linalg.solve_triangular(
                chol[:m, :m], G[sel, j], lower=True, check_finite=False
            )
            proj[:m, j] = r
            res2[j] -= r @ r
        if res2[j] < thr2[j]:
            continue
        chol[m, :m] = proj[:m, j]
        chol[m, m] = np.sqrt(res2[j])
        sel.append(j)
    t = len(sel)
    # A posteriori certificate of every decision (see above). γ covers the Gram matrix's dot
    # products of length n and the factorization's of length <= b, with a factor 2 to spare.
    gamma = (n + 2 * b) * np.finfo(np.float64).eps
    spread = d.copy()
    if t:
        L = chol[:t, :t]
        coef = scipy.linalg.solve_triangular(
            L, proj[:t], lower=True, trans="T", check_finite=False
        )  # column j: the coefficients x of w_j on the kept columns (zero from its own on)
        d_kept = d[sel]
        spread += d_kept @ np.abs(coef)
        scaled_inv = scipy.linalg.solve_triangular(
            L / d_kept[:, None], np.eye(t), lower=True, check_finite=False
        )
        if gamma * t * np.sum(scaled_inv**2) > 0.1:
            return -1
    live = norm0 > 0.0
    if np.any(np.abs(res2[live] - thr2[live]) <= 2.0 * gamma * spread[live] ** 2):
        return -1
    if t == 0:
        return 0
    Qn = out[:, :t]
    for i, j in enumerate(sel):  # column copies: no (n, t) temporary
        Qn[:, i] = W[:, j]
    for passno in range(2):  # Cholesky-QR2: the second pass removes the first one's round-off
        T = chol[:t, :t] if passno == 0 else np.linalg.cholesky(_inner(Qn, Qn))
        # Qn <- Qn T⁻ᵀ in place (BLAS trsm from the right)
        done = dtrsm(1.0, np.asfortranarray(T), Qn, side=1, lower=1, trans_a=1, overwrite_b=1)
        if not np.shares_memory(done, Qn):
            Qn[...] = done
    kept.extend(start + j for j in sel)
    return t


def _reorthogonalize(older: np.ndarray, Qn: np.ndarray, seed: int) -> None:
    """Restore, in place, the orthonormality of a block's new functions if it was lost.

    The loss ``‖[older, Qn]ᵀ Qn − [0; I]‖_F`` is estimated with ``_N_PROBES`` Gaussian probe
    vectors ``Z`` (``E[‖E Z‖_F²] = _N_PROBES · ‖E‖_F²``; reading ``older`` and ``Qn`` once or
    twice, it costs a few percent of the block). When it exceeds ``_REORTH_TOL``, ``Qn`` is
    projected once more on ``older`` and orthonormalized by Cholesky-QR, then probed again.
    Both steps keep ``span(older, Qn[:, :i])`` for every i, so the rows of R computed from the
    result afterwards still reproduce the kept candidates and stay upper trapezoidal.
    """
    t = Qn.shape[1]
    if t == 0:
        return
    Z = np.asfortranarray(np.random.default_rng(seed).standard_normal((t, _N_PROBES)))
    for attempt in range(4):
        Y = Qn @ Z
        loss_new = np.linalg.norm(_inner(Qn, Y) - Z)
        loss_old = np.linalg.norm(_inner(older, Y)) if older.shape[1] else 0.0
        if max(loss_new, loss_old) <= _REORTH_TOL * np.sqrt(_N_PROBES):
            return
        if attempt == 3:
            logger.warning(
                "%d new functions stay non-orthonormal after re-orthogonalization "
                "(probed loss %.1e)",
                t,
                max(loss_new, loss_old) / np.sqrt(_N_PROBES),
            )
            return
        logger.debug(
            "re-orthogonalizing %d new functions (probed loss %.1e, %.1e vs older)",
            t,
            loss_new / np.sqrt(_N_PROBES),
            loss_old / np.sqrt(_N_PROBES),
        )
        if loss_old > 0.0:
            _subtract_product(Qn, older, _inner(older, Qn))
        try:
            T = scipy.linalg.cholesky(_inner(Qn, Qn), lower=True, check_finite=False)
        except np.linalg.LinAlgError:  # far from orthonormal: Householder QR, same spans
            q, r = np.linalg.qr(Qn)
            Qn[...] = q * np.where(np.diag(r) < 0, -1.0, 1.0)
            continue
        done = dtrsm(1.0, np.asfortranarray(T), Qn, side=1, lower=1, trans_a=1, overwrite_b=1)
        if not np.shares_memory(done, Qn):
            Qn[...] = done


def gram_schmidt_blocks(
    blocks: Iterable[tuple[int, np.ndarray]],
    mass: np.ndarray,
    n_candidates: int,
    *,
    tol: float = 1e-2,
    block_size: int = 128,
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
    block_size : int, default 128
        Columns processed per BLAS-3 step (incoming blocks are re-cut to this size).

    Returns
    -------
    GramSchmidt
        ``(Q, R, kept)``.
    """
    tol = check_tol(tol)
    block_size = check_int(block_size, name="block_size", minimum=1)
    n = mass.shape[0]
    if not np.all(mass > 0):
        raise ValueError(
            "mass must be positive at every row (orthogonalize the rows that carry mass and "
            "copy the result to the others)"
        )
    sqrt_m = np.sqrt(mass)
    basis = _GrowingColumns(n, min(n_candidates, n, 4 * block_size))
    W_buf = np.empty((n, block_size), order="F")
    new_buf = np.empty((n, block_size), order="F")
    projected_buf = np.empty((n, block_size), order="F")
    _SCRATCH.buf = np.empty(n * block_size) if n < PARALLEL_ROWS else None  # see _SCRATCH
    try:
        return _run_blocks(
            blocks, sqrt_m, n_candidates, tol, block_size, basis, W_buf, new_buf, projected_buf
        )
    finally:
        del _SCRATCH.buf


def _run_blocks(
    blocks: Iterable[tuple[int, np.ndarray]],
    sqrt_m: np.ndarray,
    n_candidates: int,
    tol: float,
    block_size: int,
    basis: _GrowingColumns,
    W_buf: np.ndarray,
    new_buf: np.ndarray,
    projected_buf: np.ndarray,
) -> GramSchmidt:
    """Run the block loop of :func:`gram_schmidt_blocks` (its scratch buffer set)."""
    n = sqrt_m.shape[0]
    kept: list[int] = []
    r_blocks: list[tuple[int, np.ndarray]] = []
    expected = 0
    progress = Progress(logger, f"orthogonalization (n={n}): candidate", n_candidates)
    for start, raw in _recut(blocks, block_size):
        progress(start)
        if start != expected:
            raise ValueError(
                f"candidate blocks must be consecutive; expected column {expected}, got {start}"
            )
        b = raw.shape[1]
        expected += b
        if not np.all(np.isfinite(raw)):
            raise ValueError(f"candidates {start}..{start + b - 1} hold NaN or inf values")
        W = W_buf[:, :b]
        np.multiply(raw, sqrt_m[:, None], out=W)
        norm0 = _column_norms(W)
        q_before = basis.size
        n1, coeff_old = _project_out(basis.view, W)
        projected = projected_buf[:, :b]  # W minus its old-basis part, for the in-block rows of R
        projected[...] = W
        new_cols = new_buf[:, :b]
        t = -1
        if tol >= _GRAM_MIN_TOL:
            try:
                t = _select_by_gram(W, new_cols, norm0, tol, start, kept)
            except np.linalg.LinAlgError:  # Cholesky-QR broke down: an ill-conditioned block
                t = -1
            if t < 0:
                logger.debug("block at %d: Gram selection not certified; recursive path", start)
        if t < 0:
            t = _select_in_block(W, new_cols, norm0, n1, basis.view, tol, start, kept)
        _reorthogonalize(basis.view, new_cols[:, :t], seed=start)
        # Eq. (17): R[i, j] = <q_i, b_j>. Older rows are the projection coefficients; rows of
        # the functions kept in this block are their products with the projected block (the
        # old-basis part is orthogonal to them); functions kept later give 0.
        r_new = new_cols[:, :t].T @ projected
        r_blocks.append((start, np.concatenate([coeff_old, r_new]) if q_before else r_new))
        if t:
            basis.extend(new_cols[:, :t], limit=min(n_candidates, n))
    if expected != n_candidates:
        raise ValueError(f"blocks delivered {expected} candidates; expected {n_candidates}")
    q = basis.size
    kept_arr = np.asarray(kept, dtype=np.int64)
    R = np.zeros((q, n_candidates))
    for start, block in r_blocks:
        R[: block.shape[0], start : start + block.shape[1]] = block
    R[kept_arr[:, None] > np.arange(n_candidates)[None, :]] = 0.0
    Q = basis.finish()
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
    block_size: int = 128,
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
    block_size : int, default 128
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
    .. [1] F. Maggioli et al., "Orthogonalized Fourier Polynomials for Signal Approximation
       and Transfer", Computer Graphics Forum 40(2), 2021, Sec. 3.3 (Eq. 15, 17).
       doi:10.1111/cgf.142645
    .. [2] L. Giraud, J. Langou, M. Rozložník, "The loss of orthogonality in the Gram-Schmidt
       orthogonalization process", Computers & Mathematics with Applications 50, 2005.

    Examples
    --------
    >>> import numpy as np
    >>> import o3d_ofp as ofp
    >>> rng = np.random.default_rng(0)
    >>> A = rng.standard_normal((50, 2))
    >>> candidates = np.column_stack([A, A.sum(axis=1)])  # the third depends on the first two
    >>> gs = ofp.gram_schmidt(candidates, np.ones(50))
    >>> gs.Q.shape, gs.kept.tolist()
    ((50, 2), [0, 1])
    >>> bool(np.allclose(gs.Q.T @ gs.Q, np.eye(2)))
    True
    """
    m = np.asarray(mass)
    if m.ndim != 1:
        raise ValueError(f"mass must have shape (n,); got {m.shape}")
    m = as_signal(m, m.shape[0], name="mass")
    if np.any(m <= 0):
        raise ValueError("mass must be positive everywhere")
    B = np.asarray(candidates)  # not copied: only read, block by block (finiteness checked there)
    if not (np.issubdtype(B.dtype, np.floating) or np.issubdtype(B.dtype, np.integer)):
        raise TypeError(f"candidates must be a numeric array; got dtype {B.dtype}")
    if B.ndim == 1:
        B = B[:, None]
    if B.ndim != 2 or B.shape[0] != m.shape[0]:
        raise ValueError(
            f"candidates must have shape (n, P) with n = {m.shape[0]} (the mass); got {B.shape}"
        )
    return gram_schmidt_blocks([(0, B)], m, B.shape[1], tol=tol, block_size=block_size)
