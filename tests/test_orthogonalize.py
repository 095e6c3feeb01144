import numpy as np
import pytest

import o3d_ofp as ofp
from o3d_ofp.core import orthogonalize
from o3d_ofp.core.orthogonalize import gram_schmidt, resolve_tol
from o3d_ofp.core.products import eigenproducts

from ._reference import gram_schmidt_loop, projector
from .conftest import load_shared_mesh

# The centaur (15.8k vertices) runs in the slow step: its reference loops took 75 s.
REAL = [
    "faust/tr_reg_093.ply",
    pytest.param("tosca/centaur2.off", marks=pytest.mark.slow),
    "models/bunny.off",
]


def _orth_error(Q, mass):
    return np.abs(Q.T @ (mass[:, None] * Q) - np.eye(Q.shape[1])).max()


@pytest.fixture(scope="module", params=REAL)
def real_candidates(request):
    V, F = load_shared_mesh(request.param)
    eig = ofp.eigenbasis(V, F, k=29)
    B, _ = eigenproducts(eig.evecs, 2)
    return request.param, B, eig.mass


def test_fast_matches_reference_loop_on_real_shapes(real_candidates):
    name, B, mass = real_candidates
    fast = gram_schmidt(B, mass, tol=1e-2)
    Q_ref, kept_ref = gram_schmidt_loop(B, mass, 1e-2)
    np.testing.assert_array_equal(fast.kept, kept_ref, err_msg=name)
    # Same vectors, not only the same selection: both are orthonormalized in the same order.
    np.testing.assert_allclose(fast.Q, Q_ref, atol=1e-8 * np.abs(Q_ref).max())


@pytest.mark.parametrize("tol", [1e-2, 1e-9])
def test_orthonormal_to_1e_8_on_real_shapes(real_candidates, tol):
    name, B, mass = real_candidates
    gs = gram_schmidt(B, mass, tol=tol)
    assert _orth_error(gs.Q, mass) <= 1e-8, name
    # Q R = B on the kept columns (Eq. 17); round-off relative to the column norms.
    norms = np.sqrt(mass @ B**2)
    recon = gs.Q @ gs.R
    kept_err = np.sqrt(mass @ (recon[:, gs.kept] - B[:, gs.kept]) ** 2) / norms[gs.kept]
    assert kept_err.max() < 1e-10
    # every dropped column lies in the span up to tol times its norm
    dropped = np.setdiff1d(np.arange(B.shape[1]), gs.kept)
    if dropped.size:
        drop_err = np.sqrt(mass @ (recon[:, dropped] - B[:, dropped]) ** 2) / norms[dropped]
        assert drop_err.max() < tol * (1 + 1e-6)


def test_strict_threshold_agrees_with_reference_up_to_fragility(real_candidates):
    # At tol = 1e-9 hundreds of residuals lie between 1e-9 and 1e-6 and algorithms that are
    # equal in exact arithmetic differ by more than 1e-9: compare ranks, spans and errors.
    name, B, mass = real_candidates
    fast = gram_schmidt(B, mass, tol=1e-9)
    Q_ref, kept_ref = gram_schmidt_loop(B, mass, 1e-9)
    assert abs(len(fast.kept) - len(kept_ref)) <= 5, name
    f = B[:, 1:4] @ np.ones(3) + np.sin(B[:, 40] * 50)
    err = [
        np.sqrt(mass @ (f - Q @ (Q.T @ (mass * f))) ** 2) / np.sqrt(mass @ f**2)
        for Q in (fast.Q, Q_ref)
    ]
    assert abs(err[0] - err[1]) < 1e-3 * max(err[1], 1e-3)


def _spy_gram_path(monkeypatch):
    """Record what every call of the Gram-matrix selection returned (-1: not certified)."""
    results = []
    real = orthogonalize._select_by_gram

    def spy(*args, **kwargs):
        t = real(*args, **kwargs)
        results.append(t)
        return t

    monkeypatch.setattr(orthogonalize, "_select_by_gram", spy)
    return results


