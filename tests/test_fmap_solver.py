"""The map fit's exact solve: the minimizer of the quadratic energy, as L-BFGS finds it slowly."""

from __future__ import annotations

import numpy as np
import pytest

from o3d_ofp.core.fmap import (
    _Commutator,
    _energy,
    _minimize_quadratic,
    estimate_fmap,
    estimate_fmaps,
)
from o3d_ofp.core.shapes import blob
from o3d_ofp.core.spectrum import eigenbasis


def _kron_hessian(O1: np.ndarray, O2: np.ndarray) -> np.ndarray:
    """Σᵢ KᵢᵀKᵢ built the obvious way, Kᵢ vec(C) = vec(C O1ᵢ − O2ᵢ C) column by column."""
    p, a, _ = O1.shape
    b = O2.shape[1]
    K = np.zeros((p, b * a, b * a))
    for j in range(b * a):
        E = np.zeros(b * a)
        E[j] = 1.0
        C = E.reshape(b, a)
        for i in range(p):
            K[i, :, j] = (C @ O1[i] - O2[i] @ C).ravel()
    return np.einsum("ikj,ikl->jl", K, K)


def test_commutator_hessian_equals_the_obvious_one():
    rng = np.random.default_rng(0)
    O1, O2 = rng.normal(size=(6, 4, 4)), rng.normal(size=(6, 5, 5))
    # Round-off of sums of ~100 products of O(1) numbers: 1e-12 relative.
    assert np.allclose(_Commutator(O1, O2).hessian(), _kron_hessian(O1, O2), rtol=1e-12, atol=1e-12)


def test_direct_minimizer_has_zero_gradient_and_the_lowest_energy():
    rng = np.random.default_rng(1)
    a, b, p = 5, 6, 9
    A, B = rng.normal(size=(a, p)), rng.normal(size=(b, p))
    sqdiff = rng.random((b, a))
    ops = _Commutator(rng.normal(size=(p, a, a)), rng.normal(size=(p, b, b)))
    orient = _Commutator(rng.normal(size=(p, a, a)), rng.normal(size=(p, b, b)))
    weights = (1.0, 0.3, 0.1, 0.7)
    C0 = np.zeros((b, a))
    C0[0, 0] = 1.0
    C = _minimize_quadratic(C0, A, B, sqdiff, ops, orient, weights)
    assert np.array_equal(C[:, 0], C0[:, 0])  # the fixed column stays fixed
    energy, grad = _energy(C, A, B, sqdiff, ops, orient, weights)
    # The free part of the gradient vanishes at the minimizer (round-off of the solve).
    assert np.abs(grad[:, 1:]).max() < 1e-9 * max(1.0, np.abs(A).max() * np.abs(B).max())
    for _ in range(20):  # and any move of the free entries raises the energy
        D = rng.normal(size=C.shape) * 1e-3
        D[:, 0] = 0.0
        assert _energy(C + D, A, B, sqdiff, ops, orient, weights)[0] > energy


@pytest.fixture(scope="module")
def bent_pair():
    V, F = blob(4)
    W = V.copy()
    W[:, 1] += 0.2 * W[:, 0] ** 2
    return eigenbasis(V, F, k=40), eigenbasis(2.5 * W, F, k=40)


def test_direct_fit_equals_a_converged_lbfgs(bent_pair):
    e1, e2 = bent_pair
    options = dict(k1=20, k2=20, w_dcomm=(0.1, 0.0), refine=None)
    direct = estimate_fmap(e1, e2, **options)
    slow = estimate_fmap(e1, e2, solver="lbfgs", ftol=1e-15, maxiter=100_000, **options)
    for C, R in zip(direct, slow, strict=True):
        # L-BFGS-B pushed to its limit stops within ~1e-5 of the minimizer (measured on FAUST:
        # 5e-8 and 2e-5 relative); the default tolerance stops 1e-4 to 2e-2 away.
        assert np.linalg.norm(C - R) <= 1e-4 * np.linalg.norm(R)


def test_fits_of_several_sizes_equal_the_fits_one_by_one(bent_pair):
    e1, e2 = bent_pair
    landmarks = np.array([[0, 0], [50, 50]])
    shared = estimate_fmaps(e1, e2, sizes=(12, 20), w_dcomm=(0.1, 0.0), landmarks=landmarks)
    assert [(k, w) for k, w, _ in shared] == [(12, 0.1), (12, 0.0), (20, 0.1), (20, 0.0)]
    for k in (12, 20):
        alone = estimate_fmap(
            e1, e2, k1=k, k2=k, w_dcomm=(0.1, 0.0), landmarks=landmarks, refine=None
        )
        got = [C for size, _, C in shared if size == k]
        for C, R in zip(got, alone, strict=True):
            assert C.shape == (k + 1, k + 1)
            # The same linear system from the leading blocks of larger operators: round-off.
            assert np.allclose(C, R, rtol=1e-9, atol=1e-9)
    with pytest.raises(ValueError, match="sizes"):
        estimate_fmaps(e1, e2, sizes=(41,))


def test_solver_keyword_is_checked(bent_pair):
    with pytest.raises(ValueError, match="solver"):
        estimate_fmap(*bent_pair, solver="newton")


def test_farthest_points_equal_the_plain_full_update():
    from o3d_ofp.core.fmap import farthest_points

    def plain(X: np.ndarray, count: int, start: int) -> np.ndarray:
        chosen, dist = [start], np.einsum("ij,ij->i", X - X[start], X - X[start])
        for _ in range(1, count):
            c = int(np.argmax(dist))
            chosen.append(c)
            dist = np.minimum(dist, np.einsum("ij,ij->i", X - X[c], X - X[c]))
        return np.array(chosen)

    rng = np.random.default_rng(3)
    V, _ = blob(4)  # a surface (2562 vertices) and a noisy cloud: the k-d tree's pruning is
    for X in (V, V + 0.01 * rng.normal(size=V.shape)):  # exact, so the samples are equal
        for start in (0, 1234):
            np.testing.assert_array_equal(
                farthest_points(X, 600, start=start), plain(X, 600, start)
            )
