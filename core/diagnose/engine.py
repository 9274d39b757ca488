"""diagnose(): align, locate, explain, re-predict; the DiagnosisResult it returns."""
from __future__ import annotations

import json
import math
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from . import align as _align
from . import data as _data
from . import rows as _rows
from .._io import InputError
from .effects import Context, candidates
from .locate import Mismatch, conditions, empirical_dependence, local_flags, locate
from .select import Settings, fit, heldout_neutral, joint_covariance, model_columns, n_effective, select


@dataclass(frozen=True)
class EffectResult:
    """One effect named by the diagnosis, with its fitted parameters (mm, deg, s, degC, rpm).

    Frozen and self-describing so that it can be exported to a machine model: `params` and
    `uncertainty` (one standard deviation) are keyed by names that carry their unit
    (``backlash_mm``, ``kv_per_s``, ``tau_s``, ``angle_deg``; ``scale`` is dimensionless).
    """
    name: str
    outputs: tuple
    inputs: tuple
    params: dict
    uncertainty: dict      # one standard deviation, same keys as params
    evidence: dict
    rms: dict              # output -> RMS of the effect's contribution (output unit)

    @property
    def output(self) -> str:
        return ",".join(self.outputs)

    def to_dict(self) -> dict:
        return {"name": self.name, "output": self.output, "inputs": list(self.inputs),
                "params": self.params, "uncertainty": self.uncertainty,
                "evidence": dict(self.evidence, rms=self.rms)}


@dataclass(frozen=True)
class DiagnosisResult:
    """What disagrees, where, which effects explain it, and how much the fit improves.

    `fit` holds RMS per output (output unit) of REC - SIM before and after adding the effects,
    on all aligned samples and on held-out data (each of `folds` contiguous time blocks predicted
    by the model fitted without it).
    """
    outputs: tuple
    units: dict
    noise_floor: dict
    mismatch: tuple
    effects: tuple
    fit: dict
    alignment: dict
    conditions: dict
    log: tuple
    unexplained: tuple = ()  # per output whose residual stays > 3x its noise floor: dicts
    notes: tuple = ()        # alignment and column decisions, in words
    local: tuple = ()        # spans whose local residual exceeds 3x the floor (locate.local_flags)
    t: np.ndarray = field(repr=False, default=None)
    rec: dict = field(repr=False, default=None)
    sim: dict = field(repr=False, default=None)
    corrected: dict = field(repr=False, default=None)
    heldout_corrected: dict = field(repr=False, default=None)

    @property
    def names(self) -> list[str]:
        return [e.name for e in self.effects]

    def to_dict(self) -> dict:
        return _clean({
            "outputs": list(self.outputs),
            "noise_floor": dict(self.noise_floor),
            "mismatch": [m.to_dict() for m in self.mismatch],
            "effects": [e.to_dict() for e in self.effects],
            "unexplained": list(self.unexplained),
            "local": list(self.local),
            "fit": self.fit,
            "alignment": {k: v for k, v in self.alignment.items() if k not in ("sim", "rec")},
            "notes": list(self.notes),
        })

    def to_json(self, indent: int = 2) -> str:
        return json.dumps(self.to_dict(), indent=indent)

    def summary(self) -> str:
        from .report import summary_text
        return summary_text(self)

    def report(self, plot_name: str | None = None) -> str:
        from .report import markdown
        return markdown(self, plot_name)

    def plot(self, path=None):
        """The diagnosis figure (a matplotlib.figure.Figure); written as PNG when `path` is given."""
        from .report import plot
        return plot(self, path)


