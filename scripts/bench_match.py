"""Matching at scale and against pyFM: map error, seconds and peak memory, in one run.

    python scripts/bench_match.py [--levels 0 1 2] [--big] [--pyfm-levels 0 1] [--pairs]
                                  [--direct] [--match-only] [--remeshed]

``--levels`` (default 0 1 2; ``--big`` adds 3): FAUST 093 -> 087 (6890 vertices, one shared
triangulation), midpoint-subdivided ``level`` times (27.5k, 110k, 440k vertices): the truth
stays the identity at every vertex. Meshes above 50k vertices take the dense path (coarse
meshes, see o3d_ofp.workflows.dense); ``--direct`` forces the direct one for comparison.
``--remeshed``: FAUST 000 -> 001 of ``faust_remeshed`` instead (each registration remeshed on
its own, about 5,000 vertices), subdivided the same way: the two shapes share no
triangulation at any size (a shared one lets the match at the original size pair identical
samplings, which the coarse copies of the dense path cannot), and the truth is read from the
remeshed vertices' correspondence files (the colors' error through the true map is then not
given: that map is known at those vertices only).
For each size: what ``ofp.transfer_colors`` runs (the map with its eigenbases, then the
transfer of the vertex colors through OFP bases k1 = 29, k2 = 39, order 2; with
``--match-only``, ``ofp.match`` alone), and pyFM 1.3.1's pipeline (``pip install pyfmaps``;
k = 100, WKS, fit K = 30 with the orientation term, ZoomOut 30 -> 100, whose returned map is
passed to ``get_p2p(FM=...)``; see :func:`pyfm`) at two settings (:data:`PYFM_SETTINGS`):
``fast``, its fastest usual one (ZoomOut in steps of 5, ``nit=14, step=5``: about its usual
accuracy at a third of the time), for the levels in ``--pyfm-levels`` (default 0 1), and
``accurate`` (``nit=70, step=1``, the one this benchmark used before) for
``--accurate-levels`` (default 0: minutes above). The speed-ups name the setting.
``--limit-levels`` (default 0 1): the eigensolver limit, the seconds of the two shapes'
eigenfunctions with plain SciPy (robust-laplacian's operators, then ``eigsh`` with k = 100
in shift-invert mode, ``sigma=-0.01``, as pyFM calls it), and ours as a multiple of it.
``--pairs``: every ground-truth pair of ../shared/data, ours and pyFM (fast).

Map error: mean distance between the matched and the true source vertex / sqrt(source area).
Colors error (ours): the relative L2 distance of the transferred colors (a smooth pattern of the
source's coordinates, ``colors_of``) to the source's colors at each target vertex's true source
vertex, and in brackets the same through the true map (untimed, after the row's run: what the
bases alone cost); shapes above 50k vertices carry them through OFP bases on their coarse
copies.
Columns: map error, colors error, seconds until the map exists (its eigenbases included) and end
to end (match + color transfer; for the limit, the two eigensolves), peak memory (the larger of
the kernel's high-water mark of the process's resident set over the call, reset at its start
through /proc/self/clear_refs, and, every 100 ms, the resident set plus the memory of its
children of their own, USS: the forked processes of the side-by-side eigensolves; psutil. Where
the reset is refused, the resident set is sampled every 5 ms instead. A sampling thread every 5
ms cost the pipeline ~4 % of its time, the GIL it takes included), the share of the machine's
CPU other processes used during the row (steal time included; this process's own threads and
reaped children are not counted, unlike in a load average), and the comparison with ours: pyFM's
seconds over ours (a speed-up), or ours over the limit's. Both pipelines are first run once,
untimed, on another pair (see ``warm_up``). A row is flagged "busy" and a warning printed when
that share exceeded 10 %: ratios are evidence only on a quiet machine (pyFM slows down under
load far more than ours, which inflates them).
"""

from __future__ import annotations

import argparse
import os
import sys
import threading
import time
from pathlib import Path

import numpy as np
import psutil

import o3d_ofp as ofp
from o3d_ofp.boundary.convert import geometry_to_arrays

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))


def _reset_high_water_mark() -> bool:
    """Reset this process's peak resident set (VmHWM) to its current one; False if refused."""
    try:
        with open("/proc/self/clear_refs", "w") as f:
            f.write("5")
    except OSError:
        return False
    return _high_water_mark() > 0


def _high_water_mark() -> int:
    """Return the process's peak resident set since the last reset (bytes; 0 if unknown)."""
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    return 0


def _busy_seconds() -> float:
    """CPU seconds the whole machine spent busy (every core), steal time included."""
    t = psutil.cpu_times()
    return sum(t) - t.idle - getattr(t, "iowait", 0.0)


