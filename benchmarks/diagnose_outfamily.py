"""Out-of-family proof of the diagnosis: recordings made another way than mtcomp.diagnose.synth.

None of these generators shares code, naming, sampling or functional form with the effect
library or with synth (they are not tuned on):

- physics simulated on a fine time grid (10 kHz) and sampled twice, SIM and REC, on their own
  clocks and rates, instead of effects added to samples;
- jerk-limited (S-curve) moves, piecewise-linear corner paths, stop-and-measure runs;
- outputs named `carriage`, `q2`, `ELEV`, `spd_axis`, `stage`, `axis1`, `Soll_X`/`Ist_X`
  (positions in µm or inches, joint angles, velocities), 60-400 samples in some, 1 µm counts in
  some, an irregular clock with pauses and empty cells in one;
- an optical scale's cyclic interpolation error (harmonics 1 and 2 of a 20-40 µm period);
- friction at reversals simulated as stick-slip (the library's quadrant_glitch has another
  shape), and an effect outside the library (a joint hunting around a constant set point),
  which must be answered with "unexplained mismatch", not with a wrong name.

Each case states what an honest answer is: the set of library effects to name, or
"unexplained" (no effect named, or the named ones leave the output flagged unexplained).
Usage: python benchmarks/diagnose_outfamily.py [--seeds N] [--jobs J]; also run by
benchmarks/diagnose_suite.py, which reports it beside the in-family suite.
"""
from __future__ import annotations

import os
import time
from concurrent.futures import ProcessPoolExecutor

for _v in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import numpy as np  # noqa: E402

FINE = 1e-4  # s, the physics' own time step


def s_curve_path(rng, t, lo, hi, vmax, amax, jmax, dwell=(0.3, 1.5)):
    """Jerk-limited point-to-point moves with dwells on the fine grid t (position, mm or deg).

    Built as a velocity step train smoothed twice by moving averages (acceleration and jerk
    limits): the classic S-curve of a CNC interpolator, with continuous acceleration.
    """
    v = np.zeros_like(t)
    i = 0
    n = len(t)
    p = rng.uniform(lo, hi)
    start = p
    while i < n:
        i += int(rng.uniform(*dwell) / FINE)
        target = rng.uniform(lo, hi)
        d = target - p
        speed = rng.uniform(0.3, 1.0) * vmax
        dur = abs(d) / speed
        k = int(dur / FINE)
        if k < 2 or i + k >= n:
            break
        v[i:i + k] = d / (k * FINE)
        p = target
        i += k
    for width in (vmax / amax, amax / jmax):
        w = max(1, int(width / FINE))
        v = np.convolve(v, np.ones(w) / w, mode="full")[:n]
    return start + np.cumsum(v) * FINE


def corner_path(rng, t, lo, hi, feed, n_corners):
    """Piecewise-linear path at constant feed with sharp corners (G1 blocks, no smoothing) and
    an exact stop of 0.2-1 s at every corner (without stops a backlash and a delay are the same
    sign flip with the direction of motion, and no diagnosis can tell them apart)."""
    knots_t = [t[0]]
    knots_p = [rng.uniform(lo, hi)]
    while knots_t[-1] < t[-1]:
        q = rng.uniform(lo, hi)
        knots_t.append(knots_t[-1] + rng.uniform(0.2, 1.0))
        knots_p.append(knots_p[-1])
        knots_t.append(knots_t[-1] + abs(q - knots_p[-1]) / feed + 1e-3)
        knots_p.append(q)
    return np.interp(t, knots_t, knots_p)


def lag(u, tau):
    """First-order lag by explicit Euler on the fine grid (deliberately not the diagnosis' form)."""
    if tau <= 0:
        return u.copy()
    y = np.empty_like(u)
    a = FINE / tau
    acc = u[0]
    for k in range(len(u)):  # plain loop: an independent integrator
        acc += a * (u[k] - acc)
        y[k] = acc
    return y


