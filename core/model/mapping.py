"""Effect -> model parameters: one small function per effect of the diagnosis.

Each function reads one effect of the diagnosis JSON (``{"name", "output", "inputs",
"params", "uncertainty"}``, docs/diagnose.md) and returns what it becomes in the machine model:
`Param` items named like the machine FMU's parameters (``servo.kv.X``, ``backlash.X``,
``location.EC0Y``, ``workpiece_setting.translation.x``) and `Table` items (ISO 230-1
component error functions of one axis, written as CSV tables).  An effect the model cannot
carry raises `NoHome` with the reason; the export lists it, it is never dropped silently.
When the diagnosis JSON changes, only the function of the effect concerned changes.
"""
from __future__ import annotations

import math
from types import SimpleNamespace
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from ..machine import Machine
from .axes import XYZ, NoHome, coordinate_letter, linear_axis, rotary_axis


@dataclass(frozen=True)
class Param:
    """One scalar of the model: `name` is the machine FMU parameter name (also the key in the
    files), value and sigma (one standard deviation, None if unknown) in `unit`."""
    name: str
    value: float
    sigma: float | None
    unit: str
    type: str = "Real"       # "Integer" for the FMU's Integer parameters (thermal.driver)


@dataclass(frozen=True)
class Table:
    """An ISO 230-1 component error of one axis as a function of its position: component
    (e.g. EXX, EYX) of `axis`, fn(q mm) -> mm, sampled at most `spacing` mm apart; `sigma`
    describes its uncertainty in words (a function has no single sigma)."""
    axis: str
    component: str
    fn: Callable
    spacing: float
    sigma: dict = field(default_factory=dict)


@dataclass(frozen=True)
class Mapped:
    """What one effect became: its parameters and tables, and notes (approximations)."""
    effect: str
    output: str
    params: tuple = ()
    tables: tuple = ()
    notes: tuple = ()


def _p(e: dict, key: str) -> float:
    try:
        return float(e["params"][key])
    except (KeyError, TypeError, ValueError):
        raise NoHome(f"{e.get('name')}: parameter {key!r} missing in the diagnosis") from None


def _s(e: dict, key: str):
    v = (e.get("uncertainty") or {}).get(key)
    return None if v is None else float(v)


def _one_output(e: dict) -> str:
    outs = str(e.get("output", "")).split(",")
    if len(outs) != 1:
        raise NoHome(f"{e['name']} on {e.get('output')}: expected one output")
    return outs[0]


def map_servo_lag(e: dict, machine: Machine, step: float | None, interpolation: bool = False) -> Mapped:
    """kv (1/s) of the continuous first-order lag the diagnosis fits -> servo.kv.<AXIS>.

    The machine FMU's servo is exact first order for a command held over each communication
    step h; its steady following error at speed v is v h / (exp(kv h) - 1), not v/kv, so the
    continuous kv_c maps to kv = ln(1 + kv_c h)/h (derived by equating the following errors).
    With interpolation (the FMU's ramp-invariant servo, servo.interpolation = 1) the FMU is the
    continuous lag of the piecewise linear command: kv = kv_c, and servo.interpolation = 1 is
    written beside it."""
    ax = linear_axis(machine, _one_output(e))
    kv_c, s = _p(e, "kv_per_s"), _s(e, "kv_per_s")
    notes = ()
    if interpolation:
        return Mapped("servo_lag", e["output"], (Param(f"servo.kv.{ax.axis}", kv_c, s, "1/s"),
                                                 Param("servo.interpolation", 1, None, "1", "Integer")))
    if step and step > 0:
        kv = math.log1p(kv_c * step) / step
        s = None if s is None else s / (1.0 + kv_c * step)    # d kv / d kv_c
    else:
        kv, notes = kv_c, ("no communication step given: kv is the continuous one",)
    return Mapped("servo_lag", e["output"], (Param(f"servo.kv.{ax.axis}", kv, s, "1/s"),), notes=notes)


