"""Detail transfer and smoothing, judged with smoothers, maps and measures the library does not own.

**Detail.** A source with its detail, and a target made by smoothing the truth (the same
object, or another person, in another pose) with a tool the library does not implement:

* ``fairing-weak``, ``fairing-strong``: one implicit fairing step ``(M + t L)⁻¹ M X`` with the
  cotangent Laplacian of robust-laplacian (Desbrun et al. 1999), ``t`` = 1e-4 and 5e-4 of the
  area;
* ``open3d-laplacian`` (10 iterations), ``open3d-simple`` (5), ``open3d-taubin`` (100):
  Open3D's ``filter_smooth_*``, which also slide vertices along the surface (umbrella weights);
* ``brush``: a sculpting smooth brush (80 umbrella steps of 0.5 in a ball holding 40 % of the
  vertices, cosine fall-off): only part of the target lost its detail;
* ``eigen-30``: the truth projected on its first 30 eigenfunctions (the former benchmark's
  only target, kept as one smoother among others).

Pairs: FAUST 093 → 087 and 019 → 094 (registrations, one triangulation: the true map is the
identity; *different people*), TOSCA centaur2 → centaur4 (the same object), and the
independently remeshed TOSCA pairs cat0 → cat3 and horse0 → horse6 of ``bcicp_dev`` (true map:
the dataset's correspondences, each target vertex without one taking its nearest vertex's).
Maps: the true map and the map ``ofp.match`` estimates on the smoothed target.

Methods: doing nothing (the smoothed target), the ten-line baseline (the source's height along
its normals above its own implicit low-pass at ``t`` = 1e-4 of its area, carried by the map and
added along the target's normals), ``ofp.transfer_detail`` at its defaults (calibrated) and with
the former fixed ``band=30``. Measures, each as a multiple of doing nothing: symmetric mean
surface distance to the truth (point-to-triangle, 30 000 samples a side; blind to vertices
sliding along the surface), mean vertex distance to the truth, mean angle between vertex
normals; area ratio to the truth.

**Fig. 13** (``--only fig13``): the paper's pair (``t1_donut`` bumpy onto ``t0_donut`` smooth,
aligned): symmetric mean surface distance to the source against the target's own, for the
default command, the advised ``--map closest``, and ``--mode coordinates --map closest``.

**Smoothing.** Meshes with seeded noise along the normals (σ = 0.5 % of the bounding-box
diagonal); symmetric mean point-to-surface distance to the clean mesh (/ diagonal, in %), and
volume ratio to the clean mesh, for :func:`o3d_ofp.core.filtering.smooth_coordinates` at
several ``smooth`` and Open3D's ``filter_smooth_taubin`` at several iteration counts.

**Parts** (``--only parts``). The cuts of ``scripts/eval_partial.py`` (a plane keeps 55-80 % of
pose 2's area): target = the cut of pose 2 after weak fairing, truth = the cut of pose 2,
source = pose 1 whole; the true map and the map of ``ofp.match(..., partial=True)`` on the
smooth cut; the distance / √(truth's area) × doing nothing, and the area ratio.

Pictures go to ``--out`` (default ``build/eval_detail``); ``--figure`` writes the README's
picture (FAUST 093 → 087, target faired, true map).

Usage::

    python scripts/eval_detail.py --no-render          # every table
    python scripts/eval_detail.py --only detail --pairs faust_093_087 --smoothers brush
    python scripts/eval_detail.py --only figure --figure docs/detail_transfer.png
"""

from __future__ import annotations

import argparse
import math
import time
import warnings
from collections.abc import Callable
from pathlib import Path

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as sla

import o3d_ofp as ofp
from o3d_ofp import read_geometry
from o3d_ofp.boundary.convert import geometry_to_arrays
from o3d_ofp.core.geometry import face_areas_normals, vertex_normals
from o3d_ofp.workflows.detail import lowpass_coordinates

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT.parent / "shared" / "data"

