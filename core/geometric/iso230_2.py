"""ISO 230-2 evaluation of bidirectional positioning runs of one linear axis.

A run is ``n`` measurement cycles; each cycle approaches the same ``m`` target positions once in
the positive direction (increasing target, "up", ↑) and once in the negative direction ("down",
↓).  The deviation is actual minus target position, in mm.  The figures follow the definitions of
ISO 230-2 (editions 2006 and 2014 agree on all of them):

* mean unidirectional positional deviation at a position  x̄_i↑ = mean_j x_ij↑   (same for ↓)
* mean bidirectional positional deviation at a position    x̄_i = (x̄_i↑ + x̄_i↓) / 2
* reversal value at a position                             B_i = x̄_i↑ − x̄_i↓
* reversal value of the axis                               B = max |B_i|,  mean reversal B̄ = mean B_i
* estimator of the unidirectional standard uncertainty     s_i↑ = sample std (n − 1) of x_ij↑
* unidirectional repeatability at a position               R_i↑ = 4 s_i↑
* bidirectional repeatability at a position                R_i = max(2 s_i↑ + 2 s_i↓ + |B_i|, R_i↑, R_i↓)
* repeatability of the axis                                R↑ = max R_i↑, R↓ = max R_i↓, R = max R_i
* systematic positional deviation                          E↑ = max x̄_i↑ − min x̄_i↑ (same for ↓),
                                                           E = max(x̄↑, x̄↓) − min(x̄↑, x̄↓)
* range of the mean bidirectional positional deviation     M = max x̄_i − min x̄_i
* accuracy                                                 A↑ = max(x̄↑ + 2s↑) − min(x̄↑ − 2s↑) (same for ↓),
                                                           A = max(x̄↑ + 2s↑, x̄↓ + 2s↓) − min(x̄↑ − 2s↑, x̄↓ − 2s↓)

The statistics are a few lines of numpy; no maintained library implements this standard.
The CSV format is documented in docs/geometric.md.
"""
from __future__ import annotations

import csv
import io
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .._io import InputError, atomic_write, save_figure

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from matplotlib.figure import Figure

__all__ = ["PositioningRun", "Iso2302Result", "read_run_csv", "evaluate", "plot", "write_report",
           "run_to_csv"]

_UP = {"+", "up", "forward", "positive", "pos", "↑"}
_DOWN = {"-", "down", "backward", "negative", "neg", "↓", "−"}
_COLUMNS = ("target", "cycle", "direction", "deviation")
# Targets closer than this (mm) are the same target: CSV writers round differently.
_TARGET_TOL = 1e-9


@dataclass(frozen=True)
class PositioningRun:
    """Bidirectional positioning run of one axis.

    target: (m,) target positions, strictly increasing, mm.
    up, down: (n, m) deviations (actual − target) of cycle j at target i, approached in the
    positive / negative direction, mm.
    """
    target: np.ndarray
    up: np.ndarray
    down: np.ndarray
    axis: str = ""
    source: str | None = None

    def __post_init__(self):
        t = np.asarray(self.target, dtype=float)
        up = np.atleast_2d(np.asarray(self.up, dtype=float))
        dn = np.atleast_2d(np.asarray(self.down, dtype=float))
        where = self.source
        if t.ndim != 1 or t.size < 2:
            raise InputError("need at least two target positions", where, field="target")
        if np.any(np.diff(t) <= 0):
            raise InputError("target positions must be strictly increasing", where, field="target")
        if up.shape[1] != t.size or dn.shape[1] != t.size:
            raise InputError(f"deviation arrays must have {t.size} columns (one per target), got "
                             f"{up.shape[1]} (up) and {dn.shape[1]} (down)", where, field="deviation")
        if up.shape[0] != dn.shape[0]:
            raise InputError(f"unequal cycle counts: {up.shape[0]} cycles in the positive direction, "
                             f"{dn.shape[0]} in the negative direction", where, field="cycle")
        if up.shape[0] < 2:
            raise InputError("need at least two cycles per direction to estimate repeatability "
                             "(ISO 230-2 asks for five)", where, field="cycle")
        if not (np.all(np.isfinite(up)) and np.all(np.isfinite(dn)) and np.all(np.isfinite(t))):
            raise InputError("deviations and targets must be finite numbers", where, field="deviation")
        object.__setattr__(self, "target", t)
        object.__setattr__(self, "up", up)
        object.__setattr__(self, "down", dn)

    @property
    def n_cycles(self) -> int:
        return self.up.shape[0]

    @property
    def n_targets(self) -> int:
        return self.target.size


