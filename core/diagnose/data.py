"""Read the SIM and REC CSV files of a diagnosis (through mtcomp.csvtable): time, units, missing
values, repeated time stamps, the resolution of the written values, and the pairing of SIM and
REC columns under other names.

A column header is ``name`` or ``name[unit]`` (also ``name (unit)``); names are case-sensitive.
Values are converted to the interface units (mm, deg, s, degC, rpm and their rates); the kind of
a column comes from its unit first, then from a unit given as an option (``--unit COL=UNIT``),
and only last from its name (`mtcomp.diagnose.columns`); guesses from names are reported.
"""
from __future__ import annotations

import re
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from .._io import InputError
from ..csvtable import read_csv
from . import rows as _rows
from .columns import (_HEADER, INTERFACE_UNIT, KINDS, MOTION_KINDS, UNITS, _tokens,  # noqa: F401
                      _unit_of, axis_letter, kind_from_name, role, stem)


@dataclass(frozen=True)
class Column:
    """One CSV column after unit conversion."""
    key: str            # name as written, without unit: what columns are matched by (case-sensitive)
    header: str         # header as written
    kind: str           # one of KINDS
    unit: str           # unit after conversion (interface unit, or the raw unit for 'other')
    values: np.ndarray  # converted values (missing cells filled linearly between neighbours)
    quantum: float      # resolution of the written values in converted units (0 if not quantised)
    kind_from: str = "unit"  # where the kind came from: "unit", "option" or "name" (a guess)
    present: np.ndarray | None = None  # per row: the cell held a value (None: every cell did)


@dataclass(frozen=True)
class Table:
    """A time-stamped CSV file: `t` in s (strictly increasing) and its other columns."""
    path: str
    t: np.ndarray
    columns: dict = field(default_factory=dict)  # key -> Column (excluding t)
    # where t = 0 is when t came from time stamps: ("date", s since 1970-01-01) or
    # ("day", s since midnight); None for a numeric time column
    origin: tuple | None = None
    notes: tuple = ()   # what the reader decided (missing cells, repeated time stamps), in words
    # per row: removed by the row filter (--where / --exclude-rows); None: no row removed
    excluded: np.ndarray | None = None
    row_filter: tuple = ()  # the row conditions that named a column of this file

    @property
    def n(self) -> int:
        return len(self.t)


# Largest magnitude accepted in interface units (mm, deg, s, ...): 1e12 mm is a million km.
# Larger values are a corrupt cell, not a measurement, and would overflow sums of squares.
MAX_ABS = 1e12
# cells that mean "no value": loggers write an empty cell, NaN (MATLAB, pandas) or NA/null
MISSING = ("", "nan", "NaN", "NAN", "NA", "N/A", "n/a", "null", "NULL", "None", "-")
# a column with fewer values than this share of the rows is too sparse to use
MIN_PRESENT = 0.5


def _parse_header(cells: list[str], path, line: int | None = 1) -> list[tuple[str, str, str | None]]:
    """(header, name, unit) of each header cell (for in-memory arrays; files are read by
    mtcomp.csvtable, which applies the same rules)."""
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


# the name given to an unnamed first column (a row index), spelt so no logger's column has it
_INDEX = "(row index)"

# names of a time column other than `t` (English, German, French, Spanish, Italian; a logger's
# "timestamp"), matched ignoring case
_TIME_NAMES = ("t", "time", "timestamp", "time_stamp", "zeit", "zeitstempel", "temps", "tiempo",
               "tempo", "time_s", "t_s", "datetime", "date_time", "horodatage", "t_ms", "time_ms",
               "t_us", "time_us", "timestamp_ms", "timestamp_us")


def _time_key(keys: list[str]) -> str | None:
    """The time column: `t` as written, else the single column named like a time (`T`, `time`,
    `Time`, `timestamp`, `Zeit`, `temps`, ...)."""
    if "t" in keys:
        return "t"
    alts = [k for k in keys if k.lower() in _TIME_NAMES]
    return alts[0] if len(alts) == 1 else None


