"""Compensate an NC program with what the loop learned: the exported geometric errors and,
switchable, the diagnosed backlash (reversal compensation) and servo lag (feed-forward).

Geometric and setting errors go through `mtcomp.commands.compensate_program` (the program keeps
its blocks).  The dynamic effects act on the axis commands *in time*, so with either switch on
the geometrically compensated program is sampled at the control's interpolation period h (the
model's communication step, `mtcomp.fmu.cosim.interpolate_program`, feeds honoured) and every
sample is corrected as a control does it:

- backlash b of an axis (a play centred on the servo position, as in the machine FMU): the
  command is shifted by +b/2 while the axis moves in + and by -b/2 while it moves in -, so on
  each reversal of the commanded direction it jumps by b (the axis starts with the play
  centred, as the FMU does: the first move shifts by b/2);
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
    0: ideal servo), for the communication step `step` (s) the kv values are for."""
    backlash: tuple
    kv: tuple
    step: float


def read_model(outdir, machine) -> tuple:
    """(ErrorSet, ModelDynamics) of a folder written by `mtcomp model export` (missing files:
    no errors, no dynamics; step from dynamics.toml, default 1 ms)."""
    from .._io import parse_toml, read_text
    from .dynamics import load_dynamics
    machine = load_machine(machine)
    d = Path(outdir)
    if not d.is_dir():
        raise InputError("expected a model folder written by `mtcomp model export`", d)
    errors = load_errors(d / "errors.toml", machine=machine) if (d / "errors.toml").is_file() else ErrorSet()
    params, step = {}, 1e-3
    if (d / "dynamics.toml").is_file():
        params = load_dynamics(d / "dynamics.toml", machine)
        data = parse_toml(read_text(d / "dynamics.toml", what="dynamics file"), d / "dynamics.toml")
        s = data.get("step_s", step)
        if isinstance(s, bool) or not isinstance(s, (int, float)) or not (math.isfinite(s) and s > 0):
            raise InputError(f"expected a step in s > 0, got {s!r}", d / "dynamics.toml", field="step_s")
        step = float(s)
    return errors, model_dynamics(params, machine, step)


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
    return ModelDynamics(tuple(bl), tuple(kv), float(step))


def backlash_offsets(w: np.ndarray, backlash, *, eps: float = 0.0) -> np.ndarray:
    """(K, n) shifts +b/2 / -b/2 by the last commanded direction of each axis of the sampled
    commands w (K, n) (0 before its first move; moves of at most eps keep the direction)."""
    w = np.asarray(w, float)
    b = np.broadcast_to(np.asarray(backlash, float), (w.shape[1],))
    d = np.diff(w, axis=0, prepend=w[:1])
    sgn = np.where(d > eps, 1.0, np.where(d < -eps, -1.0, 0.0))
    out = np.zeros_like(w)
    for j in range(w.shape[1]):
        if b[j] == 0:
            continue
        nz = np.flatnonzero(sgn[:, j])
        if nz.size == 0:
            continue
        # last nonzero direction up to each sample (forward fill)
        idx = np.maximum.accumulate(np.where(sgn[:, j] != 0, np.arange(len(w)), -1))
        dirs = np.where(idx >= 0, sgn[np.maximum(idx, 0), j], 0.0)
        out[:, j] = 0.5 * b[j] * dirs
    return out


def feed_forward(w: np.ndarray, kv, step: float) -> np.ndarray:
    """Commands u (K, n) that make the machine FMU's servo (gain kv 1/s per axis, command held
    over each step) reach w (K, n) at the end of each step: u_k = w_k + (w_k - w_{k-1}) /
    expm1(kv h); kv = 0 (ideal servo) leaves w."""
    w = np.asarray(w, float)
    kv = np.broadcast_to(np.asarray(kv, float), (w.shape[1],))
    c = np.array([1.0 / math.expm1(k * step) if k > 0 else 0.0 for k in kv])
    d = np.diff(w, axis=0, prepend=w[:1])
    return w + d * c


