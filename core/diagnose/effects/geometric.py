"""Geometric effects: errors that are functions of the axes' positions (periodic pitch error of
a screw, cyclic error of an encoder, scale, squareness, straightness, pivot offset, workpiece
setting)."""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..align import Aligned
from .base import (LIN_AXIS, ROT_AXIS, Candidate, _se, below_rounding, legendre_cols, rot,  # noqa: F401
                   visited_spacing)


class PeriodicPitch(Candidate):
    nl_names = ("log_lead",)

    def __init__(self, output):
        super().__init__("periodic_pitch_error", (output,), (output,), 2)

    def bounds(self, ctx):
        p = ctx.values(self.outputs[0])
        rng = float(np.ptp(p))
        # identifiable leads only: at least twice the spacing of the positions that were
        # visited (a shorter period aliases), and at most half the travel
        lo = max(0.2, rng / 4000.0, 2.0 * visited_spacing(p))
        hi = max(rng / 2.0, 1.01 * lo)
        return [math.log(lo)], [math.log(hi)]

    _max_bins = 8192

    def _positions(self, ctx):
        """The positions the error repeats in (grid values): the screw turns with the command."""
        return ctx.values(self.outputs[0])

    def identifiable(self, ctx) -> bool:
        p = ctx.values(self.outputs[0])
        return 2.0 * visited_spacing(p) < float(np.ptp(p)) / 2.0

    def implausible(self, ctx, eta, beta):
        return below_rounding(ctx, self.outputs[0], beta)

    def build(self, ctx, eta):
        ph = 2 * np.pi * ctx.values(self.outputs[0]) / math.exp(eta[0])
        o = self.outputs[0]
        return None, [{o: np.sin(ph)}, {o: np.cos(ph)}]

    def coarse(self, ctx, resid, rows):
        # periodogram of the residual binned by position (the screw error repeats in p, not in
        # t): bin means on a uniform position grid, empty bins zero, FFT zero-padded 8x
        lo, hi = self.bounds(ctx)
        o = self.outputs[0]
        sl = ctx.slices[o]
        rm = rows[sl]
        pp = self._positions(ctx)[ctx.idx][rm]
        rr = resid[sl][rm]
        pmin, pmax = float(pp.min()), float(pp.max())
        lead_min = math.exp(lo[0])
        nb = int(min(self._max_bins, max(16, 4 * (pmax - pmin) / lead_min)))
        h = (pmax - pmin) / nb if pmax > pmin else 1.0
        idx = np.clip(((pp - pmin) / h).astype(int), 0, nb - 1)
        cnt = np.bincount(idx, minlength=nb)
        ok = cnt > 0
        means = np.zeros(nb)
        means[ok] = np.bincount(idx, rr, minlength=nb)[ok] / cnt[ok]
        means[ok] -= means[ok].mean()
        nfft = 8 * nb
        spec = np.abs(np.fft.rfft(means, nfft)) ** 2
        f = np.fft.rfftfreq(nfft, h)  # cycles per mm
        keep = (f >= math.exp(-hi[0])) & (f <= math.exp(-lo[0]))
        if not keep.any():
            return np.array([0.5 * (lo[0] + hi[0])])
        k = np.flatnonzero(keep)[np.argmax(spec[keep])]
        return np.array([float(np.clip(-math.log(f[k]), lo[0], hi[0]))])

    def physical(self, ctx, eta, beta, cov_eta, cov_beta):
        lead = math.exp(eta[0])
        a, b = float(beta[0]), float(beta[1])
        amp = math.hypot(a, b)
        u = ctx.al.units[self.outputs[0]]
        if cov_beta is not None and cov_beta.size and amp > 0:
            g = np.array([a / amp, b / amp])
            s_amp = float(np.sqrt(max(g @ cov_beta[:2, :2] @ g, 0)))
            gp = np.array([-b, a]) / amp ** 2
            s_ph = float(np.sqrt(max(gp @ cov_beta[:2, :2] @ gp, 0)))
        else:
            s_amp = s_ph = float("nan")
        return ({"lead_mm": lead, f"amplitude_{u}": amp, "phase_deg": math.degrees(math.atan2(b, a))},
                {"lead_mm": lead * _se(cov_eta, 0), f"amplitude_{u}": s_amp,
                 "phase_deg": math.degrees(s_ph)})


# Longest signal period taken as an encoder's (mm): optical and interferential scales have
# 0.004-0.1 mm, magnetic ones up to about 1 mm; screw leads start at about 1 mm.  The two
# ranges meet here, so that a periodic error has one name (PeriodicPitch starts at 0.2 mm).
ENCODER_MAX_PERIOD_MM = 0.2


