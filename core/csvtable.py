"""The one reader of mtcomp's CSV table files (format: docs/csv-format.md).

Every table format (error tables, measurement sheets, probe touches, positioning runs,
recordings) is a header row and data rows, read here on the standard `csv` module:

* lines whose first non-blank character is ``#`` are comments, blank lines are skipped;
  comment lines before the header are kept (`CsvTable.comments`);
* the header names the columns; a name may carry a unit, ``EXX [um]`` or ``EXX (um)``;
* every row has as many cells as the header (or fewer, padded with empty cells, when the
  format allows it); a quoted cell may not span lines;
* numbers are plain decimal numbers (``-1.5``, ``2e-6``): no ``nan``, ``inf``, ``1_000``,
  hex or non-ASCII digits; finite and within a magnitude limit; converted from the header's
  unit to the unit the caller asks for;
* every error is an `InputError` naming the file, the line and the column.

The csv module splits cells (quotes, delimiters); what it does not do, and is written here, is
line numbers across skipped comment lines, units, and strict number checks.
"""
from __future__ import annotations

import csv
import math
import os
import re
from dataclasses import dataclass

import numpy as np

from ._io import InputError, read_text

# unit -> (quantity, factor, offset): value in the quantity's base unit = value * factor + offset.
# Base units: mm, rad (angles; deg is converted like any other unit), s, degC, rpm.
UNITS: dict[str, tuple[str, float, float]] = {
    "mm": ("length", 1.0, 0.0), "m": ("length", 1e3, 0.0), "cm": ("length", 10.0, 0.0),
    "um": ("length", 1e-3, 0.0), "µm": ("length", 1e-3, 0.0), "μm": ("length", 1e-3, 0.0),
    "micron": ("length", 1e-3, 0.0), "nm": ("length", 1e-6, 0.0), "in": ("length", 25.4, 0.0),
    "rad": ("angle", 1.0, 0.0), "mrad": ("angle", 1e-3, 0.0), "urad": ("angle", 1e-6, 0.0),
    "µrad": ("angle", 1e-6, 0.0), "μrad": ("angle", 1e-6, 0.0), "deg": ("angle", math.pi / 180, 0.0),
    "°": ("angle", math.pi / 180, 0.0), "arcmin": ("angle", math.pi / 10800, 0.0),
    "arcsec": ("angle", math.pi / 648000, 0.0),
    "s": ("time", 1.0, 0.0), "ms": ("time", 1e-3, 0.0), "us": ("time", 1e-6, 0.0),
    "µs": ("time", 1e-6, 0.0), "min": ("time", 60.0, 0.0),
    "degc": ("temperature", 1.0, 0.0), "°c": ("temperature", 1.0, 0.0), "k": ("temperature", 1.0, -273.15),
    "rpm": ("speed", 1.0, 0.0), "1/min": ("speed", 1.0, 0.0), "hz": ("speed", 60.0, 0.0),
}

# Default magnitude limit of a number cell (in the caller's unit): beyond any machine, and far
# enough below float overflow that sums, squares and least squares stay finite.
MAX_ABS = 1e12

# ASCII digits only.  Unambiguous on purpose (a digit run cannot be split two ways): the whole
# column is matched by one expression, and an ambiguous one backtracks exponentially.
_NUMBER = r"[+-]?(?:[0-9]+(?:\.[0-9]*)?|\.[0-9]+)(?:[eE][+-]?[0-9]+)?"
_NUMBER_RE = re.compile(_NUMBER)
_SPACE_RE = re.compile(r"\s")  # the characters str.strip() removes
# the characters of a plain decimal number: a column made of these only, which float() accepts
# cell by cell, follows _NUMBER (float() alone would also take nan, inf, 1_000, other digits)
_NUMBER_CHARS = str.maketrans("", "", "0123456789.eE+-")
_DECIMAL_COMMA_RE = re.compile(r"[+-]?[0-9]+,[0-9]+(?:[eE][+-]?[0-9]+)?")
_HEADER_RE = re.compile(r"^(?P<name>[^\[\(]*?)\s*(?:[\[\(]\s*(?P<unit>[^\]\)]*?)\s*[\]\)])?$")


