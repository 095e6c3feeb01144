"""Estimated maps on every ground-truth pair of ../shared/data: error, verdict, seconds.

    python scripts/eval_matching.py [--scales 0.01 1000]

For each pair: the map error (mean distance between the matched and the true source vertex,
divided by sqrt(source area)), the quality report of ``ofp.match`` and the wall time of the
match (both eigenbases with k = 99 included). ``--scales`` repeats the FAUST 093 -> 087 pair
with the target scaled by each factor (the map must not change).
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np
import scipy.io

import o3d_ofp as ofp
from o3d_ofp.boundary.convert import geometry_to_arrays

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"

PAIRS = [
    ("faust/tr_reg_093.ply", "faust/tr_reg_087.ply", "identity"),
    ("faust/tr_reg_019.ply", "faust/tr_reg_094.ply", "identity"),
    ("tosca/centaur2.off", "tosca/centaur4.off", "identity"),
    ("faust_remeshed/tr_reg_000.off", "faust_remeshed/tr_reg_001.off", "vts"),
    ("faust_remeshed/tr_reg_002.off", "faust_remeshed/tr_reg_007.off", "vts"),
    ("shrec19/32.ply", "shrec19/10.off", "mat"),
]


def load(rel: str) -> tuple[np.ndarray, np.ndarray]:
    return geometry_to_arrays(ofp.read_geometry(DATA / rel))


def truth(a: str, b: str, kind: str, n2: int) -> tuple[np.ndarray, np.ndarray]:
    """(target vertices, their true source vertices)."""
    if kind == "identity":
        return np.arange(n2), np.arange(n2)
    if kind == "vts":

        def vts(rel: str) -> np.ndarray:
            path = DATA / os.path.dirname(rel) / "corres" / (Path(rel).stem + ".vts")
            return np.loadtxt(path, dtype=np.int64) - 1

        return vts(b), vts(a)
    g = scipy.io.loadmat(DATA / "shrec19/10_32.mat")["gt_matches"].ravel().astype(np.int64) - 1
    return np.arange(n2), g


def run(a: str, b: str, kind: str, scale: float = 1.0) -> str:
    V1, F1 = load(a)
    V2, F2 = load(b)
    t0 = time.perf_counter()
    corr = ofp.match((V1, F1), (V2 * scale, F2))
    seconds = time.perf_counter() - t0
    area = ofp.laplacian(V1, F1)[1].sum()
    t, s = truth(a, b, kind, len(V2))
    err = np.linalg.norm(V1[corr.p2p_21[t]] - V1[s], axis=1).mean() / np.sqrt(area)
    q = corr.quality
    name = f"{Path(a).stem} -> {Path(b).stem}" + (f" (target x{scale:g})" if scale != 1 else "")
    return (
        f"| {name} | {err:.4f} | {q.coverage_ratio:.2f} | {q.orthogonality:.2f} | "
        f"{q.inconsistency:.2f} | {q.reversed_fraction:.2f} | "
        f"{'suspect' if q.suspect else 'ok'} | {seconds:.1f} |"
    )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scales", type=float, nargs="*", default=[0.01, 1000.0])
    args = parser.parse_args(argv)
    if not DATA.is_dir():
        sys.stderr.write(f"needs the shared data at {DATA}\n")
        return 2
    print(f"load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores")
    print(
        "| pair | map error | coverage | orthogonality | inconsistency | reversed | verdict | s |"
    )
    print("|---|---|---|---|---|---|---|---|")
    for a, b, kind in PAIRS:
        print(run(a, b, kind), flush=True)
    for s in args.scales:
        print(run(*PAIRS[0], scale=s), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