def _own_seconds(proc: psutil.Process) -> float:
    t = proc.cpu_times()
    return t.user + t.system + t.children_user + t.children_system


class Peak:
    """Seconds, peak resident memory (bytes) and other processes' CPU share of the block.

    ``others``: the CPU time the machine spent busy outside this process (steal time
    included) over the block's wall time × cores, in [0, 1]. Unlike the load average it does
    not count this process's own threads, so a pipeline that uses both cores is not taken for
    a busy machine.
    """

    def __enter__(self) -> Peak:
        self._proc = psutil.Process()
        self._hwm = _reset_high_water_mark()
        self.peak = self._proc.memory_info().rss
        self._children = 0
        self._busy0, self._own0 = _busy_seconds(), _own_seconds(self._proc)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._watch, daemon=True)
        self._thread.start()
        self._t0 = time.perf_counter()
        return self

    def _resident(self) -> int:
        """Resident bytes of this process plus the unique bytes of its children.

        The children are the forked processes of the side-by-side eigensolves: they share
        this process's pages until either writes them, so only their own (USS) is added.
        """
        return self._proc.memory_info().rss + self._children

    def _children_unique(self) -> int:
        total = 0
        for child in self._proc.children(recursive=True):
            try:
                total += child.memory_full_info().uss
            except psutil.Error:  # ended in between
                pass
        return total

    def _watch(self) -> None:
        # With the kernel's high-water mark of this process (_reset_high_water_mark) the
        # samples only add the children: every 100 ms (finding the children scans /proc, USS
        # reads their smaps: ~1-5 ms of this process's time and GIL each). Without it, the
        # resident set every 5 ms as well.
        ticks = 0
        while not self._stop.wait(0.1 if self._hwm else 0.005):
            if self._hwm or ticks % 10 == 0:
                self._children = self._children_unique()
            ticks += 1
            self.peak = max(self.peak, self._resident())

    def __exit__(self, *exc: object) -> None:
        self.seconds = time.perf_counter() - self._t0
        self._stop.set()
        self._thread.join()
        self.peak = max(self.peak, self._resident(), _high_water_mark())
        busy = _busy_seconds() - self._busy0
        own = _own_seconds(self._proc) - self._own0
        cores = psutil.cpu_count() or 1
        self.others = min(1.0, max(0.0, busy - own) / max(self.seconds * cores, 1e-9))


