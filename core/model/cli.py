"""`mtcomp model export|simulate|resimulate|ssp|compensate`: the diagnosed physics back into the machine model."""
from __future__ import annotations

import argparse


def axis_values(s: str) -> tuple | float:
    from .._io import InputError
    try:
        v = tuple(float(x) for x in s.split(","))
    except ValueError:
        raise InputError(f"expected a number or comma-separated numbers per axis, got {s!r}") from None
    return v[0] if len(v) == 1 else v


def register(subparsers) -> None:
    p = subparsers.add_parser("model", help="write diagnosed effects into the machine model and re-simulate",
                              description="Close the loop of `mtcomp diagnose`: export the fitted effects in the "
                                          "machine model's formats, simulate the machine FMU, re-simulate with the "
                                          "fitted parameters (docs/model-loop.md).")
    sub = p.add_subparsers(dest="model_command", metavar="SUBCOMMAND", required=True)

    e = sub.add_parser("export", help="diagnosis JSON -> errors TOML, dynamics TOML, SSP parameter set")
    e.add_argument("diagnosis", metavar="DIAG.json", help="output of `mtcomp diagnose --json`")
    e.add_argument("-o", "--outdir", required=True, metavar="OUTDIR", help="folder to write the model files into")
    e.add_argument("--machine", metavar="PRESET|machine.toml",
                   help="machine (default: from the SIM file's provenance sidecar given with --sim)")
    e.add_argument("--sim", metavar="SIM.csv", help="the simulation the diagnosis compared with (reads its "
                   "provenance sidecar for machine and step, and the peak speed of its velocity columns v<AXIS>: "
                   "friction on a velocity output needs it)")
    e.add_argument("--step", type=float, metavar="S", help="co-simulation communication step (s)")
    e.add_argument("--quiet", action="store_true")
    e.set_defaults(func=run_export)

    b = sub.add_parser("ssp", help="bind the exported .ssv to the machine component of an SSP archive")
    b.add_argument("ssp", metavar="CELL.ssp", help="written by `mtcomp fmu ssp`")
    b.add_argument("ssv", metavar="MODEL/machine.ssv")
    b.add_argument("-o", "--output", required=True, metavar="OUT.ssp")
    b.add_argument("--name", metavar="SET", help="name of the bound parameter set (default: the .ssv's); ecos "
                   "applies one name per run: 'commands' makes `ecos --parameterSet commands` apply it together with "
                   "the compensator's commands")
    b.set_defaults(func=run_ssp)

    s = sub.add_parser("simulate", help="NC program -> machine FMU -> tool edge CSV with a provenance sidecar")
    s.add_argument("program", metavar="PROGRAM.nc")
    s.add_argument("--machine", required=True, metavar="PRESET|machine.toml")
    s.add_argument("--errors", metavar="E.toml", help="the machine's errors")
    s.add_argument("--kv", type=axis_values, default=0.0, help="servo gain 1/s, one value or one per axis (0: ideal)")
    s.add_argument("--backlash", type=axis_values, default=0.0, help="backlash mm/deg, one value or one per axis")
    s.add_argument("--noise", type=float, default=0.0, metavar="NM", help="sensor noise sigma in nm")
    s.add_argument("--seed", type=int, default=1)
    s.add_argument("--step", type=float, default=1e-3, metavar="S")
    s.add_argument("--spindle-speed", type=float, default=0.0, metavar="RPM")
    s.add_argument("--delay", type=float, default=0.0, metavar="S", help="transport delay of the commands (s)")
    s.add_argument("--dynamics", metavar="DYN.toml", help="machine FMU dynamics parameters (the format of "
                   "`model export`'s dynamics.toml: friction, thermal, ...), applied over the options above")
    s.add_argument("--drivers", metavar="DRIVERS.csv", help="logged drivers of the thermal drift over time: t and "
                   "spindle_speed [rpm] and/or temperature [degC] columns, linear between rows; written as "
                   "columns of the output")
    s.add_argument("--velocity", action="append", default=[], metavar="AXIS",
                   help="also write the actual velocity of this axis as column v<AXIS> [mm/s] or [deg/s] (the FMU's "
                        "v.<AXIS>, noise-free; repeatable): a velocity output for the diagnosis")
    s.add_argument("-o", "--output", required=True, metavar="OUT.csv")
    s.set_defaults(func=run_simulate)

    r = sub.add_parser("resimulate", help="re-run the co-simulation with the exported model; compare with REC")
    r.add_argument("model", metavar="OUTDIR", help="folder written by `mtcomp model export`")
    r.add_argument("--rec", required=True, metavar="REC.csv", help="the recording (t, x, y, z)")
    r.add_argument("--sim", metavar="SIM.csv", help="the original simulation; its provenance sidecar gives "
                   "program, machine, errors, dynamics and step")
    r.add_argument("--program", metavar="PROGRAM.nc")
    r.add_argument("--machine", metavar="PRESET|machine.toml")
    r.add_argument("--errors", metavar="E.toml", help="the base model's errors")
    r.add_argument("--step", type=float, metavar="S")
    r.add_argument("--heldout-from", type=float, metavar="T",
                   help="samples from T s on were not given to the diagnosis: report them apart")
    r.add_argument("--diagnosis", metavar="DIAG.json",
                   help="the diagnosis the model came from: its noise floors weigh the outputs; needed by --prune")
    r.add_argument("--prune", action="store_true",
                   help="drop exported effects the re-simulation does not need on the training samples "
                        "(t < --heldout-from) and rewrite the model folder with the rest")
    r.add_argument("--refine", action="store_true",
                   help="refit the exported scalars (kv, backlash, friction, delay, thermal, location, setting) through the "
                        "machine model on "
                        "the training samples (needs --diagnosis; a co-simulation per evaluation: slow)")
    r.add_argument("--complete", action="store_true",
                   help="add the backlash of every reversing linear axis the model lacks and refit every scalar through "
                        "the machine model; kept only when training samples the fit did not see agree (needs "
                        "--diagnosis; slow)")
    r.add_argument("--plot", metavar="OUT.png")
    r.add_argument("--json", metavar="OUT.json")
    r.set_defaults(func=run_resimulate)

    register_compensate(sub)


