"""Maps between different shapes, against published maps: the pairs of ``bcicp_dev``.

    python scripts/eval_nonisometric.py [--datasets TOSCA_nonIsometric TOSCA_Isometric humans]
                                        [--landmarks 6] [--pyfm] [--same-frame]
                                        [--turn random|back] [--max N] [--reverse]

The pairs of ``../shared/data/bcicp_dev/pairs.tsv`` (Ren et al., "Continuous and
orientation-preserving correspondences via functional maps", SIGGRAPH Asia 2018): twelve
gorilla -> man / woman pairs (``TOSCA_nonIsometric``) and ten TOSCA pairs of one animal in two
poses (``TOSCA_Isometric``), each shape remeshed on its own (about 5k vertices); and
(``humans``) the 30 ordered pairs of the six people of ``TOSCA_nonIsometric`` (three men and
three women in other poses: near-isometric, different bodies). For each pair ``A B`` the map
sends every vertex of ``A`` to a vertex of ``B``:

* ``ours``: ``ofp.match(B, A)`` at its defaults (no ground truth, no landmarks);
* ``ours+lm``: the same with ``--landmarks`` landmark pairs (default 6): the farthest-point
  samples of ``A``'s ground-truth vertices, paired with their true vertices on ``B`` (what a
  user clicking well-spread points gives);
* ``pyFM`` (``--pyfm``, pyfmaps 1.3.1 installed): its pipeline at its fastest usual setting
  (k = 100, WKS, fit K = 30 with the orientation term, ZoomOut ``nit=14, step=5``, the point
  map of the refined map: ``bench_match.pyfm``);
* the dataset authors' own saved maps where present (gorilla pairs only): BCICP from a WKS start
  (``WKSini_direct_BCICP``) and from a segmentation start (``SEGini_direct_BCICP``), and BIM
  (Kim et al. 2011).

``--same-frame``: ``ours`` with ``MatchOptions(same_frame=True)`` (the shapes are given in
one frame, as TOSCA's are: a shells registration keeps it where it cannot tell front from
back, ``o3d_ofp.core.shells.SWAP_TURN``). ``--turn random``: each target ``A`` turned by a
random rotation first (seeded by the pair's names), shapes not given in one frame;
``--turn back``: turned by 180° about the vertical (TOSCA's z axis), facing the other way.
``--reverse``: every pair the other way round (``B A``: a man or woman's vertices sent to the
gorilla's, ``ofp.match(A, B)``, the transfer from the gorilla onto the person); the authors'
saved maps go one way only and are left out.

Error (the field's standard measure, and the one of the BCICP paper): the mean geodesic
distance on ``B`` between the image of a ground-truth vertex of ``A`` and its true vertex,
over 1000 seeded ground-truth pairs, divided by sqrt(area of B), x100; geodesics by the heat
method of potpourri3d (``pip install potpourri3d``), which the library does not use. Each
error is printed direct and with the whole map's left / right flip forgiven (the smaller of
the errors against the truth and against its symmetric ``.sym.vts``), as the BCICP paper does.
``!`` marks a map ``ofp.match`` flagged suspect.
"""

from __future__ import annotations

import argparse
import itertools
import logging
import math
import os
import sys
import time
import warnings
from pathlib import Path

import numpy as np

import o3d_ofp as ofp
from o3d_ofp.boundary.convert import geometry_to_arrays
from o3d_ofp.core.fmap import farthest_points
from o3d_ofp.core.geometry import face_areas_normals

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "bcicp_dev"
sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))  # bench_match
#: The authors' saved maps: folder, and the index of the first vertex in its files.
PUBLISHED = {"BCICP (WKS)": ("WKSini_direct_BCICP", 1), "BCICP (seg)": ("SEGini_direct_BCICP", 1),
             "BIM": ("BIM", 0)}  # fmt: skip
