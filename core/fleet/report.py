"""The fleet's HTML report: a warnings table, and per machine every trended parameter over time
with its 1-sigma band (matplotlib Figures embedded as PNG, the project's report style)."""
from __future__ import annotations

import math
import tempfile
from pathlib import Path

from .trend import Trends

# lengths are reported in µm (mm at every interface); other units as they are
_SHOW = {"mm": ("µm", 1e3)}


def display(unit: str) -> tuple[str, float]:
    """Unit to show and the factor from the stored unit: mm -> µm, mm/degC -> µm/degC."""
    head, sep, rest = unit.partition("/")
    if head in _SHOW:
        u, f = _SHOW[head]
        return u + sep + rest, f
    return unit, 1.0


def machine_figure(tr: Trends, machine: str):
    """One machine's parameters over the nights: value with a ±1σ band and ±2σ bars, the change
    warnings (red ring) and the limits (dashed red).  Returns a matplotlib Figure."""
    import datetime as dt
    from matplotlib.figure import Figure
    # a series seen only on nights not explained is in the table of those nights, not drawn
    series = [s for s in tr.series if s.machine == machine
              and any(s.night_explained(i) for i in range(len(s.dates)))]
    n = max(len(series), 1)
    ncol = min(3, n)
    nrow = math.ceil(n / ncol)
    fig = Figure(figsize=(4.2 * ncol, 2.6 * nrow), layout="constrained")
    warned = {(w.date, w.parameter, w.output, w.effect) for w in tr.warnings if w.machine == machine}
    for i, s in enumerate(series):
        ax = fig.add_subplot(nrow, ncol, i + 1)
        u, f = display(s.unit)
        x = [dt.date.fromisoformat(d) for d in s.dates]
        v = [a * f for a in s.values]
        e = [(b if math.isfinite(b) else 0.0) * f for b in s.sigmas]
        ax.fill_between(x, [a - b for a, b in zip(v, e)], [a + b for a, b in zip(v, e)],
                        color="tab:blue", alpha=0.25, lw=0, label="±1σ")
        ax.errorbar(x, v, yerr=[2 * b for b in e], fmt="o-", ms=3, lw=1, color="tab:blue",
                    elinewidth=0.6, capsize=0)
        odd = [(xi, vi) for i, (xi, vi) in enumerate(zip(x, v)) if not s.night_explained(i)]
        if odd:
            ax.plot(*zip(*odd), "s", ms=7, mfc="white", mec="0.4", label="not explained")
        hot = [(xi, vi) for xi, vi, d in zip(x, v, s.dates)
               if (d, s.parameter, s.output, s.effect) in warned]
        if hot:
            ax.plot(*zip(*hot), "o", ms=9, mfc="none", mec="tab:red", mew=1.5, label="warning")
        for r in tr.limits.rules:
            if r.applies(s):
                for lim in (r.min, r.max):
                    if math.isfinite(lim):
                        ax.axhline(lim * f, color="tab:red", ls="--", lw=0.8)
        ax.set_title(f"{s.output}: {s.effect} {s.parameter}", fontsize=9)
        ax.set_ylabel(u or "(1)", fontsize=8)
        ax.tick_params(labelsize=7)
        _night_ticks(ax, x)
    if not series:
        fig.add_subplot(1, 1, 1).text(0.5, 0.5, "no parameter to trend", ha="center")
    fig.suptitle(f"{machine}: parameters by night (band ±1σ, bars ±2σ)", fontsize=10)
    return fig


def _night_ticks(ax, days) -> None:
    """Ticks on nights (at most 8), labelled month-day."""
    from matplotlib.dates import DateFormatter
    step = max(1, math.ceil(len(days) / 8))
    ax.set_xticks(days[::step])
    ax.xaxis.set_major_formatter(DateFormatter("%m-%d"))


def _fmt(x: float, unit: str) -> str:
    u, f = display(unit)
    return "" if not math.isfinite(x) else f"{x * f:.4g} {u}".strip()


