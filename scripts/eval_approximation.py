"""Reconstruction errors in the style of the paper's Table 1 (Sec. 4.3), as Markdown tables.

Rows are signals, columns the bases: K eigenfunctions (the paper's K includes the constant),
NK eigenfunctions, ours (tol 1e-2), ours* (tol 1e-9), and C(K+N, N) eigenfunctions (the
ideal, expensive reference). Errors are ‖f − f̃‖_M / ‖f‖_M, joint over channels; XYZ is
centred on its area-weighted mean.

Usage::

    python scripts/eval_approximation.py  # FAUST 093 (K=30, N=2), bunny RGB (K=30 and 100)
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np
import scipy.io

import o3d_ofp as ofp
from o3d_ofp import read_geometry
from o3d_ofp.boundary.convert import geometry_to_arrays

DATA = Path(__file__).resolve().parents[2] / "shared" / "data"


def eigs_error(f: np.ndarray, V: np.ndarray, F: np.ndarray, k: int) -> float:
    eig = ofp.eigenbasis(V, F, k=k)
    return ofp.approximation_error(f, eig.reconstruct(eig.project(f)), eig.mass)


def signals(V: np.ndarray, mass: np.ndarray, seed: int = 0) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(seed)
    X = V - (mass @ V) / mass.sum()
    height = (V[:, 1] - V[:, 1].min()) / np.ptp(V[:, 1])
    center = V[rng.integers(len(V))]
    radius = 0.25 * np.sqrt(mass.sum())
    return {
        "XYZ": X,
        "Ind": (np.linalg.norm(V - center, axis=1) < radius).astype(float),
        "sin(8πy)": np.sin(8 * np.pi * height),
    }


def table(name: str, V: np.ndarray, F: np.ndarray, fs: dict, K: int, order: int) -> list[str]:
    k = K - 1
    t0 = time.perf_counter()
    eig = ofp.eigenbasis(V, F, k=k)
    ours = ofp.ofp_basis(eig, order=order, preset="ours")
    star = ofp.ofp_basis(eig, order=order, preset="ours*")
    n_full = math.comb(k + order, order)
    cols = [
        f"K={K} eigs",
        f"NK={order * K} eigs",
        f"ours (q={ours.size})",
        f"ours* (q={star.size})",
    ]
    big = n_full < len(V) // 4
    if big:
        cols.append(f"{n_full} eigs")
    lines = [
        f"### {name}: n={len(V)}, K={K}, N={order}",
        "",
        "| signal | " + " | ".join(cols) + " |",
    ]
    lines.append("|---" * (len(cols) + 1) + "|")
    for sname, f in fs.items():
        row = [
            ofp.approximation_error(f, eig.reconstruct(eig.project(f)), eig.mass),
            eigs_error(f, V, F, order * K - 1),
            ours.approximation_error(f),
            star.approximation_error(f),
        ]
        if big:
            row.append(eigs_error(f, V, F, n_full - 1))
        lines.append(f"| {sname} | " + " | ".join(f"{100 * e:.2f} %" for e in row) + " |")
    lines.append("")
    lines.append(f"({time.perf_counter() - t0:.1f} s)")
    return lines


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--bunny-k", type=int, nargs="+", default=[30, 100], help="K values for the bunny"
    )
    args = parser.parse_args()
    if not DATA.exists():
        print(f"no data at {DATA}", file=sys.stderr)
        return 2
    V, F = geometry_to_arrays(read_geometry(DATA / "faust" / "tr_reg_093.ply"))
    mass = ofp.laplacian(V, F)[1]
    out = table("FAUST tr_reg_093", V, F, signals(V, mass), K=30, order=2)
    V, F = geometry_to_arrays(read_geometry(DATA / "models" / "bunny.off"))
    rgb = scipy.io.loadmat(DATA / "models" / "texture_bunny.mat")["M_col"].astype(float)
    for K in args.bunny_k:
        out += ["", *table("bunny RGB (texture_bunny.mat)", V, F, {"RGB": rgb}, K=K, order=2)]
    print("\n".join(out))
    return 0


if __name__ == "__main__":
    sys.exit(main())
