"""Benchmark the basis pipeline: Laplacian, eigensolve, products, orthogonalization.

Procedural meshes (a bumpy torus, irregular enough to have a simple spectrum) of the requested
vertex counts. For each stage: wall seconds and the peak resident memory of the process during
the stage (sampled every 5 ms by a thread, so allocations made inside SuperLU/ARPACK count).
The orthogonalization also reports its achieved GFLOP/s (flops counted from the kept set)
beside a plain GEMM of the same shape measured in the same run, and, where it is affordable,
the time of the per-column reference loop.

Usage::

    python scripts/bench_basis.py --sizes 10000 50000 200000 --k 29 --order 2
    python scripts/bench_basis.py --sizes 10000 --reference --json bench.json
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import threading
import time

import numpy as np
import psutil

import o3d_ofp as ofp
from o3d_ofp.core.orthogonalize import gram_schmidt, resolve_tol
from o3d_ofp.core.products import eigenproducts, n_eigenproducts
from o3d_ofp.core.shapes import torus


class PeakRSS:
    """Context manager: wall time and peak RSS (bytes) of the process while it is open."""

    def __init__(self, interval: float = 0.005) -> None:
        self.proc = psutil.Process(os.getpid())
        self.interval = interval

    def __enter__(self) -> PeakRSS:
        self.peak = self.proc.memory_info().rss
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()
        self.t0 = time.perf_counter()
        return self

    def _run(self) -> None:
        while not self._stop.is_set():
            self.peak = max(self.peak, self.proc.memory_info().rss)
            time.sleep(self.interval)

    def __exit__(self, *exc: object) -> None:
        self.seconds = time.perf_counter() - self.t0
        self._stop.set()
        self._thread.join()
        self.peak = max(self.peak, self.proc.memory_info().rss)


def bumpy_torus(n_target: int) -> tuple[np.ndarray, np.ndarray]:
    """Torus grid with about ``n_target`` vertices, radially displaced by smooth bumps."""
    n_minor = max(8, round(math.sqrt(n_target / 2)))
    n_major = max(8, round(n_target / n_minor))
    V, F = torus(n_major, n_minor)
    rng = np.random.default_rng(0)
    centers = V[rng.choice(len(V), 9, replace=False)]
    bump = sum(
        w * np.exp(-((V - c) ** 2).sum(1) / 0.15)
        for w, c in zip(rng.uniform(-0.15, 0.15, 9), centers, strict=True)
    )
    return V * (1.0 + bump)[:, None], F


def gs_flops(kept: np.ndarray, n: int, total: int, block: int, tol: float) -> float:
    """Floating-point operations the blocked algorithm performs for a given kept set."""
    flops = 0.0
    kept_sorted = np.sort(kept)
    for start in range(0, total, block):
        b = min(block, total - start)
        q_before = np.searchsorted(kept_sorted, start)
        t = np.searchsorted(kept_sorted, start + b) - q_before
        flops += 2 * 4.0 * n * q_before * b  # two projection passes: Qᵀ W and W -= Q C
        flops += 2.0 * n * t * b  # in-block rows of R
        if tol >= 1e-4:  # Gram selection: WᵀW, then Cholesky-QR2 (2 trsm + 1 Gram)
            flops += 2.0 * n * b * b + 4.0 * n * t * t
        else:  # recursive halving: two passes against the kept left halves, ~b/2 per level
            flops += 2 * 4.0 * n * (t / 2) * (b / 2) * max(np.log2(b), 1)
    return flops


def gemm_rate(n: int, q: int, b: int = 64, repeat: int = 3) -> float:
    """GFLOP/s of a plain (q×n)·(n×b) product, the kernel of one projection pass."""
    rng = np.random.default_rng(1)
    Q = np.asfortranarray(rng.standard_normal((n, q)))
    W = np.asfortranarray(rng.standard_normal((n, b)))
    best = math.inf
    for _ in range(repeat):
        t0 = time.perf_counter()
        Q.T @ W
        best = min(best, time.perf_counter() - t0)
    return 2.0 * n * q * b / best / 1e9


def reference_loop_seconds(B: np.ndarray, mass: np.ndarray, tol: float) -> float:
    sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))
    from tests._reference import gram_schmidt_loop

    t0 = time.perf_counter()
    gram_schmidt_loop(B, mass, tol)
    return time.perf_counter() - t0


def run(n_target: int, k: int, order: int, tol: float, reference: bool, repeat: int) -> dict:
    V, F = bumpy_torus(n_target)
    n = len(V)
    row: dict = {"n": n, "k": k, "order": order, "tol": tol}
    with PeakRSS() as m:
        ofp.laplacian(V, F)
    row["laplacian_s"], row["laplacian_peak_gb"] = m.seconds, m.peak / 1e9
    with PeakRSS() as m:
        eig = ofp.eigenbasis(V, F, k=k)
    row["eigensolve_s"], row["eigensolve_peak_gb"] = m.seconds, m.peak / 1e9  # includes Laplacian
    total = n_eigenproducts(k, order)
    row["candidates"] = total
    times = []
    for _ in range(repeat):
        with PeakRSS() as m:
            B, _ = eigenproducts(eig.evecs, order)
        times.append(m.seconds)
    row["products_s"], row["products_peak_gb"] = float(np.median(times)), m.peak / 1e9
    times = []
    for _ in range(repeat):
        with PeakRSS() as m:
            gs = gram_schmidt(B, eig.mass, tol=tol)
        times.append(m.seconds)
    row["orthogonalization_s"] = float(np.median(times))
    row["orthogonalization_peak_gb"] = m.peak / 1e9
    row["kept"] = int(gs.Q.shape[1])
    row["orth_error"] = float(
        np.abs(gs.Q.T @ (eig.mass[:, None] * gs.Q) - np.eye(gs.Q.shape[1])).max()
    )
    flops = gs_flops(gs.kept, n, total, 128, tol)
    row["orth_gflops"] = flops / max(row["orthogonalization_s"], 1e-9) / 1e9
    row["gemm_gflops"] = gemm_rate(n, max(row["kept"] // 2, 1))
    if reference:
        row["reference_loop_s"] = reference_loop_seconds(B, eig.mass, tol)
        row["speedup_vs_reference"] = row["reference_loop_s"] / row["orthogonalization_s"]
    del gs, B
    with PeakRSS() as m:
        ofp.ofp_basis(eig, order=order, tol=tol)
    row["basis_total_s"] = row["eigensolve_s"] + m.seconds
    row["basis_peak_gb"] = max(row["eigensolve_peak_gb"], m.peak / 1e9)
    return row


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[10_000, 50_000, 200_000])
    parser.add_argument("--k", type=int, default=29)
    parser.add_argument("--order", type=int, default=2)
    parser.add_argument("--tol", type=float, default=None, help="drop threshold (default: preset)")
    parser.add_argument("--preset", default="ours", choices=["ours", "ours*"])
    parser.add_argument("--reference", action="store_true", help="also time the per-column loop")
    parser.add_argument(
        "--repeat",
        type=int,
        default=3,
        help="repeats of the products and orthogonalization stages (median reported)",
    )
    parser.add_argument("--json", help="write the rows to this JSON file")
    args = parser.parse_args()
    tol = resolve_tol(args.tol, None if args.tol is not None else args.preset)
    rows = []
    header = (
        f"{'n':>8} {'eig s':>7} {'prod s':>7} {'orth s':>7} {'total s':>8} {'peak GB':>8} "
        f"{'kept':>5}/{'cand':<5} {'orth GF/s':>9} {'GEMM GF/s':>9} {'‖QᵀMQ-I‖':>9} {'ref s':>7}"
    )
    print(header)
    for size in args.sizes:
        r = run(size, args.k, args.order, tol, args.reference, args.repeat)
        rows.append(r)
        ref = f"{r['reference_loop_s']:7.2f}" if "reference_loop_s" in r else f"{'-':>7}"
        print(
            f"{r['n']:>8} {r['eigensolve_s']:7.2f} {r['products_s']:7.2f} "
            f"{r['orthogonalization_s']:7.2f} {r['basis_total_s']:8.2f} {r['basis_peak_gb']:8.2f} "
            f"{r['kept']:>5}/{r['candidates']:<5} {r['orth_gflops']:9.1f} {r['gemm_gflops']:9.1f} "
            f"{r['orth_error']:9.1e} {ref}",
            flush=True,
        )
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(rows, fh, indent=2)
    return 0


if __name__ == "__main__":
    sys.exit(main())