_STAMP = re.compile(r"(?:(?P<date>\d{4}-\d{2}-\d{2})[T ])?(?P<h>\d{1,2}):(?P<m>\d{2}):"
                    r"(?P<s>\d{2}(?:[.,]\d+)?)(?P<tz>Z|[+-]\d{2}:?\d{2})?")


def _time_stamps(cells, source, lines, column) -> tuple[np.ndarray, tuple]:
    """Seconds of ISO 8601 time stamps (``2024-03-01 12:00:00.125``, ``2024-03-01T12:00:00Z``,
    ``12:00:00.125``) relative to the first, and the origin ("date" s since 1970, or "day" s
    since midnight).  A time of day without a date that passes midnight continues on the next
    day.  Parsed by hand because numpy's datetime64 takes neither a time of day alone nor a
    decimal comma; the calendar arithmetic is numpy's."""
    days = np.zeros(len(cells))
    secs = np.zeros(len(cells))
    dated = None
    for i, c in enumerate(cells):
        m = _STAMP.fullmatch(c)
        if m is None or (dated is not None and (m.group("date") is not None) != dated):
            what = "an empty cell" if c == "" else repr(c[:40])
            raise InputError(f"expected a time in s or a time stamp like 2024-03-01 12:00:00.5 "
                             f"(the same form on every row), got {what}", source, lines[i], column)
        dated = m.group("date") is not None
        h, mi, sc = int(m.group("h")), int(m.group("m")), float(m.group("s").replace(",", "."))
        if h > 23 or mi > 59 or sc >= 61:
            raise InputError(f"not a time of day: {c!r}", source, lines[i], column)
        x = h * 3600.0 + mi * 60.0 + sc
        tz = m.group("tz")
        if tz and tz != "Z":
            sign = -1.0 if tz[0] == "-" else 1.0
            x -= sign * (int(tz[1:3]) * 3600.0 + int(tz[-2:]) * 60.0)
        if dated:
            try:
                days[i] = float(np.datetime64(m.group("date"), "D").astype(np.int64))
            except ValueError:
                raise InputError(f"not a date: {m.group('date')!r}", source, lines[i], column) from None
        secs[i] = x
    if not dated:
        # past midnight: a jump back by most of a day is the next day
        back = np.diff(secs) < -43200.0
        days[1:] = np.cumsum(back)
    absolute = (days - days[0]) * 86400.0 + (secs - secs[0])
    origin = ("date" if dated else "day", float(days[0] * 86400.0 + secs[0]) if dated else float(secs[0]))
    return absolute, origin


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


def _units_row(tab):
    """A second header row of units, as scope and trace exports write (``Time,X`` then ``s,mm``):
    taken as the units of the columns whose header has none, and removed from the data.  Only
    when every non-empty cell of the first row is a known unit (one of them the time column's),
    so a row of numbers or a stray word is never taken for units."""
    from dataclasses import replace
    if len(tab.rows) < 3:
        return tab
    first = [c.strip().strip("[]()").strip() for c in tab.rows[0]]
    if not any(first) or any(c and _unit_of(c) is None and c.lower() not in _TIME_UNITS for c in first):
        return tab
    cols = tuple(c if c.unit or not first[c.index] else replace(c, unit=first[c.index])
                 for c in tab.columns)
    return replace(tab, columns=cols, rows=tab.rows[1:], lines=tab.lines[1:])


_TIME_UNITS = ("s", "ms", "us", "µs", "min", "h", "sec")