def map_backlash(e: dict, machine: Machine, step: float | None) -> Mapped:
    """Play width b -> backlash.<AXIS> = b.  Positive: the axis lags behind the command (a
    play); negative (the diagnosis' Backlash with sign -1, an over-compensated backlash): the
    FMU's backlash element is then the mirror of the play of width |b| about the servo position,
    the same form as the diagnosis' residual -backlash_play(p, |b|)."""
    ax = linear_axis(machine, _one_output(e))
    b = _p(e, "backlash_mm")
    return Mapped("backlash", e["output"], (Param(f"backlash.{ax.axis}", b, _s(e, "backlash_mm"), "mm"),))


def map_scale_error(e: dict, machine: Machine, step: float | None) -> Mapped:
    """r = s p on output o -> positioning error E{O}{AXIS}(q) = s (sign q + offset), a table
    over the axis travel (linear: two rows)."""
    o = coordinate_letter(_one_output(e))
    ax = linear_axis(machine, o)
    s = _p(e, "scale")
    _travel(ax)
    return Mapped("scale_error", e["output"],
                  tables=(Table(ax.axis, f"E{o.upper()}{ax.axis}", lambda q, s=s, ax=ax: s * ax.coordinate(q),
                                math.inf, {"scale": _s(e, "scale")}),))


# rows a periodic table may need (64 per period) before it is refused: the export writes at most
# 20001 rows per table, and a periodic profile sampled coarser than its period would alias
MAX_PERIODIC_ROWS = 20_000


def map_periodic_pitch_error(e: dict, machine: Machine, step: float | None) -> Mapped:
    """r = A sin(2 pi p/L) + B cos(2 pi p/L) -> positioning table E{O}{AXIS}, 64 rows per lead
    (linear interpolation of a sine at 64 points per period errs by at most 0.12 % of A)."""
    o = coordinate_letter(_one_output(e))
    ax = linear_axis(machine, o)
    _travel(ax)
    lead = _p(e, "lead_mm")
    if (ax.hi - ax.lo) / lead * 64 > MAX_PERIODIC_ROWS:   # sampled coarser, the table would alias
        raise NoHome(f"periodic_pitch_error on {e['output']}: a lead of {lead:g} mm over the {ax.hi - ax.lo:g} mm "
                     f"travel of {ax.axis} needs more than {MAX_PERIODIC_ROWS} table rows (64 per lead)")
    amp_key = next((k for k in e["params"] if k.startswith("amplitude_")), "amplitude_mm")
    amp, ph = _p(e, amp_key), math.radians(_p(e, "phase_deg"))
    a, b = amp * math.cos(ph), amp * math.sin(ph)   # phase = atan2(B, A)

    def fn(q):
        w = 2 * math.pi * ax.coordinate(q) / lead
        return a * np.sin(w) + b * np.cos(w)
    return Mapped("periodic_pitch_error", e["output"],
                  tables=(Table(ax.axis, f"E{o.upper()}{ax.axis}", fn, lead / 64,
                                {"lead_mm": _s(e, "lead_mm"), "amplitude_mm": _s(e, amp_key),
                                 "phase_deg": _s(e, "phase_deg")}),))


