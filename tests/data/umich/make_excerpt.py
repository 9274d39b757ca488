"""Write SIM/REC CSV files for `mtcomp diagnose` from a run of the UMich "CNC Mill Tool Wear"
data set (public domain, CC0; System-level Manufacturing and Automation Research Testbed,
University of Michigan).

    python make_excerpt.py experiment_01.csv OUTDIR [--rows A:B]

SIM is what the control commanded (velocity, acceleration and position of X, Y, Z), REC what
the drives measured (velocity).  One row per 100 ms sample; the row index gives t.  Outputs are
the axis velocities vx, vy, vz [mm/s]: the positions are written with three significant
figures (a 1 mm step above 100 mm), far coarser than the servo lag they would show.  The
columns of the source's validity rule come along (feed rate and program number in SIM, the
measured X position in REC), for `mtcomp diagnose --where` (VALID_ROWS).
"""
import csv
import sys
from pathlib import Path

SIM = [("vx[mm/s]", "X1_CommandVelocity"), ("vy[mm/s]", "Y1_CommandVelocity"),
       ("vz[mm/s]", "Z1_CommandVelocity"), ("ax_cmd[mm/s^2]", "X1_CommandAcceleration"),
       ("ay_cmd[mm/s^2]", "Y1_CommandAcceleration"), ("az_cmd[mm/s^2]", "Z1_CommandAcceleration"),
       ("x_cmd[mm]", "X1_CommandPosition"), ("y_cmd[mm]", "Y1_CommandPosition"),
       ("z_cmd[mm]", "Z1_CommandPosition")]
REC = [("vx[mm/s]", "X1_ActualVelocity"), ("vy[mm/s]", "Y1_ActualVelocity"),
       ("vz[mm/s]", "Z1_ActualVelocity")]
# the columns of the source's validity rule (VALID_ROWS), under their own names: the control's
# state in SIM, the measured X position in REC
SIM_STATE = [("M1_CURRENT_FEEDRATE", "M1_CURRENT_FEEDRATE"),
             ("M1_CURRENT_PROGRAM_NUMBER", "M1_CURRENT_PROGRAM_NUMBER")]
REC_STATE = [("X1_ActualPosition[mm]", "X1_ActualPosition")]
# The source says that some rows do not reflect the machine: where M1_CURRENT_FEEDRATE reads
# 50, X1_ActualPosition reads 198, or (as its README words it) M1_CURRENT_PROGRAM_NUMBER is not
# 0.  Every row of the four runs reads program 1, so that last clause, read literally, would
# remove every row; the rule applied keeps a running program (number not 0) and removes the
# rows with no program (0), which is the reading under which "some rows" holds.
VALID_ROWS = ("M1_CURRENT_FEEDRATE!=50", "X1_ActualPosition!=198", "M1_CURRENT_PROGRAM_NUMBER!=0")


def convert(src, outdir, rows=None, state=True):
    """SIM and REC files from one run (`state`: with the columns of the validity rule)."""
    with open(src, newline="") as f:
        table = list(csv.reader(f))
    head, body = table[0], table[1:]
    if rows:
        body = body[rows[0]:rows[1]]
    outdir = Path(outdir)
    outdir.mkdir(parents=True, exist_ok=True)
    for name, cols in (("sim.csv", SIM + SIM_STATE * state), ("rec.csv", REC + REC_STATE * state)):
        idx = [head.index(c) for _, c in cols]
        lines = ["t[s]," + ",".join(h for h, _ in cols)]
        for i, r in enumerate(body):
            lines.append(f"{0.1 * i:.1f}," + ",".join(r[j] for j in idx))
        (outdir / name).write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    rows = None
    if "--rows" in sys.argv:
        a, b = sys.argv[sys.argv.index("--rows") + 1].split(":")
        rows = (int(a), int(b))
    convert(sys.argv[1], sys.argv[2], rows)
