"""Compensate an NC program with what the loop learned: the exported geometric errors and,
switchable, the diagnosed backlash (reversal compensation), servo lag (feed-forward), friction
at reversals (reversal spikes, mtcomp.model.friction_comp) and thermal drift (offsets predicted
from the program's spindle speed or time, mtcomp.model.thermal_comp; the transport delay times
them).

Geometric and setting errors go through `mtcomp.commands.compensate_program` (the program keeps
its blocks).  The dynamic effects act on the axis commands *in time*, so with any of them on
the geometrically compensated program is sampled at the control's interpolation period h (the
model's communication step, `mtcomp.fmu.cosim.interpolate_program`, feeds honoured) and every
sample is corrected as a control does it:

- backlash b of an axis (a play centred on the servo position, as in the machine FMU): the
  command is shifted by +b/2 while the axis moves in + and by -b/2 while it moves in -, so on
  each reversal of the commanded direction it jumps by b (the axis starts with the play
  centred, as the FMU does: the first move shifts by b/2); a negative b (over-compensated, the
  FMU's mirrored play) is inverted exactly without a jump (`backlash_offsets`);
- servo lag (first-order servo, gain kv, command held over each step as in the machine FMU):
  feed-forward u_k = w_k + (w_k - w_{k-1}) / expm1(kv h), the command that makes the servo
  reach w_k at the end of step k.  At constant velocity v this is w + v T with the lead time
  T = h / expm1(kv h) (-> 1/kv for kv h -> 0): "p + v/kv" with the velocity from the feeds.
  The backward difference makes it exact at starts, stops and the backlash jumps too.

The corrected samples are written as G1 blocks, each with the feed that makes it last its
original time (rapids included: they become G1 at the rapid rate); runs of samples on one
straight line (within the axis resolution) are merged into one block.  Written by hand: no
library does program-level reversal and feed-forward compensation.

The part error of a co-simulated run (`part_error`) is the distance of the tool edge from the
programmed tool path (the ideal machine's path, a polyline), over the feed moves.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .._io import InputError
from ..errors import ErrorSet, load_errors
from ..machine import load_machine


@dataclass(frozen=True)
class ModelDynamics:
    """What the dynamic compensation uses: per axis backlash (mm or deg) and servo gain kv (1/s,
    0: ideal servo), for the communication step `step` (s) the kv values are for; `params`: all
    the model's dynamics parameters {FMU parameter name: value} (dynamics.toml: friction, delay,
    thermal model too)."""
    backlash: tuple
    kv: tuple
    step: float
    params: dict = field(default_factory=dict, compare=False)
    unidentified: tuple = ()     # parameters left out: their sigma exceeds their value

    def machine_dynamics(self, machine):
        """The mtcomp.fmu.build.MachineDynamics the model describes (no noise)."""
        from ..fmu.build import MachineDynamics
        from .dynamics import apply_dynamics
        machine = load_machine(machine)
        return apply_dynamics(MachineDynamics(kv=tuple(self.kv), backlash=tuple(self.backlash)), self.params,
                              machine, combine=False)

    def thermal(self, machine):
        """mtcomp.model.thermal_comp.ThermalModel of the model, None without a drift."""
        from .thermal_comp import ThermalModel
        return ThermalModel.from_dynamics(self.machine_dynamics(machine))

    def glitch(self, machine) -> tuple | None:
        """(height, time) per-axis tuples of the quadrant glitch (spike form), None without it."""
        d = self.machine_dynamics(machine)
        n = load_machine(machine).n_axes
        gh, gt = d.per_axis(d.glitch_height, n, "glitch"), d.per_axis(d.glitch_time, n, "glitch")
        if not any(h != 0 and t > 0 for h, t in zip(gh, gt)):
            return None
        return gh, gt

    def encoder(self, machine) -> tuple | None:
        """(period, a1, phase1, a2, phase2) per-axis tuples of the encoder cyclic error (mm or deg,
        deg for the phases), None without it."""
        d = self.machine_dynamics(machine)
        n = load_machine(machine).n_axes
        e = tuple(d.per_axis(getattr(d, f"encoder_{f}"), n, f"encoder_{f}")
                  for f in ("period", "a1", "phase1", "a2", "phase2"))
        if not any(P > 0 and (a1 or a2) for P, a1, a2 in zip(e[0], e[1], e[3])):
            return None
        return e

    def friction(self, machine) -> tuple | None:
        """(breakaway, coulomb, tau) per-axis tuples, None without friction."""
        d = self.machine_dynamics(machine)
        n = load_machine(machine).n_axes
        brk, cou = d.per_axis(d.friction_breakaway, n, "friction"), d.per_axis(d.friction_coulomb, n, "friction")
        if not any(brk) and not any(cou):
            return None
        return brk, cou, d.per_axis(d.friction_tau, n, "friction")

    @property
    def delay(self) -> float:
        return float(self.params.get("delay", 0.0))

    @property
    def interpolation(self) -> int:
        """The servos' command over a step (servo.interpolation): 0 held, 1 linear."""
        return int(self.params.get("servo.interpolation", 0))


