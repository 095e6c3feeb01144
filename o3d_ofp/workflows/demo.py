"""The quick-start demonstration as a workflow: approximate and transfer colors on a blob.

The command line (``o3d-ofp demo``) prints this result and writes its meshes and picture.
"""

from __future__ import annotations

import dataclasses
import logging
import time

import numpy as np

from ..core.basis import approximation_error, ofp_basis
from ..core.shapes import blob
from ..core.spectrum import DEFAULT_K, eigenbasis
from .options import BasisOptions
from .pipeline import carry
from .plan import plan_pair, prepare

__all__ = ["DemoResult", "DemoRow", "demo_signal", "run_demo"]

logger = logging.getLogger(__name__)


def demo_signal(vertices: np.ndarray) -> np.ndarray:
    """RGB pattern on a shape: smooth bands, a sharp-edged region and fine stripes.

    Parameters
    ----------
    vertices : (n, 3) ndarray

    Returns
    -------
    (n, 3) ndarray
        Colors in [0, 1].
    """
    x, y, z = (vertices - vertices.mean(0)).T / np.ptp(vertices, axis=0).max()
    red = 0.5 + 0.5 * np.sin(6 * np.pi * x)
    green = 0.5 + 0.5 * np.cos(4 * np.pi * (y + z))
    blue = (np.sin(12 * np.pi * z) > 0).astype(float)  # sharp stripes: beyond any low band
    return np.column_stack([red, green, blue])


@dataclasses.dataclass(frozen=True)
class DemoRow:
    """One basis of the demo: its size, its approximations and their errors."""

    name: str
    size: int
    colors: np.ndarray
    rgb_error: float
    xyz_error: float
    seconds: float


@dataclasses.dataclass(frozen=True)
class DemoResult:
    """Everything the demo computed (arrays for the meshes and the picture)."""

    vertices: np.ndarray
    faces: np.ndarray
    colors: np.ndarray
    k: int
    order: int
    rows: tuple[DemoRow, ...]
    target_vertices: np.ndarray
    transferred: np.ndarray
    map_error: float
    transfer_error: float
    transfer_seconds: float


def run_demo(
    *, subdivisions: int = 5, seed: int = 0, k: int = DEFAULT_K, order: int = 2
) -> DemoResult:
    """Approximate a blob's colors with K eigenfunctions and both OFP bases; transfer them.

    Parameters
    ----------
    subdivisions : int, default 5
        Icosphere subdivisions of the blob (5: 10242 vertices).
    seed : int, default 0
        Shape seed.
    k : int, default 29
        Non-constant eigenfunctions.
    order : int, default 2
        Product order.

    Returns
    -------
    DemoResult
        Errors are ‖f − f̃‖_M / ‖f‖_M; XYZ centred on its area-weighted mean. The transfer goes
        to a bent, turned copy through an estimated map (no correspondence is given).
    """
    vertices, faces = blob(subdivisions, seed=seed)
    colors = demo_signal(vertices)
    t0 = time.perf_counter()
    eig = eigenbasis(vertices, faces, k=k)
    t_eig = time.perf_counter() - t0
    xyz = vertices - (eig.mass @ vertices) / eig.area

    def row(name: str, size: int, approx_rgb, approx_xyz, seconds: float) -> DemoRow:
        rgb_error = approximation_error(colors, approx_rgb, eig.mass)
        xyz_error = approximation_error(xyz, approx_xyz, eig.mass)
        return DemoRow(name, size, np.clip(approx_rgb, 0.0, 1.0), rgb_error, xyz_error, seconds)

    low = eig.reconstruct(eig.project(colors)), eig.reconstruct(eig.project(xyz))
    rows = [row("K eigs", k + 1, *low, t_eig)]
    for preset in ("ours", "ours*"):
        t0 = time.perf_counter()
        B = ofp_basis(eig, order=order, preset=preset)
        rows.append(row(preset, B.size, B.approximate(colors), B.approximate(xyz),
                        time.perf_counter() - t0))  # fmt: skip
    target = vertices.copy()
    target[:, 1] += 0.15 * target[:, 0] ** 2
    c, s = np.cos(0.7), np.sin(0.7)
    target = target @ np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]).T
    t0 = time.perf_counter()
    bases = BasisOptions(k1=k, k2=k, order=order)
    plan = plan_pair(vertices, faces, target, faces, task="colors", bases=bases)
    prepared = prepare(plan, vertices, faces, target, faces)
    g = carry(colors, plan, prepared)
    t_transfer = time.perf_counter() - t0
    p2p = prepared.correspondence.p2p_21
    map_error = float(np.linalg.norm(vertices[p2p] - vertices, axis=1).mean() / np.sqrt(eig.area))
    return DemoResult(
        vertices=vertices, faces=faces, colors=colors, k=k, order=order, rows=tuple(rows),
        target_vertices=target, transferred=np.clip(g, 0.0, 1.0), map_error=map_error,
        transfer_error=approximation_error(colors, g, prepared.eig_2.mass),
        transfer_seconds=t_transfer,
    )  # fmt: skip
