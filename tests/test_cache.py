"""Basis cache: keyed on the input and every option; a changed mesh never reuses a basis."""

from __future__ import annotations

import logging

import numpy as np

import o3d_ofp as ofp
from o3d_ofp.core.shapes import blob


def test_second_call_loads_and_changes_recompute(tmp_path, caplog):
    V, F = blob(3)
    with caplog.at_level(logging.INFO, logger="o3d_ofp.workflows.cache"):
        B1 = ofp.cached_basis(V, F, k=10, cache_dir=tmp_path)
        assert "basis cached" in caplog.text
        caplog.clear()
        B2 = ofp.cached_basis(V, F, k=10, cache_dir=tmp_path)
        assert "loaded from cache" in caplog.text
    np.testing.assert_array_equal(B1.Q, B2.Q)
    assert B2.eig.digest == ofp.shape_digest(V, F)
    assert len(list(tmp_path.glob("*.npz"))) == 1
    # Any change to the vertices, the faces or an option is another basis (another file).
    moved = V.copy()
    moved[0, 0] += 1e-12
    ofp.cached_basis(moved, F, k=10, cache_dir=tmp_path)
    ofp.cached_basis(V, F[:, ::-1], k=10, cache_dir=tmp_path)
    ofp.cached_basis(V, F, k=11, cache_dir=tmp_path)
    ofp.cached_basis(V, F, k=10, preset="ours*", cache_dir=tmp_path)
    ofp.cached_basis(V, F, k=10, components="largest", cache_dir=tmp_path)
    assert len(list(tmp_path.glob("*.npz"))) == 6
    assert ofp.shape_digest(V, F) != ofp.shape_digest(moved, F)


def test_unreadable_or_foreign_cache_files_are_recomputed(tmp_path, caplog):
    V, F = blob(3)
    B = ofp.cached_basis(V, F, k=8, cache_dir=tmp_path)
    (path,) = tmp_path.glob("*.npz")
    path.write_bytes(b"garbage")
    with caplog.at_level(logging.WARNING, logger="o3d_ofp.workflows.cache"):
        B2 = ofp.cached_basis(V, F, k=8, cache_dir=tmp_path)
    assert "damaged cache entry" in caplog.text and "recomputing and rewriting it" in caplog.text
    np.testing.assert_allclose(B2.Q, B.Q)
    # A file under this key that holds another shape's basis is not trusted.
    other = ofp.ofp_basis(ofp.eigenbasis(*blob(3, seed=5), k=8))
    other.save(path)
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="o3d_ofp.workflows.cache"):
        B3 = ofp.cached_basis(V, F, k=8, cache_dir=tmp_path)
    assert "belongs to another shape" in caplog.text
    np.testing.assert_allclose(B3.Q, B.Q)
