"""The orthonormal eigenproduct basis (Orthogonalized Fourier Polynomials).

``ofp_basis`` takes an :class:`~o3d_ofp.EigenBasis`, builds the eigenproducts of order
``<= N`` of its first ``k`` non-constant eigenfunctions (graded-lexicographic order, the
constant first) and orthonormalizes them under the mass inner product with
:func:`~o3d_ofp.gram_schmidt`.
"""

from __future__ import annotations

import dataclasses
import functools
import logging
import os
import zipfile
import zlib
from typing import Any

import numpy as np

from ._atomic import atomic_path
from ._memory import check_memory
from ._threads import single_threaded_below
from ._validation import as_signal, check_int
from .orthogonalize import PRESETS, gram_schmidt_blocks, resolve_tol
from .products import eigenproduct_blocks, eigenproduct_indices, n_eigenproducts
from .spectrum import EigenBasis, mass_weighted

__all__ = ["OFPBasis", "approximation_error", "check_basis_options", "ofp_basis"]

logger = logging.getLogger(__name__)

_FORMAT_VERSION = 1
#: What reading a damaged ``.npz`` raises: zero bytes, EOFError (or ValueError); cut short,
#: zipfile.BadZipFile; a corrupt member, zlib.error or ValueError; a missing array, KeyError.
_DAMAGED = (EOFError, KeyError, zipfile.BadZipFile, zlib.error, ValueError, OSError)


class _NotABasis(ValueError):
    """A readable ``.npz`` that is not an o3d_ofp basis (or of another format version)."""


def approximation_error(f: Any, f_approx: Any, mass: Any, *, per_channel: bool = False) -> Any:
    """Relative error ``‖f − f̃‖_M / ‖f‖_M`` of an approximation (paper, Sec. 4.3).

    Parameters
    ----------
    f : (n,) or (n, d) array_like of float
        Reference signal.
    f_approx : array_like of float, same shape as ``f``
        Its approximation.
    mass : (n,) array_like of float
        Lumped mass.
    per_channel : bool, default False
        For a multi-channel signal, return one error per channel instead of the joint
        (Frobenius) error ``sqrt(Σ_c ‖f_c − f̃_c‖²_M / Σ_c ‖f_c‖²_M)``.

    Returns
    -------
    float or (d,) ndarray
        The relative error(s); ``inf`` where ``f`` is zero and ``f̃`` is not, 0 where both are.

    Raises
    ------
    ValueError
        If the shapes disagree.

    Examples
    --------
    >>> import numpy as np
    >>> import o3d_ofp as ofp
    >>> f = np.array([1.0, 2.0, 3.0, 4.0])
    >>> mass = np.ones(4)
    >>> round(float(ofp.approximation_error(f, f + 0.1, mass)), 4)
    0.0365
    >>> two = ofp.approximation_error(np.c_[f, f], np.c_[f, f + 0.1], mass, per_channel=True)
    >>> two.round(4).tolist()
    [0.0, 0.0365]
    """
    m = np.asarray(mass, dtype=np.float64)
    if m.ndim != 1:
        raise ValueError(f"mass must have shape (n,); got {m.shape}")
    a = as_signal(f, m.shape[0], name="f")
    b = as_signal(f_approx, m.shape[0], name="f_approx")
    if a.shape != b.shape:
        raise ValueError(f"f_approx must have the shape of f {a.shape}; got {b.shape}")
    if a.ndim == 1:
        a, b = a[:, None], b[:, None]
        per_channel = False
    num = m @ (a - b) ** 2
    den = m @ a**2
    if not per_channel:
        num, den = num.sum(), den.sum()
    with np.errstate(divide="ignore", invalid="ignore"):
        err = np.sqrt(np.where(den > 0, num / den, np.where(num > 0, np.inf, 0.0)))
    return float(err) if np.ndim(err) == 0 else err


