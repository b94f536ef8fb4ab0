"""Training metrics: one CSV per run (easy to plot anywhere) and TensorBoard scalars."""

from __future__ import annotations

import csv
from pathlib import Path


class MetricsLog:
    """Appends rows of scalars to ``<dir>/learner.csv`` and, optionally, TensorBoard.

    The CSV header is fixed by the first row; later keys that were not in it are written
    to TensorBoard only, so a resumed run keeps appending to the same file.
    """

    def __init__(self, directory: Path, tensorboard_dir: Path | None = None):
        directory = Path(directory)
        directory.mkdir(parents=True, exist_ok=True)
        self.path = directory / "learner.csv"
        self._fields: list[str] | None = None
        if self.path.exists() and self.path.stat().st_size:
            with self.path.open() as f:
                self._fields = next(csv.reader(f), None)
        self._file = self.path.open("a", newline="")
        self._writer = None
        self._tb = None
        if tensorboard_dir is not None:
            from torch.utils.tensorboard import SummaryWriter

            self._tb = SummaryWriter(str(tensorboard_dir))

    def write(self, step: int, scalars: dict[str, float]) -> None:
        row = {"step": step, **scalars}
        if self._fields is None:
            self._fields = list(row)
        if self._writer is None:
            self._writer = csv.DictWriter(self._file, fieldnames=self._fields, extrasaction="ignore")
            if self._file.tell() == 0:
                self._writer.writeheader()
        self._writer.writerow(row)
        self._file.flush()
        if self._tb is not None:
            for name, value in scalars.items():
                self._tb.add_scalar(name, value, step)

    def close(self) -> None:
        self._file.close()
        if self._tb is not None:
            self._tb.close()