def read_model(outdir, machine) -> tuple:
    """(ErrorSet, ModelDynamics) of a folder written by `mtcomp model export` (missing files:
    no errors, no dynamics; step from dynamics.toml, default 1 ms)."""
    from .._io import parse_toml, read_text
    from .dynamics import load_dynamics
    from .identity import check_model_machine
    machine = load_machine(machine)
    d = Path(outdir)
    if not d.is_dir():
        raise InputError("expected a model folder written by `mtcomp model export`", d)
    check_model_machine(d, machine, what="the model's compensation")
    errors = load_errors(d / "errors.toml", machine=machine) if (d / "errors.toml").is_file() else ErrorSet()
    params, step, vague = {}, 1e-3, ()
    if (d / "dynamics.toml").is_file():
        params = load_dynamics(d / "dynamics.toml", machine)
        data = parse_toml(read_text(d / "dynamics.toml", what="dynamics file"), d / "dynamics.toml")
        s = data.get("step_s", step)
        if isinstance(s, bool) or not isinstance(s, (int, float)) or not (math.isfinite(s) and s > 0):
            raise InputError(f"expected a step in s > 0, got {s!r}", d / "dynamics.toml", field="step_s")
        step = float(s)
        params, vague = _identified(params, data.get("uncertainty"))
    md = model_dynamics(params, machine, step)
    return errors, ModelDynamics(md.backlash, md.kv, md.step, md.params, vague)


# effects whose parameters come in pairs: one unidentified parameter leaves the effect out
_PAIRS = {"glitch.height.": "glitch.time.", "glitch.time.": "glitch.height.",
          "friction.breakaway.": "friction.tau.", "friction.tau.": "friction.breakaway."}


def _identified(params: dict, unc) -> tuple:
    """(params, left out): a compensation does not act on a parameter the fit did not identify
    (its sigma exceeds its value: a quadrant glitch of -4.4 µm +/- 120 mm, peaking 0.8 ms +/- 3 s
    after the reversal, wrote a 2 µm spike into every reversal).  Its effect is set to 0 (both
    parameters of a glitch or a breakaway) and named in the report."""
    if not isinstance(unc, dict):
        return params, ()
    out = dict(params)
    vague = []
    for k, sg in unc.items():
        v = params.get(k)
        if v is None or isinstance(sg, bool) or not isinstance(sg, (int, float)) or not sg > abs(float(v)):
            continue
        if k.startswith(("servo.kv.", "backlash.", "glitch.", "friction.", "encoder.a", "delay")):
            vague.append(k)
            zero = k
            for a, b in _PAIRS.items():
                if k.startswith(a) and (a.startswith("glitch.time") or a.startswith("friction.tau")):
                    zero = b + k[len(a):]     # a time constant: the effect's height goes to 0
            out[zero] = 0.0
    return out, tuple(sorted(vague))


def model_dynamics(params: dict, machine, step: float) -> ModelDynamics:
    """ModelDynamics of {FMU parameter name: value} (servo.kv.<AXIS>, backlash.<AXIS>; the
    dynamics.toml keys, `ModelExport.dynamics_values`)."""
    machine = load_machine(machine)
    n = machine.n_axes
    bl, kv = [0.0] * n, [0.0] * n
    for k, v in params.items():
        if k.startswith("servo.kv."):
            kv[machine.axis_names.index(k[len("servo.kv."):])] = float(v)
        elif k.startswith("backlash."):
            bl[machine.axis_names.index(k[len("backlash."):])] = float(v)
    return ModelDynamics(tuple(bl), tuple(kv), float(step), dict(params))


def backlash_offsets(w: np.ndarray, backlash, *, eps: float = 0.0) -> np.ndarray:
    """(K, n) shifts (mm or deg) for the sampled commands w (K, n) that cancel the machine FMU's
    backlash element of each axis.

    b > 0 (a play): +b/2 / -b/2 by the last commanded direction (0 before the first move; moves
    of at most eps keep the direction), the reversal jump of a control's backlash compensation.

    b < 0 (an over-compensated backlash: the FMU's axis is x = 2 u - P(u), P the play of width
    |b| on the drive u): the inverse of that mirror, u = (w + P2(w)) / 2 with P2 the play of
    width 2|b| on the targets started at w_0 (as the FMU's play starts centred).  It is no
    jump: after a reversal the drive moves at half the commanded speed over 2|b| of commanded
    travel (inside its band the mirror moves the axis twice as fast as the drive), so the
    opposite step a control would take out (-|b| at each reversal) is exact only at rest, and
    this is exact on the samples."""
    from .machine_ref import play
    w = np.asarray(w, float)
    b = np.broadcast_to(np.asarray(backlash, float), (w.shape[1],))
    d = np.diff(w, axis=0, prepend=w[:1])
    sgn = np.where(d > eps, 1.0, np.where(d < -eps, -1.0, 0.0))
    out = np.zeros_like(w)
    for j in range(w.shape[1]):
        if b[j] == 0:
            continue
        if b[j] < 0:
            p2, wid = float(w[0, j]), -2.0 * float(b[j])
            for k in range(len(w)):
                p2 = play(float(w[k, j]), p2, wid)
                out[k, j] = 0.5 * (p2 - w[k, j])
            continue
        nz = np.flatnonzero(sgn[:, j])
        if nz.size == 0:
            continue
        # last nonzero direction up to each sample (forward fill)
        idx = np.maximum.accumulate(np.where(sgn[:, j] != 0, np.arange(len(w)), -1))
        dirs = np.where(idx >= 0, sgn[np.maximum(idx, 0), j], 0.0)
        out[:, j] = 0.5 * b[j] * dirs
    return out