def run_export(args: argparse.Namespace) -> int:
    from .._io import InputError
    from .export import export_model
    from .simulate import read_provenance
    machine, step, drivers, interp, peaks = args.machine, args.step, None, False, None
    if args.sim:
        prov = read_provenance(args.sim)
        machine = machine or prov.machine
        step = step if step is not None else prov.step
        drivers = _driver_starts(prov.spindle_speed, prov.temperature)
        interp = bool(prov.dynamics.interpolation)
        peaks = _velocity_peaks(args.sim)
    if machine is None:
        raise InputError("give --machine (or --sim with a provenance sidecar)", field="--machine")
    ex = export_model(args.diagnosis, machine, args.outdir, step=step, drivers=drivers, servo_interpolation=interp,
                      velocity_peaks=peaks)
    if not args.quiet:
        print(ex.summary())
    return 0


def _velocity_peaks(sim_path) -> dict:
    """{v<AXIS>: peak |v|} of SIM's velocity columns (mm/s, deg/s) over the whole file: the
    smoothing speed of friction on a velocity output is 2 % of it (the diagnosis' choice; equal
    when REC covers SIM's peak speed)."""
    import numpy as np

    from .simulate import OUTPUTS, read_recording
    _, sig = read_recording(sim_path)
    return {o: float(np.max(np.abs(v))) for o, v in sig.items() if o not in OUTPUTS}


def _driver_starts(spindle, temperature) -> dict:
    """{driver column: value at the start} of the simulation's logged drivers (the thermal
    mapping needs the spindle speed at the start)."""
    import numpy as np
    out = {}
    for name, v in (("spindle_speed", spindle), ("temperature", temperature)):
        if v is not None and not callable(v):
            out[name] = float(np.ravel(v)[0])
    return out


