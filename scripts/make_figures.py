"""Render the README's pictures into docs/ (needs ../shared/data and an EGL context).

    python scripts/make_figures.py [--out docs] [--width 480] [--only NAME ...]

1. ``faust_transfer.png``: a function on FAUST 093 transferred to FAUST 087 through an
   *estimated* map (no ground truth), with K eigenfunctions, raw products ("prods") and the
   two OFP presets, as in the paper's Fig. 10; the relative error is in each title, the color
   bar is labelled with the function.
2. ``spot_texture.png``: Spot rendered with its UV texture, the texture sampled as vertex
   colors, and that approximated with K eigenfunctions and the OFP bases (order 3, as the paper
   uses for non-human shapes).
3. ``filtering.png``: spectral smoothing and sharpening of a shape (paper's Figs. 14-15).
4. ``demo.png``: what ``o3d-ofp demo`` draws.
5. ``partial_match.png``: FAUST 087 with its legs cut off, matched onto the whole 093 with
   ``partial=True`` and without; a function of the source pulled back through each map.

``--only NAME ...`` renders only those figures.
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

import numpy as np

import o3d_ofp as ofp
from o3d_ofp import read_geometry, texture_colors
from o3d_ofp.boundary.convert import geometry_to_arrays
from o3d_ofp.core.baselines import approximate_eigs, transfer_eigs, transfer_prods
from o3d_ofp.core.filtering import sharpen_gains, smooth_gains, spectral_filter
from o3d_ofp.render.panel import View, read_png, render_panel
from o3d_ofp.workflows.estimate import match_eigenbases

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"


def load(rel: str) -> tuple[np.ndarray, np.ndarray]:
    return geometry_to_arrays(read_geometry(DATA / rel))


def faust_transfer(out: Path, width: int) -> None:
    V1, F1 = load("faust/tr_reg_093.ply")
    V2, F2 = load("faust/tr_reg_087.ply")
    e1, e2 = ofp.eigenbasis(V1, F1, k=99), ofp.eigenbasis(V2, F2, k=99)
    C = match_eigenbases(e1, e2).fmap_12
    k1, k2 = 29, 39
    f = np.sin(8 * np.pi * V1[:, 1])  # the paper's sin(8πy) on the raw height
    truth = f  # FAUST registrations share their vertex order: the true image of f is f
    s1, s2 = e1.truncate(k1), e2.truncate(k2)
    Ck = C[: k2 + 1, : k1 + 1]
    results = {
        "K eigs": transfer_eigs(f, s1, s2, Ck),
        "prods": transfer_prods(f, s1, s2, Ck, 2),
    }
    for preset in ("ours", "ours*"):
        B1 = ofp.ofp_basis(s1, order=2, preset=preset)
        B2 = ofp.ofp_basis(s2, order=2, preset=preset)
        results[preset] = ofp.transfer_signal(f, B1, B2, ofp.transfer_matrix(B1, B2, Ck))
    items = [(V1, F1, f), (V2, F2, truth)]
    titles = ["source", "target truth"]
    for name, g in results.items():
        err = ofp.approximation_error(truth, g, e2.mass)
        items.append((V2, F2, g))
        titles.append(f"{name}: error {err:.2f}")
    render_panel(
        items,
        out / "faust_transfer.png",
        titles=titles,
        width=int(0.8 * width),  # standing bodies: narrower, taller tiles
        height=int(1.3 * width),
        scalar_range=(-1.0, 1.0),
        cmap="coolwarm",
        colorbar_label="f = sin(8πy)",
    )


def spot_texture(out: Path, width: int) -> None:
    mesh = read_geometry(DATA / "models/spot_triangulated.obj")
    V, F = geometry_to_arrays(mesh)
    image = read_png(DATA / "models/spot_texture.png")
    uv = np.asarray(mesh.triangle_uvs)
    colors = texture_colors(mesh, image)
    eig = ofp.eigenbasis(V, F, k=14)
    items = [(V, F, None), (V, F, colors)]
    textures = [(uv, image), None]
    titles = ["UV texture", "vertex colors"]
    approx = approximate_eigs(colors, eig)
    items.append((V, F, np.clip(approx, 0, 1)))
    titles.append(f"15 eigs: error {ofp.approximation_error(colors, approx, eig.mass):.2f}")
    for preset in ("ours", "ours*"):
        B = ofp.ofp_basis(eig, order=3, preset=preset)
        approx = B.approximate(colors)
        items.append((V, F, np.clip(approx, 0, 1)))
        titles.append(f"{preset} ({B.size}): error {B.approximation_error(colors):.2f}")
    textures += [None] * (len(items) - len(textures))
    render_panel(
        items, out / "spot_texture.png", titles=titles, width=width, height=width,
        view=View(front=(0.8, 0.35, -1.0)), textures=textures,
    )  # fmt: skip


def filtering(out: Path, width: int) -> None:
    V, F = load("models/bunny.off")
    eig = ofp.eigenbasis(V, F, k=14)
    B = ofp.ofp_basis(eig, order=3, preset="ours*")
    grey = np.full((len(V), 3), 0.75)
    items = [
        (V, F, grey),
        (spectral_filter(B, V, smooth_gains(5.0)), F, grey),
        (spectral_filter(B, V, sharpen_gains(2.0)), F, grey),
    ]
    render_panel(
        items, out / "filtering.png", titles=["bunny", "smoothed (5)", "sharpened (2)"],
        width=width, height=width,
    )  # fmt: skip


def partial_match(out: Path, width: int) -> None:
    """Render a part (legs cut off) matched onto the whole body, with and without partial=True."""
    sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
    from eval_partial import error, plane_cut

    V1, F1 = load("faust/tr_reg_093.ply")
    V2, F2 = load("faust/tr_reg_087.ply")
    Vc, Fc, truth, kept = plane_cut(V2, F2, axis=1, side=1, fraction=0.65)
    f = np.sin(6 * np.pi * V1[:, 1] / np.ptp(V1[:, 1])) * np.cos(4 * V1[:, 0] / np.ptp(V1))
    area = ofp.laplacian(V1, F1)[1].sum()
    items, titles = [(V1, F1, f), (Vc, Fc, f[truth])], ["source (whole)", "part, truth"]
    for partial in (True, False):
        corr = ofp.match((V1, F1), (Vc, Fc), partial=partial)
        verdict = "suspect" if corr.quality.suspect else "ok"
        items.append((Vc, Fc, f[corr.p2p_21]))
        label = "partial=True" if partial else "partial=False"
        titles.append(f"{label}: error {error(V1, corr.p2p_21, truth, area):.3f} ({verdict})")
    render_panel(
        items,
        out / "partial_match.png",
        titles=titles,
        width=int(0.8 * width),
        height=int(1.3 * width),
        cmap="coolwarm",
        colorbar_label=f"a function pulled back through the map (kept area {kept:.2f})",
    )


def demo(out: Path) -> None:
    import tempfile

    from o3d_ofp.cli import main

    with tempfile.TemporaryDirectory() as tmp:
        if main(["-q", "demo", "-o", tmp]) != 0:
            raise SystemExit("the demo failed")
        os.replace(os.path.join(tmp, "demo.png"), out / "demo.png")


FIGURES = {
    "faust_transfer": faust_transfer,
    "spot_texture": spot_texture,
    "filtering": filtering,
    "partial_match": partial_match,
    "demo": lambda out, width: demo(out),
}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", default=str(Path(__file__).resolve().parents[1] / "docs"))
    parser.add_argument("--width", type=int, default=480, help="tile width in pixels (480)")
    parser.add_argument(
        "--only", nargs="*", choices=sorted(FIGURES), help="render only these figures"
    )
    args = parser.parse_args(argv)
    if not DATA.is_dir():
        sys.stderr.write(f"needs the shared data at {DATA}\n")
        return 2
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    for name in args.only or sorted(FIGURES):
        FIGURES[name](out, args.width)
    for p in sorted(out.glob("*.png")):
        sys.stdout.write(f"{p} {p.stat().st_size // 1024} kB\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