def feed_forward(w: np.ndarray, kv, step: float, interpolation: int = 0) -> np.ndarray:
    """Commands u (K, n) that make the machine FMU's servo (gain kv 1/s per axis) reach w (K, n)
    at the end of each step, the axes starting at rest at w_0; kv = 0 (ideal servo) leaves w.

    interpolation 0 (the command held over each step): u_k = w_k + (w_k - w_{k-1}) / expm1(kv h).

    interpolation 1 (ramp invariant: the command linear from u_{k-1} to u_k over step k, the
    FMU's servo.interpolation = 1): the exact step from x = w_{k-1} is x_end = u_k (1 - g/a) +
    u_{k-1} (g/a - E) + w_{k-1} E, a = kv h, E = exp(-a), g = 1 - E; x_end = w_k gives the
    recursion u_k = (w_k - E w_{k-1} - (g/a - E) u_{k-1}) / (1 - g/a), a first-order filter
    whose pole -(g/a - E)/(1 - g/a) lies in (-1, 0) (-> -1 + a/3 for small a: stable, its
    alternating transient decays over about 3/a steps), run by scipy.signal.lfilter from rest
    (u_{-1} = w_{-1} = w_0, so u_0 = w_0)."""
    w = np.asarray(w, float)
    kv = np.broadcast_to(np.asarray(kv, float), (w.shape[1],))
    if not interpolation:
        c = np.array([1.0 / math.expm1(k * step) if k > 0 else 0.0 for k in kv])
        d = np.diff(w, axis=0, prepend=w[:1])
        return w + d * c
    from scipy.signal import lfilter
    u = w.copy()
    for i, k in enumerate(kv):
        if not k > 0:
            continue
        a = k * step
        E = math.exp(-a)
        ga = -math.expm1(-a) / a
        den = 1.0 - ga
        b, a1 = [1.0 / den, -E / den], (ga - E) / den
        # direct form II transposed, state z = b1 x[-1] - a1 y[-1] at rest at w_0
        u[:, i], _ = lfilter(b, [1.0, a1], w[:, i], zi=[(b[1] - a1) * w[0, i]])
    return u


def _merge(u: np.ndarray, tol: np.ndarray, breaks=()) -> np.ndarray:
    """Indices of the samples to keep so that the dropped ones lie on the straight line (in axis
    space and time) between kept neighbours within tol (n,) per axis; the samples in `breaks`
    are kept."""
    keep = [0]
    a = 0
    K = len(u)
    j = 1
    brk = set(int(b) for b in breaks)
    while j < K - 1:
        if j in brk:
            keep.append(j)
            a = j
            j += 1
            continue
        # try to extend the run a..j+1: every sample between must be on the chord a -> j+1
        b = j + 1
        s = (np.arange(a + 1, b) - a) / (b - a)
        chord = u[a] + s[:, None] * (u[b] - u[a])
        if np.all(np.abs(u[a + 1:b] - chord) <= tol):
            j += 1
            continue
        keep.append(j)
        a = j
        j += 1
    if K > 1:
        keep.append(K - 1)
    return np.asarray(keep)


def _spindle_words(v: float) -> str:
    if v == 0:
        return "M5"
    return f"S{abs(v):.15g} {'M3' if v > 0 else 'M4'}"


def coordinate_text(value: float, resolution: float) -> str:
    """A coordinate at the control's resolution: the nearest multiple of `resolution`, written
    with the decimals that represent that multiple exactly (a 0.1 µm axis: 4 decimals; a
    0.079 µm one: 6), so that what is written is what the control runs."""
    k = round(float(value) / resolution)
    return f"{k * resolution:.{_decimals(resolution)}f}"


def _decimals(resolution: float) -> int:
    d = max(0, int(math.ceil(-math.log10(resolution) - 1e-9)))
    while d < 12 and abs(round(resolution, d) - resolution) > 1e-6 * resolution:
        d += 1
    return d


def _quantised(v: np.ndarray, res: np.ndarray) -> np.ndarray:
    return np.round(np.asarray(v, float) / res) * res


def feed_text(f: float, resolution: float) -> str:
    """A feed (mm/min) at the control's feed resolution."""
    k = max(1, round(f / resolution))
    return f"{k * resolution:.{_decimals(resolution)}f}"


