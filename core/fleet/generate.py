"""A generated fleet for tests and benchmarks: N machines x M nights of SIM/REC recordings whose
physics has a known history.

Every machine-night is one short recording of a 3-axis machine (the point-to-point motion of
`mtcomp.diagnose.synth`): x carries a backlash (play operator), y a servo lag (first-order lag
on a 10x finer grid), z a thermal drift that follows the logged spindle temperature directly
(gain in mm/degC).  The errors are computed here, independently of the diagnosis' effect models.
Histories (`FleetSpec`): every machine's thermal gain follows the season (one sinusoid over the
year, small from one night to the next); one machine's backlash grows night by night from a
given night on; another machine's servo lag steps on the night after a repair.  `Fleet.changed`
lists the (machine, date, parameter) where a parameter was made to change: what a trend report
must warn about, and nothing else.
"""
from __future__ import annotations

import datetime as _dt
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np


@dataclass(frozen=True)
class FleetSpec:
    """What to generate.  Lengths in mm, times in s, gains in mm/degC, dates ISO 8601."""
    machines: int = 20
    nights: int = 10
    start: str = "2026-03-01"
    duration: float = 12.0          # s of recording per night
    sim_rate: float = 50.0          # Hz
    rec_rate: float = 50.0          # Hz
    noise: float = 0.3e-3           # mm, white noise of the recorded positions
    backlash: tuple = (3e-3, 6e-3)  # mm, range of the machines' backlash on x
    kv: tuple = (30.0, 50.0)        # 1/s, range of the machines' position-loop gain on y
    thermal_gain: tuple = (2e-3, 4e-3)  # mm/degC on z, before the season
    season: float = 0.05            # relative amplitude of the seasonal thermal gain
    grow_machine: int = 3           # index of the machine whose backlash grows
    grow_from: int = 6              # first night (index) with a grown backlash
    grow_per_night: float = 2e-3    # mm per night
    repair_machine: int = 11        # index of the machine whose servo lag steps
    repair_night: int = 4           # first night (index) after the repair
    repair_kv: float = 1.6          # kv is multiplied by this after the repair
    seed: int = 0

    def machine_names(self) -> list[str]:
        w = max(2, len(str(self.machines)))
        return [f"m{i + 1:0{w}d}" for i in range(self.machines)]

    def dates(self) -> list[str]:
        d0 = _dt.date.fromisoformat(self.start)
        return [(d0 + _dt.timedelta(days=k)).isoformat() for k in range(self.nights)]


@dataclass(frozen=True)
class Night:
    """One generated machine-night: arrays keyed by CSV header, and the true parameters."""
    machine: str
    date: str
    sim: dict
    rec: dict
    truth: dict      # {"backlash_mm": .., "kv_per_s": .., "gain_mm_per_degC": ..}


@dataclass(frozen=True)
class Fleet:
    spec: FleetSpec
    nights: tuple                      # Night, machine-major
    changed: frozenset = field(default_factory=frozenset)  # (machine, date, parameter)

    def truth(self) -> dict:
        return {(n.machine, n.date): n.truth for n in self.nights}


def history(spec: FleetSpec, m: int, k: int) -> dict:
    """True parameters of machine index m on night index k (mm, 1/s, mm/degC)."""
    rng = np.random.default_rng([spec.seed, m])
    b0 = rng.uniform(*spec.backlash)
    kv0 = rng.uniform(*spec.kv)
    g0 = rng.uniform(*spec.thermal_gain)
    date = _dt.date.fromisoformat(spec.start) + _dt.timedelta(days=k)
    season = 1.0 + spec.season * math.sin(2 * math.pi * (date.timetuple().tm_yday - 80) / 365.25)
    b = b0 + (spec.grow_per_night * (k - spec.grow_from + 1)
              if m == spec.grow_machine and k >= spec.grow_from else 0.0)
    kv = kv0 * (spec.repair_kv if m == spec.repair_machine and k >= spec.repair_night else 1.0)
    return {"backlash_mm": b, "kv_per_s": kv, "gain_mm_per_degC": g0 * season}


def changed(spec: FleetSpec) -> frozenset:
    """(machine, date, parameter) where a parameter was made to change beyond the season."""
    names, dates = spec.machine_names(), spec.dates()
    out = set()
    if 0 <= spec.grow_machine < spec.machines:
        out |= {(names[spec.grow_machine], dates[k], "backlash_mm")
                for k in range(max(spec.grow_from, 1), spec.nights)}
    if 0 <= spec.repair_machine < spec.machines and 0 < spec.repair_night < spec.nights:
        out.add((names[spec.repair_machine], dates[spec.repair_night], "kv_per_s"))
    return frozenset(out)


def make_night(spec: FleetSpec, m: int, k: int) -> Night:
    """One machine-night's SIM and REC (headers with units) from its true parameters."""
    from ..diagnose.synth import RANGES, Trajectory, _first_order, _play
    p = history(spec, m, k)
    rng = np.random.default_rng([spec.seed, m, k, 1])
    D = spec.duration
    axes = {a: Trajectory(rng, *RANGES[a], D, vmax=20.0, acc=200.0, dwell=(0.2, 1.0)) for a in "xyz"}
    t_sim = np.arange(0.0, D, 1.0 / spec.sim_rate)
    t_rec = np.arange(0.0, D, 1.0 / spec.rec_rate)
    # fine grid for the lag (10x the faster rate), independent of the diagnosis' filter
    dtf = 0.1 / max(spec.sim_rate, spec.rec_rate)
    tf = np.arange(-1.0, D + 1.0, dtf)
    true = {a: axes[a](t_rec) for a in "xyz"}
    seg0 = axes["x"].seg[0]
    x = _play(true["x"], p["backlash_mm"], np.sign(seg0[2] - seg0[1]))
    yf = axes["y"](tf)
    y = np.interp(t_rec, tf, _first_order(yf, dtf, 1.0 / p["kv_per_s"]))
    # spindle temperature: warms over the night's run by 1-3 degC, with slow wander
    T = (20.0 + rng.uniform(0.5, 2.0) * (1.0 - np.exp(-t_rec / (0.4 * D)))
         + 0.3 * np.sin(2 * np.pi * t_rec / (rng.uniform(0.6, 1.2) * D) + rng.uniform(0, 6.3)))
    T = np.round(T, 3)
    z = true["z"] + p["gain_mm_per_degC"] * (T - T[0])
    sim = {"t": t_sim}
    for a in "xyz":
        sim[a] = axes[a](t_sim)
    rec = {"t": t_rec}
    for a, v in zip("xyz", (x, y, z)):
        rec[a] = v + rng.normal(0.0, spec.noise, len(t_rec))
    rec["t_spindle[degC]"] = T
    names, dates = spec.machine_names(), spec.dates()
    return Night(names[m], dates[k], sim, rec, p)


def make_fleet(spec: FleetSpec = FleetSpec()) -> Fleet:
    nights = tuple(make_night(spec, m, k) for m in range(spec.machines) for k in range(spec.nights))
    return Fleet(spec, nights, changed(spec))


def write_fleet(fleet: Fleet, root) -> Path:
    """Write <root>/<machine>/<date>/sim.csv,rec.csv; returns root."""
    from ..diagnose.synth import write_csv
    root = Path(root)
    for n in fleet.nights:
        d = root / n.machine / n.date
        d.mkdir(parents=True, exist_ok=True)
        write_csv(d / "sim.csv", n.sim)
        write_csv(d / "rec.csv", n.rec)
    return root
