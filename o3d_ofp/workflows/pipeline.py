"""Signals carried from a source to a target: through the OFP bases, or pulled back exactly.

:func:`transfer_function` is the array-level transfer (eigenbases in, values out): it plans
and prepares the job (:mod:`o3d_ofp.workflows.plan`), then :func:`carry` moves the values
through the bases. :func:`pull_back` reads the source's values through the map itself.

Defaults follow the paper: order 2 with k₁ = 29, k₂ = 39 non-constant eigenfunctions (its
K = 30 / 40, for humans); order 3 with k ≈ 11-14 suits other shapes (Tables 2, 5, 6).
"""

from __future__ import annotations

import logging
from typing import Any

import numpy as np

from ..core._validation import as_signal
from ..core.basis import OFPBasis
from ..core.spectrum import EigenBasis
from ..core.transfer import transfer_matrix, transfer_signal
from ..core.wording import OptionError
from .maps import Correspondence, check_correspondence
from .options import BasisOptions, moved_keywords
from .plan import Plan, Prepared, plan_pair, prepare

__all__ = ["carry", "pull_back", "transfer_function"]

logger = logging.getLogger(__name__)


@moved_keywords("k1", "k2", "order", "preset", "tol", "p2p_21", "fmap_12", "landmarks", "method")
def transfer_function(
    f_1: Any, eig_1: EigenBasis, eig_2: EigenBasis, *,
    correspondence: Correspondence | None = None, bases: tuple[OFPBasis, OFPBasis] | None = None,
    options: BasisOptions | None = None,
) -> np.ndarray:  # fmt: skip
    """Transfer a per-vertex signal from a source to a target shape with OFP bases.

    Parameters
    ----------
    f_1 : (n1,) or (n1, d) array_like of float
        Source signal.
    eig_1, eig_2 : EigenBasis
        Source and target eigenbases (computed again, larger, when the bases or an estimated
        map need more eigenfunctions than they hold).
    correspondence : Correspondence, optional
        The map: from :func:`o3d_ofp.match`, :meth:`Correspondence.load`, or a map the caller
        brings (:meth:`Correspondence.from_p2p`, :meth:`Correspondence.from_fmap`). Default:
        estimated between the eigenbases as :func:`o3d_ofp.match` does.
    bases : (OFPBasis, OFPBasis), optional
        Precomputed OFP bases of the two shapes.
    options : BasisOptions, optional
        How the bases are built (default ``BasisOptions()``: order 2 on 29 / 39
        eigenfunctions, "ours"; ``matrix="analytic"`` for Eq. 20 with the map's ``fmap_12``).

    Returns
    -------
    (n2,) or (n2, d) ndarray
        The transferred signal.

    Examples
    --------
    A smooth function carried onto the same sphere through the identity map comes back
    almost unchanged (the order-2 basis on 8 eigenfunctions holds the degree-2 harmonics):

    >>> import numpy as np
    >>> import open3d as o3d
    >>> import o3d_ofp as ofp
    >>> sphere = o3d.geometry.TriangleMesh.create_sphere(radius=1.0, resolution=10)
    >>> V, F = np.asarray(sphere.vertices), np.asarray(sphere.triangles)
    >>> eig = ofp.eigenbasis(V, F, k=8)
    >>> same = ofp.Correspondence.from_p2p(np.arange(len(V)), (V, F), (V, F))
    >>> f = V[:, 2] ** 2
    >>> options = ofp.BasisOptions(k1=8, k2=8)
    >>> g = ofp.transfer_function(f, eig, eig, correspondence=same, options=options)
    >>> g.shape
    (182,)
    >>> bool(ofp.approximation_error(f, g, eig.mass) < 0.01)
    True
    """
    for eig, name in ((eig_1, "eig_1"), (eig_2, "eig_2")):
        if not isinstance(eig, EigenBasis):  # a mesh given here: where its basis comes from
            raise OptionError(
                name, f"must be an EigenBasis (from o3d_ofp.eigenbasis(mesh)); got "
                f"{type(eig).__name__} (for the colors of Open3D geometries, "
                "o3d_ofp.transfer_colors)",
            )  # fmt: skip
    f = as_signal(f_1, eig_1.n_vertices, name="f_1")
    check_correspondence(correspondence)
    V1, F1, V2, F2 = eig_1.vertices, eig_1.faces, eig_2.vertices, eig_2.faces
    plan = plan_pair(
        V1, F1, V2, F2, task="colors", bases=options, given=correspondence,
        given_bases=bases or (None, None), via_basis=True,
    )  # fmt: skip
    prepared = prepare(
        plan, V1, F1, V2, F2, given=correspondence, eigenbases=(eig_1, eig_2),
        bases=bases or (None, None),
    )  # fmt: skip
    return carry(f, plan, prepared)


