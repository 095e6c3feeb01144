"""Laplace-Beltrami eigenbasis: the k+1 smallest eigenpairs of ``L φ = λ M φ``.

Conventions (fixed, see ``DESIGN.md``):

* ``k`` counts the non-constant eigenfunctions; an :class:`EigenBasis` holds ``k + 1`` columns.
* Column 0 is the constant ``1 / sqrt(area)``; eigenvalues ascend; columns are M-orthonormal.
* Signs are deterministic and, wherever the shape allows it, independent of vertex order,
  rigid motions and scale (details in ``_fix_signs``): each non-constant eigenfunction is
  flipped so that its third moment ``Σ m_i φ_i³`` is positive. That moment vanishes
  (``|·| sqrt(area) <= 1e-6``) for eigenfunctions odd under a symmetry of the shape, and so
  does every statistic of the eigenfunctions and masses alone; given the vertex positions,
  such an eigenfunction is made positively correlated with a coordinate across the shape,
  oriented by the first moments of the already signed eigenfunctions, which decides those
  odd under a mirror symmetry (bilateral shapes). Otherwise the entry of largest magnitude
  is made positive, which depends on vertex order when mirror vertices tie: eigenfunctions
  odd under a rotational symmetry (which no rule invariant to both rotations and vertex order
  can sign) and shapes with several mirror planes. Inside a
  repeated eigenvalue (e.g. the sphere) the basis of the eigenspace itself is arbitrary, as
  for any eigensolver.
"""

from __future__ import annotations

import dataclasses
import hashlib
import logging
import math
from collections.abc import Mapping
from typing import Any

import numpy as np
import scipy.linalg
import scipy.sparse as sp
import scipy.sparse.linalg as sla

from ._lanczos import MIN_PAIRS, MIN_VERTICES, LanczosNoConvergence, block_lanczos, dense_bytes
from ._lanczos import fits as lanczos_fits
from ._memory import available_memory, check_memory
from ._progress import Progress
from ._threads import one_blas_thread
from ._validation import as_faces, as_signal, as_vertices, check_int
from .cleaning import Cleaning, CleaningReport, CleanShape, clean_shape

__all__ = [
    "DEFAULT_K",
    "DIGEST_OPTIONS",
    "FACTORIZATIONS",
    "EigenBasis",
    "EigenSolverError",
    "check_eigenbasis",
    "eigenbasis",
    "factorize_spd",
    "input_arrays",
    "on_cleaned_vertices",
    "shape_digest",
]


#: Non-constant eigenfunctions of a basis by default: the paper's K = 30 with the constant.
DEFAULT_K = 29

logger = logging.getLogger(__name__)

#: Up to this many vertices the eigenproblem is solved densely (LAPACK); above, by shift-invert
#: Lanczos.
DENSE_MAX_VERTICES = 1500
#: Largest relative residual ‖Lφ − λMφ‖_{M⁻¹} / λ_k accepted. A converged shift-invert Lanczos
#: run gives 1e-10 or better; 1e-6 flags a wrong answer long before it is a visible one.
RESIDUAL_TOL = 1e-6
#: A third moment below this (made dimensionless by sqrt(area)) is treated as zero for the signs.
_SKEW_ZERO = 1e-6


class EigenSolverError(RuntimeError):
    """A sparse factorization or the eigensolver failed.

    The eigensolver's shift-invert system or another symmetric positive definite system of
    ``factorize_spd`` (the detail's heat steps) could not be factorized, or the
    eigensolver did not converge.
    """


def mass_weighted(f: np.ndarray, mass: np.ndarray) -> np.ndarray:
    """``M f`` for a signal of shape (n,) or (n, d), M the diagonal lumped mass."""
    return mass[:, None] * f if f.ndim == 2 else mass * f