@dataclass(frozen=True)
class Iso2302Result:
    """ISO 230-2 figures of a run; per-position arrays (m,) and axis values, all in mm."""
    run: PositioningRun
    mean_up: np.ndarray        # x̄_i↑
    mean_down: np.ndarray      # x̄_i↓
    mean_bi: np.ndarray        # x̄_i
    s_up: np.ndarray           # s_i↑
    s_down: np.ndarray         # s_i↓
    reversal_i: np.ndarray     # B_i
    R_up_i: np.ndarray         # R_i↑
    R_down_i: np.ndarray       # R_i↓
    R_i: np.ndarray            # R_i
    B: float
    B_mean: float
    R_up: float
    R_down: float
    R: float
    E_up: float
    E_down: float
    E: float
    M: float
    A_up: float
    A_down: float
    A: float

    @property
    def target(self) -> np.ndarray:
        return self.run.target

    def figures(self) -> dict[str, float]:
        """Axis figures by symbol, mm."""
        return {k: getattr(self, k) for k in
                ("A", "A_up", "A_down", "B", "B_mean", "E", "E_up", "E_down", "M", "R", "R_up",
                 "R_down")}

    def summary(self) -> str:
        """Human-readable report in µm (figures and the per-position table)."""
        um = 1e3
        r = self.run
        lines = [f"ISO 230-2 evaluation{(' of axis ' + r.axis) if r.axis else ''}"
                 f"{(' (' + r.source + ')') if r.source else ''}",
                 f"{r.n_targets} target positions {r.target[0]:g} .. {r.target[-1]:g} mm, "
                 f"{r.n_cycles} cycles in each direction", ""]
        names = [("A", "accuracy, bidirectional"), ("A_up", "accuracy, positive direction"),
                 ("A_down", "accuracy, negative direction"),
                 ("R", "repeatability, bidirectional"), ("R_up", "repeatability, positive"),
                 ("R_down", "repeatability, negative"),
                 ("E", "systematic positional deviation, bidirectional"),
                 ("E_up", "systematic positional deviation, positive"),
                 ("E_down", "systematic positional deviation, negative"),
                 ("M", "range of mean bidirectional positional deviation"),
                 ("B", "reversal value"), ("B_mean", "mean reversal value")]
        for key, text in names:
            lines.append(f"  {key:<7s} {getattr(self, key) * um:10.3f} µm   {text}")
        lines += ["", "  target/mm    x_up/um  x_down/um    x_bi/um    s_up/um  s_down/um"
                      "      B_i/um     R_i/um"]
        for i, t in enumerate(r.target):
            lines.append(f"  {t:9.3f} {self.mean_up[i] * um:10.3f} {self.mean_down[i] * um:10.3f} "
                         f"{self.mean_bi[i] * um:10.3f} {self.s_up[i] * um:10.3f} "
                         f"{self.s_down[i] * um:10.3f} {self.reversal_i[i] * um:11.3f} "
                         f"{self.R_i[i] * um:10.3f}")
        return "\n".join(lines) + "\n"

    def positions_csv(self) -> str:
        """Per-position values as CSV text, mm."""
        buf = io.StringIO()
        w = csv.writer(buf, lineterminator="\n")
        w.writerow(["target", "mean_up", "mean_down", "mean_bi", "s_up", "s_down", "reversal",
                    "R_up", "R_down", "R"])
        for i, t in enumerate(self.run.target):
            w.writerow([repr(float(v)) for v in (t, self.mean_up[i], self.mean_down[i],
                                                 self.mean_bi[i], self.s_up[i], self.s_down[i],
                                                 self.reversal_i[i], self.R_up_i[i],
                                                 self.R_down_i[i], self.R_i[i])])
        return buf.getvalue()

    def figures_csv(self) -> str:
        """Axis figures as CSV text (symbol,value), mm."""
        return "symbol,value\n" + "".join(f"{k},{float(v)!r}\n" for k, v in self.figures().items())


def evaluate(run: PositioningRun) -> Iso2302Result:
    """Evaluate a bidirectional positioning run per ISO 230-2; all outputs in mm."""
    up, dn = run.up, run.down
    mu, md = up.mean(axis=0), dn.mean(axis=0)
    su, sd = up.std(axis=0, ddof=1), dn.std(axis=0, ddof=1)
    bi = 0.5 * (mu + md)
    Bi = mu - md
    Ru, Rd = 4.0 * su, 4.0 * sd
    Ri = np.maximum.reduce([2.0 * su + 2.0 * sd + np.abs(Bi), Ru, Rd])
    both = np.concatenate([mu, md])
    return Iso2302Result(
        run=run, mean_up=mu, mean_down=md, mean_bi=bi, s_up=su, s_down=sd, reversal_i=Bi,
        R_up_i=Ru, R_down_i=Rd, R_i=Ri,
        B=float(np.max(np.abs(Bi))), B_mean=float(np.mean(Bi)),
        R_up=float(Ru.max()), R_down=float(Rd.max()), R=float(Ri.max()),
        E_up=float(mu.max() - mu.min()), E_down=float(md.max() - md.min()),
        E=float(both.max() - both.min()), M=float(bi.max() - bi.min()),
        A_up=float((mu + 2 * su).max() - (mu - 2 * su).min()),
        A_down=float((md + 2 * sd).max() - (md - 2 * sd).min()),
        A=float(max((mu + 2 * su).max(), (md + 2 * sd).max())
                - min((mu - 2 * su).min(), (md - 2 * sd).min())),
    )