def _recorded_drivers(rec_path, spindle, temperature) -> tuple:
    """(spindle speed, temperature, {driver: value at the start}) for the re-simulation: REC's
    driver columns (mtcomp.model.drivers.recording_drivers, as functions of t) over SIM's."""
    import numpy as np

    from .drivers import recording_drivers
    starts = _driver_starts(spindle, temperature)
    for name, (_, t, v) in recording_drivers(rec_path).items():
        fn = (lambda tt, t=t, v=v: np.interp(tt, t, v))
        starts[name] = float(v[0])
        if name == "spindle_speed":
            spindle = fn
        else:
            temperature = fn
    return spindle, temperature, starts


def _read_drivers(path) -> dict:
    """{"spindle_speed"|"temperature": callable of t} from a CSV with t and driver columns."""
    import numpy as np

    from .._io import InputError
    from ..csvtable import read_csv
    tab = read_csv(path, what="drivers", required=("t",))
    t = tab.numbers("t", unit="s")
    if len(t) < 2 or np.any(np.diff(t) <= 0):
        raise InputError("expected at least two rows with increasing t", path, field="t")
    out = {}
    for name, unit in (("spindle_speed", "rpm"), ("temperature", "degC")):
        try:
            v = tab.numbers(name, unit=unit)
        except (InputError, KeyError):
            continue
        out[name] = lambda tt, v=v: np.interp(tt, t, v)
    if not out:
        raise InputError("expected a spindle_speed [rpm] or temperature [degC] column", path)
    return out


def run_ssp(args: argparse.Namespace) -> int:
    from .ssp import bind_parameter_set
    bind_parameter_set(args.ssp, args.ssv, args.output, set_name=args.name)
    print(f"wrote {args.output}: {args.ssv} bound to the machine component")
    return 0


def run_simulate(args: argparse.Namespace) -> int:
    from ..errors import load_errors
    from ..fmu.build import MachineDynamics
    from ..machine import load_machine
    from .simulate import simulate, write_signals
    m = load_machine(args.machine)
    errors = load_errors(args.errors, machine=m) if args.errors else None
    dyn = MachineDynamics(kv=args.kv, backlash=args.backlash, noise=args.noise * 1e-6, seed=args.seed,
                          delay=args.delay)
    if args.dynamics:
        from .dynamics import apply_dynamics, load_dynamics
        dyn = apply_dynamics(dyn, load_dynamics(args.dynamics, m), m, combine=False)
    drivers = _read_drivers(args.drivers) if args.drivers else {}
    sig = simulate(args.program, m, errors, dyn, step=args.step,
                   spindle_speed=drivers.get("spindle_speed", args.spindle_speed),
                   temperature=drivers.get("temperature"))
    for a in args.velocity:
        if a not in m.axis_names:
            from .._io import InputError
            raise InputError(f"no axis {a!r} on {m.name} (axes {' '.join(m.axis_names)})", field="--velocity")
    write_signals(args.output, sig, args.machine, program=args.program, errors_path=args.errors, dynamics=dyn,
                  step=args.step, spindle_speed=args.spindle_speed, velocities=tuple(args.velocity))
    print(f"wrote {args.output} ({len(sig.t)} samples) and its provenance sidecar")
    return 0