@dataclasses.dataclass(frozen=True, eq=False)
class EigenBasis:
    """Laplace-Beltrami eigenpairs of one shape, with the operators they came from.

    Attributes
    ----------
    evals : (k+1,) ndarray of float64
        Eigenvalues, ascending; ``evals[0]`` is 0 up to round-off.
    evecs : (n, k+1) ndarray of float64
        M-orthonormal eigenfunctions; column 0 is the constant ``1/sqrt(area)``.
    mass : (n,) ndarray of float64
        Lumped mass (vertex areas).
    stiffness : (n, n) scipy.sparse.csr_matrix
        Cotangent stiffness matrix ``L``.
    vertices : (n, 3) ndarray of float64
        The vertex positions the basis was computed on.
    faces : (m, 3) ndarray of int64 or None
        The triangles the Laplacian was built on (the input's, cleaned, indexing the input's
        vertices), or ``None`` for a point cloud.
    cleaning : Cleaning or None
        How the input was cleaned (``None``: it was used as given). Welded vertices share
        their representative's values and mass; removed vertices have zero mass and the values
        of the nearest kept vertex.
    digest : str
        Identity of the input and of the options that shaped the basis
        (:func:`shape_digest`); used to check that a saved basis belongs to a mesh.

    All arrays are read-only.
    """

    evals: np.ndarray
    evecs: np.ndarray
    mass: np.ndarray
    stiffness: sp.csr_matrix
    vertices: np.ndarray
    faces: np.ndarray | None = None
    cleaning: Cleaning | None = None
    digest: str = ""

    def __post_init__(self) -> None:
        n = self.mass.shape[0]
        if self.evecs.shape != (n, self.evals.shape[0]):
            raise ValueError(
                f"evecs must have shape (n, k+1) = ({n}, {self.evals.shape[0]}); "
                f"got {self.evecs.shape}"
            )
        if self.stiffness.shape != (n, n) or self.vertices.shape != (n, 3):
            raise ValueError("stiffness and vertices must match the number of vertices of mass")
        L = self.stiffness
        for arr in (self.evals, self.evecs, self.mass, self.vertices, self.faces, L.data,
                    L.indices, L.indptr):  # fmt: skip
            if arr is not None:
                arr.setflags(write=False)

    @property
    def k(self) -> int:
        """Number of non-constant eigenfunctions."""
        return self.evals.shape[0] - 1

    @property
    def n_vertices(self) -> int:
        """Number of vertices."""
        return self.mass.shape[0]

    @property
    def area(self) -> float:
        """Total area (sum of the lumped mass)."""
        return float(self.mass.sum())

    def truncate(self, k: int) -> EigenBasis:
        """Return the basis of the first ``k`` non-constant eigenfunctions (plus the constant)."""
        k = check_int(k, name="k", minimum=1, maximum=self.k)
        return dataclasses.replace(
            self, evals=self.evals[: k + 1].copy(), evecs=self.evecs[:, : k + 1].copy()
        )

    def project(self, f: Any) -> np.ndarray:
        """Spectral coefficients ``Φᵀ M f`` of a signal ``f`` of shape (n,) or (n, d)."""
        f = as_signal(f, self.n_vertices)
        return self.evecs.T @ mass_weighted(f, self.mass)

    def reconstruct(self, coefficients: Any) -> np.ndarray:
        """Signal ``Φ c`` from coefficients of shape (k+1,) or (k+1, d)."""
        c = as_signal(coefficients, self.k + 1, name="coefficients")
        return self.evecs @ c

    def to_arrays(self) -> dict[str, np.ndarray]:
        """Return the basis as named arrays, for ``np.savez`` (read by :meth:`from_arrays`).

        Returns
        -------
        dict of str to ndarray
            ``evals`` (k+1,), ``evecs`` (n, k+1), ``mass`` (n,), ``vertices`` (n, 3),
            ``faces`` (m, 3) (zero rows for a point cloud), the stiffness as CSR arrays
            ``L_data``/``L_indices``/``L_indptr``, ``digest``, and ``clean_*`` when the input
            was cleaned.
        """
        L = self.stiffness
        arrays: dict[str, np.ndarray] = {
            "evals": self.evals,
            "evecs": self.evecs,
            "mass": self.mass,
            "vertices": self.vertices,
            "faces": self.faces if self.faces is not None else np.zeros((0, 3), np.int64),
            "L_data": L.data,
            "L_indices": L.indices,
            "L_indptr": L.indptr,
            "digest": np.array(self.digest),
        }
        if self.cleaning is not None:
            c = self.cleaning
            arrays["clean_index"] = c.index
            arrays["clean_kept"] = c.kept
            arrays["clean_representative"] = c.representative
            arrays["clean_report"] = c.report.as_array()
        return arrays

    @classmethod
    def from_arrays(cls, data: Mapping[str, np.ndarray]) -> EigenBasis:
        """Rebuild a basis from :meth:`to_arrays`' arrays (e.g. an open ``np.load`` file).

        Raises
        ------
        KeyError
            If an array is missing.
        ValueError
            If the arrays do not fit together.
        """
        n = data["mass"].shape[0]
        stiffness = sp.csr_matrix(
            (data["L_data"], data["L_indices"], data["L_indptr"]), shape=(n, n)
        )
        cleaning = None
        if "clean_index" in data:
            report = CleaningReport.from_array(data["clean_report"])
            cleaning = Cleaning(
                data["clean_index"], data["clean_kept"], data["clean_representative"], report
            )
        evals, evecs, mass, vertices = (data[a] for a in ("evals", "evecs", "mass", "vertices"))
        faces = data["faces"] if data["faces"].shape[0] else None
        digest = str(data["digest"]) if "digest" in data else ""
        return cls(evals, evecs, mass, stiffness, vertices, faces, cleaning, digest)


def check_eigenbasis(eig: Any, name: str = "eig") -> EigenBasis:
    """Return ``eig`` if it is an :class:`EigenBasis`, else raise a ``TypeError`` naming ``name``.

    Parameters
    ----------
    eig : object
        What the caller was given.
    name : str, default "eig"
        The keyword it was given as (for the message).

    Returns
    -------
    EigenBasis
    """
    if not isinstance(eig, EigenBasis):
        raise TypeError(f"{name} must be an EigenBasis; got {type(eig).__name__}")
    return eig


def _dense_eigs(
    stiffness: sp.csr_matrix, mass: np.ndarray, k: int
) -> tuple[np.ndarray, np.ndarray]:
    return scipy.linalg.eigh(stiffness.toarray(), np.diag(mass), subset_by_index=[0, k])


#: Factorizations of L − σM for shift-invert: "cholmod" (CHOLMOD's supernodal Cholesky from
#: the self-contained ``cholespy`` wheels) or "superlu" (SciPy). "auto" takes CHOLMOD when it
#: can be imported and falls back to SuperLU, with a log message, when it cannot or fails.
FACTORIZATIONS = ("auto", "cholmod", "superlu")


