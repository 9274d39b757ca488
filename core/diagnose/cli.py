"""`mtcomp diagnose`: compare a simulation with a recording, name and fit what is missing."""
from __future__ import annotations

import argparse


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "diagnose", help="locate where SIM and REC disagree and name the physical effect",
        description="Align a simulation (SIM) and a recording (REC), find where they disagree, "
                    "name the physical effects the simulation left out (thermal_drift, backlash, "
                    "servo_lag, periodic_pitch_error, scale_error, squareness, straightness, "
                    "pivot_offset, workpiece_setting, time_offset, friction), fit them and show "
                    "the fit improve on held-out data, or say that the mismatch is unexplained. "
                    "Columns in both files are compared (names are case-sensitive); all other "
                    "columns are inputs. Units mm, deg, s, degC, mm/s, mm/s^2 unless the header "
                    "says, e.g. z[um], vx[mm/s].")
    p.add_argument("--sim", required=True, action="append", metavar="SIM.csv",
                   help="simulated signals (CSV, column t in s); repeat with --rec for several "
                        "recordings of one machine (shared physics, a clock each, each recording "
                        "predicted from the others), or give a folder of CSV files paired with "
                        "REC's folder by name")
    p.add_argument("--rec", required=True, action="append", metavar="REC.csv",
                   help="recorded signals (CSV, column t in s); one per --sim, in the same order")
    p.add_argument("--json", metavar="OUT.json", help="write the result as JSON")
    p.add_argument("--plot", metavar="OUT.png", help="plot recorded/simulated/corrected and residuals")
    p.add_argument("--report", metavar="OUT.md", help="write a Markdown report")
    p.add_argument("--output", action="append", metavar="COL|SIMCOL=RECCOL",
                   help="compare only this column (repeatable; it must be in both files), or "
                        "REC's RECCOL with SIM's SIMCOL (several REC columns may pair with one)")
    p.add_argument("--input", action="append", metavar="COL",
                   help="treat this column as an input even if both files have it (repeatable)")
    p.add_argument("--unit", action="append", metavar="COL=UNIT",
                   help="unit of a column whose header has none, e.g. --unit vx=mm/s (repeatable)")
    p.add_argument("--where", action="append", metavar="'COL OP VALUE'",
                   help="keep only the rows where this holds, e.g. --where 'FEEDRATE!=50' "
                        "(OP ==, !=, <, <=, >, >=; VALUE a number as written in the file, or a "
                        "text for == and !=; COL a column of either file; repeatable: all must "
                        "hold). The rows removed take no part in the fit or the held-out RMS")
    p.add_argument("--exclude-rows", action="append", metavar="'COL OP VALUE'",
                   help="remove the rows where this holds, e.g. --exclude-rows 'phase==Prep' "
                        "(repeatable: a row is removed when any holds)")
    p.add_argument("--dt", type=float, metavar="S",
                   help="logging period in s of a file without a time column (rows equally spaced, "
                        "e.g. --dt 0.1 for a 10 Hz log; an unnamed first column is taken as the "
                        "row index)")
    p.add_argument("--same-clock", action="store_true",
                   help="SIM and REC were logged on one clock: no clock offset is estimated, and a "
                        "common delay found is reported as a transport delay (time_offset), not "
                        "as clock alignment")
    p.add_argument("--model", metavar="OUTDIR",
                   help="also write the fitted effects in the machine model's formats (errors TOML, "
                        "machine dynamics, SSP parameter set) into OUTDIR, as `mtcomp model export` "
                        "does (docs/model-loop.md)")
    p.add_argument("--machine", metavar="PRESET|machine.toml",
                   help="machine of the model written by --model (default: from SIM's provenance "
                        "sidecar, written by `mtcomp model simulate`)")
    p.add_argument("--quiet", action="store_true", help="do not print the summary")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import os
    from .._io import atomic_write
    from .engine import diagnose
    from .._io import InputError
    units = {}
    for item in args.unit or ():
        col, sep, unit = item.partition("=")
        if not sep or not col.strip() or not unit.strip():
            raise InputError(f"--unit {item!r}: expected COL=UNIT, e.g. vx=mm/s", field="--unit")
        units[col.strip()] = unit.strip()
    machine = step = None
    if args.model:   # resolve the machine before the (long) diagnosis, so a missing one fails fast
        from ..model.simulate import provenance_path, read_provenance
        machine = args.machine
        if provenance_path(args.sim[0]).is_file():
            prov = read_provenance(args.sim[0])
            machine, step = machine or prov.machine, prov.step
        if machine is None:
            raise InputError("--model needs the machine: give --machine (SIM has no provenance "
                             "sidecar)", field="--machine")
    sims = args.sim[0] if len(args.sim) == 1 else args.sim
    recs = args.rec[0] if len(args.rec) == 1 else args.rec
    res = diagnose(sims, recs, outputs=args.output, inputs=args.input, units=units,
                   where=args.where, exclude_rows=args.exclude_rows, same_clock=args.same_clock,
                   dt=args.dt)
    if args.json:
        atomic_write(args.json, res.to_json() + "\n")
    if args.plot:
        res.plot(args.plot)
    if args.report:
        plot_name = None
        if args.plot:
            plot_name = os.path.relpath(os.path.abspath(args.plot),
                                        os.path.dirname(os.path.abspath(args.report)))
        atomic_write(args.report, res.report(plot_name))
    if args.model:
        from ..model.export import export_model
        ex = export_model(res, machine, args.model, step=step)
    if not args.quiet:
        print(res.summary())
        if args.model:
            print(ex.summary())
    return 0
