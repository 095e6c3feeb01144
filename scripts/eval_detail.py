"""Detail transfer and smoothing against the simple alternatives, on the shared research meshes.

**Detail.** Two poses with one triangulation (the true map is the identity): TOSCA
centaur2/centaur4 (the same object) and FAUST 093/087, 019/094 (registrations tr_reg_XYZ are
subject XY // 10 in pose Z: these two pairs are *different people*, the source's body is not the
truth's: 019's area is 0.90 of 094's). Source = pose 1 with its detail;
target = pose 2 projected on its first 30 eigenfunctions (its detail removed); truth = pose 2.
For doing nothing (the smoothed target), the simple baseline (the source's height along its
normals above its own 30-eigenfunction low-pass, carried by the map and added along the
target's normals) and ours (:func:`o3d_ofp.workflows.detail.transfer_detail_frames`, defaults,
what ``ofp.transfer_detail`` and ``o3d-ofp detail`` do): mean vertex distance to the truth / √area,
mean normal angle (degrees), area and volume ratios to the truth; with the true map and with
the map estimated by ``match_eigenbases`` on k = 99 eigenbases.

**Smoothing.** Meshes with seeded noise along the normals (σ = 0.5 % of the bounding-box
diagonal); symmetric mean point-to-surface distance to the clean mesh (/ diagonal, in %), and
volume ratio to the clean mesh, for :func:`o3d_ofp.core.filtering.smooth_coordinates` at
several ``smooth`` and Open3D's ``filter_smooth_taubin`` at several iteration counts.

**Parts** (``--only parts``). The cuts of ``scripts/eval_partial.py`` (a plane keeps 55-80 % of
pose 2's area): target = the cut of pose 2's 30-eigenfunction low-pass (the same smoothing as
above, cut), truth = the cut of pose 2, source = pose 1 whole; the true map and the map of
``ofp.match(..., partial=True)`` on the smooth cut. Mode "add" (the default) and
"replace-detail"; the distance / √(truth's area), × doing nothing, the area ratio, and whether the
"already has detail" warning was given (it should not be: the target is smooth).

Pictures with error colormaps go to ``--out`` (default ``build/eval_detail``); ``--figure``
writes the README's picture of the modes (FAUST 093 → 087, true map).

Usage::

    python scripts/eval_detail.py                 # both tables, pictures
    python scripts/eval_detail.py --only detail --variants
    python scripts/eval_detail.py --only figure --figure docs/detail_transfer.png
"""

from __future__ import annotations

import argparse
import math
import time
from pathlib import Path

import numpy as np

import o3d_ofp as ofp
from o3d_ofp import read_geometry
from o3d_ofp.boundary.convert import geometry_to_arrays
from o3d_ofp.core.geometry import face_areas_normals, vertex_normals
from o3d_ofp.workflows.detail import (
    DETAIL_BAND,
    detail_vectors,
    lowpass_coordinates,
    transfer_detail_frames,
)
from o3d_ofp.workflows.estimate import match_eigenbases

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT.parent / "shared" / "data"

DETAIL_PAIRS = {
    "faust_093_087": ("faust/tr_reg_093.ply", "faust/tr_reg_087.ply"),
    "faust_019_094": ("faust/tr_reg_019.ply", "faust/tr_reg_094.ply"),
    "centaur_2_4": ("tosca/centaur2.off", "tosca/centaur4.off"),
}
#: Eigenfunctions of the target's smoothing (the eval's definition of "detail removed").
TARGET_BAND = 30
K_MATCH = 99


def load(rel: str) -> tuple[np.ndarray, np.ndarray]:
    return geometry_to_arrays(read_geometry(DATA / rel))


def volume(V: np.ndarray, F: np.ndarray) -> float:
    a, b, c = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    return float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0)


def area(V: np.ndarray, F: np.ndarray) -> float:
    return float(face_areas_normals(V, F)[0].sum())


