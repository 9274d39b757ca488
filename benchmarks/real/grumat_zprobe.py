"""Inductive Z-probe thermal drift on a Voron Trident 3D printer (grumat/voron-trident-250_config,
folder z-probe_benchmark, MIT licence).

    python benchmarks/real/grumat_zprobe.py --src SNAPSHOT --out CORPUS

Each data file is a Klipper probe-accuracy run of about 47 minutes: the probe is lowered onto
the bed at one place every 2 s while the bed and nozzle heat up, soak and cool down; the log
holds the triggered z (mm, on Klipper's 1.25 µm step lattice of this Z drive) and, every 20 s,
the bed, chamber and extruder temperatures.  SIM is what a model without heat says the probe
reads: z = 0 at every probe, with the logged temperatures as inputs; REC is the triggered z.
The source's README measures a trigger-point shift of 0.024-0.27 mm from cold to hot: the
defensible effect is thermal drift of z following the temperatures.
"""
from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import Snapshot, case_dir, cli, progress, write_csv, write_truth  # noqa: E402

SOURCE = "grumat_zprobe"
URL = "https://github.com/grumat/voron-trident-250_config"
FOLDER = "z-probe_benchmark/data/"


def parse(text: str):
    """(t_z, z) of the probes and (t_T, bed, chamber, extruder) of the temperature records,
    times in s from the first record."""
    zs, temps = [], []
    for line in text.splitlines():
        if not line.strip():
            continue
        d = json.loads(line)
        if "z" in d:
            zs.append((d["ts"], d["z"]))
        elif "btemp" in d:
            ch = d.get("atherms") or [{"temp": np.nan}]
            temps.append((d["ts"], d["btemp"], ch[0]["temp"], d["etemp"]))
    zs, temps = np.array(zs, float), np.array(temps, float)
    t0 = min(zs[0, 0], temps[0, 0])
    zs[:, 0] -= t0
    temps[:, 0] -= t0
    return zs, temps


def convert(snap: Snapshot, out: Path) -> list:
    names = [f for f in snap.files() if f.startswith(FOLDER) and f.endswith(".json")]
    commit = snap.head()
    done = []
    for i, f in enumerate(sorted(names), 1):
        case = Path(f).stem.replace("probe_accuracy_", "")
        progress(SOURCE, case, i, len(names))
        zs, temps = parse(snap.read(f))
        d = case_dir(out, SOURCE, case)
        # temperatures at the probe instants (linear between the 20 s records): SIM's inputs
        t = zs[:, 0]
        bed, ch, ex = (np.interp(t, temps[:, 0], temps[:, k]) for k in (1, 2, 3))
        write_csv(d / "sim.csv", {"t[s]": t, "z[mm]": np.zeros_like(t), "t_bed[degC]": bed,
                                  "t_chamber[degC]": ch, "t_extruder[degC]": ex})
        write_csv(d / "rec.csv", {"t[s]": t, "z[mm]": zs[:, 1]})
        shift = float(np.mean(zs[-60:, 1]) - np.mean(zs[:60, 1]))
        write_truth(d / "truth.toml", source=SOURCE, case=case, kind="3D-printer probe drift",
                    licence="MIT", url=URL, commit=commit, authors="grumat", files=[f],
                    expected={"z": ["thermal_drift"]},
                    evidence=("README (z-probe_benchmark): inductive sensors drift as bed and "
                              "nozzle heat; trigger point shifts 0.024-0.27 mm cold to hot; "
                              "z follows the logged temperatures with a lag"),
                    args=["--same-clock"],
                    facts={"z_step_mm": 0.00125, "shift_last_minus_first_2min_mm": round(shift, 5),
                           "bed_max_degC": float(temps[:, 1].max())})
        done.append(case)
    return done


if __name__ == "__main__":
    src, out = cli(SOURCE, __doc__)
    convert(Snapshot(src), out)