def read_table(path: str | Path, role: str = "file", units: dict | None = None,
               conditions=(), dt: float | None = None) -> Table:
    """Read one CSV file (header row; a time column; numbers) into a :class:`Table`.

    Read by the project's one table reader, `mtcomp.csvtable` (``#`` comments, ``,`` or else
    ``;`` or tab separators, a decimal comma in ``;``/tab files, units in headers).  `units`
    maps column names to units for columns whose header carries none (the --unit option).
    Missing cells (empty, ``NaN``, ``NA``) are allowed in every column but time and reported;
    time may be seconds (any time unit in its header) or ISO 8601 time stamps.  Raises
    InputError naming the file, line and column for a missing time column, a bad number, an
    absurd magnitude, a time that goes back, or an unknown unit on the time column.
    `conditions` (`mtcomp.diagnose.rows`) mark the rows the row filter removes; a column they
    name may hold text (it then serves the filter only).  An unnamed first column is a row
    index (pandas writes one): it is not a signal and is left out.  dt: the logging period in s
    of a file without a time column (rows equally spaced; time = row index x dt, from the row
    index column when there is one, so rows removed before keep their instants); with a time
    column it is not used.
    """
    tab = _units_row(read_csv(path, what=role, delimiter=None, decimal=None, index_name=_INDEX))
    index = _INDEX if tab.columns and tab.columns[0].name == _INDEX and not tab.columns[0].header.strip() \
        else None
    names = [n for n in tab.names if n != index]
    tkey = _time_key(names)
    if tkey is None and index is not None and len(tab) and ":" in tab.rows[0][0]:
        tkey, index = index, None   # an index of time stamps (a logger's or pandas' DatetimeIndex)
    if tkey is None and dt is None:
        raise InputError("no time column `t` (expected a header like `t,x,y,...` with t in s; for "
                         "rows logged at a fixed period without a time column, give the period: "
                         "--dt 0.1 for 10 Hz)", tab.source, tab.header_line, field="t")
    if len(tab) < 2:
        raise InputError("fewer than two data rows", tab.source)
    notes = []
    origin = None
    if tkey is None:
        if not (np.isfinite(dt) and dt > 0):
            raise InputError(f"the logging period must be a positive number of s, got {dt!r}", field="--dt")
        k = np.arange(len(tab), dtype=float)
        src = "row number"
        if index is not None:
            try:
                ix = tab.numbers(index)
            except InputError:
                ix = None   # an index of labels: the rows are counted
            if ix is not None and np.all(ix == np.round(ix)) and np.all(np.diff(ix) > 0):
                k, src = ix - ix[0], "row index column"
        t, tkey = k * dt, "t"
        notes.append(f"{Path(tab.source).name} has no time column: t = {src} x {dt:g} s (--dt)")
        cols = [("t", "t", None)]
    else:
        if dt is not None:
            notes.append(f"--dt not used for {Path(tab.source).name}: it has a time column")
        tc = tab.col(tkey)
        cells = [r[tc.index] for r in tab.rows]
        if cells and ":" in cells[0]:
            t, origin = _time_stamps(cells, tab.source, tab.lines, tc.header)
            tunit = None
        else:
            # loggers count Unix time in ms or us (1.7e12 ms): the bound on a reading does not
            # apply before the unit is known; the time in s is checked against it below
            t = tab.numbers(tkey, max_abs=1e19)
            tunit = tc.unit
        cols = [(tc.header, tkey, tunit)]
    data = [t]
    named = {(c.name, c.header): [r[c.index] for r in tab.rows] for c in tab.columns
             if any(_rows.matches(k, c.name, c.header) for k in conditions)}
    excluded, used = _rows.excluded(conditions, named, MISSING)
    text_notes = []
    for c in tab.columns:
        if c.name == tkey or c.name == index:
            continue
        if (c.name, c.header) in named and _rows.is_text(named[(c.name, c.header)], MISSING):
            # a text column (a phase, a tool state) can only serve the row filter
            text_notes.append(f"column {c.name!r} of {Path(tab.source).name} holds text: it serves "
                              "the row filter only")
            continue
        if _all_text(r[c.index] for r in tab.rows):
            # a column of labels (a phase, a tool state, a program name) is no signal; a column
            # of numbers with a bad cell stays an error below
            text_notes.append(f"column {c.name!r} of {Path(tab.source).name} holds text, not numbers: "
                              "left out (--where can still filter rows by it)")
            continue
        cols.append((c.header, c.name, c.unit))
        data.append(tab.numbers(c.name, empty=np.nan, missing=MISSING))
    out = _from_matrix(tab.source, cols, np.column_stack(data), list(tab.lines), tab.header_line,
                       units, origin=origin, excluded=excluded)
    return replace(out, notes=tuple(notes) + tuple(text_notes) + out.notes, row_filter=tuple(used))


def _all_text(cells) -> bool:
    """Every present cell of a column is a word, not a number (a column of labels).  Lazy: a
    column of numbers is settled by its first present cell."""
    seen = False
    for c in cells:
        if c.strip() and c.strip() not in MISSING:
            if not _rows.is_text([c], MISSING):
                return False
            seen = True
    return seen


