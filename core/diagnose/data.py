"""Read the SIM and REC CSV files of a diagnosis: header units, kinds of columns, checks.

A column header is ``name`` or ``name[unit]`` (also ``name (unit)``).  Values are converted to
the interface units mm, deg, s, degC (and rpm for speeds); a column without a unit is taken in
the interface unit of its kind.  The kind of a column (length, angle, time, temperature, speed,
other) comes from its unit, or from its name when there is none (``x``, ``y_cmd`` -> length,
``b`` -> angle, ``t_spindle``/``temp2`` -> temperature, ``s``/``spindle`` -> speed).
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .._io import InputError

# unit -> (kind, factor, offset): value_in_interface_unit = value * factor + offset
UNITS: dict[str, tuple[str, float, float]] = {
    "mm": ("length", 1.0, 0.0), "um": ("length", 1e-3, 0.0), "µm": ("length", 1e-3, 0.0),
    "μm": ("length", 1e-3, 0.0), "micron": ("length", 1e-3, 0.0), "nm": ("length", 1e-6, 0.0),
    "m": ("length", 1e3, 0.0), "cm": ("length", 10.0, 0.0), "in": ("length", 25.4, 0.0),
    "deg": ("angle", 1.0, 0.0), "°": ("angle", 1.0, 0.0), "rad": ("angle", 180.0 / math.pi, 0.0),
    "mrad": ("angle", 0.180 / math.pi, 0.0), "urad": ("angle", 1.8e-4 / math.pi, 0.0),
    "µrad": ("angle", 1.8e-4 / math.pi, 0.0), "arcsec": ("angle", 1.0 / 3600.0, 0.0),
    "s": ("time", 1.0, 0.0), "ms": ("time", 1e-3, 0.0), "us": ("time", 1e-6, 0.0),
    "µs": ("time", 1e-6, 0.0), "min": ("time", 60.0, 0.0),
    "degc": ("temperature", 1.0, 0.0), "°c": ("temperature", 1.0, 0.0), "c": ("temperature", 1.0, 0.0),
    "k": ("temperature", 1.0, -273.15),
    "rpm": ("speed", 1.0, 0.0), "1/min": ("speed", 1.0, 0.0), "rev/min": ("speed", 1.0, 0.0),
    "hz": ("speed", 60.0, 0.0), "rev/s": ("speed", 60.0, 0.0),
}
INTERFACE_UNIT = {"length": "mm", "angle": "deg", "time": "s", "temperature": "degC",
                  "speed": "rpm", "other": ""}

_HEADER = re.compile(r"^\s*(?P<name>[^\[\(]+?)\s*(?:[\[\(]\s*(?P<unit>[^\]\)]*?)\s*[\]\)])?\s*$")
_LINEAR = re.compile(r"^(?:q_?|cmd_?|pos_?)?[xyzuvw](?:$|[_\-\s\d].*|_?(?:cmd|act|pos|nom|set).*)")
_ROTARY = re.compile(r"^(?:q_?|cmd_?|pos_?)?[abc](?:$|[_\-\s\d].*|_?(?:cmd|act|pos|nom|set).*)")
_TEMP = re.compile(r"^(?:t[_\-\s\d].+|t[a-z]{2,}\d*|temp.*|.*temperature.*|theta_.*)$")
_SPEED = re.compile(r"^(?:s|s\d|s_.*|spindle.*|.*rpm.*|n_spindle.*)$")


def kind_from_name(key: str) -> str:
    """Guess the kind of a unit-less column from its (lower-case) name."""
    if key == "t":
        return "time"
    if _LINEAR.match(key):
        return "length"
    if _ROTARY.match(key):
        return "angle"
    if _SPEED.match(key):
        return "speed"
    if _TEMP.match(key):
        return "temperature"
    return "other"


def axis_letter(key: str, kind: str) -> str | None:
    """The ISO 841 axis letter a length/angle column refers to (``x_cmd`` -> 'x'), or None."""
    m = re.match(r"^(?:q_?|cmd_?|pos_?)?([xyzabc])", key)
    if not m:
        return None
    letter = m.group(1)
    if kind == "length" and letter in "xyz":
        return letter
    if kind == "angle" and letter in "abc":
        return letter
    return None


@dataclass(frozen=True)
class Column:
    """One CSV column after unit conversion."""
    key: str            # lower-case name without unit: what columns are matched by
    header: str         # header as written
    kind: str           # length | angle | time | temperature | speed | other
    unit: str           # unit after conversion (interface unit, or the raw unit for 'other')
    values: np.ndarray  # converted values
    quantum: float      # resolution of the written values in converted units (0 if not quantised)


@dataclass(frozen=True)
class Table:
    """A time-stamped CSV file: `t` in s (strictly increasing) and its other columns."""
    path: str
    t: np.ndarray
    columns: dict = field(default_factory=dict)  # key -> Column (excluding t)

    @property
    def n(self) -> int:
        return len(self.t)


def _parse_header(cells: list[str], path) -> list[tuple[str, str, str | None]]:
    out = []
    seen = set()
    for i, cell in enumerate(cells):
        m = _HEADER.match(cell)
        if not m or not m.group("name").strip():
            raise InputError(f"column {i + 1} has an empty or malformed name {cell!r}", path, 1)
        name = m.group("name").strip()
        key = name.lower()
        if key in seen:
            raise InputError(f"column {name!r} appears twice", path, 1, field=name)
        seen.add(key)
        unit = m.group("unit")
        out.append((cell.strip(), key, unit.strip() if unit is not None else None))
    return out


def _quantum(values: np.ndarray) -> float:
    """Resolution of written values: the step q such that every value is a multiple of q.

    Real recorders write positions in counts of the scale (e.g. 0.1 um); the noise floor cannot
    be below q/sqrt(12) then, however flat the first differences look.
    """
    v = values[np.isfinite(values)]
    if len(v) < 3:
        return 0.0
    u = np.unique(v)
    if len(u) < 2:
        return 0.0
    d = np.diff(u)
    q = float(np.min(d))
    scale = float(np.max(np.abs(u)))
    if q <= 1e-12 * max(scale, 1e-300):
        return 0.0
    # a genuinely quantised signal has all values on the q lattice
    k = v / q
    frac = np.abs(k - np.round(k))
    if np.mean(frac < 1e-3) > 0.99:
        return q
    return 0.0


def read_table(path: str | Path, role: str = "file") -> Table:
    """Read one CSV file (header row; `t` column; numbers) into a :class:`Table`.

    Raises InputError naming the file, line and column for a missing `t`, a bad number, a NaN,
    a time that does not increase, or an unknown unit on `t`.
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8-sig")
    except FileNotFoundError:
        raise InputError(f"{role} file not found", path) from None
    except UnicodeDecodeError as exc:
        raise InputError(f"not a UTF-8 text file ({exc.reason})", path) from None
    lines = text.splitlines()
    # header = first line that is neither empty nor a comment
    hline = next((i for i, s in enumerate(lines) if s.strip() and not s.lstrip().startswith("#")), None)
    if hline is None:
        raise InputError("empty file: expected a header row and data rows", path)
    header_text = lines[hline]
    delim = ","
    if "," not in header_text:
        delim = ";" if ";" in header_text else ("\t" if "\t" in header_text else ",")
    cols = _parse_header(header_text.split(delim), path)
    keys = [c[1] for c in cols]
    if "t" not in keys:
        raise InputError("no time column `t` (expected a header like `t,x,y,...` with t in s)",
                         path, hline + 1, field="t")
    ncol = len(cols)
    body = [s for s in lines[hline + 1:] if s.strip() and not s.lstrip().startswith("#")]
    if len(body) == len(lines) - hline - 1 and len(body) >= 2:
        # fast path: numpy's C parser; any problem falls through to the checking parser below,
        # which names the line and column
        try:
            data = np.loadtxt(lines[hline + 1:], delimiter=delim, ndmin=2, dtype=float)
            if data.shape[1] == ncol:
                return _from_matrix(str(path), cols, data, list(range(hline + 2, hline + 2 + len(data))),
                                    hline + 1)
        except ValueError:
            pass
    rows, linenos = [], []
    for i in range(hline + 1, len(lines)):
        s = lines[i].strip()
        if not s or s.startswith("#"):
            continue
        cells = s.split(delim)
        if len(cells) != ncol:
            raise InputError(f"expected {ncol} values, found {len(cells)}", path, i + 1)
        rows.append(cells)
        linenos.append(i + 1)
    if len(rows) < 2:
        raise InputError("fewer than two data rows", path)
    try:
        data = np.array(rows, dtype=float)
    except ValueError:
        for cells, ln in zip(rows, linenos):
            for (hdr, key, unit), c in zip(cols, cells):
                try:
                    float(c)
                except ValueError:
                    raise InputError(f"expected a number, found {c.strip()!r}", path, ln,
                                     field=hdr) from None
        raise
    return _from_matrix(str(path), cols, data, linenos, hline + 1)