def map_encoder_cyclic_error(e: dict, machine: Machine, step: float | None) -> Mapped:
    """r = sum_h A_h sin(2 pi h p/P + phi_h), h = 1, 2 (p the output coordinate, mm) ->
    positioning table E{O}{AXIS} with 64 rows per signal period P when that fits the axis travel
    in MAX_PERIODIC_ROWS rows (`mtcomp compensate --errors` can then use it); else the machine
    FMU's encoder element of the axis, encoder.{period,a1,phase1,a2,phase2}.<AXIS> (a period of
    tens of µm over hundreds of mm: controls correct it in the encoder interface, and so does the
    model).  _encoder_params gives the element's parameters on the axis.  On the angle output of a
    rotary axis (period_deg, amplitudes in deg: the axis' own reading) always the element."""
    try:
        o = coordinate_letter(_one_output(e))
    except NoHome:
        _, rax = rotary_axis(machine, _one_output(e))
        return Mapped("encoder_cyclic_error", e["output"],
                      _encoder_params(e, SimpleNamespace(axis=rax.name, sign=1.0, offset=0.0), _p(e, "period_deg"),
                                      "deg"))
    ax = linear_axis(machine, o)
    _travel(ax)
    period = _p(e, "period_mm")
    rows = (ax.hi - ax.lo) / period * 64
    if rows > MAX_PERIODIC_ROWS:
        return Mapped("encoder_cyclic_error", e["output"], _encoder_params(e, ax, period),
                      notes=(f"a period of {period * 1e3:.4g} µm over the {ax.hi - ax.lo:g} mm travel of {ax.axis} "
                             f"needs {rows:.3g} table rows (at most {MAX_PERIODIC_ROWS}): the encoder element of "
                             f"{ax.axis} holds it (encoder.*.{ax.axis}); its p is the axis position, the "
                             "diagnosis' the recorded one (the second-order difference is moved into the second harmonic)",))
    harm = []
    for h, (amp, ph, _, _) in zip((1, 2), _encoder_harmonics(e, period)):
        ph = math.radians(ph)
        harm.append((h, amp * math.cos(ph), amp * math.sin(ph)))   # phase = atan2(cos coeff, sin coeff)

    def fn(q):
        w = 2 * math.pi * ax.coordinate(q) / period
        return sum(a * np.sin(h * w) + b * np.cos(h * w) for h, a, b in harm)
    unc = {k: _s(e, k) for k in e["params"]}
    return Mapped("encoder_cyclic_error", e["output"],
                  tables=(Table(ax.axis, f"E{o.upper()}{ax.axis}", fn, period / 64, unc),))


def _encoder_harmonics(e: dict, period: float, unit: str = "mm") -> list:
    """[(A_h, phi_h deg, sigma A_h, sigma phi_h)] for h = 1, 2 of the cyclic error r as the model
    applies it, a function of the axis position q before the error (the element gives y = q +
    r(q)), from the diagnosis' r_d, a function of the recorded position y: r(q) = r_d(q + r(q)),
    solved by fixed-point iteration on one period (a contraction: |r_d'| <= 2 pi (A_1 + 2 A_2)/P,
    far below 1) and reduced to its harmonics 1 and 2 by an FFT.  To second order this adds
    (pi A_1^2/P) at phase 2 phi_1 to the second harmonic (r = r_d + r_d' r_d); the products with
    A_2 change harmonics 1 and 3.  Without it the exported A_2 was off by pi A_1^2/P (3-6 nm for
    0.1-0.4 µm at 0.05-0.2 mm: 8 of 40 seeded trials outside 3 sigma).  Harmonics 3 and up, which
    the element does not hold, are of the order 2 pi A_1 A_2/P.  Sigmas: the diagnosis', the
    second harmonic's amplitude with the term's through A_1's added in quadrature."""
    harm = []
    for h in (1, 2):
        akey = next((k for k in e["params"] if k.startswith(f"amplitude_h{h}_")), f"amplitude_h{h}_{unit}")
        harm.append([_p(e, akey), _p(e, f"phase_h{h}_deg"), _s(e, akey), _s(e, f"phase_h{h}_deg")])
    n = 256
    w = 2 * np.pi * np.arange(n) / n                      # q = w P/(2 pi) over one period

    def r_d(wy):
        return sum(a * np.sin(h * wy + math.radians(ph)) for h, (a, ph, _, _) in zip((1, 2), harm))
    r = r_d(w)
    for _ in range(100):
        r_new = r_d(w + 2 * np.pi * r / period)
        done = np.max(np.abs(r_new - r)) <= 1e-15 * max(1.0, period)
        r = r_new
        if done:
            break
    c = 2.0 * np.fft.rfft(r) / n                          # r ~ Re(c_h e^{i h w}) = A sin(h w + phi)
    out = []
    for h, (a_d, ph_d, s_a, s_ph) in zip((1, 2), harm):
        a, ph = float(abs(c[h])), float(math.degrees(math.atan2(c[h].real, -c[h].imag)))
        if h == 2 and s_a is not None and harm[0][2] is not None:
            s_a = math.hypot(s_a, 2 * math.pi * harm[0][0] * harm[0][2] / period)
        if s_ph is not None and a > 0 and a_d > 0:
            s_ph = min(s_ph * a_d / a, 180.0)             # the phase's spread shrinks as |A_h| grows
        out.append((a, ph, s_a, s_ph))
    return out