def faust_pair(level: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    import open3d as o3d

    meshes = []
    for name in ("tr_reg_093", "tr_reg_087"):
        mesh = o3d.io.read_triangle_mesh(str(DATA / "faust" / f"{name}.ply"))
        if level:
            mesh = mesh.subdivide_midpoint(level)
        meshes.append(geometry_to_arrays(mesh))
    (V1, F1), (V2, F2) = meshes
    return V1, F1, V2, F2


#: The pair of ``--remeshed`` (in ``faust_remeshed``).
REMESHED = ("tr_reg_000", "tr_reg_001")


def remeshed_pair(level: int) -> tuple[np.ndarray, ...]:
    """``(V1, F1, V2, F2, target vertices, their true source vertices)`` of ``--remeshed``.

    Midpoint subdivision keeps a mesh's vertices first, in their order (checked here: the
    truth is read at those vertices).
    """
    import open3d as o3d

    shapes, known = [], []
    for name in REMESHED:
        mesh = o3d.io.read_triangle_mesh(str(DATA / "faust_remeshed" / f"{name}.off"))
        before = np.asarray(mesh.vertices).copy()
        if level:
            mesh = mesh.subdivide_midpoint(level)
        V, F = geometry_to_arrays(mesh)
        if not np.array_equal(V[: len(before)], before):
            raise RuntimeError(f"subdividing {name} moved its vertices: the truth would not hold")
        path = DATA / "faust_remeshed" / "corres" / f"{name}.vts"
        shapes.append((V, F))
        known.append(np.loadtxt(path, dtype=np.int64) - 1)
    (V1, F1), (V2, F2) = shapes
    return V1, F1, V2, F2, known[1], known[0]


def warm_up(with_pyfm: bool) -> None:
    """Run ours (and pyFM) once, untimed, on another FAUST pair (019 -> 094).

    The first call of each pipeline in a process pays one-time costs that are not the
    method's (lazy imports, first touches of the BLAS and of the allocator): measured 0.2-0.5 s
    for ours. Warming both on other shapes makes every row a steady-state call; nothing is
    cached between calls by either library.
    """
    import open3d as o3d

    pair = []
    for name in ("tr_reg_019", "tr_reg_094"):
        mesh = o3d.io.read_triangle_mesh(str(DATA / "faust" / f"{name}.ply"))
        pair.extend(geometry_to_arrays(mesh))
    ours(*pair)
    if with_pyfm:
        pyfm(*pair)


#: The OFP bases of every color transfer the benchmark runs (ours and through the true map).
BASES = ofp.BasisOptions(k1=29, k2=39, order=2, preset="ours")


def colors_of(V: np.ndarray) -> np.ndarray:
    return 0.5 + 0.5 * np.sin(4.0 * V / np.ptp(V, axis=0).max() * np.pi)


def ours(
    V1, F1, V2, F2, *, dense_above=None, transfer=True
) -> tuple[np.ndarray, float, float, float, float, np.ndarray | None]:
    """Return the map, seconds, peak bytes and others' CPU of match + transfer, and the colors.

    (p2p_21, seconds of the match, seconds, peak bytes and others' CPU of match + transfer, the
    transferred colors or None without the transfer.) With the transfer: what
    ``ofp.transfer_colors(source, target)`` runs on arrays (the eigenbases the transfer and the
    estimation share, the map with the target's OFP basis built meanwhile, the source's basis,
    the transfer); "match" is then the time until the map exists (its eigenbases included).
    Without it: ``ofp.match`` alone.
    """
    from o3d_ofp.workflows import plan as planner
    from o3d_ofp.workflows.pipeline import carry

    class Ahead(planner._Ahead):
        """The planner's bases: asked for once the map and the eigenbases exist."""

        def result(self):
            nonlocal t_match
            t_match = time.perf_counter() - t0
            return super().result()

    t_match = 0.0
    colors = None
    saved = planner.DENSE_VERTICES, planner._Ahead
    if dense_above is not None:
        planner.DENSE_VERTICES = dense_above
    try:
        with Peak() as m:
            t0 = time.perf_counter()
            if transfer:
                plan = planner.plan_pair(V1, F1, V2, F2, task="colors", bases=BASES)
                planner._Ahead = Ahead
                prepared = planner.prepare(plan, V1, F1, V2, F2)
                colors = carry(colors_of(V1), plan, prepared)
                corr = prepared.correspondence
            else:
                corr = ofp.match((V1, F1), (V2, F2))
                t_match = time.perf_counter() - t0
    finally:
        planner.DENSE_VERTICES, planner._Ahead = saved
    return corr.p2p_21, t_match, m.seconds, m.peak, m.others, colors


def true_map_colors(V1, F1, V2, F2, p2p_21: np.ndarray) -> np.ndarray:
    """Return the colors the same pipeline carries through a given (the true) map, untimed.

    The same plan as :func:`ours`' (bases k = 29 / 39, order 2, on the coarse copies above
    50k vertices) with the map given: what the bases and their carrying cost in accuracy,
    without the estimated map's own error.
    """
    from o3d_ofp.workflows import plan as planner
    from o3d_ofp.workflows.maps import Correspondence
    from o3d_ofp.workflows.pipeline import carry

    corr = Correspondence.from_p2p(p2p_21, (V1, F1), (V2, F2))
    plan = planner.plan_pair(
        V1, F1, V2, F2, task="colors", bases=BASES, given=corr, via_basis=True
    )
    return carry(colors_of(V1), plan, planner.prepare(plan, V1, F1, V2, F2, given=corr))


def colors_error(colors: np.ndarray | None, V1: np.ndarray, target_idx, source_idx) -> float | None:
    """Relative L2 distance of transferred colors to the source's at the true points (or None).

    The truth: ``colors_of(V1)`` read at each target vertex's true source vertex; the
    distance is taken over those target vertices, relative to the truth's own spread.
    """
    if colors is None:
        return None
    truth = colors_of(V1)[source_idx]
    return float(
        np.linalg.norm(colors[target_idx] - truth) / np.linalg.norm(truth - truth.mean(axis=0))
    )


#: pyFM's ZoomOut (nit, step) from 30 to 100 functions: "fast" is its fastest usual setting.
PYFM_SETTINGS = {"fast": (14, 5), "accurate": (70, 1)}


def pyfm(V1, F1, V2, F2, setting: str = "fast") -> tuple[np.ndarray, float, float, float, float]:
    """Return pyFM's map and its costs (as :func:`ours` does).

    Its meshes processed intrinsically (no normals) at unit area, k = 100; 100 WKS
    descriptors, every second one in the operators; the fit of K = 30 with the orientation
    term; ZoomOut at :data:`PYFM_SETTINGS`. Measured on FAUST 093 -> 087 (one run each):
    4.4-5.0 s, error 0.0359 at the fast setting, where this benchmark's call before
    (``preprocess()`` with its defaults, ZoomOut on 2000 samples), given the same ZoomOut
    steps, took 9.1-11.4 s for 0.10.
    """
    from pyFM.functional import FunctionalMapping
    from pyFM.mesh import TriMesh

    nit, step = PYFM_SETTINGS[setting]
    with Peak() as m:
        meshes = [TriMesh(V, F, area_normalize=True, center=True).process(k=100, intrinsic=True)
                  for V, F in ((V1, F1), (V2, F2))]  # fmt: skip
        model = FunctionalMapping(*meshes)
        model.compute_spectral_descriptors(n_descr=100, descr_type="WKS", k_descr=100,
                                           subsample_step=2)  # fmt: skip
        model.fit(K=30, w_descr=1e0, w_lap=1e-1, w_dcomm=1e0, w_orient=1e0, verbose=False)
        FM = model.zoomout_refine(nit=nit, step=step, verbose=False)  # returns the refined map
        p2p = model.get_p2p(FM=FM)
        t_match = time.perf_counter() - m._t0
        _ = colors_of(V1)[p2p]  # pyFM's transfer: the pull-back through the point map
    return p2p, t_match, m.seconds, m.peak, m.others


def eigsh_limit(V1, F1, V2, F2) -> tuple[float, float, float]:
    """Seconds, peak bytes and others' CPU of both shapes' k = 100 eigenpairs with plain SciPy."""
    import robust_laplacian
    import scipy.sparse.linalg as sla

    with Peak() as m:
        for V, F in ((V1, F1), (V2, F2)):
            L, M = robust_laplacian.mesh_laplacian(np.asarray(V, np.float64), np.asarray(F))
            sla.eigsh(L.tocsc(), k=100, M=M.tocsc(), sigma=-0.01)
    return m.seconds, m.peak, m.others


def error(p2p: np.ndarray, V1: np.ndarray, F1: np.ndarray, target_idx, source_idx) -> float:
    area = ofp.laplacian(V1, F1)[1].sum()
    return float(
        np.linalg.norm(V1[p2p[target_idx]] - V1[source_idx], axis=1).mean() / np.sqrt(area)
    )


#: Share of the machine's CPU used by other processes above which a row's seconds are flagged.
BUSY = 0.1


def row(
    name: str,
    n: int,
    err: float | None,
    colors: str,
    t_match: float,
    seconds: float | None,
    peak: float,
    who: str,
    ratio: str,
    others: float,
) -> tuple[str, float]:
    flag = " (busy)" if others > BUSY else ""
    total = "-" if seconds is None else f"{seconds:.1f}"
    return (
        f"| {name} | {n} | {who} | {'-' if err is None else f'{err:.4f}'} | "
        f"{colors} | {t_match:.1f} | "
        f"{total} | "
        f"{peak / 1e9:.2f} | {100 * others:.0f} %{flag} | {ratio} |",
        others,
    )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--levels", type=int, nargs="*", default=[0, 1, 2])
    parser.add_argument("--big", action="store_true", help="add level 3 (440k vertices)")
    parser.add_argument("--pyfm-levels", type=int, nargs="*", default=[0, 1],
                        help="pyFM at its fast setting")  # fmt: skip
    parser.add_argument("--accurate-levels", type=int, nargs="*", default=[0],
                        help="pyFM at its accurate setting")  # fmt: skip
    parser.add_argument("--limit-levels", type=int, nargs="*", default=[0, 1],
                        help="the two eigensolves with plain SciPy")  # fmt: skip
    parser.add_argument("--direct", action="store_true", help="never the dense path")
    parser.add_argument(
        "--match-only", action="store_true", help="no color transfer (its column shows '-')"
    )
    parser.add_argument("--pairs", action="store_true")
    parser.add_argument(
        "--remeshed", action="store_true", help="FAUST 000 -> 001 remeshed (no shared triangles)"
    )
    args = parser.parse_args(argv)
    if not DATA.is_dir():
        sys.stderr.write(f"needs the shared data at {DATA}\n")
        return 2
    levels = sorted(set(args.levels) | ({3} if args.big else set()))
    dense_above = 10**12 if args.direct else None
    cores = os.cpu_count() or 1
    print(f"{cores} cores; load average {os.getloadavg()[0]:.1f} at the start")
    print(
        "| pair | vertices | method | map error | colors error | match s | match + transfer s | "
        "peak GB | others' CPU | against ours |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|")
    warm_up(with_pyfm=bool(args.pairs or set(args.pyfm_levels) & set(levels)))
    busy = []
    for level in levels:
        if args.remeshed:
            V1, F1, V2, F2, t, s = remeshed_pair(level)
            name = f"FAUST remeshed {REMESHED[0][-3:]}->{REMESHED[1][-3:]} x{4**level}"
        else:
            V1, F1, V2, F2 = faust_pair(level)
            t = s = np.arange(len(V2))
            name = f"FAUST 093->087 x{4**level}"
        p2p, t_match, seconds, peak, others, colors = ours(
            V1, F1, V2, F2, dense_above=dense_above, transfer=not args.match_only
        )
        err = error(p2p, V1, F1, t, s)
        c_err = "-"
        if colors is not None:
            c_err = f"{100 * colors_error(colors, V1, t, s):.2f} %"
            if not args.remeshed:  # the true map at every vertex: the identity
                truth = true_map_colors(V1, F1, V2, F2, t)
                c_err += f" ({100 * colors_error(truth, V1, t, s):.2f} %)"
        total = None if args.match_only else seconds
        line, others = row(name, len(V1), err, c_err, t_match, total, peak, "ours", "", others)
        print(line, flush=True)
        busy.append(others)
        for setting, wanted in (("fast", args.pyfm_levels), ("accurate", args.accurate_levels)):
            if level not in wanted:
                continue
            p2p, t_match, t_pyfm, peak, others = pyfm(V1, F1, V2, F2, setting)
            err = error(p2p, V1, F1, t, s)
            ratio = f"ours {t_pyfm / seconds:.1f}x faster"
            nit, step = PYFM_SETTINGS[setting]
            who = f"pyFM {setting} (nit={nit}, step={step})"
            line, others = row(
                name, len(V1), err, "-", t_match, t_pyfm, peak, who, ratio, others
            )
            print(line, flush=True)
            busy.append(others)
        if level in args.limit_levels:
            t_limit, peak, others = eigsh_limit(V1, F1, V2, F2)
            ratio = f"ours {seconds / t_limit:.1f}x the limit"
            who = "limit: SciPy eigsh k=100 x2"
            line, others = row(
                name, len(V1), None, "-", t_limit, t_limit, peak, who, ratio, others
            )
            print(line, flush=True)
            busy.append(others)
    if args.pairs:
        from eval_matching import PAIRS, load, truth

        sums = {"ours": [], "pyFM": []}  # (error, seconds) of each pair
        for a, b, kind in PAIRS:
            V1, F1 = load(a)
            V2, F2 = load(b)
            t, s = truth(a, b, kind, len(V2))
            name = f"{Path(a).stem}->{Path(b).stem}"
            p2p, t_match, t_ours, peak, others, colors = ours(V1, F1, V2, F2)
            err = error(p2p, V1, F1, t, s)
            sums["ours"].append((err, t_ours))
            c_err = "-" if colors is None else f"{100 * colors_error(colors, V1, t, s):.2f} %"
            line, o1 = row(name, len(V1), err, c_err, t_match, t_ours, peak, "ours", "", others)
            print(line, flush=True)
            p2p, t_match, t_pyfm, peak, others = pyfm(V1, F1, V2, F2, "fast")
            ratio = f"ours {t_pyfm / t_ours:.1f}x faster"
            err = error(p2p, V1, F1, t, s)
            sums["pyFM"].append((err, t_pyfm))
            line, o2 = row(
                name, len(V1), err, "-", t_match, t_pyfm, peak, "pyFM fast", ratio, others
            )
            print(line, flush=True)
            busy += [o1, o2]
        ours_e, ours_s = np.array(sums["ours"]).T
        pyfm_e, pyfm_s = np.array(sums["pyFM"]).T
        worst = int(np.argmax(ours_e / pyfm_e))
        print(
            f"pairs: mean error {ours_e.mean():.3f} (ours) against {pyfm_e.mean():.3f} (pyFM); "
            f"{ours_s.sum():.1f} s against {pyfm_s.sum():.1f} s in total "
            f"({pyfm_s.sum() / ours_s.sum():.1f}x pyFM fast, ours with the color transfer); "
            f"ours at most "
            f"{ours_e[worst] / pyfm_e[worst]:.2f}x pyFM's error "
            f"({Path(PAIRS[worst][0]).stem}->{Path(PAIRS[worst][1]).stem})"
        )
    if busy and max(busy) > BUSY:
        print(
            f"WARNING: the machine was busy (other processes used up to {100 * max(busy):.0f} % "
            "of its CPU during a row): the seconds and the ratios are not evidence; rerun on a "
            "quiet machine."
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