def detail_metrics(X: np.ndarray, truth: np.ndarray, F: np.ndarray) -> dict[str, float]:
    """Distance / √area, mean normal angle, area and volume ratios of X to the truth."""
    a_t = area(truth, F)
    n_x, n_t = vertex_normals(X, F), vertex_normals(truth, F)
    cos = np.clip(np.einsum("ij,ij->i", n_x, n_t), -1.0, 1.0)
    return {
        "dist": float(np.linalg.norm(X - truth, axis=1).mean() / math.sqrt(a_t)),
        "angle": float(np.degrees(np.arccos(cos)).mean()),
        "area": area(X, F) / a_t,
        "volume": volume(X, F) / volume(truth, F),
    }


def baseline_heights(eig_1: ofp.EigenBasis, eig_2: ofp.EigenBasis, p2p: np.ndarray) -> np.ndarray:
    """Closest point (the map): source height along its normals above its own low-pass."""
    V1, F1 = eig_1.vertices, eig_1.faces
    h = np.einsum("ij,ij->i", detail_vectors(eig_1, DETAIL_BAND), vertex_normals(V1, F1))
    scale = math.sqrt(eig_2.area / eig_1.area)
    return eig_2.vertices + scale * h[p2p, None] * vertex_normals(eig_2.vertices, eig_2.faces)


def run_detail(args: argparse.Namespace, out: Path) -> None:
    from o3d_ofp.render.panel import render_panel

    methods = ["nothing", "baseline", "ours"]
    if args.variants:
        methods += ["ours carry=ofp", "ours replace-detail", "ours band=20", "ours band=40"]
    rows: dict[tuple[str, str, str], dict[str, float]] = {}
    for name, (src, tgt) in DETAIL_PAIRS.items():
        t0 = time.perf_counter()
        V1, F = load(src)
        V2, F2 = load(tgt)
        eig_1 = ofp.eigenbasis(V1, F, k=K_MATCH)
        eig_truth = ofp.eigenbasis(V2, F2, k=TARGET_BAND)
        smooth = lowpass_coordinates(eig_truth, TARGET_BAND)
        eig_2 = ofp.eigenbasis(smooth, F2, k=K_MATCH)
        maps = {"true map": np.arange(len(V2))}
        maps["estimated map"] = match_eigenbases(eig_1, eig_2).p2p_21
        err = np.linalg.norm(V1[maps["estimated map"]] - V1, axis=1).mean()
        print(
            f"{name}: estimated map mean error {err / math.sqrt(eig_1.area):.4f} √area "
            f"({time.perf_counter() - t0:.0f} s)"
        )
        for map_name, p2p in maps.items():
            results = {
                "nothing": smooth,
                "baseline": baseline_heights(eig_1, eig_2, p2p),
                "ours": transfer_detail_frames(eig_1, eig_2, p2p_21=p2p),
            }
            if args.variants:
                results["ours carry=ofp"] = transfer_detail_frames(
                    eig_1, eig_2, p2p_21=p2p, carry="ofp"
                )
                results["ours replace-detail"] = transfer_detail_frames(
                    eig_1, eig_2, p2p_21=p2p, mode="replace-detail"
                )
                for b in (20, 40):
                    results[f"ours band={b}"] = transfer_detail_frames(
                        eig_1, eig_2, p2p_21=p2p, band=b
                    )
            for method, X in results.items():
                rows[name, map_name, method] = detail_metrics(X, V2, F2)
            if not args.no_render:
                err_of = {m: np.linalg.norm(results[m] - V2, axis=1) for m in results}
                top = float(np.percentile(err_of["nothing"], 95))
                shown = ["nothing", "baseline", "ours"]
                items = [(V1, F, None), (V2, F2, None)]
                items += [(results[m], F2, err_of[m]) for m in shown]
                path = out / f"detail_{name}_{map_name.split()[0]}.png"
                render_panel(
                    items,
                    path,
                    titles=["source", "truth", *shown],
                    width=360,
                    height=480,
                    scalar_range=(0.0, top),
                    colorbar_label="distance to the truth",
                    cmap="magma",
                )
    for map_name in ("true map", "estimated map"):
        print(
            f"\n### Detail transfer, {map_name} (target: pose 2 on {TARGET_BAND} eigenfunctions)\n"
        )
        print(
            "| pair | method | distance / √area | × nothing | normal angle ° | × nothing |"
            " area ratio | volume ratio |"
        )
        print("|---|---|---|---|---|---|---|---|")
        ratios: dict[str, list[tuple[float, float]]] = {m: [] for m in methods}
        for name in DETAIL_PAIRS:
            ref = rows[name, map_name, "nothing"]
            for m in methods:
                r = rows[name, map_name, m]
                rd, ra = r["dist"] / ref["dist"], r["angle"] / ref["angle"]
                ratios[m].append((rd, ra))
                print(
                    f"| {name} | {m} | {r['dist']:.4f} | {rd:.2f} | {r['angle']:.1f} | {ra:.2f} "
                    f"| {r['area']:.3f} | {r['volume']:.3f} |"
                )
        for m in methods:
            arr = np.array(ratios[m])
            print(f"| mean | {m} | | {arr[:, 0].mean():.2f} | | {arr[:, 1].mean():.2f} | | |")