def _block_feed(length: float, want: float, fmax: float, resolution: float) -> str:
    """The feed (text) of a block of `length` mm that should last `want` s: a multiple of the
    resolution, at most fmax, and rounded so that the block lasts at least `want` (the written
    program then never runs ahead of the sample clock: it is late by less than one block's
    rounding, which the next block takes back)."""
    kmax = max(1, math.floor(fmax / resolution + 1e-9))
    f = length / want * 60.0 if want > 0 else fmax
    k = min(kmax, max(1, math.floor(f / resolution)))
    return feed_text(k * resolution, resolution)


def program_max_feed(w: np.ndarray, step: float) -> float:
    """The largest path speed (mm/min, all axes as the control measures F) of the sampled
    program w (K, n): its fastest move, rapids at the rapid rate included."""
    if len(w) < 2:
        return 0.0
    return float(np.max(np.sqrt(np.sum(np.diff(w, axis=0) ** 2, axis=1)))) / step * 60.0


def limit_speed(u: np.ndarray, step: float, max_feed: float) -> tuple:
    """(commands, samples limited): u (K, n) followed at a path speed of at most max_feed
    (mm/min, over all axes as the control measures F) per step: where a correction asks for a
    faster move (the servo feed-forward's lead building up at a start or a corner, its jump at
    a backlash reversal), the command moves toward it at max_feed and catches up over the next
    steps instead of in one: no feed above max_feed and no single-block spike.  Where the
    program itself runs at max_feed the lead cannot be built (a lag compensation needs a faster
    command than the motion): the count says how often the limit acted.  Steps are appended at
    the end (at rest, until it has caught up) so that the program ends where it should.
    (Tried and dropped: limiting only the correction u - w beside the nominal motion w; it
    keeps a stale lead after each corner and measured worse on the servo + backlash case.)"""
    vmax = max_feed / 60.0 * step * (1.0 + 1e-9)
    u = np.asarray(u, float)
    if not np.any(np.sqrt(np.sum(np.diff(u, axis=0) ** 2, axis=1)) > vmax):
        return u, 0
    out = np.empty((len(u) + 10000, u.shape[1]))
    out[0] = cur = u[0].copy()
    limited = 0
    k = 1
    while k < len(out):
        tgt = u[min(k, len(u) - 1)]
        dv = tgt - cur
        n = math.sqrt(float(dv @ dv))
        if n > vmax:
            dv = dv * (vmax / n)
            limited += 1
        cur = cur + dv
        out[k] = cur
        k += 1
        if k >= len(u) and n <= vmax:
            break
    return out[:k], limited


def sampled_program(u: np.ndarray, step: float, machine, *, header=(), spindle=None, start=None,
                    max_feed: float | None = None, feed_resolution: float = 0.001) -> str:
    """NC text (G90 G94 G1 blocks) that the interpolator runs through the commands u (K, n)
    sampled every `step` s: each block lasts its samples' time (F = length / duration, mm/min,
    lengths over all axes as the control measures them); collinear runs merged.  Coordinates
    are multiples of each axis' resolution, feeds multiples of feed_resolution (mm/min): the
    rounding of each block's time is carried into the next block's feed, so that the blocks'
    times add up to the sample clock within one step (error diffusion), and no feed is above
    max_feed (default: the fastest of u).  spindle: (K,) signed speed (1/min, + M3, - M4, 0
    stopped) per sample, written as S/M3/M4/M5 words on the block that runs the sample where it
    changes (None or all 0: no spindle words).  start: where the program starts (n,); when
    u[0] is elsewhere (a thermal offset at t = 0) the first block goes there at max_feed (its
    time, a fraction of a step for a correction of a few µm, is taken from the blocks after)."""
    machine = load_machine(machine)
    res = np.asarray(machine.resolutions, float)
    fmax = float(max_feed) if max_feed else max(program_max_feed(u, step), feed_resolution)
    sp = None if spindle is None or not np.any(spindle) else np.asarray(spindle, float)
    changes = np.flatnonzero(np.diff(sp)) + 1 if sp is not None else np.zeros(0, int)
    keep = _merge(u, 0.25 * res, breaks=changes - 1)
    pending = {int(c): _spindle_words(sp[c]) for c in changes}
    names = machine.axis_names
    lines = [f"({h})" for h in header]
    lines.append("G90 G94 G1")
    fmt = lambda j, v: f"{names[j]}{coordinate_text(v, res[j])}"  # noqa: E731
    first = " " + _spindle_words(sp[0]) if sp is not None and sp[0] != 0 else ""
    q0 = _quantised(u[0], res)
    late = 0.0     # s: the written blocks' time minus the sample clock, carried into the next feed
    if start is not None:
        move = float(np.sqrt(np.sum((q0 - _quantised(start, res)) ** 2)))
        late = move / fmax * 60.0
    lines.append(" ".join(fmt(j, u[0, j]) for j in range(len(names))) + f" F{feed_text(fmax, feed_resolution)}"
                 + first)
    # The first block moves from the program's start (the parse takes unknown axes at 0, the
    # sampled program starts where the original did); the interpolator skips zero-length moves.
    prev = q0
    a = keep[0]
    for b in keep[1:]:
        p = _quantised(u[b], res)
        length = float(np.sqrt(np.sum((p - prev) ** 2)))
        spw = pending.pop(a + 1, None)
        if length == 0:
            if spw:
                lines.append(spw)   # the spindle change still acts before the next move
            continue        # the interpolator skips zero-length moves: its time goes to the next block
        ftxt = _block_feed(length, (b - a) * step - late, fmax, feed_resolution)
        late += length / float(ftxt) * 60.0 - (b - a) * step
        words = [fmt(j, u[b, j]) for j in range(len(names)) if p[j] != prev[j]]
        lines.append(" ".join(words) + f" F{ftxt}" + (" " + spw if spw else ""))
        prev, a = p, b
    lines.append("M30")
    return "\n".join(lines) + "\n"


