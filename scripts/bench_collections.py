"""Throughput of collections: one source onto N targets, serially and on 1 and 2 local workers.

FAUST 093 (colored here from its coordinates) onto the other FAUST registrations and the
remeshed FAUST shapes of ../shared/data, repeated to N targets; every map is estimated
(descriptors, ZoomOut to 100 eigenfunctions). Modes:

* ``serial``: ``transfer_many(..., workers=0)``: a plain loop in this process;
* ``1`` / ``2``: a local Dask cluster of that many single-threaded worker processes (BLAS on
  one thread each), started before the clock (its start-up and the workers' imports are
  printed separately), the source's bases computed once per run in this process.

Prints seconds, targets/minute, the 2-worker / 1-worker throughput ratio, the load average
before each run (measure with nothing else running), and how many times the source's bases
were computed (once per run).

Usage::

    .venv/bin/python scripts/bench_collections.py [--n 8] [--modes serial,1,2] [--max-load 0.5]
"""

from __future__ import annotations

import argparse
import logging
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

DATA = Path(__file__).resolve().parents[2] / "shared" / "data"
SOURCE = "faust/tr_reg_093.ply"
TARGETS = (
    "faust/tr_reg_019.ply",
    "faust/tr_reg_087.ply",
    "faust/tr_reg_094.ply",
    "faust_remeshed/tr_reg_000.off",
    "faust_remeshed/tr_reg_001.off",
    "faust_remeshed/tr_reg_002.off",
    "faust_remeshed/tr_reg_004.off",
    "faust_remeshed/tr_reg_007.off",
)


def _load() -> str:
    return " ".join(f"{x:.2f}" for x in os.getloadavg())


def _wait_for_quiet(max_load: float | None, timeout: float) -> None:
    """Wait (up to ``timeout`` s) until the 1-minute load average is below ``max_load``."""
    if max_load is None:
        return
    t0 = time.time()
    while os.getloadavg()[0] > max_load and time.time() - t0 < timeout:
        time.sleep(10)
    if os.getloadavg()[0] > max_load:
        print(f"  warning: load average still {_load()} (> {max_load}): timings are disturbed")


def _colored_source(folder: str) -> str:
    from o3d_ofp.boundary.convert import geometry_to_arrays, triangle_mesh_from_arrays
    from o3d_ofp.boundary.io import read_geometry, write_geometry

    V, F = geometry_to_arrays(read_geometry(DATA / SOURCE))
    X = (V - V.min(0)) / np.ptp(V, axis=0)
    path = os.path.join(folder, "source_093.ply")
    write_geometry(path, triangle_mesh_from_arrays(V, F, colors=0.5 + 0.5 * np.sin(6 * X)))
    return path


def _warm() -> bool:
    import open3d  # noqa: F401

    import o3d_ofp.collections.tasks  # noqa: F401

    return True


def _peak_mb() -> float:
    """Peak resident memory of this process in MB: its memory's high-water mark.

    ``VmHWM`` from ``/proc/self/status`` (Linux), which starts afresh in a new program; not
    ``ru_maxrss``, which Linux carries over ``execve`` from the parent, so a worker spawned by
    a large process would report the parent's peak.
    """
    with open("/proc/self/status", encoding="ascii") as fh:
        for line in fh:
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) / 1024  # kB
    raise RuntimeError("no VmHWM in /proc/self/status")


