"""Fit sets of effects and choose among them: BIC, cross-validation on held-out time blocks.

Fitting is variable projection: the nonlinear parameters (one or two per effect) are found by
scipy.optimize.least_squares, started from a coarse grid, while the amplitudes are solved by
linear least squares inside every residual evaluation.  Selection is forward stepwise: at each
step every candidate is screened alone on the current residual, the best few are fitted jointly
with the effects already chosen, and the best by BIC is kept only if it also lowers the
cross-validated error on contiguous held-out blocks and is larger than a fraction of the noise.
A backward pass then drops any effect the others have made redundant.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from .effects import Candidate, Context


@dataclass
class Settings:
    """Thresholds of the selection; defaults are tuned on benchmarks/diagnose_suite.py."""
    max_effects: int = 4
    bic_threshold: float = 10.0      # required BIC decrease ("very strong" evidence)
    cv_min_gain: float = 0.05        # required relative decrease of the held-out error (material)
    min_effect_snr: float = 0.5      # effect RMS / noise floor below which it is noise
    folds: int = 5
    fit_rows: int = 6000             # samples per output used for selection (all for the final fit)
    screen_rows: int = 2000          # samples per output used to screen candidates
    top: int = 6                     # screened candidates fitted jointly per step
    max_nfev: int = 60


@dataclass
class Fit:
    cands: list
    etas: list
    betas: list
    resid: np.ndarray          # whitened residual on all rows (model applied everywhere)
    rss: float                 # on the fitted rows
    n_rows: int
    contrib: list              # whitened contribution of each effect (N,)
    jac_eta: np.ndarray | None = None
    gram_inv: np.ndarray | None = None
    extra: dict = field(default_factory=dict)

    @property
    def k(self) -> int:
        return sum(c.n_params() for c in self.cands)


def _shift(ctx: Context, v: np.ndarray, tau: float) -> np.ndarray:
    """A stacked (whitened) vector or matrix of columns, each output's part taken tau s
    earlier (linear between the rows; held at the ends)."""
    out = np.array(v, dtype=float, copy=True)
    for sl in ctx.slices.values():
        if out.ndim == 1:
            out[sl] = np.interp(ctx.t - tau, ctx.t, v[sl])
        else:
            for j in range(out.shape[1]):
                out[sl, j] = np.interp(ctx.t - tau, ctx.t, v[sl, j])
    return out


def model_columns(ctx: Context, cands, etas) -> list:
    """(fixed, B) of every candidate with a time offset applied to the whole model.

    A recording that is late by tau shows the machine's response late by tau, lags and the
    other effects included: rec(t) = sim(t - tau) + e(t - tau).  Adding the offset's own term
    sim(t - tau) - sim(t) to e(t) instead leaves the cross term -tau de/dt (for a servo lag
    tau * T * acceleration), which is many noise floors on a fast axis."""
    tau = 0.0
    for c, e in zip(cands, etas):
        if c.name == "time_offset" and len(e):
            tau = float(e[0]) * ctx.al.dt
    out = []
    for c, e in zip(cands, etas):
        f, B = c.columns(ctx, e)
        if tau and c.name != "time_offset":
            f = _shift(ctx, f, tau) if f is not None else None
            B = _shift(ctx, B, tau) if B.shape[1] else B
        out.append((f, B))
    return out


def _assemble(ctx: Context, cands, etas):
    F = np.zeros(ctx.N)
    Bs, sizes = [], []
    for f, B in model_columns(ctx, cands, etas):
        if f is not None:
            F = F + f
        Bs.append(B)
        sizes.append(B.shape[1])
    B = np.hstack(Bs) if Bs and sum(sizes) else np.zeros((ctx.N, 0))
    return F, B, sizes


def _solve(B: np.ndarray, y: np.ndarray, want_inverse: bool = False):
    """Least squares of y on the columns of B via the normalised normal equations.

    Columns are scaled to unit norm (their physical scales differ by 1e8) and the small Gram
    matrix is solved with lstsq, so collinear columns give the minimum-norm answer.  Returns
    (beta, inverse Gram matrix in beta's units or None).
    """
    p = B.shape[1]
    if p == 0:
        return np.zeros(0), (np.zeros((0, 0)) if want_inverse else None)
    G = B.T @ B
    nrm = np.sqrt(np.diag(G)).copy()
    nrm[nrm == 0] = 1.0
    Gn = G / np.outer(nrm, nrm)
    beta_n, *_ = np.linalg.lstsq(Gn, (B.T @ y) / nrm, rcond=1e-12)
    Ginv = np.linalg.pinv(Gn, rcond=1e-12) / np.outer(nrm, nrm) if want_inverse else None
    return beta_n / nrm, Ginv


def _bounds(ctx: Context, cands) -> tuple[list, list]:
    """Lower and upper bounds of all candidates' nonlinear parameters, stacked."""
    lo, hi = [], []
    for c in cands:
        a, b = c.bounds(ctx)
        lo += list(a)
        hi += list(b)
    return lo, hi


def _split(x: np.ndarray, nls: list) -> list:
    """The stacked nonlinear parameters x cut into one array per candidate (sizes nls)."""
    out, i = [], 0
    for m in nls:
        out.append(x[i:i + m])
        i += m
    return out


def joint_covariance(ctx: Context, f: "Fit"):
    """Unscaled covariance of all parameters of a fit, nonlinear (eta) and amplitudes (beta)
    together: (cov_eta, cov_beta), to be multiplied by the residual variance.

    The amplitudes' own inverse Gram matrix is their covariance with the nonlinear parameters
    held at their estimates; where an amplitude is correlated with a time constant (a thermal
    gain with its lag), that understates its uncertainty several times.  Here the Jacobian of
    the prediction F(eta) + B(eta) beta in both sets (eta by central differences, beta exactly:
    the columns B) is inverted as one, columns normalised as in _solve."""
    nls = [len(e) for e in f.etas]
    x = np.concatenate([np.asarray(e, float) for e in f.etas]) if sum(nls) else np.zeros(0)
    beta = np.concatenate([np.asarray(b, float) for b in f.betas]) if f.betas else np.zeros(0)
    F0, B0, _ = _assemble(ctx, f.cands, f.etas)
    if not len(x):
        return np.zeros((0, 0)), (_solve(B0, np.zeros(ctx.N), want_inverse=True)[1]
                                  if B0.shape[1] else np.zeros((0, 0)))
    lo, hi = _bounds(ctx, f.cands)

    def pred(v):
        F, B, _ = _assemble(ctx, f.cands, _split(v, nls))
        return F + (B @ beta if B.shape[1] else 0.0)

    cols = []
    for j in range(len(x)):
        h = 1e-4 * max(1.0, abs(x[j]))
        up, dn = x.copy(), x.copy()
        up[j] = min(x[j] + h, hi[j])
        dn[j] = max(x[j] - h, lo[j])
        cols.append((pred(up) - pred(dn)) / max(up[j] - dn[j], 1e-300))
    J = np.column_stack(cols + ([B0] if B0.shape[1] else []))
    G = J.T @ J
    nrm = np.sqrt(np.diag(G)).copy()
    nrm[nrm == 0] = 1.0
    C = np.linalg.pinv(G / np.outer(nrm, nrm), rcond=1e-12) / np.outer(nrm, nrm)
    k = len(x)
    return C[:k, :k], C[k:, k:]


def fit(ctx: Context, cands: list, etas0: list, rows: np.ndarray | None = None,
        max_nfev: int = 60, target: np.ndarray | None = None, beta_default=None) -> Fit:
    """Fit `cands` jointly to the whitened residual (`target`, default REC - SIM) on `rows`.

    beta_default: amplitudes to use for columns that are zero on every fitted row (a nuisance
    such as a backlash's state before the first motion, seen in one held-out block only)."""
    from scipy.optimize import least_squares
    z = ctx.z0 if target is None else target
    if rows is not None and rows.all():
        rows = None
    take = (lambda a: a) if rows is None else (lambda a: a[rows])
    nls = [len(c.nl_names) for c in cands]
    lo, hi = _bounds(ctx, cands)
    x0 = np.concatenate([np.asarray(e, float) for e in etas0]) if sum(nls) else np.zeros(0)
    x0 = np.clip(x0, lo, hi) if len(x0) else x0

    def split(x):
        return _split(x, nls)

    def resid_rows(x):
        F, B, _ = _assemble(ctx, cands, split(x))
        y = take(z) - take(F)
        Br = take(B)
        beta, _ = _solve(Br, y)
        return y - Br @ beta

    jac = None
    x = x0
    if len(x0) and max_nfev > 0:
        # keep the start strictly inside the box: least_squares requires it
        span = np.asarray(hi) - np.asarray(lo)
        x0 = np.clip(x0, np.asarray(lo) + 1e-9 * span, np.asarray(hi) - 1e-9 * span)
        res = least_squares(resid_rows, x0, bounds=(lo, hi), method="trf", x_scale=1.0,
                            diff_step=1e-4, max_nfev=max_nfev)
        x = res.x
        jac = res.jac
    etas = split(x)
    F, B, sizes = _assemble(ctx, cands, etas)
    beta, Ginv = _solve(take(B), take(z) - take(F), want_inverse=True)
    if beta_default is not None and len(beta_default) == len(beta) and B.shape[1]:
        dead = ~np.any(take(B) != 0, axis=0)
        beta = np.where(dead, beta_default, beta)
    pred_parts, betas, i = [], [], 0
    for (f, Bc), m in zip(model_columns(ctx, cands, etas), sizes):
        b = beta[i:i + m]
        part = (f if f is not None else 0.0) + (Bc @ b if m else 0.0)
        pred_parts.append(np.broadcast_to(part, (ctx.N,)).copy() if np.isscalar(part) else part)
        betas.append(b)
        i += m
    total = F + B @ beta
    r = z - total
    rr = take(r)
    return Fit(list(cands), etas, betas, r, float(rr @ rr), len(rr), pred_parts, jac, Ginv)


def noise_rho(ctx: Context, r: np.ndarray) -> float:
    """Lag-one autocorrelation of the noise in a residual, median over outputs (0..0.99).

    From first differences taken where the simulated axes are all at rest (every effect of the
    library is constant or slow there, so the differences are noise; elsewhere an unexplained
    effect would look like strongly correlated noise), else where the output's own axis rests;
    white (0) when neither gives 30 pairs.  For AR(1) noise of lag-one correlation rho, the
    differences have lag-one correlation -(1 - rho)/2.  Differences are clipped at 5 robust
    sigmas.
    """
    al = ctx.al

    def still_of(keys):
        st = np.ones(ctx.n, bool)
        for o in keys:
            p = al.sim[o][ctx.idx]
            ok = np.concatenate([[True], np.abs(np.diff(p)) <= 1e-7 * max(float(np.ptp(p)), 1e-12)])
            st &= ok & np.concatenate([ok[1:], [True]])
        # pairs of consecutive differences inside a rest: samples k, k+1, k+2 all still
        return st[:-2] & st[1:-1] & st[2:]

    trip_all = still_of(ctx.outputs)
    vals = []
    for o, sl in ctx.slices.items():
        trip = trip_all if trip_all.sum() >= 30 else still_of([o])
        if trip.sum() < 30:
            continue  # no quiet stretch to tell noise from signal: taken as white
        d = np.diff(r[sl])
        a, b = d[:-1][trip], d[1:][trip]
        allv = np.concatenate([a, b])
        med = np.median(allv)
        sd = 1.4826 * np.median(np.abs(allv - med))
        if sd == 0:
            continue
        a = np.clip(a - med, -5 * sd, 5 * sd)
        b = np.clip(b - med, -5 * sd, 5 * sd)
        den = float(np.sqrt((a @ a) * (b @ b)))
        if den > 0:
            vals.append(float(np.clip(1.0 + 2.0 * float(a @ b) / den, 0.0, 0.99)))
    # median over outputs: one output whose effect moves while its own axis rests (a
    # squareness driven by another axis) must not make every output's noise look correlated
    return float(np.median(vals)) if vals else 0.0


def n_effective(ctx: Context) -> float:
    """Samples worth of independent information, given the noise's lag-one correlation.

    Estimated once per context from the raw residual REC - SIM (the noise does not change with
    the model), so every BIC of a selection uses the same value.
    """
    if getattr(ctx, "_neff", None) is None:
        rho = noise_rho(ctx, ctx.z0)
        ctx._neff = max(ctx.N * (1 - rho) / (1 + rho), 10.0)
    return ctx._neff


def bic(rss: float, n_rows: int, k: int, neff: float) -> float:
    return neff * math.log(max(rss, 1e-300) / n_rows) + k * math.log(neff)


def bic_per_output(ctx: Context, f: "Fit", neff: float) -> float:
    """BIC with a residual variance of its own per output (fitted on all rows).

    The pooled `bic` takes one variance for every output: a large mismatch left on one output
    (an effect outside the library, single-sample spikes of a logger) then swamps the evidence
    for an effect on another output, whose RSS is a small part of the total.  With a variance
    per output each output's log-likelihood counts on its own.  The effective sample size is
    shared out over the outputs in proportion to their rows."""
    total = 0.0
    for sl in ctx.slices.values():
        r = f.resid[sl]
        n_o = max(len(r), 1)
        total += neff * n_o / ctx.N * math.log(max(float(r @ r), 1e-300) / n_o)
    return total + f.k * math.log(neff)


def delta_bic(ctx: Context, f: "Fit", cur: "Fit", neff: float) -> float:
    """BIC change from `cur` to `f`: the stronger of the pooled and the per-output evidence
    (the pooled test keeps every decision it made before; the per-output one adds the effects
    that a mismatch on another output hid)."""
    d_pool = bic(f.rss, f.n_rows, f.k, neff) - bic(cur.rss, cur.n_rows, cur.k, neff)
    if len(ctx.slices) < 2:
        return d_pool
    return min(d_pool, bic_per_output(ctx, f, neff) - bic_per_output(ctx, cur, neff))


def fold_blocks(ctx: Context, folds: int) -> list[np.ndarray]:
    """The held-out blocks of a context's rows: one per recording when it holds several
    (leave-one-recording-out), else `folds` contiguous blocks of time."""
    from .recordings import recording_blocks
    per = recording_blocks(ctx.al, ctx.idx)
    if per is not None:
        return [b for b in per if len(b)]
    return blocks(ctx.n, folds)


def blocks(n: int, folds: int) -> list[np.ndarray]:
    edges = np.linspace(0, n, folds + 1).astype(int)
    return [np.arange(edges[i], edges[i + 1]) for i in range(folds)]


def cross_validate(ctx: Context, cands: list, etas: list, folds: int, max_nfev: int = 0,
                   fits: list | None = None, betas: list | None = None):
    """Fit on all but one contiguous block of time, predict it.

    By default the nonlinear parameters stay at `etas` (fitted on all samples) and only the
    amplitudes are refitted per fold: refitting a time constant on 80 % of a recording can run
    off to a bound where its columns are nearly collinear and the prediction of the held-out
    block explodes, which would reject a right effect for a numerical reason.

    Returns (SSE of the held-out predictions, out-of-fold whitened residual); the fold fits are
    appended to `fits` if given (with the held-out time span in fit.extra).
    """
    n = ctx.n
    oof = np.array(ctx.z0, copy=True)
    if not cands:
        return float(oof @ oof), oof
    O = len(ctx.outputs)
    for blk in fold_blocks(ctx, folds):
        held = np.zeros(n, bool)
        held[blk] = True
        rows = np.tile(~held, O)
        f = fit(ctx, cands, etas, rows, max_nfev=max_nfev,
                beta_default=np.concatenate(betas) if betas else None)
        hrows = np.tile(held, O)
        oof[hrows] = f.resid[hrows]
        if fits is not None:
            f.extra["held"] = (float(ctx.t[blk[0]]), float(ctx.t[blk[-1]]))
            fits.append(f)
    return float(oof @ oof), oof


def _conflicts(c: Candidate, model: list) -> bool:
    for m in model:
        if (c.name == m.name and set(c.outputs) & set(m.outputs)
                and (hasattr(c, "members") or hasattr(m, "members"))):
            return True
        if m.label == c.label:
            return True
        if c.name == m.name and c.name in ("workpiece_setting", "time_offset"):
            return True
        # the direct and the lagged response to the same driver are two forms of one drift
        if c.name == m.name == "thermal_drift" and c.outputs == m.outputs and c.inputs == m.inputs:
            return True
        if (c.name == m.name and c.outputs == m.outputs
                and c.name in ("backlash", "servo_lag", "scale_error", "periodic_pitch_error",
                               "friction", "quadrant_glitch")):
            return True
        # squareness is nested in straightness of the same output along the same axis
        if ({c.name, m.name} == {"squareness", "straightness"} and c.outputs == m.outputs
                and c.inputs == m.inputs):
            return True
    return False


DYNAMIC = ("servo_lag", "time_offset")


class DynamicsSlack(Candidate):
    """Not an effect: the first and second time derivatives of SIM on outputs that already
    carry a named dynamic effect (servo lag, time offset), as free columns.

    A lag or delay whose form differs a little from the library's (x - tau v, a lag of higher
    order, a lag beside a transport delay) leaves a residual of second order, about tau^2 times
    the acceleration; an effect of another kind (a quadrant glitch, a scale or pitch error) can
    take up part of that and pass every test on held-out data.  Such an effect is kept only if
    it still improves the held-out error materially with these columns beside it: what it
    explains must be more than model error of the dynamics already named.  Never reported."""

    def __init__(self, outputs):
        super().__init__("dynamics_slack", tuple(outputs), ("t",), 2 * len(outputs))

    def build(self, ctx, eta):
        from .effects import sim_derivative
        return None, [{o: sim_derivative(ctx, o, k)} for o in self.outputs for k in (1, 2)]


def _slack(model: list, c: Candidate):
    """Slack columns for testing `c` beside `model`, or None when c is itself dynamic or none
    of its outputs carries a named dynamic effect."""
    if c.name in DYNAMIC:
        return None
    dyn = {o for m in model for mm in getattr(m, "members", [m]) if mm.name in DYNAMIC
           for o in mm.outputs}
    outs = [o for o in c.outputs if o in dyn]
    return DynamicsSlack(outs) if outs else None


def _own_gain(ctx: Context, c: Candidate, oof_without: np.ndarray, oof_with: np.ndarray) -> float:
    """Relative decrease of the held-out error on c's own outputs."""
    own = np.zeros(ctx.N, bool)
    for o in c.outputs:
        own[ctx.slices[o]] = True
    s0 = float(oof_without[own] @ oof_without[own])
    return 1.0 - float(oof_with[own] @ oof_with[own]) / s0 if s0 > 0 else 0.0


def beyond_dynamics(ctx: Context, c: Candidate, rest: list, rest_etas: list, c_eta, folds: int):
    """Held-out gain of `c` on its outputs over `rest` with the dynamics slack beside both
    (None when no slack applies)."""
    sl = _slack(rest, c)
    if sl is None:
        return None
    _, o0 = cross_validate(ctx, rest + [sl], list(rest_etas) + [np.zeros(0)], folds)
    _, o1 = cross_validate(ctx, rest + [sl, c], list(rest_etas) + [np.zeros(0), c_eta], folds)
    return _own_gain(ctx, c, o0, o1)


def _screen_rows(ctx: Context, limit: int) -> np.ndarray:
    step = max(1, int(math.ceil(ctx.n / limit)))
    m = np.zeros(ctx.n, bool)
    m[::step] = True
    return np.tile(m, len(ctx.outputs))


def select(ctx: Context, cands: list, settings: Settings | None = None, progress=None):
    """Forward-backward selection; returns (final Fit, evidence per chosen effect, log)."""
    st = settings or Settings()
    log = []
    model, etas = [], []
    cur = fit(ctx, [], [])
    cv_cur, oof_cur = cross_validate(ctx, [], [], st.folds)
    srows = _screen_rows(ctx, st.screen_rows)
    evidence = {}
    coarse_cache = {}
    for step in range(st.max_effects):
        # when every trial of a step is refused (held out, identifiability), the next
        # candidates are tried: the best few may all belong to one output whose mismatch no
        # effect explains, and must not end the selection for the others
        skip = set()
        accepted = False
        for _round in range(3):
            scored = []
            r_s = cur.resid
            rss_s = float(r_s[srows] @ r_s[srows])
            nlog = math.log(max(srows.sum(), 2))
            omask = {}
            for o, sl in ctx.slices.items():
                omask[o] = np.zeros(ctx.N, bool)
                omask[o][sl] = True
                omask[o] &= srows
            for c in cands:
                if c in model or c.label in skip:
                    continue
                # a candidate that conflicts with one chosen effect may replace it (translation ->
                # translation and rotation, squareness -> straightness): greedy steps are not final
                conf = [i for i, m in enumerate(model) if _conflicts(c, [m])]
                if len(conf) > 1 or (conf and hasattr(c, "members")):
                    continue
                swap = conf[0] if conf else None
                base = r_s if swap is None else r_s + cur.contrib[swap]
                offs = []
                if c.name == "servo_lag" and swap is None:
                    # a time offset chosen earlier may hold what this lag explains (they agree to
                    # first order): screen the lag on the residual without it, jointly with the
                    # offset refitted, so that the two share the delay (alone, a lag cannot take
                    # over the offset's part of the delay on the outputs it does not lag)
                    for j, m in enumerate(model):
                        if m.name == "time_offset" and j != swap:
                            base = base + cur.contrib[j]
                            offs.append(j)
                eta0 = c.coarse(ctx, base, srows)
                if offs:
                    f1 = fit(ctx, [model[j] for j in offs] + [c], [etas[j] for j in offs] + [eta0],
                             srows, max_nfev=15, target=base)
                    coarse_cache[c.label] = f1.etas[-1]
                else:
                    f1 = fit(ctx, [c], [eta0], srows, max_nfev=15, target=base)
                    coarse_cache[c.label] = f1.etas[0]
                dk = c.n_params() - (model[swap].n_params() if swap is not None else 0)
                rss1 = f1.rss
                if base is not r_s and swap is None:
                    # outside the candidate's outputs the residual stays what it is now
                    mine = np.zeros(ctx.N, bool)
                    for o in set(c.outputs).union(*(model[j].outputs for j in offs)):
                        mine[ctx.slices[o]] = True
                    rm, ro = srows & mine, srows & ~mine
                    rss1 = float(f1.resid[rm] @ f1.resid[rm]) + float(r_s[ro] @ r_s[ro])
                gain = rss_s - rss1
                if gain > 0:
                    # the same gain as log-likelihood with a variance per output (as
                    # `bic_per_output`): on an output whose residual is small beside another's
                    # it still counts
                    touched = set(c.outputs).union(*(model[j].outputs for j in offs))
                    if swap is not None:
                        touched |= set(model[swap].outputs)
                    ll = -dk * nlog
                    for o in touched:
                        m = omask[o]
                        b0, b1 = float(r_s[m] @ r_s[m]), float(f1.resid[m] @ f1.resid[m])
                        if b0 > 0 and b1 > 0:
                            ll += m.sum() * math.log(b0 / b1)
                    scored.append((gain - dk * nlog, c, swap, ll))
            scored.sort(key=lambda g: -g[0])
            top = [g[:3] for g in scored[:st.top]]
            # the best two by that measure are tried too: the best few by the pooled gain may all
            # belong to one output with a large mismatch that no effect explains
            top += [g[:3] for g in sorted(scored[st.top:], key=lambda g: -g[3])[:2] if g[3] > 0]
            # a delay beside lags already named cannot show its gain when screened alone (shifting
            # SIM without shifting the lags' predictions): it is always tried jointly
            if any(m.name == "servo_lag" for m in model) and not any(m.name == "time_offset" for m in model):
                top += [g[:3] for g in scored[st.top:] if g[1].name == "time_offset"
                        and g[:3] not in top][:1]
            trials = []
            for _, c, swap in top:
                keep = [i for i in range(len(model)) if i != swap]
                m_new = [model[i] for i in keep] + [c]
                e_new = [etas[i] for i in keep] + [coarse_cache[c.label]]
                f = fit(ctx, m_new, e_new, max_nfev=st.max_nfev)
                # multi-start: a time offset chosen before a lag took up what the lag explains (a
                # delay and a lag agree to first order, and the cross-correlation peak includes the
                # lag); restart it from no offset
                restart = [j for j, m in enumerate(m_new[:-1]) if m.name == "time_offset"]
                if restart and c.name in ("servo_lag", "quadrant_glitch", "backlash"):
                    e2 = list(e_new)
                    for j in restart:
                        lo, hi = m_new[j].bounds(ctx)
                        e2[j] = np.array([float(np.clip(0.0, lo[0], hi[0]))])
                    f2 = fit(ctx, m_new, e2, max_nfev=st.max_nfev)
                    if f2.rss < f.rss:
                        f = f2
                trials.append((c, swap, m_new, f))
            if not trials:
                log.append(f"step {step + 1}: no candidate lowers the residual")
                break
            # one effective sample size for every BIC (from the noise, not from what is left of the
            # effects): values computed with different N_eff would not be comparable
            neff = n_effective(ctx)
            trials = sorted(((delta_bic(ctx, f, cur, neff), c, swap, m_new, f)
                             for c, swap, m_new, f in trials), key=lambda g: g[0])
            accepted = False
            for k_t, (dbic, c, swap, m_new, f) in enumerate(trials[:4]):
                if dbic > -st.bic_threshold:
                    if k_t == 0:
                        # said, so that "nothing named" reads as too little evidence, not as no idea
                        log.append(f"step {step + 1}: best candidate {c.label}: BIC change "
                                   f"{dbic:+.1f} (a fall of at least {st.bic_threshold:g} needed)")
                    break
                contrib = f.contrib[-1]
                snr = float(np.sqrt(np.mean(contrib ** 2) * len(ctx.outputs) / len(c.outputs)))
                if snr < st.min_effect_snr:
                    log.append(f"step {step + 1}: {c.label} rejected: RMS {snr:.2f} x noise")
                    continue
                why = c.implausible(ctx, f.etas[-1], f.betas[-1])
                if why:
                    log.append(f"step {step + 1}: {c.label} rejected: {why}")
                    continue
                cv_new, oof_new = cross_validate(ctx, m_new, f.etas, st.folds)
                gain = 1.0 - cv_new / cv_cur
                # materiality on the effect's own outputs (one output with a tiny noise floor must
                # not make every other output's effects look immaterial), and no loss overall
                own = np.zeros(ctx.N, bool)
                for o in c.outputs:
                    own[ctx.slices[o]] = True
                sse_cur_own = float(oof_cur[own] @ oof_cur[own])
                gain_own = 1.0 - float(oof_new[own] @ oof_new[own]) / sse_cur_own if sse_cur_own > 0 else 0.0
                if gain_own < st.cv_min_gain or gain <= 0:
                    gain = min(gain, gain_own)
                    log.append(f"step {step + 1}: {c.label} rejected: held-out error "
                               f"{-100 * gain:+.3g} %")
                    continue
                keep = [i for i in range(len(model)) if i != swap]
                g2 = beyond_dynamics(ctx, c, [model[i] for i in keep], [etas[i] for i in keep],
                                     f.etas[-1], st.folds)
                if g2 is not None and g2 < st.cv_min_gain:
                    log.append(f"step {step + 1}: {c.label} rejected: held-out error {-100 * g2:+.1f} % "
                               "beside the dynamics' second-order slack (model error of the lag or "
                               "delay already named, not an effect)")
                    continue
                what = "added" if swap is None else f"replaces {model[swap].label}"
                log.append(f"step {step + 1}: {c.label} {what}: dBIC {dbic:.1f}, held-out error "
                           f"{-100 * gain:+.1f} %, RMS {snr:.1f} x noise")
                if swap is not None:
                    evidence.pop(model[swap].label, None)
                evidence[c.label] = {"delta_bic": round(float(dbic), 2),
                                     "heldout_error_reduction": round(float(gain), 4),
                                     "snr": round(snr, 2), "n_effective": round(float(neff), 1)}
                model, etas, cur, cv_cur, oof_cur = m_new, list(f.etas), f, cv_new, oof_new
                accepted = True
                if progress:
                    progress(f"{what} {c.label}")
                break
            if accepted:
                break
            refused = [g[1].label for g in trials[:4] if g[0] <= -st.bic_threshold]
            if not refused:
                break  # the best lacks the evidence: so do the rest
            skip |= set(refused)
        if not accepted:
            break
    # exchange pass: greedy steps can pick a combination that mimics a simpler truth (a
    # workpiece rotation plus a squareness of the other axis reproduce one squareness); try
    # replacing each chosen effect by the best few candidates screened on what it explained
    if len(model) >= 2:
        model, etas, cur, cv_cur = _exchange(ctx, cands, model, etas, cur, cv_cur, oof_cur, st,
                                             srows, coarse_cache, evidence, log)
    # backward pass: an effect that a later one made redundant goes
    changed = True
    while changed and len(model) > 1:
        changed = False
        neff = n_effective(ctx)
        worst = None
        for i, c in enumerate(model):
            sub = model[:i] + model[i + 1:]
            f = fit(ctx, sub, etas[:i] + etas[i + 1:], max_nfev=st.max_nfev)
            d = -delta_bic(ctx, cur, f, neff)  # rise of BIC without it, by the measure that kept it
            if d < st.bic_threshold and (worst is None or d < worst[0]):
                worst = (d, i, f)
        if worst is not None:
            d, i, f = worst
            log.append(f"backward: {model[i].label} dropped (BIC rises by {d:.1f} only)")
            evidence.pop(model[i].label, None)
            model, etas, cur = model[:i] + model[i + 1:], etas[:i] + etas[i + 1:], f
            changed = True
    # backward pass on held-out error: every kept effect that is not itself a lag or delay must
    # still earn its place beside the others and the dynamics' second-order slack (an effect
    # chosen before the lag or delay it now only corrects would otherwise stay)
    changed = True
    while changed and len(model) > 1:
        changed = False
        for i, c in enumerate(model):
            rest, rest_etas = model[:i] + model[i + 1:], etas[:i] + etas[i + 1:]
            g2 = beyond_dynamics(ctx, c, rest, rest_etas, etas[i], st.folds)
            if g2 is not None and g2 < st.cv_min_gain:
                log.append(f"backward (held out): {c.label} dropped: held-out error "
                           f"{-100 * g2:+.1f} % beside the dynamics' second-order slack")
                evidence.pop(c.label, None)
                model, etas = rest, rest_etas
                cur = fit(ctx, model, etas, max_nfev=st.max_nfev)
                etas = list(cur.etas)
                changed = True
                break
    final = fit(ctx, model, etas, max_nfev=st.max_nfev * 2) if model else cur
    # the longer final fit may carry a parameter to where it is no longer plausible (a time
    # constant run into its bound): such an effect is not identified and goes
    while model:
        bad = [(i, w) for i, c in enumerate(model)
               for w in [c.implausible(ctx, final.etas[i], final.betas[i])] if w]
        if not bad:
            break
        i, why = bad[0]
        log.append(f"final: {model[i].label} dropped: {why}")
        evidence.pop(model[i].label, None)
        model, etas = model[:i] + model[i + 1:], final.etas[:i] + final.etas[i + 1:]
        final = fit(ctx, model, etas, max_nfev=st.max_nfev * 2) if model else fit(ctx, [], [])
    model, final = honest_gate(ctx, cands, model, final, st, evidence, log)
    return final, evidence, log


def _exchange(ctx, cands, model, etas, cur, cv_cur, oof_cur, st, srows, coarse_cache, evidence,
              log):
    """Replace one chosen effect by another candidate while that lowers BIC by the threshold.

    A replacement must also keep what the effect it replaces explained: the held-out error on
    that effect's own outputs may not rise by more than `cv_min_gain`.  The pooled BIC and the
    pooled held-out error are ruled by the outputs with the largest residuals; with many outputs
    at once (a spindle's mismatch outside the library beside the axes' lags) they would trade a
    lag that explains most of a small output's mismatch for a small gain on a large one."""
    nlog = math.log(max(srows.sum(), 2))
    refused = set()
    for _ in range(3):
        neff = n_effective(ctx)
        b_cur = bic(cur.rss, cur.n_rows, cur.k, neff)
        best = None
        for i, e in enumerate(model):
            rest, rest_etas = model[:i] + model[i + 1:], etas[:i] + etas[i + 1:]
            base = cur.resid + cur.contrib[i]
            rss_base = float(base[srows] @ base[srows])
            scored = []
            for c in cands:
                if c in model or _conflicts(c, rest) or (e.label, c.label) in refused:
                    continue
                eta0 = coarse_cache.get(c.label)
                if eta0 is None:
                    continue
                # at the nonlinear parameters found when screening: only the amplitudes move
                f1 = fit(ctx, [c], [eta0], srows, max_nfev=1, target=base) if len(eta0) else \
                    fit(ctx, [c], [eta0], srows, target=base)
                scored.append((rss_base - f1.rss - c.n_params() * nlog, c))
            scored.sort(key=lambda g: -g[0])
            for _, c in scored[:2]:
                f = fit(ctx, rest + [c], rest_etas + [coarse_cache[c.label]], max_nfev=st.max_nfev)
                d = bic(f.rss, f.n_rows, f.k, neff) - b_cur
                if d < -st.bic_threshold and (best is None or d < best[0]):
                    best = (d, i, c, f)
        if best is None:
            break
        d, i, c, f = best
        if c.implausible(ctx, f.etas[-1], f.betas[-1]):
            break  # an exchange never brings in what the forward steps would refuse
        m_new = model[:i] + model[i + 1:] + [c]
        cv_new, oof_new = cross_validate(ctx, m_new, f.etas, st.folds)
        if cv_new > cv_cur * (1.0 + st.cv_min_gain):
            break
        # what the effect replaced explained on its own outputs must stay explained
        own = np.zeros(ctx.N, bool)
        for o in model[i].outputs:
            own[ctx.slices[o]] = True
        s_cur = float(oof_cur[own] @ oof_cur[own])
        loss = float(oof_new[own] @ oof_new[own]) / s_cur - 1.0 if s_cur > 0 else 0.0
        if loss > st.cv_min_gain:
            log.append(f"exchange: {c.label} does not replace {model[i].label}: held-out error on "
                       f"{', '.join(model[i].outputs)} {100 * loss:+.1f} %")
            refused.add((model[i].label, c.label))
            continue
        log.append(f"exchange: {c.label} replaces {model[i].label} (BIC {d:.1f})")
        old = evidence.pop(model[i].label, {})
        evidence[c.label] = dict(old, delta_bic_exchange=round(float(d), 2))
        model, etas, cur, cv_cur, oof_cur = m_new, list(f.etas), f, cv_new, oof_new
    return model, etas, cur, cv_cur


# a nonlinear parameter within this fraction of its range of a bound sits at the bound: the
# data do not identify it (a time constant pinned at the shortest the grid allows)
BOUND_EDGE = 1e-3


def at_bound(ctx: Context, c: Candidate, eta) -> str | None:
    """Which nonlinear parameter of `c` sits at a bound of its range (None: none does)."""
    lo, hi = c.bounds(ctx)
    names = list(getattr(c, "nl_names", ())) or [f"parameter {j}" for j in range(len(lo))]
    for j, (a, b, e) in enumerate(zip(lo, hi, np.atleast_1d(eta))):
        edge = BOUND_EDGE * (b - a)
        if e <= a + edge or e >= b - edge:
            return f"{names[j] if j < len(names) else j} at the {'lower' if e <= a + edge else 'upper'} bound"
    return None


COARSE_ROWS = 2000


def neutral_fit(ctx: Context, cands: list, train: np.ndarray, max_nfev: int,
                beta_default=None) -> Fit:
    """Fit `cands` on the rows `train` only (a boolean mask over the stacked rows), every
    nonlinear parameter started from the candidate's own coarse grid on those rows: no value
    found on the held-out rows enters (the effects in turn, each on what the ones before it
    leave, then all jointly)."""
    r = np.array(ctx.z0, copy=True)
    etas = []
    # the starting grids on at most about COARSE_ROWS training rows per output (a start, not
    # the estimate: the joint fit below uses every training row)
    step = max(1, int(math.ceil(train.sum() / len(ctx.outputs) / COARSE_ROWS)))
    sparse = train.copy()
    if step > 1:
        keep = np.zeros(ctx.n, bool)
        keep[::step] = True
        sparse &= np.tile(keep, len(ctx.outputs))
    for c in cands:
        eta0 = c.coarse(ctx, r, sparse)
        f1 = fit(ctx, [c], [eta0], train, max_nfev=min(15, max_nfev), target=r)
        etas.append(f1.etas[0])
        r = f1.resid
    f = fit(ctx, cands, etas, train, max_nfev=max_nfev, beta_default=beta_default)
    # a delay screened before the lags takes up what they explain (they agree to first order):
    # the joint fit is also started from no delay, the other neutral start, and the better kept
    off = [j for j, c in enumerate(cands) if c.name == "time_offset"]
    if off and len(cands) > 1:
        e2 = list(etas)
        for j in off:
            lo, hi = cands[j].bounds(ctx)
            e2[j] = np.array([float(np.clip(0.0, lo[0], hi[0]))])
        f2 = fit(ctx, cands, e2, train, max_nfev=max_nfev, beta_default=beta_default)
        if f2.rss < f.rss:
            f = f2
    return f


def heldout_neutral(ctx: Context, cands: list, folds: int, max_nfev: int = 30, fits=None,
                    beta_default=None) -> np.ndarray:
    """Out-of-fold whitened residual: each contiguous block predicted by `cands` fitted on the
    other blocks from neutral starts (`neutral_fit`).  The fold fits are appended to `fits`
    with the held-out span in fit.extra["held"]."""
    oof = np.array(ctx.z0, copy=True)
    if not cands:
        return oof
    O = len(ctx.outputs)
    for blk in fold_blocks(ctx, folds):
        held = np.zeros(ctx.n, bool)
        held[blk] = True
        f = neutral_fit(ctx, cands, np.tile(~held, O), max_nfev, beta_default)
        hrows = np.tile(held, O)
        oof[hrows] = f.resid[hrows]
        if fits is not None:
            f.extra["held"] = (float(ctx.t[blk[0]]), float(ctx.t[blk[-1]]))
            fits.append(f)
    return oof


def _clock_instead(ctx: Context, cands: list, model: list, i: int):
    """On separate clocks a servo lag of a few samples and a clock offset agree to first order:
    the baseline a lag must beat is the model with a clock offset in its place (None when the
    clocks are one, the effect is no lag, or the model already has an offset)."""
    c = model[i]
    if ctx.al.same_clock or c.name != "servo_lag" or any(m.name == "time_offset" for m in model):
        return None
    off = [k for k in cands if k.name == "time_offset"]
    return off[0] if off else None


def honest_gate(ctx: Context, cands: list, model: list, final: "Fit", st: Settings, evidence: dict,
                log: list):
    """The tool's own rules applied again after the final fit, with every parameter refitted
    on the training blocks from neutral starts: an effect stays only if it lowers the held-out
    error on its own outputs by `cv_min_gain` against the model without it, and none of its
    nonlinear parameters sits at a bound.  The weakest offender goes first, then the rest are
    judged again.  Returns (model, final fit)."""
    while model:
        bd = np.concatenate(final.betas) if final.betas else None
        folds = []
        oof = heldout_neutral(ctx, model, st.folds, beta_default=bd, fits=folds)
        final.extra["heldout_folds"] = folds
        # outputs the whole model predicts worse than no model at all, every parameter refitted
        # without the block from the final values (the rule of the selection before the gate)
        _, oof_w = cross_validate(ctx, model, final.etas, st.folds, max_nfev=10, betas=final.betas)
        worse = {o for o, sl in ctx.slices.items()
                 if float(oof_w[sl] @ oof_w[sl]) > float(ctx.z0[sl] @ ctx.z0[sl])}
        worst = None
        for i, c in enumerate(model):
            why = at_bound(ctx, c, final.etas[i])
            if why is None and set(c.outputs) <= worse:
                why = (f"held out, {', '.join(c.outputs)} worse with the model than without any "
                       "effect")
            gain = None
            if why is None:
                rest = model[:i] + model[i + 1:]
                clock = _clock_instead(ctx, cands, model, i)
                base = rest + ([clock] if clock is not None else [])
                oof0 = heldout_neutral(ctx, base, st.folds) if base else ctx.z0
                gain = _own_gain(ctx, c, oof0, oof)
                if gain < st.cv_min_gain:
                    why = (f"held-out error {-100 * gain:+.1f} % with every parameter refitted on "
                           "the training blocks" + (" (against a clock offset in its place)"
                                                    if clock is not None else ""))
            else:
                gain = -np.inf
            if why and (worst is None or gain < worst[0]):
                worst = (gain, i, why, clock if gain > -np.inf else None)
            if not why:
                ev = evidence.get(c.label)
                if ev is not None:
                    ev["heldout_error_reduction_neutral"] = round(float(gain), 4)
        if worst is None:
            break
        _, i, why, clock = worst
        worst_label = model[i].label
        evidence.pop(model[i].label, None)
        model, etas = model[:i] + model[i + 1:], final.etas[:i] + final.etas[i + 1:]
        if clock is not None:
            # what the lag took is the clocks' difference: the offset takes its place
            log.append(f"final: {clock.label} replaces {worst_label}: {why}")
            etas = etas + [clock.coarse(ctx, final.resid + final.contrib[i], np.ones(ctx.N, bool))]
            model = model + [clock]
        else:
            log.append(f"final: {worst_label} dropped: {why}")
        final = fit(ctx, model, etas, max_nfev=st.max_nfev * 2) if model else fit(ctx, [], [])
    return model, final