def _from_matrix(label: str, cols, data: np.ndarray, linenos, hline: int | None) -> Table:
    """Checks and unit conversion shared by files and in-memory arrays."""
    path = label
    bad = ~np.isfinite(data)
    if bad.any():
        r, c = np.argwhere(bad)[0]
        raise InputError(f"value is {data[r, c]} (expected a finite number)", path,
                         linenos[r] if linenos else None, field=cols[c][0])
    columns = {}
    t = None
    for j, (hdr, key, unit) in enumerate(cols):
        raw = data[:, j]
        if unit:
            u = unit.lower().replace(" ", "")
            if u in UNITS:
                kind, fac, off = UNITS[u]
            else:
                kind, fac, off = None, 1.0, 0.0
        else:
            kind, fac, off = kind_from_name(key), 1.0, 0.0
        if key == "t":
            if kind != "time":
                raise InputError(f"unit {unit!r} of t is not a time unit (s, ms, us, min)",
                                 path, hline, field=hdr)
            t = raw * fac
            continue
        if kind is None:  # a unit we do not know: keep the values as written
            kind, cunit = "other", unit
        else:
            cunit = INTERFACE_UNIT[kind]
        q = _quantum(raw)
        columns[key] = Column(key, hdr, kind, cunit, raw * fac + off, q * abs(fac))
    dt = np.diff(t)
    if not np.all(dt > 0):
        i = int(np.argmax(~(dt > 0)))
        raise InputError(f"t must increase strictly: {t[i + 1]:g} s follows {t[i]:g} s "
                         "(sort the rows or remove duplicates)", path,
                         linenos[i + 1] if linenos else None, field="t")
    return Table(str(path), t, columns)


def table_from_arrays(data, name: str = "arrays") -> Table:
    """Build a Table from a mapping name -> 1-D array (keys may carry units, ``z[um]``)."""
    items = {str(k): np.asarray(v, dtype=float).ravel() for k, v in dict(data).items()}
    cols = _parse_header(list(items.keys()), name)
    if "t" not in [c[1] for c in cols]:
        raise InputError("no time column `t`", name, field="t")
    n = {len(v) for v in items.values()}
    if len(n) != 1:
        raise InputError("all arrays must have the same length", name)
    if n.pop() < 2:
        raise InputError("fewer than two samples", name)
    return _from_matrix(name, cols, np.column_stack(list(items.values())), None, None)


def load(source, role: str) -> Table:
    """Accept a path, a Table, or a mapping of arrays (e.g. a dict or a DataFrame)."""
    if isinstance(source, Table):
        return source
    if isinstance(source, (str, Path)):
        return read_table(source, role)
    if hasattr(source, "to_dict") and hasattr(source, "columns"):  # DataFrame-like
        source = {c: np.asarray(source[c]) for c in source.columns}
    return table_from_arrays(source, role)
