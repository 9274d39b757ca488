"""A synthetic machine with known geometric errors, for testing the measurement-to-compensation chain.

Every component of every linear axis is a polynomial plus a periodic term with a random phase,
scaled to a chosen peak over the travel; squareness errors are constants.  The functions are in
the canonical form the measurement chain recovers (docs/geometric.md): translational and angular
components vanish at position 0 (the datum the interferometer is zeroed at), straightness
components have no least-squares slope over the travel (a slope is a squareness), and the
squareness of the axes is EC0Y (Y to X), EB0Z and EA0Z (Z to X and Y).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import AxisErrorTable, ErrorSet, GeometricErrors, component_names
from ..machine import Machine

__all__ = ["SyntheticErrors", "make_synthetic", "run_positions"]

SQUARENESS = ("EC0Y", "EB0Z", "EA0Z")


@dataclass(frozen=True)
class SyntheticErrors:
    """Known error functions: coefficients per component and constant squareness (rad).

    coeffs[name] = (c1, c2, c3, amplitude, wavelength, phase): value(s) =
    c1 u + c2 u² + c3 u³ + amplitude sin(2π s / wavelength + phase), u = s / half-travel,
    minus the value at s = 0 (and, for straightness, minus its least-squares slope).
    """
    machine: Machine
    coeffs: dict
    slopes: dict
    squareness: dict
    step: float = 1.0

    def value(self, name: str, s) -> np.ndarray:
        """Component `name` (e.g. "EYX") at positions s (mm): mm or rad."""
        s = np.asarray(s, dtype=float)
        ax = self.machine.axis(name[-1])
        half = 0.5 * (ax.limits[1] - ax.limits[0])
        c1, c2, c3, amp, lam, ph = self.coeffs[name]

        def raw(x):
            u = x / half
            return c1 * u + c2 * u**2 + c3 * u**3 + amp * np.sin(2 * np.pi * x / lam + ph)
        return raw(s) - raw(0.0) - self.slopes.get(name, 0.0) * s

    def table(self, axis: str, step: float | None = None) -> AxisErrorTable:
        ax = self.machine.axis(axis)
        lo, hi = ax.limits
        h = step or self.step
        pos = np.unique(np.concatenate([np.arange(lo, hi, h), [hi, 0.0]]))
        return AxisErrorTable(axis, pos, {n: self.value(n, pos) for n in component_names(axis)})

    def geometric(self, step: float | None = None) -> GeometricErrors:
        tables = {a.name: self.table(a.name, step) for a in self.machine.axes}
        return GeometricErrors(tables, dict(self.squareness))

    def errors(self, step: float | None = None) -> ErrorSet:
        """The synthetic machine as an ErrorSet (tables sampled every `step` mm)."""
        return ErrorSet(geometric=self.geometric(step))


def run_positions(axis, step: float) -> np.ndarray:
    """Target positions lo, lo + step, ..., hi of an axis (hi always included), mm."""
    lo, hi = axis.limits
    n = int(np.ceil((hi - lo) / step - 1e-9))
    return np.linspace(lo, hi, n + 1) if np.isclose(lo + n * step, hi) else \
        np.append(np.arange(n) * step + lo, hi)


def make_synthetic(machine: Machine, seed: int = 0, max_linear: float = 0.020,
                   max_angular: float = 50e-6, step: float = 1.0,
                   min_wavelength: float = 150.0, run_step: float = 10.0) -> SyntheticErrors:
    """Random smooth errors for every component of every linear axis of `machine`.

    Each component peaks at between half and all of max_linear (mm) or max_angular (rad) over the
    travel; the periodic term carries a third of the peak with a wavelength of at least
    `min_wavelength` mm.  Squareness errors are up to max_angular.  The straightness slopes are
    removed by least squares over the positions lo, lo + run_step, ..., hi: the positions the
    simulated runs visit, so the measurement chain's convention matches the truth exactly.
    """
    rng = np.random.default_rng(seed)
    coeffs, slopes = {}, {}
    sq = {}
    for ax in machine.axes:
        if ax.is_rotary:
            raise ValueError("synthetic errors are defined for linear axes only")
        s = run_positions(ax, run_step)
        for name in component_names(ax.name):
            c = rng.normal(size=3)
            lam = rng.uniform(min_wavelength, 2.5 * min_wavelength)
            phase = rng.uniform(0, 2 * np.pi)
            peak = (max_linear if name[1] in "XYZ" else max_angular) * rng.uniform(0.5, 1.0)
            straight = name[1] != name[2] and name[1] in "XYZ"

            def canonical(cf):
                f = SyntheticErrors(machine, {name: cf}, {}, {}, step)
                v = f.value(name, s)
                m = float(np.polyfit(s, v, 1)[0]) if straight else 0.0
                return v - m * s, m
            # Two thirds of the peak from the polynomial, one third from the periodic term,
            # then the whole function scaled so its canonical form peaks at exactly `peak`.
            poly, _ = canonical((c[0], c[1], c[2], 0.0, lam, phase))
            k = (2 / 3) * peak / max(np.max(np.abs(poly)), 1e-300)
            cf = (c[0] * k, c[1] * k, c[2] * k, peak / 3, lam, phase)
            v, _ = canonical(cf)
            g = peak / np.max(np.abs(v))
            cf = tuple(x * g for x in cf[:4]) + cf[4:]
            coeffs[name] = cf
            if straight:
                slopes[name] = canonical(cf)[1]
    for name in SQUARENESS:
        if name[-1] in machine.axis_names:
            sq[name] = float(rng.uniform(-1, 1) * max_angular)
    return SyntheticErrors(machine, coeffs, slopes, sq, step)