def _direction(text: str) -> int | None:
    t = text.strip().lower()
    if t in _UP:
        return +1
    if t in _DOWN:
        return -1
    return None


def read_run_csv(path: str | os.PathLike, axis: str = "", unit: str = "mm") -> PositioningRun:
    """Read a positioning run CSV (columns target, cycle, direction, deviation; mm).

    Rows of one cycle and direction must appear in the order the targets were approached
    (increasing for the positive direction, decreasing for the negative one); lines starting
    with ``#`` are comments (read by `mtcomp.csvtable`, docs/csv-format.md: units in the header
    such as ``deviation [um]`` are converted to `unit`: "mm", or "rad" for the angular runs of a
    measurement set).  Errors name the file, line and field.
    """
    from ..csvtable import read_csv
    path = Path(path)
    tab = read_csv(path, what="positioning run", case_sensitive=False)
    missing = [c for c in _COLUMNS if not tab.has(c)]
    if missing:
        raise tab.error(f"header lacks column(s) {', '.join(missing)}; expected "
                        f"'target,cycle,direction,deviation'")
    if not len(tab):
        raise InputError("no data rows after the header", path, tab.header_line)
    # numbers checked column by column (plain, finite, units from the header converted to mm)
    targets = tab.numbers("target", unit="mm", max_abs=1e6)
    devs = tab.numbers("deviation", unit=unit, max_abs=1e3)
    dcol = tab.col("direction").header
    # (direction, cycle) -> list of (target, deviation, line) in file order
    runs: dict[tuple[int, int], list[tuple[float, float, int]]] = {}
    for r, lineno in enumerate(tab.lines):
        target, dev = float(targets[r]), float(devs[r])
        cycle = tab.integer(r, "cycle", lo=0, hi=10**6)
        d = _direction(tab.cell(r, "direction"))
        if d is None:
            raise InputError(f"direction must be '+' or '-' (or up/down), got "
                             f"{tab.cell(r, 'direction')!r}", path, lineno, dcol)
        seq = runs.setdefault((d, cycle), [])
        if seq:
            prev = seq[-1][0]
            step = (target - prev) * d
            if abs(target - prev) <= _TARGET_TOL:
                raise InputError(f"target {target:g} repeated in cycle {cycle}, direction "
                                 f"{'+' if d > 0 else '-'} (line {seq[-1][2]})", path, lineno,
                                 "target")
            if step < 0:
                raise InputError(
                    f"non-monotonic targets: in cycle {cycle}, direction {'+' if d > 0 else '-'} "
                    f"target {target:g} follows {prev:g}; targets must "
                    f"{'increase' if d > 0 else 'decrease'} in the order of approach",
                    path, lineno, "target")
        seq.append((target, dev, lineno))
    if not runs:
        raise InputError("no data rows after the header", path, hdr_line)
    dirs = {d for d, _ in runs}
    if dirs != {+1, -1}:
        have = "positive" if +1 in dirs else "negative"
        lack = "negative" if +1 in dirs else "positive"
        raise InputError(f"missing direction: the run has only {have}-direction approaches; "
                         f"ISO 230-2 needs both (no {lack}-direction rows)", path, field="direction")
    cycles = {d: sorted(c for dd, c in runs if dd == d) for d in (+1, -1)}
    if len(cycles[+1]) != len(cycles[-1]):
        raise InputError(f"unequal cycle counts: {len(cycles[+1])} cycles in the positive "
                         f"direction, {len(cycles[-1])} in the negative direction", path,
                         field="cycle")
    # Reference target list: the targets most runs visit (in more than half of them), so a target
    # missing from the first cycle is reported as missing there, not as extra everywhere else.
    counts: dict[float, int] = {}
    for seq in runs.values():
        for t, _, _ in seq:
            key = next((k for k in counts if abs(k - t) <= _TARGET_TOL), t)
            counts[key] = counts.get(key, 0) + 1
    ref = np.array(sorted(t for t, c in counts.items() if 2 * c > len(runs)))
    if ref.size < 2:
        raise InputError("no two targets are shared by most cycles: expected every cycle to approach the "
                         "same target positions", path, field="target")
    up = np.empty((len(cycles[+1]), ref.size))
    dn = np.empty_like(up)
    for d, arr in ((+1, up), (-1, dn)):
        for j, c in enumerate(cycles[d]):
            seq = runs[(d, c)]
            ts = np.array([t for t, _, _ in seq])
            order = np.argsort(ts)
            ts_sorted = ts[order]
            if ts.size != ref.size or np.any(np.abs(ts_sorted - ref) > _TARGET_TOL):
                extra = sorted(set(np.round(ts, 9)) - set(np.round(ref, 9)))
                lack = sorted(set(np.round(ref, 9)) - set(np.round(ts, 9)))
                what = []
                if lack:
                    what.append("missing target(s) " + ", ".join(f"{v:g}" for v in lack))
                if extra:
                    what.append("extra target(s) " + ", ".join(f"{v:g}" for v in extra))
                raise InputError(
                    f"unequal cycles: cycle {c}, direction {'+' if d > 0 else '-'} has "
                    f"{'; '.join(what) or 'different targets'} compared with the targets most cycles "
                    f"approach ({', '.join(f'{v:g}' for v in ref)})", path, seq[0][2], "target")
            arr[j] = np.array([v for _, v, _ in seq])[order]
    return PositioningRun(target=ref, up=up, down=dn, axis=axis, source=str(path))


