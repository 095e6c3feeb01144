"""Thread safety of the file and console plumbing (what a Dask worker's threads share).

Open3D's verbosity level and the process umask are process-wide; a basis file can be damaged
on disk. These tests hammer them from several threads and check the clear errors.
"""

from __future__ import annotations

import os
import random
import threading
import time

import numpy as np
import pytest

import o3d_ofp as ofp
from o3d_ofp.core import _atomic
from o3d_ofp.core._atomic import atomic_path, current_umask
from o3d_ofp.core.shapes import blob


def _open_fds() -> int:
    return len(os.listdir("/proc/self/fd"))


# ----------------------------------------------------------------------------- verbosity


def test_verbosity_is_errors_inside_and_restored_after_interleaved_threads():
    o3d = pytest.importorskip("open3d")
    from o3d_ofp.boundary._verbosity import open3d_errors_only

    levels = o3d.utility.VerbosityLevel
    before = o3d.utility.get_verbosity_level()
    o3d.utility.set_verbosity_level(levels.Debug)  # distinguishable from Error and the default
    wrong: list[object] = []
    start = threading.Barrier(8)

    def work(seed: int) -> None:
        rng = random.Random(seed)
        start.wait()
        for _ in range(100):
            with open3d_errors_only():
                time.sleep(rng.random() * 1e-4)  # let the other threads enter and leave
                # Every thread inside must see Error, whoever entered first or left last. With
                # Open3D's own VerbosityContextManager a thread that entered second restores
                # the Error level it saved, or one leaving early puts Debug back under others.
                if o3d.utility.get_verbosity_level() != levels.Error:
                    wrong.append(o3d.utility.get_verbosity_level())
                if rng.random() < 0.3:
                    with open3d_errors_only():  # nested in the same thread
                        pass

    try:
        threads = [threading.Thread(target=work, args=(i,)) for i in range(8)]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        assert wrong == []
        assert o3d.utility.get_verbosity_level() == levels.Debug  # the last one out restored it
    finally:
        o3d.utility.set_verbosity_level(before)


def test_open3d_verbosity_changed_only_through_the_helper():
    # the boundary must not use Open3D's unsynchronized context manager anywhere
    root = os.path.dirname(ofp.__file__)
    offenders = []
    for folder, _, names in os.walk(root):
        for name in names:
            if name.endswith(".py") and name != "_verbosity.py":
                with open(os.path.join(folder, name), encoding="utf-8") as fh:
                    text = fh.read()
                if "VerbosityContextManager" in text or "set_verbosity_level" in text:
                    offenders.append(name)
    assert offenders == []


# ----------------------------------------------------------------------------- umask


@pytest.fixture
def umask_027():
    old = os.umask(0o027)
    try:
        yield 0o027
    finally:
        os.umask(old)


def test_current_umask_reads_without_changing(umask_027, monkeypatch):
    assert current_umask() == umask_027
    # Reading it must never set the umask (racy: another thread may create a file meanwhile).
    monkeypatch.setattr(os, "umask", lambda *a: pytest.fail("os.umask called at run time"))
    assert current_umask() == umask_027


def test_atomic_files_respect_umask_from_many_threads(tmp_path, umask_027, monkeypatch):
    monkeypatch.setattr(os, "umask", lambda *a: pytest.fail("os.umask called at run time"))

    def write(i: int) -> None:
        with atomic_path(tmp_path / f"f{i}.npy", suffix=".npy") as tmp:
            np.save(tmp, np.arange(i + 1))

    threads = [threading.Thread(target=write, args=(i,)) for i in range(16)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    names = sorted(os.listdir(tmp_path))
    assert names == sorted(f"f{i}.npy" for i in range(16))  # no temporary file left
    for name in names:
        assert os.stat(tmp_path / name).st_mode & 0o777 == 0o640  # 0666 & ~027
    np.testing.assert_array_equal(np.load(tmp_path / "f5.npy"), np.arange(6))


def test_written_geometry_files_respect_umask(tmp_path, umask_027, monkeypatch):
    pytest.importorskip("open3d")
    from o3d_ofp.boundary.convert import triangle_mesh_from_arrays
    from o3d_ofp.boundary.io import write_geometry

    monkeypatch.setattr(os, "umask", lambda *a: pytest.fail("os.umask called at run time"))
    V, F = blob(2)
    write_geometry(tmp_path / "m.ply", triangle_mesh_from_arrays(V, F))
    assert os.listdir(tmp_path) == ["m.ply"]
    assert os.stat(tmp_path / "m.ply").st_mode & 0o777 == 0o640


def test_umask_fallback_when_proc_is_missing(monkeypatch):
    # Without /proc the value read once at import is used, again without calling os.umask.
    monkeypatch.setattr(_atomic, "_umask_from_proc", lambda: None)
    monkeypatch.setattr(_atomic, "_UMASK_AT_IMPORT", 0o077)
    monkeypatch.setattr(os, "umask", lambda *a: pytest.fail("os.umask called at run time"))
    assert _atomic.default_file_mode() == 0o600


# ----------------------------------------------------------------------------- damaged bases


@pytest.fixture(scope="module")
def basis_bytes(tmp_path_factory):
    V, F = blob(2)
    path = tmp_path_factory.mktemp("basis") / "b.npz"
    ofp.ofp_basis(ofp.eigenbasis(V, F, k=6)).save(path)
    return path.read_bytes()


@pytest.mark.parametrize(
    "damage",
    ["zero_bytes", "first_half", "no_directory", "bit_flips", "not_a_zip", "npy"],
)
def test_damaged_basis_file_gives_clear_error_without_leaking(tmp_path, basis_bytes, damage):
    path = tmp_path / "b.npz"
    if damage == "zero_bytes":
        path.write_bytes(b"")
    elif damage == "first_half":
        path.write_bytes(basis_bytes[: len(basis_bytes) // 2])
    elif damage == "no_directory":
        path.write_bytes(basis_bytes[:-30])  # the end-of-central-directory record cut off
    elif damage == "bit_flips":  # damage inside the stored arrays, zip structure intact
        data = bytearray(basis_bytes)
        for i in range(200, len(data) // 2, 997):
            data[i] ^= 0xFF
        path.write_bytes(bytes(data))
    elif damage == "not_a_zip":
        path.write_bytes(b"hello, this is text and not a basis")
    else:
        with open(path, "wb") as fh:
            np.save(fh, np.ones(3))
    before = _open_fds()
    with pytest.raises(ValueError, match="basis file") as info:
        ofp.OFPBasis.load(path)
    assert str(path) in str(info.value)
    assert _open_fds() == before  # the damaged file's handle is closed


def test_intact_basis_file_still_loads(tmp_path, basis_bytes):
    path = tmp_path / "b.npz"
    path.write_bytes(basis_bytes)
    B = ofp.OFPBasis.load(path)
    assert B.k == 6 and B.Q.shape[0] == 162


def test_basis_of_another_kind_is_named_as_such(tmp_path):
    path = tmp_path / "other.npz"
    np.savez(path, a=np.ones(3))
    with pytest.raises(ValueError, match="is not an o3d_ofp basis file"):
        ofp.OFPBasis.load(path)
