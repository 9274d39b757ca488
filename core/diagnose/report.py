"""Text summary, Markdown report and figure of a DiagnosisResult (µm/µrad/ppm for reading)."""
from __future__ import annotations

import math

SIGNATURE = {
    "thermal_drift": "slow drift following a first-order lag of a thermal load "
                     "(spindle speed or a logged temperature)",
    "backlash": "offset that flips sign with the direction of the axis' last motion",
    "servo_lag": "lag proportional to velocity with first-order dynamics (position loop gain kv)",
    "periodic_pitch_error": "error periodic in the axis position (period = screw lead)",
    "encoder_cyclic_error": "error periodic in the measured position with the encoder's signal "
                            "period (harmonics 1 and 2), the same at every speed",
    "scale_error": "error proportional to the axis' own position",
    "squareness": "error proportional to another axis' position",
    "straightness": "smooth curve of the error along another axis' travel",
    "pivot_offset": "error following (R(angle) - I) d of a rotary axis: tool edge off its centre",
    "workpiece_setting": "constant offset and small rotation of the workpiece frame",
    "time_offset": "every output lags the simulation by the same time (clock offset)",
    "quadrant_glitch": "spike against the new direction after every reversal of the axis "
                       "(friction flips, the loop rebuilds the torque); in its stick-slip form "
                       "the slide stays at the reversal point until the command has left it by "
                       "the breakaway distance, then slips back with time constant tau",
    "friction": "velocity lost against the direction of motion (Coulomb) and in proportion to it "
                "(viscous)",
}


def _val(v: float, key: str) -> str:
    """A parameter value for humans: mm -> um, small angles -> urad, ratios -> ppm."""
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "n/a"
    if key.endswith("_mm") and abs(v) < 1e-3:
        return f"{v * 1e6:.4g} nm"
    if key.endswith("_mm") and abs(v) < 1.0:
        return f"{v * 1e3:.4g} µm"
    if key.endswith("_deg") and key != "phase_deg" and abs(v) < 0.1:
        return f"{math.radians(v) * 1e6:.4g} µrad"
    if key == "scale":
        return f"{v * 1e6:.4g} ppm"
    if key.startswith("gain_mm_per"):
        return f"{v * 1e3:.4g} µm/{key.split('_per_', 1)[1]}"
    if key.endswith("_s") and not key.endswith("_per_s") and abs(v) < 1.0:
        return f"{v * 1e3:.4g} ms"
    return f"{v:.5g}"


def _len(v: float, unit: str) -> str:
    if unit == "mm":
        return f"{v * 1e6:.4g} nm" if abs(v) < 1e-3 else f"{v * 1e3:.4g} µm"
    if unit == "deg":
        return f"{math.radians(v) * 1e6:.4g} µrad"
    if unit == "mm/s" and abs(v) < 0.1:
        return f"{v * 1e3:.4g} µm/s"
    return f"{v:.4g} {unit}".strip()


def _unexplained_lines(res, indent="  ") -> list:
    out = []
    for u in res.unexplained:
        o, un = u["output"], res.units[u["output"]]
        out.append(f"{indent}{o}: unexplained mismatch, residual RMS {_len(u['rms'], un)} (held out "
                   f"{_len(u['holdout_rms'], un)}) = {u['ratio']:.3g}x its noise floor "
                   f"{_len(u['noise_floor'], un)}")
        for w in u["where"][:2]:
            out.append(f"{indent}  where: {w}")
        for c in u["correlates"]:
            out.append(f"{indent}  {c}")
        emp = u.get("empirical")
        if emp:
            out.append(f"{indent}  empirical dependence on {emp['signal']} (not a known physical "
                       f"effect): a smooth function of it lowers the held-out RMS "
                       f"{_len(emp['heldout_rms_before'], un)} -> {_len(emp['heldout_rms_after'], un)}")
    return out


def _effect_line(e) -> str:
    ps = ", ".join(f"{k} = {_val(v, k)} +/- {_val(e.uncertainty.get(k), k)}"
                   for k, v in e.params.items() if not k.startswith(("range_", "initial_state")))
    line = f"{e.name} on {e.output} (from {', '.join(e.inputs)}): {ps}"
    if e.evidence.get("meaning"):
        line += f"; {e.evidence['meaning']}"
    return line


