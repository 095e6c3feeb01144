"""A high-frequency signal through the ground-truth map: FAUST 093 -> 087, sin(8πy) and XYZ.

The functional map is the one of the true correspondence (same triangulation: vertex i <-> i),
k = 29 / 39 eigenfunctions; the transfers are K eigenfunctions, raw eigenproducts of order 2
(prods, Nogneng et al. 2018) and ours (OFP basis of order 2, Π extracted from C by nearest
neighbours, Sec. 3.4; and Π the true point map itself, which the 30 x 40 functional map only
approximates). Error: ‖f − f̃‖_M / ‖f‖_M on the target, the truth being f itself.

Usage::

    python scripts/eval_sine.py
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

import o3d_ofp as ofp
from o3d_ofp.boundary.convert import geometry_to_arrays
from o3d_ofp.core.baselines import transfer_eigs, transfer_prods

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"


def main() -> int:
    if not DATA.is_dir():
        sys.stderr.write(f"needs the shared data at {DATA}\n")
        return 2
    V1, F1 = geometry_to_arrays(ofp.read_geometry(DATA / "faust" / "tr_reg_093.ply"))
    V2, F2 = geometry_to_arrays(ofp.read_geometry(DATA / "faust" / "tr_reg_087.ply"))
    e1, e2 = ofp.eigenbasis(V1, F1, k=29), ofp.eigenbasis(V2, F2, k=39)
    C = ofp.fmap_from_p2p(np.arange(len(V2)), e1, e2)
    B1, B2 = ofp.ofp_basis(e1, order=2), ofp.ofp_basis(e2, order=2)
    T12 = ofp.transfer_matrix(B1, B2, C)
    # the same bases through the true point map itself (what a caller with a vertex map
    # passes), not the one read off its 30 x 40 functional map
    T_p2p = ofp.transfer_matrix(B1, B2, p2p_21=np.arange(len(V2)))
    print("| signal | K eigs | prods | ours | ours, the point map |\n|---|---|---|---|---|")
    for name, f in (
        ("sin(8πy)", np.sin(8 * np.pi * V1[:, 1])),
        ("XYZ", V1 - (e1.mass @ V1) / e1.area),
    ):
        errors = [
            ofp.approximation_error(f, g, e2.mass)
            for g in (
                transfer_eigs(f, e1, e2, C),
                transfer_prods(f, e1, e2, C, 2),
                ofp.transfer_signal(f, B1, B2, T12),
                ofp.transfer_signal(f, B1, B2, T_p2p),
            )
        ]
        print(f"| {name} | " + " | ".join(f"{x:.3f}" for x in errors) + " |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