@dataclasses.dataclass(frozen=True, eq=False)
class OFPBasis:
    """An orthonormal basis of eigenproducts on one shape.

    Attributes
    ----------
    Q : (n, q) ndarray of float64 (or float32, see :func:`ofp_basis`'s ``dtype``)
        M-orthonormal basis functions, in candidate order.
    R : (q, P) ndarray of float64
        Gram-Schmidt coefficients ``<q_i, b_j>_M`` (Eq. 17); ``Q R`` reproduces the candidates.
    indices : (q,) ndarray of int64
        Position of each kept function in the candidate list ``eigenproduct_indices(k, order)``.
    eig : EigenBasis
        The eigenbasis the products were built from (its first ``k`` non-constant columns).
    k : int
        Number of non-constant eigenfunctions multiplied.
    order : int
        Maximum product order N.
    tol : float
        Relative drop threshold used.

    All arrays are read-only. ``mass`` is the eigenbasis' lumped mass.

    References
    ----------
    .. [1] F. Maggioli, S. Melzi, M. Ovsjanikov, M. M. Bronstein, E. Rodolà, "Orthogonalized
       Fourier Polynomials for Signal Approximation and Transfer", Computer Graphics Forum
       40(2), 2021. doi:10.1111/cgf.142645

    Examples
    --------
    >>> import numpy as np
    >>> import open3d as o3d
    >>> import o3d_ofp as ofp
    >>> sphere = o3d.geometry.TriangleMesh.create_sphere(radius=1.0, resolution=10)
    >>> B = ofp.ofp_basis(ofp.eigenbasis(sphere, k=8), order=2)
    >>> f = np.asarray(sphere.vertices)[:, 2] ** 2
    >>> B.project(f).shape == (B.size,)
    True
    >>> B.approximate(f).shape
    (182,)
    >>> B.approximation_error(f) < 0.01
    True
    """

    Q: np.ndarray
    R: np.ndarray
    indices: np.ndarray
    eig: EigenBasis
    k: int
    order: int
    tol: float

    def __post_init__(self) -> None:
        n, q = self.Q.shape
        if n != self.eig.n_vertices:
            raise ValueError(
                f"Q has {n} rows but the eigenbasis has {self.eig.n_vertices} vertices"
            )
        if self.R.shape != (q, n_eigenproducts(self.k, self.order)) or self.indices.shape != (q,):
            raise ValueError("R and indices do not match Q, k and order")
        for name in ("Q", "R", "indices"):
            getattr(self, name).setflags(write=False)

    @property
    def mass(self) -> np.ndarray:
        """(n,) lumped mass."""
        return self.eig.mass

    @property
    def n_vertices(self) -> int:
        """Number of vertices n."""
        return self.Q.shape[0]

    @property
    def size(self) -> int:
        """Number of basis functions q."""
        return self.Q.shape[1]

    @property
    def products(self) -> list[tuple[int, ...]]:
        """Index tuple of the eigenproduct each basis function comes from (``()`` = constant)."""
        cands = eigenproduct_indices(self.k, self.order)
        return [cands[i] for i in self.indices]

    def project(self, f: Any) -> np.ndarray:
        """Coefficients ``Qᵀ M f``.

        Parameters
        ----------
        f : (n,) or (n, d) array_like of float
            Per-vertex signal.

        Returns
        -------
        (q,) or (q, d) ndarray
            Its coefficients in the basis.
        """
        f = as_signal(f, self.n_vertices)
        Mf = mass_weighted(f, self.mass)
        if self.Q.dtype == np.float32:  # stay in single precision: no float64 copy of Q
            return (self.Q.T @ Mf.astype(np.float32)).astype(np.float64)
        return self.Q.T @ Mf

    def reconstruct(self, coefficients: Any) -> np.ndarray:
        """Signal ``Q c`` from coefficients of shape (q,) or (q, d)."""
        c = as_signal(coefficients, self.size, name="coefficients")
        if self.Q.dtype == np.float32:
            return (self.Q @ c.astype(np.float32)).astype(np.float64)
        return self.Q @ c

    def approximate(self, f: Any) -> np.ndarray:
        """Best approximation ``Q Qᵀ M f`` of ``f`` in the span, shape of ``f``.

        Examples
        --------
        >>> import numpy as np
        >>> import open3d as o3d
        >>> import o3d_ofp as ofp
        >>> sphere = o3d.geometry.TriangleMesh.create_sphere(radius=1.0, resolution=10)
        >>> B = ofp.ofp_basis(ofp.eigenbasis(sphere, k=8), order=2)
        >>> xyz = np.asarray(sphere.vertices)
        >>> B.approximate(xyz).shape  # one column per channel
        (182, 3)
        >>> bool(np.abs(B.approximate(xyz) - xyz).max() < 0.05)
        True
        """
        return self.reconstruct(self.project(f))

    def approximation_error(self, f: Any, *, per_channel: bool = False) -> Any:
        """Relative error ``‖f − Q Qᵀ M f‖_M / ‖f‖_M`` (see :func:`approximation_error`).

        Examples
        --------
        >>> import numpy as np
        >>> import open3d as o3d
        >>> import o3d_ofp as ofp
        >>> sphere = o3d.geometry.TriangleMesh.create_sphere(radius=1.0, resolution=10)
        >>> z = np.asarray(sphere.vertices)[:, 2]
        >>> B2 = ofp.ofp_basis(ofp.eigenbasis(sphere, k=8), order=2)
        >>> B1 = ofp.ofp_basis(ofp.eigenbasis(sphere, k=8), order=1)
        >>> B2.approximation_error(z**2) < B1.approximation_error(z**2)  # z² is a product
        True
        """
        return approximation_error(f, self.approximate(f), self.mass, per_channel=per_channel)

    @functools.cached_property
    def dirichlet_energies(self) -> np.ndarray:
        """(q,) Dirichlet energy ``q_iᵀ L q_i`` of every (unit-norm) basis function."""
        energies = np.einsum("ij,ij->j", self.Q, self.eig.stiffness @ self.Q).astype(np.float64)
        energies.setflags(write=False)
        return energies

    @functools.cached_property
    def energy_order(self) -> np.ndarray:
        """(q,) permutation sorting the basis functions by increasing Dirichlet energy."""
        order = np.argsort(self.dirichlet_energies, kind="stable")
        order.setflags(write=False)
        return order

    def save(self, path: str | os.PathLike[str]) -> None:
        """Write the basis and its eigenbasis to a ``.npz`` file (written atomically).

        Parameters
        ----------
        path : str or os.PathLike
            Destination, a ``.npz`` file.

        Raises
        ------
        ValueError
            For a name without ``.npz`` (NumPy would write another file than the one named),
            as :meth:`o3d_ofp.Correspondence.save` does.
        """
        payload = {
            "format_version": np.int64(_FORMAT_VERSION),
            "Q": self.Q,
            "R": self.R,
            "indices": self.indices,
            "k": np.int64(self.k),
            "order": np.int64(self.order),
            "tol": np.float64(self.tol),
            **self.eig.to_arrays(),
        }
        path = os.fspath(path)
        if not path.endswith(".npz"):
            raise ValueError(f"{path}: a basis is saved as .npz; name it {path}.npz")
        with atomic_path(path, suffix=".npz") as tmp:
            np.savez(tmp, **payload)

    @classmethod
    def load(cls, path: str | os.PathLike[str]) -> OFPBasis:
        """Read a basis written by :meth:`save`.

        Raises
        ------
        FileNotFoundError
            If ``path`` does not exist.
        ValueError
            If the file is not an o3d_ofp basis, its version is unknown, or it is damaged
            (zero bytes, cut short, a corrupt or missing member): a cache treats this as a
            miss and recomputes.
        """
        path = os.fspath(path)
        # Our own handle, closed on every path: np.load leaks the one it opens itself when
        # the zip directory of a cut-short file cannot be read.
        with open(path, "rb") as fh:
            head = fh.read(6)
            fh.seek(0)
            if head.startswith(b"\x93NUMPY"):  # one .npy array
                raise _NotABasis(f"{path!r} is not an o3d_ofp basis file (.npz)")
            if head and not head.startswith(b"PK"):  # np.load would speak of pickles
                raise _NotABasis(
                    f"{path!r} is not an o3d_ofp basis file: not an .npz archive (bases are "
                    "written by OFPBasis.save, o3d-ofp basis or --cache)"
                )
            try:
                data = np.load(fh, allow_pickle=False)
                if not isinstance(data, np.lib.npyio.NpzFile):  # one .npy array
                    raise _NotABasis(f"{path!r} is not an o3d_ofp basis file (.npz)")
                with data:
                    return cls._from_npz(data, path)
            except _NotABasis:
                raise
            except _DAMAGED as exc:
                raise ValueError(
                    f"cannot read basis file {path!r} (damaged or incomplete; recompute it): "
                    f"{type(exc).__name__}: {exc}"
                ) from exc

    @classmethod
    def _from_npz(cls, data: Any, path: str) -> OFPBasis:
        """Build the basis from an open ``np.load`` archive (errors name ``path``)."""
        if "format_version" not in data or int(data["format_version"]) != _FORMAT_VERSION:
            raise _NotABasis(f"{path!r} is not an o3d_ofp basis file (version {_FORMAT_VERSION})")
        eig = EigenBasis.from_arrays(data)
        return cls(
            Q=data["Q"],
            R=data["R"],
            indices=data["indices"],
            eig=eig,
            k=int(data["k"]),
            order=int(data["order"]),
            tol=float(data["tol"]),
        )