def summary_text(res) -> str:
    a = res.alignment
    lines = [f"diagnosis of {len(res.outputs)} output(s) over {a['samples']} samples "
             f"({a['t_start']:.3f}..{a['t_end']:.3f} s, step {a['grid_step_s'] * 1e3:.3g} ms)"]
    for n in res.notes:
        lines.append(f"  note: {n}")
    for o in res.outputs:
        u = res.units[o]
        lines.append(f"  {o}: noise floor {_len(res.noise_floor[o], u)}, RMS "
                     f"{_len(res.fit['rms_before'][o], u)} -> {_len(res.fit['rms_after'][o], u)}, "
                     f"held out {_len(res.fit['holdout_rms_before'][o], u)} -> "
                     f"{_len(res.fit['holdout_rms_after'][o], u)}")
    if res.mismatch:
        lines.append("where the residual REC - SIM stands out (largest spans per output):")
        per = {}
        for m in res.mismatch:
            per.setdefault(m.output, []).append(m)
        for o, ms in per.items():
            for m in ms[:3]:
                w = m.where.split("; overall: ")[0]
                lines.append(f"  {o}: RMS {_len(m.rms, res.units[o])}; {w}")
            if len(ms) > 3:
                lines.append(f"  {o}: {len(ms) - 3} more span(s) in the JSON/report")
    else:
        lines.append("the residual REC - SIM is within the noise everywhere")
    for o, cs in res.conditions.items():
        for c in cs:
            lines.append(f"  {c}")
    if res.effects:
        lines.append("effects:")
        for e in res.effects:
            lines.append("  " + _effect_line(e))
    if res.unexplained:
        lines.append("unexplained mismatch (more than 3x the noise floor after the effects; not noise):")
        lines += _unexplained_lines(res)
    elif not res.effects:
        lines.append("effects: none (the residual is within 3x the noise floor)"
                     + (" over the whole record" if getattr(res, "local", ()) else ""))
    lines += _local_lines(res)
    return "\n".join(lines)


def _local_lines(res, indent="  ") -> list:
    """The spans whose local residual exceeds 3x the floor (held out), in words."""
    loc = getattr(res, "local", ())
    if not loc:
        return []
    out = ["locally above 3x the noise floor (held out; not explained there):"]
    for d in loc:
        un = res.units[d["output"]]
        out.append(f"{indent}{d['output']}: t {d['t_start']:.4g}-{d['t_end']:.4g} s, RMS "
                   f"{_len(d['rms'], un)} = {d['ratio']:.3g}x the floor; {d['where']}")
    return out


def markdown(res, plot_name: str | None = None) -> str:
    a = res.alignment
    out = ["# Diagnosis: simulation vs recording", "",
           f"SIM `{a['sim']}` ({a['sim_rate_hz']:.4g} Hz) against REC `{a['rec']}` "
           f"({a['rec_rate_hz']:.4g} Hz): {a['samples']} common samples from {a['t_start']:.3f} "
           f"to {a['t_end']:.3f} s every {a['grid_step_s'] * 1e3:.4g} ms. "
           f"Clock offset removed before the comparison (REC's clock minus SIM's): "
           f"{a.get('clock_offset_s', 0.0):.6g} s; remaining coarse offset "
           f"{a['coarse_offset_s'] * 1e3:.4g} ms (left to `time_offset`).", ""]
    out += [f"- {n}" for n in res.notes] + ([""] if res.notes else [])
    out += [
           "## Fit", "",
           "| output | noise floor | RMS before | RMS after | held-out before | held-out after |",
           "|---|---|---|---|---|---|"]
    for o in res.outputs:
        u = res.units[o]
        f = res.fit
        out.append(f"| {o} | {_len(res.noise_floor[o], u)} | {_len(f['rms_before'][o], u)} | "
                   f"{_len(f['rms_after'][o], u)} | {_len(f['holdout_rms_before'][o], u)} | "
                   f"{_len(f['holdout_rms_after'][o], u)} |")
    out += ["", f"Held out: each of {a['folds']} contiguous time blocks is predicted by the "
            "effects fitted on the other blocks.", "", "## Effects", ""]
    if res.effects:
        out += ["| effect | output | inputs | parameters (1 sigma) | evidence |", "|---|---|---|---|---|"]
        for e in res.effects:
            ps = "<br>".join(f"{k} = {_val(v, k)} +/- {_val(e.uncertainty.get(k), k)}"
                             for k, v in e.params.items() if not k.startswith("range_"))
            ev = ", ".join(f"{k} {v}" for k, v in e.evidence.items())
            out.append(f"| {e.name} | {e.output} | {', '.join(e.inputs)} | {ps} | {ev} |")
        out += ["", "Signatures: " + "; ".join(f"**{e.name}**: {SIGNATURE.get(e.name, '')}"
                                               for e in res.effects) + "."]
    elif not res.unexplained:
        out.append("None: the residual is within 3x the noise floor.")
    else:
        out.append("None of the library.")
    if res.unexplained:
        out += ["", "## Unexplained mismatch", "",
                "The residual stays above 3x the noise floor: this is not noise, and no effect of "
                "the library explains it.", ""]
        out += ["- " + ln.strip() for ln in _unexplained_lines(res, "")]
    if getattr(res, "local", ()):
        out += ["", "## Local mismatch", ""] + ["- " + ln.strip() for ln in _local_lines(res)[1:]]
    out += ["", "## Where the residual stands out", ""]
    if res.mismatch:
        out += ["| output | t start (s) | t end (s) | RMS | conditions |", "|---|---|---|---|---|"]
        for m in res.mismatch:
            out.append(f"| {m.output} | {m.t_start:.3f} | {m.t_end:.3f} | "
                       f"{_len(m.rms, res.units[m.output])} | {m.where} |")
    else:
        out.append("Nowhere: the residual is within the noise floor.")
    conds = [c for cs in res.conditions.values() for c in cs]
    if conds:
        out += ["", "Dependence on operating conditions:", ""] + [f"- {c}" for c in conds]
    out += ["", "## Selection log", ""] + [f"- {x}" for x in res.log] if res.log else []
    if plot_name:
        out += ["", f"![recorded, simulated and corrected]({plot_name})"]
    return "\n".join(out) + "\n"


