"""The record of one shape of a collection run, and the summary files of a run."""

from __future__ import annotations

import csv
import dataclasses
import io
import json
import logging
import math
import os
from collections.abc import Iterable
from typing import Any

import numpy as np

from ..core._atomic import atomic_path
from ..core.wording import Said

__all__ = ["STATUSES", "SUMMARY_FIELDS", "TargetResult", "write_summary"]

logger = logging.getLogger(__name__)

#: What happened to a shape: done, failed (see ``error``), or skipped (its output was up to
#: date, or its cache entries were already there).
STATUSES = ("ok", "failed", "skipped")


@dataclasses.dataclass(frozen=True)
class TargetResult:
    """What happened to one shape of a collection run.

    Attributes
    ----------
    index : int
        Position of the shape in the list given (after directories were expanded).
    name : str
        File name of the shape (``target_<index>.ply`` for a geometry given without a path).
    path : str or None
        The input file (absolute), or ``None`` for a geometry.
    status : {"ok", "failed", "skipped"}
        Done; failed (``error`` says why; the other shapes went on); or skipped (an earlier
        run made the output from the same files with the same options, as the output
        folder's record says, or for bases: every cache entry was already there). A skipped
        transfer keeps what was found when its output was made (``coverage``, ``suspect``,
        ``n_vertices``, ``warnings``, ``notes``), as recorded.
    output : str or None
        The file written (the transferred target, or the cached basis for
        :func:`~o3d_ofp.bases_many`); ``None`` when nothing was written.
    seconds : float
        Wall time spent on the shape (on its worker).
    coverage : float
        Map coverage: fraction of the source's vertices some target vertex maps to; NaN
        when no map was made.
    suspect : bool or None
        Whether the quality check found the map doubtful (``None``: no map).
    error : str
        Why the shape failed (exception type and message); empty otherwise.
    kind : {"colors", "texture", "detail", "basis"}
        What was done ("texture": baked into the target's UVs; a target without UVs of a
        texture run gets vertex colors: "colors").
    n_vertices : int
        Vertices of the shape (0 when it could not be read).
    cached : bool
        Whether its eigenbasis came from the cache.
    worker : str
        Address of the Dask worker that ran it (``"local"`` in the calling process).
    warnings : tuple of str or Said
        What was said about the shape's result (:class:`~o3d_ofp.OFPWarning` messages: a
        suspect map with its reasons and fix, parts left out, ...); empty when nothing was.
    notes : tuple of str or Said
        The notes of its map's quality report (``notes`` of :class:`~o3d_ofp.MapQuality`: e.g. a
        target whose area says other units or a part, a point cloud's estimated normals);
        empty when there were none or no map.
    values : (n, 3) ndarray or None
        The transferred colors (kind "colors") or the new vertex positions ("detail"), kept
        only when no ``output_dir`` was given; not part of the summary files.
    """

    index: int
    name: str
    path: str | None
    status: str
    output: str | None = None
    seconds: float = 0.0
    coverage: float = math.nan
    suspect: bool | None = None
    error: str | Said = ""
    kind: str = "colors"
    n_vertices: int = 0
    cached: bool = False
    worker: str = ""
    warnings: tuple[str | Said, ...] = ()
    notes: tuple[str | Said, ...] = ()
    values: np.ndarray | None = dataclasses.field(default=None, repr=False, compare=False)

    def __post_init__(self) -> None:
        if self.status not in STATUSES:
            raise ValueError(f"status must be one of {STATUSES}; got {self.status!r}")

    @property
    def ok(self) -> bool:
        """True unless the shape failed."""
        return self.status != "failed"

    def row(self) -> dict[str, Any]:
        """Return the summary row: every field but ``values`` (NaN coverage as ``None``)."""
        out = {name: getattr(self, name) for name in SUMMARY_FIELDS}
        nan = isinstance(self.coverage, float) and math.isnan(self.coverage)
        out.update(coverage=None if nan else self.coverage, seconds=round(float(self.seconds), 3))
        return {**out, "error": str(self.error), "warnings": [str(w) for w in self.warnings],
                "notes": [str(n) for n in self.notes]}  # fmt: skip


#: Columns of summary.csv (and keys of every summary.json row), in order.
SUMMARY_FIELDS = tuple(f.name for f in dataclasses.fields(TargetResult) if f.name != "values")


def write_summary(
    results: Iterable[TargetResult], output_dir: str | os.PathLike[str]
) -> tuple[str, str]:
    """Write ``summary.csv`` and ``summary.json`` (one row per shape) into ``output_dir``.

    Both files are written atomically. The JSON file holds ``{"counts": {status: n},
    "results": [row, ...]}``; the CSV file one row per shape with the columns
    ``o3d_ofp.collections.SUMMARY_FIELDS``: the fields of :class:`~o3d_ofp.TargetResult`
    but ``values``, in order (empty cells for ``None``).

    Parameters
    ----------
    results : iterable of TargetResult
        The records of a run (from :func:`~o3d_ofp.transfer_many` or
        :func:`~o3d_ofp.bases_many`).
    output_dir : str or os.PathLike
        Folder (created when missing).

    Returns
    -------
    csv_path, json_path : str
        The files written.

    Examples
    --------
    >>> import json
    >>> import tempfile
    >>> import o3d_ofp as ofp
    >>> results = [
    ...     ofp.TargetResult(0, "a.ply", "a.ply", "ok", coverage=0.9),
    ...     ofp.TargetResult(1, "b.ply", "b.ply", "failed", error="ValueError: no faces"),
    ... ]
    >>> with tempfile.TemporaryDirectory() as folder:
    ...     csv_path, json_path = ofp.write_summary(results, folder)
    ...     with open(json_path, encoding="utf-8") as fh:
    ...         summary = json.load(fh)
    >>> summary["counts"]
    {'ok': 1, 'failed': 1, 'skipped': 0}
    >>> [row["error"] for row in summary["results"]]
    ['', 'ValueError: no faces']
    """
    rows = [r.row() for r in results]
    folder = os.fspath(output_dir)
    os.makedirs(folder, exist_ok=True)
    counts = {s: sum(r["status"] == s for r in rows) for s in STATUSES}
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=SUMMARY_FIELDS, lineterminator="\n")
    writer.writeheader()
    for r in rows:
        joined = {k: " | ".join(r[k]) for k in ("warnings", "notes")}
        writer.writerow({**{k: "" if v is None else v for k, v in r.items()}, **joined})
    csv_path, json_path = (os.path.join(folder, f"summary.{ext}") for ext in ("csv", "json"))
    summary = json.dumps({"counts": counts, "results": rows}, indent=1) + "\n"
    for path, text in ((csv_path, buf.getvalue()), (json_path, summary)):
        with atomic_path(path, suffix=".tmp") as tmp, open(tmp, "w", encoding="utf-8") as fh:
            fh.write(text)
    logger.info("summary of %d shapes (%s) in %s", len(rows), counts, folder)
    return csv_path, json_path