def _encoder_params(e: dict, ax, period: float, unit: str = "mm") -> tuple:
    """The encoder element's parameters of axis ax for the diagnosis' r(x) on output coordinate
    x = sign q + offset.  The element adds d(q) to the axis, which moves x by sign d, so
    d(q) = sign r(sign q + offset) = sum_h A_h sin(2 pi h q/P + sign psi_h), psi_h = phi_h +
    360 h offset/P deg (sign = -1: -sin(-u + psi) = sin(u - psi)).  Sigma of the phase: the
    diagnosis' with the period's through the offset, 360 h offset sigma_P / P^2, added in
    quadrature (their correlation is not in the diagnosis)."""
    sp = _s(e, f"period_{unit}")
    out = [Param(f"encoder.period.{ax.axis}", period, sp, unit)]
    for h, (amp, ph, s_amp, s_ph) in zip((1, 2), _encoder_harmonics(e, period, unit)):
        psi = ax.sign * (ph + 360.0 * h * ax.offset / period)
        psi = float((psi + 180.0) % 360.0 - 180.0)
        if s_ph is not None and sp is not None:
            s_ph = math.hypot(s_ph, 360.0 * h * ax.offset * sp / period ** 2)
        out += [Param(f"encoder.a{h}.{ax.axis}", amp, s_amp, unit),
                Param(f"encoder.phase{h}.{ax.axis}", psi, s_ph, "deg")]
    return tuple(out)


def map_straightness(e: dict, machine: Machine, step: float | None) -> Mapped:
    """r_o = sum c_k P_k(xi) along axis j -> straightness table E{O}{J}(q_J) over the fitted
    range; outside it the profile is continued with its end values' polynomial (noted)."""
    from numpy.polynomial import legendre
    o = coordinate_letter(_one_output(e))
    j = coordinate_letter(_driver(e))
    ax = linear_axis(machine, j)
    _travel(ax)
    coef = [float(e["params"].get(f"P{k}_mm", 0.0)) for k in range(5)]
    lo, hi = _p(e, "range_lo_mm"), _p(e, "range_hi_mm")

    def fn(q):
        xi = (2 * ax.coordinate(q) - (lo + hi)) / max(hi - lo, 1e-12)
        return legendre.legval(xi, coef)
    return Mapped("straightness", e["output"],
                  tables=(Table(ax.axis, f"E{o.upper()}{ax.axis}", fn, max(hi - lo, 1.0) / 200,
                                {k: _s(e, k) for k in e["params"] if k.startswith("P")}),),
                  notes=(f"fitted over {j} = {lo:g}..{hi:g} mm; the table extrapolates the polynomial beyond",))


def map_squareness(e: dict, machine: Machine, step: float | None) -> Mapped:
    """r_o = g p_j (g rad) -> tilt of axis J about the third coordinate k: ISO 230-1 location
    error E{K}0{J} = g / ((e_k x e_j) . e_o); e.g. r_x = g y gives EC0Y = -g (Y tilted towards -X
    for g > 0), r_y = g x gives EC0X = g.  The axis' own sense cancels out."""
    o = coordinate_letter(_one_output(e))
    j = coordinate_letter(_driver(e))
    ax = linear_axis(machine, j)
    linear_axis(machine, o)
    if o == j:
        raise NoHome("squareness of an output with itself")
    io, ij = XYZ.index(o), XYZ.index(j)
    ik = 3 - io - ij
    cross = float(np.cross(np.eye(3)[ik], np.eye(3)[ij])[io])   # +-1
    g = math.radians(_p(e, "angle_deg"))
    s = _s(e, "angle_deg")
    name = f"E{'ABC'[ik]}0{ax.axis}"
    return Mapped("squareness", e["output"],
                  (Param(f"location.{name}", g / cross, None if s is None else math.radians(s), "rad"),))