def plot(res, path=None):
    """Figure: per output, recorded/simulated/corrected (top) and residuals before and after
    (bottom, µm / µrad), legends outside the data.  Returns the matplotlib.figure.Figure and
    writes it as PNG when `path` is given (no pyplot state, the caller's backend untouched)."""
    from matplotlib.figure import Figure
    outs = list(res.outputs)[:6]
    fig = Figure(figsize=(11, 3.2 * len(outs) + 0.6))
    axes = fig.subplots(2 * len(outs), 1, sharex=True, squeeze=False)
    t = res.t
    for i, o in enumerate(outs):
        u = res.units[o]
        scale, ru = ((1e3, "µm") if u == "mm" else (math.pi / 180 * 1e6, "µrad") if u == "deg"
                     else (1.0, u))
        ax = axes[2 * i, 0]
        ax.plot(t, res.rec[o], lw=0.8, label="recorded")
        ax.plot(t, res.sim[o], lw=0.8, ls="--", label="simulated")
        ax.plot(t, res.corrected[o], lw=0.8, ls=":", label="simulated + effects")
        ax.set_ylabel(f"{o} ({u})" if u else o)
        ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=7, frameon=False)
        ax = axes[2 * i + 1, 0]
        ax.plot(t, (res.rec[o] - res.sim[o]) * scale, lw=0.6, label="REC - SIM")
        ax.plot(t, (res.rec[o] - res.corrected[o]) * scale, lw=0.6, label="after (fitted)")
        ax.plot(t, (res.rec[o] - res.heldout_corrected[o]) * scale, lw=0.6, ls="--", alpha=0.8,
                label="after (held out)")
        first = True
        for m in res.mismatch:
            if m.output == o:
                ax.axvspan(m.t_start, m.t_end, color="0.9", zorder=0,
                           label="residual stands out" if first else None)
                first = False
        n = res.noise_floor[o] * scale
        ax.axhline(2 * n, color="k", lw=0.4, ls=":", label="±2 noise floor")
        ax.axhline(-2 * n, color="k", lw=0.4, ls=":")
        ax.set_ylabel(f"residual {o} ({ru})")
        ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=7, frameon=False)
    axes[-1, 0].set_xlabel("t (s)")
    per = {}
    for e in res.effects:
        per.setdefault(e.name, []).extend(e.outputs)
    names = ", ".join(f"{n} ({', '.join(dict.fromkeys(o))})" for n, o in per.items()) or \
        "no effect of the library"
    if res.unexplained:
        names += "; unexplained mismatch on " + ", ".join(u["output"] for u in res.unexplained)
    fig.suptitle(f"Diagnosis: {names}", fontsize=10)
    fig.tight_layout(rect=(0, 0, 0.86, 1))
    if path is not None:
        from .._io import atomic_path
        with atomic_path(path) as tmp:
            fig.savefig(tmp, format="png", dpi=110)
    return fig