def run_resimulate(args: argparse.Namespace) -> int:
    import json

    from .._io import InputError, atomic_write
    from ..errors import load_errors
    from ..machine import load_machine
    from .simulate import read_provenance, resimulate
    if args.sim:
        prov = read_provenance(args.sim)
        program = args.program or prov.program
        machine = load_machine(args.machine) if args.machine else prov.machine
        errors = load_errors(args.errors, machine=machine) if args.errors else prov.errors
        dyn, step, spindle, temp = prov.dynamics, args.step or prov.step, prov.spindle_speed, prov.temperature
    else:
        if not (args.program and args.machine and args.step):
            raise InputError("give --sim SIM.csv with its provenance sidecar, or --program, --machine and --step",
                             field="--sim")
        program, machine, step, spindle, dyn = args.program, load_machine(args.machine), args.step, 0.0, None
        temp = None
        errors = load_errors(args.errors, machine=machine) if args.errors else None
    if program is None:
        raise InputError("the provenance names no program: give --program", field="--program")
    from .identity import check_model_machine
    check_model_machine(args.model, machine, what="model resimulate")
    spindle, temp, starts = _recorded_drivers(args.rec, spindle, temp)
    model, noise = args.model, None
    if args.diagnosis:
        from .export import read_diagnosis
        noise = read_diagnosis(args.diagnosis).get("noise_floor")
    if args.prune or args.refine or args.complete:
        from .export import export_model, write_export
        from .simulate import prune, read_recording, refine
        if not args.diagnosis:
            raise InputError("--prune, --refine and --complete need --diagnosis DIAG.json", field="--diagnosis")
        t_rec, rec = read_recording(args.rec)
        log: list = []
        kw = dict(program=program, machine=machine, errors=errors, dynamics=dyn, step=step, spindle_speed=spindle,
                  temperature=temp, train_until=args.heldout_from, noise_floor=noise, log=log)
        ex = export_model(args.diagnosis, machine, None, step=step, drivers=starts,
                          servo_interpolation=bool(getattr(dyn, "interpolation", 0)),
                          velocity_peaks=_velocity_peaks(args.sim) if args.sim else None)
        if args.prune:
            ex = prune(ex, t_rec, rec, **kw)
        if args.refine:
            ex = refine(ex, t_rec, rec, stride=4, **kw)
        if args.complete:
            from ..fmu.cosim import interpolate_program
            from .complete import complete
            q = interpolate_program(program, machine, step)[1]
            ex = complete(ex, t_rec, rec, q=q, stride=4, **kw)
        model = write_export(ex, args.model)
        print("\n".join(log))
    res, _, _ = resimulate(model, args.rec, program=program, machine=machine, errors=errors, dynamics=dyn,
                           step=step, spindle_speed=spindle, temperature=temp, heldout_from=args.heldout_from,
                           noise_floor=noise)
    if args.json:
        atomic_write(args.json, json.dumps(res.to_dict(), indent=2) + "\n")
    if args.plot:
        res.plot(args.plot)
    print(res.summary())
    return 0


def register_compensate(sub) -> None:
    c = sub.add_parser("compensate", help="compensate an NC program with the model: geometric errors, backlash, "
                       "servo lag (each switchable)")
    c.add_argument("program", metavar="PROGRAM.nc")
    c.add_argument("--model", required=True, metavar="OUTDIR", help="folder written by `mtcomp model export` "
                   "(errors.toml, dynamics.toml)")
    c.add_argument("--machine", required=True, metavar="PRESET|machine.toml")
    c.add_argument("--errors", metavar="E.toml", help="the machine's known errors, added to the model's "
                   "(the diagnosis fitted what they lacked)")
    c.add_argument("--no-geometric", action="store_true", help="leave the geometric and setting errors out")
    c.add_argument("--force", action="store_true", help="compensate a program mtcomp has already compensated")
    c.add_argument("--no-backlash", action="store_true", help="no reversal compensation")
    c.add_argument("--no-servo", action="store_true", help="no servo-lag feed-forward")
    c.add_argument("--no-friction", action="store_true", help="no reversal spikes for the friction breakaway, no lead for the quadrant glitch")
    c.add_argument("--no-thermal", action="store_true", help="no thermal offsets (spindle- or time-driven drift "
                   "subtracted along the program; a drift driven by a logged temperature goes to OUT.thermal.toml "
                   "for the control)")
    c.add_argument("--no-encoder", action="store_true", help="leave the encoder cyclic error (the machine "
                   "FMU's encoder element) to the control's encoder interface: no w - r(w) on the targets")
    c.add_argument("--no-delay", action="store_true", help="take the thermal offsets at the command's time, not "
                   "at the time the axes act (t + transport delay)")
    c.add_argument("--rapid", type=float, default=3000.0, metavar="MM_PER_MIN",
                   help="the G0 rate of the control, for the sampling (default 3000)")
    c.add_argument("--max-feed", type=float, metavar="MM_PER_MIN",
                   help="highest feed the sampled program may write (default: the program's fastest move, rapids at "
                        "--rapid included): corrections that need more are spread over the next steps")
    c.add_argument("--feed-resolution", type=float, default=0.001, metavar="MM_PER_MIN",
                   help="the control's feed resolution: feeds are written as multiples of it (default 0.001)")
    c.add_argument("--cosim", action="store_true",
                   help="co-simulate the machine the model describes (machine FMU) with the program uncompensated, "
                        "compensated for the geometric errors only, + backlash, + servo, + friction, + thermal "
                        "(those in the model): print the part errors")
    c.add_argument("-o", "--output", required=True, metavar="OUT.nc")
    c.set_defaults(func=run_compensate)