def map_pivot_offset(e: dict, machine: Machine, step: float | None) -> Mapped:
    """r = (R(theta) - I) d about rotary axis K -> centre offset of K: ISO 230-7 location errors
    E{X,Y,Z}0K = -d.  A centre moved by d0 maps a point p to R (p - c - d0) + c + d0, i.e. adds
    (I - R) d0, zero at theta = 0 as the diagnosed effect.  Exact when K is the first rotary axis
    of the chain (its rotation acts in the workpiece frame) and turns about +X, +Y or +Z."""
    driver = _driver(e)
    i, ax = rotary_axis(machine, driver)
    k = "ABC".index(ax.name) if ax.name in "ABC" else None
    u = np.asarray(ax.direction, float)
    if k is None or abs(u[k] - 1.0) > 1e-9:
        raise NoHome(f"pivot offset about {ax.name}: the axis does not turn about +{'XYZ'[k] if k is not None else '?'}")
    if any(a.is_rotary for a in machine.axes[:i]):
        raise NoHome(f"pivot offset about {ax.name}: another rotary axis precedes it in the chain")
    params = []
    for c in "xyz":
        key = f"d{c}_mm"
        if key in e["params"]:
            s = _s(e, key)
            params.append(Param(f"location.E{c.upper()}0{ax.name}", -_p(e, key), s, "mm"))
    return Mapped("pivot_offset", e["output"], tuple(params))


def map_workpiece_setting(e: dict, machine: Machine, step: float | None) -> Mapped:
    """Translation T (mm) and small angles w (deg) -> workpiece_setting.translation/angle, the
    diagnosis follows mtcomp.errors.WorkpieceSetting (x_nominal = R x_real + T)."""
    params = []
    for c in "xyz":
        if f"t{c}_mm" in e["params"]:
            params.append(Param(f"workpiece_setting.translation.{c}", _p(e, f"t{c}_mm"), _s(e, f"t{c}_mm"), "mm"))
    for c, a in zip("xyz", "abc"):
        if f"r{c}_deg" in e["params"]:
            params.append(Param(f"workpiece_setting.angle.{a}", _p(e, f"r{c}_deg"), _s(e, f"r{c}_deg"), "deg"))
    return Mapped("workpiece_setting", e["output"], tuple(params),
                  notes=("angles combine as R = Rz(c) Ry(b) Rx(a): equal to the diagnosed small rotation to "
                         "first order",) if any(p.name.startswith("workpiece_setting.angle") for p in params) else ())


THERMAL_GAIN = 1e-3    # K per 1/min: the FMU's thermal.gain a spindle-driven drift is written with
AMBIENT = 20.0         # degC: the FMU's ambient start value, the thermal mapping's reference point
_SPINDLE_UNITS = ("rpm", "1_min", "rev_min")
_TEMPERATURE_UNITS = ("degC", "degc", "C", "K")


