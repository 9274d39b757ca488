"""Read the SIM and REC CSV files of a diagnosis: header units, kinds of columns, checks.

A column header is ``name`` or ``name[unit]`` (also ``name (unit)``); names are case-sensitive.
Values are converted to the interface units mm, deg, s, degC, rpm, mm/s, deg/s, mm/s^2 and
deg/s^2; a column without a unit is taken in the interface unit of its kind.  The kind of a
column comes from its unit first, then from a unit given as an option (``--unit COL=UNIT``),
and only last from its name (``x``, ``y_cmd`` -> length, ``b``, ``q1`` -> angle, ``vx``,
``X1_ActualVelocity`` -> velocity, ``z_acc_cmd`` -> acceleration, ``t_spindle``/``temp2`` ->
temperature, ``s``/``spindle`` -> speed); guesses from names are reported.
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
# velocities and accelerations of linear and rotary axes: every length/angle unit over s, min
for _u, (_k, _f, _) in list(UNITS.items()):
    if _k not in ("length", "angle"):
        continue
    _vk, _ak = ("velocity", "acceleration") if _k == "length" else ("angular_velocity",
                                                                       "angular_acceleration")
    UNITS[_u + "/s"] = (_vk, _f, 0.0)
    UNITS[_u + "/min"] = (_vk, _f / 60.0, 0.0)
    for _sq in ("/s^2", "/s2", "/s²", "/s/s", "/s**2"):
        UNITS[_u + _sq] = (_ak, _f, 0.0)
INTERFACE_UNIT = {"length": "mm", "angle": "deg", "time": "s", "temperature": "degC",
                  "speed": "rpm", "velocity": "mm/s", "angular_velocity": "deg/s",
                  "acceleration": "mm/s^2", "angular_acceleration": "deg/s^2", "other": ""}
KINDS = tuple(INTERFACE_UNIT)
# kinds an output can have (what the effect library acts on)
MOTION_KINDS = ("length", "angle", "velocity", "angular_velocity", "acceleration",
                "angular_acceleration")
_DERIVED = {"length": ("velocity", "acceleration"),
            "angle": ("angular_velocity", "angular_acceleration")}

_HEADER = re.compile(r"^\s*(?P<name>[^\[\(]+?)\s*(?:[\[\(]\s*(?P<unit>[^\]\)]*?)\s*[\]\)])?\s*$")
_LINEAR = re.compile(r"^(?:q_?|cmd_?|pos_?)?[xyzuvw](?:$|[_\-\s\d].*|_?(?:cmd|act|pos|nom|set).*)")
_ROTARY = re.compile(r"^(?:q_?|cmd_?|pos_?)?[abc](?:$|[_\-\s\d].*|_?(?:cmd|act|pos|nom|set).*)")
_JOINT = re.compile(r"^(?:q|joint|j|theta|th)_?\d*(?:$|_(?:cmd|act|set|nom|meas|des)\w*)")
_TEMP = re.compile(r"^(?:t[_\-\s\d].+|t[a-z]{2,}\d*|temp.*|.*temperature.*|.*_temp\w*|theta_.*)$")
_SPEED = re.compile(r"^(?:s|s\d|s_.*|spindle.*|.*rpm.*|n_spindle.*)$")
_TOKENS = re.compile(r"[A-Z]+(?![a-z])|[A-Z]?[a-z]+|\d+")
_VEL_WORDS = {"v", "vel", "velo", "velocity", "feedrate", "speed"}
_ACC_WORDS = {"acc", "accel", "acceleration"}


def _tokens(name: str) -> list[str]:
    """Lower-case words of a column name: `X1_CommandVelocity` -> ['x', '1', 'command', 'velocity']."""
    return [w.lower() for w in _TOKENS.findall(name)]


def kind_from_name(key: str) -> str:
    """Guess the kind of a unit-less column from its name (the last resort; reported)."""
    low = key.lower()
    if low in ("t", "time"):
        return "time"
    words = _tokens(key)
    if _TEMP.match(low) and not _LINEAR.match(low):
        return "temperature"
    base = "angle" if _ROTARY.match(low) or _JOINT.match(low) else "length"
    has_axis = bool(_LINEAR.match(low) or _ROTARY.match(low) or _JOINT.match(low)
                    or _axis_in_words(words))
    if any(w in _ACC_WORDS for w in words) or re.match(r"^(?:acc|a)_?[xyzuvw]\d?$", low):
        if has_axis or re.match(r"^(?:acc|a)_?[xyzuvw]", low):
            return _DERIVED[base][1]
    if any(w in _VEL_WORDS for w in words) or re.match(r"^v_?[xyzabc]\d?$", low):
        if "spindle" not in words and (has_axis or re.match(r"^v_?[xyzabc]", low)):
            return _DERIVED["angle" if re.match(r"^v_?[abc]", low) else base][0]
    if _SPEED.match(low) and not (_axis_in_words(words) and not {"speed", "rpm", "n"} & set(words)):
        return "speed"
    if _axis_in_words(words) in tuple("xyz") and len(words) <= 3:
        return "length"
    if _LINEAR.match(low):
        return "length"
    if _ROTARY.match(low) or _JOINT.match(low):
        return "angle"
    if _TEMP.match(low):
        return "temperature"
    if low in ("pos", "position"):
        return "length"
    return "other"


def _axis_in_words(words) -> str | None:
    for w in words:
        if len(w) == 1 and w in "xyzabc":
            return w
        if len(w) == 2 and w[0] in "va" and w[1] in "xyzabc":
            return w[1]
    return None


def axis_letter(key: str, kind: str) -> str | None:
    """The ISO 841 axis letter a motion column refers to (``x_cmd``, ``vx``, ``X1_ActualVelocity``
    -> 'x'), or None (joint angles, unnamed signals)."""
    low = key.lower()
    m = re.match(r"^(?:q_?|cmd_?|pos_?)?([xyzabc])(?:$|[^a-z]|_?(?:cmd|act|pos|nom|set))", low)
    letter = m.group(1) if m else _axis_in_words(_tokens(key))
    if letter is None:
        return None
    linear = kind in ("length", "velocity", "acceleration")
    rotary = kind in ("angle", "angular_velocity", "angular_acceleration")
    if linear and letter in "xyz":
        return letter
    if rotary and letter in "abc":
        return letter
    return None


@dataclass(frozen=True)
class Column:
    """One CSV column after unit conversion."""
    key: str            # name as written, without unit: what columns are matched by (case-sensitive)
    header: str         # header as written
    kind: str           # one of KINDS
    unit: str           # unit after conversion (interface unit, or the raw unit for 'other')
    values: np.ndarray  # converted values
    quantum: float      # resolution of the written values in converted units (0 if not quantised)
    kind_from: str = "unit"  # where the kind came from: "unit", "option" or "name" (a guess)


@dataclass(frozen=True)
class Table:
    """A time-stamped CSV file: `t` in s (strictly increasing) and its other columns."""
    path: str
    t: np.ndarray
    columns: dict = field(default_factory=dict)  # key -> Column (excluding t)

    @property
    def n(self) -> int:
        return len(self.t)


# Largest magnitude accepted in interface units (mm, deg, s, ...): 1e12 mm is a million km.
# Larger values are a corrupt cell, not a measurement, and would overflow sums of squares.
MAX_ABS = 1e12


def _parse_header(cells: list[str], path, line: int | None = 1) -> list[tuple[str, str, str | None]]:
    out = []
    seen = {}
    for i, cell in enumerate(cells):
        m = _HEADER.match(cell)
        if not m or not m.group("name").strip():
            raise InputError(f"column {i + 1} has an empty or malformed name {cell!r}", path, line)
        name = m.group("name").strip()
        # names are case-sensitive, as in CSV: `X` (commanded) and `x` (measured) are two columns
        if name in seen:
            raise InputError(f"column {name!r} appears twice (columns {seen[name]} and {i + 1})",
                             path, line, field=name)
        seen[name] = i + 1
        unit = m.group("unit")
        out.append((cell.strip(), name, unit.strip() if unit is not None else None))
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


def _time_key(keys: list[str]) -> str | None:
    """The time column: `t` as written, else a single `T`, `time` or `Time`."""
    if "t" in keys:
        return "t"
    alts = [k for k in keys if k.lower() in ("t", "time")]
    return alts[0] if len(alts) == 1 else None


def _decimal_resolution(values: np.ndarray) -> float:
    """Rounding step of values written with a fixed number of significant figures.

    Loggers that write 3 significant figures (many PLC and cloud collectors) round each value
    to a step that grows with its size (0.01 at 5.86, 1 at 198); the noise floor cannot be
    below that rounding.  The number of significant figures is the 95th percentile over the
    values of the digits each needs (trailing zeros make some values look shorter); the result
    is the RMS over all values of their step.  Tiny for full-precision files.
    """
    v = np.abs(values[np.isfinite(values)])
    nz = v[v != 0]
    if len(nz) < 3:
        return 0.0
    if len(nz) > 20000:
        nz = nz[:: len(nz) // 20000]
    mag = np.floor(np.log10(nz))
    digits = np.full(len(nz), 16.0)
    todo = np.ones(len(nz), bool)
    for d in range(1, 16):
        step = 10.0 ** (mag[todo] - d + 1)
        x = nz[todo] / step
        ok = np.abs(x - np.round(x)) <= 1e-6 + 1e-14 * x
        idx = np.flatnonzero(todo)[ok]
        digits[idx] = d
        todo[idx] = False
        if not todo.any():
            break
    n_sig = float(np.percentile(digits, 95))
    if n_sig >= 8:
        return 0.0
    vv = v[:: max(1, len(v) // 20000)]
    steps = np.where(vv > 0, 10.0 ** (np.floor(np.log10(np.where(vv > 0, vv, 1.0))) - n_sig + 1), 0.0)
    return float(np.sqrt(np.mean(steps ** 2)))


def read_table(path: str | Path, role: str = "file", units: dict | None = None) -> Table:
    """Read one CSV file (header row; `t` column; numbers) into a :class:`Table`.

    `units` maps column names to units for columns whose header carries none (the --unit
    option).  Raises InputError naming the file, line and column for a missing `t`, a bad
    number, a NaN or absurd magnitude, a time that does not increase, or an unknown unit on `t`.
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8-sig")
    except FileNotFoundError:
        raise InputError(f"{role} file not found", path) from None
    except IsADirectoryError:
        raise InputError(f"{role} is a directory, expected a CSV file", path) from None
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
    cols = _parse_header(header_text.split(delim), path, hline + 1)
    keys = [c[1] for c in cols]
    if _time_key(keys) is None:
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
                                    hline + 1, units)
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
    return _from_matrix(str(path), cols, data, linenos, hline + 1, units)