def _fill_missing(t: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, int]:
    """Missing values filled linearly between the neighbours present (held at the ends), and
    the longest run of missing rows."""
    bad = ~np.isfinite(v)
    if not bad.any():
        return v, 0
    ok = ~bad
    out = v.copy()
    out[bad] = np.interp(t[bad], t[ok], v[ok])
    edges = np.diff(np.concatenate([[0], bad.astype(np.int8), [0]]))
    runs = np.flatnonzero(edges == -1) - np.flatnonzero(edges == 1)
    return out, int(runs.max())


def _from_matrix(label: str, cols, data: np.ndarray, linenos, hline: int | None,
                 units: dict | None = None, origin: tuple | None = None,
                 excluded: np.ndarray | None = None) -> Table:
    """Checks and unit conversion shared by files and in-memory arrays (NaN: a missing value)."""
    path = label
    units = dict(units or {})
    inf = np.isinf(data)
    if inf.any():
        r, c = np.argwhere(inf)[0]
        raise InputError(f"value is {data[r, c]} (expected a finite number)", path,
                         linenos[r] if linenos else None, field=cols[c][0])
    columns = {}
    notes = []
    tkey = _time_key([c[1] for c in cols])
    jt = [c[1] for c in cols].index(tkey)
    hdr_t, _, unit_t = cols[jt]
    if origin is None:
        if not unit_t and units and tkey in units:
            unit_t = units[tkey]
        if not unit_t:
            unit_t = name_unit(tkey)
        ut = _unit_of(unit_t) if unit_t else ("time", 1.0, 0.0)
        if ut is None or ut[0] != "time":
            raise InputError(f"unit {unit_t!r} of {tkey} is not a time unit (s, ms, us, min)",
                             path, hline, field=hdr_t)
        t = data[:, jt] * ut[1]
    else:
        t = data[:, jt]
    if np.isnan(t).any():
        r = int(np.argmax(np.isnan(t)))
        raise InputError("the time is missing (expected a number on every row)", path,
                         linenos[r] if linenos else None, field=hdr_t)
    for j, (hdr, key, unit) in enumerate(cols):
        if j == jt:
            continue
        raw = data[:, j]
        src = "unit"
        if unit is None and key in units:
            unit, src = units[key], "option"
        elif unit is None and name_unit(key):
            # `pos_um`, `angle_arcmin`: a unit written as the last word of the name
            unit, src = name_unit(key), "unit"
        if unit is not None and unit.strip().lower() in COUNTS:
            raise InputError(f"unit {unit!r} of column {key!r}: a count needs its size; give the "
                             f"resolution as the unit, e.g. {key}[0.1um] in the header or --unit "
                             f"{key}=0.0001mm", path, hline if src == "unit" else None,
                             field=hdr if src == "unit" else f"--unit {key}")
            if _unit_of(unit) is None and unit not in ("", "-", "1"):
                raise InputError(f"unknown unit {unit!r} given for column {key!r} (expected one of "
                                 "mm, um, nm, in, deg, rad, mm/s, deg/s, mm/s^2, degC, rpm, or a "
                                 "resolution like 0.5um for counts)", field=f"--unit {key}")
        if unit:
            u = _unit_of(unit)
            kind, fac, off = u if u is not None else (None, 1.0, 0.0)
        else:
            kind, fac, off = kind_from_name(key), 1.0, 0.0
            src = "name"
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
        q = max(_quantum(raw), _decimal_resolution(raw)) if np.isfinite(raw).all() else \
            max(_quantum(raw[np.isfinite(raw)]), _decimal_resolution(raw[np.isfinite(raw)]))
        present = None
        miss = np.isnan(v)
        if miss.any():
            n_ok = int((~miss).sum())
            if n_ok < max(2, MIN_PRESENT * len(v)):
                notes.append(f"column {key!r} of {Path(path).name} is left out: only {n_ok} of "
                             f"{len(v)} rows hold a value")
                continue
            present = ~miss
            first = int(np.argmax(miss))
            where = f" (first on line {linenos[first]})" if linenos else ""
            v, run = _fill_missing(t, v)
            notes.append(f"column {key!r} of {Path(path).name}: {int(miss.sum())} missing values{where}, "
                         f"longest run {run} rows; as an output, rows without a value take no part "
                         "in the fit; as an input, it is filled linearly between its neighbours")
        columns[key] = Column(key, hdr, kind, cunit, v, q * abs(fac), src, present)
    if np.any(np.abs(t) > MAX_ABS):
        r = int(np.argmax(np.abs(t) > MAX_ABS))
        raise InputError(f"time {t[r]:g} s is out of range (a count of ms or us since 1970 "
                         f"needs its unit in the header, e.g. {tkey}[ms])", path,
                         linenos[r] if linenos else None, field=tkey)
    dt = np.diff(t)
    if np.any(dt < 0):
        i = int(np.argmax(dt < 0))
        raise InputError(f"t must increase: {t[i + 1]:g} s follows {t[i]:g} s "
                         "(sort the rows)", path, linenos[i + 1] if linenos else None, field=tkey)
    if np.any(dt == 0):
        # a row written twice (the same stamp, the same values) is merged; a time stamp repeated
        # with other values is refused: which of the two is the reading at that time cannot be
        # known, and averaging them would make up a value no instrument read
        _refuse_repeated_stamps(t, columns, path, linenos, tkey)
        t0 = t
        t, columns, k = _merge_repeated(t, columns)
        if excluded is not None:
            # a time stamp is set aside when any of its rows is
            _, inv = np.unique(t0, return_inverse=True)
            excluded = np.bincount(inv, weights=excluded.astype(float), minlength=len(t)) > 0
        first = int(np.argmax(dt == 0)) + 1
        where = f" (first on line {linenos[first]})" if linenos else ""
        notes.append(f"{k} rows of {Path(path).name} repeat the time stamp and the values of the "
                     f"row before{where}: each written twice, kept once")
        if len(t) < 2:
            raise InputError("fewer than two distinct times", path, field=tkey)
    if excluded is not None and not excluded.any():
        excluded = None
    return Table(str(path), t, columns, origin, tuple(notes), excluded)


