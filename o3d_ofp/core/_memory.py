"""Memory estimates: refuse a request that cannot fit, with the number, before allocating."""

from __future__ import annotations

import logging
import math

from ._lanczos import MIN_PAIRS, MIN_VERTICES, dense_bytes, fits

__all__ = ["available_memory", "basis_job_bytes", "check_memory", "format_bytes"]

logger = logging.getLogger(__name__)


def available_memory() -> int | None:
    """Bytes of memory the system can give us now (psutil's ``available``), or None if unknown."""
    try:
        import psutil
    except ImportError:  # pragma: no cover - a dependency
        return None
    try:
        return int(psutil.virtual_memory().available)
    except (OSError, RuntimeError, AttributeError):
        return None


def format_bytes(nbytes: float) -> str:
    """Human-readable size, e.g. ``'3.2 GB'``."""
    for unit in ("B", "kB", "MB", "GB", "TB"):
        if abs(nbytes) < 1000 or unit == "TB":
            return f"{nbytes:.3g} {unit}"
        nbytes /= 1000
    raise AssertionError("unreachable")


def check_memory(nbytes: float, what: str, *, limit: float | None = None) -> None:
    """Raise ``ValueError`` when ``nbytes`` exceeds ``limit`` (default: the available memory).

    Parameters
    ----------
    nbytes : float
        Estimated peak bytes of the request.
    what : str
        Description used in the message (e.g. ``"the product basis (k=60, order 3)"``).
    limit : float, optional
        Bytes allowed; default the system's available memory (no check when unknown).
    """
    if limit is None:
        limit = available_memory()
        if limit is None:
            return
    if nbytes > limit:
        raise ValueError(
            f"{what} needs about {format_bytes(nbytes)} of memory, more than the "
            f"{format_bytes(limit)} available; lower k or the order, or use a coarser mesh"
        )
    logger.debug("%s: estimated %s of %s", what, format_bytes(nbytes), format_bytes(limit))


#: Nonzeros of the sparse factor of ``L - sigma M`` per ``n log2 n``: measured with SuperLU
#: (MMD on AᵀA+A, symmetric mode, L and U together) on subdivided spheres: 4.9 at n = 642,
#: 5.9 at 2562, 6.9 at 10242, 8.0 at 40962 (growing by ~1 per 4x; 12 covers n up to ~1e7).
#: CHOLMOD keeps one triangle only, about half of this.
FACTOR_FILL = 12.0
#: Bytes per stored nonzero of a sparse factor: a float64 value and an int32 row index.
_BYTES_PER_NONZERO = 12.0
#: Nonzeros per row of the Laplacian and mass matrices of a triangle mesh (~7 on average) or a
#: k-nearest-neighbour cloud Laplacian; two matrices, CSR, in float64 with int32 indices.
_LAPLACIAN_ROW = 2 * 12 * 12.0


def basis_job_bytes(
    n: int, *, k: int, order: int, eig_k: int | None = None, block_size: int = 128
) -> float:
    """Estimated peak memory of an eigenbasis plus OFP basis computation, in bytes.

    The larger of the two stages: the eigensolve (the Laplacian and mass matrices, the sparse
    factorization of ``L - sigma M`` used by shift-invert, the Lanczos vectors) and the product
    stage (the n x (eig_k+1) eigenbasis kept, the kept basis in storage that grows up to 2x,
    R, and the candidate blocks), plus the input and the finished basis.

    Parameters
    ----------
    n : int
        Vertices of the shape (before cleaning: an upper bound).
    k : int
        Non-constant eigenfunctions multiplied into products.
    order : int
        Product order N.
    eig_k : int, optional
        Eigenfunctions computed (>= k, e.g. for map estimation); default ``k``.
    block_size : int, default 128
        Candidate columns per orthogonalization step.

    Returns
    -------
    float
        Bytes.
    """
    from .products import n_eigenproducts

    eig_k = max(k, eig_k or 0)
    kk = min(eig_k, max(n - 1, 1))
    # (a count beyond 2^62 cannot fit any memory: capped so that the bytes stay a float)
    total = min(n_eigenproducts(min(k, kk), order), 2**62)
    q_max = min(total, n)
    ncv = min(n, max(2 * (kk + 1) + 1, 20))
    matrices = _LAPLACIAN_ROW * n
    factor = FACTOR_FILL * n * math.log2(max(n, 2)) * _BYTES_PER_NONZERO
    eigensolve = matrices + factor + 8.0 * n * (ncv + 3 * (kk + 1))
    if kk + 1 >= MIN_PAIRS and n >= MIN_VERTICES and fits(n, kk + 1):  # block Lanczos (_solve)
        block = matrices + factor + dense_bytes(n, kk + 1) + 16.0 * n * (kk + 1)
        eigensolve = max(eigensolve, block)
    products = matrices + 8.0 * (n * (kk + 1) + 2 * n * q_max + 2 * q_max * total)
    products += 8.0 * 5 * n * block_size  # the candidates, three block buffers, the scratch
    return 8.0 * 3 * n + max(eigensolve, products)
