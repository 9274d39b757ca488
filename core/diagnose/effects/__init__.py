"""The library of physical effects a simulation may have left out.

Every effect predicts the residual REC - SIM it would cause on one or more outputs, as
``fixed(eta) + B(eta) @ beta``: ``eta`` are the few nonlinear parameters (time constants, screw
lead, clock offset, kv) that are fitted by nonlinear least squares, ``beta`` the amplitudes that
enter linearly and are solved exactly for every ``eta`` (variable projection).  All vectors are
stacked over the outputs and divided by each output's noise floor, so outputs in mm and deg and
of different noise weigh by their information.

Signatures and parameters (documented for users in docs/diagnose.md):

- thermal_drift: r = k (F_tau[u] - u(t0)) + r0 exp(-(t - t0)/tau) + c, F_tau a first-order lag
  of a driver u (spindle speed, a logged temperature, any other slowly varying input) started
  in steady state; k in mm per unit of u, tau in s, r0 the unknown initial thermal state and c
  the unknown reference (mm).
- backlash: play operator of width b on the axis position: after a reversal at p_rev the
  error moves from +-b/2 to -+b/2 over the first b of travel, r = clip(d b/2 - (p - p_rev), -b/2, b/2),
  d = +1/-1 the direction of the last motion (kept during dwells).  A second candidate has the
  other sign (negative width B < 0, ISO 230-2 reversal value B negative): the error leads the
  command, the control over-compensating its backlash; reported in those words.
- servo_lag: r = F_{1/kv}[p] - p, p the simulated axis position: a first-order position loop
  of gain kv (1/s); the steady following error is v/kv.  Also in its linear (steady-state)
  form r = -v/kv, for loops that are not exactly first order.
- periodic_pitch_error: r = A sin(2 pi p / L) + B cos(2 pi p / L), L the screw lead (mm).
- scale_error: r = s * p (s dimensionless, about the axis zero).
- squareness: r_o = g * p_j, p_j the position of another linear axis (g in rad, reported in deg).
- straightness: r_o = sum_k c_k P_k(xi), xi the other axis' position mapped to [-1, 1],
  Legendre orders 0..4 (squareness is its one-parameter, linear special case).
- pivot_offset: r = (R_axis(theta) - I) d, d the tool edge's offset from a rotary axis' centre
  in the plane of rotation (mm); zero at theta = 0 where the tool was set.
- workpiece_setting: r = -(T + w x p): workpiece frame translated by T (mm) and turned by the
  small angles w (reported in deg), p the simulated tool position.
- time_offset: r = sim(t - tau) - sim(t) on every output at once: REC's clock lags by tau (s).
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass

import numpy as np

from ..align import Aligned
from .base import (LIN_AXIS, ROT_AXIS, Candidate, Context, _se, backlash_play,  # noqa: F401
                   below_rounding, direction_of_motion, first_order, legendre_cols, rot,
                   visited_spacing)
from .dynamic import (ServoLag, ServoLagDerivative, ServoLagHermite, ServoLagRate,  # noqa: F401
                      ThermalDirect, ThermalDrift, TimeOffset, sim_derivative)
from .friction import Backlash, Friction, QuadrantGlitch, StickSlip  # noqa: F401
from .geometric import (EncoderCyclic, PeriodicPitch, PivotOffset, ScaleError,  # noqa: F401
                        Squareness, Straightness, WorkpieceSetting, position_step)

EFFECT_NAMES = ("thermal_drift", "backlash", "servo_lag", "periodic_pitch_error", "scale_error",
                "squareness", "straightness", "pivot_offset", "workpiece_setting", "time_offset",
                "friction", "quadrant_glitch", "encoder_cyclic_error")


class Group(Candidate):
    """The same effect on several outputs at once, each with its own parameters (e.g. a servo
    lag on every axis).  Tried beside the single-output candidates because one effect common
    to all outputs (a time offset) can explain to first order what each output's own effect
    explains, and a greedy step adding one output's effect at a time cannot leave it."""

    def __init__(self, members):
        m0 = members[0]
        super().__init__(m0.name, tuple(o for m in members for o in m.outputs),
                         tuple(dict.fromkeys(i for m in members for i in m.inputs)),
                         sum(m.n_lin for m in members))
        self.members = list(members)

    @property
    def label(self) -> str:
        return "+".join(m.label for m in self.members)

    def n_params(self) -> int:
        return sum(m.n_params() for m in self.members)

    @property
    def nl_names(self):
        return tuple(n for m in self.members for n in m.nl_names)

    def split_eta(self, eta):
        out, i = [], 0
        for m in self.members:
            k = len(m.nl_names)
            out.append(np.asarray(eta[i:i + k]))
            i += k
        return out

    def split_beta(self, beta):
        out, i = [], 0
        for m in self.members:
            out.append(np.asarray(beta[i:i + m.n_lin]))
            i += m.n_lin
        return out

    def implausible(self, ctx, eta, beta):
        for m, e, b in zip(self.members, self.split_eta(eta), self.split_beta(beta)):
            why = m.implausible(ctx, e, b)
            if why:
                return f"{m.label}: {why}"
        return None

    def bounds(self, ctx):
        lo, hi = [], []
        for m in self.members:
            a, b = m.bounds(ctx)
            lo += list(a)
            hi += list(b)
        return lo, hi

    def build(self, ctx, eta):
        fixed, cols = None, []
        for m, e in zip(self.members, self.split_eta(eta)):
            f, c = m.build(ctx, e)
            if f is not None:
                fixed = dict(fixed or {})
                for k, v in f.items():
                    fixed[k] = fixed.get(k, 0.0) + v
            cols += c
        return fixed, cols

    def coarse(self, ctx, resid, rows):
        return np.concatenate([np.atleast_1d(m.coarse(ctx, resid, rows)) for m in self.members])