def warning_rows(tr: Trends) -> list[list]:
    rows = []
    for w in tr.warnings:
        if w.kind == "change":
            what = (f"moved {_fmt(w.value - w.reference, w.unit)} from {_fmt(w.reference, w.unit)} "
                    f"= {abs(w.value - w.reference) / w.band:.1f} × combined σ "
                    f"(> {tr.limits.k:g})")
        else:
            what = f"beyond the limit {_fmt(w.limit, w.unit)}"
        rows.append([w.machine, w.date, w.output, f"{w.effect}.{w.parameter}", w.kind,
                     f"{_fmt(w.value, w.unit)} ± {_fmt(w.sigma, w.unit)}", what])
    return rows


# above this many machines only those with a warning get a figure (a page stays readable and
# its size bounded: about 50 kB per figure); every machine keeps its table
MAX_FIGURES = 50


def html(tr: Trends, source: str = "", max_figures: int = MAX_FIGURES) -> str:
    """The report as one self-contained HTML page: figures for every machine when there are
    at most `max_figures`, else for the machines with a warning."""
    from .._io import save_figure
    from ..htmlreport import Section, render
    sections = []
    s = Section("Summary")
    s.text(f"{len(tr.machines)} machines, {len(tr.dates)} nights "
           f"({tr.dates[0] if tr.dates else '-'} to {tr.dates[-1] if tr.dates else '-'}), "
           f"{len(tr.series)} parameter series. Change test: a night against the inverse-variance "
           f"mean of up to {tr.limits.window} earlier nights since the last change, beyond "
           f"{tr.limits.k:g} combined σ (widened by the night-to-night scatter where larger); "
           f"{len(tr.limits.rules)} limit rule(s). {len(tr.unexplained)} night(s) not explained "
           "(not in the change test).")
    warned = {w.machine for w in tr.warnings}
    every = len(tr.machines) <= max_figures
    if not every:
        s.text(f"{len(tr.machines)} machines: figures only for the {len(warned)} with a warning; "
               "every machine has its table.")
    s.verdict(not tr.warnings, f"{len(tr.warnings)} warning(s) on {len(warned)} machine(s)")
    if tr.errors:
        s.verdict(False, f"{len(tr.errors)} machine-night(s) could not be diagnosed")
    sections.append(s)
    if tr.warnings:
        w = Section("Warnings")
        w.table(["machine", "night", "output", "parameter", "kind", "value ± 1σ", "why"],
                warning_rows(tr))
        sections.append(w)
    if tr.unexplained:
        u = Section("Nights not explained")
        u.text("The diagnosis left these outputs' residual above 3x their noise floor: the model "
               "named does not describe the recording (an effect the library lacks, or effects "
               "the recording could not tell apart). Their parameters are shown (grey squares) "
               "but take no part in the change test.")
        u.table(["machine", "night", "outputs unexplained", "effects named"],
                [list(x) for x in tr.unexplained])
        sections.append(u)
    if tr.errors:
        e = Section("Nights not diagnosed")
        e.table(["machine", "night", "reason"], [list(x) for x in tr.errors])
        sections.append(e)
    with tempfile.TemporaryDirectory(prefix="mtcomp-fleet-") as tmp:
        for m in tr.machines:
            sec = Section(f"Machine {m}")
            mine = [x for x in tr.series if x.machine == m]
            if mine:
                sec.table(["output", "parameter", "nights", "last night", "last value ± 1σ",
                           "first value"],
                          [[x.output, f"{x.effect}.{x.parameter}", len(x.dates), x.dates[-1],
                            f"{_fmt(x.values[-1], x.unit)} ± {_fmt(x.sigmas[-1], x.unit)}",
                            _fmt(x.values[0], x.unit)] for x in mine])
            if every or m in warned:
                png = Path(tmp) / f"{len(sections)}.png"
                save_figure(machine_figure(tr, m), png, dpi=72)
                sec.figure(png, f"{m}: each parameter by night; band ±1σ, bars ±2σ, red rings: "
                                "warnings, dashed: limits")
            sections.append(sec)
        return render("Fleet: machine parameters over time", source, sections)
