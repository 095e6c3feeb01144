"""Collections: one source onto many targets and the bases of many shapes, on a real scheduler.

The cluster is started here (two single-threaded worker processes on 127.0.0.1). The shapes
are small procedural blobs and bent copies with the same vertex order, so the identity is the
ground truth of every map.
"""

from __future__ import annotations

import contextlib
import csv
import json
import logging
import os
import subprocess
import sys
import threading
import time
import warnings
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import pytest

from o3d_ofp.core.shapes import blob

o3d = pytest.importorskip("open3d", reason="collections read and write with Open3D")
distributed = pytest.importorskip("distributed", reason="collections run on Dask")

from o3d_ofp.boundary.convert import triangle_mesh_from_arrays  # noqa: E402
from o3d_ofp.boundary.io import read_geometry, write_geometry  # noqa: E402
from o3d_ofp.collections import (  # noqa: E402
    COUNTERS,
    SUMMARY_FIELDS,
    TargetResult,
    bases_many,
    transfer_many,
    write_summary,
)


def _bent(V, amount):
    W = V.copy()
    W[:, 1] += amount * W[:, 0] ** 2
    return W


@pytest.fixture(scope="module")
def client(tmp_path_factory):
    """Start a real scheduler, two worker processes; a task that kills its worker fails at once.

    The workers get the collections' environment (one BLAS thread, Dask's malloc setting left
    out), which is also put back in this process afterwards; their scratch space is a
    temporary folder.
    """
    import dask

    from o3d_ofp.collections.engine import _worker_environment

    with _worker_environment() as pre_spawn:
        config = {
            "distributed.scheduler.allowed-failures": 0,
            "distributed.nanny.pre-spawn-environ": pre_spawn,
            "temporary-directory": str(tmp_path_factory.mktemp("dask")),
        }
        with dask.config.set(config):
            cluster = distributed.LocalCluster(
                processes=True,
                n_workers=2,
                threads_per_worker=1,
                host="127.0.0.1",
                dashboard_address=None,
                scheduler_kwargs={"dashboard_address": "127.0.0.1:0"},  # no fixed port
                silence_logs=logging.CRITICAL,
            )
        with cluster, distributed.Client(cluster) as c:
            yield c


@pytest.fixture(scope="module")
def shapes(tmp_path_factory):
    """Write a colored source, three bent copies, a corrupt PLY; (paths, V, F, colors)."""
    d = tmp_path_factory.mktemp("collection")
    V, F = blob(3)  # 642 vertices
    colors = 0.5 + 0.5 * np.sin(3 * V)
    write_geometry(d / "src.ply", triangle_mesh_from_arrays(V, F, colors=colors))
    for i, amount in enumerate((0.1, 0.15, 0.2)):
        write_geometry(d / f"t{i}.ply", triangle_mesh_from_arrays(_bent(V, amount), F))
    header = b"ply\nformat binary_little_endian 1.0\nelement vertex 642\nproperty float x\n"
    (d / "bad.ply").write_bytes(header + b"end_header\n\x00\x01\x02")
    paths = {p.stem: str(p) for p in d.iterdir()}
    return paths, V, F, colors


def _colors(path):
    return np.asarray(read_geometry(path).vertex_colors)


def test_all_ok_on_a_cluster_and_a_bad_target_fails_alone(client, shapes, tmp_path):
    paths, V, _, colors = shapes
    before = COUNTERS["source_bases"]
    targets = [paths["t0"], paths["bad"], paths["t1"]]
    results = transfer_many(paths["src"], targets, client=client, output_dir=tmp_path)
    assert COUNTERS["source_bases"] - before == 1  # once, in the caller, for every target
    assert [r.status for r in results] == ["ok", "failed", "ok"]
    assert [r.name for r in results] == ["t0.ply", "bad.ply", "t1.ply"]
    bad = results[1]
    assert "cut short" in bad.error and bad.error.startswith("ValueError")
    assert bad.output is None and not (tmp_path / "bad.ply").exists()
    workers = set(client.scheduler_info()["workers"])
    for r in (results[0], results[2]):
        assert r.output == str(tmp_path / r.name)
        assert r.worker in workers and r.n_vertices == len(V) and r.seconds > 0
        assert r.coverage > 0.5 and r.suspect is False
        # The bent copies keep the vertex order: the identity is the ground truth.
        assert np.abs(_colors(r.output) - colors).mean() < 0.05
    csv_path, json_path = write_summary(results, tmp_path)
    lines = Path(csv_path).read_text().splitlines()
    assert lines[0].split(",") == list(SUMMARY_FIELDS) and len(lines) == 4
    summary = json.loads(Path(json_path).read_text())
    assert summary["counts"] == {"ok": 2, "failed": 1, "skipped": 0}
    assert summary["results"][1]["status"] == "failed" and summary["results"][1]["coverage"] is None


def test_rerun_skips_finished_work_and_redoes_a_touched_input(client, shapes, tmp_path, caplog):
    paths, *_ = shapes
    targets = [paths["t0"], paths["t1"], paths["t2"]]
    run = dict(client=client, output_dir=tmp_path, map="identity")
    first = transfer_many(paths["src"], targets, **run)
    assert [r.status for r in first] == ["ok"] * 3
    before = COUNTERS["source_bases"]
    with caplog.at_level(logging.INFO, logger="o3d_ofp.collections"):
        again = transfer_many(paths["src"], targets, **run)
    assert [r.status for r in again] == ["skipped"] * 3
    assert "t1.ply: skipped" in caplog.text
    assert "was made from these files with the same options" in caplog.text
    assert COUNTERS["source_bases"] == before  # nothing to do: no source basis either
    future = time.time() + 5
    os.utime(paths["t1"], (future, future))
    third = transfer_many(paths["src"], targets, **run)
    assert [r.status for r in third] == ["skipped", "ok", "skipped"]
    forced = transfer_many(paths["src"], targets[:1], skip_existing=False, **run)
    assert forced[0].status == "ok"
    os.utime(paths["t1"])  # back to now: the module's later reruns would not skip it for 5 s


def test_second_run_reuses_the_cached_eigenbases(client, shapes, tmp_path):
    paths, *_ = shapes
    targets = [paths["t0"], paths["t1"]]
    cache = tmp_path / "cache"
    run = dict(client=client, cache_dir=cache, map="identity", skip_existing=False)
    first = transfer_many(paths["src"], targets, output_dir=tmp_path / "a", **run)
    assert [(r.status, r.cached) for r in first] == [("ok", False)] * 2
    entries = sorted(cache.glob("eig-*.npz"))
    assert len(entries) == 3  # the source's and the two targets'
    cached_before = COUNTERS["target_eigenbases_cached"]
    second = transfer_many(paths["src"], targets, output_dir=tmp_path / "b", **run)
    assert [(r.status, r.cached) for r in second] == [("ok", True)] * 2
    assert COUNTERS["target_eigenbases_cached"] - cached_before == 2
    for a, b in zip(first, second, strict=True):
        np.testing.assert_allclose(_colors(b.output), _colors(a.output), atol=1e-6)


def test_a_scheduler_address_opens_a_client(client, shapes, tmp_path):
    paths, *_ = shapes
    address = client.scheduler.address
    assert address.startswith("tcp://127.0.0.1:")
    (r,) = transfer_many(paths["src"], [paths["t2"]], client=address, output_dir=tmp_path,
                         map="identity")  # fmt: skip
    assert r.status == "ok" and r.worker in client.scheduler_info()["workers"]