SAMPLES = 1000
#: The people of TOSCA_nonIsometric, matched among themselves by ``--datasets humans``.
HUMANS = ("8_man_01", "8_man_05", "8_man_07", "8_woman_01", "8_woman_02", "8_woman_03")


def load(dataset: str, name: str) -> tuple[np.ndarray, np.ndarray]:
    return geometry_to_arrays(ofp.read_geometry(DATA / dataset / f"{name}.off"))


def truth(dataset: str, name: str, *, symmetric: bool = False) -> np.ndarray:
    """Ground-truth vertices (0-based): row i of every shape's file is the same point."""
    suffix = ".sym.vts" if symmetric else ".vts"
    return np.loadtxt(DATA / dataset / "corres" / f"{name}{suffix}", dtype=np.int64) - 1


def area(V: np.ndarray, F: np.ndarray) -> float:
    return float(face_areas_normals(V, F)[0].sum())


def geodesic_errors(
    V: np.ndarray, F: np.ndarray, true: np.ndarray, images: dict[str, np.ndarray]
) -> dict[str, float]:
    """Mean geodesic distance on (V, F) from each map's images to the true vertices, x100/√area."""
    import potpourri3d as pp3d

    solver = pp3d.MeshHeatMethodDistanceSolver(V, F)
    sums = dict.fromkeys(images, 0.0)
    for i, j in enumerate(true):
        d = solver.compute_distance(int(j))
        for name, image in images.items():
            sums[name] += float(d[image[i]])
    return {name: 100.0 * s / len(true) / math.sqrt(area(V, F)) for name, s in sums.items()}


def pyfm_map(VA: np.ndarray, FA: np.ndarray, VB: np.ndarray, FB: np.ndarray) -> np.ndarray:
    """Return pyFM's map (a vertex of B for every vertex of A) at its fastest usual setting."""
    from bench_match import pyfm  # one place for pyFM's call

    return np.asarray(pyfm(VB, FB, VA, FA, "fast")[0])


def run_pair(dataset: str, a: str, b: str, args: argparse.Namespace) -> dict[str, object]:
    VA, FA = load(dataset, a)
    VB, FB = load(dataset, b)
    if args.turn:  # errors are geodesic on B: turning A changes nothing else
        from scipy.spatial.transform import Rotation

        seed = int.from_bytes(f"{a} {b}".encode(), "little") % 2**32
        turn = (Rotation.random(random_state=seed) if args.turn == "random"
                else Rotation.from_euler("z", 180.0, degrees=True))  # fmt: skip
        VA = VA @ turn.as_matrix().T
    ta, tb, tb_sym = truth(dataset, a), truth(dataset, b), truth(dataset, b, symmetric=True)
    maps: dict[str, np.ndarray] = {}
    seconds: dict[str, float] = {}
    suspect: dict[str, bool] = {}
    landmarks = None
    if args.landmarks:
        spread = farthest_points(VA[ta], args.landmarks)
        landmarks = np.stack([tb[spread], ta[spread]], axis=1)  # [vertex of B, vertex of A]
    for name, given in (("ours", None), ("ours+lm", landmarks)):
        if name == "ours+lm" and given is None:
            continue
        t0 = time.perf_counter()
        options = ofp.MatchOptions(same_frame=args.same_frame and given is None)
        corr = ofp.match((VB, FB), (VA, FA), landmarks=given, options=options)
        seconds[name] = time.perf_counter() - t0
        maps[name], suspect[name] = np.asarray(corr.p2p_21), bool(corr.quality.suspect)
    if args.pyfm:
        t0 = time.perf_counter()
        maps["pyFM"] = pyfm_map(VA, FA, VB, FB)
        seconds["pyFM"] = time.perf_counter() - t0
    for name, (folder, first) in PUBLISHED.items():
        path = DATA / dataset / "maps" / folder / f"{a}_{b}.map"
        if path.exists():
            T = np.loadtxt(path)
            if not np.isnan(T).any():
                maps[name] = T.astype(np.int64) - first
    pick = np.random.default_rng(0).choice(len(ta), size=min(SAMPLES, len(ta)), replace=False)
    images = {name: m[ta[pick]] for name, m in maps.items()}
    direct = geodesic_errors(VB, FB, tb[pick], images)
    flipped = geodesic_errors(VB, FB, tb_sym[pick], images)
    forgiven = {name: min(direct[name], flipped[name]) for name in direct}
    return {"direct": direct, "forgiven": forgiven, "seconds": seconds, "suspect": suspect}