def _unit_of(unit: str | None):
    """(kind, factor, offset) of a unit string, or None when unknown."""
    if unit is None:
        return None
    return UNITS.get(unit.lower().replace(" ", "").replace("sec", "s"))


def _from_matrix(label: str, cols, data: np.ndarray, linenos, hline: int | None,
                 units: dict | None = None) -> Table:
    """Checks and unit conversion shared by files and in-memory arrays."""
    path = label
    units = dict(units or {})
    bad = ~np.isfinite(data)
    if bad.any():
        r, c = np.argwhere(bad)[0]
        raise InputError(f"value is {data[r, c]} (expected a finite number)", path,
                         linenos[r] if linenos else None, field=cols[c][0])
    columns = {}
    t = None
    tkey = _time_key([c[1] for c in cols])
    for j, (hdr, key, unit) in enumerate(cols):
        raw = data[:, j]
        src = "unit"
        if unit is None and key in units:
            unit, src = units[key], "option"
            if _unit_of(unit) is None and unit not in ("", "-", "1"):
                raise InputError(f"unknown unit {unit!r} given for column {key!r} (expected one of "
                                 "mm, um, nm, deg, rad, mm/s, deg/s, mm/s^2, degC, rpm, ...)",
                                 field=f"--unit {key}")
        if unit:
            u = _unit_of(unit)
            kind, fac, off = u if u is not None else (None, 1.0, 0.0)
        else:
            kind, fac, off = kind_from_name(key), 1.0, 0.0
            src = "name"
        if key == tkey:
            if kind != "time":
                raise InputError(f"unit {unit!r} of {key} is not a time unit (s, ms, us, min)",
                                 path, hline, field=hdr)
            t = raw * fac
            continue
        if kind is None:  # a unit we do not know: keep the values as written
            kind, cunit = "other", unit
        else:
            cunit = INTERFACE_UNIT[kind]
        v = raw * fac + off
        big = np.abs(v) > MAX_ABS
        if big.any():
            r = int(np.argmax(big))
            raise InputError(f"value {raw[r]:g} is out of range (|value| above {MAX_ABS:g} "
                             f"{cunit or 'units'}: a corrupt cell?)", path,
                             linenos[r] if linenos else None, field=hdr)
        q = max(_quantum(raw), _decimal_resolution(raw))
        columns[key] = Column(key, hdr, kind, cunit, v, q * abs(fac), src)
    if np.any(np.abs(t) > MAX_ABS):
        r = int(np.argmax(np.abs(t) > MAX_ABS))
        raise InputError(f"time {t[r]:g} s is out of range", path, linenos[r] if linenos else None,
                         field=tkey)
    dt = np.diff(t)
    if not np.all(dt > 0):
        i = int(np.argmax(~(dt > 0)))
        raise InputError(f"t must increase strictly: {t[i + 1]:g} s follows {t[i]:g} s "
                         "(sort the rows or remove duplicates)", path,
                         linenos[i + 1] if linenos else None, field=tkey)
    return Table(str(path), t, columns)


