"""A hobby servo (Feetech STS3215, 12 V) on a pendulum test bench: commanded vs measured angle
(kscalelabs/sysid, data/feetech/STS_3215_12V_20250317/processed at commit 6b78737; no licence
file: the data stay out of the repository).

    python benchmarks/real/kscale_sts3215.py --src SNAPSHOT --out CORPUS

Each JSON run logs at 100 Hz (interpolated to 200 Hz by the source) the servo's goal position
and measured position (rad), with the bench's arm length, point mass and the servo's
proportional gain kp.  The cases are the smooth 'sin_sin' runs (a sine of a sine: reversals at
varying speed).  A proportionally controlled servo follows its goal with a lag that shrinks as
kp grows; the source's own model adds friction (LuGre) and notes backlash in the gear train.
The defensible effect is the position loop's lag; backlash, a reversal glitch, a sag under the
arm's weight (a scale-like error) or a delay may come on top.
"""
from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import Snapshot, case_dir, cli, progress, write_csv, write_truth  # noqa: E402

SOURCE = "kscale_sts3215"
URL = "https://github.com/kscalelabs/sysid"
COMMIT = "6b78737007c8741c6db3e50f8f05f048c16b68d2"
FOLDER = "data/feetech/STS_3215_12V_20250317/processed/"
TRAJ = "sin_sin"
PER_KP = 1          # one run per gain and arm length: the cases differ in stiffness and load
KPS = (4, 12, 32)   # the softest, a middle and the stiffest gain of the bench


def convert(snap: Snapshot, out: Path) -> list:
    files = sorted(f for f in snap.files(COMMIT) if f.startswith(FOLDER) and TRAJ in f)
    seen, chosen = {}, []
    for f in files:
        d = json.loads(snap.read(f, COMMIT))
        key = (d["kp"], d["length"])
        if seen.get(key, 0) < PER_KP and d["mass"] > 1.0 and d["kp"] in KPS:
            seen[key] = seen.get(key, 0) + 1
            chosen.append((f, d))
    done = []
    for i, (f, d) in enumerate(chosen, 1):
        e = d["entries"]
        t = np.array([x["timestamp"] for x in e], float)
        t -= t[0]
        keep = np.r_[True, np.diff(t) > 0]
        goal = np.array([x["goal_position"] for x in e], float)[keep]
        pos = np.array([x["position"] for x in e], float)[keep]
        t = t[keep]
        case = f"sinsin_kp{d['kp']}_L{int(round(d['length'] * 1000))}"
        progress(SOURCE, case, i, len(chosen))
        c = case_dir(out, SOURCE, case)
        write_csv(c / "sim.csv", {"t[s]": t, "q[rad]": goal})
        write_csv(c / "rec.csv", {"t[s]": t, "q[rad]": pos})
        write_truth(c / "truth.toml", source=SOURCE, case=case, kind="hobby servo, goal vs measured angle",
                    licence="none stated (not redistributed)", url=URL, commit=COMMIT,
                    authors="K-Scale Labs", files=[f], expected={"q": ["servo_lag"]},
                    acceptable={"q": ["time_offset", "backlash", "quadrant_glitch", "scale_error"]},
                    evidence=(f"README: proportional position control (kp {d['kp']}), arm "
                              f"{d['length'] * 1000:.0f} mm with {d['mass']:.2f} kg; the servo follows "
                              f"its goal with the loop's lag (RMS error {np.std(pos - goal):.3f} rad); "
                              f"friction and gear backlash noted by the source"),
                    args=["--same-clock"],
                    facts={"kp": d["kp"], "mass_kg": d["mass"], "length_m": d["length"],
                           "rms_error_rad": float(np.std(pos - goal)), "rate_hz": d["sample_rate"]})
        done.append(case)
    return done


if __name__ == "__main__":
    src, out = cli(SOURCE, __doc__)
    convert(Snapshot(src), out)
