"""CSV logs of a training run: `train_log.csv` (losses per step) and `val_log.csv`.

Each row is a mapping with a `step` column; the header is written with the first row. On
resume, `RunLog.truncate` drops the rows after the checkpoint's step so that the logs of a
resumed run match those of an uninterrupted one.

Example:
    >>> import tempfile, pathlib
    >>> log = RunLog(pathlib.Path(tempfile.mkdtemp()))
    >>> for step in (1, 2, 3):
    ...     log.train.append({"step": step, "loss": 0.5})
    >>> log.truncate(2)
    >>> log.train.path.read_text().splitlines()
    ['step,loss', '1,0.5', '2,0.5']
"""

from __future__ import annotations

import csv
from collections.abc import Mapping
from pathlib import Path
from typing import Any


class CsvLog:
    """One CSV file of rows that each hold a `step` column.

    Args:
        path: the CSV file (its folder must exist when the first row is appended).
    """

    def __init__(self, path: str | Path):
        self.path = Path(path)

    def append(self, row: Mapping[str, Any]) -> None:
        """Append a row (with a header first when the file is new). A row with columns that
        the header lacks (a log of an older version) rewrites the file with all columns."""
        new = not self.path.exists()
        if not new:
            header = self._header()
            if list(row) != header:
                fields = header + [key for key in row if key not in header]
                if fields != header:
                    self._rewrite([*self.rows(), dict(row)], fields)
                    return
                row = {key: row.get(key, "") for key in header}
        with self.path.open("a", newline="") as handle:
            writer = csv.DictWriter(handle, fieldnames=list(row))
            if new:
                writer.writeheader()
            writer.writerow(row)

    def _header(self) -> list[str]:
        with self.path.open(newline="") as handle:
            return next(csv.reader(handle), [])

    def _rewrite(self, rows: list[Mapping[str, Any]], fields: list[str]) -> None:
        """Replace the file with `rows` under the header `fields` (atomically)."""
        tmp = self.path.with_name(f".{self.path.name}.tmp")
        with tmp.open("w", newline="") as handle:
            writer = csv.DictWriter(handle, fieldnames=fields, restval="")
            writer.writeheader()
            writer.writerows(rows)
        tmp.replace(self.path)

    def rows(self) -> list[dict[str, str]]:
        """The rows read back (values as strings); empty when there is no file."""
        if not self.path.exists():
            return []
        with self.path.open(newline="") as handle:
            return list(csv.DictReader(handle))

    def truncate(self, step: int) -> None:
        """Drop the rows whose `step` is after `step`."""
        if not self.path.exists():
            return
        fields = self._header()
        self._rewrite([r for r in self.rows() if int(r["step"]) <= step], fields)


class RunLog:
    """The train and validation logs of a run in `out_dir`."""

    def __init__(self, out_dir: str | Path):
        out_dir = Path(out_dir)
        self.train = CsvLog(out_dir / "train_log.csv")
        self.val = CsvLog(out_dir / "val_log.csv")

    def truncate(self, step: int) -> None:
        """Cut both logs back to `step` (resume from a checkpoint of that step)."""
        self.train.truncate(step)
        self.val.truncate(step)


__all__ = ["CsvLog", "RunLog"]