def play(p, width):
    """Backlash: the driven part follows the screw only once the gap is taken up."""
    y = np.empty_like(p)
    h = width / 2
    cur = p[0]
    for k in range(len(p)):
        cur = min(max(cur, p[k] - h), p[k] + h)
        y[k] = cur
    return y


def sample(t, y, t_s, clock=0.0):
    """Values at times t_s of a recorder whose clock reads t + clock (the physical time is t_s - clock)."""
    return np.interp(np.asarray(t_s) - clock, t, y)


def case(kind: str, seed: int) -> dict:
    """One out-of-family case: {'sim': ..., 'rec': ..., 'expect': set or 'unexplained', 'outs': ...}."""
    rng = np.random.default_rng(seed)
    noise = 0.2e-3  # mm: a shop-floor encoder with 0.2 µm noise
    if kind == "joint_servo_lag":
        # a robot joint in degrees, named q2, servo time constant 15-40 ms, SIM 250 Hz, REC 100 Hz
        T = rng.uniform(12, 20)
        t = np.arange(0, T, FINE)
        cmd = s_curve_path(rng, t, -60, 60, 40.0, 200.0, 4000.0)
        tau = rng.uniform(0.015, 0.04)
        act = lag(cmd, tau)
        ts = np.arange(0, T, 1 / 250)
        tr = np.arange(0.05, T - 0.05, 1 / 100)
        rec = sample(t, act, tr) + rng.normal(0, 2e-4, len(tr))
        return {"sim": {"t": ts, "q2[deg]": sample(t, cmd, ts)}, "rec": {"t": tr, "q2[deg]": rec},
                "expect": {"servo_lag"}, "truth": {"kv_per_s": 1 / tau}}
    if kind == "velocity_servo_lag":
        # velocity output with its commanded acceleration logged, 10 Hz like a cloud collector
        T = rng.uniform(25, 40)
        t = np.arange(0, T, FINE)
        cmd = s_curve_path(rng, t, 0, 200, 30.0, 300.0, 5000.0)
        v = np.gradient(cmd, FINE)
        a = np.gradient(v, FINE)
        tau = rng.uniform(0.005, 0.02)
        va = lag(v, tau)
        ts = np.arange(0, T, 0.1)
        return {"sim": {"t": ts, "spd_axis[mm/s]": sample(t, v, ts), "acc_axis[mm/s^2]": sample(t, a, ts)},
                "rec": {"t": ts, "spd_axis[mm/s]": sample(t, va, ts) + rng.normal(0, 0.02, len(ts))},
                "expect": {"servo_lag"}, "truth": {"kv_per_s": 1 / tau}}
    if kind == "backlash_um_counts":
        # jerk-limited moves, backlash 3-10 µm, REC in 1 µm counts, header in µm, 300 samples
        T = rng.uniform(20, 30)
        t = np.arange(0, T, FINE)
        cmd = s_curve_path(rng, t, 0, 150, 50.0, 500.0, 10000.0)
        b = rng.uniform(3e-3, 10e-3)
        act = play(cmd, b)
        ts = np.arange(0, T, 1 / 200)
        tr = np.linspace(0.1, T - 0.1, 300)
        rec = np.round((sample(t, act, tr) + rng.normal(0, noise, len(tr))) * 1e3)  # µm counts
        return {"sim": {"t": ts, "carriage[um]": sample(t, cmd, ts) * 1e3},
                "rec": {"t": tr, "carriage[um]": rec}, "expect": {"backlash"}, "truth": {"backlash_mm": b}}
    if kind == "stop_and_measure":
        # ISO 230-2 style: bidirectional runs to 9 targets, reading after settling; reversal 5-15 µm
        targets = np.sort(rng.uniform(0, 400, 9))
        seq = np.concatenate([targets, targets[::-1]] * 3)
        rev = rng.uniform(5e-3, 15e-3)
        ts, ps, tr, pr = [], [], [], []
        tt, prev, d = 0.0, seq[0] - 5.0, 1.0
        for p in seq:
            move = np.linspace(prev, p, 40)
            ts += list(tt + np.linspace(0, 2.0, 40, endpoint=False))
            ps += list(move)
            ts += list(tt + 2.0 + np.linspace(0, 1.9, 10))
            ps += [p] * 10
            d = np.sign(p - prev) if p != prev else d
            tr.append(tt + 3.5)
            pr.append(p - d * rev / 2 + rng.normal(0, 1e-3))
            prev = p
            tt += 4.0
        return {"sim": {"t": np.array(ts), "ELEV": np.array(ps)}, "rec": {"t": np.array(tr), "ELEV": np.array(pr)},
                "expect": {"backlash"}, "truth": {"backlash_mm": rev}}
    if kind == "thermal_spindle_steps":
        # growth of a spindle axis after speed steps (no temperature logged), 200-400 samples
        T = rng.uniform(1800, 3600)
        n = int(rng.integers(200, 400))
        tf = np.linspace(0, T, 20000)
        hf = tf[1] - tf[0]
        speed = np.where(tf < T * 0.2, 0.0, np.where(tf < T * 0.6, 12000.0, 4000.0))
        tau = rng.uniform(0.15, 0.4) * T
        g = np.empty_like(tf)
        acc = 0.0
        for k in range(len(tf)):
            acc += hf / tau * (speed[k] * 2e-6 - acc)  # 24 µm at 12000 rpm in steady state
            g[k] = acc
        tr = np.linspace(1.0, T - 1.0, n)
        ts = np.linspace(0, T, 2 * n)
        z = 25.0 + 0.0 * ts
        return {"sim": {"t": ts, "spindle_z": z, "S_speed[rpm]": np.interp(ts, tf, speed)},
                "rec": {"t": tr, "spindle_z": 25.0 + np.interp(tr, tf, g) + rng.normal(0, noise, n)},
                "expect": {"thermal_drift"}, "truth": {"tau_s": tau}}
    if kind == "clock_and_lag":
        # REC on a clock started 0.2-0.6 s apart and a servo lag on both axes (stage A and B)
        T = rng.uniform(15, 25)
        t = np.arange(-1, T + 1, FINE)
        clock = rng.uniform(0.2, 0.6) * rng.choice([-1, 1])
        outs = {}
        recs = {}
        ts = np.arange(0, T, 1 / 500)
        tr = np.arange(0.5 + max(clock, 0), T - 0.5 + min(clock, 0), 1 / 250)
        tau = rng.uniform(0.01, 0.03)
        for name in ("stageA", "stageB"):
            cmd = s_curve_path(rng, t, 0, 100, 40.0, 400.0, 8000.0)
            outs[name] = sample(t, cmd, ts)
            recs[name] = sample(t, lag(cmd, tau), tr, clock) + rng.normal(0, noise, len(tr))
        return {"sim": {"t": ts, **outs}, "rec": {"t": tr, **recs}, "expect": {"servo_lag"},
                "truth": {"kv_per_s": 1 / tau, "clock": clock}}
    if kind == "corners_sim_coarse":
        # a G1 corner path commanded at 20 Hz, recorded at 500 Hz, with a backlash
        T = rng.uniform(20, 30)
        t = np.arange(0, T, FINE)
        cmd = corner_path(rng, t, 0, 80, rng.uniform(5, 15), 20)
        b = rng.uniform(3e-3, 8e-3)
        ts = np.arange(0, T, 1 / 20)
        tr = np.arange(0.2, T - 0.2, 1 / 500)
        return {"sim": {"t": ts, "carriage": sample(t, cmd, ts)},
                "rec": {"t": tr, "carriage": sample(t, play(cmd, b), tr) + rng.normal(0, noise, len(tr))},
                "expect": {"backlash"}, "truth": {"backlash_mm": b}}
    if kind == "friction_stick_slip":
        # friction at reversals simulated as stick-slip: after every reversal the slide stays
        # stuck for 20-60 ms while the command moves away, then slips back with a 30 ms decay
        # (a different shape from the library's quadrant_glitch, which must still name it)
        T = rng.uniform(15, 25)
        t = np.arange(0, T, FINE)
        cmd = 50 + 30 * np.sin(2 * np.pi * t / rng.uniform(2.0, 4.0))
        v = np.gradient(cmd, FINE)
        rev = np.flatnonzero(np.diff(np.sign(v)) != 0)
        err = np.zeros_like(t)
        stick = rng.uniform(0.02, 0.06)
        ks = int(stick / FINE)
        for i in rev:
            a = np.arange(i, min(len(t), i + ks))
            err[a] = cmd[i] - cmd[a]
            if i + ks < len(t):
                b = np.arange(i + ks, min(len(t), i + ks + int(0.4 / FINE)))
                err[b] = (cmd[i] - cmd[i + ks]) * np.exp(-(t[b] - t[i + ks]) / 0.03)
        ts = np.arange(0, T, 1 / 200)
        tr = np.arange(0.1, T - 0.1, 1 / 200)
        return {"sim": {"t": ts, "stage": sample(t, cmd, ts)},
                "rec": {"t": tr, "stage": sample(t, cmd + err, tr) + rng.normal(0, noise, len(tr))},
                "expect": {"quadrant_glitch"}}
    if kind == "joint_hunting":
        # outside the library: a tendon joint hunting (limit cycle) around a constant set point
        T = rng.uniform(10, 20)
        ts = np.arange(0, T, 1 / 100)
        tr = np.arange(0.05, T - 0.05, 1 / 100)
        cmd = np.where(ts < T / 3, 10.0, 25.0)
        f = rng.uniform(1.5, 4.0)
        act = np.where(tr < T / 3, 10.0, 25.0) + 0.05 * np.sign(np.sin(2 * np.pi * f * tr)) * (tr > T / 3 + 0.5)
        return {"sim": {"t": ts, "q4[deg]": cmd}, "rec": {"t": tr, "q4[deg]": act + rng.normal(0, 2e-4, len(tr))},
                "expect": "unexplained"}
    if kind == "null_fine":
        # no effect: the same S-curve physics sampled twice, 1 µm counts in µm
        T = rng.uniform(10, 20)
        t = np.arange(0, T, FINE)
        cmd = s_curve_path(rng, t, 0, 100, 40.0, 400.0, 8000.0)
        ts = np.arange(0, T, 1 / 250)
        tr = np.arange(0.1, T - 0.1, 1 / 100)
        return {"sim": {"t": ts, "slide[um]": sample(t, cmd, ts) * 1e3},
                "rec": {"t": tr, "slide[um]": np.round(sample(t, cmd, tr) * 1e3 + rng.normal(0, 0.3, len(tr)))},
                "expect": set()}
    if kind == "encoder_cyclic_scale":
        # a slow scan of an optical scale (signal period 20 or 40 µm) whose interpolation error
        # has a first and a second harmonic, behind a position loop; REC in µm at 1 kHz, 3 nm noise
        T = rng.uniform(8, 14)
        t = np.arange(0, T, FINE)
        cmd = s_curve_path(rng, t, 0, rng.uniform(1.0, 3.0), rng.uniform(0.3, 1.0), 10.0, 200.0,
                           dwell=(0.1, 0.4))
        tau = rng.uniform(0.01, 0.03)
        act = lag(cmd, tau)
        period = float(rng.choice([0.02, 0.04]))
        a1, a2 = rng.uniform(20e-6, 60e-6), rng.uniform(8e-6, 20e-6)
        f1, f2 = rng.uniform(0, 2 * np.pi, 2)
        read = act + a1 * np.cos(2 * np.pi * act / period + f1) + a2 * np.cos(4 * np.pi * act / period + f2)
        ts = np.arange(0, T, 1 / 2000)
        tr = np.arange(0.05, T - 0.05, 1 / 1000)
        return {"sim": {"t": ts, "table_x[um]": sample(t, cmd, ts) * 1e3},
                "rec": {"t": tr, "table_x[um]": (sample(t, read, tr) + rng.normal(0, 3e-6, len(tr))) * 1e3},
                "expect": {"encoder_cyclic_error", "servo_lag"}, "truth": {"period_mm": period}}
    if kind == "gaps_irregular_backlash":
        # a logger on an irregular clock (exponential jitter around 5 ms), two pauses of 1-3 s and
        # 1 % of its cells empty (NaN), backlash 4-10 µm on jerk-limited moves
        T = rng.uniform(20, 30)
        t = np.arange(0, T, FINE)
        cmd = s_curve_path(rng, t, 0, 120, 40.0, 400.0, 8000.0)
        b = rng.uniform(4e-3, 10e-3)
        ts = np.arange(0, T, 1 / 250)
        tr = np.cumsum(rng.exponential(0.005, int(2 * T / 0.005)))
        tr = tr[(tr > 0.1) & (tr < T - 0.1)]
        for _ in range(2):
            a = rng.uniform(2, T - 5)
            tr = tr[(tr < a) | (tr > a + rng.uniform(1, 3))]
        rec = sample(t, play(cmd, b), tr) + rng.normal(0, noise, len(tr))
        rec[rng.random(len(tr)) < 0.01] = np.nan
        return {"sim": {"t": ts, "axis1": sample(t, cmd, ts)}, "rec": {"t": tr, "axis1": rec},
                "expect": {"backlash"}, "truth": {"backlash_mm": b}}
    if kind == "inch_sparse_lag":
        # a servo lag seen by 60-100 readings in inches (5 decimals: 0.25 µm) of a 20 s run
        T = rng.uniform(15, 25)
        t = np.arange(0, T, FINE)
        cmd = s_curve_path(rng, t, 0, 200, 40.0, 300.0, 5000.0)
        tau = rng.uniform(0.02, 0.05)
        n = int(rng.integers(60, 100))
        ts = np.arange(0, T, 1 / 100)
        tr = np.sort(rng.uniform(0.2, T - 0.2, n))
        rec = np.round((sample(t, lag(cmd, tau), tr) + rng.normal(0, 0.5e-3, n)) / 25.4, 5)
        return {"sim": {"t": ts, "carriage[mm]": sample(t, cmd, ts)}, "rec": {"t": tr, "carriage[in]": rec},
                "expect": {"servo_lag"}, "truth": {"kv_per_s": 1 / tau}}
    if kind == "soll_ist_names":
        # German names, command and measurement in different columns (Soll_X / Ist_X), no units:
        # a backlash on X, nothing on Y
        T = rng.uniform(15, 25)
        t = np.arange(0, T, FINE)
        cx = s_curve_path(rng, t, 0, 100, 30.0, 300.0, 6000.0)
        cy = s_curve_path(rng, t, 0, 100, 30.0, 300.0, 6000.0)
        b = rng.uniform(3e-3, 8e-3)
        ts = np.arange(0, T, 1 / 200)
        tr = np.arange(0.1, T - 0.1, 1 / 200)
        return {"sim": {"t": ts, "Soll_X": sample(t, cx, ts), "Soll_Y": sample(t, cy, ts)},
                "rec": {"t": tr, "Ist_X": sample(t, play(cx, b), tr) + rng.normal(0, noise, len(tr)),
                        "Ist_Y": sample(t, cy, tr) + rng.normal(0, noise, len(tr))},
                "expect": {"backlash"}, "truth": {"backlash_mm": b}}
    raise ValueError(kind)


