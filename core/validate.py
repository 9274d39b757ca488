"""Checks of values read from set-up files (TOML): types, ranges, shapes, finiteness, unknown keys.

Every reader of a file format validates each value once, where it reads it, with these helpers,
so every rejection is an `InputError` naming the file, the field and what was expected.  A TOML
parser hands over Python values: booleans (which Python counts as integers), strings, integers of
any size, floats including nan and inf, lists and tables; each helper accepts exactly the kinds
of value its field means and nothing that merely converts (``"1"``, ``true``, ``[[1, 2, 3]]``).
"""
from __future__ import annotations

import math
from collections.abc import Mapping

from ._io import InputError

# Largest magnitude any length or angle of a set-up file may have (mm or deg): far beyond any
# machine, far below where float arithmetic or the controller's integer counts overflow.
MAX_MAGNITUDE = 1e9


def _describe(value) -> str:
    if isinstance(value, bool):  # as TOML writes it
        return "true" if value else "false"
    r = repr(value)
    return r if len(r) <= 60 else r[:57] + "..."


def table(value, file, field: str) -> dict:
    """A TOML table (dict)."""
    if not isinstance(value, Mapping):
        raise InputError(f"expected a table, got {_describe(value)}", file, field=field)
    return dict(value)


def check_keys(d: Mapping, allowed, file, field: str | None) -> None:
    """Refuse keys of `d` that are not in `allowed`, naming the first unknown one."""
    unknown = sorted(set(d) - set(allowed), key=str)
    if unknown:
        where = f"{field}.{unknown[0]}" if field else str(unknown[0])
        raise InputError(f"unknown key {unknown[0]!r}; expected some of {', '.join(sorted(allowed))}",
                         file, field=where)


def string(value, file, field: str, *, choices=None, nonempty: bool = True, max_len: int = 10_000) -> str:
    """A string (non-empty by default, optionally one of `choices`)."""
    if not isinstance(value, str):
        raise InputError(f"expected a string, got {_describe(value)}", file, field=field)
    if choices is not None and value not in choices:
        raise InputError(f"expected one of {', '.join(map(repr, choices))}, got {_describe(value)}",
                         file, field=field)
    if nonempty and not value.strip():
        raise InputError("expected a non-empty string", file, field=field)
    if len(value) > max_len:
        raise InputError(f"string longer than {max_len} characters", file, field=field)
    return value


def number(value, file, field: str, *, lo: float | None = None, hi: float | None = None,
           lo_open: bool = False, allow_inf: bool = False, max_abs: float = MAX_MAGNITUDE,
           unit: str = "") -> float:
    """A real number: an int or float (never a bool or a string), finite (infinite only when
    allow_inf), |x| <= max_abs, within [lo, hi] (lo exclusive when lo_open)."""
    u = f" {unit}" if unit else ""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise InputError(f"expected a number{' in' + u if u else ''}, got {_describe(value)}", file, field=field)
    if isinstance(value, int) and abs(value) > max_abs:
        # large TOML integers (above 2**63 too) are refused before float() could overflow
        raise InputError(f"{_describe(value)} is out of range: expected |x| <= {max_abs:g}{u}", file, field=field)
    x = float(value)
    if math.isnan(x):
        raise InputError(f"expected a number{' in' + u if u else ''}, got nan", file, field=field)
    if math.isinf(x):
        if not allow_inf:
            raise InputError(f"expected a finite number{u}, got {x}", file, field=field)
    elif abs(x) > max_abs:
        raise InputError(f"{x:g} is out of range: expected |x| <= {max_abs:g}{u}", file, field=field)
    if lo is not None and (x <= lo if lo_open else x < lo):
        raise InputError(f"expected a value {'>' if lo_open else '>='} {lo:g}{u}, got {x:g}", file, field=field)
    if hi is not None and x > hi:
        raise InputError(f"expected a value <= {hi:g}{u}, got {x:g}", file, field=field)
    return x


def integer(value, file, field: str, *, lo: int | None = None, hi: int | None = None) -> int:
    """An integer (never a bool, a float or a string) within [lo, hi]."""
    if isinstance(value, bool) or not isinstance(value, int):
        raise InputError(f"expected an integer, got {_describe(value)}", file, field=field)
    if (lo is not None and value < lo) or (hi is not None and value > hi):
        rng = f"[{'' if lo is None else lo}, {'' if hi is None else hi}]"
        raise InputError(f"expected an integer in {rng}, got {_describe(value)}", file, field=field)
    return value


def vector(value, n: int | tuple[int, int], file, field: str, *, max_abs: float = MAX_MAGNITUDE,
           lo: float | None = None, unit: str = "", nonzero: bool = False) -> tuple[float, ...]:
    """A list of n numbers (or between n[0] and n[1]), each checked as `number`."""
    lo_n, hi_n = (n, n) if isinstance(n, int) else n
    want = f"{lo_n}" if lo_n == hi_n else f"{lo_n} to {hi_n}"
    u = f" in {unit}" if unit else ""
    if not isinstance(value, (list, tuple)) or not lo_n <= len(value) <= hi_n:
        raise InputError(f"expected a list of {want} numbers{u}, got {_describe(value)}", file, field=field)
    out = tuple(number(x, file, f"{field}[{i}]", max_abs=max_abs, lo=lo, unit=unit) for i, x in enumerate(value))
    if nonzero and not any(out):
        raise InputError("expected a non-zero vector", file, field=field)
    return out