@dataclass(frozen=True)
class CompensationReport:
    """What was compensated: geometric (bool), backlash / servo (per axis values used, or None),
    step (s, of the sampling, None without dynamics), blocks (written), geometric report (dict
    of compensate_program); friction ((breakaway, coulomb, tau) per axis, or None), glitch
    ((height, time) per axis of the quadrant glitch's spike form, or None), thermal
    ("spindle_speed" | "time" when subtracted along the program, "temperature" when left to the
    control, None), delay (s, the lead the thermal offsets were evaluated with, None),
    thermal_control (the control's parameters, mtcomp.model.thermal_comp.control_parameters,
    for a drift driven by a logged temperature); encoder ((period, a1, phase1, a2, phase2) per
    axis of the encoder cyclic error subtracted from the targets, or None)."""
    geometric: bool
    backlash: tuple | None
    kv: tuple | None
    step: float | None
    blocks: int
    geometric_report: dict = field(default_factory=dict)
    friction: tuple | None = None
    thermal: str | None = None
    delay: float | None = None
    thermal_control: dict | None = None
    glitch: tuple | None = None
    encoder: tuple | None = None
    max_feed: float | None = None     # mm/min: no written feed above it
    limited: int = 0                  # samples whose correction was spread (limit_speed)
    servo_needs: float | None = None  # mm/min: the feed the servo feed-forward needed, left out above max_feed
    unidentified: tuple = ()          # model parameters left out (sigma above their value)

    def summary(self) -> str:
        th = None
        if self.thermal == "temperature":
            th = "thermal drift (logged temperature): left to the control, parameters for it written apart"
        elif self.thermal:
            th = f"thermal offsets from the {self.thermal.replace('_', ' ')}" + (
                f" at the axes' time (delay {self.delay * 1e3:g} ms)" if self.delay else "")
        parts = ["geometric and setting errors" if self.geometric else None,
                 f"backlash {', '.join(f'{b * 1e3:g} µm' for b in self.backlash)}" if self.backlash else None,
                 f"servo feed-forward kv {', '.join(f'{k:g}' for k in self.kv)} 1/s" if self.kv else None,
                 "reversal spikes (friction breakaway " + ", ".join(f"{b * 1e3:g}" for b in self.friction[0])
                 + " µm)" if self.friction else None,
                 "quadrant glitch lead (height " + ", ".join(f"{g * 1e3:g}" for g in self.glitch[0]) + " µm)"
                 if self.glitch else None,
                 "encoder cyclic error (period " + ", ".join(f"{P * 1e3:g}" for P in self.encoder[0] if P > 0)
                 + " µm)" if self.encoder else None, th]
        what = "; ".join(p for p in parts if p) or "nothing"
        tail = f" (sampled every {self.step * 1e3:g} ms)" if self.step else ""
        if self.max_feed:
            tail += f"; feeds at most F{self.max_feed:g}"
            if self.limited:
                tail += (f" ({self.limited} samples' corrections spread over the next steps to stay below it: "
                         "raise it with --max-feed)")
        if self.unidentified:
            tail += f"; left out, not identified by the fit (sigma above the value): {', '.join(self.unidentified)}"
        if self.servo_needs:
            tail += (f"; servo feed-forward NOT applied: it needs feeds up to F{self.servo_needs:.0f}, above "
                     f"F{self.max_feed:g} (give --max-feed {math.ceil(self.servo_needs)} to apply it)")
        return f"compensated: {what}; {self.blocks} blocks{tail}"


def _no_errors(e: ErrorSet) -> bool:
    """True for an ErrorSet that changes nothing (a model folder without geometric effects)."""
    return (not e.geometric.tables and not any(e.geometric.location.values()) and not np.any(e.tool.offset)
            and not np.any(e.workpiece.translation) and not np.any(e.workpiece.angles))