#: name: (source, target, truth: "identity" or the bcicp_dev folder of the .vts files)
DETAIL_PAIRS = {
    "faust_093_087": ("faust/tr_reg_093.ply", "faust/tr_reg_087.ply", "identity"),
    "faust_019_094": ("faust/tr_reg_019.ply", "faust/tr_reg_094.ply", "identity"),
    "centaur_2_4": ("tosca/centaur2.off", "tosca/centaur4.off", "identity"),
    "cat_0_3": ("bcicp_dev/TOSCA_Isometric/cat0.off", "bcicp_dev/TOSCA_Isometric/cat3.off",
                "bcicp_dev/TOSCA_Isometric/corres"),
    "horse_0_6": ("bcicp_dev/TOSCA_Isometric/horse0.off", "bcicp_dev/TOSCA_Isometric/horse6.off",
                  "bcicp_dev/TOSCA_Isometric/corres"),
}  # fmt: skip
#: Heat time (fraction of the source's area) of the baseline's low-pass.
BASELINE_TIME = 1e-4


def load(rel: str) -> tuple[np.ndarray, np.ndarray]:
    return geometry_to_arrays(read_geometry(DATA / rel))


def volume(V: np.ndarray, F: np.ndarray) -> float:
    a, b, c = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    return float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0)


def area(V: np.ndarray, F: np.ndarray) -> float:
    return float(face_areas_normals(V, F)[0].sum())


def cotangent(V: np.ndarray, F: np.ndarray) -> tuple[sp.csc_matrix, np.ndarray]:
    """robust-laplacian's cotangent stiffness and lumped mass (not the library's own call)."""
    import robust_laplacian

    L, M = robust_laplacian.mesh_laplacian(np.asarray(V, np.float64), np.asarray(F))
    return L.tocsc(), np.asarray(M.diagonal())


def fairing(V: np.ndarray, F: np.ndarray, fraction: float) -> np.ndarray:
    """One implicit fairing step (M + t L)⁻¹ M V, t = fraction · area."""
    L, m = cotangent(V, F)
    return sla.spsolve((sp.diags(m) + fraction * m.sum() * L).tocsc(), m[:, None] * V)


def _open3d(V: np.ndarray, F: np.ndarray, how: str, iterations: int) -> np.ndarray:
    import open3d as o3d

    mesh = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(V), o3d.utility.Vector3iVector(F))
    return np.asarray(
        getattr(mesh, f"filter_smooth_{how}")(number_of_iterations=iterations).vertices
    )


def brush(V: np.ndarray, F: np.ndarray, *, share: float = 0.4, steps: int = 80) -> np.ndarray:
    """Smooth like a sculpting brush: umbrella steps in a ball, cosine fall-off (seeded)."""
    centre = V[np.random.default_rng(0).integers(len(V))]
    d = np.linalg.norm(V - centre, axis=1)
    radius = np.quantile(d, share)
    weight = np.where(d < radius, 0.5 * (1 + np.cos(np.pi * d / radius)), 0.0)
    n = len(V)
    rows = np.concatenate([F[:, 0], F[:, 1], F[:, 2], F[:, 1], F[:, 2], F[:, 0]])
    cols = np.concatenate([F[:, 1], F[:, 2], F[:, 0], F[:, 0], F[:, 1], F[:, 2]])
    A = sp.csr_matrix((np.ones(rows.size), (rows, cols)), shape=(n, n))
    A.data[:] = 1.0
    degree = np.maximum(np.asarray(A.sum(1)).ravel(), 1.0)
    X = V.copy()
    for _ in range(steps):
        X += 0.5 * weight[:, None] * ((A @ X) / degree[:, None] - X)
    return X


