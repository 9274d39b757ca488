"""Probe touches of the bowls: the touches CSV (bowl id, probe centre at trigger, approach), read
with errors naming file and line, and written atomically."""
from __future__ import annotations

import csv
import io
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .._io import InputError


@dataclass(frozen=True)
class Touches:
    """Probe touches: bowl id (m,), probe centre at trigger (m, 3) mm, unit approach (m, 3).

    `lines` (m,) are the source line numbers (CSV) so errors can point at them (0 = synthetic).
    """
    bowl: np.ndarray
    points: np.ndarray
    approach: np.ndarray
    lines: np.ndarray = field(default=None)
    source: str | None = None

    def __post_init__(self):
        if self.lines is None:
            object.__setattr__(self, "lines", np.zeros(len(self.bowl), int))

    def of(self, bowl_id: int) -> np.ndarray:
        return np.flatnonzero(self.bowl == bowl_id)


TOUCH_COLUMNS = ("bowl", "x", "y", "z", "ax", "ay", "az")


def touches_to_csv(t: Touches) -> str:
    buf = io.StringIO()
    buf.write("# probe touches: bowl id, probe centre at trigger x y z (mm), unit approach ax ay az\n")
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(TOUCH_COLUMNS)
    for b, p, a in zip(t.bowl, t.points, t.approach):
        w.writerow([int(b)] + [f"{v:.9f}" for v in p] + [f"{v:.9f}" for v in a])
    return buf.getvalue()


def write_touches(t: Touches, path) -> Path:
    from .._io import atomic_write
    return atomic_write(path, touches_to_csv(t))


def read_touches(path) -> Touches:
    """Read a touches CSV (columns bowl,x,y,z,ax,ay,az in any order and case, more columns
    ignored; '#' comments; x y z in mm or with a unit in the header, docs/csv-format.md) with
    `mtcomp.csvtable`; errors name file, line and column."""
    from ..csvtable import read_csv
    tab = read_csv(path, what="touches", case_sensitive=False)
    missing = [c for c in TOUCH_COLUMNS if not tab.has(c)]
    if missing:
        raise tab.error(f"header must contain columns {','.join(TOUCH_COLUMNS)}; missing {','.join(missing)}")
    if not len(tab):
        raise InputError("no touches in file", tab.source)
    bowl = np.array([tab.integer(r, "bowl") for r in range(len(tab))], int)
    # 1e6 mm: far beyond any machine, and squares stay finite in the sphere fit
    points = np.column_stack([tab.numbers(c, unit="mm", max_abs=1e6) for c in ("x", "y", "z")])
    a = np.column_stack([tab.numbers(c, max_abs=1e6) for c in ("ax", "ay", "az")])
    na = np.linalg.norm(a, axis=1)
    if np.any(na < 1e-9):
        raise tab.error("approach vector is zero", int(np.argmax(na < 1e-9)), tab.col("ax").header)
    return Touches(bowl=bowl, points=points, approach=a / na[:, None],
                   lines=np.array(tab.lines, int), source=str(path))