def carry(f_1: np.ndarray, plan: Plan, prepared: Prepared) -> np.ndarray:
    """Carry a checked source signal through a prepared job's OFP bases.

    The transfer matrix of the plan (``"p2p"``: least squares of ``Q₂ O = Π Q₁``; ``"analytic"``:
    Eq. 20 from the map's ``fmap_12``), then the signal's coefficients through it. A side
    whose basis is on its coarse copy (``plan.coarse_bases``) is carried there and back by
    the prepared ``restrict_1`` / ``prolong_2``.
    """
    assert prepared.bases is not None
    B_1, B_2 = prepared.bases
    corr = prepared.correspondence
    if plan.matrix == "analytic":
        transfer_12 = transfer_matrix(B_1, B_2, corr.fmap_12, method="analytic")
        return transfer_signal(f_1, B_1, B_2, transfer_12)
    # A side whose basis lives on its coarse copy (plan.coarse_bases): the source's values are
    # its cells' means there, the map is read at the target's coarse vertices and lands in
    # the source's cells, and the target's coarse result is interpolated to its vertices.
    c_1, c_2 = prepared.coarse
    p2p = corr.p2p_21 if c_2 is None else corr.p2p_21[c_2.samples]
    if c_1 is not None:
        assert prepared.restrict_1 is not None
        p2p, f_1 = c_1.cell[p2p], prepared.restrict_1 @ f_1
    transfer_12 = transfer_matrix(B_1, B_2, method="p2p", p2p_21=p2p)
    g = transfer_signal(f_1, B_1, B_2, transfer_12)
    if c_2 is not None:
        assert prepared.prolong_2 is not None
        g = prepared.prolong_2 @ g
    return g


def pull_back(f_1: Any, correspondence: Correspondence, faces_1: Any = None) -> np.ndarray:
    """Carry a source signal to the target exactly through the map (no basis).

    With a surface map (``correspondence.barycentric_21``, e.g. ``match(method="closest")``)
    every target vertex gets the source signal interpolated at its point on the source
    surface; otherwise the value at its source vertex.

    Parameters
    ----------
    f_1 : (n1,) or (n1, d) array_like of float
        Source signal.
    correspondence : Correspondence
        The map.
    faces_1 : (m1, 3) array_like of int, optional
        The source triangles the surface map refers to (required with a surface map).

    Returns
    -------
    (n2,) or (n2, d) ndarray
    """
    correspondence = check_correspondence(correspondence)
    if correspondence is None:
        raise TypeError("pull_back needs a correspondence")
    f = as_signal(f_1, correspondence.n_source, name="f_1")
    if correspondence.barycentric_21 is None:
        return f[correspondence.p2p_21]
    if faces_1 is None:
        raise ValueError("a surface map needs the source triangles (faces_1)")
    F = np.asarray(faces_1)
    if F.ndim != 2 or F.shape[1] != 3 or correspondence.faces_21.max() >= F.shape[0]:
        raise ValueError(
            f"faces_1 has shape {F.shape}: not the triangles the correspondence refers to"
        )
    corners = F[correspondence.faces_21]  # (n2, 3) source vertices
    w = correspondence.barycentric_21
    if f.ndim == 1:
        return np.einsum("ij,ij->i", f[corners], w)
    return np.einsum("ijd,ij->id", f[corners], w)
