"""Small CSV tables of pixels and points with named columns."""

from __future__ import annotations

import csv
import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from sea3d.errors import CsvError
from sea3d.io._atomic import atomic_open

__all__ = ["CsvError", "read_columns", "write_columns"]


def read_columns(path: str | os.PathLike[str], columns: Sequence[str]) -> NDArray[np.float64]:
    """Read the named numeric columns of a CSV file with a header row.

    Returns:
        ``(N, len(columns))`` float64, in the order asked for.

    Raises:
        CsvError: the file is missing, has no header, lacks a column, or holds a value that is
            not a number (naming the file, line and column).
    """
    p = Path(path)
    if not p.is_file():
        raise CsvError(f"{p}: file not found")
    with p.open(newline="") as fh:
        reader = csv.reader(fh)
        try:
            header = [h.strip() for h in next(reader)]
        except StopIteration:
            raise CsvError(
                f"{p}: empty file; expected a header with columns {list(columns)}"
            ) from None
        missing = [c for c in columns if c not in header]
        if missing:
            raise CsvError(f"{p}: missing column(s) {missing}; the header has {header}")
        idx = [header.index(c) for c in columns]
        rows: list[list[float]] = []
        for line_no, row in enumerate(reader, start=2):
            if not row or all(not cell.strip() for cell in row):
                continue
            values = []
            for c, i in zip(columns, idx, strict=True):
                try:
                    values.append(float(row[i]))
                except (IndexError, ValueError):
                    cell = row[i] if i < len(row) else "<missing>"
                    raise CsvError(
                        f"{p}: line {line_no}, column '{c}': not a number: {cell!r}"
                    ) from None
            rows.append(values)
    return np.asarray(rows, dtype=np.float64).reshape(-1, len(columns))


def write_columns(
    path: str | os.PathLike[str], columns: Sequence[str], values: NDArray[np.generic]
) -> None:
    """Write a CSV with a header row; floats with 12 significant digits, booleans as 0/1."""
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    with atomic_open(p, "w", newline="") as fh:
        writer = csv.writer(fh)
        writer.writerow(columns)
        for row in values:
            writer.writerow(
                [str(int(v)) if isinstance(v, bool | np.bool_) else f"{float(v):.12g}" for v in row]
            )