def _merge(u: np.ndarray, tol: np.ndarray) -> np.ndarray:
    """Indices of the samples to keep so that the dropped ones lie on the straight line (in axis
    space and time) between kept neighbours within tol (n,) per axis."""
    keep = [0]
    a = 0
    K = len(u)
    j = 1
    while j < K - 1:
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


def sampled_program(u: np.ndarray, step: float, machine, *, header=()) -> str:
    """NC text (G90 G94 G1 blocks) that the interpolator runs through the commands u (K, n)
    sampled every `step` s: each block lasts its samples' time (F = length / duration, mm/min,
    lengths over all axes as the control measures them); collinear runs merged."""
    machine = load_machine(machine)
    res = machine.resolutions
    keep = _merge(u, 0.25 * res)
    dec = [a.decimals for a in machine.axes]
    names = machine.axis_names
    lines = [f"({h})" for h in header]
    lines.append("G90 G94 G1")
    fmt = lambda j, v: f"{names[j]}{v:.{dec[j]}f}"  # noqa: E731
    lines.append(" ".join(fmt(j, u[0, j]) for j in range(len(names))) + " F1000")
    # The first block moves from the program's start (the parse takes unknown axes at 0, the
    # sampled program starts where the original did) and must take no time: the interpolator
    # skips zero-length moves.  Written positions are rounded: feeds use the rounded lengths.
    prev = np.array([round(v, d) for v, d in zip(u[0], dec)])
    a = keep[0]
    for b in keep[1:]:
        p = np.array([round(v, d) for v, d in zip(u[b], dec)])
        length = float(np.sqrt(np.sum((p - prev) ** 2)))
        if length == 0:
            continue        # the interpolator skips zero-length moves: its time goes to the next block
        f = length / ((b - a) * step) * 60.0
        words = [fmt(j, u[b, j]) for j in range(len(names)) if p[j] != prev[j]]
        # 15 digits: the block times add up over thousands of blocks to the sample clock
        lines.append(" ".join(words) + f" F{f:.15g}")
        prev, a = p, b
    lines.append("M30")
    return "\n".join(lines) + "\n"


@dataclass(frozen=True)
class CompensationReport:
    """What was compensated: geometric (bool), backlash / servo (per axis values used, or None),
    step (s, of the sampling, None without dynamics), blocks (written), geometric report (dict
    of compensate_program)."""
    geometric: bool
    backlash: tuple | None
    kv: tuple | None
    step: float | None
    blocks: int
    geometric_report: dict = field(default_factory=dict)

    def summary(self) -> str:
        parts = ["geometric and setting errors" if self.geometric else None,
                 f"backlash {', '.join(f'{b * 1e3:g} µm' for b in self.backlash)}" if self.backlash else None,
                 f"servo feed-forward kv {', '.join(f'{k:g}' for k in self.kv)} 1/s" if self.kv else None]
        what = "; ".join(p for p in parts if p) or "nothing"
        tail = f" (sampled every {self.step * 1e3:g} ms)" if self.step else ""
        return f"compensated: {what}; {self.blocks} blocks{tail}"


def _no_errors(e: ErrorSet) -> bool:
    """True for an ErrorSet that changes nothing (a model folder without geometric effects)."""
    return (not e.geometric.tables and not any(e.geometric.location.values()) and not np.any(e.tool.offset)
            and not np.any(e.workpiece.translation) and not np.any(e.workpiece.angles))


