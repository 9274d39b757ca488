"""The four development runs of the UMich "CNC Mill Tool Wear" data set (public domain, CC0;
SMART lab, University of Michigan): commanded vs measured axis velocities of a 3-axis mill
logged at 10 Hz.

    python benchmarks/real/umich_cnc.py --src DATA_DIR --out CORPUS

DATA_DIR holds experiment_NN.csv.  SIM is the commanded velocity, acceleration and position,
REC the measured velocity (tests/data/umich/make_excerpt.py).  Every moving axis follows its
command with the lag of its position loop (kv about 110-170 1/s): the defensible effect is a
servo lag on vx, vy and vz.
"""
from __future__ import annotations

import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(HERE.parent.parent / "tests" / "data" / "umich"))
from _common import case_dir, cli, progress, write_truth  # noqa: E402

SOURCE = "umich_cnc"
URL = "https://www.kaggle.com/datasets/shasun/tool-wear-detection-in-cnc-mill"
RUNS = ("01", "04", "06", "11")


def convert(src: Path, out: Path) -> list:
    from make_excerpt import convert as make
    done = []
    for i, r in enumerate(RUNS, 1):
        case = f"exp{r}"
        progress(SOURCE, case, i, len(RUNS))
        d = case_dir(out, SOURCE, case)
        make(Path(src) / f"experiment_{r}.csv", d, state=False)
        write_truth(d / "truth.toml", source=SOURCE, case=case, kind="CNC command vs actual velocity",
                    licence="CC0 (public domain)", url=URL, commit="",
                    authors="System-level Manufacturing and Automation Research Testbed, University of Michigan",
                    files=[f"experiment_{r}.csv"],
                    expected={"vx": ["servo_lag"], "vy": ["servo_lag"], "vz": ["servo_lag"]},
                    acceptable={o: ["time_offset"] for o in ("vx", "vy", "vz")},
                    evidence=("commanded vs actual velocity of one control's log: a position loop "
                              "follows with a first-order lag, velocity error -a_cmd/kv"),
                    facts={"rate_hz": 10.0})
        done.append(case)
    return done


if __name__ == "__main__":
    src, out = cli(SOURCE, __doc__)
    convert(src, out)