def position_step(p: np.ndarray) -> float:
    """Spacing in position of what is known about a periodic error: the larger of the spacing
    of the visited positions and the distance travelled between two samples by 90 % of the
    moving samples (a longer step makes the phase at a sample depend on its exact time; a
    period resolved only by the slow ends of fast moves is not identified)."""
    d = np.abs(np.diff(np.asarray(p, float)))
    rng = float(np.ptp(p))
    moving = d > 1e-9 * max(rng, 1e-300)
    step = float(np.percentile(d[moving], 90)) if moving.any() else rng
    return max(visited_spacing(p), step)


class EncoderCyclic(PeriodicPitch):
    """Cyclic (interpolation) error of an encoder or resolver: periodic in the measured position
    with the encoder's signal period P, first and second harmonics (offset and gain mismatch
    of the sine/cosine signals give the first, their phase error and distortion the second),
    amplitude independent of speed.  r = sum_{h=1,2} a_h sin(2 pi h p / P) + b_h cos(2 pi h p / P),
    p the RECORDED position (the encoder reads the actual position: a following error of more
    than a fraction of P would scramble a phase taken from the command).

    Told from a screw's periodic pitch error by its period (below ENCODER_MAX_PERIOD_MM for a
    length; any period up to a revolution for an angle, where no screw applies) and by the
    harmonic 2.  Identifiable only when the shortest period modelled, P/2, is at least twice
    the spacing in position of the samples (`position_step` of the commanded positions):
    P >= 4 x that spacing, and the command travels at least two periods.
    """
    nl_names = ("log_period",)
    _max_bins = 1 << 16

    def __init__(self, output):
        Candidate.__init__(self, "encoder_cyclic_error", (output,), (output,), 4)

    def _positions(self, ctx):
        return ctx.al.rec[self.outputs[0]]

    def _range(self, ctx):
        # spacing and travel of the COMMANDED positions: the phase is taken from the recorded
        # position, but the positions must be visited by the motion, not by the error itself
        # (an axis hunting around a constant set point has a residual that is trivially a
        # function of its recorded position)
        p = ctx.values(self.outputs[0])
        travel = float(np.ptp(p))
        lo = 4.0 * position_step(p)
        top = 360.0 if ctx.al.kinds[self.outputs[0]] == "angle" else ENCODER_MAX_PERIOD_MM
        return lo, min(top, travel / 2.0)

    def bounds(self, ctx):
        lo, hi = self._range(ctx)
        return [math.log(lo)], [math.log(max(hi, 1.01 * lo))]

    def identifiable(self, ctx) -> bool:
        lo, hi = self._range(ctx)
        return 0 < lo < hi

    def implausible(self, ctx, eta, beta):
        lo, hi = self._range(ctx)
        if math.exp(eta[0]) > hi * 1.0001:
            return f"period above the encoder range ({hi:.3g})"
        return below_rounding(ctx, self.outputs[0], beta)

    def build(self, ctx, eta):
        ph = 2 * np.pi * self._positions(ctx) / math.exp(eta[0])
        o = self.outputs[0]
        return None, [{o: np.sin(ph)}, {o: np.cos(ph)}, {o: np.sin(2 * ph)}, {o: np.cos(2 * ph)}]

    def physical(self, ctx, eta, beta, cov_eta, cov_beta):
        period = math.exp(eta[0])
        u = ctx.al.units[self.outputs[0]] or "mm"
        pu = "deg" if ctx.al.kinds[self.outputs[0]] == "angle" else "mm"
        params = {f"period_{pu}": period}
        unc = {f"period_{pu}": period * _se(cov_eta, 0)}
        for h in (1, 2):
            a, b = float(beta[2 * h - 2]), float(beta[2 * h - 1])
            amp = math.hypot(a, b)
            if cov_beta is not None and cov_beta.size and amp > 0:
                c = cov_beta[2 * h - 2:2 * h, 2 * h - 2:2 * h]
                g = np.array([a, b]) / amp
                gp = np.array([-b, a]) / amp ** 2
                s_amp, s_ph = (float(np.sqrt(max(g @ c @ g, 0))), float(np.sqrt(max(gp @ c @ gp, 0))))
            else:
                s_amp = s_ph = float("nan")
            params[f"amplitude_h{h}_{u}"] = amp
            params[f"phase_h{h}_deg"] = math.degrees(math.atan2(b, a))
            unc[f"amplitude_h{h}_{u}"] = s_amp
            unc[f"phase_h{h}_deg"] = math.degrees(s_ph)
        return params, unc


class ScaleError(Candidate):
    def __init__(self, output):
        super().__init__("scale_error", (output,), (output,), 1)

    def build(self, ctx, eta):
        o = self.outputs[0]
        return None, [{o: ctx.values(o)}]

    def physical(self, ctx, eta, beta, cov_eta, cov_beta):
        return {"scale": float(beta[0])}, {"scale": _se(cov_beta, 0)}