def map_thermal_drift(e: dict, machine: Machine, step: float | None, drivers: dict | None = None) -> Mapped:
    """r_o = k (F_tau[u] - u0) + r0 exp(-t/tau) + c, u a logged driver -> the FMU's thermal
    model: one temperature T with T' = (T_target - T)/tau, T(0) = ambient + excess, the tool
    edge moved by drift_o (T - T_ref) along output o (tool frame = workpiece frame: exact for a
    machine without rotary axes on the tool side at angle 0).

    Spindle speed S (driver 0, T_target = ambient + G S): T - T_ref = G (F[S] - S0) + (excess -
    G S0) exp(-t/tau) + (ambient + G S0 - T_ref), so with G = THERMAL_GAIN: drift = k/G,
    excess = r0/drift + G S0, T_ref = ambient + G S0 - c/drift.  A logged temperature u (driver
    1, T_target = ambient + u - u0): drift = k, excess = r0/k, T_ref = ambient - c/k (u0 drops
    out).  S0, the spindle speed at the start, comes from `drivers` (0 when not given, noted)."""
    o = coordinate_letter(_one_output(e))
    linear_axis(machine, o)
    gkey = next((k for k in e["params"] if k.startswith("gain_mm_per_")), None)
    if gkey is None:
        raise NoHome("thermal_drift: no gain_mm_per_<unit> in the diagnosis")
    unit = gkey[len("gain_mm_per_"):]
    k, sk = _p(e, gkey), _s(e, gkey)
    tau, stau = _p(e, "tau_s"), _s(e, "tau_s")
    ikey = next((q for q in e["params"] if q.startswith("initial_")), None)
    okey = next((q for q in e["params"] if q.startswith("offset_")), None)
    r0 = float(e["params"][ikey]) if ikey else 0.0
    c = float(e["params"][okey]) if okey else 0.0
    sr0, sc = (_s(e, ikey) if ikey else None), (_s(e, okey) if okey else None)
    if sk is not None and abs(k) < 3 * sk:
        raise NoHome(f"thermal_drift on {e['output']}: the drift gain {k:.3g} +/- {sk:.2g} mm per {unit} is not "
                     "significant; the initial state and reference cannot be written as temperatures without it")
    notes = []
    if any(a.is_rotary and a.side == "tool" for a in machine.axes):
        notes.append("drift along the tool frame: equal to the diagnosed output direction with the tool-side "
                     "rotary axes at zero")
    if unit in _SPINDLE_UNITS:
        driver, G = 0, THERMAL_GAIN
        drift = k / G
        name = str((e.get("inputs") or ["?"])[0])
        s0 = (drivers or {}).get(name)
        if s0 is None:
            s0 = 0.0
            notes.append(f"spindle speed at the start taken as 0 (the start value of {name} was not given)")
        excess = r0 / drift + G * s0
        ref = AMBIENT + G * s0 - c / drift
    elif unit in _TEMPERATURE_UNITS:
        driver, G = 1, None
        drift = k
        excess = r0 / drift
        ref = AMBIENT - c / drift
    else:
        raise NoHome(f"thermal_drift driven by {e.get('inputs')} in {unit}: the machine FMU's thermal model is "
                     "driven by the spindle speed or a logged temperature")
    if abs(drift) > 1.0 or abs(excess) > 100.0 or not -50.0 <= ref <= 100.0:
        raise NoHome(f"thermal_drift on {e['output']}: drift {drift:.3g} mm/K, initial excess {excess:.3g} K, "
                     f"reference {ref:.3g} degC are outside the FMU's ranges")
    ad = abs(drift)
    params = [Param("thermal.driver", driver, None, "1", "Integer"),
              Param("thermal.time_constant", tau, stau, "s"),
              Param(f"thermal.drift.{o}", drift, None if sk is None else sk / (G or 1.0), "mm/K"),
              Param("thermal.initial_excess", excess, None if sr0 is None else sr0 / ad, "K"),
              Param("thermal.reference", ref, None if sc is None else sc / ad, "degC")]
    if G is not None:
        params.insert(1, Param("thermal.gain", G, None, "K.min"))
    notes.append(f"one thermal state, ambient {AMBIENT:g} degC" + (f", gain {G:g} K per 1/min (drift scaled to it)"
                                                                   if G is not None else ""))
    return Mapped("thermal_drift", e["output"], tuple(params), notes=tuple(notes))


def merge_thermal(first: Mapped, other: Mapped) -> Mapped:
    """A second thermal drift (another output) beside `first`: the FMU has one thermal state,
    so only its drift gain is kept, and only with the same driver (else NoHome)."""
    drv = {p.name: p.value for p in first.params}["thermal.driver"]
    if {p.name: p.value for p in other.params}["thermal.driver"] != drv:
        raise NoHome("the machine FMU has one thermal state, already driven by the "
                     + ("spindle speed" if drv == 0 else "logged temperature"))
    keep = tuple(p for p in other.params if p.name.startswith("thermal.drift."))
    return Mapped("thermal_drift", other.output, keep,
                  notes=(f"shares the time constant, initial state and reference of the thermal drift on "
                         f"{first.output} (one thermal state)",))