def unit_factor(unit: str | None, to: str | None, *, source=None, line=None, column=None) -> tuple[float, float]:
    """(factor, offset) turning values in `unit` into `to` (None or "" on either side: no
    conversion).  Units of different quantities are an InputError."""
    if not unit or not to or unit.lower() == to.lower():
        return 1.0, 0.0
    a, b = UNITS.get(unit.lower()) or UNITS.get(unit), UNITS.get(to.lower()) or UNITS.get(to)
    if a is None:
        raise InputError(f"unknown unit {unit!r}; expected {to} or a unit convertible to it "
                         f"({', '.join(u for u, q in UNITS.items() if b and q[0] == b[0])})",
                         source, line, column)
    if b is None or a[0] != b[0]:
        raise InputError(f"unit {unit!r} is not a unit of {b[0] if b else repr(to)}; expected {to}",
                         source, line, column)
    # v_to = ((v * fa + oa) - ob) / fb
    return a[1] / b[1], (a[2] - b[2]) / b[1]


@dataclass(frozen=True)
class Column:
    """One header cell: name as written (without unit), its unit (None if none), position."""
    name: str
    unit: str | None
    index: int
    header: str


@dataclass(frozen=True)
class CsvTable:
    """The cells of a CSV table file, with the line number of every row.

    rows[i] are the stripped cells of data row i (as many as there are columns), written on
    line lines[i] of `source`.  Use `number`, `integer`, `cell` and `numbers` to read cells:
    they check and name the file, line and column of any bad cell."""
    source: str
    header_line: int
    columns: tuple[Column, ...]
    rows: tuple[tuple[str, ...], ...]
    lines: tuple[int, ...]
    comments: tuple[str, ...] = ()
    case_sensitive: bool = True
    decimal: str = "."  # "," for files written with a decimal comma (``;`` or tab separated)

    def __len__(self) -> int:
        return len(self.rows)

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(c.name for c in self.columns)

    def _key(self, name: str) -> str:
        return name if self.case_sensitive else name.lower()

    def has(self, name: str) -> bool:
        return any(self._key(c.name) == self._key(name) for c in self.columns)

    def col(self, name: str) -> Column:
        for c in self.columns:
            if self._key(c.name) == self._key(name):
                return c
        raise InputError(f"no column {name!r} (columns: {', '.join(self.names)})", self.source, self.header_line)

    def error(self, what: str, row: int | None = None, name: str | None = None) -> InputError:
        """An InputError at data row `row` (0-based; None: the header) and column `name`."""
        line = self.header_line if row is None else self.lines[row]
        return InputError(what, self.source, line, name)

    def cell(self, row: int, name: str) -> str:
        return self.rows[row][self.col(name).index]

    def number(self, row: int, name: str, *, unit: str | None = None, lo: float | None = None,
               hi: float | None = None, max_abs: float = MAX_ABS, empty: float | None = None) -> float:
        """The number in one cell, in `unit` (converted from the header's unit), finite, with
        |x| <= max_abs and within [lo, hi].  An empty cell gives `empty`, or is an error when
        `empty` is None."""
        c = self.col(name)
        s = self.rows[row][c.index]
        if s == "" and empty is not None:
            return empty
        x = _parse_number(s.replace(",", ".") if self.decimal == "," else s, self.source,
                          self.lines[row], c.header)
        fac, off = unit_factor(c.unit, unit, source=self.source, line=self.header_line, column=c.header)
        x = x * fac + off
        _check_range(x, s, lo, hi, max_abs, unit, self.source, self.lines[row], c.header)
        return x

    def integer(self, row: int, name: str, *, lo: int | None = None, hi: int | None = None) -> int:
        """The integer in one cell (digits with an optional sign), within [lo, hi]."""
        c = self.col(name)
        s = self.rows[row][c.index]
        if not re.fullmatch(r"[+-]?[0-9]{1,18}", s):
            raise InputError(f"expected an integer, got {_show(s)}", self.source, self.lines[row], c.header)
        v = int(s)
        if (lo is not None and v < lo) or (hi is not None and v > hi):
            rng = f"[{'' if lo is None else lo}, {'' if hi is None else hi}]"
            raise InputError(f"expected an integer in {rng}, got {v}", self.source, self.lines[row], c.header)
        return v

    def numbers(self, name: str, *, unit: str | None = None, lo: float | None = None, hi: float | None = None,
                max_abs: float = MAX_ABS, empty: float | None = None, missing: tuple = ("",)) -> np.ndarray:
        """A whole column as a float array, checked like `number` (one regular-expression pass
        over the column; the first bad cell is named).  With `empty` given, the cells in
        `missing` (default: empty cells only) read as `empty`."""
        c = self.col(name)
        cells = [r[c.index] for r in self.rows]
        if self.decimal == ",":
            cells = [s.replace(",", ".") for s in cells]
        if empty is not None and set(missing).isdisjoint(cells):
            empty = None  # no cell to fill: the plain path
        if empty is not None:
            miss = set(missing)
            blank = [s in miss for s in cells]
            cells = ["0" if b else s for s, b in zip(cells, blank)]
        x = None
        if cells and not "".join(cells).translate(_NUMBER_CHARS) and all(cells):
            try:
                x = np.array(cells, dtype=float)
            except ValueError:
                x = None  # a malformed number ("1e", "."): named below
        if x is None:
            if cells and not re.fullmatch(rf"(?:{_NUMBER}\n)*{_NUMBER}", "\n".join(cells)):
                for i, s in enumerate(cells):
                    _parse_number(s, self.source, self.lines[i], c.header)
            x = np.array(cells, dtype=float) if cells else np.zeros(0)
        fac, off = unit_factor(c.unit, unit, source=self.source, line=self.header_line, column=c.header)
        if fac != 1.0 or off != 0.0:
            x = x * fac + off
        bad = ~np.isfinite(x) | (np.abs(x) > max_abs)
        if lo is not None:
            bad |= x < lo
        if hi is not None:
            bad |= x > hi
        if empty is not None:
            bad &= ~np.array(blank, dtype=bool)
            x[np.array(blank, dtype=bool)] = empty
        if bad.any():
            i = int(np.argmax(bad))
            _check_range(float(x[i]), cells[i], lo, hi, max_abs, unit, self.source, self.lines[i], c.header)
        return x


