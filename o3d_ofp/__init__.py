"""o3d_ofp: Orthogonalized Fourier Polynomials for Open3D meshes and point clouds.

The package is layered (see the documentation's "Architecture" page): :mod:`o3d_ofp.core`
(arrays only), :mod:`o3d_ofp.workflows` (whole runs over arrays), :mod:`o3d_ofp.boundary`
(Open3D geometries in and out), :mod:`o3d_ofp.collections` (many shapes, on Dask) and the
front ends :mod:`o3d_ofp.cli` and :mod:`o3d_ofp.render`. The names below
are the public API. Importing the package does not import Open3D: the boundary functions import
it when they are called.

References
----------
.. [1] F. Maggioli, S. Melzi, M. Ovsjanikov, M. M. Bronstein, E. Rodolà, "Orthogonalized Fourier
   Polynomials for Signal Approximation and Transfer", Computer Graphics Forum 40(2), 2021
   (Eurographics 2021). doi:10.1111/cgf.142645
"""

from __future__ import annotations

import logging

from .boundary.api import (
    cached_basis,
    eigenbasis,
    filter_geometry,
    match,
    shape_digest,
    transfer_colors,
    transfer_detail,
)
from .boundary.bake import texture_pullback, transfer_texture
from .boundary.io import read_geometry, write_geometry
from .boundary.pick import pick_landmarks
from .boundary.texture import texture_colors
from .collections import TargetResult, bases_many, transfer_many, write_summary
from .core._version import __version__
from .core._warnings import OFPWarning
from .core.basis import OFPBasis, approximation_error, ofp_basis
from .core.cleaning import CleaningReport, clean_shape
from .core.correspondence import fmap_from_p2p, nearest_neighbors, p2p_from_fmap, p2p_from_template
from .core.descriptors import hks, wks
from .core.fmap import estimate_fmap, icp_refine, lift_fmap, zoomout_refine
from .core.laplacian import laplacian
from .core.orthogonalize import PRESETS, GramSchmidt, gram_schmidt
from .core.products import eigenproduct_indices, eigenproducts, n_eigenproducts
from .core.spectrum import EigenBasis, EigenSolverError
from .core.transfer import transfer_matrix, transfer_signal
from .render import render_panel, show
from .workflows.estimate import match_eigenbases
from .workflows.maps import Correspondence, MapQuality
from .workflows.options import BasisOptions, DetailOptions, MatchOptions
from .workflows.pipeline import transfer_function

__all__ = [
    "PRESETS",
    "BasisOptions",
    "CleaningReport",
    "Correspondence",
    "DetailOptions",
    "EigenBasis",
    "EigenSolverError",
    "GramSchmidt",
    "MapQuality",
    "MatchOptions",
    "OFPBasis",
    "OFPWarning",
    "TargetResult",
    "__version__",
    "approximation_error",
    "bases_many",
    "cached_basis",
    "clean_shape",
    "eigenbasis",
    "eigenproduct_indices",
    "eigenproducts",
    "estimate_fmap",
    "filter_geometry",
    "fmap_from_p2p",
    "gram_schmidt",
    "hks",
    "icp_refine",
    "laplacian",
    "lift_fmap",
    "match",
    "match_eigenbases",
    "n_eigenproducts",
    "nearest_neighbors",
    "ofp_basis",
    "p2p_from_fmap",
    "p2p_from_template",
    "pick_landmarks",
    "read_geometry",
    "render_panel",
    "shape_digest",
    "show",
    "texture_colors",
    "texture_pullback",
    "transfer_colors",
    "transfer_detail",
    "transfer_function",
    "transfer_many",
    "transfer_matrix",
    "transfer_signal",
    "transfer_texture",
    "wks",
    "write_geometry",
    "write_summary",
    "zoomout_refine",
]

logging.getLogger(__name__).addHandler(logging.NullHandler())
