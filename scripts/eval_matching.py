"""Estimated maps on every ground-truth pair of ../shared/data: error, verdict, seconds.

    python scripts/eval_matching.py [--scales 0.01 1000] [--all-pairs] [--variants] [--unrelated]

For each pair: the map error (mean distance between the matched and the true source vertex,
divided by sqrt(source area)), the quality report of ``ofp.match`` and the wall time of the
match (both eigenbases with k = 99 included). ``--scales`` repeats the FAUST 093 -> 087 pair
with the target scaled by each factor (the map must not change).

The bounds of the quality report (``o3d_ofp.workflows.quality.MAX_ORTHOGONALITY`` and the
others) are read off these tables: ``--all-pairs`` adds every ordered pair of the FAUST and of
the FAUST-remeshed shapes (32, with ground truth); ``--variants`` maps of the same shape or
kind without ground truth (error "-"): decimated (Open3D's quadric decimation), subdivided,
noisy and point-cloud copies; ``--unrelated`` maps between shapes of other kinds (no right
map exists: they should be suspect).
"""

from __future__ import annotations

import argparse
import itertools
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
    name = f"{Path(a).stem} -> {Path(b).stem}" + (f" (target x{scale:g})" if scale != 1 else "")
    return row(name, corr, err, seconds)


def row(name: str, corr: ofp.Correspondence, err: float | None, seconds: float) -> str:
    q = corr.quality
    error = "-" if err is None else f"{err:.4f}"
    return (
        f"| {name} | {error} | {q.coverage_ratio:.2f} | {q.orthogonality:.2f} | "
        f"{q.inconsistency:.2f} | {q.reversed_fraction:.2f} | "
        f"{'suspect' if q.suspect else 'ok'} | {seconds:.1f} |"
    )


def untrue(name: str, source: tuple, target: tuple) -> str:
    """Match a pair without ground truth: its row (error "-")."""
    t0 = time.perf_counter()
    corr = ofp.match(source, target)
    return row(name, corr, None, time.perf_counter() - t0)


def all_pairs() -> list[tuple[str, str, str]]:
    faust = [f"faust/tr_reg_{i}.ply" for i in ("019", "087", "093", "094")]
    remeshed = [f"faust_remeshed/tr_reg_{i}.off" for i in ("000", "001", "002", "004", "007")]
    pairs = [(a, b, "identity") for a, b in itertools.permutations(faust, 2)]
    return pairs + [(a, b, "vts") for a, b in itertools.permutations(remeshed, 2)]


def variants() -> list[tuple[str, tuple, tuple]]:
    """(name, source, target) of maps between copies of one shape or of one kind."""
    import open3d as o3d

    def mesh(rel: str):
        return o3d.io.read_triangle_mesh(str(DATA / rel))

    def arrays(m) -> tuple[np.ndarray, np.ndarray]:
        return geometry_to_arrays(m)

    def decimated(m, vertices: int) -> tuple[np.ndarray, np.ndarray]:
        return arrays(m.simplify_quadric_decimation(2 * vertices))

    def noisy(m, share: float) -> tuple[np.ndarray, np.ndarray]:
        V, F = arrays(m)
        rng = np.random.default_rng(0)
        return V + rng.normal(size=V.shape) * share * np.ptp(V, axis=0).max(), F

    f93, f87 = mesh("faust/tr_reg_093.ply"), mesh("faust/tr_reg_087.ply")
    out = [
        ("093 -> 087 decimated to 3000", arrays(f93), decimated(f87, 3000)),
        ("093 -> 087 decimated to 1000", arrays(f93), decimated(f87, 1000)),
        ("093 decimated to 2000 -> 087", decimated(f93, 2000), arrays(f87)),
        ("093 -> 087 subdivided", arrays(f93), arrays(f87.subdivide_midpoint(1))),
        ("093 -> 087 as points", arrays(f93), (arrays(f87)[0], None)),
        ("093 as points -> 087 as points", (arrays(f93)[0], None), (arrays(f87)[0], None)),
        ("093 -> 087 with 0.3 % noise", arrays(f93), noisy(f87, 0.003)),
        ("093 -> 087 with 1 % noise", arrays(f93), noisy(f87, 0.01)),
        ("bunny -> bunny_small", arrays(mesh("models/bunny.off")),
         arrays(mesh("models/bunny_small.ply"))),
    ]  # fmt: skip
    for rel, share in (
        ("models/bunny.off", 0.3),
        ("models/spot_triangulated.obj", 0.5),
        ("models/teddy.obj", 0.3),
        ("tosca/centaur4.off", 0.2),
        ("nasty/dog.off", 0.5),
        ("models/205-Greek_Sculpture.off", 0.3),
    ):
        m = mesh(rel)
        n = int(share * len(m.vertices))
        out.append((f"{Path(rel).stem} -> decimated to {n}", arrays(m), decimated(m, n)))
    out.append(("t1_donut -> t0_donut", load("models/t1_donut.obj"), load("models/t0_donut.obj")))
    return out


UNRELATED = [
    ("faust/tr_reg_093.ply", "models/bunny.off"),
    ("faust/tr_reg_093.ply", "models/teddy.obj"),
    ("faust/tr_reg_093.ply", "tosca/centaur2.off"),
    ("faust/tr_reg_093.ply", "nasty/dog.off"),
    ("tosca/centaur2.off", "faust/tr_reg_093.ply"),
    ("models/spot_triangulated.obj", "faust/tr_reg_093.ply"),
    ("models/bunny.off", "models/spot_triangulated.obj"),
    ("nasty/dog.off", "tosca/centaur2.off"),
]