def test_damaged_cache_entries_are_recomputed_and_rewritten(shapes, tmp_path, caplog):
    from o3d_ofp.workflows.cache import cached_basis, fetch_basis, fetch_eigenbasis

    _, V, F, _ = shapes
    eig, hit = fetch_eigenbasis(V, F, k=20, cache_dir=tmp_path)
    assert not hit
    (path,) = tmp_path.glob("eig-*.npz")
    good = path.read_bytes()
    for damaged in (b"", good[: len(good) // 2]):  # zero bytes, cut short
        path.write_bytes(damaged)
        caplog.clear()
        with caplog.at_level(logging.WARNING, logger="o3d_ofp.workflows.cache"):
            again, hit = fetch_eigenbasis(V, F, k=20, cache_dir=tmp_path)
        assert not hit and "damaged cache entry" in caplog.text
        np.testing.assert_array_equal(again.evecs, eig.evecs)
        assert path.stat().st_size == len(good)
    assert fetch_eigenbasis(V, F, k=20, cache_dir=tmp_path)[1]
    # The OFP basis goes where cached_basis looks, and a damaged one is recomputed too.
    B, hit = fetch_basis(V, F, k=10, cache_dir=tmp_path, eig=eig)
    assert not hit
    np.testing.assert_array_equal(cached_basis(V, F, k=10, cache_dir=tmp_path).Q, B.Q)
    (bpath,) = (p for p in tmp_path.glob("*.npz") if not p.name.startswith("eig-"))
    bpath.write_bytes(b"")
    assert not fetch_basis(V, F, k=10, cache_dir=tmp_path)[1]
    assert fetch_basis(V, F, k=10, cache_dir=tmp_path)[1]


def test_two_targets_given_as_geometries(client, shapes, tmp_path):
    paths, V, F, colors = shapes
    targets = [triangle_mesh_from_arrays(_bent(V, a), F) for a in (0.1, 0.2)]
    results = transfer_many(
        paths["src"], targets, client=client, output_dir=tmp_path, map="identity"
    )
    assert [(r.status, r.name, r.path) for r in results] == [
        ("ok", "target_0.ply", None),
        ("ok", "target_1.ply", None),
    ]
    for r in results:
        assert r.output == str(tmp_path / r.name) and r.values is None
        assert np.abs(_colors(r.output) - colors).mean() < 0.05
    assert not targets[0].has_vertex_colors()  # the inputs are not modified
    # Without output_dir nothing is written and the records keep the values.
    kept = transfer_many(paths["src"], targets, client=client, map="identity")
    assert all(r.output is None and r.values.shape == (len(V), 3) for r in kept)
    np.testing.assert_allclose(
        kept[0].values, _colors(results[0].output), atol=1 / 255
    )  # PLY: uint8


def test_detail_in_this_process(shapes, tmp_path):
    """Detail for each target, as the two-shape call does it (calibrated, and with a band).

    The bent copies are as detailed as the smooth source: calibrated, nothing is added, and
    the result says why; a band adds the detail above it everywhere.
    """
    import o3d_ofp as ofp

    paths, V, _, _ = shapes
    identity = ofp.Correspondence.from_p2p(np.arange(len(V)), len(V), len(V))
    bent = _bent(V, 0.1)
    for band in (None, 30):
        before = COUNTERS["source_bases"]
        results = transfer_many(
            paths["src"],
            [paths["t0"], paths["t1"]],
            kind="detail",
            workers=0,
            output_dir=tmp_path / str(band),
            map="identity",
            **({} if band is None else {"band": band}),
        )
        assert COUNTERS["source_bases"] - before == 1
        assert [(r.status, r.kind, r.worker) for r in results] == [("ok", "detail", "local")] * 2
        moved = np.asarray(read_geometry(results[0].output).vertices)
        if band is None:
            np.testing.assert_allclose(moved, bent, atol=1e-6 * np.ptp(bent))
            said = [str(w) for w in results[0].warnings]
            assert any("no detail the target lacks was found" in w for w in said)
        else:
            assert moved.shape == bent.shape and 0 < np.abs(moved - bent).max() < 0.1 * np.ptp(bent)
        # The same as the two-shape call with the same map (PLY stores float32 coordinates).
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", ofp.OFPWarning)
            one = ofp.transfer_detail(read_geometry(paths["src"]), read_geometry(paths["t0"]),
                                      correspondence=identity, band=band)  # fmt: skip
        np.testing.assert_allclose(moved, np.asarray(one.vertices), atol=1e-6 * np.ptp(bent))


def test_dense_targets_are_matched_on_coarse_copies_in_this_process(shapes, tmp_path, monkeypatch):
    import o3d_ofp as ofp
    from o3d_ofp.workflows import dense, estimate, plan

    paths, _, _, _ = shapes
    # The 642-vertex shapes made "dense" (above 500 vertices, coarse copies of 400): each
    # target's map comes from the dense path, and the OFP bases are the coarse copies'.
    monkeypatch.setattr(plan, "DENSE_VERTICES", 500)
    monkeypatch.setattr(estimate, "COARSE_VERTICES", 400)
    monkeypatch.setitem(dense.coarse_shape.__kwdefaults__, "coarse_vertices", 400)
    sizes: list[int] = []
    real = plan.eigenbasis

    def spy(V, F, *, k, **options):
        sizes.append(k)
        return real(V, F, k=k, **options)

    monkeypatch.setattr(plan, "eigenbasis", spy)
    coarse_sizes: list[int] = []
    real_coarse = dense.eigenbasis

    def coarse_spy(V, F, *, k, **options):
        coarse_sizes.append(V.shape[0])
        return real_coarse(V, F, k=k, **options)

    monkeypatch.setattr(dense, "eigenbasis", coarse_spy)
    results = transfer_many(
        paths["src"], [paths["t0"], paths["t1"]], workers=0, output_dir=tmp_path, k1=12, k2=12
    )
    assert [r.status for r in results] == ["ok", "ok"]
    # no full-resolution eigenbasis: the map and the OFP bases live on the coarse copies
    assert sizes == []
    # coarse eigenbases: the source's once (shared), then each target's
    assert len(coarse_sizes) == 3, coarse_sizes
    # each target's colors are those of the two-shape pipeline (its own coarse copies)
    one = ofp.transfer_colors(read_geometry(paths["src"]), read_geometry(paths["t0"]),
                              options=ofp.BasisOptions(k1=12, k2=12))  # fmt: skip
    assert len(coarse_sizes) == 5
    # PLY stores colors as 8-bit: half a step of 1/255
    np.testing.assert_allclose(
        _colors(results[0].output), np.asarray(one.vertex_colors), atol=0.5 / 255 + 1e-9
    )


def test_cli_detail_onto_several_targets(shapes, tmp_path, capsys):
    paths, V, _, _ = shapes
    out = tmp_path / "out"
    argv = ["detail", paths["src"], paths["t0"], paths["t1"], "-o", out, "--workers", "0",
            "--map", "identity", "--mode", "replace-detail", "--band", "20"]  # fmt: skip
    assert _cli(*argv) == 0
    assert "2 ok, 0 failed, 0 skipped" in capsys.readouterr().out
    import o3d_ofp as ofp

    identity = ofp.Correspondence.from_p2p(np.arange(len(V)), len(V), len(V))
    one = ofp.transfer_detail(read_geometry(paths["src"]), read_geometry(paths["t1"]),
                              correspondence=identity, mode="replace-detail", band=20)  # fmt: skip
    moved = np.asarray(read_geometry(out / "t1.ply").vertices)
    np.testing.assert_allclose(moved, np.asarray(one.vertices), atol=1e-5)
    assert _cli(*argv[:-2], "--band", "40", "--k1", "30") == 2  # refused before any work
    err = capsys.readouterr().err
    assert "--k1 (the OFP bases' sizes and threshold) does not apply: mode 'replace-detail'" in err
    # in this process (--workers 0) the library's warnings name their target (a trial: two
    # bare "the target already has detail" lines)
    argv = ["detail", paths["src"], paths["t0"], paths["t1"], "-o", tmp_path / "add",
            "--workers", "0", "--map", "identity", "--band", "20"]  # fmt: skip
    assert _cli(*argv) == 0
    said = [line for line in capsys.readouterr().err.splitlines() if "already has detail" in line]
    assert [line.split(": ")[1] for line in said] == ["t0.ply", "t1.ply"], said


def test_bases_many_fills_the_cache_that_transfers_reuse(client, shapes, tmp_path, caplog):
    import o3d_ofp as ofp
    from o3d_ofp.boundary.convert import geometry_to_arrays

    paths, *_ = shapes
    cache = tmp_path / "cache"
    shapes_ = [paths["t0"], paths["bad"], paths["t1"]]
    results = bases_many(shapes_, cache_dir=cache, client=client, k=39)
    assert [(r.status, r.kind) for r in results] == [
        ("ok", "basis"),
        ("failed", "basis"),
        ("ok", "basis"),
    ]
    assert "cut short" in results[1].error
    assert all(os.path.isfile(r.output) for r in results if r.ok)
    again = bases_many(shapes_, cache_dir=cache, client=client, k=39)
    assert [r.status for r in again] == ["skipped", "failed", "skipped"]
    n_files = len(list(cache.iterdir()))
    with caplog.at_level(logging.INFO, logger="o3d_ofp.workflows.cache"):
        ofp.cached_basis(*geometry_to_arrays(read_geometry(paths["t0"])), k=39, cache_dir=cache)
    assert f"basis loaded from cache {results[0].output}" in caplog.text  # the CLI's --cache
    assert len(list(cache.iterdir())) == n_files
    out = transfer_many(
        paths["src"], [paths["t0"]], client=client, cache_dir=cache, output_dir=tmp_path / "out"
    )
    assert [(r.status, r.cached) for r in out] == [("ok", True)]


def test_bad_calls_are_refused_before_any_work(shapes, tmp_path):
    paths, *_ = shapes
    with pytest.raises(TypeError, match="k3 is not an option of transfer_many"):
        transfer_many(paths["src"], [paths["t0"]], workers=0, k3=4)
    with pytest.raises(ValueError, match="kind"):
        transfer_many(paths["src"], [paths["t0"]], kind="zzz", workers=0)
    with pytest.raises(ValueError, match="no texture or vertex colors to bake"):  # colorless
        transfer_many(paths["t1"], [paths["t0"]], kind="texture", workers=0, output_dir=tmp_path)
    with pytest.raises(ValueError, match="output_dir is needed by kind='texture'"):
        transfer_many(paths["src"], [paths["t0"]], kind="texture", workers=0)
    with pytest.raises(ValueError, match="signal"):
        transfer_many(paths["src"], [paths["t0"]], signal="xyz", workers=0)
    with pytest.raises(ValueError, match="texture_size"):
        transfer_many(paths["src"], [paths["t0"]], texture_size=0, workers=0)
    with pytest.raises(ValueError, match="shells must be True or False"):
        transfer_many(paths["src"], [paths["t0"]], shells="no", workers=0)
    with pytest.raises(ValueError, match="same_frame must be True or False"):
        transfer_many(paths["src"], [paths["t0"]], same_frame="yes", workers=0)
    with pytest.raises(ValueError, match=r"same_frame .* shells=False turns them off"):
        transfer_many(paths["src"], [paths["t0"]], same_frame=True, shells=False, workers=0)
    with pytest.raises(ValueError, match="no vertex colors"):
        transfer_many(paths["t0"], [paths["t1"]], workers=0, skip_existing=False)
    with pytest.raises(ValueError, match="would overwrite"):
        transfer_many(paths["src"], [paths["t0"]], output_dir=os.path.dirname(paths["t0"]))
    with pytest.raises(FileNotFoundError):
        transfer_many(str(tmp_path / "nope.ply"), [paths["t0"]], workers=0)
    with pytest.raises(ValueError, match="targets holds no shapes"):
        transfer_many(paths["src"], [str(tmp_path)], workers=0)


def test_targets_given_as_one_path_are_refused_naming_the_argument(shapes, tmp_path, monkeypatch):
    """One path (or geometry) where a list is expected: refused at once, nothing transferred.

    A string is iterable: taken as the list of its characters, "." would name the working
    folder and every mesh file in it would be transferred.
    """
    from o3d_ofp.core.wording import OptionError

    paths, V, F, _ = shapes
    monkeypatch.chdir(tmp_path)
    (tmp_path / "here.ply").write_bytes(Path(paths["t0"]).read_bytes())  # in the working folder
    out, before = tmp_path / "out", COUNTERS["source_bases"]
    for one in ("one/target.ply", Path("one/target.ply"), triangle_mesh_from_arrays(V, F)):
        with pytest.raises(OptionError, match="must be a list of shapes") as info:
            transfer_many(paths["src"], one, workers=0, output_dir=out, map="identity")
        assert info.value.option == "targets", info.value
    with pytest.raises(OptionError, match=r"not one str: pass \['one/target.ply'\]"):
        transfer_many(paths["src"], "one/target.ply", workers=0, output_dir=out)
    with pytest.raises(OptionError) as info:
        bases_many("one/target.ply", cache_dir=tmp_path / "cache", workers=0)
    assert info.value.option == "paths"
    assert COUNTERS["source_bases"] == before  # no work done
    assert sorted(p.name for p in tmp_path.iterdir()) == ["here.ply"]  # nothing written


def test_bad_workers_are_refused_before_dask_starts(shapes, tmp_path, client):
    from o3d_ofp.core.wording import OptionError

    paths, *_ = shapes
    calls = [
        lambda: transfer_many(paths["src"], [paths["t0"]], workers=-3, output_dir=tmp_path / "o"),
        lambda: transfer_many(paths["src"], [paths["t0"]], workers=0, client=client),
        lambda: transfer_many(paths["src"], [paths["t0"]], workers=1.5),
        lambda: bases_many([paths["t0"]], cache_dir=tmp_path / "cache", workers=-3),
    ]
    for call in calls:
        t0 = time.perf_counter()
        with pytest.raises(OptionError) as info:
            call()
        assert time.perf_counter() - t0 < 0.3  # at once: no cluster, no eigensolve
        assert info.value.option == "workers", info.value
    with pytest.raises(OptionError) as info:
        calls[1]()
    from o3d_ofp.cli._common import error_text  # each reader its own words

    assert "give it or client=, not both" in str(info.value)
    assert error_text(info.value) == "--workers 0 runs in this process: give it or --scheduler, " \
        "not both"
    assert sorted(p.name for p in tmp_path.iterdir()) == []  # no folder made


def test_a_file_where_a_folder_is_expected_is_refused_naming_it(shapes, tmp_path):
    from o3d_ofp.core.wording import OptionError

    paths, *_ = shapes
    a_file = tmp_path / "file.txt"
    a_file.write_text("x")
    source, targets = paths["src"], [paths["t0"]]
    calls = [
        ("output_dir", lambda: transfer_many(source, targets, workers=0, output_dir=a_file)),
        ("cache_dir", lambda: transfer_many(source, targets, workers=0, cache_dir=a_file)),
        ("cache_dir", lambda: bases_many(targets, cache_dir=a_file, workers=0)),
    ]
    before = COUNTERS["source_bases"]
    for name, call in calls:
        with pytest.raises(OptionError, match="is a file; a folder is expected") as info:
            call()
        assert info.value.option == name and str(a_file) in str(info.value)
    assert COUNTERS["source_bases"] == before and a_file.read_text() == "x"


def test_a_local_cluster_leaves_no_scratch_space_and_takes_no_fixed_port(
    shapes, tmp_path, monkeypatch
):
    """The local cluster's scratch space is removed with it; its scheduler takes a free port.

    Dask's defaults: <tmp>/dask-scratch-space, left behind; the scheduler's HTTP server on port
    8787, which a cluster started beside another one finds taken (a warning, here an error).
    """
    import socket
    import tempfile

    paths, *_ = shapes
    tmp = tmp_path / "tmp"
    tmp.mkdir()
    monkeypatch.setenv("TMPDIR", str(tmp))  # the worker processes'
    monkeypatch.setattr(tempfile, "tempdir", str(tmp))  # this process's
    with socket.socket() as other:  # another cluster's scheduler
        with contextlib.suppress(OSError):  # (taken already: as good)
            other.bind(("127.0.0.1", 8787))
            other.listen()
        results = transfer_many(paths["src"], [paths["t0"], paths["t1"]], workers=1,
                                output_dir=tmp_path / "out", map="identity")  # fmt: skip
    assert [r.status for r in results] == ["ok", "ok"]
    assert results[0].worker.startswith("tcp://127.0.0.1:")  # on a local cluster
    assert list(tmp.iterdir()) == []


def test_importing_collections_does_not_import_dask():
    code = (
        "import sys, o3d_ofp.collections\n"
        "bad = [m for m in ('dask', 'distributed', 'open3d', 'tqdm') if m in sys.modules]\n"
        "assert not bad, bad\n"
    )
    subprocess.run([sys.executable, "-c", code], check=True)


# --------------------------------------------------------------------------- thread safety


def _transfer(seed):
    """One whole transfer on a 2562-vertex pair (CHOLMOD + Lanczos, descriptors, ZoomOut)."""
    from o3d_ofp.core.basis import ofp_basis
    from o3d_ofp.core.spectrum import eigenbasis
    from o3d_ofp.workflows.estimate import match_eigenbases
    from o3d_ofp.workflows.options import BasisOptions, MatchOptions
    from o3d_ofp.workflows.pipeline import transfer_function

    V, F = blob(4, seed=seed)
    e1, e2 = eigenbasis(V, F, k=30), eigenbasis(_bent(V, 0.15), F, k=30)
    options = MatchOptions(k_fit=15, zoomout_to=30, zoomout_subsample=300)
    corr = match_eigenbases(e1, e2, options=options)
    bases = (ofp_basis(e1, k=15), ofp_basis(e2, k=20))
    sizes = BasisOptions(k1=15, k2=20)
    f = transfer_function(V, e1, e2, correspondence=corr, bases=bases, options=sizes)
    return e2.evecs, corr.p2p_21, f


def _blas_threads():
    from threadpoolctl import threadpool_info

    return [i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"]


@pytest.fixture
def restore_blas():
    """Put the process' BLAS thread count back (concurrent calls may leave it changed)."""
    from threadpoolctl import threadpool_limits

    before = _blas_threads()
    yield before
    threadpool_limits(limits=max(before), user_api="blas")


def test_two_transfers_in_threads_match_the_serial_results(restore_blas):
    serial = [_transfer(s) for s in (0, 1)]
    with ThreadPoolExecutor(2) as pool:
        threaded = list(pool.map(_transfer, (0, 1)))
    for (e_s, p_s, g_s), (e_t, p_t, g_t) in zip(serial, threaded, strict=True):
        # Equal up to round-off: BLAS limits are process-wide, so a product outside a limited
        # block may run on one thread while the other thread is inside one (a different
        # summation order: differences of a few ulps, measured 3e-14 on entries of size ~0.3).
        # Two threads overwriting each other's data would differ at O(1).
        np.testing.assert_allclose(e_t, e_s, rtol=0, atol=1e-10)
        np.testing.assert_array_equal(p_t, p_s)
        np.testing.assert_allclose(g_t, g_s, rtol=0, atol=1e-10)
    # and the process' BLAS setting is what it was (not left at the limit of the stages)
    assert _blas_threads() == restore_blas


def test_blas_thread_limits_survive_concurrent_calls(restore_blas):
    from o3d_ofp.core._threads import blas_threads

    a_in, b_in, a_out = threading.Event(), threading.Event(), threading.Event()
    seen = {}

    def first():
        with blas_threads(1):
            a_in.set()
            b_in.wait(10)
        a_out.set()

    def second():
        a_in.wait(10)
        with blas_threads(1):
            b_in.set()
            a_out.wait(10)
            seen["inside"] = _blas_threads()

    threads = [threading.Thread(target=f) for f in (first, second)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert seen["inside"] == [1] * len(seen["inside"])  # still limited inside the second call
    assert _blas_threads() == restore_blas  # and the process' setting back afterwards


# --------------------------------------------------------------------------- the CLI


def _cli(*argv):
    from o3d_ofp.cli.main import main

    return main([str(a) for a in argv])


def test_cli_several_targets_on_a_scheduler_summary_rerun_and_force(client, shapes, tmp_path,
                                                                    capsys):  # fmt: skip
    paths, _, _, colors = shapes
    out = tmp_path / "out"
    args = ["transfer", paths["src"], paths["t0"], paths["bad"], paths["t1"], "-o", out,
            "--scheduler", client.scheduler.address, "--map", "identity"]  # fmt: skip
    assert _cli(*args) == 1  # one target failed: exit 1, the others written
    text = capsys.readouterr().out
    assert "failed   bad.ply: ValueError" in text and "ok       t0.ply" in text
    assert "2 ok, 1 failed, 0 skipped" in text
    names = sorted(p.name for p in out.iterdir())
    assert names == [".o3d_ofp_outputs.json", "summary.csv", "summary.json", "t0.ply", "t1.ply"]
    for name in ("t0.ply", "t1.ply"):
        assert np.abs(_colors(out / name) - colors).mean() < 0.05
    summary = json.loads((out / "summary.json").read_text())
    assert summary["counts"] == {"ok": 2, "failed": 1, "skipped": 0}
    # Rerun: the finished targets are skipped and said so; only the bad one is tried again.
    assert _cli(*args) == 1
    text = capsys.readouterr().out
    assert "skipped  t0.ply: up to date" in text and "0 ok, 1 failed, 2 skipped" in text
    # Other options make other outputs: redone, not skipped (found by a trial: a rerun with
    # --k1 20, or `detail` over color transfers, kept the old outputs as "up to date").
    assert _cli(*args, "--k1", "20") == 1
    captured = capsys.readouterr()
    assert "2 ok, 1 failed, 0 skipped" in captured.out
    assert "made with other options: k1 29 -> 20" in captured.err
    assert _cli(*args, "--k1", "20") == 1
    assert "0 ok, 1 failed, 2 skipped" in capsys.readouterr().out
    # All good targets: exit 0; --force redoes finished work.
    good = [a for a in args if a != paths["bad"]]
    assert _cli(*good, "--force") == 0
    assert "2 ok, 0 failed, 0 skipped" in capsys.readouterr().out


def test_cli_folder_of_targets_in_process_and_basis_of_a_collection(shapes, tmp_path, capsys):
    paths, *_ = shapes
    folder = tmp_path / "targets"
    folder.mkdir()
    for name in ("t0", "t1"):
        (folder / f"{name}.ply").write_bytes(Path(paths[name]).read_bytes())
    cache = tmp_path / "cache"
    assert _cli("basis", folder, paths["src"], "--cache", cache, "--workers", "0") == 0
    assert "3 ok, 0 failed, 0 skipped" in capsys.readouterr().out
    assert len(list(cache.glob("eig-*.npz"))) == 3  # the eigenbases the map estimation needs
    assert _cli("basis", folder, "--cache", cache, "--workers", "0") == 0
    assert "0 ok, 0 failed, 2 skipped" in capsys.readouterr().out  # all cached already
    # a shape file that does not exist: refused before any work (a trial: the others were
    # solved first, then it failed with exit 1)
    missing = tmp_path / "nosuch.ply"
    assert _cli("basis", paths["src"], missing, "--cache", tmp_path / "c2", "--workers", "0") == 2
    assert f"{missing}: no such shape file or folder" in capsys.readouterr().err
    assert not (tmp_path / "c2").exists() or not list((tmp_path / "c2").iterdir())
    solved = COUNTERS["target_eigenbases_computed"]
    out = tmp_path / "out"
    assert _cli("transfer", paths["src"], folder, "-o", out, "--workers", "0",
                "--cache", cache) == 0  # fmt: skip
    assert COUNTERS["target_eigenbases_computed"] == solved  # every eigenbasis from the cache
    assert (out / "t0.ply").is_file() and (out / "t1.ply").is_file()


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--landmarks", "0:0"], "--landmarks (vertex pairs belong to one pair of shapes) does"),
        (["--save-map", "m.npz"], "--save-map (one map per pair) does not apply"),
        (["--map", "closest"], "--map closest: with several targets the map is"),
        (["--signal", "xyz"], "--signal xyz: with several targets the signal is"),
        (["--k1", "0"], "--k1: expected a positive integer"),
        (["--same-frame", "--no-shells"], "--same-frame chooses among the registrations of the "
         "shapes' smooth shells, and --no-shells turns them off"),
    ],
)
def test_cli_several_targets_refuses_pair_only_flags(shapes, tmp_path, capsys, extra, message):
    paths, *_ = shapes
    argv = ["transfer", paths["src"], paths["t0"], paths["t1"], "-o", tmp_path / "o", *extra]
    assert _cli(*argv) == 2
    assert message in capsys.readouterr().err
    assert not (tmp_path / "o").exists()  # refused before any work


def test_cli_bad_collection_usage_is_refused(shapes, tmp_path, capsys):
    paths, *_ = shapes
    a_file = tmp_path / "file.txt"
    a_file.write_text("x")
    cases = [
        (["transfer", paths["src"], paths["t0"], paths["t1"], "-o", a_file],
         "is a file; with several targets -o names a folder"),
        (["transfer", paths["src"], paths["t0"], "-o", tmp_path / "one.ply", "--workers", "2"],
         "--workers applies to several targets"),
        (["basis", paths["t0"], paths["t1"], "-o", tmp_path / "b.npz"],
         "-o names the basis file of ONE shape"),
        (["basis", paths["t0"], paths["t1"]], "give -o FILE.npz (one shape) or --cache DIR"),
        (["basis", paths["t0"], paths["t1"], "--cache", a_file], "--cache"),
        # found by a trial: a folder named x1.ply was made; a scheduler where nothing
        # listens was found after the source's eigensolve, as "cannot read or write"
        (["transfer", paths["src"], paths["t0"], paths["t1"], "-o", tmp_path / "x1.ply"],
         "x1.ply: with several targets -o names a folder"),
        (["transfer", paths["src"], paths["t0"], paths["t1"], "-o", tmp_path / "o",
          "--scheduler", "tcp://127.0.0.1:9"], "--scheduler tcp://127.0.0.1:9: nothing answers"),
        (["transfer", paths["src"], paths["t0"], paths["t1"], "-o", tmp_path / "o",
          "--scheduler", "localhost"], "expected tcp://HOST:PORT"),
        # a trial's typo ran every other target first (exit 1 at the end)
        (["transfer", paths["src"], paths["t0"], tmp_path / "typo.ply", "-o", tmp_path / "o",
          "--workers", "0"], "typo.ply: no such target file or folder"),
        # the OFP bases' flags in detail's add mode: named as flags, not as keywords
        (["detail", paths["src"], paths["t0"], paths["t1"], "-o", tmp_path / "o", "--k1", "5",
          "--order", "3", "--workers", "0"],
         "error: --k1 (the OFP bases' sizes and threshold) does not apply: mode 'add'"),
        # the output folder holding a target: said with the flag, not the keyword
        (["transfer", paths["src"], paths["t0"], paths["t1"], "-o",
          os.path.dirname(paths["t0"]), "--workers", "0"], "the output folder"),
    ]  # fmt: skip
    for argv, message in cases:
        assert _cli(*argv) == 2, argv
        assert message in capsys.readouterr().err, argv
    assert a_file.read_text() == "x"
    assert not (tmp_path / "x1.ply").exists() and not (tmp_path / "o").exists()


def _textured(V, F, image):
    """Build a mesh with spherical per-corner UVs and ``image`` as its texture."""
    mesh = triangle_mesh_from_arrays(V, F)
    P = V[F.reshape(-1)]
    u = 0.5 + np.arctan2(P[:, 1], P[:, 0]) / (2 * np.pi)
    v = 0.5 + np.arcsin(np.clip(P[:, 2] / np.linalg.norm(P, axis=1), -1, 1)) / np.pi
    mesh.triangle_uvs = o3d.utility.Vector2dVector(np.column_stack([u, v]))
    mesh.textures = [o3d.geometry.Image(image)]
    mesh.triangle_material_ids = o3d.utility.IntVector(np.zeros(len(F), dtype=np.int32))
    return mesh


def test_cli_textured_source_bakes_every_target_like_the_two_shape_command(shapes, tmp_path,
                                                                           capsys):  # fmt: skip
    from PIL import Image

    _, V, F, _ = shapes
    yy, xx = np.mgrid[0:64, 0:64]
    image = np.stack([(xx * 4) % 256, (yy * 4) % 256, ((xx // 8 + yy // 8) % 2) * 255], axis=-1)
    write_geometry(tmp_path / "src.obj", _textured(V, F, image.astype(np.uint8)))
    for i, amount in enumerate((0.1, 0.2)):
        write_geometry(
            tmp_path / f"t{i}.obj",
            _textured(_bent(V, amount), F, image[::-1].copy().astype(np.uint8)),
        )
    out = tmp_path / "out"
    argv = ["transfer", tmp_path / "src.obj", tmp_path / "t0.obj", tmp_path / "t1.obj", "-o", out,
            "--workers", "0", "--texture-size", "64"]  # fmt: skip
    assert _cli(*argv) == 0
    assert (out / "t0.obj").is_file() and (out / "t0.mtl").is_file()
    assert _cli("transfer", tmp_path / "src.obj", tmp_path / "t0.obj", "-o", tmp_path / "one.obj",
                "--texture-size", "64") == 0  # fmt: skip
    many = sorted(out.glob("t0*.png"))
    one = sorted(tmp_path.glob("one*.png"))
    assert len(many) == 1 and len(one) == 1
    # The same map and the same bake: the same image, texel for texel (and a real picture).
    baked = np.asarray(Image.open(many[0]))
    np.testing.assert_array_equal(baked, np.asarray(Image.open(one[0])))
    assert baked.std() > 20


def test_texture_run_records_what_each_target_got(shapes, tmp_path, capsys):
    """A target without UVs gets vertex colors: its record says "colors", not "texture".

    And the two-shape command says when a target's UVs are dropped for a .ply output.
    """
    _, V, F, _ = shapes
    yy, xx = np.mgrid[0:32, 0:32]
    image = np.stack([xx * 8, yy * 8, (xx + yy) % 2 * 255], axis=-1).astype(np.uint8)
    write_geometry(tmp_path / "src.obj", _textured(V, F, image))
    write_geometry(tmp_path / "uv.obj", _textured(_bent(V, 0.1), F, image))
    write_geometry(tmp_path / "plain.ply", triangle_mesh_from_arrays(_bent(V, 0.2), F))
    targets = [str(tmp_path / "uv.obj"), str(tmp_path / "plain.ply")]
    results = transfer_many(
        str(tmp_path / "src.obj"), targets, kind="texture", workers=0,
        output_dir=tmp_path / "out", map="identity", texture_size=32,
    )  # fmt: skip
    assert [(r.status, r.kind) for r in results] == [("ok", "texture"), ("ok", "colors")]
    # the PLY target stays a PLY (a trial's came out as an OBJ with vertex colors)
    assert [os.path.basename(r.output) for r in results] == ["uv.obj", "plain.ply"]
    code = _cli("transfer", tmp_path / "src.obj", tmp_path / "uv.obj", "--map", "identity",
                "-o", tmp_path / "flat.ply")  # fmt: skip
    assert code == 0 and "cannot hold a texture" in capsys.readouterr().err


def test_a_source_without_its_material_takes_texture_in_a_collection(shapes, tmp_path, capsys):
    """--texture FILE gives a collection the image of a source read without its .mtl.

    Found by a trial: the error advised --texture FILE, which collections refused.
    """
    from PIL import Image

    _, V, F, _ = shapes
    yy, xx = np.mgrid[0:32, 0:32]
    image = np.stack([xx * 8, yy * 8, (xx // 4 + yy // 4) % 2 * 255], axis=-1).astype(np.uint8)
    write_geometry(tmp_path / "src.obj", _textured(V, F, image))
    for name in ("src.mtl", *(p.name for p in tmp_path.glob("src*.png"))):
        (tmp_path / name).unlink()  # the OBJ alone: UVs, no image
    Image.fromarray(image).save(tmp_path / "image.png")
    for i, amount in enumerate((0.1, 0.2)):
        write_geometry(tmp_path / f"t{i}.obj", _textured(_bent(V, amount), F, image))
    argv = ["transfer", tmp_path / "src.obj", tmp_path / "t0.obj", tmp_path / "t1.obj",
            "--map", "identity", "--workers", "0", "--texture-size", "32"]  # fmt: skip
    assert _cli(*argv, "-o", tmp_path / "a") == 2
    assert "--texture FILE" in capsys.readouterr().err
    assert _cli(*argv, "-o", tmp_path / "b", "--texture", tmp_path / "nope.png") == 2
    err = capsys.readouterr().err
    assert "--texture" in err and "no such image file" in err
    assert _cli(*argv, "-o", tmp_path / "c", "--texture", tmp_path / "image.png") == 0
    results = json.loads((tmp_path / "c" / "summary.json").read_text())["results"]
    assert [r["kind"] for r in results] == ["texture", "texture"]
    baked = np.asarray(Image.open(next((tmp_path / "c").glob("t0*.png"))))
    assert baked.std() > 20  # a picture, not a flat color


# --------------------------------------------------------------------------- last: kills a worker


def test_a_killed_worker_is_a_failed_record(client):
    from o3d_ofp.collections.engine import _run
    from o3d_ofp.collections.tasks import ShapeSpec

    def task(shared, spec):
        if spec.index == 1:
            os._exit(1)  # what the nanny's memory monitor does to a worker over its limit
        return TargetResult(index=spec.index, name=spec.name, path=None, status="ok")

    specs = [ShapeSpec(0, "a", None), ShapeSpec(1, "b", None)]
    records: list[TargetResult] = []
    run = {"client": client, "workers": None, "progress": False}
    _run(task, None, specs, kind="colors", on_record=records.append, **run)
    by_index = {r.index: r for r in records}
    assert by_index[0].status == "ok"
    assert by_index[1].status == "failed" and by_index[1].error.startswith("KilledWorker")


def test_a_local_cluster_that_does_not_start_names_the_script_guard(monkeypatch):
    """Without `if __name__ == "__main__":` the workers re-run a script: say so (trial)."""
    distributed = pytest.importorskip("distributed")
    from o3d_ofp.collections.engine import open_client

    def fail(*args, **kwargs):
        raise RuntimeError("Nanny failed to start.")

    monkeypatch.setattr(distributed, "LocalCluster", fail)
    with pytest.raises(RuntimeError, match=r'Nanny failed.*__name__ == "__main__".*workers=0'):
        with open_client(workers=1):
            pass


def test_bases_larger_than_the_estimation_are_kept_or_refused(shapes, tmp_path, caplog):
    """--k1 / --k2 above the estimation's 99 are honoured; a shape too small is refused.

    Found by a trial: a collection capped k1 = k2 = 150 at 99 silently (the pair command
    honours them), and took k1 = 7000 on a 6890-vertex source without a word.
    """
    paths, _, _, _ = shapes
    with caplog.at_level(logging.DEBUG, logger="o3d_ofp.core.basis"):
        results = transfer_many(
            paths["src"], [paths["t0"]], workers=0, output_dir=tmp_path, k1=110, k2=120
        )
    assert [r.status for r in results] == ["ok"]
    sizes = [int(m.split("k=")[1].split()[0]) for m in caplog.messages if "ofp_basis" in m]
    assert sorted(sizes) == [110, 120], caplog.messages
    with pytest.raises(ValueError, match=r"k1 \(700\): src.ply has 642 vertices, too few"):
        transfer_many(paths["src"], [paths["t1"]], workers=0, output_dir=tmp_path, k1=700)


def test_read_only_output_folder_is_refused_first_and_no_empty_folder_is_left(
    shapes, tmp_path, capsys, read_only_folder
):
    """A read-only -o folder is refused first; a run refused at once leaves no folder.

    Found by a trial: a read-only -o folder failed at each target's write, after the
    source's eigensolve, and the summary was lost; a run that failed at once (bad source,
    too large k1) left an empty output folder.
    """
    from o3d_ofp.cli import main

    paths, _, _, _ = shapes
    folder = read_only_folder
    before = COUNTERS["source_bases"]
    with pytest.raises(PermissionError, match="cannot be written"):
        transfer_many(paths["src"], [paths["t0"]], workers=0, output_dir=folder)
    assert COUNTERS["source_bases"] == before  # refused before the source's bases
    argv = ["transfer", paths["src"], paths["t0"], paths["t1"], "--workers", "0"]
    assert main([*argv, "-o", str(folder)]) == 2
    assert "cannot be written" in capsys.readouterr().err
    assert main([*argv, "-o", str(folder / "new")]) == 2  # made inside a read-only folder
    # a run refused after the folder was made removes it again (only when it is empty)
    new = tmp_path / "new"
    with pytest.raises(ValueError, match=r"k1 \(700\)"):
        transfer_many(paths["src"], [paths["t0"]], workers=0, output_dir=new, k1=700)
    assert not new.exists()


def test_a_suspect_target_says_why_in_its_record_and_q_still_names_failures(
    client, shapes, tmp_path, capsys
):
    """A suspect map's reasons are in its record; -q still names the failed targets.

    Found by a trial: a suspect map's reasons were printed only by the worker process (a
    raw Python warning), the record said ``suspect: true`` alone; with -q the failed targets
    were not named at all. A fix a collection refuses is read from the reasons' codes (not
    from a word of theirs).
    """
    from o3d_ofp.cli.main import main
    from o3d_ofp.core.shapes import icosphere

    paths, _, _, _ = shapes
    sphere = tmp_path / "sphere.ply"
    write_geometry(sphere, triangle_mesh_from_arrays(*icosphere(3)))
    out = tmp_path / "out"
    [r] = transfer_many(paths["src"], [str(sphere)], client=client, output_dir=out)
    assert r.status == "ok" and r.suspect and r.warnings
    assert "suspect" in r.warnings[0] and "likely causes" in r.warnings[0]
    # shapes of other kinds: known pairs are advised where parts correspond, which a
    # collection does not take: the target transferred alone with them
    assert "a few known vertex pairs" in r.warnings[0]
    assert "a collection takes no landmarks" in r.warnings[0]
    _, json_path = write_summary([r], out)
    written = json.loads(Path(json_path).read_text())["results"][0]["warnings"]
    assert written == [str(w) for w in r.warnings]
    # -q: the failures are still named (on stderr, once), nothing else is printed
    argv = ["-q", "transfer", paths["src"], paths["bad"], paths["t0"], "--workers", "0"]
    assert main([*argv, "-o", str(tmp_path / "q")]) == 1
    captured = capsys.readouterr()
    assert captured.err.count("bad.ply: failed: ValueError") == 1 and captured.out == ""
    assert "t0" not in captured.err
    # a target whose output is named otherwise (STL holds no colors: written as PLY) is named
    # by its own file too (a trial's failed s087.stl was logged as "s087.ply: failed")
    bad_stl = tmp_path / "bad.stl"
    bad_stl.write_bytes(Path(paths["bad"]).read_bytes())
    argv = ["-q", "transfer", paths["src"], str(bad_stl), paths["t0"], "--workers", "0"]
    assert main([*argv, "-o", str(tmp_path / "q_stl")]) == 1
    assert "bad.stl (-> bad.ply): failed: " in capsys.readouterr().err
    # -q in this process (the log is at WARNING): the record still keeps what was said
    argv = ["-q", "transfer", paths["src"], str(sphere), paths["t0"], "--workers", "0"]
    assert main([*argv, "-o", str(tmp_path / "q2")]) == 0
    captured = capsys.readouterr()  # the suspect target is still named under -q
    assert "sphere.ply: the map is suspect" in captured.err and captured.out == ""
    rows = json.loads((tmp_path / "q2" / "summary.json").read_text())["results"]
    assert rows[0]["suspect"] and "suspect" in rows[0]["warnings"][0], rows[0]
    assert rows[1]["warnings"] == []


def test_local_workers_leave_ctrl_c_to_this_process(monkeypatch):
    """Processes started for a local cluster ignore SIGINT; this process keeps its handler.

    Found by a trial: Ctrl-C in a terminal reached every worker, each printing a traceback.
    """
    import signal

    from o3d_ofp.collections.engine import _children_ignore_interrupts, open_client

    code = "import signal; print(signal.getsignal(signal.SIGINT) == signal.SIG_IGN)"
    probe = [sys.executable, "-c", code]
    before = signal.getsignal(signal.SIGINT)
    with _children_ignore_interrupts():
        child = subprocess.run(probe, capture_output=True, text=True, check=True).stdout
    assert child.strip() == "True", child
    assert signal.getsignal(signal.SIGINT) is before
    # open_client: ignored while the cluster starts its processes (a stand-in here), not while
    # it runs: Ctrl-C still interrupts this process
    seen = []

    class Cluster:
        def __init__(self, **kwargs):
            seen.append(signal.getsignal(signal.SIGINT))

        def __enter__(self):
            return self

        def __exit__(self, *exc):
            return False

    class Client(Cluster):
        def __init__(self, cluster):
            pass

    monkeypatch.setattr(distributed, "LocalCluster", Cluster)
    monkeypatch.setattr(distributed, "Client", Client)
    with open_client(workers=1):
        assert signal.getsignal(signal.SIGINT) is before
    assert seen == [signal.SIG_IGN]


def test_an_interrupted_rerun_with_other_options_leaves_no_stale_record(shapes, tmp_path,
                                                                        monkeypatch):  # fmt: skip
    """An interrupted run records what it remade, and nothing it did not.

    Found by a review: the options record was written after the whole run, so outputs
    remade with other options by an interrupted run were later skipped as "the same".
    """
    from o3d_ofp.collections import engine

    paths, _, _, _ = shapes
    targets = [paths["t0"], paths["t1"], paths["t2"]]
    out = tmp_path / "out"
    run = {"workers": 0, "output_dir": out, "map": "identity"}
    assert [r.status for r in transfer_many(paths["src"], targets, k1=29, **run)] == ["ok"] * 3
    real = engine.transfer_task

    def interrupted(shared, spec):
        if spec.index == 2:
            raise KeyboardInterrupt
        return real(shared, spec)

    monkeypatch.setattr(engine, "transfer_task", interrupted)
    time.sleep(0.01)  # the remade outputs are newer than the first run's
    with pytest.raises(KeyboardInterrupt):
        transfer_many(paths["src"], targets, k1=20, **run)
    monkeypatch.setattr(engine, "transfer_task", real)
    record = json.loads((out / ".o3d_ofp_outputs.json").read_text())["outputs"]
    assert record["t0.ply"]["options"]["k1"] == 20 and record["t1.ply"]["options"]["k1"] == 20
    assert "t2.ply" not in record  # to be remade: no record until it is
    again = transfer_many(paths["src"], targets, k1=29, **run)
    assert [r.status for r in again] == ["ok", "ok", "ok"]  # none skipped as "the same"


def test_a_collection_without_dask_is_refused_first(shapes, tmp_path, capsys, monkeypatch):
    """Without Dask a collection is refused before any work, with a pip line that works.

    Found by a fresh-install trial: without Dask the source's eigensolve ran first, then
    exit 1 with a pip line for a package that is not on PyPI.
    """
    import importlib.util

    from o3d_ofp.cli.main import main

    paths, _, _, _ = shapes
    real = importlib.util.find_spec

    def find_spec(name, *args):
        return None if name == "distributed" else real(name, *args)

    monkeypatch.setattr(importlib.util, "find_spec", find_spec)
    before = COUNTERS["source_bases"]
    argv = ["transfer", paths["src"], paths["t0"], paths["t1"], "-o", str(tmp_path / "o")]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert "Dask is not installed" in err and "--workers 0" in err and "-e '.[dask]'" in err
    assert COUNTERS["source_bases"] == before and not (tmp_path / "o").exists()


def test_a_collection_logs_each_target_s_quality_notes(shapes, tmp_path, capsys):
    """A collection's log keeps each target's quality notes; a one-pair run prints them once.

    A review: once the one-pair commands stopped logging the quality report they print, a
    collection (which prints no such report) lost it too, e.g. a target in other units.
    """
    paths, V, F, _ = shapes
    big = tmp_path / "big.ply"
    write_geometry(big, triangle_mesh_from_arrays(2.0 * _bent(V, 0.1), F))
    code = _cli("transfer", paths["src"], big, paths["t1"], "-o", tmp_path / "out",
                "--workers", "0")  # fmt: skip
    assert code == 0
    first = capsys.readouterr()
    err = first.err
    assert "the target's area is" in err  # the note of big.ply, at the default level
    # each target's line says of what its coverage is (a trial read it as the target's share),
    # in the log and in the command line's own line per target
    assert "map coverage" in err and "of the source's vertices" in err
    line = next(t for t in first.out.splitlines() if t.startswith("ok       big.ply"))
    assert "map coverage" in line and line.split("map coverage")[1].split(" -> ")[0].endswith(
        "of the source's vertices"
    )
    # one pair: printed once, on stdout (not also in the log)
    assert _cli("transfer", paths["src"], big, "-o", tmp_path / "one.ply") == 0
    captured = capsys.readouterr()
    assert "the target's area is" in captured.out and "the target's area is" not in captured.err


def test_a_target_in_other_units_has_the_area_note_in_the_summary(shapes, tmp_path, capsys):
    """The map's quality notes are in the summary files, not only in the log.

    Found by a trial: a target in millimetres (the source in metres) gave a pair run the
    note on the area ratio, and a collection's summary nothing.
    """
    from o3d_ofp.cli.main import main

    paths, V, F, _ = shapes
    mm = tmp_path / "mm.ply"
    write_geometry(mm, triangle_mesh_from_arrays(1000.0 * _bent(V, 0.1), F))
    out = tmp_path / "out"
    argv = ["transfer", paths["src"], str(mm), paths["t1"], "--workers", "0", "-o", str(out)]
    assert main(argv) == 0
    capsys.readouterr()
    rows = json.loads((out / "summary.json").read_text())["results"]
    assert len(rows[0]["notes"]) == 1 and "1e+06 times the source's" in rows[0]["notes"][0]
    assert rows[1]["notes"] == []
    with open(out / "summary.csv", newline="") as fh:
        cells = list(csv.DictReader(fh))
    assert cells[0]["notes"] == rows[0]["notes"][0] and cells[1]["notes"] == ""


def test_a_rerun_keeps_what_was_found_when_the_skipped_outputs_were_made(
    shapes, tmp_path, capsys
):
    """A skipped output's record keeps its map's suspect flag, coverage, warnings and notes.

    Found by a trial: a rerun over a folder skipped the finished targets and rewrote the
    summary with their suspect flags and warnings empty: the record that two written
    outputs were wrong was gone.
    """
    from o3d_ofp.cli.main import main
    from o3d_ofp.core.shapes import icosphere

    paths, V, F, _ = shapes
    sphere, mm = tmp_path / "sphere.ply", tmp_path / "mm.ply"
    write_geometry(sphere, triangle_mesh_from_arrays(*icosphere(3)))  # a suspect map
    write_geometry(mm, triangle_mesh_from_arrays(1000.0 * _bent(V, 0.1), F))  # a note
    out = tmp_path / "out"
    argv = ["transfer", paths["src"], str(sphere), str(mm), "--workers", "0", "-o", str(out)]
    assert main(argv) == 0
    first = json.loads((out / "summary.json").read_text())["results"]
    assert first[0]["suspect"] and first[0]["warnings"] and first[1]["notes"]
    capsys.readouterr()
    assert main(argv) == 0
    printed = capsys.readouterr().out
    assert "skipped  sphere.ply: up to date" in printed and "SUSPECT when it was made" in printed
    again = json.loads((out / "summary.json").read_text())["results"]
    assert [r["status"] for r in again] == ["skipped", "skipped"]
    for before, now in zip(first, again, strict=True):
        for key in ("coverage", "suspect", "n_vertices", "warnings", "notes", "kind"):
            assert now[key] == before[key], key


def test_a_fix_a_collection_cannot_apply_says_to_transfer_the_target_alone():
    """A fix a collection refuses (a partial match, landmarks) says to run the target alone.

    The fixes are read from the messages' codes, never from their words.
    """
    from o3d_ofp.collections.tasks import _for_collections
    from o3d_ofp.core.wording import Said

    part = Said(
        "the target looks like a part of the other shape; fix: {partial} with the whole shape "
        "as the source", {}, "looks_partial",
    )  # fmt: skip
    said = _for_collections(part)
    assert "o3d_ofp.match(..., partial=True) with the whole shape" in said
    assert "a collection makes no partial match" in said and "--partial" in said
    # a reason inside a suspect map's message: its code is read too
    suspect = Said("{what} is suspect:\n  - {r0}", {"what": "the map", "r0": part}, "suspect")
    assert "a collection makes no partial match" in _for_collections(suspect)
    assert _for_collections("coverage 0.2") == "coverage 0.2"
    assert str(_for_collections(Said("coverage {c}", {"c": 0.2}, "low"))) == "coverage 0.2"
    # the command and function of the collection's own kind
    symmetric = Said("a symmetric shape: fix: give a few known vertex pairs ({landmarks})")
    said = _for_collections(symmetric, "detail")
    assert "(o3d-ofp detail SOURCE TARGET --landmarks ..., or ofp.match(" in said
    assert "then ofp.transfer_detail(..., correspondence=...)" in said
    assert "o3d-ofp transfer SOURCE TARGET --landmarks" in _for_collections(symmetric)
    assert "ofp.transfer_texture(" in _for_collections(symmetric, "texture")
    # a map of the caller's or of closest points, which a collection refuses (a trial: the
    # detail's "estimated map hid the detail" advised --map FILE to a collection)
    unseen = Said("detail needs a map you trust: {give_map}; aligned copies: "
                  "{coordinates_closest}", {}, "detail_unseen")  # fmt: skip
    said = _for_collections(unseen, "detail")
    assert "a collection's maps are estimated or the identity" in said
    assert "o3d-ofp detail SOURCE TARGET --map FILE or --map closest" in said
    assert "ofp.transfer_detail(source, target, correspondence=...)" in said
    # a partial shape named as one likely cause among others is no fix to apply
    cause = Said("likely causes: a part of the other shape ({partial})", {}, "causes_far")
    assert _for_collections(cause) is cause  # unchanged, still a Said (worded by its reader)


def test_targets_sharing_a_file_name_are_renamed_and_said(tmp_path, caplog):
    """Two targets named ``x.ply`` in two folders: outputs ``x-0.ply`` and ``x-1.ply``, said.

    A trial: the renaming was silent, and the outputs did not say which target they came from.
    """
    from o3d_ofp.collections.engine import _specs

    items = [str(tmp_path / "a" / "x.ply"), str(tmp_path / "b" / "x.ply"), "y.ply"]
    with caplog.at_level(logging.INFO, logger="o3d_ofp.collections.engine"):
        specs, failed = _specs(items, str(tmp_path / "out"), "colors")
    assert [s.name for s in specs] == ["x-0.ply", "x-1.ply", "y.ply"] and not failed
    assert specs[1].output == str(tmp_path / "out" / "x-1.ply")
    (said,) = [r.getMessage() for r in caplog.records if "would write" in r.getMessage()]
    assert said == "2 targets would write x.ply: their outputs are named x-0.ply, x-1.ply"


def test_a_renamed_duplicate_never_takes_another_target_s_name(tmp_path):
    """``a/shape.ply``, ``b/shape.ply`` and ``c/shape-1.ply``: three outputs, not two.

    A trial: the second ``shape.ply`` was renamed ``shape-1.ply``, the third target's own
    name, and one result overwrote the other with every row "ok". Names differing only in
    letter case are one file on some file systems: renamed too.
    """
    from o3d_ofp.collections.engine import _names

    items = [str(tmp_path / d / n) for d, n in
             (("a", "shape.ply"), ("b", "shape.ply"), ("c", "shape-1.ply"))]  # fmt: skip
    assert _names(items, "colors") == ["shape-0.ply", "shape-1-2.ply", "shape-1.ply"]
    cased = [str(tmp_path / "a" / "X.ply"), str(tmp_path / "b" / "x.ply")]
    assert _names(cased, "colors") == ["X-0.ply", "x-1.ply"]


def test_relative_paths_are_read_where_the_caller_stands(client, shapes, tmp_path, monkeypatch):
    """Relative target and output paths name the caller's files, whatever the workers' folder.

    A trial with ``--scheduler``: the workers (started in another folder) opened that
    folder's ``A/shape.ply``, another person, and could not write into the output folder.
    """
    paths, _, _, colors = shapes
    here = tmp_path / "here"
    (here / "t").mkdir(parents=True)
    (here / "t" / "t0.ply").write_bytes(Path(paths["t0"]).read_bytes())
    monkeypatch.chdir(here)  # this process only: the workers stay where they were started
    results = transfer_many(paths["src"], ["t/t0.ply"], client=client, output_dir="out",
                            map="identity")  # fmt: skip
    assert [r.status for r in results] == ["ok"], results[0].error
    assert results[0].path == str(here / "t" / "t0.ply")
    assert np.abs(_colors(here / "out" / "t0.ply") - colors).mean() < 0.05


def test_a_rerun_redoes_outputs_of_another_source_or_target_or_not_its_own(shapes, tmp_path,
                                                                             caplog):  # fmt: skip
    """Only outputs the record says were made from these very files, unchanged, are skipped.

    A trial: a source with an older modification time (``cp -p``) left the outputs of another
    source "up to date"; targets given in another order swapped their ``-<i>`` names and were
    skipped, each row crediting the other's output; a folder of copies of the targets (no
    record) was skipped as "made with the same options"; an edited output was kept.
    """
    paths, V, F, colors = shapes
    run = {"workers": 0, "map": "identity"}
    red = tmp_path / "red.ply"
    write_geometry(red, triangle_mesh_from_arrays(V, F, colors=np.tile([1.0, 0, 0], (len(V), 1))))
    os.utime(red, (1e9, 1e9))  # 2001: older than every output
    out = tmp_path / "out"
    assert [r.status for r in transfer_many(paths["src"], [paths["t0"]], output_dir=out,
                                            **run)] == ["ok"]  # fmt: skip
    with caplog.at_level(logging.INFO, logger="o3d_ofp.collections"):
        (again,) = transfer_many(red, [paths["t0"]], output_dir=out, **run)
    assert again.status == "ok" and "made from another source" in caplog.text
    assert np.allclose(_colors(out / "t0.ply"), [1.0, 0, 0], atol=0.05)
    # an edited output is made again
    (out / "t0.ply").write_bytes(Path(paths["t1"]).read_bytes())
    assert transfer_many(red, [paths["t0"]], output_dir=out, **run)[0].status == "ok"
    assert transfer_many(red, [paths["t0"]], output_dir=out, **run)[0].status == "skipped"
    # two targets of one name, given the other way round: both made again, each its own
    a, b = tmp_path / "a", tmp_path / "b"
    for folder, name in ((a, "t0"), (b, "t1")):
        folder.mkdir()
        (folder / "shape.ply").write_bytes(Path(paths[name]).read_bytes())
    out2 = tmp_path / "out2"
    transfer_many(paths["src"], [a / "shape.ply", b / "shape.ply"], output_dir=out2, **run)
    caplog.clear()
    with caplog.at_level(logging.INFO, logger="o3d_ofp.collections"):
        swapped = transfer_many(paths["src"], [b / "shape.ply", a / "shape.ply"],
                                output_dir=out2, **run)  # fmt: skip
    assert [r.status for r in swapped] == ["ok", "ok"]
    assert f"made from another target, {a / 'shape.ply'}" in caplog.text
    b_bent = np.asarray(read_geometry(b / "shape.ply").vertices)
    assert np.allclose(np.asarray(read_geometry(out2 / "shape-0.ply").vertices), b_bent)
    # a folder holding files of the targets' names that no run made: made, not skipped
    out3 = tmp_path / "out3"
    out3.mkdir()
    (out3 / "t0.ply").write_bytes(Path(paths["t0"]).read_bytes())
    caplog.clear()
    with caplog.at_level(logging.INFO, logger="o3d_ofp.collections"):
        (made,) = transfer_many(paths["src"], [paths["t0"]], output_dir=out3, **run)
    assert made.status == "ok" and "not recorded as made by o3d_ofp" in caplog.text
    assert np.abs(_colors(out3 / "t0.ply") - colors).mean() < 0.05


def test_a_textured_source_s_image_is_part_of_what_the_outputs_were_made_from(shapes, tmp_path):
    """A changed texture image redoes the outputs; unchanged, they are skipped.

    A trial: after the source's image was edited, every target was "skipped: up to date".
    """
    from PIL import Image

    paths, V, F, _ = shapes
    mesh = triangle_mesh_from_arrays(V, F)
    uv = (V[:, :2] - V[:, :2].min(0)) / np.ptp(V[:, :2], axis=0)
    mesh.triangle_uvs = o3d.utility.Vector2dVector(uv[F].reshape(-1, 2))
    mesh.triangle_material_ids = o3d.utility.IntVector(np.zeros(len(F), dtype=np.int32))
    image = np.zeros((16, 16, 3), np.uint8)
    image[:, 8:] = 255
    mesh.textures = [o3d.geometry.Image(image)]
    src = tmp_path / "src.obj"
    write_geometry(src, mesh)
    (png,) = tmp_path.glob("*.png")
    run = {"workers": 0, "map": "identity", "output_dir": tmp_path / "out", "kind": "colors"}
    assert transfer_many(src, [paths["t0"]], **run)[0].status == "ok"
    assert transfer_many(src, [paths["t0"]], **run)[0].status == "skipped"
    Image.fromarray(255 - image).save(png)
    os.utime(png, (1e9, 1e9))  # an old time, as a copy keeping times would give
    assert transfer_many(src, [paths["t0"]], **run)[0].status == "ok"


def test_strict_fails_a_skipped_output_made_from_a_suspect_map(shapes, tmp_path):
    """Under ``strict`` an output recorded as made from a suspect map fails its target.

    A trial: a rerun with ``--strict`` skipped such outputs with exit 0.
    """
    paths, *_ = shapes
    out = tmp_path / "out"
    run = {"workers": 0, "map": "identity", "output_dir": out}
    assert transfer_many(paths["src"], [paths["t0"]], **run)[0].status == "ok"
    path = out / ".o3d_ofp_outputs.json"
    record = json.loads(path.read_text())
    record["outputs"]["t0.ply"]["found"]["suspect"] = True  # as a suspect map records it
    path.write_text(json.dumps(record))
    assert transfer_many(paths["src"], [paths["t0"]], **run)[0].status == "skipped"
    (r,) = transfer_many(paths["src"], [paths["t0"]], strict=True, **run)
    assert r.status == "failed" and "suspect map (strict)" in str(r.error)


def test_basis_offers_no_force_and_an_interrupt_on_a_cluster_says_what_may_still_run(
    shapes, tmp_path, capsys, caplog, monkeypatch
):
    """``basis --help`` lists no ``--force`` (refused there); an interrupt names running tasks.

    A trial: ``basis --help`` offered ``--force`` and the command refused it; after Ctrl-C
    with ``--scheduler`` the cluster's running tasks wrote outputs after "interrupted".
    """
    from o3d_ofp.collections import engine

    assert _cli("basis", "--help") == 0
    assert "--force" not in capsys.readouterr().out

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(engine, "_run", interrupted)
    paths, *_ = shapes
    for client, said in ((None, False), ("tcp://127.0.0.1:1", True)):
        caplog.clear()
        with caplog.at_level(logging.WARNING), pytest.raises(KeyboardInterrupt):
            transfer_many(paths["src"], [paths["t0"]], client=client, output_dir=tmp_path / "o",
                          map="identity")  # fmt: skip
        assert "interrupted: 0 of 1 targets done" in caplog.text
        assert ("cannot be stopped from here" in caplog.text) is said