def run_parts(args: argparse.Namespace) -> None:
    """Detail onto parts: the cuts of eval_partial.py, their smoothed pose-2 targets."""
    import warnings

    from eval_partial import CUTS, plane_cut

    print("\n### Detail transfer onto parts (target: the cut of pose 2 on 30 eigenfunctions)\n")
    print(
        "| cut | map | map error | map verdict | method | distance / √area | × nothing "
        "| area ratio | warned |"
    )
    print("|---|---|---|---|---|---|---|---|---|")
    sources: dict[str, ofp.EigenBasis] = {}
    for name, src, tgt, axis, side, fraction in CUTS:
        V1, F1 = load(src)
        if src not in sources:
            sources[src] = ofp.eigenbasis(V1, F1, k=K_MATCH)
        eig_1 = sources[src]
        V2, F2 = load(tgt)
        smooth_whole = lowpass_coordinates(ofp.eigenbasis(V2, F2, k=TARGET_BAND), TARGET_BAND)
        Vc, Fc, orig, _ = plane_cut(V2, F2, axis=axis, side=side, fraction=fraction)
        truth, smooth = Vc, smooth_whole[orig]
        eig_2 = ofp.eigenbasis(smooth, Fc, k=K_MATCH)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # its verdict is in the table
            corr = ofp.match((V1, F1), (smooth, Fc), partial=True, eigenbases=(eig_1, eig_2))
        estimated = corr.p2p_21
        verdict = {"true": "-", "estimated": "suspect" if corr.quality.suspect else "ok"}
        nothing = detail_metrics(smooth, truth, Fc)["dist"]
        for map_name, p2p in (("true", orig), ("estimated", estimated)):
            err = np.linalg.norm(V1[p2p] - V1[orig], axis=1).mean() / math.sqrt(eig_1.area)
            for mode in ("add", "replace-detail"):
                with warnings.catch_warnings(record=True) as said:
                    warnings.simplefilter("always")
                    X = transfer_detail_frames(eig_1, eig_2, p2p_21=p2p, mode=mode)
                warned = any("already has detail" in str(w.message) for w in said)
                r = detail_metrics(X, truth, Fc)
                print(
                    f"| {name} | {map_name} | {err:.4f} | {verdict[map_name]} | {mode} "
                    f"| {r['dist']:.4f} | "
                    f"{r['dist'] / nothing:.2f} | {r['area']:.3f} | {'yes' if warned else 'no'} |",
                    flush=True,
                )


