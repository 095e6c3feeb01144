"""Function transfer tables in the style of the paper's Sec. 4.4, on the pairs in ../shared/data.

For each pair and each function family (HK with K and with 200 eigenfunctions, HKS, WKS, Rand,
XYZ, Ind), the transfer error ‖f_gt − f̃‖_M / ‖f_gt‖_M on the target (f_gt: the source function
pulled back through the ground-truth correspondence) for K eigs / prods / ours / ours* / NK,
once with the ground-truth functional map and once with an estimated one (WKS descriptors,
orientation term, ZoomOut to 100; no ground truth used). Also the mean error of the p2p maps:
Euclidean distance between the matched and the true target positions, divided by √area.

``--pyfm`` also runs pyFM at its fastest usual setting (``bench_match.pyfm``; ``pip install
pyfmaps``, evaluation only) on FAUST 093→087 and TOSCA centaur2→centaur4 in the same process and
prints both p2p errors and the maps' seconds.

Usage::

    python scripts/eval_transfer.py                  # all pairs, Markdown tables on stdout
    python scripts/eval_transfer.py --pairs faust_093_087 --pyfm
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
from o3d_ofp.core.baselines import transfer_eigs, transfer_prods
from o3d_ofp.core.correspondence import p2p_from_template
from o3d_ofp.core.io import read_vts
from o3d_ofp.workflows.estimate import match_eigenbases

DATA = Path(__file__).resolve().parents[2] / "shared" / "data"

# name: (source, target, ground truth kind, order, k1, k2)
PAIRS = {
    "faust_093_087": ("faust/tr_reg_093.ply", "faust/tr_reg_087.ply", "identity", 2, 29, 39),
    "faust_019_094": ("faust/tr_reg_019.ply", "faust/tr_reg_094.ply", "identity", 2, 29, 39),
    "centaur_2_4": ("tosca/centaur2.off", "tosca/centaur4.off", "identity", 3, 11, 11),
    "faust_remeshed_000_001": (
        "faust_remeshed/tr_reg_000.off",
        "faust_remeshed/tr_reg_001.off",
        "vts",
        2,
        29,
        39,
    ),
    "faust_remeshed_002_007": (
        "faust_remeshed/tr_reg_002.off",
        "faust_remeshed/tr_reg_007.off",
        "vts",
        2,
        29,
        39,
    ),
    "shrec19_32_10": ("shrec19/32.ply", "shrec19/10.off", "shrec", 2, 29, 39),
}
COLUMNS = ["K eigs", "prods", "ours", "ours*", "NK"]


def load(rel: str) -> tuple[np.ndarray, np.ndarray]:
    return geometry_to_arrays(read_geometry(DATA / rel))


def ground_truth(kind: str, src: str, tgt: str, V2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Dense p2p_21 and the target vertices where it is exact (others: nearest listed vertex)."""
    n2 = V2.shape[0]
    if kind == "identity":
        return np.arange(n2), np.arange(n2)
    if kind == "shrec":
        gt = (
            scipy.io.loadmat(DATA / "shrec19" / "10_32.mat")["gt_matches"].ravel().astype(np.int64)
            - 1
        )
        return gt, np.arange(n2)
    a = read_vts(DATA / "faust_remeshed" / "corres" / (Path(src).stem + ".vts"))
    b = read_vts(DATA / "faust_remeshed" / "corres" / (Path(tgt).stem + ".vts"))
    return p2p_from_template(a, b, V2), np.unique(b)