def check_basis_options(order: Any, tol: Any, preset: Any) -> tuple[int, float]:
    """Check :func:`ofp_basis`' ``order``, ``tol`` and ``preset``; return ``(order, tol)``.

    Callers that build a basis after expensive work (the eigensolves of a transfer) call it
    first, so that a bad option is refused before that work.
    """
    return check_int(order, name="order", minimum=1), resolve_tol(tol, preset)


def ofp_basis(
    eig: EigenBasis,
    *,
    order: int = 2,
    tol: float | None = None,
    preset: str | None = None,
    k: int | None = None,
    block_size: int = 128,
    dtype: Any = np.float64,
) -> OFPBasis:
    """Build the orthonormal eigenproduct basis of a shape.

    Parameters
    ----------
    eig : EigenBasis
        Laplace-Beltrami eigenbasis (from :func:`o3d_ofp.eigenbasis`).
    order : int, default 2
        Maximum product order N >= 1 (N = 1 gives back the eigenbasis itself).
    tol : float, optional
        Relative drop threshold in (0, 1); default 1e-2 (the "ours" preset).
    preset : {"ours", "ours*"}, optional
        "ours" = 1e-2 (permissive, stable for transfer); "ours*" = 1e-9 (strict, more
        functions, for reconstruction and filtering). Do not combine with a different ``tol``.
    k : int, optional
        Multiply only the first ``k`` non-constant eigenfunctions (default: all of ``eig``).
    block_size : int, default 128
        Columns per BLAS-3 step of the orthogonalization (does not change the result).
    dtype : {numpy.float64, numpy.float32}, default float64
        Storage of Q. The selection and orthogonalization always run in double precision;
        float32 then halves the stored basis (and the memory of projections), at the cost of
        single-precision round-off: measured on FAUST (k = 29) ‖QᵀMQ − I‖ ≈ 5e-9 instead of
        1e-14, approximation errors changed by < 4e-7 relative (see the CHANGELOG).

    Returns
    -------
    OFPBasis
        ``q <= C(k+N, N)`` M-orthonormal functions.

    Raises
    ------
    TypeError, ValueError
        For a non-EigenBasis ``eig``, ``order < 1``, ``tol`` outside (0, 1), unknown preset,
        or ``k`` larger than the eigenbasis.

    References
    ----------
    .. [1] F. Maggioli et al., "Orthogonalized Fourier Polynomials for Signal Approximation
       and Transfer", Computer Graphics Forum 40(2), 2021, Sec. 3.3. doi:10.1111/cgf.142645

    Examples
    --------
    >>> import numpy as np
    >>> import open3d as o3d
    >>> import o3d_ofp as ofp
    >>> sphere = o3d.geometry.TriangleMesh.create_sphere(radius=1.0, resolution=10)
    >>> B = ofp.ofp_basis(ofp.eigenbasis(sphere, k=8), order=2)
    >>> B.n_vertices, B.size <= ofp.n_eigenproducts(8, 2)
    (182, True)
    >>> bool(np.allclose(B.Q.T @ (B.mass[:, None] * B.Q), np.eye(B.size)))  # M-orthonormal
    True
    >>> z = np.asarray(sphere.vertices)[:, 2]
    >>> B.approximation_error(z**2) < 0.01
    True
    """
    if not isinstance(eig, EigenBasis):
        raise TypeError(
            f"eig must be an EigenBasis (from o3d_ofp.eigenbasis); got {type(eig).__name__}"
        )
    order, tol = check_basis_options(order, tol, preset)
    k = eig.k if k is None else check_int(k, name="k", minimum=1, maximum=eig.k)
    if k < eig.k:
        eig = eig.truncate(k)
    block_size = check_int(block_size, name="block_size", minimum=1)
    if np.dtype(dtype) not in (np.float64, np.float32):
        raise ValueError(f"dtype must be float64 or float32; got {dtype!r}")
    total = n_eigenproducts(k, order)
    n = eig.n_vertices
    q_max = min(total, n)  # at most this many functions can be kept
    # Kept basis (resizable storage: up to 2x while growing), R (q, P) and its blocks, and the
    # candidate block with its work buffers; the full (n, P) candidate matrix is never formed.
    check_memory(
        8.0 * (2 * n * q_max + 2 * q_max * total + 5 * n * block_size),
        f"the product basis (n={n}, k={k}, order={order}: {total} candidates)",
    )
    evecs, mass = eig.evecs, eig.mass
    c = eig.cleaning
    if c is not None:
        # Orthogonalize on the cleaned surface (one row per cleaned vertex, carrying its whole
        # mass), then copy rows back to the input's vertices: duplicates and removed vertices
        # hold copies of a cleaned vertex's values, so the M-inner products are the same.
        evecs = evecs[c.representative]
        mass = np.bincount(c.index, weights=eig.mass, minlength=c.n_vertices)
    with single_threaded_below(evecs.shape[0]):
        gs = gram_schmidt_blocks(
            eigenproduct_blocks(evecs, order, block_size=block_size),
            mass,
            total,
            tol=tol,
            block_size=block_size,
        )
    if c is not None:
        gs = gs._replace(Q=np.ascontiguousarray(c.extend(gs.Q)))
    if np.dtype(dtype) == np.float32:
        gs = gs._replace(Q=gs.Q.astype(np.float32))
    name = next((p for p, t in PRESETS.items() if t == tol), f"tol={tol:g}")
    logger.debug(
        "ofp_basis (%s): k=%d order=%d kept %d of %d candidates",
        name,
        k,
        order,
        gs.Q.shape[1],
        total,
    )
    return OFPBasis(Q=gs.Q, R=gs.R, indices=gs.kept, eig=eig, k=k, order=order, tol=tol)
