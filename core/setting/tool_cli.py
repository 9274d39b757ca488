"""`mtcomp tool-setting plan|simulate|estimate`: a thin layer over mtcomp.setting.tool."""
from __future__ import annotations

import argparse
from pathlib import Path

from .._io import InputError


def _floats(text: str) -> tuple[float, ...]:
    try:
        return tuple(float(x) for x in text.replace(" ", "").split(",") if x)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated numbers, got {text!r}") from None


def _tests(text: str) -> tuple[str, ...]:
    t = tuple(x.strip().upper() for x in text.split(",") if x.strip())
    if not t or any(x not in "ABC" or len(x) != 1 for x in t):
        raise argparse.ArgumentTypeError(f"expected some of A,B,C, got {text!r}")
    return t


def _locations(text: str):
    t = text.strip()
    if t.lower() in ("auto", "none"):
        return t.lower()
    names = tuple(x.strip().upper() for x in t.split(",") if x.strip())
    if not names or any(len(x) != 4 or x[0] != "E" or x[2] != "0" for x in names):
        raise argparse.ArgumentTypeError(f"expected auto, none or names like EX0C,EY0C, got {text!r}")
    return names


def _location_values(text: str) -> dict:
    out = {}
    for item in (x.strip() for x in text.split(",") if x.strip()):
        name, _, val = item.partition("=")
        name = name.strip().upper()
        try:
            v = float(val)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected NAME=mm like EX0C=0.039, got {item!r}") from None
        if len(name) != 4 or name[0] != "E" or name[2] != "0" or name[1] not in "XYZ" or not abs(v) < 10.0:
            raise argparse.ArgumentTypeError(f"expected a position location error like EX0C=0.039 (mm, |v| < 10), "
                                             f"got {item!r}")
        out[name] = v
    return out


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "tool-setting", help="tool setting errors by grooving (paper 000): plan, simulate, estimate",
        description="Measure the offset of the tool edge from the rotation centres by cutting and "
                    "measuring grooves (docs/tool-setting.md). Lengths in mm, angles in deg.")
    sub = p.add_subparsers(dest="tool_setting_cmd", metavar="SUBCOMMAND", required=True)

    pl = sub.add_parser("plan", help="NC programs, layout PNG and measurement sheet for the grooving tests")
    pl.add_argument("--machine", default="robonano-ui", help="preset name or machine TOML (default robonano-ui)")
    pl.add_argument("-o", "--outdir", required=True, help="output directory")
    pl.add_argument("--tests", type=_tests, default=("A", "B", "C"), help="tests to plan (default A,B,C)")
    pl.add_argument("--depth", type=float, default=0.1, help="depth of cut D, mm (default 0.1)")
    pl.add_argument("--length", type=float, default=4.0, help="A and B groove length, mm (default 4)")
    pl.add_argument("--triangle-side", type=float, default=6.0, help="C triangle side, mm (default 6)")
    pl.add_argument("--spacing", type=float, default=2.0, help="B groove spacing, mm (default 2)")
    pl.add_argument("--b-angles", type=_floats, default=None,
                    help="B inclinations, deg, the first is the reference (default: chosen by --criterion "
                         "within the B travel, the tool's flanks and the plate)")
    pl.add_argument("--criterion", choices=("D", "A"), default="D",
                    help="optimal-design criterion over the estimator's covariance: D (log det, default) or "
                         "A (trace)")
    pl.add_argument("--target-sigma", type=float, default=None,
                    help="required 1-sigma of every estimated error, mm: B grooves are added until it is met "
                         "(refused, with what limits it, if the plate cannot)")
    pl.add_argument("--sigma-pos", type=float, default=0.001,
                    help="microscope position sigma the design assumes, mm (default 0.001)")
    pl.add_argument("--sigma-depth", type=float, default=0.001,
                    help="microscope depth sigma the design assumes, mm (default 0.001)")
    pl.add_argument("--expected-offset", type=float, default=0.5,
                    help="largest tool setting offset expected in the XZ plane, mm: inclined B grooves are "
                         "programmed deeper by 2 r sin(|B|/2) so they are cut whatever the offset (default 0.5)")
    pl.add_argument("--min-flank", type=float, default=15.0,
                    help="least angle between a tilted V tool's flank and the surface, deg (default 15)")
    pl.add_argument("--feed", type=float, default=50.0, help="cutting feed, mm/min (default 50)")
    pl.add_argument("--plunge-feed", type=float, default=5.0, help="plunge feed, mm/min (default 5)")
    pl.add_argument("--tip-angle", type=float, default=90.0, help="V tool included angle, deg (default 90)")
    pl.add_argument("--locations", type=_locations, default="auto",
                    help="rotary axis location errors the plan must make observable besides the tool offset: "
                         "'auto' (report which are, default), 'none', or names like EX0C,EY0C (refused with the "
                         "reason if the tests cannot see them)")
    pl.add_argument("--repeat-first", action="store_true",
                    help="cut the first groove again at the end (ISO 230-3): 'estimate' then fits the tool's drift "
                         "against the workpiece over the procedure and reports it")
    pl.add_argument("--no-png", action="store_true", help="skip the layout drawing")
    pl.add_argument("--clearance", type=float, default=0.2,
                    help="the programs are verified on their plates: rapids keep this clearance, mm (0.2)")
    pl.set_defaults(func=_plan)

    si = sub.add_parser("simulate", help="virtual grooving: predicted grooves and synthetic measurements")
    si.add_argument("--plan", required=True, help="plan.toml written by 'plan'")
    si.add_argument("--machine", help="preset or TOML (default: the plan's machine)")
    si.add_argument("--offset", type=float, nargs=3, required=True, metavar=("TX", "TY", "TZ"),
                    help="true tool setting error, mm, tool frame")
    si.add_argument("--location", type=_location_values, default={},
                    help="true rotary axis location errors, mm, e.g. EX0C=0.039,EY0C=-0.150 (default none)")
    si.add_argument("--sigma-pos", type=float, default=0.001, help="microscope position noise, mm (default 0.001)")
    si.add_argument("--sigma-depth", type=float, default=0.001, help="microscope depth noise, mm (default 0.001)")
    si.add_argument("--seed", type=int, default=None)
    si.add_argument("--frame-offset", type=float, default=0.0,
                    help="random microscope origin per test, uniform in +-this, mm (default 0)")
    si.add_argument("--frame-rotation", type=float, default=0.0,
                    help="random microscope frame rotation per test, uniform in +-this, deg (default 0)")
    si.add_argument("--frame-scale", type=float, default=0.0,
                    help="microscope scale (magnification) error of the u, v readings, relative (default 0)")
    si.add_argument("--drift", type=float, nargs=3, default=None, metavar=("DX", "DY", "DZ"),
                    help="thermal drift of the tool against the workpiece over the procedure, mm, workpiece frame "
                         "(linear in the cutting order; default none)")
    si.add_argument("--compensation", help="errors TOML the programs are compensated for (cut compensated grooves)")
    si.add_argument("-o", "--output", required=True, help="filled measurement sheet (CSV)")
    si.add_argument("--png", help="layout with the predicted grooves")
    si.set_defaults(func=_simulate)

    es = sub.add_parser("estimate", help="tool setting error with uncertainty from a filled measurement sheet")
    es.add_argument("measurements", help="filled measurement sheet (CSV)")
    es.add_argument("--plan", help="plan.toml (default: plan.toml next to the measurements)")
    es.add_argument("--machine", help="preset or TOML (default: the plan's machine)")
    es.add_argument("--sigma-pos", type=float, default=0.001, help="position sigma, mm, for rows without one")
    es.add_argument("--sigma-depth", type=float, default=0.001, help="depth sigma, mm, for rows without one")
    es.add_argument("--fit-rotation", action="store_true",
                    help="also fit a rotation of the microscope frame per test (not aligned to the face axes)")
    es.add_argument("--fit-scale", action="store_true",
                    help="also fit a scale (magnification) error of the microscope per test")
    es.add_argument("--locations", type=_locations, default="auto",
                    help="rotary axis location errors to estimate with the tool offset: 'auto' (every one the "
                         "plan makes observable, default), 'none', or names like EX0C,EY0C")
    es.add_argument("--known-errors", help="errors TOML with already known geometric errors to include in the model")
    es.add_argument("-o", "--output", help="errors TOML for 'mtcomp compensate'")
    es.add_argument("--report", help="text report")
    es.add_argument("--png", help="report figure")
    es.add_argument("--nc-dir", help="write compensated grooving programs here")
    es.add_argument("--clearance", type=float, default=0.2,
                    help="compensated programs are verified on their plates: rapids keep this clearance, mm (0.2)")
    es.set_defaults(func=_estimate)


