"""Unit mistakes a diagnosis should say before it names physics: a recording in µm under a
header read as mm (x1000), a time column in ms read as s.

A factor of 1000 is no effect of a machine: when it explains the mismatch far better than the
effects fitted, the user is told which unit to write in the header.
"""
from __future__ import annotations

import numpy as np

# the usual slips: a factor of 1000 between neighbouring units (mm/µm, s/ms, µm/nm)
FACTORS = (1e-3, 1e3)
# a unit mistake must explain the mismatch this many times better than the effects fitted
BETTER = 3.0


def _rms(a) -> float:
    a = np.asarray(a, float)
    return float(np.sqrt(np.mean(a * a))) if a.size else float("nan")


def time_scale_hint(sim_t: np.ndarray, rec_t: np.ndarray) -> str | None:
    """A warning when REC's time spans about 1000x SIM's or 1/1000 of it (one is in ms)."""
    ss, sr = float(np.ptp(sim_t)), float(np.ptp(rec_t))
    if ss <= 0 or sr <= 0:
        return None
    ratio = sr / ss
    for f, which, other in ((1e3, "REC", "SIM"), (1e-3, "SIM", "REC")):
        if f / 3 < ratio < f * 3:
            return (f"likely unit mistake: {which}'s time spans {max(ratio, 1 / ratio):.3g}x "
                    f"{other}'s; if {which}'s time is in ms, write its header as t[ms] (read as s, "
                    "its readings are 1000x too far apart)")
    return None


def value_scale_notes(al, rms_after: dict) -> tuple:
    """Warnings for outputs whose REC, scaled by 1/1000 or 1000, matches SIM `BETTER` times
    better than the effects fitted do (offsets aside)."""
    rows = al.rows()
    notes = []
    for o in al.outputs:
        rec, sim = al.rec[o][rows], al.sim[o][rows]
        if np.ptp(sim) == 0:
            continue
        for f in FACTORS:
            d = rec * f - sim
            r = _rms(d - np.median(d))
            if r * BETTER < rms_after[o]:
                unit = al.units.get(o) or ""
                hint = ("µm" if unit == "mm" else "m" if unit == "mm" else "") if f == 1e-3 else \
                    ("m" if unit == "mm" else "")
                notes.append(
                    f"likely unit mistake: REC's {o} x {f:g} matches SIM {rms_after[o] / max(r, 1e-300):.3g}x "
                    f"better than the effects fitted (RMS {r:.3g} against {rms_after[o]:.3g} "
                    f"{unit}): " + (f"is it in {hint}? write its header as {o}[{'um' if hint == 'µm' else hint}]"
                                    if hint else "check the unit in its header"))
                break
    return tuple(notes)