def run_to_csv(run: PositioningRun) -> str:
    """CSV text of a run in the documented input format (inverse of read_run_csv)."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(_COLUMNS)
    for j in range(run.n_cycles):
        for i in range(run.n_targets):
            w.writerow([repr(float(run.target[i])), j + 1, "+", repr(float(run.up[j, i]))])
        for i in reversed(range(run.n_targets)):
            w.writerow([repr(float(run.target[i])), j + 1, "-", repr(float(run.down[j, i]))])
    return buf.getvalue()


def plot(result: Iso2302Result, path: str | os.PathLike | None = None, title: str | None = None) -> Figure:
    """The standard's figure (mean deviations ± 2s per direction, figures A, B, E, M, R) as a
    matplotlib Figure; written as PNG to `path` only when one is given."""
    from matplotlib.figure import Figure

    um = 1e3
    r = result.run
    t = r.target
    fig = Figure(figsize=(8, 5), dpi=120)
    ax = fig.subplots()
    for j in range(r.n_cycles):
        ax.plot(t, r.up[j] * um, ".", color="tab:red", ms=3, alpha=0.5)
        ax.plot(t, r.down[j] * um, ".", color="tab:blue", ms=3, alpha=0.5)
    ax.plot(t, result.mean_up * um, "-o", color="tab:red", ms=4, label="mean, positive (↑)")
    ax.plot(t, result.mean_down * um, "-o", color="tab:blue", ms=4, label="mean, negative (↓)")
    for m, s, c in ((result.mean_up, result.s_up, "tab:red"),
                    (result.mean_down, result.s_down, "tab:blue")):
        ax.plot(t, (m + 2 * s) * um, "--", color=c, lw=0.8)
        ax.plot(t, (m - 2 * s) * um, "--", color=c, lw=0.8)
    ax.plot(t, result.mean_bi * um, ":", color="k", lw=1, label="mean bidirectional")
    ax.axhline(0.0, color="0.6", lw=0.5)
    ax.set_xlabel("target position / mm")
    ax.set_ylabel("positional deviation / µm")
    ax.set_title(title or f"ISO 230-2 positioning{(' of axis ' + r.axis) if r.axis else ''}")
    text = "\n".join(f"{k} = {getattr(result, k) * um:.2f} µm" for k in ("A", "R", "E", "M", "B"))
    ax.text(0.01, 0.98, text, transform=ax.transAxes, va="top", ha="left", fontsize=9,
            family="monospace", bbox=dict(facecolor="white", alpha=0.8, edgecolor="0.7"))
    ax.legend(loc="upper left", bbox_to_anchor=(1.02, 1.0), fontsize=8)
    ax.grid(True, lw=0.3)
    fig.tight_layout()
    if path is not None:
        save_figure(fig, path)
    return fig


def write_report(result: Iso2302Result, stem: str | os.PathLike) -> dict[str, Path]:
    """Write <stem>.txt (summary), <stem>_positions.csv, <stem>_figures.csv and <stem>.png."""
    stem = Path(stem)
    out = {
        "text": atomic_write(stem.with_name(stem.name + ".txt"), result.summary()),
        "positions": atomic_write(stem.with_name(stem.name + "_positions.csv"),
                                  result.positions_csv()),
        "figures": atomic_write(stem.with_name(stem.name + "_figures.csv"), result.figures_csv()),
    }
    out["plot"] = stem.with_name(stem.name + ".png")
    plot(result, out["plot"])
    return out