# units that count increments of an unknown size
COUNTS = ("counts", "count", "cnt", "cts", "inc", "incs", "increments", "ticks", "steps")
# units written as the last word of a column name (`pos_um`, `angle_arcmin`, `t_ms`); `_in`
# and `_s` are not among them: they mean "input" and "spindle" as often as inch and second
_NAME_UNITS = ("um", "µm", "nm", "mm", "deg", "rad", "mrad", "urad", "arcmin", "arcsec", "degc",
               "ms", "us", "mm/s", "mm_s", "um_s", "deg_s")
_NAME_UNIT = re.compile(r"^.+?[_\-](?P<u>" + "|".join(re.escape(u) for u in _NAME_UNITS) + r")$",
                        re.IGNORECASE)


def name_unit(key: str) -> str | None:
    """The unit a column's name ends in (``pos_um`` -> 'um', ``t_ms`` -> 'ms'), or None."""
    m = _NAME_UNIT.match(key)
    if not m:
        return None
    u = m.group("u").lower()
    return u.replace("_s", "/s") if u.endswith("_s") else u


def _refuse_repeated_stamps(t: np.ndarray, columns: dict, path, linenos, tkey) -> None:
    """InputError naming the first line that repeats the time stamp of the line before with
    other values in some column."""
    for i in np.flatnonzero(np.diff(t) == 0):
        for k, c in columns.items():
            a, b = c.values[i], c.values[i + 1]
            if not (a == b or (np.isnan(a) and np.isnan(b))):
                line = linenos[i + 1] if linenos else None
                prev = f"line {linenos[i]}" if linenos else "the row before"
                raise InputError(f"time {t[i + 1]:g} s repeats the time stamp of {prev} with "
                                 f"another value of {k!r} ({b:g} after {a:g}): t must increase "
                                 "strictly (each reading at its own time)", path, line, field=tkey)