def table_from_arrays(data, name: str = "arrays", units: dict | None = None) -> Table:
    """Build a Table from a mapping name -> 1-D array (keys may carry units, ``z[um]``)."""
    try:
        items = {str(k): np.asarray(v, dtype=float).ravel() for k, v in dict(data).items()}
    except (TypeError, ValueError) as exc:
        raise InputError(f"expected numeric arrays ({exc})", name) from None
    cols = _parse_header(list(items.keys()), name, None)
    if _time_key([c[1] for c in cols]) is None:
        raise InputError("no time column `t`", name, field="t")
    n = {len(v) for v in items.values()}
    if len(n) != 1:
        raise InputError("all arrays must have the same length", name)
    if n.pop() < 2:
        raise InputError("fewer than two samples", name)
    return _from_matrix(name, cols, np.column_stack(list(items.values())), None, None, units)


def load(source, role: str, units: dict | None = None) -> Table:
    """Accept a path, a Table, or a mapping of arrays (e.g. a dict or a DataFrame)."""
    if isinstance(source, Table):
        return source
    if isinstance(source, (str, Path)):
        return read_table(source, role, units)
    if hasattr(source, "to_dict") and hasattr(source, "columns"):  # DataFrame-like
        source = {c: np.asarray(source[c]) for c in source.columns}
    return table_from_arrays(source, role, units)