# effects that act on a machine at rest (the only candidates of a stop-and-measure recording)
AT_REST = ("thermal_drift", "backlash", "periodic_pitch_error", "encoder_cyclic_error", "scale_error",
           "squareness", "straightness", "pivot_offset", "workpiece_setting")
_DERIV = {"velocity": "acceleration", "angular_velocity": "angular_acceleration"}


_ROLE_WORDS = {"v", "vel", "velo", "velocity", "spd", "speed", "feed", "feedrate", "a", "acc",
               "accel", "acceleration", "cmd", "command", "commanded", "act", "actual", "set",
               "nom", "meas", "measured", "des"}


# the derivative marks of a joint coordinate in robotics: q, qd, qdd (or dq, ddq), q_dot, q_ddot
_DOTS = {"d", "dd", "dot", "ddot"}
_Q_DOTTED = re.compile(r"^d{0,2}qd{0,2}$")


def _stem(key: str) -> str:
    """A name without the words that say which derivative or which side it is:
    `spd_axis` and `acc_axis` -> 'axis', `X1_CommandVelocity` -> 'x1', `q1dd`, `qdd1`,
    `ddq1` and `q1_ddot` -> 'q1'."""
    from ..columns import _tokens
    return "".join("q" if _Q_DOTTED.match(w) else w for w in _tokens(key)
                   if w not in _ROLE_WORDS and w not in _DOTS)


def _pairs_with(sig_o, key_o: str, sig_d, key_d: str, n_rate_outs: int, n_derivs: int) -> bool:
    """Is the derivative signal d the commanded derivative of output o?"""
    if sig_o.letter is not None and sig_d.letter is not None:
        return sig_o.letter == sig_d.letter
    if _stem(key_o) and _stem(key_o) == _stem(key_d):
        return True
    return n_rate_outs == 1 and n_derivs == 1


