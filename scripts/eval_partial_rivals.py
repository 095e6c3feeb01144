"""The rival check of partial maps, measured offline: every start refined, the rule applied.

    python scripts/eval_partial_rivals.py [--only NAME ...] [--margin M] [--share S]

For the 8 cuts and 4 remeshed cuts of ``scripts/eval_partial.py --remeshed`` and the 48
changed targets of ``--robustness``: the partial match's starts are fitted and refined by the
partial ZoomOut as ``ofp.match(..., partial=True)`` does, the best-ranked one (and, when its
refinement turns over, the next ones) refined by geodesic distances; the map returned is
checked by the distortion and stretch bounds; then the next ``RIVAL_STARTS``
orientation-preserving starts are refined, the least distorted refinement that passes the
bounds and sends most of the part elsewhere is taken instead when it distorts less (as the
match does), and the map returned gets the rival rule (``RIVAL_MARGIN``, ``RIVAL_SHARE``, or
``--margin`` / ``--share``; the map a refinement was taken instead of is its rival). Prints
one row per map that passes (the error of the map returned, the closest further refinement's
distortion ratio, share apart and error against the best-ranked start's map, and the verdict
of the rule, "(taken)" when a further refinement was; the errors are the checked maps', which
the rule reads: the match then polishes the map it returns, which moves it little, see
``eval_partial.py --remeshed``) and the counts: right maps (error at most 0.05), wrong ones
flagged by the rule, further refinements taken. About 45 minutes on 2 cores (each case is a
whole partial match and up to three more refinements).
"""

from __future__ import annotations

import argparse
import sys
import warnings
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import eval_partial as E

import o3d_ofp as ofp
from o3d_ofp.core.filtering import smooth_coordinates
from o3d_ofp.core.partial import (
    fit_partial_fmap,
    geodesic_distortion,
    map_stretch,
    partial_descriptors,
    partial_p2p,
    partial_zoomout,
    rescaled,
)
from o3d_ofp.core.spectrum import on_cleaned_vertices
from o3d_ofp.workflows import partial as P
from o3d_ofp.workflows.matching import DCOMM_WEIGHTS
from o3d_ofp.workflows.options import ESTIMATION_K, FIT_K
from o3d_ofp.workflows.quality import MAX_DISTORTION, MAX_REVERSED, MAX_STRETCH, map_quality


def analyse(eig_1, eig_2, err_of, margin: float, share_min: float) -> dict:
    """Return the map's verdict and its closest rival (on the cleaned surfaces, like match)."""
    s1, rep_1 = on_cleaned_vertices(eig_1)
    s2, rep_2 = on_cleaned_vertices(eig_2)

    def back(p):  # a surface point map on the input vertices, for the error
        p = p if rep_1 is None else rep_1[p]
        return p if rep_2 is None else p[eig_2.cleaning.index]

    u1, u2 = rescaled(s1, s1.area), rescaled(s2, s1.area)
    k2_fit = min(FIT_K, s2.k)
    k2_final = P._final_target_size(u1, u2, k2_fit=k2_fit, k1_max=min(ESTIMATION_K, s1.k))
    options = {"landmarks": None, "w_dcomm": DCOMM_WEIGHTS, "w_orient": 1.0,
               "descriptors": partial_descriptors(u1, u2)}  # fmt: skip
    starts = [C for k, solver in P._start_fits(k2_fit)
              for C in fit_partial_fmap(u1, u2, k2=k, solver=solver, **options)]  # fmt: skip

    def measure(p2p):
        return {
            "turned": map_quality(p2p, s1, s2, None, partial=True).reversed_fraction,
            "dist": geodesic_distortion(p2p, u1.vertices, u1.faces, u2.vertices, u2.faces),
            "stretch": map_stretch(p2p, u1.vertices, u2.vertices, u2.faces),
            "err": err_of(back(p2p)),
            "p2p": p2p,
        }

    def started(C):
        if k2_final > C.shape[0] - 1:
            C = partial_zoomout(C, u1, u2, k2_final=k2_final, subsample=2000)
        return measure(partial_p2p(C, u1, u2))

    def refined(m):
        return measure(P._refine(m["p2p"], u1, u2, k2_fit=k2_fit, k2_final=k2_final,
                                 subsample=2000)[1])  # fmt: skip

    first = [started(C) for C in starts]
    order = sorted(range(len(first)), key=lambda i: (first[i]["turned"] > MAX_REVERSED,
                                                     first[i]["dist"]))  # fmt: skip
    best = order[0]
    chosen, final, turned_over, known = best, refined(first[best]), set(), {}
    known[best] = final
    if final["turned"] > MAX_REVERSED and first[best]["turned"] <= MAX_REVERSED:
        turned_over.add(best)
        final, chosen = None, None
        others = [i for i in order if first[i]["turned"] <= MAX_REVERSED and i != best]
        for i in others[: P.NEXT_STARTS]:
            known[i] = refined(first[i])
            if known[i]["turned"] > MAX_REVERSED:
                turned_over.add(i)
            elif known[i]["dist"] < first[best]["dist"]:
                final, chosen = known[i], i
                break
        if final is None:
            return {"flagged": True, "err": first[best]["err"]}
    if final["dist"] > MAX_DISTORTION or final["stretch"] > MAX_STRETCH:
        return {"flagged": True, "err": final["err"]}
    candidates = [i for i in order if first[i]["turned"] <= MAX_REVERSED and i != chosen
                  and i not in turned_over][: P.RIVAL_STARTS]  # fmt: skip
    X, M2 = u1.vertices, u2.mass

    def share_apart(a, b):
        return float(M2 @ (np.linalg.norm(X[a] - X[b], axis=1) > P.DISAGREEMENT) / M2.sum())

    closest, passing = None, []
    for i in candidates:
        r = known.get(i) or refined(first[i])
        if r["turned"] > MAX_REVERSED or r["dist"] > MAX_DISTORTION:
            continue
        if r["stretch"] > MAX_STRETCH:
            continue
        share = share_apart(final["p2p"], r["p2p"])
        ratio = r["dist"] / final["dist"]
        if share > 0.1 and (closest is None or ratio < closest[0]):
            closest = (ratio, share, r["err"])
        passing.append((r, share))
    # the least distorted refinement that passes and sends most of the part elsewhere is
    # taken when it distorts less (the match's rule, o3d_ofp.workflows.partial:
    # PartialMatch.review); the map it replaces is then its rival
    elsewhere = [r for r, share in passing if share > share_min]
    best = min(elsewhere, key=lambda r: r["dist"], default=None)
    taken = best is not None and best["dist"] < final["dist"]
    others = [(r, False) for r, _ in passing]
    if taken:
        others = [(r, False) for r, _ in passing if r is not best] + [(final, True)]
        final = best
    rival = any(
        share_apart(final["p2p"], r["p2p"]) > share_min
        and (given_way or r["dist"] <= (1 + margin) * final["dist"])
        for r, given_way in others
    )  # fmt: skip
    return {"flagged": False, "err": final["err"], "closest": closest, "rival": rival,
            "taken": taken}  # fmt: skip