def cell(name: str, result: dict[str, object]) -> str:
    direct, forgiven = result["direct"], result["forgiven"]
    mark = "!" if result["suspect"].get(name, False) else ""  # type: ignore[union-attr]
    return f"{direct[name]:.1f} / {forgiven[name]:.1f}{mark}"  # type: ignore[index]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--datasets", nargs="+", default=["TOSCA_nonIsometric", "TOSCA_Isometric"],
                        choices=["TOSCA_nonIsometric", "TOSCA_Isometric", "humans"])  # fmt: skip
    parser.add_argument("--landmarks", type=int, default=6, help="landmark pairs (0: none)")
    parser.add_argument("--pyfm", action="store_true", help="also pyFM (pyfmaps 1.3.1)")
    parser.add_argument("--same-frame", action="store_true",
                        help="ours with MatchOptions(same_frame=True)")
    parser.add_argument("--turn", choices=["random", "back"],
                        help="turn each target first: at random, or to face the other way")
    parser.add_argument("--max", type=int, default=None, help="at most this many pairs a dataset")
    parser.add_argument("--reverse", action="store_true", help="every pair the other way round")
    args = parser.parse_args(argv)
    if not (DATA / "pairs.tsv").exists():
        parser.error(f"{DATA / 'pairs.tsv'} not found: this benchmark needs ../shared/data")
    warnings.simplefilter("ignore")  # the suspect verdicts are read from the maps' quality
    logging.disable(logging.WARNING)
    lines = [line.split() for line in (DATA / "pairs.tsv").read_text().splitlines() if line]
    for name in args.datasets:
        if name == "humans":
            dataset, pairs = "TOSCA_nonIsometric", list(itertools.permutations(HUMANS, 2))
        else:
            dataset, pairs = name, [(a, b) for d, a, b in lines if d == name]
        pairs = [(b, a) if args.reverse else (a, b) for a, b in pairs[: args.max]]
        results = []
        print(f"\n### {name}: mean geodesic error x100 (direct / left-right flip forgiven; "
              "! flagged suspect)\n")  # fmt: skip
        for a, b in pairs:
            result = run_pair(dataset, a, b, args)
            if not results:
                names = list(result["direct"])  # type: ignore[arg-type]
                print("| pair | " + " | ".join(names) + " | seconds |")
                print("|---" * (len(names) + 2) + "|")
            results.append(result)
            secs = ", ".join(f"{k} {v:.1f}" for k, v in result["seconds"].items())  # type: ignore[union-attr]
            print(f"| {a} -> {b} | " + " | ".join(cell(n, result) for n in names) + f" | {secs} |",
                  flush=True)  # fmt: skip
        if not results:
            continue
        print()
        for name in names:
            d = np.array([r["direct"][name] for r in results])  # type: ignore[index]
            f = np.array([r["forgiven"][name] for r in results])  # type: ignore[index]
            flagged = sum(r["suspect"].get(name, False) for r in results)  # type: ignore[union-attr]
            s = [r["seconds"][name] for r in results if name in r["seconds"]]  # type: ignore[operator,index]
            timing = f", {np.mean(s):.1f} s a pair" if s else ""
            verdict = f", {flagged} flagged" if name in results[0]["suspect"] else ""  # type: ignore[operator]
            print(f"{name}: mean {d.mean():.1f} / {f.mean():.1f}, at most 20 on {(d <= 20).sum()} "
                  f"of {len(d)}, worst {d.max():.1f}{verdict}{timing}")  # fmt: skip
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