def map_time_offset(e: dict, machine: Machine, step: float | None) -> Mapped:
    """REC(t) = SIM(t - tau), tau > 0 (REC lags) -> transport delay `delay` = tau: every axis
    acts on the command given tau earlier (with an ideal servo the tool edge then follows the
    nominal one tau late; the FMU interpolates the commands between steps)."""
    tau, s = _p(e, "offset_s"), _s(e, "offset_s")
    if tau <= 0:
        raise NoHome(f"time_offset of {tau:.3g} s: the recording leads the simulation, which a transport delay "
                     "cannot do (a clock offset of the recording)")
    return Mapped("time_offset", e["output"], (Param("delay", tau, s, "s"),))


def map_quadrant_glitch(e: dict, machine: Machine, step: float | None) -> Mapped:
    """Both forms of the diagnosis' quadrant glitch have a home in the machine FMU.

    Stick-slip form (breakaway delta, catch-up tau) -> friction.breakaway.<AXIS> = delta,
    friction.tau.<AXIS> = tau: the FMU's friction element is that model (the slide stays where
    the motion reversed until the drive has moved delta back, then its lag decays with tau).

    Spike form r = -A d s exp(1 - s), s = (t - t_rev)/tau (peak A, output unit, at tau s after
    the reversal) -> glitch.height.<AXIS> = A, glitch.time.<AXIS> = tau: the FMU adds exactly
    this term to the axis after each reversal of the drive's motion.  The output is
    sign * q + offset of its axis, and r flips with d: A is the same on the axis."""
    ax = linear_axis(machine, _one_output(e))
    bkey = next((k for k in e["params"] if k.startswith("breakaway_")), None)
    if bkey is not None:
        return Mapped("quadrant_glitch", e["output"],
                      (Param(f"friction.breakaway.{ax.axis}", _p(e, bkey), _s(e, bkey), "mm"),
                       Param(f"friction.tau.{ax.axis}", _p(e, "tau_s"), _s(e, "tau_s"), "s")))
    pkey = next((k for k in e["params"] if k.startswith("peak_")), None)
    if pkey is None:
        raise NoHome("quadrant_glitch: neither breakaway_<unit> (stick-slip) nor peak_<unit> (spike) in the "
                     "diagnosis")
    a, tau = _p(e, pkey), _p(e, "tau_s")
    if abs(a) > 1.0 or not 0.0 < tau <= 100.0:
        raise NoHome(f"quadrant_glitch on {e['output']}: height {a:.3g} mm, time {tau:.3g} s are outside the FMU's "
                     "ranges (+-1 mm, 0..100 s)")
    return Mapped("quadrant_glitch", e["output"],
                  (Param(f"glitch.height.{ax.axis}", a, _s(e, pkey), "mm"),
                   Param(f"glitch.time.{ax.axis}", tau, _s(e, "tau_s"), "s")),
                  notes=("spike form: the FMU's glitch starts at the reversal of the drive's motion resolved to the "
                         "step; the diagnosis places it half a sample either side",))


def velocity_output_axis(machine: Machine, output: str):
    """The machine axis of a velocity output ``v<AXIS>`` (``vX``, ``vC``: the actual-velocity
    columns mtcomp.model.simulate writes, the FMU's v.<AXIS>), or None."""
    return machine.axes[machine.axis_names.index(output[1:])] \
        if len(output) > 1 and output[0] == "v" and output[1:] in machine.axis_names else None


