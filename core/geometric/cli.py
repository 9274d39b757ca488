"""`mtcomp geometric ...`: ISO 230-2 evaluation, tables from runs, volumetric map, compensation
tables, and a synthetic machine to try them on.  A thin layer over mtcomp.geometric."""
from __future__ import annotations

import argparse
from pathlib import Path

from .._io import InputError


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "geometric", help="geometric errors: ISO 230-2, tables from runs, volumetric map, "
                          "compensation tables",
        description="Geometric errors from laser-interferometer runs (docs/geometric.md).")
    sub = p.add_subparsers(dest="geometric_command", metavar="SUBCOMMAND")
    p.set_defaults(func=lambda a: (p.print_help(), 2)[1])

    s = sub.add_parser("iso230-2", help="evaluate a bidirectional positioning run (ISO 230-2)")
    s.add_argument("run", help="run CSV: target,cycle,direction,deviation (mm)")
    s.add_argument("--axis", default="", help="axis name for the report")
    s.add_argument("-o", "--output", help="output stem (default: next to the run, <run>_iso230-2); "
                                          "writes .txt, _positions.csv, _figures.csv, .png")
    s.set_defaults(func=_iso)

    s = sub.add_parser("reversal", help="reversal (backlash) per target from an ISO 230-2 run: bidirectional "
                                        "tables and the backlash parameter for the control")
    s.add_argument("run", help="run CSV: target,cycle,direction,deviation (mm)")
    s.add_argument("--axis", default="X", help="axis name (default X)")
    s.add_argument("--unit", type=float, default=1e-6,
                   help="control's detection unit, mm (default 1e-6 = 1 nm)")
    s.add_argument("--interval", type=float, help="compensation interval, mm (default: mean target spacing)")
    s.add_argument("-o", "--output", required=True, help="output directory: <axis>_reversal.csv (mm) and "
                                                          "<axis>_pitch_bidirectional.csv (detection units)")
    s.set_defaults(func=_reversal)

    s = sub.add_parser("rotary", help="location errors of a rotary table (ISO 230-7) from a sphere probed at "
                                      "several angles")
    s.add_argument("readings", help="CSV angle_deg,x,y,z: sphere centre readings (linear axes, mm) per angle")
    s.add_argument("--axis", required=True, help="the tested rotary axis (workpiece side)")
    s.add_argument("--machine", default="robonano-a0ib", help="machine preset or TOML (default robonano-a0ib)")
    s.add_argument("--sigma", type=float, default=0.0005, help="1 sigma of a reading, mm (default 0.0005)")
    s.add_argument("-o", "--output", help="errors TOML with the estimated location errors")
    s.set_defaults(func=_rotary)

    s = sub.add_parser("build", help="component error tables from a measurement set")
    s.add_argument("set", help="measurement set TOML (runs, set-up offsets)")
    s.add_argument("--machine", help="machine preset or TOML (default: the set's machine)")
    s.add_argument("-o", "--output", required=True,
                   help="errors TOML to write (one CSV per axis next to it)")
    s.set_defaults(func=_build)

    s = sub.add_parser("map", help="volumetric error over the work volume (PNG, CSV, figures)")
    s.add_argument("errors", help="errors TOML")
    s.add_argument("--machine", default="vmc-moving-column", help="machine preset or TOML")
    s.add_argument("--step", type=float, default=25.0, help="grid spacing, mm (default 25)")
    s.add_argument("-o", "--output", required=True, help="output stem: .png, .csv, .txt")
    s.set_defaults(func=_map)

    s = sub.add_parser("table", help="compensation tables: 3-D lattice and ISO 230-1 CSV tables")
    s.add_argument("errors", help="errors TOML (the model to compensate)")
    s.add_argument("--machine", default="vmc-moving-column", help="machine preset or TOML")
    s.add_argument("--lattice-step", type=float, default=25.0, help="lattice spacing, mm")
    s.add_argument("--truth", help="errors TOML of the real machine for the residual "
                                   "(default: the model itself, which shows the lattice "
                                   "interpolation error)")
    s.add_argument("--program", help="also rewrite this NC program with corrected commands "
                                     "(written to DIR/<name>_comp<suffix>)")
    s.add_argument("--stock", help="verify the rewritten program against this stock on the machine with "
                                   "--truth (or the model): box:x0,y0,z0,x1,y1,z1 (mm), plane:Z or a STEP file")
    s.add_argument("--clearance", type=float, default=0.2,
                   help="with --stock: clearance every rapid keeps from it, mm (0.2)")
    s.add_argument("--reversal", nargs="+", metavar="CSV",
                   help="reversal tables (<stem>_<axis>_reversal.csv of 'build'): the program and the report "
                        "are corrected per direction of approach, the residual given per direction")
    s.add_argument("--force", action="store_true",
                   help="rewrite a --program that mtcomp has already compensated")
    s.add_argument("-o", "--output", required=True, help="output directory")
    s.set_defaults(func=_table)

    s = sub.add_parser("simulate", help="synthetic machine and simulated interferometer runs")
    s.add_argument("--machine", default="vmc-moving-column", help="machine preset or TOML")
    s.add_argument("--seed", type=int, default=0)
    s.add_argument("--step", type=float, default=5.0, help="run target spacing, mm")
    s.add_argument("--noise", type=float, nargs=3, metavar=("LIN_UM", "STRAIGHT_UM", "ANG_URAD"),
                   default=(0.1, 0.2, 0.2), help="reading noise, 1 sigma (µm, µm, µrad)")
    s.add_argument("--reversal", type=float, default=2.0,
                   help="reversal B = x_up - x_down of the positioning runs, µm (negative: ordinary backlash, "
                        "moving up lags; default 2)")
    s.add_argument("-o", "--output", required=True,
                   help="measurement set TOML to write; the true errors go to <stem>_truth.toml")
    s.set_defaults(func=_simulate)