def compensate_with_model(text: str, machine, errors: ErrorSet | None = None, dynamics: ModelDynamics | None = None,
                          *, geometric: bool = True, backlash: bool = True, servo: bool = True,
                          friction: bool = True, thermal: bool = True, delay: bool = True,
                          encoder: bool = True, rapid: float = 3000.0, filename: str = "<string>", provenance=None,
                          force: bool = False, max_feed: float | None = None,
                          feed_resolution: float = 0.001) -> tuple:
    """Rewrite an NC program for the machine the model describes: geometric and setting
    `errors` (when `geometric`), then the `dynamics` thermal offsets (`thermal`: spindle- or
    time-driven drift subtracted along the program; a drift driven by a logged temperature is
    left to the control, its parameters in the report), friction reversal spikes and the
    quadrant glitch's lead (`friction`),
    backlash (`backlash`) and servo lag (`servo`); `delay`: the thermal offsets are taken at the
    time the axes act (t + transport delay); `encoder`: the encoder cyclic error r of each axis
    is subtracted from its targets, w - r(w) (encoder_commands: exact to second order).  Returns (new_text, CompensationReport).  rapid:
    the G0 rate (mm/min) the control runs, for the sampling.  With every new switch off (or
    nothing of it in the model) the output is the one without them, byte for byte.

    The sampled program keeps the original's timeline (within one step), writes coordinates at
    each axis' resolution and feeds at feed_resolution (mm/min), and has no feed above max_feed
    (mm/min; default: the program's fastest move, rapids at `rapid` included): corrections
    that would need a faster move are spread over the next steps (limit_speed)."""
    from ..commands import compensate_program
    from ..gcode.provenance import check_nc_write, header_lines
    machine = load_machine(machine)
    n = machine.n_axes
    bl = tuple(float(v) for v in dynamics.backlash) if (dynamics and backlash and any(dynamics.backlash)) else None
    kv = tuple(float(v) for v in dynamics.kv) if (dynamics and servo and any(dynamics.kv)) else None
    for name, vals in (("backlash", bl), ("kv", kv)):
        if vals is not None and len(vals) != n:
            raise InputError(f"expected {n} {name} values (one per axis of {machine.name}), got {len(vals)}",
                             field=name)
    fr = dynamics.friction(machine) if (dynamics and friction and dynamics.params) else None
    gl = dynamics.glitch(machine) if (dynamics and friction and dynamics.params) else None
    tm = dynamics.thermal(machine) if (dynamics and thermal and dynamics.params) else None
    enc = dynamics.encoder(machine) if (dynamics and encoder and dynamics.params) else None
    from .thermal_comp import DRIVERS, control_parameters
    th_name = DRIVERS[tm.driver] if tm is not None else None
    th_ctl = control_parameters(tm, machine) if th_name == "temperature" else None
    th_pred = tm if th_name in ("spindle_speed", "time") else None
    lead = dynamics.delay if (th_pred is not None and delay and dynamics.delay) else None
    check_nc_write(text, filename=filename, force=force)
    sampled = (bl is not None or kv is not None or fr is not None or gl is not None or th_pred is not None
               or enc is not None)
    rep_geo: dict = {}
    geo = bool(geometric and errors is not None and not _no_errors(errors))
    if geo:
        text, rep_geo = compensate_program(text, machine, errors, filename=filename, force=force,
                                           provenance=None if sampled else list(provenance or []))
    extra = dict(friction=fr, thermal=th_name, delay=lead, thermal_control=th_ctl, glitch=gl, encoder=enc)
    if not sampled:
        return text, CompensationReport(geo, None, None, None, int(rep_geo.get("blocks", 0)), rep_geo, **extra)
    from ..fmu.cosim import interpolate_program
    from ..gcode import parse
    from .thermal_comp import spindle_profile
    h = dynamics.step
    prog = parse(text, axes=machine.axis_names, filename=filename)
    _, w = interpolate_program(prog, machine, h, rapid=rapid)
    w0 = w[0].copy()
    fmax = float(max_feed) if max_feed else program_max_feed(w, h)
    if not (fmax > 0 and math.isfinite(fmax)):
        raise InputError(f"expected a maximum feed > 0 mm/min, got {max_feed!r}", field="max_feed")
    sp = spindle_profile(prog, machine, h, rapid=rapid)
    if th_pred is not None:
        from .thermal_comp import predicted_temperature, thermal_correction, thermal_offsets
        T = predicted_temperature(th_pred, len(w), h, sp, lead=lead or 0.0)
        w = thermal_correction(machine, w, thermal_offsets(machine, w, th_pred, T, errors), errors)
    if enc is not None:
        w = encoder_commands(w, enc)
    w = _glitch_and_friction(w, h, gl, fr, bl)
    u = w + (backlash_offsets(w, bl) if bl else 0.0)
    servo_needs = None
    if kv:
        # one step at rest at the end: the feed-forward takes the lead back there (without it
        # the program ended on the last moving sample, its command v/kv past the end point)
        uf = feed_forward(np.vstack([u, u[-1:]]), kv, h, dynamics.interpolation)
        need = program_max_feed(uf, h)
        if need > fmax * (1 + 1e-6):
            # the lead a first-order servo needs is built by a faster command than the motion:
            # above the allowed feed it is left out (spread, it would lag behind every corner
            # and leave the program late by 1/kv at its end), and said so
            servo_needs, kv = need, None
        else:
            u = uf
    what = ", ".join(x for x, on in (("geometric and setting errors", geo), ("backlash", bl),
                                     ("servo feed-forward", kv), ("friction reversal spikes", fr),
                                     ("quadrant glitch lead", gl), ("encoder cyclic error", enc),
                                     (f"thermal offsets ({th_name})", th_pred),
                                     (f"at the axes' time (delay {lead:g} s)" if lead else "", lead)) if on)
    items = list(provenance or []) + [("DYNAMICS", f"{what}; sampled every {h:g} s; G0 as G1 at {rapid:g} mm/min")]
    u, limited = limit_speed(u, h, fmax)
    if sp is not None and len(sp) < len(u):
        sp = np.concatenate([sp, np.full(len(u) - len(sp), sp[-1])])
    new = sampled_program(u, h, machine, header=header_lines(items), spindle=sp, start=w0, max_feed=fmax,
                          feed_resolution=feed_resolution)
    blocks = sum(1 for ln in new.splitlines() if ln and ln[0] in machine.axis_names)
    return new, CompensationReport(geo, bl, kv, h, blocks, rep_geo, **extra, max_feed=fmax, limited=limited,
                                   servo_needs=servo_needs, unidentified=dynamics.unidentified)