def _cholmod_operator(A: sp.csc_matrix) -> sla.LinearOperator:
    from cholespy import CholeskySolverD, MatrixType

    n = A.shape[0]
    A = sp.csc_matrix(A)
    A.sort_indices()
    solver = CholeskySolverD(
        n,
        np.ascontiguousarray(A.indptr, dtype=np.int32),
        np.ascontiguousarray(A.indices, dtype=np.int32),
        np.ascontiguousarray(A.data, dtype=np.float64),
        MatrixType.CSC,
    )

    def solve(b: np.ndarray) -> np.ndarray:
        rhs = np.ascontiguousarray(b, dtype=np.float64)
        rhs = rhs.reshape(n) if rhs.ndim == 1 or rhs.shape[1] == 1 else rhs
        x = np.empty_like(rhs)
        solver.solve(rhs, x)  # (n, b): one pass over the factor for the whole block
        return x.reshape(b.shape)

    return sla.LinearOperator((n, n), matvec=solve, matmat=solve, dtype=np.float64)


def _superlu_operator(A: sp.csc_matrix) -> sla.LinearOperator:
    # Symmetric mode with a minimum-degree ordering of AᵀA+A: half the fill and factor time
    # of SuperLU's default COLAMD ordering on Laplacians.
    lu = sla.splu(
        A, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0, options={"SymmetricMode": True}
    )
    return sla.LinearOperator(A.shape, matvec=lu.solve, matmat=lu.solve, dtype=np.float64)


def _factorize(A: sp.csc_matrix, sigma: float, factorization: str) -> tuple[Any, str]:
    """Return (operator x ↦ A⁻¹x, backend name) of ``A = L − σM``; CHOLMOD first."""
    return factorize_spd(
        A, factorization=factorization, what=f"L - sigma*M (sigma={sigma:.3g})",
        singular="The Laplacian is numerically singular: look for degenerate or duplicated "
        "triangles",
    )  # fmt: skip


def factorize_spd(
    A: sp.spmatrix, *, factorization: str = "auto", what: str = "the matrix", singular: str = ""
) -> tuple[sla.LinearOperator, str]:
    """Factorize a sparse symmetric positive definite matrix once, for many solves.

    The rule of the eigensolver's shift-invert and the detail's heat steps: CHOLMOD's
    supernodal Cholesky (``cholespy``) when it can be imported, else SciPy's SuperLU in
    symmetric mode (logged). Measured on a 110k-vertex FAUST body, ``M + t L``, one BLAS
    thread: factorization 1.8 s (SuperLU 1.4-1.7 s), a solve of three columns 0.024 s (SuperLU
    0.09 s as a block, 0.17 s column by column).

    Parameters
    ----------
    A : (n, n) sparse matrix
        Symmetric positive definite.
    factorization : {"auto", "cholmod", "superlu"}
        The backend; "auto" falls back to SuperLU when CHOLMOD is missing or fails.
    what, singular : str
        How messages name ``A``, and what they advise when it cannot be factorized.

    Returns
    -------
    operator : LinearOperator
        ``x ↦ A⁻¹x`` for a vector (n,) or a block (n, b) (one pass for the whole block).
    backend : str
        "cholmod" or "superlu".

    Raises
    ------
    EigenSolverError
        Neither backend could factorize ``A``.
    """
    if factorization not in FACTORIZATIONS:
        raise ValueError(f"factorization must be one of {FACTORIZATIONS}; got {factorization!r}")
    A = sp.csc_matrix(A)
    n = A.shape[0]
    if factorization in ("auto", "cholmod"):
        try:
            return _cholmod_operator(A), "cholmod"
        except ImportError as exc:
            if factorization == "cholmod":
                raise ValueError(
                    "factorization='cholmod' needs the cholespy package (pip install cholespy)"
                ) from exc
            logger.info("cholespy is not installed: factorizing with SuperLU (slower)")
        except (ValueError, RuntimeError) as exc:
            if factorization == "cholmod":
                raise EigenSolverError(
                    f"CHOLMOD could not factorize {what} (n={n}): {exc}"
                ) from exc
            logger.warning("CHOLMOD failed (%s); falling back to SuperLU", exc)
    try:
        return _superlu_operator(A), "superlu"
    except RuntimeError as exc:
        raise EigenSolverError(
            f"could not factorize {what} (n={n}): {exc}" + (f". {singular}" if singular else "")
        ) from exc


#: Solves of ARPACK's shift-invert Lanczos per wanted eigenpair, for the progress estimate:
#: measured 2.5-3.8 (FAUST at 6.9k and 27.5k vertices, a torus, a blob; k = 29, 39 and 99; the
#: same count at both FAUST sizes: it follows the spectrum, not the vertex count). Block Lanczos
#: reports its Krylov space against its usual size (see ``_lanczos.krylov_dim``).
_SOLVES_PER_PAIR = 3.0


def _counted(solve: Any, n: int, k: int, expected: int) -> Any:
    """Wrap ``solve`` (of one vector or a block) to report Lanczos' progress.

    ARPACK says nothing until it ends (20-40 s on a 440k-vertex shape): the count of solved
    vectors against the usual count is the only measure there is.
    """
    progress = Progress(
        logger, f"eigenbasis: n={n} k={k}: Lanczos step", expected, about=True
    )  # fmt: skip
    count = 0

    def counted(b: np.ndarray) -> np.ndarray:
        nonlocal count
        count += 1 if b.ndim == 1 else b.shape[1]
        progress(count)
        return solve(b)

    return counted