SMOOTHERS: dict[str, Callable[[np.ndarray, np.ndarray], np.ndarray]] = {
    "fairing-weak": lambda V, F: fairing(V, F, 1e-4),
    "fairing-strong": lambda V, F: fairing(V, F, 5e-4),
    "open3d-laplacian": lambda V, F: _open3d(V, F, "laplacian", 10),
    "open3d-simple": lambda V, F: _open3d(V, F, "simple", 5),
    "open3d-taubin": lambda V, F: _open3d(V, F, "taubin", 100),
    "brush": brush,
    "eigen-30": lambda V, F: lowpass_coordinates(ofp.eigenbasis(V, F, k=30), 30),
}


def true_map(truth: str, src: str, tgt: str, V1: np.ndarray, V2: np.ndarray) -> np.ndarray:
    """Return the source vertex of every target vertex, from the data's ground truth."""
    if truth == "identity":
        return np.arange(len(V2))
    from scipy.spatial import cKDTree

    def vts(rel: str) -> np.ndarray:
        name = Path(rel).stem
        return np.loadtxt(DATA / truth / f"{name}.vts", dtype=np.int64) - 1

    a, b = vts(src), vts(tgt)
    p2p = np.full(len(V2), -1)
    p2p[b] = a
    known = np.flatnonzero(p2p >= 0)
    missing = np.flatnonzero(p2p < 0)
    p2p[missing] = p2p[known[cKDTree(V2[known]).query(V2[missing])[1]]]
    return p2p


def _scene(V: np.ndarray, F: np.ndarray):
    import open3d as o3d

    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(V.astype(np.float32)), o3d.core.Tensor(F.astype(np.uint32)))
    return scene


def _distance_to(scene, points: np.ndarray) -> np.ndarray:
    import open3d as o3d

    return scene.compute_distance(o3d.core.Tensor(points.astype(np.float32))).numpy()


SAMPLES = 30000


def sample_surface(V: np.ndarray, F: np.ndarray, n: int, seed: int) -> np.ndarray:
    """``n`` points uniformly (by area) on the triangles, seeded."""
    from eval_cloud import at, sample

    return at(V, F, *sample(V, F, n, seed))


def surface_distance(
    X: np.ndarray, F: np.ndarray, clean: np.ndarray, G: np.ndarray | None = None
) -> float:
    """Symmetric mean point-to-surface distance between (X, F) and (clean, G or F)."""
    G = F if G is None else G
    d_xc = _distance_to(_scene(clean, G), sample_surface(X, F, SAMPLES, 1)).mean()
    d_cx = _distance_to(_scene(X, F), sample_surface(clean, G, SAMPLES, 2)).mean()
    return 0.5 * float(d_xc + d_cx)


def detail_metrics(X: np.ndarray, truth: np.ndarray, F: np.ndarray) -> dict[str, float]:
    """Surface and vertex distances / √area, mean normal angle, area and volume ratios."""
    a_t = area(truth, F)
    n_x, n_t = vertex_normals(X, F), vertex_normals(truth, F)
    cos = np.clip(np.einsum("ij,ij->i", n_x, n_t), -1.0, 1.0)
    return {
        "surface": surface_distance(X, F, truth) / math.sqrt(a_t),
        "vertex": float(np.linalg.norm(X - truth, axis=1).mean() / math.sqrt(a_t)),
        "angle": float(np.degrees(np.arccos(cos)).mean()),
        "area": area(X, F) / a_t,
        "volume": volume(X, F) / volume(truth, F),
    }


def baseline(V1: np.ndarray, F1: np.ndarray, T: np.ndarray, F2: np.ndarray, p2p: np.ndarray):
    """Add the source's height above its implicit low-pass along the normals (ten lines)."""
    low = fairing(V1, F1, BASELINE_TIME)
    h = np.einsum("ij,ij->i", V1 - low, vertex_normals(V1, F1))
    scale = math.sqrt(area(T, F2) / area(V1, F1))
    return T + scale * h[p2p, None] * vertex_normals(T, F2)