# 1e-6 goes through the recursive projections; 1e-3 and 1e-2 through the Gram-matrix selection
# (tol >= _GRAM_MIN_TOL), whose decisions must not depend on how the columns are cut either.
@pytest.mark.parametrize("tol", [1e-6, 1e-3, 1e-2])
def test_block_size_does_not_change_selection(tol, monkeypatch):
    rng = np.random.default_rng(1)
    n = 300
    base = rng.standard_normal((n, 25))
    # Many exact and near dependencies: products of a few columns, duplicates, combinations.
    B = np.concatenate(
        [base, base[:, :10] * 1e3, base[:, :5] @ rng.standard_normal((5, 20)), base * base[:, :1]],
        axis=1,
    )
    mass = rng.uniform(0.5, 2.0, n)
    gram_results = _spy_gram_path(monkeypatch)
    ref = gram_schmidt(B, mass, tol=tol, block_size=1)
    for bs in (3, 16, 64, 500):
        gs = gram_schmidt(B, mass, tol=tol, block_size=bs)
        np.testing.assert_array_equal(gs.kept, ref.kept)
        np.testing.assert_allclose(projector(gs.Q, mass), projector(ref.Q, mass), atol=1e-10)
    _, kept_loop = gram_schmidt_loop(B, mass, tol)
    np.testing.assert_array_equal(ref.kept, kept_loop)
    assert len(ref.kept) == 25 + 25  # base, then the 25 independent products base * base[:, 0]
    if tol >= orthogonalize._GRAM_MIN_TOL:
        # the Gram selection itself decided (certified) every block here, none fell back
        assert gram_results and min(gram_results) >= 0
    else:
        assert not gram_results


def test_scale_invariance_zero_and_duplicate_columns():
    rng = np.random.default_rng(2)
    B = rng.standard_normal((100, 6))
    B = np.column_stack([B[:, :3], np.zeros(100), 2 * B[:, 0], B[:, 3:]])
    mass = rng.uniform(0.1, 1.0, 100)
    gs = gram_schmidt(B, mass, tol=1e-2)
    np.testing.assert_array_equal(gs.kept, [0, 1, 2, 5, 6, 7])
    for s in (1e-12, 1e12):
        np.testing.assert_array_equal(gram_schmidt(B * s, mass * s, tol=1e-2).kept, gs.kept)
    # R is upper trapezoidal in the candidate order
    assert np.all(gs.R[gs.kept[:, None] > np.arange(B.shape[1])[None, :]] == 0)


def test_ill_conditioned_candidates_stay_orthonormal():
    # Monomials x^0..x^14 on [0, 1]: condition number ~1e17; single-pass CGS breaks down.
    x = np.linspace(0, 1, 2000)
    B = np.vander(x, 15, increasing=True)
    mass = np.full(2000, 1 / 2000)
    for tol in (1e-2, 1e-9):
        gs = gram_schmidt(B, mass, tol=tol)
        assert _orth_error(gs.Q, mass) < 1e-12


def test_presets_and_errors():
    assert resolve_tol(None, "ours") == 1e-2 and resolve_tol(None, "ours*") == 1e-9
    assert resolve_tol(1e-4, None) == 1e-4 and resolve_tol() == 1e-2
    with pytest.raises(ValueError, match="preset must be one of"):
        resolve_tol(None, "theirs")
    with pytest.raises(ValueError, match="contradicts preset"):
        resolve_tol(1e-3, "ours")
    B, mass = np.ones((4, 2)), np.ones(4)
    for bad in (0.0, 1.0, -1e-3, 2.0):
        with pytest.raises(ValueError, match="tol must lie strictly between 0 and 1"):
            gram_schmidt(B, mass, tol=bad)
    with pytest.raises(TypeError, match="tol must be a float"):
        gram_schmidt(B, mass, tol="small")
    with pytest.raises(ValueError, match="mass must be positive"):
        gram_schmidt(B, -mass)
    with pytest.raises(ValueError, match=r"candidates must have shape \(n, P\) with n = 5"):
        gram_schmidt(B, np.ones(5))
    bad_B = B.copy()
    bad_B[0, 0] = np.inf
    with pytest.raises(ValueError, match=r"candidates 0..1 hold NaN or inf"):
        gram_schmidt(bad_B, mass)


