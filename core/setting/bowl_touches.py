"""Probe touches of the bowls: the touches CSV (bowl id, probe centre at trigger, approach), read
with errors naming file and line, and written atomically."""
from __future__ import annotations

import csv
import io
import math
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
    """Read a touches CSV (columns bowl,x,y,z,ax,ay,az; '#' comments); errors name file and line."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8", errors="replace")  # bad bytes fail as cells
    except FileNotFoundError:
        raise InputError("file not found", path) from None
    rows, header = [], None
    for lineno, line in enumerate(text.splitlines(), 1):
        s = line.strip()
        if not s or s.startswith("#"):
            continue
        cells = [c.strip() for c in next(csv.reader([s]))]
        if header is None:
            header = [c.lower() for c in cells]
            missing = [c for c in TOUCH_COLUMNS if c not in header]
            if missing:
                raise InputError(f"header must contain columns {','.join(TOUCH_COLUMNS)}; missing "
                                 f"{','.join(missing)}", path, lineno)
            continue
        if len(cells) != len(header):
            raise InputError(f"expected {len(header)} values, got {len(cells)}", path, lineno)
        rec = dict(zip(header, cells))
        try:
            bid = int(rec["bowl"])
        except ValueError:
            raise InputError(f"bowl id must be an integer, got {rec['bowl']!r}", path, lineno,
                             "bowl") from None
        vals = []
        for c in TOUCH_COLUMNS[1:]:
            try:
                v = float(rec[c])
            except ValueError:
                raise InputError(f"expected a number, got {rec[c]!r}", path, lineno, c) from None
            if not math.isfinite(v):
                raise InputError(f"expected a finite number, got {rec[c]!r}", path, lineno, c)
            vals.append(v)
        a = np.array(vals[3:])
        na = np.linalg.norm(a)
        if na < 1e-9:
            raise InputError("approach vector is zero", path, lineno, "ax")
        rows.append((bid, vals[:3], a / na, lineno))
    if not rows:
        raise InputError("no touches in file", path)
    return Touches(bowl=np.array([r[0] for r in rows], int),
                   points=np.array([r[1] for r in rows], float),
                   approach=np.array([r[2] for r in rows], float),
                   lines=np.array([r[3] for r in rows], int), source=str(path))