SMOOTH_MESHES = {
    "bunny": "models/bunny.off",
    "faust_093": "faust/tr_reg_093.ply",
    "centaur2": "tosca/centaur2.off",
    "teddy": "models/teddy.obj",
}
SMOOTH_VALUES = (0.005, 0.0075, 0.01, 0.0125, 0.015, 0.02)
TAUBIN_ITERATIONS = (5, 10, 20, 50, 100, 200)
NOISE = 0.005  # of the bounding-box diagonal
SAMPLES = 30000


def _scene(V: np.ndarray, F: np.ndarray):
    import open3d as o3d

    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(V.astype(np.float32)), o3d.core.Tensor(F.astype(np.uint32)))
    return scene


def _distance_to(scene, points: np.ndarray) -> np.ndarray:
    import open3d as o3d

    return scene.compute_distance(o3d.core.Tensor(points.astype(np.float32))).numpy()


def sample_surface(V: np.ndarray, F: np.ndarray, n: int, seed: int) -> np.ndarray:
    """``n`` points uniformly (by area) on the triangles, seeded."""
    rng = np.random.default_rng(seed)
    a = face_areas_normals(V, F)[0]
    f = rng.choice(len(F), n, p=a / a.sum())
    u = rng.random((n, 2))
    flip = u.sum(1) > 1
    u[flip] = 1 - u[flip]
    A, B, C = V[F[f, 0]], V[F[f, 1]], V[F[f, 2]]
    return A + u[:, :1] * (B - A) + u[:, 1:] * (C - A)


def surface_distance(X: np.ndarray, clean: np.ndarray, F: np.ndarray) -> float:
    """Symmetric mean point-to-surface distance (exact point-triangle distances)."""
    d_xc = _distance_to(_scene(clean, F), sample_surface(X, F, SAMPLES, 1)).mean()
    d_cx = _distance_to(_scene(X, F), sample_surface(clean, F, SAMPLES, 2)).mean()
    return 0.5 * float(d_xc + d_cx)


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
        d_noisy = surface_distance(noisy, V, F)
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
            d = surface_distance(X, V, F)
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


def modes_figure(path: Path) -> None:
    """Render the detail transfer's modes on FAUST 093 → 087 (target: 087, smoothed)."""
    from o3d_ofp.render.panel import render_panel

    V1, F = load("faust/tr_reg_093.ply")
    V2, _ = load("faust/tr_reg_087.ply")
    smooth = lowpass_coordinates(ofp.eigenbasis(V2, F, k=TARGET_BAND), TARGET_BAND)
    source, target = (V1, F), (smooth, F)
    given = ofp.Correspondence.from_p2p(np.arange(len(V2)), source, target)
    shown = [("source (093)", V1), ("target (087, smoothed)", smooth)]
    for mode in ("add", "replace-detail", "coordinates"):
        t0 = time.perf_counter()
        moved = ofp.transfer_detail(source, target, mode=mode, correspondence=given)
        X = np.asarray(moved.vertices)
        d = detail_metrics(X, V2, F)
        print(
            f"figure: mode {mode}: distance to the truth {d['dist']:.4f} √area "
            f"({time.perf_counter() - t0:.0f} s)"
        )
        shown.append((f'mode="{mode}"', X))
    shown.append(("truth (087)", V2))
    render_panel(
        [(X, F, None) for _, X in shown],
        path,
        titles=[t for t, _ in shown],
        width=300,
        height=480,
    )
    print(f"wrote {path}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--only", choices=("detail", "smoothing", "figure", "parts"))
    parser.add_argument("--figure", help="write the README's picture of the modes here (.png)")
    parser.add_argument("--variants", action="store_true", help="also print ours' variants")
    parser.add_argument("--no-render", action="store_true", help="skip the pictures")
    parser.add_argument("--out", default=str(ROOT / "build" / "eval_detail"))
    args = parser.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    if args.only in (None, "detail"):
        run_detail(args, out)
    if args.only in (None, "smoothing"):
        run_smoothing(args, out)
    if args.only in (None, "parts"):
        run_parts(args)
    if args.figure:
        modes_figure(Path(args.figure))


if __name__ == "__main__":
    main()