def _iso(args: argparse.Namespace) -> int:
    from . import iso230_2
    run = iso230_2.read_run_csv(args.run, axis=args.axis)
    res = iso230_2.evaluate(run)
    stem = Path(args.output) if args.output else Path(args.run).with_name(
        Path(args.run).stem + "_iso230-2")
    out = iso230_2.write_report(res, stem)
    print(res.summary(), end="")
    print("written: " + ", ".join(str(p) for p in out.values()))
    return 0


def _reversal(args: argparse.Namespace) -> int:
    from . import iso230_2
    from .reversal import reversal_table
    table = reversal_table(iso230_2.evaluate(iso230_2.read_run_csv(args.run, axis=args.axis)))
    files = table.write(args.output, unit=args.unit, interval=args.interval)
    um = 1e3
    print(f"axis {table.axis}: reversal B = {table.B * um:.3f} µm, mean reversal B_mean = {table.B_mean * um:+.3f} µm, "
          f"backlash (lost motion) = {table.backlash * um:+.3f} µm")
    for p, b in zip(table.position, table.reversal_i):
        print(f"  {p:10.3f} mm  B_i = {b * um:+8.3f} µm")
    print("written: " + ", ".join(str(f) for f in files))
    return 0


def _rotary(args: argparse.Namespace) -> int:
    from ..errors import ErrorSet, save_errors
    from ..machine import load_machine
    from . import rotary
    m = load_machine(args.machine)
    if args.axis not in m.axis_names or not m.axis(args.axis).is_rotary or m.axis(args.axis).side != "workpiece":
        raise InputError(f"expected a rotary axis of the workpiece side of {m.name}, got {args.axis!r}", field="--axis")
    angles, readings = rotary.read_readings_csv(args.readings)
    sphere = rotary.sphere_from_readings(m, args.axis, angles, readings)
    plan = rotary.SpherePlan(args.axis, tuple(float(a) for a in angles), tuple(float(v) for v in sphere))
    est = rotary.estimate_rotary(m, plan, readings, sigma=args.sigma)
    print(est.summary())
    if args.output:
        unc = {f"geometric.location.{n}": float(s) for n, s in zip(est.names, est.sigma)}
        save_errors(est.errors(ErrorSet()), args.output, uncertainty=unc,
                    meta={"produced_by": "mtcomp geometric rotary", "readings": str(args.readings)})
        print(f"written: {args.output}")
    return 0


def _build(args: argparse.Namespace) -> int:
    from ..errors import save_errors
    from . import tables
    mset = tables.load_measurement_set(args.set)
    res = tables.build_tables(args.machine or mset.machine, mset)
    # largest 1-sigma of each component (mm or rad) and the squareness sigmas, for the record
    unc = {f"geometric.{k}": float(max(v) if hasattr(v, "__len__") else v)
           for k, v in res.uncertainty.items()}
    out = Path(args.output)
    rev = res.reversal()
    # the direction-dependent part the (bidirectional-mean) tables leave out, one CSV per axis
    texts = {out.with_name(f"{out.stem}_{ax}_reversal.csv"): t.to_csv() for ax, t in rev.items()}
    save_errors(res.errors, args.output, uncertainty=unc,
                meta={"source": "mtcomp geometric build", "measurement_set": Path(args.set).name,
                      "reversal": ", ".join(p.name for p in texts) or "none"})
    from .._io import atomic_write
    for path, text in texts.items():
        atomic_write(path, text)
    print(res.summary(), end="")
    print(f"written: {args.output}" + "".join(f", {p}" for p in texts))
    return 0


def _linear_machine(spec, three: bool = True):
    """The machine of --machine, refused up front when the command cannot handle it."""
    from ..machine import load_machine
    m = load_machine(spec)
    if m.n_rotary or (three and m.n_axes != 3):
        raise InputError(f"machine {m.name} has axes {' '.join(m.axis_names)}: this command covers "
                         f"{'3-axis machines with' if three else 'machines with'} linear axes only",
                         field="--machine")
    return m


def _load_errors(path, machine):
    """The errors file, refused when it holds errors of axes `machine` lacks (they would be
    ignored without a word)."""
    from ..errors import load_errors
    return load_errors(path, machine=machine)