MEASURES = ("surface", "vertex", "angle")
METHODS = ("nothing", "baseline", "ours", "ours band=30")


def run_detail(args: argparse.Namespace, out: Path) -> None:
    from o3d_ofp.render.panel import render_panel

    pairs = [p for p in DETAIL_PAIRS if not args.pairs or p in args.pairs]
    smoothers = [s for s in SMOOTHERS if not args.smoothers or s in args.smoothers]
    rows: dict[tuple[str, str, str, str], dict[str, float]] = {}
    errors: dict[tuple[str, str], float] = {}
    seconds: list[float] = []
    for name in pairs:
        src, tgt, truth_of = DETAIL_PAIRS[name]
        V1, F1 = load(src)
        V2, F2 = load(tgt)
        given = true_map(truth_of, src, tgt, V1, V2)
        source = (V1, F1)
        for smoother in smoothers:
            T = SMOOTHERS[smoother](V2, F2)
            target = (T, F2)
            maps = {"true": ofp.Correspondence.from_p2p(given, source, target)}
            if not args.true_only:
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")  # its verdict is not the point here
                    maps["estimated"] = ofp.match(source, target)
                est = maps["estimated"].p2p_21
                errors[name, smoother] = float(
                    np.linalg.norm(V1[est] - V1[given], axis=1).mean() / math.sqrt(area(V1, F1))
                )
            for map_name, corr in maps.items():
                results = {"nothing": T, "baseline": baseline(V1, F1, T, F2, corr.p2p_21)}
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")  # "already has detail": measured, not said
                    t0 = time.perf_counter()
                    ours = ofp.transfer_detail(source, target, correspondence=corr)
                    seconds.append(time.perf_counter() - t0)
                    results["ours"] = np.asarray(ours.vertices)
                    fixed = ofp.transfer_detail(source, target, correspondence=corr, band=30)
                    results["ours band=30"] = np.asarray(fixed.vertices)
                for method, X in results.items():
                    rows[name, smoother, map_name, method] = detail_metrics(X, V2, F2)
                ref = rows[name, smoother, map_name, "nothing"]
                r = rows[name, smoother, map_name, "ours"]
                ratio = {m: r[m] / ref[m] for m in MEASURES}
                print(f"{name} {smoother} {map_name} map: ours × nothing: surface "
                      f"{ratio['surface']:.2f}, vertex {ratio['vertex']:.2f}, angle "
                      f"{ratio['angle']:.2f}, area {r['area']:.3f}", flush=True)  # fmt: skip
                if not args.no_render and map_name == "true" and name == pairs[0]:
                    err = {m: np.linalg.norm(results[m] - V2, axis=1) for m in results}
                    top = float(np.percentile(err["nothing"], 95))
                    shown = ["nothing", "baseline", "ours"]
                    items = [(V1, F1, None), (V2, F2, None)]
                    items += [(results[m], F2, err[m]) for m in shown]
                    render_panel(items, out / f"detail_{name}_{smoother}.png",
                                 titles=["source", "truth", "target (smoothed)", "baseline",
                                         "ours"], width=300, height=420,
                                 scalar_range=(0.0, top), colorbar_label="distance to the truth",
                                 cmap="magma")  # fmt: skip
    print(f"\nours: {np.mean(seconds):.2f} s a transfer on average ({len(seconds)} transfers)")
    if errors:
        print("\n### Estimated maps: mean error / √area (Euclidean, on the source)\n")
        print("| pair | " + " | ".join(smoothers) + " |")
        print("|---|" + "---|" * len(smoothers))
        for name in pairs:
            print(f"| {name} | " + " | ".join(f"{errors[name, s]:.3f}" for s in smoothers) + " |")
    for map_name in ("true",) if args.true_only else ("true", "estimated"):
        print(f"\n### Detail transfer, {map_name} map: × doing nothing (surface / vertex / "
              "normal angle), area ratio to the truth\n")  # fmt: skip
        print("| pair | smoother | nothing: surface, angle ° | baseline | ours | ours band=30 |")
        print("|---|---|---|---|---|---|")
        summary: dict[str, list[list[float]]] = {m: [] for m in METHODS}
        for name in pairs:
            for smoother in smoothers:
                ref = rows[name, smoother, map_name, "nothing"]
                cells = [f"{ref['surface']:.4f}, {ref['angle']:.1f} (area {ref['area']:.2f})"]
                for method in METHODS:
                    r = rows[name, smoother, map_name, method]
                    ratios = [r[m] / ref[m] for m in MEASURES]
                    summary[method].append([*ratios, r["area"], ref["area"], r["volume"]])
                    if method != "nothing":
                        cells.append(" / ".join(f"{x:.2f}" for x in ratios) + f", {r['area']:.2f}")
                print(f"| {name} | {smoother} | " + " | ".join(cells) + " |")
        print("\n| method | surface mean (max) | vertex mean (max) | angle mean (max) | "
              "area off the truth ≤ the target's | volume / the truth's (range) |")  # fmt: skip
        print("|---|---|---|---|---|---|")
        for method in METHODS[1:]:
            a = np.array(summary[method])
            closer = np.mean(np.abs(a[:, 3] - 1) <= np.abs(a[:, 4] - 1) + 1e-9)
            print(f"| {method} | " + " | ".join(
                f"{a[:, i].mean():.2f} ({a[:, i].max():.2f})" for i in range(3)
            ) + f" | {100 * closer:.0f} % | {a[:, 5].min():.2f}-{a[:, 5].max():.2f} |")  # fmt: skip


