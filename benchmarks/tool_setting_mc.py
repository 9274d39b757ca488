"""Monte Carlo of the tool-setting grooving procedure (paper 000), side by side with the closed forms.

1. The paper's experiment, virtually: true setting error that reproduces Table 1's A distances,
   1 um microscope noise, estimate, cut again with compensated programs; distribution of the
   compensated groove distances over N runs (mean, 95th percentile) beside the paper's values.
   Baseline in the same runs: compensation from the closed forms (A/C patterns for t_x, t_y;
   B depths, paper eq. (1)-(2) re-derived, for t_z).
2. Injected and recovered: random true offsets up to 1 mm per component; rate of estimates
   within 3 sigma of the reported covariance.
3. t_z uncertainty at B = +-10 deg: least squares with lateral positions against the closed
   form from depths alone, for several noise levels.

Writes its section of docs/benchmarks.md.  Usage: python benchmarks/tool_setting_mc.py [N]
"""
from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _report import machine_line, update_section  # noqa: E402

from mtcomp.errors import ErrorSet, ToolSetting  # noqa: E402
from mtcomp.machine import load_machine  # noqa: E402
from mtcomp.setting import tool_estimate as te  # noqa: E402
from mtcomp.setting.tool import (PAPER_COMPENSATED, PAPER_ORIGINAL, MicroscopeNoise, PlanOptions, cut_grooves,  # noqa: E402
                                 make_plan, paper_offset,
                                 simulate_grooving, table1_distances)



