"""The machine FMU's dynamics in Python: the reference the C model (fmu/c/machine.c) is tested
against, step by step.

Per axis, in this order: transport delay of the commands, first-order servo (command held over
the step, or linear from the previous step's command), backlash (play), friction at reversals
(stick-slip), quadrant glitch (spike form, `glitch`), velocity friction of a velocity-mode axis
(`velfriction`: the actual velocity, whose deficit the position integrates); then the exact forward model (mtcomp.kinematics.forward) at the actual positions,
the thermal drift added along the tool frame.  The math is in docs/model-loop.md ("The machine
FMU's dynamics"); each function says what it computes and in which units.  Written out by hand:
no library has this discrete machine model, and the test needs an independent implementation.

Times: the command row k is given at t_k = k h; every output is the state at the end of that
step, t_k + h (the FMU has no direct feed-through).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["ReferenceRun", "delayed_commands", "servo_step", "play", "backlash_out", "FrictionState", "friction_step",
           "glitch", "velfriction", "encoder_cyclic", "axis_response", "temperature", "simulate_reference"]


@dataclass(frozen=True)
class ReferenceRun:
    """p (K, 3) mm tool edge in the real workpiece frame, actual (K, n) mm/deg axis positions,
    temperature (K,) degC, all at the end of each step; velocity (K, n) mm/s, deg/s the actual
    axis velocities over each step (the FMU's v.<AXIS>)."""
    p: np.ndarray
    actual: np.ndarray
    temperature: np.ndarray
    velocity: np.ndarray | None = None


def delayed_commands(q: np.ndarray, step: float, delay: float) -> np.ndarray:
    """(K, n) commands the axes act on at t_k: q at t_k - delay, linear between the rows, the
    first row before the start."""
    q = np.asarray(q, float)
    if delay == 0.0:
        return q.copy()
    t = np.arange(len(q)) * step
    return np.column_stack([np.interp(t - delay, t, q[:, j]) for j in range(q.shape[1])])


def servo_step(x0: float, c0: float, c1: float, kv: float, h: float) -> tuple[float, float]:
    """First-order servo x' = kv (c - x) over one step h from x0, the command linear from c0 to
    c1 (c0 = c1: held).  Returns (x at the end, x where the motion reverses inside the step, or
    the end).  With e = c - x: e' = m - kv e, m = (c1 - c0)/h, so e(t) = m/kv + (e0 - m/kv)
    exp(-kv t); x' = 0 where e = 0, i.e. exp(-kv t*) = m / (m - kv e0)."""
    if not kv > 0.0:
        return c1, c1
    a = kv * h
    g = -math.expm1(-a)
    if c0 == c1:
        end = x0 + (c1 - x0) * g
        return end, end
    end = c1 - (c1 - c0) * g / a - (c0 - x0) * (1.0 - g)
    mid = end
    m, e0 = (c1 - c0) / h, c0 - x0
    den = m - kv * e0
    if den != 0.0:
        E = m / den
        if 1.0 - g < E < 1.0:
            mid = c0 + m * (-math.log(E) / kv)
    return end, mid


def play(inp: float, out: float, b: float) -> float:
    """Backlash as a play operator of width b: the output moves only when the input leaves
    [out - b/2, out + b/2]."""
    if inp - out > 0.5 * b:
        return inp - 0.5 * b
    if inp - out < -0.5 * b:
        return inp + 0.5 * b
    return out


def backlash_out(servo: float, play_state: float, b: float) -> float:
    """The position after the backlash element of width b (mm or deg) from the servo position
    and the play state (a play of width |b|): b >= 0 the play itself; b < 0 (an over-compensated
    backlash, ISO 230-2 reversal value negative) its mirror about the servo position,
    2 servo - play, which leads the command by |b|/2 where the play lags it."""
    return 2.0 * servo - play_state if b < 0 else play_state


@dataclass
class FrictionState:
    """slide: the slide position; err: play output - slide while it slides; direction of the
    last motion (+1, -1, 0 before any); stuck: static friction holds the slide."""
    slide: float
    err: float = 0.0
    direction: float = 0.0
    stuck: bool = False


def friction_step(st: FrictionState, s0: float, s1: float, h: float, breakaway: float, coulomb: float,
                  tau: float) -> None:
    """Friction at reversals over one step in which the play output moved from s0 to s1 (mm or
    deg), updating `st` in place.  After a reversal of the motion the slide sticks where it is;
    it breaks away when the drive has wound up by `breakaway` past it (the instant interpolated
    linearly in the step); then its lag behind the drive relaxes from the breakaway distance to
    the Coulomb distance with time constant tau: err = d (coulomb + (breakaway - coulomb)
    exp(-(t - t_b)/tau)), d the direction of motion."""
    d = st.direction
    ds = s1 - s0
    if abs(ds) > 1e-12:
        nd = 1.0 if ds > 0 else -1.0
        if d != 0.0 and nd != d:
            st.stuck = True
        d = st.direction = nd
    decay = (lambda t: math.exp(-t / tau)) if tau > 0 else (lambda t: 0.0)
    if st.stuck:
        stick = st.slide
        D1 = d * (s1 - stick)
        if D1 >= breakaway:
            D0 = d * (s0 - stick)
            f = (breakaway - D0) / (D1 - D0) if D1 > D0 else 1.0
            f = min(max(f, 0.0), 1.0)
            st.stuck = False
            st.err = d * (coulomb + (breakaway - coulomb) * decay((1.0 - f) * h))
            st.slide = s1 - st.err
        return
    target = d * coulomb
    st.err = target + (st.err - target) * decay(h)
    st.slide = s1 - st.err


def glitch(since: np.ndarray, direction: np.ndarray, height: float, time: float) -> np.ndarray:
    """Quadrant glitch (spike form, mm or deg): -height d s exp(1 - s), s = since/time, `since` the
    time (s) from the drive's last reversal (inf before any), d the direction of motion since;
    the diagnosis' quadrant_glitch (mtcomp.diagnose.effects.friction.QuadrantGlitch), peak
    `height` at `time` after the reversal.  time = 0: none."""
    since = np.asarray(since, float)
    if not time > 0:
        return np.zeros_like(since)
    s = since / time
    ok = (s > 0) & (s <= 700.0)
    sc = np.where(ok, s, 0.0)
    return np.where(ok, -height * np.asarray(direction, float) * sc * np.exp(1.0 - sc), 0.0)


def velfriction(v, coulomb: float, viscous: float, vs: float):
    """Actual velocity (mm/s, deg/s) of a velocity-mode axis whose drive moves at v: its
    proportional velocity loop loses coulomb tanh(v/vs) + viscous v to friction,
    v - coulomb tanh(v/vs) - viscous v (vs = 0: sign(v)); the diagnosis' `friction` on a
    velocity output (mtcomp.diagnose.effects.friction.Friction) with the same vs."""
    v = np.asarray(v, float)
    s = np.tanh(v / vs) if vs > 0 else np.sign(v)
    return v - coulomb * s - viscous * v


def encoder_cyclic(p: np.ndarray, period: float, a1: float, phase1: float, a2: float = 0.0,
                   phase2: float = 0.0) -> np.ndarray:
    """Encoder cyclic error (mm or deg) at axis positions p: a1 sin(2 pi p/period + phase1) +
    a2 sin(4 pi p/period + phase2), phases in deg; 0 with period 0.  The machine FMU adds it to
    the actual position the other elements give (the diagnosis' encoder_cyclic_error)."""
    p = np.asarray(p, float)
    if not period > 0:
        return np.zeros_like(p)
    w = 2 * np.pi * p / period
    return a1 * np.sin(w + math.radians(phase1)) + a2 * np.sin(2 * w + math.radians(phase2))


def axis_response(q: np.ndarray, step: float, dynamics, n_axes: int | None = None, *,
                  with_velocity: bool = False):
    """(K, n) actual axis positions (mm/deg) at the end of each step for the commands q (K, n)
    given at t_k = k step, under `dynamics` (mtcomp.fmu.build.MachineDynamics).  with_velocity:
    (positions, velocities (K, n) mm/s or deg/s over each step).

    Velocity friction: the drive's mean velocity over step k, v_k = (servo_k+1 - servo_k)/h,
    becomes velfriction(v_k); the position adds the integral of the deficit, h sum (v_a - v)."""
    q = np.asarray(q, float)
    K, n = q.shape
    kv = dynamics.per_axis(dynamics.kv, n, "kv")
    bl = dynamics.per_axis(dynamics.backlash, n, "backlash")
    brk = dynamics.per_axis(dynamics.friction_breakaway, n, "friction_breakaway")
    cou = dynamics.per_axis(dynamics.friction_coulomb, n, "friction_coulomb")
    ftau = dynamics.per_axis(dynamics.friction_tau, n, "friction_tau")
    gh = dynamics.per_axis(getattr(dynamics, "glitch_height", 0.0), n, "glitch_height")
    gt = dynamics.per_axis(getattr(dynamics, "glitch_time", 0.0), n, "glitch_time")
    vfc = dynamics.per_axis(getattr(dynamics, "velfriction_coulomb", 0.0), n, "velfriction_coulomb")
    vfb = dynamics.per_axis(getattr(dynamics, "velfriction_viscous", 0.0), n, "velfriction_viscous")
    vfs = dynamics.per_axis(getattr(dynamics, "velfriction_vs", 0.0), n, "velfriction_vs")
    enc = [dynamics.per_axis(getattr(dynamics, f"encoder_{f}", 0.0), n, f"encoder_{f}")
           for f in ("period", "a1", "phase1", "a2", "phase2")]
    c1 = delayed_commands(q, step, float(dynamics.delay))
    # the command a step before: the delayed command at t_k - h (the first row before the start)
    c0 = np.vstack([c1[:1], c1[:-1]]) if dynamics.interpolation else c1
    if dynamics.interpolation and dynamics.delay:
        t = np.arange(K) * step
        c0 = np.column_stack([np.interp(t - step - dynamics.delay, t, q[:, j]) for j in range(n)])
    out = np.empty((K, n))
    vel = np.empty((K, n))
    for i in range(n):
        servo = q[0, i]
        pl = q[0, i]
        fr = FrictionState(q[0, i])
        on = brk[i] > 0 or cou[i] > 0
        since = np.full(K, np.inf)     # from the drive's last reversal to the end of step k
        gdir = np.zeros(K)
        d, t_rev = 0.0, None
        for k in range(K):
            end, mid = servo_step(servo, float(c0[k, i]), float(c1[k, i]), kv[i], step)
            w = abs(bl[i])
            pl = play(servo, pl, w)
            s0 = backlash_out(servo, pl, bl[i])
            pl = play(mid, pl, w)
            pl = play(end, pl, w)
            s1 = backlash_out(end, pl, bl[i])
            # the drive's motion over the step (resolved to the step): a reversal starts the glitch
            # at the step's start, t_k = k h
            if abs(end - servo) > 1e-12:
                nd = 1.0 if end > servo else -1.0
                if d != 0.0 and nd != d:
                    t_rev = k * step
                d = nd
            gdir[k] = d
            if t_rev is not None:
                since[k] = (k + 1) * step - t_rev
            vel[k, i] = (end - servo) / step     # the drive's, made actual below
            servo = end
            if on:
                friction_step(fr, s0, s1, step, brk[i], cou[i], ftau[i])
                out[k, i] = fr.slide
            else:
                out[k, i] = s1
        if gt[i] > 0:
            out[:, i] += glitch(since, gdir, gh[i], gt[i])
        va = velfriction(vel[:, i], vfc[i], vfb[i], vfs[i])
        # the deficit accumulated step by step, as the FMU does (same rounding)
        dfc = 0.0
        for k in range(K):
            dfc += (va[k] - vel[k, i]) * step
            out[k, i] += dfc
        vel[:, i] = va
        out[:, i] += encoder_cyclic(out[:, i], *(e[i] for e in enc))
    return (out, vel) if with_velocity else out


def temperature(K: int, step: float, dynamics, spindle_speed=0.0, temperature_input=20.0) -> np.ndarray:
    """(K,) machine temperature (degC) at the end of each step: T' = (T_target - T)/tau, the
    driver held over each step, T(0) = ambient + initial_excess; T_target = ambient + gain *
    spindle speed (driver spindle), ambient + (temperature input - its first value) (driver
    temperature), ambient (driver time)."""
    s = np.broadcast_to(np.asarray(spindle_speed, float), (K,))
    u = np.broadcast_to(np.asarray(temperature_input, float), (K,))
    drv = dynamics.driver_code
    g = -math.expm1(-step / dynamics.thermal_time_constant)
    T = dynamics.ambient + dynamics.initial_excess
    out = np.empty(K)
    for k in range(K):
        target = dynamics.ambient
        if drv == 0:
            target += dynamics.thermal_gain * s[k]
        elif drv == 1:
            target += u[k] - u[0]
        T += (target - T) * g
        out[k] = T
    return out


def simulate_reference(machine, q, step: float, errors=None, dynamics=None, *, spindle_speed=0.0,
                       temperature_input=20.0) -> ReferenceRun:
    """The machine FMU's noise-free outputs for commands q (K, n) given at t_k = k step: tool
    edge (forward model at the actual positions, plus drift (T - T_reference) along the tool
    frame), actual positions and temperature at the end of each step."""
    from ..fmu.build import MachineDynamics
    from ..kinematics import forward
    from ..machine import load_machine
    machine = load_machine(machine)
    dyn = dynamics or MachineDynamics()
    q = np.asarray(q, float)
    act, vel = axis_response(q, step, dyn, with_velocity=True)
    T = temperature(len(q), step, dyn, spindle_speed, temperature_input)
    pose = forward(machine, act, errors, strict=False)
    drift = np.asarray(dyn.drift, float) * (T - dyn.reference_temperature)[:, None]
    p = pose.p + np.einsum("nij,nj->ni", pose.R, drift)
    return ReferenceRun(p, act, T, vel)