def _clean(x):
    """JSON-safe: numpy scalars to Python, NaN/inf to None."""
    if isinstance(x, dict):
        return {str(k): _clean(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_clean(v) for v in x]
    if isinstance(x, (np.floating, float)):
        x = float(x)
        return x if math.isfinite(x) else None
    if isinstance(x, np.integer):
        return int(x)
    if isinstance(x, np.str_):
        return str(x)
    return x


def _nrem(tab) -> int:
    return 0 if tab.excluded is None else int(tab.excluded.sum())


def _row_filter_notes(conds, S, R) -> tuple:
    """Check that every row condition names a column of SIM or REC; say what it removed."""
    if not conds:
        return ()
    for c in conds:
        if c not in S.row_filter and c not in R.row_filter:
            have = sorted(set(S.columns) | set(R.columns))
            raise InputError(f"{c.describe()}: no column {c.column!r} in SIM or REC (they have "
                             f"{', '.join(have)})", field=c.option)
    said = "; ".join(c.describe() for c in conds)
    for tab, role in ((S, "SIM"), (R, "REC")):
        if tab.n - _nrem(tab) < 8:
            raise InputError(f"the row filter ({said}) leaves {tab.n - _nrem(tab)} rows of {role} "
                             "(expected at least 8)", field=conds[0].option)
    return (f"row filter ({said}): {_nrem(S)} of {S.n} rows of SIM and {_nrem(R)} of {R.n} rows "
            "of REC removed; the fit and the held-out RMS use only the rows kept",)


def _rms(a) -> float:
    a = np.asarray(a, float)
    return float(np.sqrt(np.mean(a * a))) if a.size else float("nan")


# a residual above this many noise floors is not noise: it is reported as unexplained
UNEXPLAINED_RATIO = 3.0


def _per_recording(al, ctx, oof) -> dict:
    """Held-out RMS before and after per recording and output (each recording predicted by the
    model fitted on the others), output units."""
    out = {}
    for r in al.recordings:
        inr = (ctx.idx >= r.start) & (ctx.idx < r.stop)
        d = {"holdout_rms_before": {}, "holdout_rms_after": {}}
        for o in al.outputs:
            sl = ctx.slices[o]
            d["holdout_rms_before"][o] = _rms(ctx.z0[sl][inr] * ctx.sigma[o])
            d["holdout_rms_after"][o] = _rms(oof[sl][inr] * ctx.sigma[o])
        b = sum(v ** 2 for v in d["holdout_rms_before"].values())
        a = sum(v ** 2 for v in d["holdout_rms_after"].values())
        d["ratio"] = (a / b) ** 0.5 if b > 0 else float("nan")
        out[r.name] = d
    return out


def _loop_shapes(ctx, final, effects, floor) -> tuple:
    """A backlash is named only with the shape of a play: where what is left after it still
    trends with the travel since each reversal, the loop is gradual (a hysteresis), said so."""
    from .effects.friction import loop_shape
    notes = ()
    for e in effects:
        if e.name != "backlash":
            continue
        o = e.outputs[0]
        sh = loop_shape(ctx, o, final.resid[ctx.slices[o]] * ctx.sigma[o], floor[o])
        if sh is None:
            continue
        e.evidence["loop_shape"] = {"trend_share": round(sh["share"], 3), "swing": sh["swing"],
                                    "play": not sh["significant"]}
        if sh["significant"]:
            notes += (f"{o}: the reversal error is not the step of a play: after the backlash "
                      f"what is left still swings by {sh['swing']:.3g} {ctx.al.units[o]} with the "
                      "travel since each reversal (a gradual hysteresis loop, e.g. friction "
                      "pre-sliding or a Preisach-type loop; the backlash named is its step part "
                      "only)",)
    return notes


def _same_file(a, b) -> bool:
    """SIM and REC are paths of one file."""
    import os
    if not (isinstance(a, (str, Path)) and isinstance(b, (str, Path))):
        return False
    try:
        return os.path.samefile(a, b)
    except OSError:
        return False


def _pairs(sim, rec) -> tuple[list, list]:
    """SIM and REC as equally long lists of sources: one each, lists of several (one machine's
    recordings), or two folders whose CSV files of the same name are paired."""
    def many(x):
        return isinstance(x, (list, tuple))
    if not many(sim) and not many(rec) and isinstance(sim, (str, Path)) and Path(sim).is_dir():
        if not (isinstance(rec, (str, Path)) and Path(rec).is_dir()):
            raise InputError(f"--sim {sim} is a folder: --rec must be a folder too", field="--rec")
        a = {p.name: p for p in sorted(Path(sim).glob("*.csv"))}
        b = {p.name: p for p in sorted(Path(rec).glob("*.csv"))}
        both = sorted(set(a) & set(b))
        if not both:
            raise InputError(f"no CSV file of the same name in {sim} and {rec} (SIM and REC of one "
                             "recording are paired by their file name)", field="--rec")
        return [a[k] for k in both], [b[k] for k in both]
    sims = list(sim) if many(sim) else [sim]
    recs = list(rec) if many(rec) else [rec]
    if len(sims) != len(recs) or not sims:
        raise InputError(f"{len(sims)} SIM and {len(recs)} REC sources: give one --rec for each "
                         "--sim, in the same order", field="--rec")
    return sims, recs


def _recording_names(sims, recs) -> list:
    """A short distinct name per recording: REC's file name, or its folder and name."""
    def nm(x, i):
        return Path(x).name if isinstance(x, (str, Path)) else f"recording {i + 1}"
    names = [nm(r, i) for i, r in enumerate(recs)]
    if len(set(names)) < len(names):
        names = [(Path(r).parent.name if isinstance(r, (str, Path)) else f"recording {i + 1}")
                 for i, r in enumerate(recs)]
    if len(set(names)) < len(names):
        names = [f"recording {i + 1}" for i in range(len(recs))]
    return names


def _aligned_pair(sim, rec, conds, outputs, inputs, units, same_clock, dt):
    """Load one SIM/REC pair and put it on its grid: (Aligned, SIM table, REC table, same_clock)."""
    one_log = _same_file(sim, rec)
    S = _data.load(sim, "SIM", units, conds, dt)
    R = S if one_log else _data.load(rec, "REC", units, conds, dt)
    log_notes = ()
    if one_log:
        # the commanded and the measured signals of one log: split by the names' role words,
        # and logged on one clock (no clock offset to estimate; a delay is the machine's)
        S, R, log_notes = _data.split_log(S, outputs, inputs)
        same_clock = True
    filter_notes = _row_filter_notes(conds, S, R) + log_notes
    S, R, clock_notes = _data.common_clock(S, R)
    S, outs, pair_notes = _data.pair_columns(S, R, outputs)
    if one_log:
        R, kept_notes = _data.compared_only(R, outs or [k for k in R.columns if k in S.columns])
        pair_notes += kept_notes
    _refuse_unknown_units(S, R, outs)
    from .mistakes import time_scale_hint
    hint = time_scale_hint(S.t, R.t)
    try:
        al = _align.align(S, R, outputs=outs, inputs=inputs,
                          notes=filter_notes + tuple(S.notes) + tuple(R.notes) + clock_notes
                          + pair_notes + ((hint,) if hint else ()), same_clock=same_clock)
    except InputError as e:
        if hint:
            raise InputError(f"{e.what}; {hint}", e.file, e.line, field=e.field) from None
        raise
    return al, S, R, same_clock


def _refuse_unknown_units(S, R, outs) -> None:
    """A compared column must have a unit the diagnosis understands: a unit it does not know
    is refused by name (an input with one is kept as written)."""
    keys = outs or [k for k in R.columns if k in S.columns]
    for tab in (S, R):
        for k in keys:
            c = tab.columns.get(k)
            if c is not None and c.kind == "other" and c.kind_from in ("unit", "option") and c.unit:
                raise InputError(f"unknown unit {c.unit!r} of compared column {k!r} (expected a "
                                 "length, angle, velocity or acceleration unit: mm, um, nm, inch, "
                                 "deg, rad, arcmin, arcsec, mm/s, deg/s, mm/s^2, or a resolution "
                                 "like 0.1um for counts)", tab.path, field=c.header)


def diagnose(sim, rec, settings: Settings | None = None, progress=None, outputs=None,
             inputs=None, units=None, where=None, exclude_rows=None,
             same_clock: bool = False, dt: float | None = None) -> DiagnosisResult:
    """Diagnose a simulation against a recording.

    sim, rec: CSV paths, or mappings header -> 1-D array (dict, DataFrame-like) with a `t`
    column in s (headers may carry units, ``z[um]``).  Columns in both are the outputs compared;
    all others are inputs the effects may use.  outputs / inputs: column names to compare /
    to treat as inputs only; units: column name -> unit for columns whose header has none.
    Names are case-sensitive.  where / exclude_rows: row conditions ``'COL!=50'``,
    ``'phase==Prep'`` (`mtcomp.diagnose.rows`): only rows where every `where` holds and no
    `exclude_rows` does take part in the fit and the held-out RMS; nothing is interpolated across
    the rows removed.  same_clock: SIM and REC share one clock (no clock offset is estimated; a
    common delay is reported as a transport delay, `time_offset`).  dt: the logging period in s of
    a CSV without a time column (rows equally spaced).  SIM and REC may be one file whose
    commanded and actual columns are paired by `outputs` (``X_cmd=X_act``).  Raises
    mtcomp.InputError for unusable input.
    """
    st = settings or Settings()
    say = progress or (lambda msg: None)
    conds = _rows.parse(where, exclude_rows)
    sims, recs = _pairs(sim, rec)
    pairs = [_aligned_pair(s, r, conds, outputs, inputs, units, same_clock, dt)
             for s, r in zip(sims, recs)]
    if len(pairs) > 1:
        from .recordings import join
        names = _recording_names(sims, recs)
        al = join([p[0] for p in pairs], names)
        st = replace(st, folds=len(pairs))
    else:
        al = pairs[0][0]
    _, S, R, same_clock = pairs[0]
    say(f"aligned: {al.n} samples every {al.dt:g} s, outputs {', '.join(al.outputs)}")
    mism = locate(al)
    # selection on an evenly strided subset of the grid (filters still run on all samples),
    # then the chosen effects are refitted on every sample
    step = max(1, int(np.ceil(len(al.rows()) / st.fit_rows)))
    ctx_sel = Context(al, al.rows(step))
    cands = candidates(al)
    # a candidate whose parameter range is empty on these data cannot be identified (a servo
    # lag when both files are sampled every few seconds): it is not offered
    cands = [c for c in cands if all(a < b for a, b in zip(*c.bounds(ctx_sel)))]
    say(f"{len(cands)} candidate effects, selecting on {ctx_sel.n} of {al.n} samples")
    chosen, evidence, log = select(ctx_sel, cands, st, progress=say)
    ctx = Context(al, al.rows()) if step > 1 else ctx_sel
    rows = ctx.idx  # grid samples backed by data (all, unless the files have gaps)

    def full(x, o):
        """A per-output array on ctx's rows spread onto the whole grid (0 in gaps)."""
        out = np.zeros(al.n)
        out[rows] = x
        return out
    final = (fit(ctx, chosen.cands, chosen.etas, max_nfev=15) if step > 1 and chosen.cands
             else (chosen if step == 1 else fit(ctx, [], [])))

    # uncertainties: least-squares covariance scaled by the residual variance, inflated for
    # correlated residuals (N / N_effective)
    dof = max(final.n_rows - final.k, 1)
    s2 = final.rss / dof
    infl = ctx.N / n_effective(ctx)
    # nonlinear parameters and amplitudes together: an amplitude correlated with a time
    # constant is as uncertain as the pair (the amplitudes' Gram matrix alone holds eta fixed)
    ce_all, cb_all = joint_covariance(ctx, final)
    cov_eta_all = ce_all * s2 * infl
    cov_beta_all = cb_all * s2 * infl
    effects = []
    clock_fine = (0.0, 0.0)
    latency_note = ()
    # outputs that carry a servo lag in the final model (a group holds one per output)
    lagged = {o for c in final.cands for m in getattr(c, "members", [c])
              if m.name == "servo_lag" for o in m.outputs}
    ie = ib = 0
    for c, eta, beta, contrib in zip(final.cands, final.etas, final.betas, final.contrib):
        ne, nb = len(eta), len(beta)
        ce = cov_eta_all[ie:ie + ne, ie:ie + ne] if cov_eta_all is not None and ne else np.zeros((0, 0))
        cb = cov_beta_all[ib:ib + nb, ib:ib + nb] if cov_beta_all is not None and nb else np.zeros((0, 0))
        ie += ne
        ib += nb
        if hasattr(c, "members"):
            # a group reports one effect per output, each with its own parameters
            je = jb = 0
            for m, em, bm in zip(c.members, c.split_eta(eta), c.split_beta(beta)):
                cem = ce[je:je + len(em), je:je + len(em)] if ce.size else np.zeros((0, 0))
                cbm = cb[jb:jb + len(bm), jb:jb + len(bm)] if cb.size else np.zeros((0, 0))
                je += len(em)
                jb += len(bm)
                params, unc = m.physical(ctx, em, bm, cem, cbm)
                rms = {o: _rms(contrib[ctx.slices[o]] * ctx.sigma[o]) for o in m.outputs}
                effects.append(EffectResult(m.name, tuple(m.outputs), tuple(m.inputs), params,
                                            unc, evidence.get(c.label, {}), rms))
            continue
        params, unc = c.physical(ctx, eta, beta, ce, cb)
        rms = {o: _rms(contrib[ctx.slices[o]] * ctx.sigma[o]) for o in c.outputs}
        if c.name == "time_offset" and same_clock:
            # one clock (the user says so): a common delay is a delay of the machine or its
            # loop (or of the logger's sampling), never a clock offset
            effects.append(EffectResult(
                c.name, tuple(c.outputs), tuple(c.inputs), params, unc,
                dict(evidence.get(c.label, {}),
                     meaning="transport delay: SIM and REC share one clock (--same-clock), so "
                             "REC(t) = SIM(t - delay) is a delay of the machine or its loop, not a "
                             "clock offset"), rms))
            continue
        if c.name == "time_offset" and (al.clock_offset or set(c.outputs) <= lagged
                                        or any(r.clock_offset_s for r in al.recordings)):
            # the clocks were aligned: what is left of the offset refines that alignment (a
            # latency on top of another clock start cannot be told from it).  Likewise a common
            # delay of outputs that all lag: a transport delay and a first-order lag agree to
            # first order (-(delay + tau) * rate), and a delay common to every lagging output
            # cannot be attributed to the clocks, the logger or the drives from the data; it is
            # timing of the recording, not a further effect of the machine
            clock_fine = (params["offset_s"], unc["offset_s"])
            if not al.clock_offset:
                latency_note = (f"a common delay of {params['offset_s'] * 1e3:.3g} ms "
                                f"(+/- {unc['offset_s'] * 1e3:.2g} ms) beside the servo lags is kept "
                                f"in the alignment: logger or loop latency, not separable from "
                                f"the lags or from a clock offset",)
            continue
        ev = evidence.get(c.label, {})
        said = c.meaning(params) if hasattr(c, "meaning") else None
        if said:
            ev = dict(ev, meaning=said)
        effects.append(EffectResult(c.name, tuple(c.outputs), tuple(c.inputs), params, unc, ev, rms))

    sig = ctx.sigma
    corrected, held = {}, {}
    oof = np.array(ctx.z0, copy=True)
    if final.cands:
        # held-out prediction: fold models fitted on the selection subset without the block,
        # evaluated on every sample of the block; every parameter, the nonlinear ones (time
        # constants, leads, widths) included, is refitted without the held-out block from the
        # candidates' own neutral starts (never from the values fitted on all samples)
        # the selection's last judgement of the chosen model is this prediction (the same
        # model on the same rows): reused
        folds = chosen.extra.get("heldout_folds")
        if not folds or [c.label for c in folds[0].cands] != [c.label for c in final.cands]:
            folds = []
            heldout_neutral(ctx_sel, final.cands, st.folds, fits=folds,
                            beta_default=np.concatenate(final.betas) if final.betas else None)
        starts = [f.extra["held"][0] for f in folds] + [np.inf]
        for i, f in enumerate(folds):
            inblk = (ctx.t >= starts[i]) & (ctx.t < starts[i + 1])
            pred = np.zeros(ctx.N)
            for (fx, B), beta in zip(model_columns(ctx, f.cands, f.etas), f.betas):
                pred += (fx if fx is not None else 0.0) + (B @ beta if B.shape[1] else 0.0)
            m = np.tile(inblk, len(al.outputs))
            oof[m] = ctx.z0[m] - pred[m]
    fitd = {"rms_before": {}, "rms_after": {}, "holdout_rms_before": {}, "holdout_rms_after": {}}
    # noise floor: the residual after the fit shows the noise better when the effects change
    # quickly between samples (sparse recordings); never above the estimate before the fit
    floor = {o: min(al.noise_floor[o], _align.noise_sigma(final.resid[ctx.slices[o]] * sig[o],
                                                            al.quantum[o]))
             for o in al.outputs}
    for o in al.outputs:
        sl = ctx.slices[o]
        before = (al.rec[o] - al.sim[o])[rows]
        after = final.resid[sl] * sig[o]
        corrected[o] = al.rec[o] - full(after, o)
        held[o] = al.rec[o] - full(oof[sl] * sig[o], o)
        fitd["rms_before"][o] = _rms(before)
        fitd["rms_after"][o] = _rms(after)
        fitd["holdout_rms_before"][o] = _rms(before)
        fitd["holdout_rms_after"][o] = _rms(oof[sl] * sig[o])
    if al.recordings:
        fitd["recordings"] = _per_recording(al, ctx, oof)
    shape_notes = _loop_shapes(ctx, final, effects, floor)
    from .noise import check_residual
    fitd["whiteness"] = {}
    white_notes = ()
    for o in al.outputs:
        w = check_residual(oof[ctx.slices[o]] * sig[o], al.kinds[o],
                          al.sim[o][rows] if al.kinds[o] == "angle" else None)
        fitd["whiteness"][o] = {k: v for k, v in w.items() if k != "reasons"}
        if not w["white"] and fitd["holdout_rms_after"][o] > 1.5 * floor[o]:
            white_notes += (f"{o}: what is left is not white noise ({'; '.join(w['reasons'])}): "
                            "structure the effects do not explain, whatever its size against the "
                            "noise floor",)
    from .mistakes import value_scale_notes
    unit_notes = value_scale_notes(al, fitd["rms_after"])
    cond = {o: conditions(al, o, al.rec[o] - al.sim[o], sig[o]) for o in al.outputs}
    unexplained = []
    floor_notes = ()
    for o in al.outputs:
        sl = ctx.slices[o]
        after = full(final.resid[sl] * sig[o], o)
        worst = max(fitd["rms_after"][o], fitd["holdout_rms_after"][o])
        # SIM evaluated between its samples is known to its interpolation error only: the floor
        # a fit can reach is the noise and that resampling error together
        resample = float(al.interp.get(o, ("", 0.0))[1] or 0.0)
        total = math.hypot(floor[o], resample)
        if UNEXPLAINED_RATIO * floor[o] < worst <= UNEXPLAINED_RATIO * total:
            floor_notes += (f"{o}: the residual ({worst:.3g} {al.units[o]}) is at the resampling "
                            f"floor: the noise ({floor[o]:.3g}) and SIM's interpolation error "
                            f"between its samples ({resample:.3g}) together; SIM's samples are too "
                            "far apart to tell more, not an unexplained effect",)
            continue
        if worst > UNEXPLAINED_RATIO * floor[o]:
            spans = locate(al, max_spans=3, resid={o: after}, only=(o,))
            unexplained.append({
                "output": o, "rms": fitd["rms_after"][o], "holdout_rms": fitd["holdout_rms_after"][o],
                "noise_floor": floor[o], "ratio": worst / floor[o],
                "where": [m.where for m in spans],
                "correlates": conditions(al, o, after, floor[o]),
                "empirical": empirical_dependence(al, o, full(oof[sl] * sig[o], o)),
                "interpolation_error": al.interp.get(o, ("", 0.0))[1]})
    local = []
    for o in al.outputs:
        if any(u["output"] == o for u in unexplained):
            continue
        local += local_flags(al, o, full(oof[ctx.slices[o]] * sig[o], o), floor[o],
                             UNEXPLAINED_RATIO)
    # the recording-wide conditions of an output belong to the words of each of its spans
    mism = [Mismatch(m.output, m.t_start, m.t_end,
                     m.where + "".join(f"; overall: {c}" for c in cond[m.output]), m.rms)
            for m in mism]
    alignment = {"grid_step_s": al.dt, "samples": int(len(rows)), "grid_samples": al.n, "t_start": float(al.t[0]),
                 "t_end": float(al.t[-1]), "clock_offset_s": al.clock_offset + clock_fine[0],
                 "clock_offset_uncertainty_s": clock_fine[1],
                 "coarse_offset_s": al.offset0,
                 "sim_rate_hz": al.rates["sim"], "rec_rate_hz": al.rates["rec"],
                 "folds": st.folds, "quantum": dict(al.quantum), "at_rest": al.at_rest,
                 "same_clock": bool(same_clock),
                 "recordings": [r.to_dict() for r in al.recordings],
                 "interpolation": {o: v[0] for o, v in al.interp.items()},
                 "interpolation_error": {o: v[1] for o, v in al.interp.items()},
                 "columns": {k: {"role": r[0], "kind": r[1], "unit": r[2], "kind_from": r[3]}
                             for k, r in al.roles.items()},
                 "sim": getattr(S, "path", "SIM"), "rec": getattr(R, "path", "REC"),
                 "row_filter": {"conditions": [c.describe() for c in conds],
                                "sim_rows_removed": _nrem(S), "rec_rows_removed": _nrem(R),
                                "sim_rows": S.n, "rec_rows": R.n}}
    return DiagnosisResult(
        outputs=tuple(al.outputs), units=dict(al.units), noise_floor=floor,
        mismatch=tuple(mism), effects=tuple(effects), fit=fitd, alignment=alignment,
        conditions=cond, log=tuple(log), unexplained=tuple(unexplained), local=tuple(local),
        notes=unit_notes + shape_notes + floor_notes + white_notes + tuple(al.notes) + latency_note + tuple(
            f"column {k!r} taken as {r[1]} ({r[2] or 'no unit'}) from its name: give the unit "
            f"in the header (e.g. {k}[{r[2] or 'unit'}]) or with --unit {k}=UNIT"
            for k, r in al.roles.items() if r[3] == "name" and r[1] != "other"),
        t=al.t, rec=dict(al.rec), sim=dict(al.sim),
        corrected=corrected, heldout_corrected=held)


__all__ = ["diagnose", "DiagnosisResult", "EffectResult", "Mismatch", "Settings"]