KINDS = ("joint_servo_lag", "velocity_servo_lag", "backlash_um_counts", "stop_and_measure",
         "thermal_spindle_steps", "clock_and_lag", "corners_sim_coarse", "friction_stick_slip",
         "joint_hunting", "null_fine", "encoder_cyclic_scale", "gaps_irregular_backlash",
         "inch_sparse_lag", "soll_ist_names")


def run(spec):
    from mtcomp.diagnose import diagnose
    kind, seed = spec
    c = case(kind, seed)
    t0 = time.perf_counter()
    res = diagnose(c["sim"], c["rec"])
    dt = time.perf_counter() - t0
    named = set(res.names)
    unexpl = {u["output"] for u in res.unexplained}
    if c["expect"] == "unexplained":
        ok = bool(unexpl)
    else:
        ok = named == c["expect"] and (not c["expect"] or not unexpl)
    ratio = max(res.fit["holdout_rms_after"][o] / res.noise_floor[o] for o in res.outputs)
    # the one answer that must never happen: nothing named, nothing said, far above the noise
    silent = (not named and not unexpl and ratio > 3.0)
    return {"kind": kind, "seed": seed, "named": sorted(named), "unexplained": sorted(unexpl),
            "expect": c["expect"] if isinstance(c["expect"], str) else sorted(c["expect"]),
            "ok": ok, "ratio": ratio, "silent": silent, "seconds": dt}