def _show(s: str) -> str:
    return repr(s) if len(s) <= 40 else repr(s[:37] + "...")


def _parse_number(s: str, source, line, column) -> float:
    if not _NUMBER_RE.fullmatch(s):
        what = "an empty cell" if s == "" else _show(s)
        raise InputError(f"expected a number, got {what}", source, line, column)
    x = float(s)
    if not math.isfinite(x):
        raise InputError(f"{_show(s)} is out of range: expected a finite number", source, line, column)
    return x


def _check_range(x, s, lo, hi, max_abs, unit, source, line, column):
    u = f" {unit}" if unit else ""
    if not math.isfinite(x) or abs(x) > max_abs:
        raise InputError(f"{_show(s)} is out of range: expected |x| <= {max_abs:g}{u}", source, line, column)
    if lo is not None and x < lo:
        raise InputError(f"{_show(s)}: expected a value >= {lo:g}{u}", source, line, column)
    if hi is not None and x > hi:
        raise InputError(f"{_show(s)}: expected a value <= {hi:g}{u}", source, line, column)


def parse_csv(text: str, source: str | os.PathLike = "<string>", *, required=(), allowed=None,
              case_sensitive: bool = True, delimiter: str | None = ",", pad: bool = False,
              min_rows: int = 0, what: str = "table", decimal: str | None = ".",
              index_name: str | None = None) -> CsvTable:
    """Split CSV text into a checked `CsvTable`.

    required: column names that must be present; allowed: the only names accepted (None: any).
    case_sensitive=False matches names (and reports duplicates) ignoring case.  delimiter=None
    takes ``,`` or else ``;`` or a tab, whichever the header line contains.  pad=True accepts
    rows shorter than the header (missing cells are empty).  min_rows: fewest data rows.
    decimal: "." or ","; None takes "," when the separator is not a comma and a data cell of
    the first rows is a number written with a decimal comma (``1,5``; spreadsheets of many
    locales), else ".".  Numbers never have thousands separators.  index_name: the name given
    to an unnamed FIRST column (the row index that pandas' ``to_csv`` and many loggers write
    with an empty header cell); None: an unnamed column is an error, as every other one."""
    source = str(source)
    lines = text.replace("\r\n", "\n").replace("\r", "\n").split("\n")
    comments: list[str] = []
    body: list[tuple[int, str]] = []
    for n, ln in enumerate(lines, 1):
        s = ln.strip()
        if not s:
            continue
        if s.startswith("#"):
            if not body:
                comments.append(s[1:].strip())
            continue
        body.append((n, ln))
    if not body:
        raise InputError(f"empty {what}: expected a header row and data rows", source)
    hline, htext = body[0]
    if delimiter is None:
        delimiter = "," if "," in htext else (";" if ";" in htext else ("\t" if "\t" in htext else ","))

    def records():
        reader = csv.reader((ln for _, ln in body), delimiter=delimiter, strict=True)
        k = 0
        while True:
            try:
                cells = next(reader)
            except StopIteration:
                return
            except csv.Error as exc:
                raise InputError(f"malformed CSV: {exc}", source, body[min(k, len(body) - 1)][0]) from None
            if reader.line_num != k + 1:  # a quoted cell ran over the end of its line
                raise InputError("a quoted cell runs over the end of the line", source, body[k][0])
            # most lines have no blank to strip (a scan in C instead of a strip per cell)
            yield body[k][0], ([c.strip() for c in cells] if _SPACE_RE.search(body[k][1]) else cells)
            k += 1

    recs = records()
    _, hcells = next(recs)
    columns = []
    seen: dict[str, int] = {}
    for i, h in enumerate(hcells):
        m = _HEADER_RE.match(h)
        name = m.group("name").strip() if m else ""
        if not name and i == 0 and index_name is not None and not h.strip():
            name = index_name
            while name in (c.strip() for c in hcells[1:]):
                name += "_"
        if not name:
            raise InputError(f"column {i + 1} of the header has no name (got {_show(h)})", source, hline)
        key = name if case_sensitive else name.lower()
        if key in seen:
            raise InputError(f"column {name!r} appears twice (columns {seen[key] + 1} and {i + 1})",
                             source, hline, name)
        seen[key] = i
        unit = m.group("unit")
        columns.append(Column(name, unit.strip() if unit is not None else None, i, h))
    fold = (lambda s: s) if case_sensitive else str.lower
    names = {fold(c.name) for c in columns}
    missing = [r for r in required if fold(r) not in names]
    if missing:
        raise InputError(f"missing column(s) {', '.join(missing)}; the header must name "
                         f"{', '.join(required)}", source, hline)
    if allowed is not None:
        ok = {fold(a) for a in allowed}
        for c in columns:
            if fold(c.name) not in ok:
                raise InputError(f"unknown column {c.name!r}; expected some of {', '.join(allowed)}",
                                 source, hline, c.header)
    n = len(columns)
    rows, linenos = [], []
    for lineno, cells in recs:
        if len(cells) != n:
            if pad and len(cells) < n:
                cells = cells + [""] * (n - len(cells))
            else:
                raise InputError(f"expected {n} values (one per column), got {len(cells)}", source, lineno)
        rows.append(tuple(cells))
        linenos.append(lineno)
    if len(rows) < min_rows:
        raise InputError(f"expected at least {min_rows} data rows, got {len(rows)}", source)
    if decimal is None:
        decimal = "."
        if delimiter != ",":
            decimal = "," if any(_DECIMAL_COMMA_RE.fullmatch(c) for r in rows[:50] for c in r) else "."
    if decimal not in (".", ","):
        raise ValueError(f"decimal must be '.' or ',', got {decimal!r}")
    if decimal == "," and delimiter == ",":
        raise ValueError("a decimal comma needs another separator than ','")
    return CsvTable(source, hline, tuple(columns), tuple(rows), tuple(linenos), tuple(comments),
                    case_sensitive, decimal)


def read_csv(path: str | os.PathLike, *, what: str = "table", max_bytes: int | None = None, **kw) -> CsvTable:
    """Read a CSV table file (UTF-8, a byte-order mark is dropped); options as `parse_csv`.
    A missing, binary or device file is an InputError too."""
    text = read_text(path, what=f"{what} file", encoding="utf-8-sig", max_bytes=max_bytes)
    return parse_csv(text, path, what=what, **kw)