def repair_rows(pairs: list[tuple[str, str, str | None]]) -> None:
    """Print the spectral maps, their disagreement with the geodesic ones, the re-estimates."""
    import math

    from o3d_ofp.core.fmap import unit_area
    from o3d_ofp.workflows import matching

    print("\n| pair | spectral map error | disagreement | re-estimate error | kept |")
    print("|---|---|---|---|---|")
    share, most = matching.REPAIR_SHARE, matching.REPAIR_MAX_SHARE
    matching.REPAIR_SHARE = matching.REPAIR_MAX_SHARE = math.inf  # the map before the check
    rows = []
    try:
        for a, b, kind in pairs:
            V1, F1 = load(a)
            V2, F2 = load(b)
            if V1.shape[0] * V2.shape[0] > matching.REPAIR_MAX_PAIRS:
                continue
            e1, e2 = ofp.eigenbasis(V1, F1, k=99), ofp.eigenbasis(V2, F2, k=99)
            corr = ofp.match((V1, F1), (V2, F2), eigenbases=(e1, e2))
            C, disagreement = matching.geodesic_repair(
                corr.p2p_21, unit_area(e1), unit_area(e2), k_final=corr.options["zoomout_to"],
                subsample=corr.options["zoomout_subsample"],
                share=-1.0,
            )  # fmt: skip
            if kind is None:  # shapes of other kinds: no truth, the disagreement only
                verdict = "suspect" if corr.quality.suspect else "ok"
                flag = "flagged" if disagreement > most else "not flagged"
                print(f"| {Path(a).stem} -> {Path(b).stem} ({verdict} before) | - | "
                      f"{disagreement:.3f} | - | {flag} |", flush=True)  # fmt: skip
                continue
            tv, ts = truth(a, b, kind, len(V2))
            again = ofp.p2p_from_fmap(C, unit_area(e1), unit_area(e2))
            before, after = (
                float(np.linalg.norm(V1[p2p[tv]] - V1[ts], axis=1).mean() / e1.area**0.5)
                for p2p in (corr.p2p_21, again)
            )
            redo = disagreement > share
            rows.append((before, disagreement, after, redo))
            print(
                f"| {Path(a).stem} -> {Path(b).stem} | {rows[-1][0]:.4f} | {disagreement:.3f} | "
                f"{rows[-1][2]:.4f} | {'re-estimate' if redo else 'spectral'} |",
                flush=True,
            )
    finally:
        matching.REPAIR_SHARE, matching.REPAIR_MAX_SHARE = share, most
    kept = [r for r in rows if not r[3]]
    redone = [r for r in rows if r[3]]
    if kept:
        print(
            f"kept ({len(kept)}): spectral errors up to {max(r[0] for r in kept):.3f}, "
            f"disagreement up to {max(r[1] for r in kept):.3f}, re-estimates would change the "
            f"errors by {min(r[2] - r[0] for r in kept):+.3f} to "
            f"{max(r[2] - r[0] for r in kept):+.3f}"
        )
    if redone:
        print(
            f"re-estimated ({len(redone)}): spectral errors {min(r[0] for r in redone):.3f}-"
            f"{max(r[0] for r in redone):.3f}, disagreement {min(r[1] for r in redone):.3f}-"
            f"{max(r[1] for r in redone):.3f}, re-estimates {min(r[2] for r in redone):.3f}-"
            f"{max(r[2] for r in redone):.3f}"
        )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scales", type=float, nargs="*", default=[0.01, 1000.0])
    parser.add_argument("--all-pairs", action="store_true", help="every FAUST / remeshed pair")
    parser.add_argument("--variants", action="store_true", help="copies of one shape or kind")
    parser.add_argument("--unrelated", action="store_true", help="shapes of other kinds")
    parser.add_argument(
        "--repair",
        action="store_true",
        help="only the pairs (and, with --unrelated, the shapes of other kinds): the spectral "
        "map without the geodesic repair, its disagreement with its geodesic refinement and "
        "the re-estimate's error (REPAIR_SHARE's and REPAIR_MAX_SHARE's table)",
    )
    args = parser.parse_args(argv)
    if not DATA.is_dir():
        sys.stderr.write(f"needs the shared data at {DATA}\n")
        return 2
    print(f"load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores")
    print(
        "| pair | map error | coverage | orthogonality | inconsistency | reversed | verdict | s |"
    )
    print("|---|---|---|---|---|---|---|---|")
    pairs = PAIRS
    if args.all_pairs:
        pairs = all_pairs() + [p for p in PAIRS if p[2] not in ("identity", "vts")]
    if args.repair:
        repair_rows(pairs + ([(a, b, None) for a, b in UNRELATED] if args.unrelated else []))
        return 0
    for a, b, kind in pairs:
        print(run(a, b, kind), flush=True)
    for s in args.scales:
        print(run(*PAIRS[0], scale=s), flush=True)
    if args.variants:
        for name, source, target in variants():
            print(untrue(name, source, target), flush=True)
    if args.unrelated:
        for a, b in UNRELATED:
            print(untrue(f"{Path(a).stem} -> {Path(b).stem}", load(a), load(b)), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
