"""`mtcomp fleet diagnose|report`: nightly diagnosis of many machines on Dask, and their trends."""
from __future__ import annotations

import argparse
import sys

from ..cliargs import positive_float, positive_int


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "fleet", help="diagnose every machine's nightly recordings on Dask; trends that warn",
        description="Diagnose many machines' recordings night by night on Dask distributed "
                    "(an embedded local cluster, or --scheduler), keep the results as a Parquet "
                    "dataset partitioned by machine and date, and report each parameter over "
                    "time with warnings. Needs the optional extra: pip install 'mtcomp[fleet]'.")
    p.set_defaults(func=_no_command, fleet_parser=p)
    sub = p.add_subparsers(dest="fleet_command", metavar="COMMAND")

    d = sub.add_parser(
        "diagnose", help="diagnose every machine-night of SOURCE into DATASET",
        description="Diagnose every machine-night of SOURCE as `mtcomp diagnose` would and write "
                    "one row per machine x night x effect x parameter to the Parquet dataset "
                    "DATASET (machine=<m>/date=<d>/part-0.parquet). SOURCE is a folder "
                    "<machine>/<date>/sim.csv,rec.csv (options per machine in "
                    "<machine>/diagnose.toml) or a manifest CSV with columns machine,date,sim,rec "
                    "and option columns (output, input, unit, where, exclude_rows, same_clock, "
                    "dt). A night already in DATASET is replaced. Exit status 1 when a night "
                    "could not be diagnosed (listed).")
    d.add_argument("source", metavar="SOURCE", help="folder <machine>/<date>/ or manifest CSV")
    d.add_argument("-o", "--out", required=True, metavar="DATASET", help="dataset folder to write")
    d.add_argument("--scheduler", metavar="tcp://HOST:8786",
                   help="address of a running Dask scheduler (default: an embedded local cluster)")
    d.add_argument("--workers", type=positive_int, metavar="N",
                   help="worker processes of the embedded cluster (default: one per core)")
    d.add_argument("--output", action="append", metavar="COL|SIMCOL=RECCOL",
                   help="as for mtcomp diagnose, for every machine (repeatable)")
    d.add_argument("--input", action="append", metavar="COL", help="as for mtcomp diagnose")
    d.add_argument("--unit", action="append", metavar="COL=UNIT", help="as for mtcomp diagnose")
    d.add_argument("--where", action="append", metavar="'COL OP VALUE'", help="as for mtcomp diagnose")
    d.add_argument("--exclude-rows", action="append", metavar="'COL OP VALUE'",
                   help="as for mtcomp diagnose")
    d.add_argument("--dt", type=positive_float, metavar="S", help="as for mtcomp diagnose")
    d.add_argument("--same-clock", action="store_true", help="as for mtcomp diagnose")
    d.add_argument("--skip-done", action="store_true",
                   help="skip the nights DATASET already holds from the same files (SHA-256), "
                        "options and mtcomp version without error: a nightly run over the whole "
                        "SOURCE diagnoses only what is new or changed")
    d.add_argument("--progress", action="store_true",
                   help="show progress even when stderr is not a terminal")
    d.add_argument("--quiet", action="store_true", help="do not print the summary")
    d.set_defaults(func=run_diagnose)

    r = sub.add_parser(
        "report", help="HTML report of DATASET: parameters over time, warnings",
        description="Per machine and output, each parameter over the nights with its 1-sigma "
                    "band, and a table of warnings: a change beyond k combined sigmas against the "
                    "earlier nights, or a limit of --limits crossed. Exit status 1 when any "
                    "warning was raised, 0 when none.")
    r.add_argument("dataset", metavar="DATASET", help="dataset written by mtcomp fleet diagnose")
    r.add_argument("-o", "--out", required=True, metavar="REPORT.html")
    r.add_argument("--limits", metavar="limits.toml",
                   help="[change] k, window and [[limit]] parameter, min, max (docs/fleet.md)")
    r.add_argument("--quiet", action="store_true", help="do not print the warnings")
    r.set_defaults(func=run_report)


def _no_command(args) -> int:
    from .run import require
    require()
    args.fleet_parser.print_help()
    return 2


def _defaults(args) -> dict:
    from .source import _option
    opts = {"outputs": args.output, "inputs": args.input, "where": args.where,
            "exclude_rows": args.exclude_rows, "same_clock": bool(args.same_clock), "dt": args.dt}
    if args.unit:
        opts["units"] = _option("unit", ";".join(args.unit), "--unit")[1]
    return {k: v for k, v in opts.items() if v not in (None, False, [])}


def run_diagnose(args) -> int:
    from ..progress import Progress
    from .run import require, run_fleet
    from .source import plan
    require()
    jobs = plan(args.source, _defaults(args))
    prog = Progress("fleet diagnose", enabled=True if args.progress else None)
    run = run_fleet(jobs, args.out, scheduler=args.scheduler, workers=args.workers, progress=prog,
                    skip_done=args.skip_done)
    if not args.quiet:
        print(run.summary())
    return 1 if run.errors else 0


def run_report(args) -> int:
    from .._io import atomic_write
    from .dataset import read
    from .report import html
    from .run import require
    from .trend import Limits, load_limits, trends
    require(("pyarrow",))
    limits = load_limits(args.limits) if args.limits else Limits()
    tr = trends(read(args.dataset), limits)
    atomic_write(args.out, html(tr, f"dataset {args.dataset}"))
    if not args.quiet:
        for w in tr.warnings:
            print(f"warning: {w.machine} {w.date} {w.output} {w.effect}.{w.parameter}: {w.kind}",
                  file=sys.stdout)
        print(f"{len(tr.warnings)} warning(s), {len(tr.errors)} night(s) not diagnosed; "
              f"report {args.out}")
    return 1 if tr.warnings else 0