def _plan(args) -> int:
    from ..machine import load_machine
    from .tool_plan import PlanOptions, make_plan, write_plan
    m = load_machine(args.machine)
    from .tool_design import design_plan, predicted_covariance
    kw = {} if args.b_angles is None else {"b_angles": args.b_angles}
    opts = PlanOptions(tests=args.tests, depth=args.depth, length=args.length, triangle_side=args.triangle_side,
                       spacing=args.spacing, feed=args.feed, plunge_feed=args.plunge_feed,
                       tip_angle=args.tip_angle, repeat_first=args.repeat_first, **kw)
    if args.b_angles is None:
        designed = design_plan(m, opts, criterion=args.criterion, sigma_pos=args.sigma_pos,
                               sigma_depth=args.sigma_depth, target_sigma=args.target_sigma,
                               min_flank=args.min_flank, expected_offset=args.expected_offset)
        plan = designed.plan
    else:
        plan = make_plan(m, opts)
        names, cov = predicted_covariance(m, plan, args.sigma_pos, args.sigma_depth)
        from .tool_design import DesignedPlan, _checked
        designed = _checked(DesignedPlan(plan, names, cov, "given", args.sigma_pos, args.sigma_depth, (),
                                         args.target_sigma), False)
    if Path(args.machine).exists():
        # a machine file, not a preset: record where it is so simulate/estimate find it
        from dataclasses import replace
        plan = replace(plan, machine=str(Path(args.machine).resolve()))
    from .tool_model import observable_parameters
    if args.locations not in ("auto", "none"):
        from .tool_estimate import _location_names
        _location_names(m, plan, args.locations, None)        # InputError naming what cannot be seen, and why
    obs = observable_parameters(m, plan)
    if not args.clearance >= 0:
        raise InputError(f"expected a clearance >= 0 mm, got {args.clearance}", field="--clearance")
    checks = {}
    files = write_plan(m, plan, args.outdir, png=not args.no_png, clearance=args.clearance,
                       report=checks.update)
    print(f"{len(plan.grooves)} grooves ({', '.join(plan.ids)}) for machine {m.name}")
    print(designed.summary())
    print(obs.summary())
    for res in checks.values():
        print(res.summary())
    for f in files:
        print(f"wrote {f}")
    return 0