def families(
    eig200: ofp.EigenBasis, V1: np.ndarray, K: int, rng: np.random.Generator
) -> dict[str, np.ndarray]:
    """Source functions of the paper's families (Sec. 4.3), several columns each."""
    n = V1.shape[0]
    t = 4 * math.log(10) / eig200.evals[-1]  # exp(−λt) = 1e-4 at the last eigenvalue: sharp
    centers = rng.integers(0, n, 5)
    weights = np.exp(-eig200.evals * t)
    hk200 = eig200.evecs @ (weights[:, None] * eig200.evecs[centers].T)
    eK = eig200.truncate(K)
    hkK = eK.evecs @ (weights[: K + 1, None] * eK.evecs[centers].T)
    hks = ofp.hks(eig200, n_times=5)
    wks = ofp.wks(eig200, n_energies=5)
    X = V1 - (eig200.mass @ V1) / eig200.area
    ind = np.stack(
        [
            (np.linalg.norm(V1 - V1[c], axis=1) < 0.25 * math.sqrt(eig200.area)).astype(float)
            for c in centers
        ],
        axis=1,
    )
    return {
        "HK (K eigs)": hkK,
        "HK (200 eigs)": hk200,
        "HKS": hks,
        "WKS": wks,
        "Rand": rng.uniform(size=(n, 5)),
        "XYZ": X,
        "Ind": ind,
    }


def p2p_error(
    p2p: np.ndarray, gt: np.ndarray, V1: np.ndarray, on: np.ndarray, area1: float
) -> float:
    """Mean distance, on the source, between matched and true source vertices, / √area."""
    return float(np.linalg.norm(V1[p2p[on]] - V1[gt[on]], axis=1).mean() / math.sqrt(area1))


def run_pair(name: str, n_eig: int = 200) -> list[str]:
    src, tgt, kind, order, k1, k2 = PAIRS[name]
    V1, F1 = load(src)
    V2, F2 = load(tgt)
    gt, on = ground_truth(kind, src, tgt, V2)
    t0 = time.perf_counter()
    big = min(n_eig - 1, V1.shape[0] - 2, V2.shape[0] - 2)
    e1_big, e2_big = ofp.eigenbasis(V1, F1, k=big), ofp.eigenbasis(V2, F2, k=big)
    e1, e2 = e1_big.truncate(k1), e2_big.truncate(k2)
    nk1, nk2 = order * (k1 + 1) - 1, order * (k2 + 1) - 1
    e1N, e2N = e1_big.truncate(nk1), e2_big.truncate(nk2)
    B = {
        p: (ofp.ofp_basis(e1, order=order, preset=p), ofp.ofp_basis(e2, order=order, preset=p))
        for p in ("ours", "ours*")
    }
    fs = families(e1_big, V1, k1, np.random.default_rng(0))
    lines = [
        f"### {name}: {Path(src).name} ({V1.shape[0]} v) → {Path(tgt).name} ({V2.shape[0]} v), "
        f"order {order}, k1 = {k1}, k2 = {k2} (paper K = {k1 + 1} / {k2 + 1}); "
        f"ours keeps {B['ours'][0].size} / {B['ours'][1].size}, "
        f"ours* {B['ours*'][0].size} / {B['ours*'][1].size}",
        "",
    ]
    mass_on = np.zeros(V2.shape[0])
    mass_on[on] = e2.mass[on]

    def err(g: np.ndarray, f_gt: np.ndarray) -> float:
        # zero mass off the vertices where the ground truth is exact: they do not count
        return ofp.approximation_error(f_gt, g, mass_on)

    zoom_to = min(99, big)
    settings = {}
    C_gt_big = ofp.fmap_from_p2p(gt, e1_big, e2_big, k1=max(nk1, k1), k2=max(nk2, k2))
    settings["ground-truth map"] = (C_gt_big, C_gt_big)
    ts = time.perf_counter()
    _corr = match_eigenbases(e1_big, e2_big, options=ofp.MatchOptions(zoomout_to=zoom_to))
    C_est_big, p2p_est = _corr.fmap_12, _corr.p2p_21
    t_match = time.perf_counter() - ts
    settings["estimated map"] = (C_est_big, C_est_big)
    for setting, (C_small_src, C_nk_src) in settings.items():
        C = C_small_src[: k2 + 1, : k1 + 1]
        C_nk = (
            C_nk_src[: nk2 + 1, : nk1 + 1]
            if C_nk_src.shape[0] > nk2 and C_nk_src.shape[1] > nk1
            else None
        )
        T = {p: ofp.transfer_matrix(*B[p], C) for p in B}
        p2p_C = ofp.p2p_from_fmap(C, e1, e2)
        lines += [
            f"**{setting}** (p2p error of Π from C: {p2p_error(p2p_C, gt, V1, on, e1.area):.4f}"
            + (
                f"; final ZoomOut map: {p2p_error(p2p_est, gt, V1, on, e1.area):.4f}, "
                f"{t_match:.1f} s"
                if setting == "estimated map"
                else ""
            )
            + ")",
            "",
            "| family | " + " | ".join(COLUMNS) + " |",
            "|---" * (len(COLUMNS) + 1) + "|",
        ]
        for fam, f in fs.items():
            f_gt = f[gt]
            row = [
                err(transfer_eigs(f, e1, e2, C), f_gt),
                err(transfer_prods(f, e1, e2, C, order), f_gt),
                err(ofp.transfer_signal(f, *B["ours"], T["ours"]), f_gt),
                err(ofp.transfer_signal(f, *B["ours*"], T["ours*"]), f_gt),
                err(transfer_eigs(f, e1N, e2N, C_nk), f_gt) if C_nk is not None else float("nan"),
            ]
            lines.append(f"| {fam} | " + " | ".join(f"{100 * e:.1f} %" for e in row) + " |")
        lines.append("")
    lines.append(f"({time.perf_counter() - t0:.0f} s for this pair)")
    return lines