def progress(i, n, t0, what):
    if i % max(1, n // 20) == 0 or i == n:
        el = time.perf_counter() - t0
        print(f"\r{what}: {i}/{n} ({el:.1f} s)", end="" if i < n else "\n", flush=True)


def paper_runs(m, n):
    plan = make_plan(m)
    t_true = np.array(paper_offset())
    noise = MicroscopeNoise(0.001, 0.001)
    before = table1_distances(plan, cut_grooves(m, plan, t_true))
    ls, cf, tz_err = [], [], []
    t0 = time.perf_counter()
    for k in range(n):
        meas = simulate_grooving(m, t_true, noise, seed=10_000 + k, plan=plan)
        est = te.estimate(m, meas)
        c = est.closed
        t_cf = np.array([(c["A"][0] + c["C"][0]) / 2, (c["A"][1] + c["C"][1]) / 2, c["B_depth"][1]])
        for t_hat, out in ((est.offset, ls), (t_cf, cf)):
            comp = ErrorSet(tool=ToolSetting(tuple(t_hat)))
            d = table1_distances(plan, cut_grooves(m, plan, t_true, compensation=comp))
            out.append([*d["A"], *d["C"]])
        tz_err.append((est.offset[2] - t_true[2], t_cf[2] - t_true[2]))
        progress(k + 1, n, t0, "paper experiment")
    return before, np.array(ls) * 1e3, np.array(cf) * 1e3, np.array(tz_err) * 1e3


def coverage(m, n):
    from scipy import stats
    plan = make_plan(m, PlanOptions(depth=0.3))
    rng = np.random.default_rng(20260)
    comp, allin, d2 = [], [], []
    t0 = time.perf_counter()
    for k in range(n):
        t = rng.uniform(-1.0, 1.0, 3)
        meas = simulate_grooving(m, t, MicroscopeNoise(0.001, 0.001), 20260 + 1 + k, plan=plan, frame_offset=0.5)
        est = te.estimate(m, meas, closed=False)
        z = np.abs(est.offset - t) / est.sigma
        comp.append(z <= 3)
        allin.append(np.all(z <= 3))
        d2.append(est.mahalanobis2(t))
        progress(k + 1, n, t0, "injected and recovered")
    d2 = np.array(d2)
    return (np.mean(comp, axis=0), float(np.mean(allin)), float(np.mean(d2 <= stats.chi2.ppf(0.99, 3))),
            float(np.mean(d2)))


def tz_sigmas(m, sp, sd, theta=10.0):
    plan = make_plan(m, PlanOptions(b_angles=(0.0, theta, -theta)))
    meas = simulate_grooving(m, (0.1, 0.1, 0.1), plan=plan, noise=MicroscopeNoise(sp, sd), seed=1)
    est = te.estimate(m, meas, closed=False)
    # Same measurements for both: the closed form takes the mean of each groove's start and end
    # depths (sigma_depth / sqrt 2 per groove), the least squares takes every value.
    return te.b_depth_closed_form_sigma(theta, -theta, sd / np.sqrt(2))[1], float(est.sigma[2])


def main(n: int = 1000) -> str:
    m = load_machine("robonano-ui")
    t_start = time.perf_counter()
    before, ls, cf, tz = paper_runs(m, n)
    cov_comp, cov_all, cov_m99, d2mean = coverage(m, n)
    names = ["A du", "A dv", "C du", "C dv"]
    paper_b = [*PAPER_ORIGINAL["A"], *PAPER_ORIGINAL["C"]]
    paper_a = [*PAPER_COMPENSATED["A"], *PAPER_COMPENSATED["C"]]
    ours_b = [x * 1e3 for x in (*before["A"], *before["C"])]
    rows = ["| distance | paper original | virtual original | paper compensated | LS compensated mean | "
            "LS 95th pct | closed-form compensated mean | closed-form 95th pct |",
            "|---|---|---|---|---|---|---|---|"]
    for j, nm in enumerate(names):
        rows.append(f"| {nm} | {paper_b[j]:.2f} | {ours_b[j]:.2f} | {paper_a[j]:.2f} | {ls[:, j].mean():.2f} | "
                    f"{np.percentile(ls[:, j], 95):.2f} | {cf[:, j].mean():.2f} | {np.percentile(cf[:, j], 95):.2f} |")
    worst_ls = np.max(ls, axis=1)
    worst_cf = np.max(cf, axis=1)
    sig_rows = ["| sigma_pos [um] | sigma_depth [um] | B angles | closed form sigma(t_z) from depths [um] | "
                "LS sigma(t_z) [um] | ratio |", "|---|---|---|---|---|---|"]
    ratios = {}
    for sp, sd, th in ((1.0, 1.0, 10.0), (1.0, 0.1, 10.0), (0.5, 0.1, 10.0), (0.2, 0.1, 10.0), (1.0, 0.1, 45.0)):
        c, l = tz_sigmas(m, sp * 1e-3, sd * 1e-3, th)
        ratios[(sp, sd, th)] = c / l
        sig_rows.append(f"| {sp:g} | {sd:g} | 0, +-{th:g} | {c * 1e3:.2f} | {l * 1e3:.2f} | {c / l:.1f} |")
    md = f"""## Tool setting by grooving (paper 000): Monte Carlo

`python benchmarks/tool_setting_mc.py {n}`, {n} runs per experiment, {time.perf_counter() - t_start:.0f} s. {machine_line()}

**Paper's experiment, virtually.** Machine robonano-ui, default plan (D = 0.1 mm, B at 0/+-10 deg),
true offset t = {tuple(round(x * 1e3, 2) for x in paper_offset())} um (reproduces Table 1's A distances),
microscope noise 1 um on positions and depths. Groove distances in um; "LS" = weighted least squares
(this package), "closed form" = the paper's procedure (A and C patterns for t_x, t_y, B depths with
the re-derived eq. (1)-(2) for t_z), both compensated through `retarget` and cut again virtually.

{chr(10).join(rows)}

Runs with every compensated distance below 5 um: LS {np.mean(worst_ls < 5) * 100:.1f} %, closed form
{np.mean(worst_cf < 5) * 100:.1f} %. The C distances of the paper cannot be matched together with its
A distances by a single tool offset on this machine model (both tests see the same t_x, t_y), see
docs/tool-setting.md. t_z error (not visible in Table 1's distances): RMS LS {np.sqrt(np.mean(tz[:, 0] ** 2)):.2f} um,
closed form from depths {np.sqrt(np.mean(tz[:, 1] ** 2)):.2f} um.

**Injected and recovered.** {n} seeded trials, true offsets uniform in +-1 mm per component, depth of
cut 0.3 mm, noise 1 um, random microscope origin per test: estimate within 3 sigma (reported covariance)
per component t_x {cov_comp[0] * 100:.1f} %, t_y {cov_comp[1] * 100:.1f} %, t_z {cov_comp[2] * 100:.1f} %;
all three at once {cov_all * 100:.1f} %; Mahalanobis distance inside the chi2(3) 99 % bound
{cov_m99 * 100:.1f} %; mean squared Mahalanobis distance {d2mean:.2f} (3 expected).

**t_z from depths versus lateral positions** (default plan; the same measurements for both: depth
and position at the start and end of every groove; the closed form uses the mean depth per groove):

{chr(10).join(sig_rows)}

The ratio scales with sigma_depth / sigma_pos: depths carry t_z with the factor (1 - cos theta)
(0.015 at 10 deg), lateral positions with sin theta (0.17).
"""
    update_section("tool_setting_mc", md)
    print(md)
    return md


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 1000)
