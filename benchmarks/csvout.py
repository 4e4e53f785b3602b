"""The one CSV writer of the benchmark scripts: every script writes its rows through
:func:`write_rows`, so that every CSV under ``benchmarks/results/`` has the same shape (a
header row, then one row per measurement) and its folder is created on the way."""

from __future__ import annotations

import csv
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

__all__ = ["write_rows"]


def write_rows(path: str | Path, rows: Sequence[Mapping[str, Any]], columns: Sequence[str] | None = None) -> Path:
    """Write ``rows`` to ``path`` as CSV with the header ``columns`` (default: the first
    row's keys; keys outside ``columns`` are left out, missing ones are empty). Returns the
    path written."""
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    fields = list(columns) if columns is not None else list(rows[0]) if rows else []
    with out.open("w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=fields, extrasaction="ignore")
        writer.writeheader()
        writer.writerows(rows)
    return out
