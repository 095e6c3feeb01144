"""The steps of a map estimation as a strategy, run by :func:`o3d_ofp.workflows.estimate.estimate`.

:func:`~o3d_ofp.workflows.estimate.estimate` runs the steps in their order (fit starts, refine
them, settle on a map, judge it, review it); a :class:`Strategy` says how each is done for one
kind of match (:class:`~o3d_ofp.workflows.matching.FullMatch`,
:class:`~o3d_ofp.workflows.partial.PartialMatch`).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any, ClassVar

import numpy as np

from ..core.spectrum import EigenBasis
from .maps import Correspondence, MapQuality
from .options import MatchOptions, required_k

__all__ = ["Run", "Settled", "Strategy"]


@dataclasses.dataclass
class Run:
    """What one estimation carries from step to step (built by :func:`estimate`).

    Attributes
    ----------
    eig_1, eig_2 : EigenBasis
        Source and target eigenbases on their cleaned surfaces.
    u1, u2 : EigenBasis
        Their scaled copies (the strategy's :meth:`Strategy.scaled`).
    landmarks : (p, 2) ndarray of int or None
        Known pairs on the surfaces' vertices.
    options : MatchOptions
        The estimation's options.
    report : callable
        ``report(stage, fraction_done)``.
    state : dict
        What a strategy keeps between its steps.
    """

    eig_1: EigenBasis
    eig_2: EigenBasis
    u1: EigenBasis
    u2: EigenBasis
    landmarks: np.ndarray | None
    options: MatchOptions
    report: Callable[[str, float], None]
    state: dict[str, Any] = dataclasses.field(default_factory=dict)


@dataclasses.dataclass
class Settled:
    """The map a strategy settled on: its functional map, point map and what it knows of it."""

    fmap_12: np.ndarray
    p2p_21: np.ndarray
    info: dict[str, Any] = dataclasses.field(default_factory=dict)


class Strategy:
    """How each step of :func:`estimate` is done for one kind of match (subclasses fill it in).

    ``method`` names the maps it makes (``Correspondence.method``), ``title`` starts its log
    lines, ``what`` names its map in a warning; ``refine_share`` is the share of the progress
    the refinements of the starts take, after ``refine_share[0]`` (the defaults: the full
    match's).
    """

    method: ClassVar[str] = "estimate"
    title: ClassVar[str] = "match"
    what: ClassVar[str] = "the estimated map"
    refine_share: ClassVar[tuple[float, float]] = (0.1, 0.5)

    def needs(self, n1: int, n2: int, options: MatchOptions) -> tuple[int, int]:
        """Return the eigenfunctions computed on each shape for this estimation.

        ``zoomout_to`` on both (fewer on a shape with fewer vertices).
        """
        return required_k(n1, options.zoomout_to), required_k(n2, options.zoomout_to)

    def least(self, n1: int, n2: int, options: MatchOptions) -> tuple[int, int]:
        """Return the fewest eigenfunctions each given eigenbasis may hold (:meth:`needs`)."""
        return self.needs(n1, n2, options)

    def check(self, eig_1: EigenBasis, eig_2: EigenBasis) -> None:
        """Refuse bases this estimation cannot run on (beyond their sizes); default: none."""

    def scaled(self, eig_1: EigenBasis, eig_2: EigenBasis) -> tuple[EigenBasis, EigenBasis]:
        """Return the copies of the bases the estimation runs on."""
        raise NotImplementedError

    def starts(self, run: Run) -> list[Any]:
        """Return the starting maps (fitted to descriptors)."""
        raise NotImplementedError

    def refine(self, run: Run, index: int, start: Any) -> Any:
        """One start refined (run two at a time, one per core)."""
        raise NotImplementedError

    def settle(self, run: Run, starts: list[Any], refined: list[Any]) -> Settled:
        """Choose among the refined starts and finish the chosen map."""
        raise NotImplementedError

    def judge(self, run: Run, settled: Settled) -> MapQuality:
        """Return the settled map's quality report."""
        raise NotImplementedError

    def review(self, run: Run, settled: Settled, quality: MapQuality) -> tuple[Settled, MapQuality]:
        """Return a second look at the judged map (repair, rivals, polish); default: none."""
        return settled, quality

    def rival_without_landmarks(self, run: Run, quality: MapQuality) -> bool:
        """Whether the map estimated without the landmarks is to be tried too; default: no."""
        return False

    def against_free(
        self, run: Run, settled: Settled, quality: MapQuality, free: Settled,
        free_quality: MapQuality,
    ) -> tuple[Settled, MapQuality]:  # fmt: skip
        """Return the landmarks' map, or the one estimated without them (default: the first)."""
        return settled, quality

    def options(self, run: Run, settled: Settled) -> dict[str, Any]:
        """Return the options recorded in the Correspondence."""
        return {
            **run.options.estimation,
            "components": run.options.components,
            "landmarks": None if run.landmarks is None else run.landmarks.tolist(),
        }

    def for_coarse(self) -> Strategy:
        """Return the strategy of the estimation between a dense pair's coarse copies."""
        return self

    def extend(self, corr: Correspondence, coarse_1: Any, coarse_2: Any, V1: Any, V2: Any) -> Any:
        """Extend a coarse map to every vertex: (full point map, coarse Correspondence)."""
        raise NotImplementedError

    def dense(
        self,
        again: Callable[..., Correspondence],
        size: int,
        shapes: tuple[np.ndarray, ...],
        report: Callable[[str, float], None],
        *,
        opinions: bool = True,
    ) -> Correspondence:
        """Run the dense path's match: ``again(size, share, prefix)`` once.

        A strategy may check it against matches on other coarse copies of the full meshes
        ``shapes`` (the partial match's ``opinions``); ``report`` is the whole run's progress.
        """
        return again(size, (0.0, 1.0), "")