def head_to_head(name: str) -> str:
    """Run pyFM and ours on one pair, in this process: p2p errors and the maps' seconds.

    pyFM at its fastest usual setting, called as ``bench_match.pyfm`` does (one place for
    pyFM's call: k = 100, WKS, the fit of K = 30 with the orientation term, ZoomOut
    ``nit=14, step=5``, the point map of the refined map).
    """
    sys.path.insert(0, str(Path(__file__).resolve().parent))  # bench_match
    from bench_match import pyfm

    src, tgt, kind, *_ = PAIRS[name]
    V1, F1 = load(src)
    V2, F2 = load(tgt)
    gt, on = ground_truth(kind, src, tgt, V2)
    area1 = ofp.laplacian(V1, F1)[1].sum()
    p2p_pyfm, t_pyfm, *_ = pyfm(V1, F1, V2, F2, "fast")
    t0 = time.perf_counter()
    e1, e2 = ofp.eigenbasis(V1, F1, k=99), ofp.eigenbasis(V2, F2, k=99)
    p2p_ours = match_eigenbases(e1, e2).p2p_21
    t_ours = time.perf_counter() - t0
    a, b = p2p_error(p2p_ours, gt, V1, on, area1), p2p_error(p2p_pyfm, gt, V1, on, area1)
    times = f"{t_ours:.1f} | {t_pyfm:.1f} | {t_pyfm / t_ours:.1f}×"
    return f"| {name} | {a:.4f} | {b:.4f} | {a / b:.2f} | {times} |"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--pairs", nargs="+", default=list(PAIRS), choices=list(PAIRS))
    parser.add_argument(
        "--pyfm", action="store_true", help="head-to-head with pyFM (needs pyfmaps)"
    )
    parser.add_argument("--no-tables", action="store_true", help="only the head-to-head")
    args = parser.parse_args()
    if not DATA.exists():
        print(f"no data at {DATA}", file=sys.stderr)
        return 2
    if not args.no_tables:
        for name in args.pairs:
            print("\n".join(run_pair(name)), "\n", flush=True)
    if args.pyfm:
        print("| pair | ours p2p error | pyFM p2p error | ratio | ours s | pyFM s | speed-up |")
        print("|---|---|---|---|---|---|---|")
        for name in ("faust_093_087", "centaur_2_4"):
            print(head_to_head(name), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