def _shift_invert_eigs(
    stiffness: sp.csr_matrix,
    mass: np.ndarray,
    k: int,
    *,
    maxiter: int,
    shift: float = 0.01,
    ncv: int | None = None,
    seed: int = 0,
    factorization: str = "auto",
    block: bool = False,
) -> tuple[np.ndarray, np.ndarray]:
    n = mass.shape[0]
    area = float(mass.sum())
    # Shift just left of 0 at a fraction (1 % by default) of Weyl's estimate of the first
    # eigenvalue (4π/area): L − σM is then positive definite with a condition number ~ 100·n,
    # and σ scales with the mesh, so the whole computation is invariant to uniform scaling.
    sigma = -shift * 4.0 * math.pi / area
    M = sp.diags(mass, format="csc")
    shifted = (stiffness - sigma * M).tocsc()
    op, backend = _factorize(shifted, sigma, factorization)
    logger.debug("shift-invert: sigma=%.3g, factorization %s", sigma, backend)
    if block:
        return _block_eigs(op, mass, sigma, k, seed=seed)
    solve = _counted(op.matvec, n, k, round(_SOLVES_PER_PAIR * (k + 1)))
    op = sla.LinearOperator(op.shape, matvec=solve, dtype=op.dtype)
    v0 = np.random.default_rng(seed).standard_normal(n)  # fixed start: reproducible runs
    # tol=0: machine precision. A looser tol (1e-10) halves the Lanczos work on FAUST but misses
    # copies of repeated eigenvalues (measured on the sphere: one of the five λ = 6 replaced by
    # λ = 12), which no residual check can see.
    try:
        evals, evecs = sla.eigsh(stiffness, k=k + 1, M=M, sigma=sigma, which="LM", OPinv=op,
                                 v0=v0, ncv=ncv, maxiter=maxiter, tol=0.0)  # fmt: skip
    except sla.ArpackNoConvergence as exc:
        raise EigenSolverError(
            f"the eigensolver did not converge within maxiter={maxiter} restarts for k={k} on "
            f"{n} vertices ({len(exc.eigenvalues)} of {k + 1} eigenpairs converged); try a "
            "smaller k or a larger maxiter"
        ) from exc
    except sla.ArpackError as exc:
        raise EigenSolverError(f"ARPACK failed for k={k} on {n} vertices: {exc}") from exc
    if not (np.all(np.isfinite(evals)) and np.all(np.isfinite(evecs))):
        raise EigenSolverError(f"ARPACK returned non-finite eigenpairs for k={k} on {n} vertices")
    return evals, evecs


def _block_eigs(
    op: sla.LinearOperator, mass: np.ndarray, sigma: float, k: int, *, seed: int
) -> tuple[np.ndarray, np.ndarray]:
    """Block Lanczos (``_lanczos``) on the symmetric ``M^½ (L − σM)⁻¹ M^½``: λ = σ + 1/θ."""
    n = mass.shape[0]
    root = np.sqrt(mass)[:, None]
    solve = _counted(op.matmat, n, k, 2 * (k + 1) + 200)  # the usual space (see krylov_dim)

    def apply(X: np.ndarray) -> np.ndarray:
        return root * solve(root * X)

    try:
        theta, Y = block_lanczos(apply, n, k + 1, seed=seed)
    except LanczosNoConvergence as exc:
        raise EigenSolverError(f"block Lanczos, k={k} on {n} vertices: {exc}") from exc
    if not (np.all(np.isfinite(theta)) and np.all(np.isfinite(Y)) and np.all(theta > 0)):
        raise EigenSolverError(f"block Lanczos gave invalid eigenpairs for k={k} on {n} vertices")
    return sigma + 1.0 / theta, Y / root