def run_fig13(args: argparse.Namespace, out: Path) -> None:
    """Run the paper's Fig. 13 pair as a new user: distance to the source × the target's."""
    V1, F1 = load("models/t1_donut.obj")
    V2, F2 = load("models/t0_donut.obj")
    source, target = (V1, F1), (V2, F2)
    own = surface_distance(V2, F2, V1, F1)
    print("\n### Fig. 13 (t1_donut onto t0_donut): symmetric surface distance to the source × "
          "the target's own\n")  # fmt: skip
    print("| command | × the target's own | warnings | seconds |")
    print("|---|---|---|---|")
    runs = {
        "o3d-ofp detail t1 t0 (default)": {},
        "--map closest": {"method": "closest"},
        "--map closest --mode coordinates": {"method": "closest", "mode": "coordinates"},
        "--map closest --band 30": {"method": "closest", "band": 30},
    }
    shown = [("source (t1)", V1, F1), ("target (t0)", V2, F2)]
    for label, kw in runs.items():
        t0 = time.perf_counter()
        with warnings.catch_warnings(record=True) as said:
            warnings.simplefilter("always")
            corr = ofp.match(source, target, method=kw.get("method", "estimate"))
            options = {k: v for k, v in kw.items() if k != "method"}
            moved = ofp.transfer_detail(source, target, correspondence=corr, **options)
        X = np.asarray(moved.vertices)
        codes = sorted({str(w.message).split(":")[0][:60] for w in said
                        if issubclass(w.category, ofp.OFPWarning)})  # fmt: skip
        print(
            f"| {label} | {surface_distance(X, F2, V1, F1) / own:.2f} | "
            f"{'; '.join(codes) or '-'} | {time.perf_counter() - t0:.1f} |"
        )
        shown.append((label, X, F2))
    if not args.no_render:
        from o3d_ofp.render.panel import render_panel

        render_panel([(X, F, None) for _, X, F in shown], out / "fig13.png",
                     titles=[t for t, _, _ in shown], width=320, height=320)  # fmt: skip