def test_gram_path_falls_back_when_cholesky_fails(monkeypatch):
    rng = np.random.default_rng(4)
    B = rng.standard_normal((200, 40))
    B[:, 20:] = B[:, :20] @ rng.standard_normal((20, 20)) + 1e-3 * rng.standard_normal((200, 20))
    mass = rng.uniform(0.5, 1.5, 200)
    expected = gram_schmidt(B, mass, tol=1e-2)

    def broken(*args, **kwargs):
        raise np.linalg.LinAlgError("forced")

    monkeypatch.setattr(np.linalg, "cholesky", broken)
    got = gram_schmidt(B, mass, tol=1e-2)
    np.testing.assert_array_equal(got.kept, expected.kept)
    assert _orth_error(got.Q, mass) < 1e-12


def _kahan_candidates(n, p, tol, seed, margin=1.05):
    """Kahan-like candidates: M-orthonormal directions mixed by a Kahan matrix.

    K = diag(s^j)(I − c·strictly-upper ones) with s² + c² = 1 has unit columns whose residual
    against the columns before it is s^j; s is set so that the last one is ``margin·tol``.
    So every candidate is kept by the column loop, yet K's condition number grows like
    ((1 + c)/s)^p (computed: 7e13 for p = 100 at tol = 1e-2, 1e20 to 5e28 for the others
    here): residuals taken from the Gram matrix, whose error grows with its square, are
    meaningless.
    """
    rng = np.random.default_rng(seed)
    s = (margin * tol) ** (1.0 / (p - 1))
    c = np.sqrt(1.0 - s * s)
    K = s ** np.arange(p)[:, None] * (np.eye(p) - c * np.triu(np.ones((p, p)), 1))
    mass = rng.uniform(0.5, 2.0, n)
    U, _ = np.linalg.qr(rng.standard_normal((n, p)))
    return (U / np.sqrt(mass)[:, None]) @ K, mass


@pytest.mark.parametrize(
    ("p", "tol", "seed"),
    [
        # Before the Gram selection was certified it kept 66 of 100, 281 of 300, all 150 but
        # with ‖QᵀMQ − I‖ = 8e-6 (Cholesky-QR2 of an ill-conditioned block), 143 of 200.
        (100, 1e-2, 0),
        (300, 1e-2, 0),
        (150, 1e-2, 1),
        (200, 1e-3, 2),
        # Recursive path: the right selection, but ‖QᵀMQ − I‖ was 3e-10..4e-10 before the
        # re-orthogonalization check.
        (300, 1e-6, 3),
        (300, 1e-9, 4),
    ],
)
def test_kahan_like_candidates_keep_the_loop_selection_and_orthonormality(
    p, tol, seed, monkeypatch
):
    B, mass = _kahan_candidates(3000, p, tol, seed)
    gram_results = _spy_gram_path(monkeypatch)
    gs = gram_schmidt(B, mass, tol=tol)
    _, kept_ref = gram_schmidt_loop(B, mass, tol)
    np.testing.assert_array_equal(kept_ref, np.arange(p))  # all residuals are above tol
    np.testing.assert_array_equal(gs.kept, kept_ref)
    assert _orth_error(gs.Q, mass) <= 1e-10
    # Q R reproduces the candidates (all kept) and R stays upper triangular
    norms = np.sqrt(mass @ B**2)
    assert (np.sqrt(mass @ (gs.Q @ gs.R - B) ** 2) / norms).max() < 1e-10
    assert np.all(np.tril(gs.R, -1) == 0)
    if tol >= orthogonalize._GRAM_MIN_TOL:
        # The Gram selection was tried on every block and refused at least one (the recursive
        # projections then decided it): the case this test is about.
        assert len(gram_results) == -(-p // 128) and min(gram_results) == -1


def test_two_orthogonalizations_in_two_threads_keep_their_own_scratch(real_candidates):
    """Each thread's products go through its own scratch buffer (released afterwards)."""
    from concurrent.futures import ThreadPoolExecutor

    _, B, mass = real_candidates
    jobs = [(B, 1e-2), (B[:, ::-1].copy(), 1e-3)]  # different candidates, different selections
    alone = [gram_schmidt(b, mass, tol=t, block_size=32) for b, t in jobs]
    with ThreadPoolExecutor(max_workers=2) as pool:
        together = list(
            pool.map(lambda job: gram_schmidt(job[0], mass, tol=job[1], block_size=32), jobs)
        )
    for a, b in zip(alone, together, strict=True):
        np.testing.assert_array_equal(a.kept, b.kept)
        np.testing.assert_array_equal(a.Q, b.Q)
    assert not hasattr(orthogonalize._SCRATCH, "buf")