def run_all(seeds: int = 2, jobs: int = 2, progress=print) -> list:
    specs = [(k, 500 + 37 * s + i) for s in range(seeds) for i, k in enumerate(KINDS)]
    out = []
    with ProcessPoolExecutor(max_workers=jobs) as ex:
        for r in ex.map(run, specs):
            out.append(r)
            if progress:
                progress(f"  {r['kind']:24s} expect {str(r['expect']):28s} named {'+'.join(r['named']) or 'none':24s} "
                         f"unexplained {','.join(r['unexplained']) or '-':10s} {'ok ' if r['ok'] else 'MISS'} "
                         f"held-out/noise {r['ratio']:.2f} {r['seconds']:.1f} s")
    return out


def markdown(results) -> str:
    lib = [r for r in results if r["expect"] not in ("unexplained", [])]
    out_lib = [r for r in results if r["expect"] == "unexplained"]
    null = [r for r in results if r["expect"] == []]
    seeds = sorted({r["seed"] for r in results})
    lines = [f"Out-of-family cases (`benchmarks/diagnose_outfamily.py`, not tuned on): "
             f"{len(results)} recordings from physics simulated at 10 kHz and sampled twice "
             f"(seed 500 + 37 s + i for repetition s and family i: seeds {seeds[0]}..{seeds[-1]}).", "",
             "| family | cases | honest answer | held-out RMS / noise (median) |", "|---|---|---|---|"]
    for k in KINDS:
        rs = [r for r in results if r["kind"] == k]
        if rs:
            lines.append(f"| {k} | {len(rs)} | {sum(r['ok'] for r in rs)}/{len(rs)} | "
                         f"{np.median([r['ratio'] for r in rs]):.2f} |")
    tot = sum(r["ok"] for r in results)
    lines += ["", f"In the library: {sum(r['ok'] for r in lib)}/{len(lib)} right effect set; outside "
              f"it: {sum(r['ok'] for r in out_lib)}/{len(out_lib)} said 'unexplained'; null: "
              f"{sum(r['ok'] for r in null)}/{len(null)} clean; all: {tot}/{len(results)} = "
              f"{100 * tot / max(len(results), 1):.0f} %. Cases ending silent (nothing named, nothing "
              f"flagged, residual > 3x noise): {sum(r['silent'] for r in results)}."]
    bad = [r for r in results if not r["ok"]]
    if bad:
        lines += ["", "Misses: " + "; ".join(
            f"{r['kind']} (seed {r['seed']}): named {'+'.join(r['named']) or 'none'}, unexplained "
            f"{','.join(r['unexplained']) or '-'}" for r in bad) + "."]
    return "\n".join(lines)


if __name__ == "__main__":
    import argparse
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", type=int, default=2)
    ap.add_argument("--jobs", type=int, default=min(2, os.cpu_count() or 1))
    a = ap.parse_args()
    res = run_all(a.seeds, a.jobs)
    print(markdown(res))