def _merge_repeated(t: np.ndarray, columns: dict):
    """Average the rows that share a time stamp: (unique t, columns, rows merged)."""
    ut, inv, cnt = np.unique(t, return_inverse=True, return_counts=True)
    out = {}
    for k, c in columns.items():
        w = np.ones(len(t)) if c.present is None else c.present.astype(float)
        s = np.bincount(inv, weights=c.values * w, minlength=len(ut))
        n = np.bincount(inv, weights=w, minlength=len(ut))
        pres = n > 0
        v = np.where(pres, s / np.maximum(n, 1), np.nan)
        if not pres.all():
            v, _ = _fill_missing(ut, v)
        out[k] = Column(c.key, c.header, c.kind, c.unit, v, c.quantum, c.kind_from,
                        None if pres.all() else pres)
    return ut, out, int(len(t) - len(ut))


def table_from_arrays(data, name: str = "arrays", units: dict | None = None,
                      conditions=()) -> Table:
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
    mat = np.column_stack(list(items.values()))
    named = {(c[1], c[0]): mat[:, j] for j, c in enumerate(cols)
             if any(_rows.matches(k, c[1], c[0]) for k in conditions)}
    excluded, used = _rows.excluded(conditions, named)
    return replace(_from_matrix(name, cols, mat, None, None, units, excluded=excluded),
                   row_filter=tuple(used))


def load(source, role: str, units: dict | None = None, conditions=(), dt: float | None = None) -> Table:
    """Accept a path, a Table, or a mapping of arrays (e.g. a dict or a DataFrame).
    `conditions`: the row filter (`mtcomp.diagnose.rows`), applied to paths and arrays.
    dt: the logging period of a file without a time column (`read_table`)."""
    if isinstance(source, Table):
        return source
    if isinstance(source, (str, Path)):
        return read_table(source, role, units, conditions, dt)
    if hasattr(source, "to_dict") and hasattr(source, "columns"):  # DataFrame-like
        source = {c: np.asarray(source[c]) for c in source.columns}
    return table_from_arrays(source, role, units, conditions)


def common_clock(sim: Table, rec: Table) -> tuple[Table, Table, tuple]:
    """SIM and REC on one clock when their times came from time stamps of the same form (REC
    moved by the difference of their origins); otherwise unchanged, with a note when only one
    file has time stamps (its times then count from its first row)."""
    if sim.origin and rec.origin and sim.origin[0] == rec.origin[0]:
        d = rec.origin[1] - sim.origin[1]
        return sim, replace(rec, t=rec.t + d, origin=sim.origin), (
            f"time stamps of both files read on one clock (REC starts {d:+.6g} s after SIM)",)
    for tab, role in ((sim, "SIM"), (rec, "REC")):
        if tab.origin:
            return sim, rec, (f"{role}'s time stamps are counted from its first row (the other file "
                              "has times in s): the clock offset is left to the alignment",)
    return sim, rec, ()


def split_log(tab: Table, outputs=None, inputs=None) -> tuple[Table, Table, tuple]:
    """SIM and REC from one log holding both the commanded and the measured signals (SIM and REC
    given as the same file).  SIM keeps the columns whose name says command (``X_cmd``,
    ``X1_CommandVelocity``, ``Soll_X``), the SIM side of ``--output SIMCOL=RECCOL`` pairs and the
    ``--input`` columns; REC the columns whose name says measurement (``X_act``, ``Ist_X``,
    ``..._ActualVelocity``) and the REC side of the pairs.  A column whose name says neither
    (a drive current, a bus voltage) is left out: as an input it would explain the
    measurement by another measurement of the same motion.  Returns SIM, REC, notes."""
    sim_keep, rec_keep = set(inputs or ()), set()
    for o in outputs or ():
        if "=" in o:
            a, b = (x.strip() for x in o.split("=", 1))
            sim_keep.add(a)
            rec_keep.add(b)
    sim_cols, rec_cols, left = {}, {}, []
    for k, c in tab.columns.items():
        r = role(k)
        if k in rec_keep or (r == "measured" and k not in sim_keep):
            rec_cols[k] = c
        elif k in sim_keep or r == "command":
            sim_cols[k] = c
        else:
            left.append(k)
    if not rec_cols or not sim_cols:
        raise InputError("SIM and REC are one file, but its column names do not say which "
                         "signals were commanded and which measured: pair them, e.g. --output "
                         "X_cmd=X_act", tab.path, field="--output")
    notes = [f"one log for SIM and REC ({Path(tab.path).name}): commanded {', '.join(sim_cols)}; "
             f"measured {', '.join(rec_cols)}; both on one clock"]
    if left:
        notes.append(f"left out (their names say neither command nor measurement; --input COL "
                     f"uses one as an input): {', '.join(left)}")
    return (replace(tab, columns=sim_cols), replace(tab, columns=rec_cols, notes=()),
            tuple(notes))