def run_compensate(args: argparse.Namespace) -> int:
    from pathlib import Path

    from .. import __version__
    from .._io import InputError, atomic_write, read_text
    from ..errors import load_errors
    from ..machine import load_machine
    from .compensate import compensate_with_model, read_model
    from .simulate import combine_errors
    m = load_machine(args.machine)
    errors, dyn = read_model(args.model, m)
    if args.errors:
        errors = combine_errors(load_errors(args.errors, machine=m), errors, m)
    for name, v in (("--rapid", args.rapid), ("--max-feed", args.max_feed), ("--feed-resolution", args.feed_resolution)):
        if v is not None and not (v > 0 and v < float("inf")):
            raise InputError(f"expected a feed > 0 mm/min, got {v}", field=name)
    src = Path(args.program)
    from ..gcode.provenance import check_nc_write
    check_nc_write(None, output=args.output, inputs=(src, args.errors))
    text = read_text(src, what="NC program")
    prov = [("VERSION", f"mtcomp {__version__}"), ("MACHINE", m.name), ("SOURCE", src.name),
            ("MODEL", Path(args.model).name)]
    new, rep = compensate_with_model(text, m, None if args.no_geometric else errors, dyn,
                                     backlash=not args.no_backlash, servo=not args.no_servo,
                                     friction=not args.no_friction, thermal=not args.no_thermal,
                                     delay=not args.no_delay, encoder=not args.no_encoder, rapid=args.rapid, filename=str(src), provenance=prov,
                                     force=args.force, max_feed=args.max_feed,
                                     feed_resolution=args.feed_resolution)
    atomic_write(args.output, new)
    print(f"{src} -> {args.output}: {rep.summary()}")
    if rep.thermal_control is not None:
        from .thermal_comp import control_file_text
        ctl = Path(str(args.output) + ".thermal.toml")
        atomic_write(ctl, control_file_text(rep.thermal_control))
        print(f"thermal drift driven by a logged temperature: not in the program; the control's parameters -> {ctl}")
    if args.cosim:
        from .compensate import compare_compensations
        pe = compare_compensations(text, m, errors, dyn, rapid=args.rapid, filename=str(src), max_feed=args.max_feed)
        print("part error on the model's machine (distance of the tool edge from the programmed path, feed "
              "moves; reach: of the programmed points from the tool edge's path):")
        for k, v in pe.items():
            print(f"  compensation {k:<10} max {v['max'] * 1e3:9.4f} µm   RMS {v['rms'] * 1e3:9.4f} µm   "
                  f"reach {v['reach'] * 1e3:9.4f} µm")
        from .claim import claim_band, model_sigmas
        band = claim_band(text, new, m, errors, dyn, model_sigmas(args.model), rapid=args.rapid)
        res_um = min(a.resolution for a in m.axes if not a.is_rotary) * 1e3
        print(f"  the written program, with the model's uncertainty ({band['draws']} draws of its parameters): "
              f"max {band['max'][0] * 1e3:.4f}..{band['max'][1] * 1e3:.4f} µm, RMS {band['rms'][0] * 1e3:.4f}.."
              f"{band['rms'][1] * 1e3:.4f} µm (coordinates written at {res_um:g} µm; physics the model lacks is "
              "not in this band)")
    return 0