def encoder_commands(w: np.ndarray, encoder) -> np.ndarray:
    """(K, n) targets with the encoder cyclic error taken out: the machine FMU's encoder element
    adds r(p) to the position p the other elements give, so they are asked for p = w - r(w)
    and the axis reaches w - r(w) + r(w - r(w)) = w + e, |e| <= max|r'| max|r| <= (2 pi/P)(a1 +
    2 a2)(|a1| + |a2|) (mean value theorem): exact to second order (12.6 nm for 0.2 µm at a 20 µm
    period).  A control interpolating linearly between the samples needs them to resolve the
    period (feed x step well below P); the machine FMU takes them at the steps.
    encoder: (period, a1, phase1, a2, phase2) per axis (ModelDynamics.encoder)."""
    from .machine_ref import encoder_cyclic
    w = np.array(w, float, copy=True)
    for i, par in enumerate(zip(*encoder)):
        if par[0] > 0:
            w[:, i] -= encoder_cyclic(w[:, i], *par)
    return w


def _glitch_and_friction(w: np.ndarray, h: float, gl, fr, bl) -> np.ndarray:
    """The drive positions (before backlash and feed-forward) for the targets w: the FMU adds the
    glitch after the friction element, so the targets are led by the glitch first
    (friction_comp.glitch_commands) and the friction inverted on that.  The glitch runs on the
    drive's reversals, which the friction (and backlash) compensation can move by a few steps:
    with friction too, the glitch's clock is taken from the drive and the two solved again until
    the drive's reversals stay (at most 4 rounds)."""
    from .friction_comp import friction_commands, glitch_commands
    if gl is None:
        return friction_commands(w, h, *fr) if fr is not None else w
    g = glitch_commands(w, h, *gl)
    s = friction_commands(g, h, *fr) if fr is not None else g
    if fr is None and not bl:
        return s
    for _ in range(4):
        drive = s + (backlash_offsets(s, bl) if bl else 0.0)
        g2 = glitch_commands(w, h, *gl, drive=drive)
        if np.array_equal(g2, g):
            break
        g = g2
        s = friction_commands(g, h, *fr) if fr is not None else g
    return s


# ---------------------------------------------------------------- part error of a co-simulation

def programmed_path(program, machine, step: float, *, rapid: float = 3000.0, arc_step_deg: float = 1.0) -> tuple:
    """(t (K,) s, path (K, 3) mm, feed (K,) bool): the ideal machine's tool edge for the
    program sampled at step (arcs as chords of at most arc_step_deg), True where the sample is
    on a feed move."""
    from ..fmu.cosim import interpolate_program
    from ..kinematics import forward
    machine = load_machine(machine)
    t, q, rap = interpolate_program(program, machine, step, rapid=rapid, with_rapid=True,
                                    max_arc_step_deg=arc_step_deg)
    return t, forward(machine, q).p, ~np.asarray(rap)


def distance_to_path(points: np.ndarray, path: np.ndarray) -> np.ndarray:
    """Distance (mm) of each point (M, 3) from the polyline path (K, 3): the nearest vertex by a
    k-d tree (scipy), then the exact distance to the segments on either side of it and of its
    neighbours (the path is sampled finely enough that the nearest segment is among those)."""
    from scipy.spatial import cKDTree
    points = np.asarray(points, float)
    path = np.asarray(path, float)
    K = len(path)
    _, near = cKDTree(path).query(points, k=min(4, K))
    near = np.atleast_2d(near.T).T if near.ndim == 1 else near
    best = np.full(len(points), np.inf)
    for c in range(near.shape[1]):
        for off in (-1, 0):
            i0 = np.clip(near[:, c] + off, 0, K - 2)
            a, b = path[i0], path[i0 + 1]
            ab = b - a
            den = np.einsum("ij,ij->i", ab, ab)
            s = np.where(den > 0, np.einsum("ij,ij->i", points - a, ab) / np.where(den > 0, den, 1.0), 0.0)
            s = np.clip(s, 0.0, 1.0)
            d = np.linalg.norm(points - (a + s[:, None] * ab), axis=1)
            best = np.minimum(best, d)
    return best