def cases(only: list[str] | None):
    """(name, label, source arrays, target arrays, error function) of every case."""
    sources: dict[str, tuple] = {}
    for name, a, b, axis, side, fraction in E.CUTS:
        for label, scale, smooth, kept in E.ROBUSTNESS:
            if only and not any(o in f"{name} {label}" for o in only):
                continue
            if a not in sources:
                V1, F1 = E.load(a)
                sources[a] = (V1, F1, ofp.eigenbasis(V1, F1, k=99))
            V1, F1, e1 = sources[a]
            V2, F2 = E.load(b)
            if smooth:
                V2 = smooth_coordinates(ofp.eigenbasis(V2, F2, k=40), V2, smooth=smooth)
            Vc, Fc, orig, _ = E.plane_cut(V2, F2, axis=axis, side=side, fraction=kept or fraction)
            yield name, label, e1, ofp.eigenbasis(scale * Vc, Fc, k=99), (
                lambda p, V1=V1, orig=orig, e1=e1: E.error(V1, p, orig, e1.area))
    for a, b, axis, side, fraction in E.REMESHED:
        name = f"{a} -> {b}"
        if only and not any(o in name for o in only):
            continue
        V1, F1 = E.load(f"faust_remeshed/{a}.off")
        V2, F2 = E.load(f"faust_remeshed/{b}.off")
        corres = [np.loadtxt(E.DATA / "faust_remeshed" / "corres" / f"{n}.vts", dtype=np.int64)
                  - 1 for n in (a, b)]  # fmt: skip
        Vc, Fc, orig, _ = E.plane_cut(V2, F2, axis=axis, side=side, fraction=fraction)
        index = np.full(len(V2), -1)
        index[orig] = np.arange(orig.size)
        rows = index[corres[1]] >= 0
        e1 = ofp.eigenbasis(V1, F1, k=99)
        yield name, "as listed", e1, ofp.eigenbasis(Vc, Fc, k=99), (
            lambda p, V1=V1, e1=e1, index=index, rows=rows, corres=corres: E.error(
                V1, p[index[corres[1][rows]]], corres[0][rows], e1.area))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--only", nargs="+", help="cases whose name or label contains one")
    parser.add_argument("--margin", type=float, default=P.RIVAL_MARGIN)
    parser.add_argument("--share", type=float, default=P.RIVAL_SHARE)
    args = parser.parse_args(argv)
    print("| case | target | error | closest rival: distortion ratio, apart, error | rival |\n"
          "|---|---|---|---|---|")  # fmt: skip
    taken = 0
    counts = {"flagged by the other checks": 0, "right": 0, "right flagged by a rival": 0,
              "wrong": 0, "wrong flagged by a rival": 0}  # fmt: skip
    for name, label, e1, ec, err_of in cases(args.only):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            r = analyse(e1, ec, err_of, args.margin, args.share)
        if r["flagged"]:
            counts["flagged by the other checks"] += 1
            continue
        kind = "right" if r["err"] <= 0.05 else "wrong"
        counts[kind] += 1
        counts[f"{kind} flagged by a rival"] += r["rival"]
        taken += r["taken"]
        c = r["closest"]
        closest = f"{c[0]:.3f}, {100 * c[1]:.0f} %, {c[2]:.3f}" if c else "-"
        verdict = ("yes" if r["rival"] else "no") + (" (taken)" if r["taken"] else "")
        print(f"| {name} | {label} | {r['err']:.4f} | {closest} | {verdict} |", flush=True)
    print(", ".join(f"{k}: {v}" for k, v in counts.items()) + f"; a further start taken: {taken}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