def run_parts(args: argparse.Namespace) -> None:
    """Detail onto parts: the cuts of eval_partial.py, their faired pose-2 targets."""
    from eval_partial import CUTS, plane_cut

    print("\n### Detail transfer onto parts (target: the cut of pose 2 after weak fairing)\n")
    print("| cut | map | map error | map verdict | distance / √area | × nothing | area ratio |")
    print("|---|---|---|---|---|---|---|")
    for name, src, tgt, axis, side, fraction in CUTS:
        V1, F1 = load(src)
        V2, F2 = load(tgt)
        smooth_whole = SMOOTHERS["fairing-weak"](V2, F2)
        Vc, Fc, orig, _ = plane_cut(V2, F2, axis=axis, side=side, fraction=fraction)
        truth, smooth = Vc, smooth_whole[orig]
        source, target = (V1, F1), (smooth, Fc)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # its verdict is in the table
            estimated = ofp.match(source, target, partial=True)
        verdict = {"true": "-", "estimated": "suspect" if estimated.quality.suspect else "ok"}
        maps = {"true": ofp.Correspondence.from_p2p(orig, source, target), "estimated": estimated}
        nothing = detail_metrics(smooth, truth, Fc)["surface"]
        for map_name, corr in maps.items():
            p2p = corr.p2p_21
            err = np.linalg.norm(V1[p2p] - V1[orig], axis=1).mean() / math.sqrt(area(V1, F1))
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                X = np.asarray(ofp.transfer_detail(source, target, correspondence=corr).vertices)
            r = detail_metrics(X, truth, Fc)
            print(f"| {name} | {map_name} | {err:.4f} | {verdict[map_name]} | {r['surface']:.4f} "
                  f"| {r['surface'] / nothing:.2f} | {r['area']:.3f} |", flush=True)  # fmt: skip


SMOOTH_MESHES = {
    "bunny": "models/bunny.off",
    "faust_093": "faust/tr_reg_093.ply",
    "centaur2": "tosca/centaur2.off",
    "teddy": "models/teddy.obj",
    "cat0 (remeshed)": "bcicp_dev/TOSCA_Isometric/cat0.off",
    "greek sculpture": "models/205-Greek_Sculpture.off",
    "dog": "nasty/dog.off",
}
SMOOTH_VALUES = (0.005, 0.0075, 0.01, 0.0125, 0.015, 0.02, 0.025)
TAUBIN_ITERATIONS = (5, 10, 20, 50, 100, 200)
NOISE = 0.005  # of the bounding-box diagonal