def run(mode: str, source: str, targets: list[str], out: str) -> dict:
    from o3d_ofp.collections import COUNTERS, open_client, transfer_many

    before = COUNTERS["source_bases"]
    startup = 0.0
    if mode == "serial":
        t0 = time.perf_counter()
        results = transfer_many(source, targets, workers=0, output_dir=out, skip_existing=False)
        seconds = time.perf_counter() - t0
        peak = _peak_mb()  # this process (serial runs first: nothing earlier inflates it)
    else:
        t0 = time.perf_counter()
        with open_client(workers=int(mode)) as client:
            client.run(_warm)
            startup = time.perf_counter() - t0
            t1 = time.perf_counter()
            results = transfer_many(
                source, targets, client=client, output_dir=out, skip_existing=False
            )
            seconds = time.perf_counter() - t1
            peak = max(client.run(_peak_mb).values())  # the largest worker (fresh processes)
    return {
        "mode": mode,
        "seconds": seconds,
        "startup": startup,
        "per_target": float(np.mean([r.seconds for r in results])),
        "ok": sum(r.status == "ok" for r in results),
        "failed": [f"{r.name}: {r.error}" for r in results if r.status == "failed"],
        "suspect": sum(bool(r.suspect) for r in results),
        "source_bases": COUNTERS["source_bases"] - before,
        "peak_mb": peak,
    }


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--n", type=int, default=8, help="targets (the 8 held shapes, repeated)")
    p.add_argument("--modes", default="serial,1,2", help="comma-separated: serial, 1, 2, ...")
    p.add_argument(
        "--max-load", type=float, default=None, help="wait until the load average is below this"
    )
    p.add_argument("--wait", type=float, default=600, help="longest wait for a quiet machine (s)")
    p.add_argument("-v", "--verbose", action="store_true", help="log at INFO")
    args = p.parse_args()
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING)
    for handler in logging.getLogger().handlers:  # Dask sets INFO on its own loggers
        handler.addFilter(lambda r: r.levelno >= logging.WARNING or not r.name.startswith("distr"))
    missing = [t for t in (SOURCE, *TARGETS) if not (DATA / t).exists()]
    if missing:
        print(f"research data missing under {DATA}: {missing}")
        return 1
    targets = [str(DATA / TARGETS[i % len(TARGETS)]) for i in range(args.n)]
    print(f"python {sys.version.split()[0]}, cores {os.cpu_count()}, {args.n} targets")
    print(f"source {SOURCE} onto: " + ", ".join(TARGETS))
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        source = _colored_source(tmp)
        for mode in args.modes.split(","):
            _wait_for_quiet(args.max_load, args.wait)
            load = _load()
            r = run(mode, source, targets, os.path.join(tmp, f"out_{mode}_{len(rows)}"))
            r["load"] = load
            r["load_after"] = _load()
            rows.append(r)
            print(
                f"  {mode:>6}: {r['seconds']:7.1f} s  {60 * args.n / r['seconds']:6.2f} targets/min"
                f"  (mean {r['per_target']:.1f} s per target on its worker; peak RSS "
                f"{r['peak_mb']:.0f} MB per process; start-up "
                f"{r['startup']:.1f} s)  ok {r['ok']}/{args.n}, suspect {r['suspect']}, source "
                f"bases computed {r['source_bases']}x, load before {load}, after "
                f"{r['load_after']}"
            )
            for f in r["failed"]:
                print(f"          failed {f}")
    print()
    print(
        "| mode | workers | seconds | targets/min | peak MB per process | source bases "
        "| load avg before (1/5/15 min) | load avg after |"
    )
    print("|---|---|---|---|---|---|---|---|")
    for r in rows:
        workers = "in-process" if r["mode"] == "serial" else r["mode"]
        print(
            f"| {r['mode']} | {workers} | {r['seconds']:.1f} | {60 * args.n / r['seconds']:.2f} | "
            f"{r['peak_mb']:.0f} | {r['source_bases']} | {r['load']} | {r['load_after']} |"
        )
    best: dict[str, float] = {}  # fastest run of each mode: the least disturbed one
    for r in rows:
        best[r["mode"]] = min(best.get(r["mode"], np.inf), r["seconds"])
    if "1" in best and "2" in best:
        print(f"throughput 2 workers / 1 worker: {best['1'] / best['2']:.2f}x (fastest runs)")
    if "serial" in best and "2" in best:
        print(f"throughput 2 workers / serial:   {best['serial'] / best['2']:.2f}x (fastest runs)")
    print(f"load average at the end: {_load()}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