def compared_only(rec: Table, outputs) -> tuple[Table, tuple]:
    """REC of one log (`split_log`) after the pairing (`pair_columns`): the columns compared
    only.  A measured column compared with nothing would be an input, and another measurement of
    the same motion explains a residual without naming a cause."""
    left = [k for k in rec.columns if k not in outputs]
    if not left:
        return rec, ()
    if len(left) == len(rec.columns):
        raise InputError("SIM and REC are one file, but no measured column pairs with a commanded "
                         "one by name: pair them, e.g. --output X_cmd=X_act", rec.path, field="--output")
    return (replace(rec, columns={k: c for k, c in rec.columns.items() if k not in left}),
            (f"left out (measurements with no command to compare with; --input COL uses one as an "
             f"input): {', '.join(left)}",))


def pair_columns(sim: Table, rec: Table, outputs=None) -> tuple[Table, list | None, tuple]:
    """Pairs of a SIM column and REC columns under other names, as outputs.

    `outputs` entries ``SIMCOL=RECCOL`` compare REC's RECCOL with SIM's SIMCOL (the output is
    named RECCOL; several REC columns may pair with one SIM column, e.g. a motor encoder and a
    linear scale).  Without `outputs`, a SIM column of a motion kind that REC does not have is
    paired with the REC columns of the same kind whose name differs only by role words
    (``X_cmd`` with ``X_act``, ``Soll_X`` with ``Ist_X``); every pairing is said in the notes.
    Returns SIM with a copy of the SIM column under each REC name, the output names, notes.
    """
    pairs = []
    plain = None
    if outputs:
        plain = []
        for o in outputs:
            if "=" in o:
                s, r = (x.strip() for x in o.split("=", 1))
                if s not in sim.columns:
                    raise InputError(f"--output {o!r}: SIM has no column {s!r} (it has "
                                     f"{', '.join(sim.columns)})", field="--output")
                if r not in rec.columns:
                    raise InputError(f"--output {o!r}: REC has no column {r!r} (it has "
                                     f"{', '.join(rec.columns)})", field="--output")
                pairs.append((s, r, "option"))
                plain.append(r)
            else:
                plain.append(o)
    else:
        rec_only = [k for k in rec.columns if k not in sim.columns]
        for s, cs in sim.columns.items():
            if s in rec.columns or cs.kind not in MOTION_KINDS + ("other",):
                continue
            st = stem(s)
            if not st:
                continue
            hits = [r for r in rec_only if stem(r) == st and rec.columns[r].kind == cs.kind]
            for r in hits:
                # a REC column that matches two SIM columns is left alone (ambiguous)
                if sum(stem(k) == st and c.kind == cs.kind for k, c in sim.columns.items()
                       if k not in rec.columns) == 1:
                    pairs.append((s, r, "name"))
    if not pairs:
        return sim, plain, ()
    cols = dict(sim.columns)
    notes = []
    for s, r, how in pairs:
        if r in sim.columns:
            raise InputError(f"--output {s}={r}: SIM has a column {r!r} already", field="--output")
        c = sim.columns[s]
        cols[r] = Column(r, c.header, c.kind, c.unit, c.values, c.quantum, c.kind_from, c.present)
        notes.append(f"REC's {r!r} is compared with SIM's {s!r}"
                     + (" (their names differ only by words of role: give --output "
                        f"{s}={r} to choose pairs yourself)" if how == "name" else ""))
    for s in {p[0] for p in pairs}:
        cols.pop(s, None)  # the SIM column lives on as the paired outputs
    return replace(sim, columns=cols), plain, tuple(notes)
