"""End-to-end benchmark: per-stage time and peak memory, scaling with n, and pyFM head-to-head.

Scaling (``--sizes``): a bumpy torus of about n vertices is the source; the target is a bent
copy with the same vertex order, so the map's error is measured exactly. The chain is the
issue's "whole chain": eigensolve (k on both shapes), products, orthogonalization (order N,
tol), functional map estimation (WKS fit, no refinement), p2p map, transfer of the
coordinates. Every stage reports wall seconds and the process's peak RSS during it (sampled
every 5 ms, so memory allocated inside CHOLMOD/ARPACK counts); the growth of each stage's
time with n is fitted as ``t ∝ n^p`` over the sizes run.

Head-to-head (``--pair faust``): FAUST 093 → 087 (6890 vertices each, paper settings:
k₁ = 29, k₂ = 39, order 2, estimated map without ground truth) end to end with o3d_ofp,
and pyFM's standard pipeline (``pip install pyfmaps``: k = 100 WKS descriptors, fit K = 30 with
the orientation term, ZoomOut 30 → 100, p2p) on the same pair, in the same process,
``--repeat`` times alternately; medians, the speed ratio and both p2p errors (mean geodesic
proxy: Euclidean distance to the true match / √area; FAUST registrations share vertex order).

    python scripts/bench.py --sizes 10000 50000 200000 500000 --json bench.json
    python scripts/bench.py --sizes --pair faust --repeat 3
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from bench_basis import PeakRSS, bumpy_torus

import o3d_ofp as ofp
from o3d_ofp.core.correspondence import p2p_from_fmap
from o3d_ofp.core.fmap import estimate_fmap
from o3d_ofp.core.orthogonalize import resolve_tol
from o3d_ofp.core.products import eigenproduct_blocks

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
STAGES = ("eigensolve", "products", "orthogonalization", "map", "p2p", "transfer")


def bent(V: np.ndarray) -> np.ndarray:
    """Return a near-isometric copy: bent around the z axis, moved."""
    W = V.copy()
    W[:, 1] += 0.1 * W[:, 0] ** 2
    return W + 1.0


def chain(n_target: int, k: int, order: int, tol: float) -> dict:
    V1, F = bumpy_torus(n_target)
    V2 = bent(V1)
    row: dict = {"n": len(V1), "k": k, "order": order, "tol": tol}

    def stage(name: str, fn):
        with PeakRSS() as m:
            out = fn()
        row[f"{name}_s"] = row.get(f"{name}_s", 0.0) + m.seconds
        row[f"{name}_peak_gb"] = max(row.get(f"{name}_peak_gb", 0.0), m.peak / 1e9)
        return out

    e1 = stage("eigensolve", lambda: ofp.eigenbasis(V1, F, k=k))
    e2 = stage("eigensolve", lambda: ofp.eigenbasis(V2, F, k=k))
    for e in (e1, e2):  # the products alone (streamed, as ofp_basis makes them)
        stage(
            "products", lambda e=e: sum(b.shape[1] for _, b in eigenproduct_blocks(e.evecs, order))
        )
    B1 = stage("basis", lambda: ofp.ofp_basis(e1, order=order, tol=tol))
    B2 = stage("basis", lambda: ofp.ofp_basis(e2, order=order, tol=tol))
    row["orthogonalization_s"] = row["basis_s"] - row["products_s"]
    row["orthogonalization_peak_gb"] = row.pop("basis_peak_gb")
    row["kept"] = B1.size
    C = stage("map", lambda: estimate_fmap(e1, e2, k1=k, k2=k, refine=None))
    p2p = stage("p2p", lambda: p2p_from_fmap(C, e1, e2))
    stage(
        "transfer",
        lambda: ofp.transfer_signal(V1, B1, B2, ofp.transfer_matrix(B1, B2, p2p_21=p2p)),
    )
    row["p2p_error"] = float(np.linalg.norm(V1[p2p] - V1, axis=1).mean() / np.sqrt(e1.area))
    row["total_s"] = sum(row[f"{s}_s"] for s in STAGES)
    row["peak_gb"] = max(row[f"{s}_peak_gb"] for s in STAGES if f"{s}_peak_gb" in row)
    return row


def fit_exponents(rows: list[dict]) -> dict:
    """Least-squares slope of log(time) against log(n), per stage (needs two sizes or more)."""
    if len(rows) < 2:
        return {}
    x = np.log([r["n"] for r in rows])
    out = {}
    for s in (*STAGES, "total"):
        y = np.log([max(r[f"{s}_s"], 1e-6) for r in rows])
        out[s] = float(np.polyfit(x, y, 1)[0])
    return out


def ours_end_to_end(V1, F1, V2, F2, f) -> tuple[np.ndarray, np.ndarray, float]:
    t0 = time.perf_counter()
    e1, e2 = ofp.eigenbasis(V1, F1, k=99), ofp.eigenbasis(V2, F2, k=99)
    corr = ofp.match_eigenbases(e1, e2)
    options = ofp.BasisOptions(k1=29, k2=39, order=2)
    g = ofp.transfer_function(f, e1, e2, correspondence=corr, options=options)
    return corr.p2p_21, g, time.perf_counter() - t0


def pyfm_end_to_end(V1, F1, V2, F2, f) -> tuple[np.ndarray, np.ndarray, float]:
    from pyFM.functional import FunctionalMapping
    from pyFM.mesh import TriMesh

    t0 = time.perf_counter()
    model = FunctionalMapping(TriMesh(V1, F1), TriMesh(V2, F2))
    model.preprocess(n_descr=100, descr_type="WKS", k_process=100, k_descr=100, verbose=False)
    model.fit(K=(30, 30), w_descr=1e0, w_lap=1e-2, w_dcomm=1e-1, w_orient=1e0, verbose=False)
    # pyfmaps 1.3.1: zoomout_refine RETURNS the refined map (model.FM_12 is not updated).
    FM = model.zoomout_refine(nit=70, step=1, subsample=2000, verbose=False)  # 30 → 100
    p2p = model.get_p2p(FM=FM)
    g = f[p2p]  # pyFM's transfer of a signal: pull back through the point map
    return p2p, g, time.perf_counter() - t0


def head_to_head(repeat: int) -> dict:
    from o3d_ofp import read_geometry
    from o3d_ofp.boundary.convert import geometry_to_arrays

    V1, F1 = geometry_to_arrays(read_geometry(DATA / "faust/tr_reg_093.ply"))
    V2, F2 = geometry_to_arrays(read_geometry(DATA / "faust/tr_reg_087.ply"))
    area = ofp.laplacian(V1, F1)[1].sum()
    f = V1 - V1.mean(axis=0)
    runs: dict = {"ours": [], "pyfm": []}
    errors: dict = {}
    for _ in range(repeat):
        for name, fn in (("ours", ours_end_to_end), ("pyfm", pyfm_end_to_end)):
            p2p, _, seconds = fn(V1, F1, V2, F2, f)
            runs[name].append(seconds)
            errors[name] = float(np.linalg.norm(V1[p2p] - V1, axis=1).mean() / np.sqrt(area))
    med = {k: statistics.median(v) for k, v in runs.items()}
    return {
        "pair": "FAUST tr_reg_093 -> tr_reg_087",
        "ours_s": med["ours"],
        "pyfm_s": med["pyfm"],
        "speedup": med["pyfm"] / med["ours"],
        "ours_p2p_error": errors["ours"],
        "pyfm_p2p_error": errors["pyfm"],
        "runs": runs,
    }


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="*", default=[10_000, 50_000, 200_000])
    parser.add_argument("--k", type=int, default=29)
    parser.add_argument("--order", type=int, default=2)
    parser.add_argument("--preset", default="ours", choices=["ours", "ours*"])
    parser.add_argument("--pair", choices=["faust"], help="pyFM head-to-head on a shared pair")
    parser.add_argument("--repeat", type=int, default=3, help="head-to-head repeats (median)")
    parser.add_argument("--json", help="write all results to this JSON file")
    args = parser.parse_args()
    tol = resolve_tol(None, args.preset)
    result: dict = {"chain": []}
    if args.sizes:
        cols = " ".join(f"{s[:6]:>7}" for s in STAGES)
        print(f"{'n':>8} {cols} {'total':>7} {'peak GB':>8} {'kept':>5} {'p2p err':>8}")
        for size in args.sizes:
            r = chain(size, args.k, args.order, tol)
            result["chain"].append(r)
            cells = " ".join(f"{r[f'{s}_s']:7.2f}" for s in STAGES)
            print(
                f"{r['n']:>8} {cells} {r['total_s']:7.2f} {r['peak_gb']:8.2f} {r['kept']:>5} "
                f"{r['p2p_error']:8.4f}",
                flush=True,
            )
        exps = fit_exponents(result["chain"])
        if exps:
            result["exponents"] = exps
            print("time ∝ n^p:", ", ".join(f"{s} {p:.2f}" for s, p in exps.items()))
    if args.pair:
        if not DATA.is_dir():
            print(f"no shared data at {DATA}", file=sys.stderr)
            return 2
        h = head_to_head(args.repeat)
        result["head_to_head"] = h
        print(
            f"{h['pair']}: o3d_ofp {h['ours_s']:.2f} s (p2p error {h['ours_p2p_error']:.4f}), "
            f"pyFM {h['pyfm_s']:.2f} s (p2p error {h['pyfm_p2p_error']:.4f}): "
            f"{h['speedup']:.1f}x faster (median of {args.repeat})"
        )
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(result, fh, indent=2)
    return 0


if __name__ == "__main__":
    sys.exit(main())