def _rayleigh_ritz(
    stiffness: sp.csr_matrix, mass: np.ndarray, evecs: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Re-solve the problem in span(evecs): exactly M-orthonormal vectors, best eigenvalues."""
    Lr = evecs.T @ (stiffness @ evecs)
    Mr = evecs.T @ (mass[:, None] * evecs)
    Lr = 0.5 * (Lr + Lr.T)
    Mr = 0.5 * (Mr + Mr.T)
    theta, Y = scipy.linalg.eigh(Lr, Mr)
    return theta, evecs @ Y


def _fix_signs(
    evecs: np.ndarray, mass: np.ndarray, vertices: np.ndarray | None = None
) -> np.ndarray:
    """Give each eigenfunction a sign independent of vertex order, rigid motions and scale.

    Parameters
    ----------
    evecs : (n, k) ndarray
        Non-constant eigenfunctions, M-orthonormal and M-orthogonal to the constant, in
        ascending order of eigenvalue.
    mass : (n,) ndarray
        Lumped mass.
    vertices : (n, 3) ndarray, optional
        The positions the Laplacian was built on; without them step 2 is skipped.

    Returns
    -------
    (n, k) ndarray
        ``evecs`` with each column multiplied by +1 or -1.

    Notes
    -----
    With ``f = sqrt(area) φ`` (unit RMS), ``w = m / area`` and "vanishing" meaning
    ``|·| <= 1e-6`` (``_SKEW_ZERO``), each column is made to satisfy the first that applies of:

    1. ``Σ w f³ > 0``. All odd moments ``Σ w f^(2j+1)`` vanish together for an eigenfunction
       that is odd under a symmetry of the shape (``f∘σ = -f``), so higher odd moments add
       nothing; and so does any statistic of the eigenfunctions and the mass alone, which
       are the same for the shape and its mirror image.
    2. (``vertices`` given) ``Σ w f h z > 0`` for the first ``h`` in ``1, s_1 f_1, s_2 f_2, ...``
       (the columns signed by step 1, in order) where it does not vanish (as a correlation
       ``Σ w f h z / sqrt(Σ w (h z)²)``). ``z = ν·(x - c) / r`` is a coordinate across the
       shape: ``c`` the centroid, ``r`` the RMS radius, and ``ν = u_a × u_b / |u_a × u_b|``
       the orientation of the first moments ``u_j = Σ w s_j f_j (x - c) / r`` of the
       step-1 columns, ``a`` the first with ``|u_a| > 0.05`` and ``b`` the next with
       ``|û_a × u_b| > 0.05`` (step skipped if there is none). ``z`` is invariant to rigid
       motions and scale and changes sign in a mirror image, so this decides the
       eigenfunctions that are odd under a mirror symmetry of the shape (bilateral symmetry:
       a mirror plane and no other symmetry, as for human and animal bodies), with the same
       result for every vertex order and pose.
    3. The entry of largest magnitude is positive.

    Step 3 depends on the vertex order whenever opposite entries tie in magnitude, which is
    the case for eigenfunctions odd under a symmetry that steps 1-2 cannot decide: a
    proper rotation (e.g. a 180° turn), because no rule invariant both to vertex order and
    to rotations can (the turned shape is the same shape with its vertices permuted, and the
    eigenfunction changes sign); and, by this rule, shapes with two or more mirror planes
    (their step-1 moments span at most a line). Inside a repeated eigenvalue the basis of
    the eigenspace is itself arbitrary, as for any eigensolver.
    """
    area = float(mass.sum())
    root = math.sqrt(area)
    # products, not evecs**3: glibc's pow takes a slow path on negative bases (27.5k x 99:
    # 0.17 s against 6 ms)
    skew = root * (mass @ (evecs * evecs * evecs))
    sign = np.where(np.abs(skew) > _SKEW_ZERO, np.sign(skew), 0.0)
    open_ = np.flatnonzero(sign == 0.0)
    done = np.flatnonzero(sign != 0.0)
    if vertices is not None and open_.size and done.size >= 2:
        w = mass / area
        Y = vertices - w @ vertices
        radius = math.sqrt(float(w @ np.einsum("ij,ij->i", Y, Y)))
        Y = Y / radius if radius > 0.0 else Y
        U = (evecs.T @ (w[:, None] * Y))[done] * (root * sign[done, None])  # |u_j| <= 1
        norms = np.linalg.norm(U, axis=1)
        normal = None
        large = np.flatnonzero(norms > 0.05)
        if large.size:
            a = int(large[0])
            cross = np.cross(U[a] / norms[a], U[a + 1 :])
            size = np.linalg.norm(cross, axis=1)
            apart = np.flatnonzero(size > 0.05)
            if apart.size:
                normal = cross[apart[0]] / size[apart[0]]
        if normal is not None:
            z = Y @ normal
            corr = root * (evecs.T @ (w * z))[open_] / math.sqrt(float(w @ z**2))
            hit = np.abs(corr) > _SKEW_ZERO
            sign[open_[hit]] = np.sign(corr[hit])
            open_ = open_[~hit]
            E = evecs[:, open_]  # usually empty by now: h = s_j f_j is the rare second try
            for h in done if open_.size else ():
                g = z * (root * sign[h] * evecs[:, h])
                corr = root * ((w * g) @ E) / math.sqrt(float(w @ g**2))
                hit = np.abs(corr) > _SKEW_ZERO
                sign[open_[hit]] = np.sign(corr[hit])
                open_, E = open_[~hit], E[:, ~hit]
                if not open_.size:
                    break
    if open_.size:
        peak = evecs[np.argmax(np.abs(evecs[:, open_]), axis=0), open_]
        sign[open_] = np.where(peak < 0.0, -1.0, 1.0)
    return evecs * sign


def _relative_residuals(
    stiffness: sp.csr_matrix, mass: np.ndarray, evals: np.ndarray, evecs: np.ndarray
) -> np.ndarray:
    R = stiffness @ evecs - (mass[:, None] * evecs) * evals
    dual = np.sqrt(np.sum(R * R / mass[:, None], axis=0))  # ‖r‖_{M⁻¹}, the natural norm of L φ
    return dual / max(float(evals[-1]), np.finfo(float).tiny)


#: Attempts of the sparse solver, in order: (shift as a fraction of 4π/area, ncv factor (0: the
#: default 1.5 (k+1) + ...), seed).
#: A failed factorization, an unconverged Lanczos run or a failed residual check moves on to
#: the next, each logged as a warning; the last failure is raised.
_ATTEMPTS = ((0.01, 0, 0), (0.1, 4, 1), (1.0, 6, 2))
#: After the sparse attempts, problems up to this size are solved densely as a last resort.
_DENSE_FALLBACK_MAX = 4000


#: Above this share of the vertices, eigenpairs are computed densely (LAPACK) when the shape
#: has at most :data:`_DENSE_LARGE_K_MAX` vertices: Lanczos then needs nearly n vectors and
#: restarts (measured, k = 5001 on 6890 vertices: Lanczos unfinished after 14 minutes, the
#: dense solve 280 s on one BLAS thread).
_DENSE_K_SHARE = 0.25
_DENSE_LARGE_K_MAX = 12_000


def _block_fits(n: int, k: int) -> bool:
    """Whether block Lanczos suits ``k + 1`` pairs of ``n`` vertices and fits in memory.

    It keeps up to ``krylov_dim`` vectors where ARPACK keeps ``ncv`` (about 1.5 (k+1)), and
    its space must stay small beside n (``_lanczos.fits``); otherwise ARPACK runs alone.
    """
    if not lanczos_fits(n, k + 1):
        return False
    available = available_memory()
    return available is None or dense_bytes(n, k + 1) < 0.5 * available


def _dense_for_large_k(n: int, k: int) -> bool:
    return n <= _DENSE_LARGE_K_MAX and (k + 1) > _DENSE_K_SHARE * n


@one_blas_thread  # Lanczos' many BLAS-2 calls: threads only spin (see _threads)
def _solve(
    shape: CleanShape, k: int, maxiter: int, factorization: str
) -> tuple[np.ndarray, np.ndarray]:
    """Return a cleaned shape's eigenpairs, constant first, checked; retried as ``_ATTEMPTS`` says.

    The memory they need is checked first.
    """
    stiffness, mass, vertices = shape.stiffness, shape.mass, shape.vertices
    n = mass.shape[0]
    default_ncv = min(n, max(2 * (k + 1) + 1, 20))  # ARPACK's own Krylov space
    check_memory(
        8.0 * n * (default_ncv + 3 * (k + 1))
        + (8.0 * n * n if n <= _DENSE_FALLBACK_MAX else 0.0)
        + (3 * 8.0 * n * n if _dense_for_large_k(n, k) else 0.0),
        f"the eigensolver (n={n}, k={k})",
    )
    plans: list[tuple[str, dict[str, Any]]] = []
    if n <= DENSE_MAX_VERTICES or k + 2 >= n:  # ARPACK needs k + 1 < n - 1 eigenpairs
        plans.append(("dense", {}))
    elif _dense_for_large_k(n, k):
        logger.info(
            "eigenbasis: %d eigenpairs of %d vertices, a large share: dense LAPACK (about "
            "n³ work: 5001 eigenpairs of a 6890-vertex shape took 4.7 min)", k + 1, n,
        )  # fmt: skip
        plans.append(("dense", {}))
    else:
        if k + 1 >= MIN_PAIRS and n >= MIN_VERTICES and _block_fits(n, k):
            plans.append(("block Lanczos", {"factorization": factorization, "block": True}))
        for shift, ncv_factor, seed in _ATTEMPTS:
            # 1.5 (k+1) Lanczos vectors first (ARPACK's default is 2 (k+1) + 1): measured 20 %
            # less time at k = 99 on FAUST with the same residuals; retries use more.
            ncv = max(ncv_factor * (k + 1), 20) if ncv_factor else k + 1 + max(20, (k + 1) // 2)
            options = {"shift": shift, "ncv": min(n - 1, ncv), "seed": seed}
            plans.append(("shift-invert Lanczos", {**options, "factorization": factorization}))
        if n <= _DENSE_FALLBACK_MAX:
            plans.append(("dense", {}))
    last: Exception | None = None
    for attempt, (method, options) in enumerate(plans):
        if attempt == 1 and plans[0][0] == "block Lanczos":
            # the fast path gave up: the usual solver takes over, nothing for the user to do
            logger.info("eigensolver: %s; ARPACK takes over", last)
        elif attempt:  # every result is checked below: a retry that passes is as good
            logger.info("eigensolver attempt %d did not pass (%s); retrying with %s %s",
                        attempt, last, method, options)  # fmt: skip
        try:
            if method == "dense":
                evals, evecs = _dense_eigs(stiffness, mass, k)
            else:
                evals, evecs = _shift_invert_eigs(stiffness, mass, k, maxiter=maxiter, **options)
            evals, evecs = _finish(stiffness, mass, evals, evecs, method, k, vertices)
        except (EigenSolverError, np.linalg.LinAlgError) as exc:
            last = exc
            continue
        res = _relative_residuals(stiffness, mass, evals, evecs)
        worst = int(np.argmax(res))
        if res[worst] <= RESIDUAL_TOL:
            logger.debug("eigenbasis: n=%d k=%d via %s, λ_k=%.6g, max relative residual %.2e",
                         n, k, method, evals[-1], res[worst])  # fmt: skip
            return evals, evecs
        last = EigenSolverError(
            f"eigenpair {worst} (λ={evals[worst]:.6g}) has relative residual {res[worst]:.3g} > "
            f"{RESIDUAL_TOL:g} after {method} on {n} vertices, k={k}: the solver did not converge"
        )
    assert last is not None
    if len(plans) > 1:
        raise EigenSolverError(
            f"all {len(plans)} eigensolver attempts failed; last: {last}"
        ) from last
    raise last


def _finish(
    stiffness: sp.csr_matrix,
    mass: np.ndarray,
    evals: np.ndarray,
    evecs: np.ndarray,
    method: str,
    k: int,
    vertices: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Rayleigh-Ritz, ascending order, exact constant first, deterministic signs."""
    n = mass.shape[0]
    evals, evecs = _rayleigh_ritz(stiffness, mass, evecs)
    order = np.argsort(evals, kind="stable")
    evals, evecs = evals[order], evecs[:, order]
    area = float(mass.sum())
    const = np.full(n, 1.0 / math.sqrt(area))
    overlap = abs(float(const @ (mass * evecs[:, 0])))
    if overlap < 1.0 - 1e-6:
        raise EigenSolverError(
            f"the first eigenfunction from {method} is not constant (M-overlap with the constant "
            f"{overlap:.6f}); the Laplacian is not that of one connected surface"
        )
    evecs[:, 0] = const
    evals[0] = 0.0
    # Keep the rest exactly M-orthogonal to the now exact constant.
    evecs[:, 1:] -= np.outer(const, const @ (mass[:, None] * evecs[:, 1:]))
    evecs[:, 1:] /= np.sqrt(mass @ evecs[:, 1:] ** 2)
    evecs[:, 1:] = _fix_signs(evecs[:, 1:], mass, vertices)
    return evals, evecs


def _expand(
    shape: CleanShape, evals: np.ndarray, evecs: np.ndarray, vertices: np.ndarray, digest: str
) -> EigenBasis:
    """Carry a cleaned shape's eigenpairs, mass, stiffness and faces to the input vertices.

    A welded vertex gets its representative's values and an equal share of its mass; a removed
    vertex gets the nearest kept vertex's values and zero mass. With ``A`` the (n_c, n_in)
    averaging matrix (row sums 1, ``A Φ_in = Φ_c``), the stiffness ``AᵀLA`` and the mass keep
    every inner product and Dirichlet energy of the cleaned shape.
    """
    c = shape.cleaning
    faces = None if shape.faces is None else c.representative[shape.faces]
    mass, stiffness = shape.mass, shape.stiffness
    if c.report.changed:
        idx, kept = c.index, c.kept
        mult = c.multiplicity.astype(np.float64)
        share = np.where(kept, 1.0 / mult[idx], 0.0)
        mass = shape.mass[idx] * share
        A = sp.csr_matrix((share, (idx, np.arange(c.n_input))), shape=(c.n_vertices, c.n_input))
        stiffness = sp.csr_matrix(A.T @ shape.stiffness @ A)
        stiffness.sum_duplicates()
        evecs = c.extend(evecs)
    evals, evecs = np.ascontiguousarray(evals), np.ascontiguousarray(evecs)
    cleaning = c if c.report.changed else None
    return EigenBasis(evals, evecs, mass, stiffness, vertices, faces, cleaning, digest)


#: Options of :func:`eigenbasis` that change the basis of a given input (besides ``k``).
DIGEST_OPTIONS = ("weld_tolerance", "components", "mollify_factor", "n_neighbors")


def input_arrays(vertices: Any, faces: Any) -> tuple[np.ndarray, np.ndarray | None]:
    """Return validated float64 copies of vertices (n, 3) and faces (m, 3) (or None)."""
    vertices = as_vertices(vertices)
    faces = None if faces is None else as_faces(faces, vertices.shape[0])
    return vertices, faces


def shape_digest(
    vertices: Any,
    faces: Any = None,
    *,
    weld_tolerance: float | None = 1e-9,
    components: str = "auto",
    mollify_factor: float = 1e-5,
    n_neighbors: int = 30,
) -> str:
    """Identify a shape and the options its eigenbasis depends on (``EigenBasis.digest``).

    Parameters
    ----------
    vertices, faces, weld_tolerance, components, mollify_factor, n_neighbors
        As in :func:`eigenbasis`.

    Returns
    -------
    str
        A 32-character hex digest: equal inputs and options give equal digests.
    """
    vertices, faces = input_arrays(vertices, faces)
    return _digest(vertices, faces, weld_tolerance, components, mollify_factor, n_neighbors)


def _digest(
    vertices: np.ndarray,
    faces: np.ndarray | None,
    weld_tolerance: float | None,
    components: str,
    mollify_factor: float,
    n_neighbors: int,
) -> str:
    """BLAKE2b-128 hex digest of validated arrays and of the options their basis depends on."""
    # n_neighbors shapes only a cloud's basis
    options = {"weld_tolerance": weld_tolerance, "components": components,
               "mollify_factor": float(mollify_factor),
               "n_neighbors": n_neighbors if faces is None else None}  # fmt: skip
    h = hashlib.blake2b(digest_size=16)
    h.update(np.ascontiguousarray(vertices, dtype=np.float64).tobytes())
    h.update(b"|faces|")
    if faces is not None:
        h.update(np.ascontiguousarray(faces, dtype=np.int64).tobytes())
    h.update(repr(sorted(options.items())).encode())
    return h.hexdigest()


def eigenbasis(
    vertices: Any,
    faces: Any = None,
    *,
    k: int = DEFAULT_K,
    weld_tolerance: float | None = 1e-9,
    components: str = "auto",
    mollify_factor: float = 1e-5,
    n_neighbors: int = 30,
    maxiter: int | None = None,
    clamp_k: bool = False,
    factorization: str = "auto",
) -> EigenBasis:
    """Compute the ``k + 1`` smallest Laplace-Beltrami eigenpairs of a mesh or point cloud.

    The input is first cleaned by :func:`o3d_ofp.clean_shape` (duplicated vertices
    welded, degenerate/duplicated faces and unreferenced vertices removed, stray components
    handled by ``components``); the eigenpairs of the cleaned surface are then given on the
    caller's **original** vertices (see :attr:`EigenBasis.cleaning`).

    Parameters
    ----------
    vertices : (n, 3) array_like of float
        Vertex (point) positions. (``o3d_ofp.eigenbasis``, the package-level function, also
        takes an Open3D geometry here.)
    faces : (m, 3) array_like of int, optional
        Triangles; ``None`` for a point cloud.
    k : int, default 29
        Number of non-constant eigenfunctions (the paper's K = 30 is ``k=29``); ``1 <= k < n``
        with n the number of vertices after cleaning.
    weld_tolerance : float or None, default 1e-9
        Relative distance (to the bounding box's largest side) under which vertices are welded.
    components : {"auto", "largest", "error"}, default "auto"
        Policy for several connected components (:func:`o3d_ofp.clean_shape`): "auto" keeps the
        largest when it holds ≥ 90 % of the area, else raises.
    mollify_factor, n_neighbors : float, int
        Passed to :func:`o3d_ofp.laplacian` (default 1e-5; 30 neighbours per point
        of a point cloud).
    maxiter : int, optional
        Bound on the Lanczos restarts per attempt (default ``max(1000, 10 (k + 1))``).
    clamp_k : bool, default False
        Reduce a ``k`` the cleaned shape cannot hold to ``n − 1`` (with a warning), not raise.
    factorization : {"auto", "cholmod", "superlu"}, default "auto"
        Sparse factorization of ``L − σM`` for shift-invert: CHOLMOD's supernodal Cholesky
        (from the ``cholespy`` wheels; 5-20× faster to factor than SuperLU on 50k-500k
        vertices) when it can be imported, else SciPy's SuperLU (logged).

    Returns
    -------
    EigenBasis
        Eigenvalues ``(k+1,)`` ascending, M-orthonormal eigenvectors ``(n, k+1)`` with the
        constant first and deterministic signs, the lumped mass and the stiffness matrix, all
        on the input's n vertices.

    Raises
    ------
    TypeError, ValueError
        On malformed input, ``k`` out of range, a shape that is no surface once cleaned, or
        several comparable components.
    EigenSolverError
        If every solver attempt fails (see Notes).

    Notes
    -----
    Small problems (``n <= DENSE_MAX_VERTICES``) are solved densely. Otherwise ARPACK's
    shift-invert Lanczos runs on ``L − σM`` (σ = −0.01·4π/area, scale-invariant) factorized
    once (CHOLMOD or SuperLU, see ``factorization``). A Rayleigh-Ritz step on the converged
    subspace makes the vectors M-orthonormal to round-off; every residual
    ``‖Lφ − λMφ‖_{M⁻¹} / λ_k`` is then checked against ``RESIDUAL_TOL``. When the
    factorization fails, Lanczos does not converge within ``maxiter`` or a check fails, the
    solve is retried (logged as a warning) with a shift 10× and 100× further from the
    spectrum and a larger Krylov space, and finally, for at most 4000 vertices, densely; only
    then is :class:`EigenSolverError` raised.

    References
    ----------
    .. [1] F. Maggioli, S. Melzi, M. Ovsjanikov, M. M. Bronstein, E. Rodolà, "Orthogonalized
       Fourier Polynomials for Signal Approximation and Transfer", Computer Graphics Forum
       40(2), 2021 (Eurographics). doi:10.1111/cgf.142645
    """
    vertices, faces = input_arrays(vertices, faces)
    k = check_int(k, name="k", minimum=1)
    if factorization not in FACTORIZATIONS:
        raise ValueError(f"factorization must be one of {FACTORIZATIONS}; got {factorization!r}")
    if maxiter is None:
        maxiter = max(1000, 10 * (k + 1))
    maxiter = check_int(maxiter, name="maxiter", minimum=1)
    values = (weld_tolerance, components, mollify_factor, n_neighbors)
    options = dict(zip(DIGEST_OPTIONS, values, strict=True))  # the cleaning's, and the digest's
    shape = clean_shape(vertices, faces, **options)
    k = _fitted_k(k, shape, clamp_k)
    evals, evecs = _solve(shape, k, maxiter, factorization)
    return _expand(shape, evals, evecs, vertices, _digest(vertices, faces, **options))


def _fitted_k(k: int, shape: CleanShape, clamp_k: bool) -> int:
    """Check ``k`` against the cleaned shape's vertices (reduced to n − 1 with ``clamp_k``)."""
    n = shape.mass.shape[0]
    if k >= n and clamp_k and n >= 2:
        logger.warning("k=%d reduced to %d: the shape has %d vertices", k, n - 1, n)
        k = n - 1
    if k >= n:
        raise ValueError(
            f"k must be smaller than the number of vertices: k={k} but the shape has {n} "
            f"vertices{' after cleaning' if shape.cleaning.report.changed else ''}, so k <= {n - 1}"
        )
    return k


def on_cleaned_vertices(eig: EigenBasis) -> tuple[EigenBasis, np.ndarray | None]:
    """Return the basis on the cleaned surface's vertices: one row per welded group, none removed.

    An input whose vertices were welded (an OBJ read with its UVs repeats every vertex on a
    seam) or partly removed carries copies in :class:`EigenBasis`: identical rows of ``evecs``
    and ``vertices``. Searches in the spectral embedding then meet exact ties at every copy
    (measured: Spot, 17564 input vertices for 2930 surface ones, matched 7x slower) and
    per-vertex counts (coverage) count copies. This basis has the cleaned surface's rows only:
    the same eigenpairs, the summed mass of each group, the stiffness ``Eᵀ S E`` of the
    surface (``E`` the input-to-surface indicator; it undoes the averaging of the input
    stiffness exactly) and faces in its own numbering.

    Parameters
    ----------
    eig : EigenBasis

    Returns
    -------
    basis : EigenBasis
        ``eig`` itself when its input was used as given.
    representative : (n_c,) ndarray of int64 or None
        The input vertex of each row (``None`` when ``basis`` is ``eig``); an input vertex ``i``
        is row ``eig.cleaning.index[i]``.
    """
    c = eig.cleaning
    if c is None or not c.report.changed:
        return eig, None
    rep = np.asarray(c.representative, dtype=np.int64)
    idx = np.asarray(c.index, dtype=np.int64)
    kept = np.flatnonzero(np.asarray(c.kept))
    n_c = rep.shape[0]
    E = sp.csr_matrix((np.ones(kept.shape[0]), (kept, idx[kept])), shape=(c.n_input, n_c))
    stiffness = sp.csr_matrix(E.T @ eig.stiffness @ E)
    mass = np.bincount(idx[kept], weights=eig.mass[kept], minlength=n_c)
    faces = None if eig.faces is None else idx[eig.faces]
    evals, evecs, vertices = np.array(eig.evals), eig.evecs[rep], eig.vertices[rep]
    return EigenBasis(evals, evecs, mass, stiffness, vertices, faces), rep