def _map(args: argparse.Namespace) -> int:
    from .._io import atomic_write
    from . import volumetric
    if args.step <= 0:
        raise InputError("must be positive", field="--step")
    machine = _linear_machine(args.machine)
    errors = _load_errors(args.errors, machine)
    vmap = volumetric.error_map(machine, errors, step=args.step)
    stem = Path(args.output)
    volumetric.plot_map(vmap, stem.with_name(stem.name + ".png"))
    atomic_write(stem.with_name(stem.name + ".csv"), vmap.to_csv())
    atomic_write(stem.with_name(stem.name + ".txt"), vmap.summary())
    print(vmap.summary(), end="")
    print(f"written: {stem}.png, {stem}.csv, {stem}.txt")
    return 0


def _table(args: argparse.Namespace) -> int:
    from .._io import atomic_write
    from . import comptables
    if args.lattice_step <= 0:
        raise InputError("must be positive", field="--lattice-step")
    machine = _linear_machine(args.machine)
    model = _load_errors(args.errors, machine)
    truth = _load_errors(args.truth, machine) if args.truth else model
    out = Path(args.output)
    # Everything is computed before the first file is written, so bad input leaves no output.
    if args.stock and not args.program:
        raise InputError("--stock verifies the program of --program: give one", field="--stock")
    if not args.clearance >= 0:
        raise InputError(f"expected a clearance >= 0 mm, got {args.clearance}", field="--clearance")
    from .reversal import load_reversal
    rev = load_reversal(args.reversal or ())
    program = _rewrite_program(args, model, rev) if args.program else None
    check = None
    if program is not None and args.stock:
        # the corrected program as the real machine runs it (issue 14: every emitted program is
        # verified), before anything is written
        from ..verify import parse_stock, verify_program
        check = verify_program(machine, program[1], filename=program[0], stock=parse_stock(args.stock),
                               clearance=args.clearance, errors=truth, retracts=True)
    lat = comptables.lattice_table(machine, model, args.lattice_step, reversal=rev)
    rep = comptables.compensation_report(machine, truth, model, lat, reversal_truth=rev or None)
    atomic_write(out / "lattice.csv", lat.to_csv())
    files = comptables.write_iso_tables(model.geometric, out, "comp")
    atomic_write(out / "residual.txt", rep.summary())
    print(rep.summary(), end="")
    written = [out / "lattice.csv", *files, out / "residual.txt"]
    if program is not None:
        name, text, msg = program
        written.append(atomic_write(out / name, text))
        print(msg + f" -> {out / name}")
        print(check.summary() if check is not None else
              "  not verified against a stock (give --stock)")
    print("written: " + ", ".join(str(f) for f in written))
    return 0


def _rewrite_program(args: argparse.Namespace, model, reversal=None):
    """Corrected commands as an NC program, through the core's program rewriting (tables held
    at their end values just beyond the travel, as in the other compensation forms).
    Returns (file name, text, message)."""
    from ..commands import compensate_program
    from ..gcode import read_program
    from ..machine import load_machine
    from .comptables import extend_tables
    src = Path(args.program)
    text = read_program(src)
    machine = load_machine(args.machine)
    from ..gcode.provenance import check_nc_write, writer_items
    check_nc_write(None, output=Path(args.output) / (src.stem + "_comp" + src.suffix), inputs=(src,))
    new_text, rep = compensate_program(
        text, machine, extend_tables(model), filename=str(src), force=getattr(args, "force", False),
        provenance=writer_items("geometric table --program", errors=args.errors,
                                machine=machine.name, source=src),
        reversal=reversal or None)
    msg = (f"{src}: {rep['blocks']} motion blocks; model tool-edge error max "
           f"{rep['before_max'] * 1e3:.3f} µm before, {rep['after_max'] * 1e3:.4f} µm after")
    return src.stem + "_comp" + src.suffix, new_text, msg


def _simulate(args: argparse.Namespace) -> int:
    from ..errors import save_errors
    from . import synthetic, tables
    if not args.step > 0:
        raise InputError("must be positive", field="--step")
    if not (min(args.noise) >= 0 and abs(args.reversal) < 1000):
        raise InputError(f"noise must be >= 0 and the reversal a finite number of µm, got {args.noise} and "
                         f"{args.reversal}", field="--noise" if not min(args.noise) >= 0 else "--reversal")
    machine = _linear_machine(args.machine, three=False)
    syn = synthetic.make_synthetic(machine, seed=args.seed, run_step=args.step,
                                   min_wavelength=250.0)
    truth = syn.errors()
    lin, st, ang = args.noise
    noise = tables.Noise(lin * 1e-3, st * 1e-3, ang * 1e-6, args.reversal * 1e-3)
    mset = tables.simulate_runs(machine, truth, tables.Setup.typical(args.seed), noise,
                                step=args.step, seed=args.seed)
    out = Path(args.output)
    tables.save_measurement_set(mset, out)
    truth_path = out.with_name(out.stem + "_truth.toml")
    save_errors(truth, truth_path, meta={"source": "mtcomp geometric simulate",
                                         "seed": args.seed})
    print(f"written: {out} ({len(mset.runs)} runs), {truth_path}")
    return 0