def run_smoothing(args: argparse.Namespace, out: Path) -> None:
    import open3d as o3d

    from o3d_ofp.core.filtering import DEFAULT_SMOOTH, smooth_coordinates
    from o3d_ofp.render.panel import render_panel

    print(
        "\n### Smoothing: noise along the normals, σ = 0.5 % of the diagonal (seed 0); "
        "symmetric mean distance to the clean surface, % of the diagonal\n"
    )
    print("| mesh | method | distance % | × noisy | volume ratio |")
    print("|---|---|---|---|---|")
    for name, rel in SMOOTH_MESHES.items():
        V, F = load(rel)
        diag = float(np.linalg.norm(V.max(0) - V.min(0)))
        rng = np.random.default_rng(0)
        noisy = V + rng.normal(0.0, NOISE * diag, len(V))[:, None] * vertex_normals(V, F)
        vol0 = volume(V, F)
        d_noisy = surface_distance(noisy, F, V)
        rows: list[tuple[str, np.ndarray]] = [("noisy input", noisy)]
        mesh = o3d.geometry.TriangleMesh(
            o3d.utility.Vector3dVector(noisy), o3d.utility.Vector3iVector(F)
        )
        for it in TAUBIN_ITERATIONS:
            X = np.asarray(mesh.filter_smooth_taubin(number_of_iterations=it).vertices)
            rows.append((f"Taubin {it} it.", X))
        eig = ofp.eigenbasis(noisy, F, k=5)
        for S in SMOOTH_VALUES:
            label = f"ours smooth={S:g}" + (" (default)" if S == DEFAULT_SMOOTH else "")
            rows.append((label, smooth_coordinates(eig, noisy, smooth=S)))
        results = {}
        for label, X in rows:
            d = surface_distance(X, F, V)
            results[label] = (d, X)
            print(
                f"| {name} | {label} | {100 * d / diag:.3f} | {d / d_noisy:.2f} "
                f"| {volume(X, F) / vol0:.4f} |"
            )
        best_t = min((k for k in results if k.startswith("Taubin")), key=lambda k: results[k][0])
        best_o = min((k for k in results if k.startswith("ours")), key=lambda k: results[k][0])
        print(
            f"| {name} | **best: {best_t} {results[best_t][0] / d_noisy:.2f}, "
            f"{best_o} {results[best_o][0] / d_noisy:.2f}** | | | |"
        )
        if not args.no_render:
            clean_scene = _scene(V, F)
            shown = ["noisy input", best_t, f"ours smooth={DEFAULT_SMOOTH:g} (default)", best_o]
            items = [(V, F, None)]
            items += [
                (results[k][1], F, 100 * _distance_to(clean_scene, results[k][1]) / diag)
                for k in shown
            ]
            render_panel(
                items,
                out / f"smooth_{name}.png",
                titles=["clean", *shown],
                width=400,
                height=400,
                scalar_range=(0.0, 100 * 2.5 * NOISE),
                colorbar_label="distance to the clean surface, % of the diagonal",
                cmap="magma",
            )


def detail_figure(path: Path) -> None:
    """Render the README's picture: FAUST 093 → 087, target faired (weak), ours, truth."""
    from o3d_ofp.render.panel import render_panel

    V1, F = load("faust/tr_reg_093.ply")
    V2, _ = load("faust/tr_reg_087.ply")
    smooth = SMOOTHERS["fairing-weak"](V2, F)
    source, target = (V1, F), (smooth, F)
    given = ofp.Correspondence.from_p2p(np.arange(len(V2)), source, target)
    t0 = time.perf_counter()
    ours = np.asarray(ofp.transfer_detail(source, target, correspondence=given).vertices)
    seconds = time.perf_counter() - t0
    nothing, d = detail_metrics(smooth, V2, F), detail_metrics(ours, V2, F)
    print(f"figure: ours × nothing: surface {d['surface'] / nothing['surface']:.2f}, normal angle "
          f"{d['angle'] / nothing['angle']:.2f} ({seconds:.1f} s)")  # fmt: skip
    shown = [("source (093)", V1), ("target (087, faired)", smooth), ("ours", ours),
             ("truth (087)", V2)]  # fmt: skip
    render_panel([(X, F, None) for _, X in shown], path, titles=[t for t, _ in shown],
                 width=300, height=480)  # fmt: skip
    print(f"wrote {path}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--only", choices=("detail", "fig13", "smoothing", "figure", "parts"))
    parser.add_argument("--figure", help="write the README's detail picture here (.png)")
    parser.add_argument("--pairs", nargs="+", choices=list(DETAIL_PAIRS), help="detail pairs")
    parser.add_argument("--smoothers", nargs="+", choices=list(SMOOTHERS), help="target smoothers")
    parser.add_argument("--true-only", action="store_true", help="skip the estimated maps")
    parser.add_argument("--no-render", action="store_true", help="skip the pictures")
    parser.add_argument("--out", default=str(ROOT / "build" / "eval_detail"))
    args = parser.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    if args.only in (None, "detail"):
        run_detail(args, out)
    if args.only in (None, "fig13"):
        run_fig13(args, out)
    if args.only in (None, "smoothing"):
        run_smoothing(args, out)
    if args.only in (None, "parts"):
        run_parts(args)
    if args.figure:
        detail_figure(Path(args.figure))


if __name__ == "__main__":
    main()