def part_error(program, signals, machine, *, rapid: float = 3000.0, fine: int = 4) -> dict:
    """Part error of a co-simulated run of `program` (signals: mtcomp.model.simulate.Signals of
    the program or of a compensated version of it, same timing) over the feed moves.

    "max", "rms" (mm): the distance of each tool edge sample from the programmed path (contour
    error; "e" per sample, with "t"), from the second sample on (the first is the machine at
    the program's start before it moves).  "reach" (mm): the other way, the largest distance of a
    commanded point of the program (one per step) from the tool edge's path: it sees the ends
    and reversal points the tool does not reach (short by b/2 with a backlash b), which lie on
    the path; it also holds the corner cut of the interpolation period (up to about v h at a
    sharp corner), which moves with the timing of the run."""
    machine = load_machine(machine)
    step = float(signals.t[1] - signals.t[0])
    # the path the program means: arcs as 0.02 deg chords (sagitta 1.5e-8 of the radius; the
    # interpolator runs them as 1 deg chords, sagitta 3.8e-5 r, an error of the run)
    _, path, _ = programmed_path(program, machine, step / fine, rapid=rapid, arc_step_deg=0.02)
    t, cmd, feed = programmed_path(program, machine, step, rapid=rapid)
    k = min(len(t), len(signals.t))
    # from the second sample on: the first is the machine at the program's start, before the
    # program moves (a compensated program gets there by a first move that takes no time)
    sel = np.flatnonzero(feed[:k])
    sel = sel[sel > 0]
    e = distance_to_path(signals.p[sel], path)
    back = distance_to_path(cmd[sel], signals.p[:k]) if sel.size > 1 else np.zeros(0)
    return {"max": float(e.max(initial=0.0)), "rms": float(np.sqrt(np.mean(e ** 2))) if e.size else 0.0,
            "reach": float(back.max(initial=0.0)), "e": e, "t": t[sel]}


def compensation_stages(dynamics: ModelDynamics | None, machine) -> list:
    """[(name, compensate_with_model switches or None for the original program)]: none,
    geometric, then + backlash, + servo, + friction, + encoder (cyclic error) and + thermal where the model has them
    (thermal only when the program predicts its driver: spindle speed or time); each stage adds
    one switch to the one before."""
    machine = load_machine(machine)
    off = dict(backlash=False, servo=False, friction=False, thermal=False, encoder=False)
    stages = [("none", None), ("geometric", dict(off))]
    if dynamics is not None and any(dynamics.backlash):
        stages.append(("+backlash", dict(off, backlash=True)))
    if dynamics is not None and any(dynamics.kv):
        stages.append(("+servo", dict(off, backlash=True, servo=True)))
    has_fr = bool(dynamics and dynamics.params and (dynamics.friction(machine) or dynamics.glitch(machine)))
    tm = dynamics.thermal(machine) if (dynamics and dynamics.params) else None
    if has_fr:
        stages.append(("+friction", dict(off, backlash=True, servo=True, friction=True)))
    enc = bool(dynamics and dynamics.params and dynamics.encoder(machine))
    if enc:
        stages.append(("+encoder", dict(off, backlash=True, servo=True, friction=True, encoder=True)))
    if tm is not None and tm.driver != 1:
        stages.append(("+thermal", dict(off, backlash=True, servo=True, friction=True, thermal=True, encoder=True)))
    return stages


def compare_compensations(text: str, machine, errors: ErrorSet, dynamics: ModelDynamics, *,
                          rapid: float = 3000.0, compiler: str = "cmake", filename: str = "<string>",
                          max_feed: float | None = None) -> dict:
    """Co-simulate the program on the machine the model describes (errors, dynamics; no noise)
    uncompensated and compensated stage by stage (`compensation_stages`: geometric only,
    + backlash, + servo feed-forward, + friction reversal spikes, + thermal offsets); the
    machine's spindle follows each run's own S words (the thermal driver).  Returns
    {stage name: part_error dict (max, rms, reach in mm)}."""
    from .simulate import simulate
    from .thermal_comp import spindle_profile
    machine = load_machine(machine)
    dyn = dynamics.machine_dynamics(machine)
    out = {}
    for name, kw in compensation_stages(dynamics, machine):
        prog = text if kw is None else compensate_with_model(text, machine, errors, dynamics, rapid=rapid,
                                                             filename=filename, max_feed=max_feed, **kw)[0]
        sp = spindle_profile(prog, machine, dynamics.step, rapid=rapid)
        sig = simulate(prog, machine, errors, dyn, step=dynamics.step, compiler=compiler,
                       spindle_speed=np.abs(sp) if np.any(sp) else 0.0)
        pe = part_error(text, sig, machine, rapid=rapid)
        out[name] = {"max": pe["max"], "rms": pe["rms"], "reach": pe["reach"]}
    return out