def _machine_for(args, plan):
    from ..machine import load_machine
    return load_machine(args.machine or plan.machine)


def _simulate(args) -> int:
    from .._io import atomic_write
    from ..errors import load_errors
    from .tool import MicroscopeNoise, cut_grooves, load_plan, measurements_csv, plot_layout, simulate_grooving
    plan = load_plan(args.plan)
    m = _machine_for(args, plan)
    for name in ("sigma_pos", "sigma_depth"):
        if not getattr(args, name) >= 0:
            raise InputError(f"expected a sigma >= 0 mm, got {getattr(args, name)}", field=name.replace("_", "-"))
    comp = load_errors(args.compensation, machine=m) if args.compensation else None
    from ..errors import ErrorSet, GeometricErrors, ToolSetting
    from .tool_model import location_candidates
    bad = [k for k in args.location if k not in location_candidates(m)]
    if bad:
        raise InputError(f"{', '.join(bad)} moves no groove: expected some of {', '.join(location_candidates(m))}",
                         field="location")
    truth = ErrorSet(tool=ToolSetting(tuple(args.offset)), geometric=GeometricErrors(location=args.location))
    meas = simulate_grooving(m, truth, MicroscopeNoise(args.sigma_pos, args.sigma_depth), args.seed,
                             plan=plan, compensation=comp, frame_offset=args.frame_offset,
                             frame_rotation=args.frame_rotation, frame_scale=args.frame_scale, drift=args.drift)
    text = measurements_csv(meas, f"simulated: offset {tuple(args.offset)} mm, location {args.location} mm, "
                                  f"sigma pos {args.sigma_pos} mm, "
                                  f"depth {args.sigma_depth} mm, seed {args.seed}")
    atomic_write(args.output, text)
    print(f"wrote {args.output} ({len(meas.points)} points)")
    if args.png:
        plot_layout(plan, args.png, cuts=cut_grooves(m, plan, truth, comp),
                    title=f"predicted grooves (black) for offset {tuple(args.offset)} mm")
        print(f"wrote {args.png}")
    return 0


def _estimate(args) -> int:
    from .._io import atomic_write
    from .tool import load_plan, read_measurements
    from .tool_estimate import estimate, plot_report, report_text, write_errors
    from .tool_plan import nc_programs
    meas_path = Path(args.measurements)
    plan_path = Path(args.plan) if args.plan else meas_path.parent / "plan.toml"
    if not plan_path.exists():
        raise InputError("plan not found (give --plan)", plan_path)
    plan = load_plan(plan_path)
    m = _machine_for(args, plan)
    if not args.clearance >= 0:
        raise InputError(f"expected a clearance >= 0 mm, got {args.clearance}", field="--clearance")
    meas = read_measurements(meas_path, plan, args.sigma_pos, args.sigma_depth)
    known = None
    if args.known_errors:
        from ..errors import load_errors
        known = load_errors(args.known_errors, machine=m)
    est = estimate(m, meas, fit_rotation=args.fit_rotation, known=known, fit_scale=args.fit_scale,
                   locations=() if args.locations == "none" else args.locations)
    # Compute every output before writing any, so a failure leaves nothing behind.
    report = report_text(m, meas, est) if args.report else None
    progs = nc_programs(m, plan, compensation=est.errors(known)) if args.nc_dir else {}
    # the compensated programs verified on the machine with the estimated errors (the real one)
    from .tool_verify import verify_grooving
    checks = verify_grooving(m, plan, progs, est.errors(known), clearance=args.clearance) if progs else {}
    print(est.summary())
    written = []
    if args.output:
        written.append(write_errors(est, args.output, source=meas_path.name, known=known))
    if report is not None:
        written.append(atomic_write(args.report, report))
    for res in checks.values():
        print(res.summary())
    for t, txt in progs.items():
        written.append(atomic_write(Path(args.nc_dir) / f"tool_setting_{t}_compensated.nc", txt))
    if args.png:
        plot_report(m, meas, est, args.png)
        written.append(args.png)
    for f in written:
        print(f"wrote {f}")
    return 0
