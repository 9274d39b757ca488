"""Row filter of a diagnosis: rows of a log that do not reflect the machine are set aside.

Loggers write rows that are not measurements of the machine: a default feed rate while no
program runs, a parked axis' home position written as a placeholder, a "Prep" phase.  An
engineer knows the rule (the logger's documentation says it) and gives it as conditions:

- ``--where 'COL OP VALUE'`` keeps only the rows where the condition holds;
- ``--exclude-rows 'COL OP VALUE'`` removes the rows where it holds.

OP is one of ``==`` (also ``=``), ``!=``, ``<``, ``<=``, ``>``, ``>=``; VALUE a number, or a
text (quoted, or any word that is not a number) compared with ``==``/``!=`` only.  COL is a
column of either file, by its name as written (with or without its header unit); a column in
both files is tested in each.  Numbers are compared as written in the file (before any unit
conversion).  A row is kept when every ``--where`` holds and no ``--exclude-rows`` does; a row
with no value in the column (empty cell) fails a ``--where`` and passes an ``--exclude-rows``.

The rows removed are not deleted and nothing is interpolated across them: the grid samples
that fall on them, or between a removed row and its neighbour, take no part in the fit, the
held-out RMS, the noise floor or the RMS (as for the gaps of a logger, `align`).
Hand-written: a six-operator comparison grammar is smaller than any expression library and
cannot run code.
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass

import numpy as np

from .._io import InputError

_COND = re.compile(r"^\s*(?P<col>[^=!<>]+?)\s*(?P<op>==|!=|<=|>=|<|>|=)\s*(?P<val>.*?)\s*$")


@dataclass(frozen=True)
class Condition:
    """One row condition: `keep` True for --where (keep rows where it holds), False for
    --exclude-rows (remove rows where it holds)."""
    column: str
    op: str
    value: float | str
    keep: bool
    text: str          # as the user wrote it

    @property
    def option(self) -> str:
        return "--where" if self.keep else "--exclude-rows"

    def describe(self) -> str:
        return f"{self.option} {self.text!r}"


def parse(where=None, exclude=None) -> tuple[Condition, ...]:
    """Conditions from the option strings (InputError naming the option for a bad one)."""
    out = []
    for items, keep in ((where, True), (exclude, False)):
        for s in items or ():
            opt = "--where" if keep else "--exclude-rows"
            m = _COND.match(str(s))
            if not m or not m.group("val"):
                raise InputError(f"{opt} {s!r}: expected COLUMN OP VALUE with OP one of ==, !=, <, "
                                 "<=, >, >= (e.g. 'FEEDRATE!=50' or 'phase==Prep')", field=opt)
            col, op, val = m.group("col").strip(), m.group("op"), m.group("val")
            op = "==" if op == "=" else op
            if len(val) >= 2 and val[0] == val[-1] and val[0] in "'\"":
                value: float | str = val[1:-1]
            else:
                try:
                    value = float(val)
                except ValueError:
                    value = val
                else:
                    if not math.isfinite(value):
                        raise InputError(f"{opt} {s!r}: the value must be a finite number or a "
                                         "text", field=opt)
            if isinstance(value, str) and op not in ("==", "!="):
                raise InputError(f"{opt} {s!r}: a text ({value!r}) is compared with == or != "
                                 "only", field=opt)
            out.append(Condition(col, op, value, keep, str(s).strip()))
    return tuple(out)


def matches(cond: Condition, key: str, header: str) -> bool:
    """Does the condition name this column (by its name, or its header with unit)?"""
    return cond.column in (key, header.strip())


def _number(cell: str) -> float:
    try:
        return float(cell.replace(",", ".")) if cell else math.nan
    except ValueError:
        return math.nan


def holds(cond: Condition, cells, missing=()) -> np.ndarray:
    """Per row: the condition holds (False where the cell is empty or missing).

    `cells` are the cells as written (strings) or numbers.  A text value is compared with the
    stripped cell; a number with the cell read as a number (a cell that is not a number fails
    `==` and `<`...; it passes `!=`)."""
    cells = list(cells)
    if cells and not isinstance(cells[0], str):
        nums = np.asarray(cells, float)
        strs = None
    else:
        strs = [c.strip() for c in cells]
        nums = np.array([math.nan if c in missing else _number(c) for c in strs])
    present = np.isfinite(nums) if strs is None else np.array([c not in missing for c in strs])
    text = strs is not None and is_text(strs, missing)
    if text and not isinstance(cond.value, str):
        raise InputError(f"{cond.describe()}: column {cond.column!r} holds text; expected a "
                         "text to compare with (== or !=)", field=cond.option)
    if isinstance(cond.value, str):
        if not text:
            raise InputError(f"{cond.describe()}: column {cond.column!r} holds numbers; "
                             "expected a number to compare with", field=cond.option)
        eq = np.array([c == cond.value for c in strs])
        res = eq if cond.op == "==" else ~eq
        return res & present
    v = cond.value
    with np.errstate(invalid="ignore"):
        res = {"==": nums == v, "!=": nums != v, "<": nums < v, "<=": nums <= v,
               ">": nums > v, ">=": nums >= v}[cond.op]
    return res & present


def is_text(cells, missing=()) -> bool:
    """A column of cells as written holds text (some present cell is not a number)."""
    for c in cells:
        c = c.strip()
        if c and c not in missing and not math.isfinite(_number(c)) and c.lower() not in ("nan", "inf", "-inf"):
            return True
    return False


def excluded(conds, columns: dict, missing=()) -> tuple[np.ndarray | None, set]:
    """Rows removed by the conditions that name a column of this file, and the conditions used.

    `columns` maps (key, header) -> cells of that column (strings or numbers)."""
    keep = None
    used = set()
    for c in conds:
        for (key, header), cells in columns.items():
            if not matches(c, key, header):
                continue
            h = holds(c, cells, missing)
            ok = h if c.keep else ~h
            keep = ok if keep is None else keep & ok
            used.add(c)
    return (None if keep is None else ~keep), used