def compensate_with_model(text: str, machine, errors: ErrorSet | None = None, dynamics: ModelDynamics | None = None,
                          *, geometric: bool = True, backlash: bool = True, servo: bool = True,
                          rapid: float = 3000.0, filename: str = "<string>", provenance=None) -> tuple:
    """Rewrite an NC program for the machine the model describes: geometric and setting
    `errors` (when `geometric`), then the `dynamics` backlash (when `backlash`) and servo lag
    (when `servo`).  Returns (new_text, CompensationReport).  rapid: the G0 rate (mm/min) the
    control runs, for the sampling."""
    from ..commands import compensate_program
    from ..gcode.provenance import compensated_line, header_lines
    machine = load_machine(machine)
    n = machine.n_axes
    bl = tuple(float(v) for v in dynamics.backlash) if (dynamics and backlash and any(dynamics.backlash)) else None
    kv = tuple(float(v) for v in dynamics.kv) if (dynamics and servo and any(dynamics.kv)) else None
    for name, vals in (("backlash", bl), ("kv", kv)):
        if vals is not None and len(vals) != n:
            raise InputError(f"expected {n} {name} values (one per axis of {machine.name}), got {len(vals)}",
                             field=name)
    done = compensated_line(text)
    if done is not None:
        raise InputError("this program was already compensated by mtcomp (provenance header): use the original "
                         "program", filename, done)
    sampled = bl is not None or kv is not None
    rep_geo: dict = {}
    geo = bool(geometric and errors is not None and not _no_errors(errors))
    if geo:
        text, rep_geo = compensate_program(text, machine, errors, filename=filename,
                                           provenance=None if sampled else list(provenance or []))
    if not sampled:
        return text, CompensationReport(geo, None, None, None, int(rep_geo.get("blocks", 0)), rep_geo)
    from ..fmu.cosim import interpolate_program
    from ..gcode import parse
    h = dynamics.step
    prog = parse(text, axes=machine.axis_names, filename=filename)
    _, w = interpolate_program(prog, machine, h, rapid=rapid)
    u = w + (backlash_offsets(w, bl) if bl else 0.0)
    if kv:
        u = feed_forward(u, kv, h)
    what = ", ".join(x for x, on in (("geometric and setting errors", geo), ("backlash", bl),
                                     ("servo feed-forward", kv)) if on)
    items = list(provenance or []) + [("DYNAMICS", f"{what}; sampled every {h:g} s; G0 as G1 at {rapid:g} mm/min")]
    new = sampled_program(u, h, machine, header=header_lines(items))
    blocks = sum(1 for ln in new.splitlines() if ln and ln[0] in machine.axis_names)
    return new, CompensationReport(geo, bl, kv, h, blocks, rep_geo)


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
    error; "e" per sample, with "t").  "reach" (mm): the other way, the largest distance of a
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
    sel = np.flatnonzero(feed[:k])
    e = distance_to_path(signals.p[sel], path)
    back = distance_to_path(cmd[sel], signals.p[:k]) if sel.size > 1 else np.zeros(0)
    return {"max": float(e.max(initial=0.0)), "rms": float(np.sqrt(np.mean(e ** 2))) if e.size else 0.0,
            "reach": float(back.max(initial=0.0)), "e": e, "t": t[sel]}


def compare_compensations(text: str, machine, errors: ErrorSet, dynamics: ModelDynamics, *,
                          rapid: float = 3000.0, compiler: str = "cmake", filename: str = "<string>") -> dict:
    """Co-simulate the program on the machine the model describes (errors, dynamics; no noise)
    uncompensated, compensated for the geometric errors only, + backlash, + servo feed-forward;
    returns {"none"|"geometric"|"+backlash"|"+servo": part_error dict (max, rms, reach in mm)}."""
    from ..fmu.build import MachineDynamics
    from .simulate import simulate
    machine = load_machine(machine)
    dyn = MachineDynamics(kv=tuple(dynamics.kv), backlash=tuple(dynamics.backlash))
    out = {}
    for name, kw in (("none", None), ("geometric", dict(backlash=False, servo=False)),
                     ("+backlash", dict(servo=False)), ("+servo", {})):
        prog = text if kw is None else compensate_with_model(text, machine, errors, dynamics, rapid=rapid,
                                                             filename=filename, **kw)[0]
        sig = simulate(prog, machine, errors, dyn, step=dynamics.step, compiler=compiler)
        pe = part_error(text, sig, machine, rapid=rapid)
        out[name] = {"max": pe["max"], "rms": pe["rms"], "reach": pe["reach"]}
    return out
