"""The eigensolver's two Lanczos methods on the same shapes: block Lanczos against ARPACK.

    python scripts/bench_eigensolve.py [--levels 0 1] [--k 29 39 59 99]

FAUST tr_reg_093 (../shared/data) midpoint-subdivided ``level`` times (6890, 27.5k, 110k,
440k vertices). For each ``k``: ``ofp.eigenbasis(V, F, k=k)`` (Laplacian, factorization,
Lanczos, Rayleigh-Ritz, signs, checks: the whole call, one BLAS thread as in the library) by
block Lanczos (o3d_ofp.core._lanczos) and by ARPACK (SciPy's ``eigsh``, the library's
fallback), alternately, ``--repeat`` times each (best time kept); seconds, peak memory of the
process during the call (psutil, sampled every 5 ms), ARPACK / block, the largest eigenvalue
difference relative to λ_k, and which method the library picks (block Lanczos from
``MIN_PAIRS`` eigenpairs on ``MIN_VERTICES`` vertices, see o3d_ofp.core._lanczos).
"""

from __future__ import annotations

import argparse
import os
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

from bench_match import Peak, faust_pair

import o3d_ofp as ofp
from o3d_ofp.core import _lanczos, spectrum


def solve(V: np.ndarray, F: np.ndarray, k: int, method: str) -> tuple[ofp.EigenBasis, Peak]:
    saved = spectrum.MIN_PAIRS, spectrum.MIN_VERTICES, spectrum._block_fits
    if method == "block":
        spectrum.MIN_PAIRS = spectrum.MIN_VERTICES = 0
    else:
        spectrum._block_fits = lambda n, k: False
    try:
        with Peak() as m:
            eig = ofp.eigenbasis(V, F, k=k)
    finally:
        spectrum.MIN_PAIRS, spectrum.MIN_VERTICES, spectrum._block_fits = saved
    return eig, m


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--levels", type=int, nargs="+", default=[0, 1])
    parser.add_argument("--k", type=int, nargs="+", default=[29, 39, 59, 99])
    parser.add_argument("--repeat", type=int, default=2)
    args = parser.parse_args(argv)
    print(
        f"library default: block Lanczos from {_lanczos.MIN_PAIRS} eigenpairs (k + 1) on "
        f"{_lanczos.MIN_VERTICES} vertices or more"
    )
    print("| vertices | k | block s | ARPACK s | ARPACK / block | block peak GB | ARPACK peak GB "
          "| max dλ / λ_k | default | others' CPU |")  # fmt: skip
    print("|---|---|---|---|---|---|---|---|---|---|")
    for level in args.levels:
        V, F = faust_pair(level)[:2]
        ofp.eigenbasis(V, F, k=5)  # warm-up: imports, first factorization
        for k in args.k:
            best: dict[str, tuple[float, float]] = {}
            evals: dict[str, np.ndarray] = {}
            others = 0.0
            for _ in range(args.repeat):
                for method in ("block", "arpack"):
                    eig, m = solve(V, F, k, method)
                    old = best.get(method, (np.inf, 0.0))
                    best[method] = (min(old[0], m.seconds), max(old[1], m.peak))
                    evals[method] = eig.evals
                    others = max(others, m.others)
            diff = np.abs(evals["block"] - evals["arpack"]).max() / evals["arpack"][-1]
            block = k + 1 >= _lanczos.MIN_PAIRS and V.shape[0] >= _lanczos.MIN_VERTICES
            default = "block" if block else "ARPACK"
            print(
                f"| {V.shape[0]} | {k} | {best['block'][0]:.2f} | {best['arpack'][0]:.2f} | "
                f"{best['arpack'][0] / best['block'][0]:.2f}x | {best['block'][1] / 1e9:.2f} | "
                f"{best['arpack'][1] / 1e9:.2f} | {diff:.1e} | {default} | {others:.0%} |",
                flush=True,
            )
    return 0


if __name__ == "__main__":
    sys.exit(main())