def map_friction(e: dict, machine: Machine, step: float | None, velocity_peaks: dict | None = None) -> Mapped:
    """Friction fitted on a velocity output v<AXIS> -> the machine FMU's velocity friction.

    The diagnosis fits r_v = -c tanh(v/v_s) - b v on the output (c in its unit, mm/s or deg/s;
    b dimensionless; v SIM's velocity, v_s = 2 % of SIM's peak |v| on the diagnosed span).  The
    FMU's velocity-mode axis gives v.<AXIS> = v - c tanh(v/v_s) - b v for the drive's velocity v,
    which is SIM's v.<AXIS> (the base model has no velocity friction): the same term, so
    velfriction.coulomb.<AXIS> = c, velfriction.viscous.<AXIS> = b and velfriction.vs.<AXIS> =
    0.02 peak.  The diagnosis JSON does not carry v_s: velocity_peaks {output: SIM's peak |v|
    over the span the diagnosis saw} gives it (mtcomp.model.loop and the CLI take it from SIM);
    without it the effect has no home."""
    o = _one_output(e)
    ax = velocity_output_axis(machine, o)
    if ax is None:
        raise NoHome(f"friction on {o}: not a velocity output v<AXIS> of an axis of {machine.name} "
                     f"({', '.join('v' + a for a in machine.axis_names)}): the model cannot place it")
    peak = (velocity_peaks or {}).get(o)
    if not peak or not math.isfinite(peak) or peak <= 0:
        raise NoHome(f"friction on {o}: the smoothing speed v_s (2 % of SIM's peak speed) is unknown: give SIM's "
                     "velocity column (--sim) so that the export can take its peak")
    unit = "deg/s" if ax.is_rotary else "mm/s"
    ckey = next((k for k in e["params"] if k.startswith("coulomb_")), None)
    if ckey is None:
        raise NoHome("friction: parameter coulomb_<unit> missing in the diagnosis")
    c, b = _p(e, ckey), _p(e, "viscous")
    if abs(c) > 1e4 or abs(b) > 1.0:
        raise NoHome(f"friction on {o}: coulomb {c:.3g} {unit}, viscous {b:.3g} are outside the FMU's ranges "
                     "(+-1e4, +-1)")
    return Mapped("friction", o,
                  (Param(f"velfriction.coulomb.{ax.name}", c, _s(e, ckey), unit),
                   Param(f"velfriction.viscous.{ax.name}", b, _s(e, "viscous"), "1"),
                   Param(f"velfriction.vs.{ax.name}", 0.02 * float(peak), 0.0, unit)),
                  notes=(f"v_s = 2 % of SIM's peak speed {float(peak):.6g} {unit} (the diagnosis' own choice)",))


def _no_home(reason: str):
    def f(e, machine, step):
        raise NoHome(reason)
    f.__doc__ = reason
    return f


MAPPERS = {
    "servo_lag": map_servo_lag,
    "backlash": map_backlash,
    "scale_error": map_scale_error,
    "periodic_pitch_error": map_periodic_pitch_error,
    "encoder_cyclic_error": map_encoder_cyclic_error,
    "straightness": map_straightness,
    "squareness": map_squareness,
    "pivot_offset": map_pivot_offset,
    "workpiece_setting": map_workpiece_setting,
    "thermal_drift": map_thermal_drift,
    "time_offset": map_time_offset,
    "quadrant_glitch": map_quadrant_glitch,
    "friction": map_friction,
}


def map_effect(e: dict, machine: Machine, step: float | None = None, drivers: dict | None = None,
               servo_interpolation: bool = False, velocity_peaks: dict | None = None) -> Mapped:
    """The model parameters of one diagnosed effect (a dict of the diagnosis JSON), or NoHome.
    drivers: {driver column: value at the start} for the thermal drift; servo_interpolation:
    the model's servos follow the command linearly between steps (servo.interpolation = 1);
    velocity_peaks: {velocity output: SIM's peak |v|} for friction on a velocity output."""
    f = MAPPERS.get(e.get("name"))
    if f is None:
        raise NoHome(f"effect {e.get('name')!r} is not known to the model export")
    if f is map_thermal_drift:
        return f(e, machine, step, drivers)
    if f is map_servo_lag:
        return f(e, machine, step, servo_interpolation)
    if f is map_friction:
        return f(e, machine, step, velocity_peaks)
    return f(e, machine, step)


def _driver(e: dict) -> str:
    ins = list(e.get("inputs") or ())
    if len(ins) != 1:
        raise NoHome(f"{e['name']}: expected one driver input, got {ins}")
    return str(ins[0]).strip().lower()


def _travel(ax) -> None:
    if not (math.isfinite(ax.lo) and math.isfinite(ax.hi)) or abs(ax.lo) > 1e5 or abs(ax.hi) > 1e5:
        raise NoHome(f"axis {ax.axis} has no finite travel to lay a table over")