class Squareness(Candidate):
    def __init__(self, output, driver):
        super().__init__("squareness", (output,), (driver,), 1)

    def build(self, ctx, eta):
        return None, [{self.outputs[0]: ctx.values(self.inputs[0])}]

    def physical(self, ctx, eta, beta, cov_eta, cov_beta):
        return ({"angle_deg": math.degrees(float(beta[0]))},
                {"angle_deg": math.degrees(_se(cov_beta, 0))})


class Straightness(Candidate):
    # constant and linear terms are included: a straightness profile is measured against no
    # particular line, so neither its offset nor its slope is known to be zero; squareness is
    # the one-parameter, linear special case
    ORDERS = (0, 1, 2, 3, 4)

    def __init__(self, output, driver):
        super().__init__("straightness", (output,), (driver,), len(self.ORDERS))

    def _xi(self, ctx):
        p = ctx.values(self.inputs[0])
        lo, hi = float(p.min()), float(p.max())
        return (2 * p - (lo + hi)) / max(hi - lo, 1e-12), lo, hi

    def build(self, ctx, eta):
        xi, _, _ = self._xi(ctx)
        return None, [{self.outputs[0]: c} for c in legendre_cols(xi, self.ORDERS)]

    def physical(self, ctx, eta, beta, cov_eta, cov_beta):
        _, lo, hi = self._xi(ctx)
        u = ctx.al.units[self.outputs[0]]
        xi = np.linspace(-1, 1, 201)
        prof = np.column_stack(legendre_cols(xi, self.ORDERS)) @ np.asarray(beta)
        par = {f"P{k}_{u}": float(b) for k, b in zip(self.ORDERS, beta)}
        unc = {f"P{k}_{u}": _se(cov_beta, i) for i, k in enumerate(self.ORDERS)}
        # peak-to-valley about the best straight line through the profile (ISO 230-1 style)
        lin = np.polyval(np.polyfit(xi, prof, 1), xi)
        par.update({f"peak_to_valley_{u}": float(np.ptp(prof - lin)), "range_lo_mm": lo,
                    "range_hi_mm": hi})
        return par, unc


class PivotOffset(Candidate):
    def __init__(self, outputs, driver, axis: int, comps: tuple):
        super().__init__("pivot_offset", tuple(outputs), (driver,), len(comps))
        self.axis = axis
        self.comps = comps  # tool-edge offset components (0=x,1=y,2=z) in the plane of rotation

    def build(self, ctx, eta):
        R = rot(self.axis, np.radians(ctx.values(self.inputs[0])))
        cols = []
        for c in self.comps:
            col = R[:, :, c] - np.eye(3)[c]  # (R - I) e_c
            cols.append({o: col[:, LIN_AXIS[ctx.al.signals[o].letter]] for o in self.outputs})
        return None, cols

    def physical(self, ctx, eta, beta, cov_eta, cov_beta):
        names = [f"d{'xyz'[c]}_mm" for c in self.comps]
        return ({n: float(b) for n, b in zip(names, beta)},
                {n: _se(cov_beta, i) for i, n in enumerate(names)})


class WorkpieceSetting(Candidate):
    def __init__(self, al: Aligned, outputs, with_rotation: bool):
        super().__init__("workpiece_setting", tuple(outputs), tuple(outputs), 0)
        self.with_rotation = with_rotation
        lets = {al.signals[o].letter: o for o in self.outputs}
        names = [f"t{L}_mm" for L in sorted(lets)]
        self._rot = []
        if with_rotation:
            for ax in range(3):
                # w about ax moves the two other components, each needs the third's position
                seen = [L for L in lets if LIN_AXIS[L] != ax
                        and "xyz"[3 - ax - LIN_AXIS[L]] in lets]
                if seen:
                    self._rot.append(ax)
                    names.append(f"r{'xyz'[ax]}_deg")
        self._names = names
        self.n_lin = len(names)

    @property
    def label(self) -> str:
        return super().label + ("+rotation" if self.with_rotation else "")

    def build(self, ctx, eta):
        al = ctx.al
        lets = {al.signals[o].letter: o for o in self.outputs}
        p = np.zeros((al.n, 3))
        for L, o in lets.items():
            p[:, LIN_AXIS[L]] = ctx.values(o)
        cols = [{o: -np.ones(al.n)} for L, o in sorted(lets.items())]
        for ax in self._rot:
            w = np.zeros(3)
            w[ax] = 1.0
            r = -np.cross(w, p)  # -(w x p)
            cols.append({o: r[:, LIN_AXIS[L]] for L, o in lets.items()})
        return None, cols

    def physical(self, ctx, eta, beta, cov_eta, cov_beta):
        par, unc = {}, {}
        for i, (nm, b) in enumerate(zip(self._names, beta)):
            f = math.degrees(1.0) if nm.endswith("_deg") else 1.0
            par[nm] = float(b) * f
            unc[nm] = _se(cov_beta, i) * f
        return par, unc