def candidates(al: Aligned) -> list[Candidate]:
    """Every effect the data could support, given the outputs' kinds and the available drivers."""
    # outputs of unknown kind (no unit, a name that says nothing) are treated as positions of
    # an unnamed axis: the effects that need an axis letter do not apply to them
    outs = [o for o in al.outputs if al.kinds[o] in ("length", "angle", "other")]
    rates = [o for o in al.outputs if al.kinds[o] in ("velocity", "angular_velocity",
                                                        "acceleration", "angular_acceleration")]
    moving = {o for o in outs + rates if np.ptp(al.sim[o]) > 0}
    sig = al.signals
    lin_drivers = [k for k, s in sig.items() if s.kind == "length" and np.ptp(s.values) > 0]
    ang_drivers = [k for k, s in sig.items() if s.kind == "angle" and np.ptp(s.values) > 0
                   and s.letter in ROT_AXIS]
    thermal_drivers = [k for k, s in sig.items() if s.source != "sim-output"
                       and s.kind in ("temperature", "speed", "other") and np.ptp(s.values) > 0]
    out = []
    for o in outs:
        for d in thermal_drivers:
            out.append(ThermalDrift(o, d))
            if sig[d].kind == "temperature":
                out.append(ThermalDirect(o, d))
        if o in moving:
            out += [Backlash(o), Backlash(o, sign=-1), ServoLag(o), ScaleError(o)]
            if not al.at_rest:
                out.append(ServoLagRate(o))
            if not al.at_rest:
                qg = QuadrantGlitch(o)
                if qg._reversals(Context(al, al.rows(max(1, al.n // 2000))))[2] >= 2:
                    out += [qg, StickSlip(o)]
            if al.kinds[o] in ("length", "other"):
                pp = PeriodicPitch(o)
                if pp.identifiable(Context(al, al.rows(max(1, al.n // 2000)))):
                    out.append(pp)
            if al.kinds[o] in ("length", "angle", "other"):
                ec = EncoderCyclic(o)
                if ec.identifiable(Context(al, al.rows(max(1, al.n // 2000)))):
                    out.append(ec)
        if al.kinds[o] == "length":
            for d in lin_drivers:
                if d == o or (sig[d].letter is not None and sig[d].letter == sig[o].letter):
                    continue
                out += [Squareness(o, d), Straightness(o, d)]
    for o in rates:
        if o not in moving:
            continue
        # servo lag through a logged commanded derivative of the same axis when there is one
        dk = _DERIV.get(al.kinds[o])
        # SIM's side of another output counts too: a commanded acceleration compared with the
        # measured one is still the command the velocity loop followed
        all_d = [k for k, s in sig.items() if dk and s.kind == dk and s.source in ("sim", "sim-output")
                 and k != o and np.ptp(s.values) > 0]
        n_rate = sum(al.kinds[r] == al.kinds[o] for r in rates)
        derivs = [k for k in all_d if _pairs_with(sig[o], o, sig[k], k, n_rate, len(all_d))]
        out += ([c for d in derivs for c in (ServoLagDerivative(o, d), ServoLagHermite(o, d))]
                or [ServoLag(o)])
        if al.kinds[o] in ("velocity", "angular_velocity"):
            out.append(Friction(o))
    lin_outs = {sig[o].letter: o for o in outs if al.kinds[o] == "length" and sig[o].letter in LIN_AXIS}
    for d in ang_drivers:
        ax = ROT_AXIS[sig[d].letter]
        plane = [c for c in range(3) if c != ax]
        affected = [lin_outs["xyz"[c]] for c in plane if "xyz"[c] in lin_outs]
        if affected:
            out.append(PivotOffset(affected, d, ax, tuple(plane)))
    if lin_outs:
        wo = [lin_outs[L] for L in sorted(lin_outs)]
        out.append(WorkpieceSetting(al, wo, False))
        ws = WorkpieceSetting(al, wo, True)
        if ws._rot:
            out.append(ws)
    if moving:
        out.append(TimeOffset(tuple(o for o in al.outputs if o in moving)))
        lags = [c for c in out if type(c) is ServoLag]
        # the common offset and the axes' lags are entangled (the correlation peak that starts
        # the offset holds both, and a delay and a lag agree to first order): one lag added to
        # a shared offset cannot improve the fit while the other axes still need the offset as
        # it is, so the lags of all axes are also tried as one group
        if len(lags) >= 2:
            out.append(Group(lags))
        rate_lags = [c for c in out if type(c) is ServoLagRate]
        if len(rate_lags) >= 2:
            out.append(Group(rate_lags))
    if al.at_rest:
        out = [c for c in out if c.name in AT_REST]
    return out
