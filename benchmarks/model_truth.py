"""An independent machine simulator: the truth the model loop is judged against.

Written apart from mtcomp's effect library (mtcomp.diagnose.effects) and from the machine
FMU's C model: its own physics, integrated on a fine grid (`sub` substeps per interpolation
period, 20 by default), so that it differs from the FMU's exact discrete servo as a real
machine does.  Only the command trajectory comes from mtcomp (the control's interpolator,
mtcomp.fmu.cosim.interpolate_program): that is the control, not the machine.

Per linear axis i of a 3-axis machine (X, Y, Z, tool edge = axis positions):
- the control holds command w_k over each period [t_k, t_k + h) (zero-order hold), delayed by
  a transport delay;
- the drive d follows it as a first-order position loop, d' = kv (w - d) (kv 1/s), integrated
  by classical Runge-Kutta on the substeps;
- a play of width b between drive and table (lost motion centred at the start): the table
  position s follows the drive only when d - s leaves [-b/2, b/2];
- stick-slip friction at reversals: when the drive reverses, the table lags by the breakaway a
  (in the old direction), a lost motion the integrator of the position loop recovers with time
  constant tau: e(t) = -a sgn(new direction) exp(-(t - t_rev)/tau);
- squareness: x_tool = x + gamma y (gamma in rad, the tool's x drifts with y);
- thermal: T' = (T_in(t) - T)/tau_T on the substeps from T(0) = T_in(0) + excess; the tool
  edge moves by k (T - T_ref) along z (k mm/K);
- sensor noise: white, sigma in mm, added to the recorded samples.

Recorded like the machine FMU's runs: row k labelled t_k holds the state at t_k + h.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np


@dataclass(frozen=True)
class Truth:
    """The true effects.  kv (1/s per axis, 0: ideal), backlash b (mm per axis), breakaway a
    (mm per axis) and tau (s per axis) of the stick-slip, squareness gamma (rad, x by y),
    thermal gain k (mm/K along z), time constant tau_T (s), initial excess (K), reference
    (degC), delay (s), noise sigma (mm)."""
    kv: tuple = (0.0, 0.0, 0.0)
    backlash: tuple = (0.0, 0.0, 0.0)
    breakaway: tuple = (0.0, 0.0, 0.0)
    stick_tau: tuple = (0.02, 0.02, 0.02)
    squareness: float = 0.0
    thermal_k: float = 0.0
    thermal_tau: float = 2.0
    thermal_excess: float = 0.0
    thermal_ref: float = 20.0
    delay: float = 0.0
    noise: float = 0.0
    extra: dict = field(default_factory=dict)


def _rk4_factor(z: float) -> float:
    """d_{j+1} = R d_j + (1 - R) w for one RK4 step of d' = kv (w - d), z = kv dt, w held."""
    return 1.0 - z + z * z / 2.0 - z ** 3 / 6.0 + z ** 4 / 24.0


def _first_order(u: np.ndarray, R: float, x0: float) -> np.ndarray:
    """x_{j+1} = R x_j + (1 - R) u_j from x0: the states after each substep (scipy's lfilter)."""
    from scipy.signal import lfilter
    y, _ = lfilter([1.0 - R], [1.0, -R], u, zi=[R * x0])
    return y


def _play(d: np.ndarray, b: float) -> np.ndarray:
    """Table positions behind a play of width b (lost motion centred at the start)."""
    if b <= 0:
        return d.copy()
    s = np.empty_like(d)
    cur, hb = float(d[0]), 0.5 * b
    for j, x in enumerate(d.tolist()):
        if x - cur > hb:
            cur = x - hb
        elif x - cur < -hb:
            cur = x + hb
        s[j] = cur
    return s


def _stick(d: np.ndarray, tj: np.ndarray, a: float, tau: float) -> np.ndarray:
    """Lost motion of the stick-slip: -a sgn(new direction) exp(-(t - t_rev)/tau) after each
    reversal of the drive d (on the substeps tj)."""
    if a == 0:
        return np.zeros_like(d)
    step = np.diff(d, prepend=d[0])
    dirn = np.where(step > 1e-12, 1.0, np.where(step < -1e-12, -1.0, 0.0))
    idx = np.maximum.accumulate(np.where(dirn != 0, np.arange(len(d)), -1))
    last = np.where(idx >= 0, dirn[np.maximum(idx, 0)], 0.0)          # last nonzero direction
    prev = np.concatenate([[0.0], last[:-1]])
    rev = (dirn != 0) & (prev != 0) & (dirn != prev)
    ridx = np.maximum.accumulate(np.where(rev, np.arange(len(d)), -1))
    age = np.where(ridx >= 0, tj - tj[np.maximum(ridx, 0)], np.inf)
    return np.where(ridx >= 0, -a * last * np.exp(-age / tau), 0.0)


def run(w: np.ndarray, h: float, truth: Truth, *, temperature=None, sub: int = 20, seed: int = 0) -> np.ndarray:
    """Tool edge (K, 3) mm for the commands w (K, 3) held over periods of h s.  temperature:
    callable of t (s) -> degC (the thermal driver), or None.  Row k: the state at t_k + h."""
    w = np.asarray(w, float)
    K = len(w)
    dt = h / sub
    J = K * sub
    tj = (np.arange(J) + 1) * dt                      # the end of each substep
    # the command on the substeps: held over each period, delayed
    shift = int(round(truth.delay / dt))
    src = np.clip((np.arange(J) - shift) // sub, 0, K - 1)
    out_pos = np.empty((K, 3))
    ends = (np.arange(K) + 1) * sub - 1
    for i in range(3):
        cmd = w[src, i]
        kv = float(truth.kv[i])
        d = _first_order(cmd, _rk4_factor(kv * dt), float(w[0, i])) if kv > 0 else cmd
        s = _play(d, float(truth.backlash[i])) + _stick(d, tj, float(truth.breakaway[i]), float(truth.stick_tau[i]))
        out_pos[:, i] = s[ends]
    p = out_pos.copy()
    p[:, 0] += truth.squareness * out_pos[:, 1]
    if truth.thermal_k and temperature is not None:
        Tin = np.asarray(temperature(tj - dt), float)               # held over each substep
        R = math.exp(-dt / truth.thermal_tau)
        T = _first_order(Tin, R, float(temperature(0.0)) + truth.thermal_excess)
        p[:, 2] += truth.thermal_k * (T[ends] - truth.thermal_ref)
    if truth.noise:
        p = p + np.random.default_rng(seed).normal(0.0, truth.noise, p.shape)
    return p


def run_program(program, machine, h: float, truth: Truth, *, temperature=None, sub: int = 20, seed: int = 0,
                rapid: float = 3000.0):
    """(t (K,) s, commands (K, n), tool edge (K, 3)) of an NC program (text) on the true machine."""
    from mtcomp.fmu.cosim import interpolate_program
    from mtcomp.machine import load_machine
    m = load_machine(machine)
    t, q = interpolate_program(program, m, h, rapid=rapid)
    return t, q, run(q, h, truth, temperature=temperature, sub=sub, seed=seed)
