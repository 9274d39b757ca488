"""Argument types for the command line: numbers checked where argparse reads them.

`type=positive_float` refuses 0, negatives, nan, inf and text with argparse's one-line usage
error (exit status 2), so no command sees a value it cannot use.
"""
from __future__ import annotations

import argparse
import math


def _float(text: str) -> float:
    try:
        x = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not math.isfinite(x):
        raise argparse.ArgumentTypeError(f"expected a finite number, got {text!r}")
    return x


def finite_float(text: str) -> float:
    """A finite number."""
    return _float(text)


def positive_float(text: str) -> float:
    """A finite number > 0."""
    x = _float(text)
    if not x > 0:
        raise argparse.ArgumentTypeError(f"expected a number > 0, got {text!r}")
    return x


def nonnegative_float(text: str) -> float:
    """A finite number >= 0."""
    x = _float(text)
    if not x >= 0:
        raise argparse.ArgumentTypeError(f"expected a number >= 0, got {text!r}")
    return x


def positive_int(text: str) -> int:
    """An integer >= 1."""
    try:
        n = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number, got {text!r}") from None
    if n < 1:
        raise argparse.ArgumentTypeError(f"expected a whole number >= 1, got {text!r}")
    return n
