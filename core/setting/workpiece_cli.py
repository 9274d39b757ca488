"""`mtcomp workpiece-setting plan|probe|fit|compensate|simulate` (paper 001): a thin layer over
mtcomp.setting.workpiece.  File formats: docs/workpiece-setting.md."""
from __future__ import annotations

import sys
from pathlib import Path

from .._io import InputError


def _floats(text: str, n: int | None, what: str) -> list[float]:
    try:
        vals = [float(v) for v in text.replace(";", ",").split(",") if v.strip()]
    except ValueError:
        raise InputError(f"expected comma-separated numbers, got {text!r}", field=what) from None
    if n is not None and len(vals) != n:
        raise InputError(f"expected {n} comma-separated numbers, got {len(vals)}", field=what)
    return vals


def _positions(text: str):
    pts = []
    for k, pair in enumerate(text.split(";")):
        if pair.strip():
            pts.append(_floats(pair, 2, f"positions[{k}]"))
    return pts


def _warn(lines):
    for w in lines:
        print(f"warning: {w}", file=sys.stderr)


def cmd_plan(args) -> int:
    from .._io import atomic_write, dump_toml
    from .bowls import plan_bowls, plan_to_dict, probing_program, roughing_program
    if not args.clearance >= 0:
        raise InputError(f"expected a clearance >= 0 mm, got {args.clearance}", field="--clearance")
    from .bowl_design import design_bowl_plan
    designed = design_bowl_plan(args.bowls, criterion=args.criterion, probe_sigma=args.probe_sigma,
                                target_sigma=args.target_sigma, touches=args.touches,
                                blank=_floats(args.blank, 3, "blank"), tool_radius=args.tool_radius,
                                depth=args.depth, probe_radius=args.probe_radius,
                                positions=_positions(args.positions) if args.positions else None)
    plan = designed.plan
    aim = None
    if args.aim:
        from ..errors import load_errors
        aim = load_errors(args.aim).workpiece
    out = Path(args.out)
    rough = Path(args.roughing) if args.roughing else out.with_name(out.stem + "-roughing.nc")
    probe = Path(args.probing) if args.probing else out.with_name(out.stem + "-probing.nc")
    # all texts first, then the files: an error leaves nothing behind
    texts = [(out, dump_toml(plan_to_dict(plan))), (rough, roughing_program(plan)),
             (probe, probing_program(plan, aim=aim, repeat_first=args.repeat_first))]
    # both programs verified on the blank before anything is written (issue 14)
    from .blank_check import verify_plan_programs
    checks = verify_plan_programs(plan, texts[1][1], texts[2][1], clearance=args.clearance)
    for path, text in texts:
        atomic_write(path, text)
    print(f"{len(plan.bowls)} bowls R{plan.tool_radius:g} depth {plan.depth:g} mm, "
          f"{len(plan.directions)} touches each with probe R{plan.probe_radius:g}: "
          f"{out}, {rough}, {probe}")
    print(designed.summary())
    for res in checks:
        print(res.summary())
    return 0


def cmd_probe(args) -> int:
    import numpy as np
    from ..errors import WorkpieceSetting
    from .bowls import load_plan, virtual_probe, write_touches
    plan = load_plan(args.plan)
    v = _floats(args.pose, 6, "pose")
    pose = WorkpieceSetting(tuple(v[:3]), tuple(v[3:]))
    if args.repeat_first or args.drift:
        from .bowl_drift import apply_drift, probe_with_repeat
        drift = _floats(args.drift, 3, "drift") if args.drift else [0.0, 0.0, 0.0]
        if args.repeat_first:
            t = probe_with_repeat(pose, plan, args.noise, args.seed, drift)
        else:
            t = apply_drift(virtual_probe(pose, plan, args.noise, np.random.default_rng(args.seed)), drift)
    else:
        t = virtual_probe(pose, plan, args.noise, np.random.default_rng(args.seed))
    if args.probe_error or args.lobing:
        from .probe_cal import apply_probe_model
        t = apply_probe_model(t, radius_error=args.probe_error, lobe_amplitude=args.lobing)
    write_touches(t, args.out)
    print(f"{len(t.bowl)} virtual touches -> {args.out}")
    return 0


def cmd_fit(args) -> int:
    from .._io import atomic_write, dump_toml
    from .bowls import fit_bowls, load_plan, read_touches
    from .frame import frame_from_bowls
    from .probe_cal import fit_with_probe, load_calibration
    plan = load_plan(args.plan)
    touches = read_touches(args.touches)
    cal = load_calibration(args.probe) if args.probe else None
    radius = plan.tool_radius if args.fix_radius else args.bowl_radius
    known = set(map(int, touches.bowl)) <= set(plan.ids)
    fit_kw = dict(probe_sigma=args.probe_sigma, bowl_radius=radius, shared_radius=not args.radius_per_bowl,
                  k=args.k, bowls=plan.ids if known else None)
    frame_kw = dict(method=args.method, file=args.touches, reference=args.reference, runout=args.runout)
    from .bowl_drift import fit_with_drift, visits
    drift = None
    if any(len(v) >= 2 for v in visits(touches).values()):
        # a bowl touched again at the end: fit and remove the drift over the probing
        from dataclasses import replace as _replace
        from .probe_cal import UNCALIBRATED_NOTE, corrected_touches
        t = corrected_touches(touches, cal, plan.probe_radius) if cal is not None else touches
        sigma = args.probe_sigma if args.probe_sigma is not None else fit_bowls(t, plan.probe_radius, **fit_kw).sigma
        fit, est, drift = fit_with_drift(t, plan, sigma, fit_kw=fit_kw, frame_kw=frame_kw)
        if cal is None:
            est = _replace(est, warnings=tuple(est.warnings) + (UNCALIBRATED_NOTE,))
    else:
        fit, est = fit_with_probe(touches, plan, cal, fit_kw=fit_kw, frame_kw=frame_kw)
    if cal is not None:
        print(f"touches corrected with the probe calibration {args.probe} (effective radius "
              f"{cal.effective_radius:.6f} ± {cal.effective_radius_sigma * 1e3:.3f} µm, nominal {plan.probe_radius:g} mm)")
    print(fit.summary())
    print(est.summary())
    if drift is not None:
        print(drift.summary())
    _warn(fit.warnings)
    _warn(est.warnings)
    if args.report:
        rep = est.to_dict()
        rep["bowl_fits"] = [{"id": f.bowl, "centre_mm": [float(v) for v in f.centre],
                             "radius_mm": f.radius, "rms_um": f.rms * 1e3,
                             "rejected_touches": [int(f.lines[j]) or j + 1 for j in f.rejected]}
                            for f in fit.fits]
        rep["probe_sigma_mm"] = fit.sigma
        atomic_write(args.report, dump_toml(rep))
    meta = {"source": "mtcomp workpiece-setting fit", "plan": str(args.plan),
            "touches": str(args.touches), "method": est.method}
    meta["probe_calibration"] = str(args.probe) if args.probe else "none: dz carries the probe's radius error"
    if drift is not None:
        meta["drift_mm"] = [float(v) for v in drift.value]
    est.save(args.out, meta=meta)
    print(f"workpiece setting -> {args.out}")
    return 0


def cmd_probe_sphere(args) -> int:
    import numpy as np
    from .bowls import Touches, write_touches
    from .probe_cal import sphere_directions, virtual_sphere_touches
    if not args.touches >= 1:
        raise InputError(f"expected at least one touch, got {args.touches}", field="--touches")
    P, A = virtual_sphere_touches(args.sphere_diameter, args.probe_radius, sphere_directions(args.touches),
                                  centre=_floats(args.centre, 3, "centre"), noise=args.noise, rng=args.seed,
                                  axial=args.axial, lobes=args.lobes, lobe_amplitude=args.lobing)
    write_touches(Touches(bowl=np.zeros(len(P), int), points=P, approach=A), args.out)
    print(f"{len(P)} virtual touches on a {args.sphere_diameter:g} mm sphere -> {args.out}")
    return 0


def cmd_probe_calibrate(args) -> int:
    from .bowls import read_touches
    from .probe_cal import calibrate_probe, plot_calibration, save_calibration
    t = read_touches(args.touches)
    cal = calibrate_probe(t.points, t.approach, args.sphere_diameter, args.probe_radius, harmonics=args.harmonics,
                          sigma=args.probe_sigma, diameter_sigma=args.diameter_sigma, axial=args.axial_term,
                          source=str(args.touches))
    fig = plot_calibration(cal) if args.png else None
    print(cal.summary())
    save_calibration(cal, args.out)
    print(f"probe calibration -> {args.out}")
    if fig is not None:
        from .._io import save_figure
        save_figure(fig, args.png)
        print(f"wrote {args.png}")
    return 0


def cmd_compensate(args) -> int:
    from .._io import load_toml
    from .. import gcode
    from .._io import atomic_write
    from ..errors import load_errors
    from ..machine import load_machine
    from ..verify import VerifyError
    from .blank_check import verify_on_blank
    from .workpiece import compensate_text
    if not (args.clearance >= 0 and args.tool_radius >= 0):
        raise InputError("expected a clearance and a tool radius >= 0 mm",
                         field="--clearance" if not args.clearance >= 0 else "--tool-radius")
    if args.no_verify and (args.plan or args.stock):
        raise InputError("--no-verify with --plan or --stock: choose one", field="--no-verify")
    machine = load_machine(args.machine)
    # an errors file without the section would read as a zero pose and copy the program unchanged
    if "workpiece_setting" not in load_toml(args.errors):
        raise InputError("no [workpiece_setting] section: expected the output of "
                         "'mtcomp workpiece-setting fit'", args.errors, field="workpiece_setting")
    errors = load_errors(args.errors, machine=machine)
    # the transform applies the workpiece setting only: other errors in the file would be dropped
    # without a word, and the user believes the program compensated for them
    other = [name for name, zero in (("[tool_setting]", errors.tool.is_zero),
                                     ("[geometric]", errors.geometric.is_zero)) if not zero]
    if other and not args.workpiece_only:
        raise InputError(f"the errors file also has {' and '.join(other)}, which this command does not apply "
                         "(it transforms for the workpiece setting only): use 'mtcomp compensate' to apply "
                         "every error of the file, or pass --workpiece-only to apply just [workpiece_setting]",
                         args.errors, field=other[0].strip("[]"))
    stock, source = _blank(args)
    text = gcode.read_program(args.program)
    from ..gcode.provenance import check_nc_write, stamp, writer_items
    check_nc_write(text, filename=str(args.program), output=args.out,
                   inputs=(args.program, args.errors, args.plan), force=args.force,
                   what="transform it for the workpiece setting")
    from ..commands import parse_tool_lengths
    tools = parse_tool_lengths(args.tool_lengths)
    new, n = compensate_text(machine, text, errors.workpiece, mode=args.mode, filename=str(args.program),
                             tool_lengths=tools)
    print(f"{n} motion lines transformed ({args.mode})")
    if stock is not None:
        # verified as the control runs it, on the blank where it really is (the measured pose),
        # before the file exists: a failing program is never written unless asked
        res = verify_on_blank(machine, new, errors.workpiece, stock, clearance=args.clearance,
                              tool_radius=args.tool_radius, filename=str(args.out),
                              raise_on_violation=False, tool_lengths=tools)
        print(f"blank from {source}, at the measured pose:")
        print("  " + res.summary().replace("\n", "\n  "))
        if not res.ok and not args.warn_only:
            raise VerifyError(f"{len(res.violations)} block(s) fail the verification, nothing written; "
                              f"first: {res.violations[0].describe(res.clearance, res.tolerance)} "
                              "(--warn-only writes it anyway)", res)
    else:
        _warn(["program not verified: give --plan (the blank of a bowl plan) or --stock"])
    new = stamp(new, writer_items("workpiece-setting compensate", errors=args.errors,
                                  machine=machine.name, source=args.program,
                                  options=f"mode {args.mode}" + ("; force" if args.force else "")))
    atomic_write(args.out, new)
    print(f"wrote {args.out}")
    return 0


def _blank(args):
    """The stock to verify against and where it comes from: --stock, --plan, or the plan named
    in the errors file's [meta] by 'mtcomp workpiece-setting fit' (found as written or next to
    the errors file); (None, None) without any."""
    from .._io import load_toml
    from ..verify import parse_stock
    from .blank_check import plan_stock
    from .bowls import load_plan
    if args.stock:
        return parse_stock(args.stock), args.stock
    if args.plan:
        return plan_stock(load_plan(args.plan)), args.plan
    if args.no_verify:
        return None, None
    meta = load_toml(args.errors).get("meta", {})
    named = meta.get("plan") if isinstance(meta, dict) else None
    if isinstance(named, str) and named:
        for cand in (Path(named), Path(args.errors).parent / Path(named).name):
            if cand.is_file():
                return plan_stock(load_plan(cand)), f"{cand} (plan of the fit)"
    return None, None


def cmd_simulate(args) -> int:
    from .._io import atomic_write
    from .bowls import load_plan
    from .cellsim import CellConfig, RobotPlacement, simulate_cell
    robot = RobotPlacement(repeatability=args.repeatability, rotation_sigma=args.rotation_sigma,
                           offset=tuple(_floats(args.gripper_offset, 3, "gripper-offset")),
                           rotation=tuple(_floats(args.gripper_rotation, 3, "gripper-rotation")))
    cfg = CellConfig(machine=args.machine, plan=load_plan(args.plan) if args.plan else None,
                     robot=robot, probe_sigma=args.probe_sigma, mode=args.mode, trials=args.trials,
                     seed=args.seed, bowl_radius=args.bowl_radius,
                     shared_radius=not args.radius_per_bowl, cutter_radius_error=args.cutter_radius_error,
                     runout=args.runout, bowl_position_sigma=args.bowl_position_sigma,
                     reference=args.reference, microscope_scale=args.microscope_scale,
                     probe_drift=tuple(_floats(args.probe_drift, 3, "probe-drift")), repeat_first=args.repeat_first)

    def progress(i, n):
        if sys.stderr.isatty() and (i % 50 == 0 or i == n):
            print(f"\r{i}/{n} trials", end="\n" if i == n else "", file=sys.stderr)
    res = simulate_cell(cfg, progress)
    table = res.table()
    print(table)
    if args.out:
        atomic_write(args.out, table)
    if args.png:
        res.plot(args.png)
    return 0


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "workpiece-setting", help="workpiece setting errors after robot loading (paper 001)",
        description="Reference bowls, probing, sphere fit, workpiece frame with uncertainty, NC "
                    "transform and a virtual cell for the setting of a blank loaded by a robot.")
    sub = p.add_subparsers(dest="action", metavar="ACTION")
    sub.required = True

    a = sub.add_parser("plan", help="bowl plan, roughing program and probing program")
    a.add_argument("--bowls", type=int, default=3, help="number of bowls (>= 3, default 3)")
    a.add_argument("--blank", default="20,20,5", help="blank size lx,ly,lz mm (default 20,20,5)")
    a.add_argument("--tool-radius", type=float, default=2.0, help="ball end mill radius, mm (2.0)")
    a.add_argument("--depth", type=float, default=1.0, help="bowl depth, mm (1.0, <= radius)")
    a.add_argument("--probe-radius", type=float, default=0.5, help="probe tip radius, mm (0.5)")
    a.add_argument("--touches", type=int, default=9, help="touches per bowl (9)")
    a.add_argument("--positions", help="explicit bowl positions 'x,y;x,y;...' mm (default: chosen by --criterion)")
    a.add_argument("--criterion", choices=("D", "A"), default="D",
                   help="optimal-design criterion over the workpiece setting's covariance for the bowl positions "
                        "and touch rings: D (log det, default) or A (trace, angles at the blank's corner)")
    a.add_argument("--target-sigma", type=float, default=None,
                   help="required 1-sigma of dx, dy, dz and of each angle at the blank's corner, mm: touches "
                        "are added until it is met (refused if it cannot be)")
    a.add_argument("--probe-sigma", type=float, default=0.0005,
                   help="probe noise the design assumes, mm (default 0.0005)")
    a.add_argument("--repeat-first", action="store_true",
                   help="the probing program touches the first bowl again at the end: 'fit' then estimates and "
                        "removes the drift over the probing")
    a.add_argument("-o", "--out", required=True, help="plan TOML to write")
    a.add_argument("--roughing", help="roughing program (default <plan>-roughing.nc)")
    a.add_argument("--probing", help="probing program (default <plan>-probing.nc)")
    a.add_argument("--aim", help="errors TOML of a coarse first probing: place the probing "
                   "moves on the blank where it was found (second pass)")
    a.add_argument("--clearance", type=float, default=0.2,
                   help="the programs are verified on the blank: rapids keep this clearance, mm (0.2)")
    a.set_defaults(func=cmd_plan)

    a = sub.add_parser("probe", help="virtual probing of a blank at a given pose (touches CSV)")
    a.add_argument("plan", help="plan TOML")
    a.add_argument("--pose", required=True, help="true pose dx,dy,dz,a,b,c (mm, deg)")
    a.add_argument("--noise", type=float, default=0.0, help="probe noise 1 sigma, mm (0)")
    a.add_argument("--seed", type=int, default=0)
    a.add_argument("--probe-error", type=float, default=0.0,
                   help="the real probe's effective radius minus the plan's, mm (ball radius and pre-travel; 0)")
    a.add_argument("--lobing", type=float, default=0.0, help="the real probe's 3-lobe pre-travel amplitude, mm (0)")
    a.add_argument("--repeat-first", action="store_true",
                   help="touch the first bowl again at the end (then 'fit' estimates the drift over the probing)")
    a.add_argument("--drift", help="drift of the probe against the blank over the probing dx,dy,dz mm (linear)")
    a.add_argument("-o", "--out", required=True, help="touches CSV to write")
    a.set_defaults(func=cmd_probe)

    a = sub.add_parser("fit", help="fit bowls from probe touches, write the workpiece setting")
    a.add_argument("plan", help="plan TOML")
    a.add_argument("touches", help="touches CSV (bowl,x,y,z,ax,ay,az)")
    a.add_argument("--probe-sigma", type=float, help="probe noise 1 sigma, mm (default: pooled "
                   "from the fit residuals)")
    g = a.add_mutually_exclusive_group()
    g.add_argument("--bowl-radius", type=float, help="fix the bowl radius, mm (calibrated tool)")
    g.add_argument("--fix-radius", action="store_true", help="fix the bowl radius at the plan's "
                   "tool radius")
    g.add_argument("--radius-per-bowl", action="store_true", help="fit a radius per bowl "
                   "(default: one radius for all bowls, cut by one tool)")
    a.add_argument("--method", choices=("auto", "paper", "lsq"), default="auto",
                   help="frame: paper (3 bowls), lsq (best-fit), auto (default)")
    a.add_argument("--reference", choices=("bottom", "centre"), default="bottom",
                   help="bowl height from the bottom points (default; immune to the cutter radius) "
                        "or from the centres of the nominal radius")
    a.add_argument("--runout", type=float, default=0.0,
                   help="measured radial run-out of the ball end mill that cut the bowls, mm (0): its bias "
                        "on the bowls' bottom points is removed")
    a.add_argument("--k", type=float, default=5.0, help="outlier threshold in sigma (5)")
    a.add_argument("--probe", help="probe calibration TOML from 'probe-calibrate': touches are corrected for the "
                                   "effective radius and lobing first (without it dz carries the probe's radius error)")
    a.add_argument("-o", "--out", required=True, help="errors TOML to write (mtcomp format)")
    a.add_argument("--report", help="also write a report TOML (covariance, residuals)")
    a.set_defaults(func=cmd_fit)

    a = sub.add_parser("probe-calibrate", help="probe effective radius and lobing from touches on a reference sphere")
    a.add_argument("touches", help="touches CSV on the sphere (bowl,x,y,z,ax,ay,az; the bowl column is ignored)")
    a.add_argument("--sphere-diameter", type=float, required=True, help="certified sphere diameter, mm")
    a.add_argument("--diameter-sigma", type=float, default=0.0, help="its 1-sigma, mm (certificate; default 0)")
    a.add_argument("--probe-radius", type=float, required=True, help="nominal probe ball radius, mm")
    a.add_argument("--harmonics", type=int, default=3, help="azimuthal lobing harmonics 2..K (default K = 3)")
    a.add_argument("--probe-sigma", type=float, help="probe noise 1 sigma, mm (default: from the residuals)")
    a.add_argument("--axial-term", action="store_true",
                   help="also fit axial minus lateral pre-travel (needs touches well below the equator)")
    a.add_argument("--png", help="plot of the effective radius against the approach direction")
    a.add_argument("-o", "--out", required=True, help="probe calibration TOML to write (for fit --probe)")
    a.set_defaults(func=cmd_probe_calibrate)

    a = sub.add_parser("probe-sphere", help="virtual touches on a reference sphere (for probe-calibrate)")
    a.add_argument("--sphere-diameter", type=float, default=25.0, help="sphere diameter, mm (25)")
    a.add_argument("--probe-radius", type=float, required=True, help="true effective probe radius, mm")
    a.add_argument("--axial", type=float, default=0.0, help="axial minus lateral pre-travel, mm (0)")
    a.add_argument("--lobing", type=float, default=0.0, help="lobing amplitude, mm (0)")
    a.add_argument("--lobes", type=int, default=3, help="number of lobes (3)")
    a.add_argument("--touches", type=int, default=49, help="touches, pole then rings of 8 to the equator (49)")
    a.add_argument("--centre", default="0,0,0", help="sphere centre x,y,z mm")
    a.add_argument("--noise", type=float, default=0.0, help="probe noise 1 sigma, mm (0)")
    a.add_argument("--seed", type=int, default=0)
    a.add_argument("-o", "--out", required=True, help="touches CSV to write")
    a.set_defaults(func=cmd_probe_sphere)

    a = sub.add_parser("compensate", help="transform an NC program for the measured setting")
    a.add_argument("program", help="NC program (G-code)")
    a.add_argument("--errors", required=True, help="errors TOML with [workpiece_setting]")
    a.add_argument("--machine", default="robonano-a0ib", help="machine preset or TOML")
    a.add_argument("--mode", choices=("auto", "3axis", "5axis"), default="auto",
                   help="3axis: paper 001 formula; 5axis: tool direction too (default auto)")
    a.add_argument("--workpiece-only", action="store_true",
                   help="apply only [workpiece_setting] of an errors file that has other errors too")
    a.add_argument("--tool-lengths", help="tool lengths of G43.4 H words: 1=50.2,2=75, a CSV file of "
                   "lines H,length_mm or a LinuxCNC tool table (the lever of head axes in 5axis mode)")
    a.add_argument("--plan", help="bowl plan TOML: verify the program against its blank (default: the "
                   "plan named in the errors file by 'workpiece-setting fit', if found)")
    a.add_argument("--stock", help="verify against this stock instead: box:x0,y0,z0,x1,y1,z1 (mm, blank "
                   "frame), plane:Z or a STEP file")
    a.add_argument("--clearance", type=float, default=0.2,
                   help="clearance every rapid keeps from the blank, mm (0.2)")
    a.add_argument("--tool-radius", type=float, default=0.0,
                   help="ball radius of the tool for the verification, mm (0: point tool)")
    a.add_argument("--warn-only", action="store_true",
                   help="write the program even if the verification fails (prints the failures)")
    a.add_argument("--no-verify", action="store_true", help="do not look for the plan of the fit")
    a.add_argument("-o", "--out", required=True, help="program to write")
    a.add_argument("--force", action="store_true",
                   help="transform a program that mtcomp has already compensated")
    a.set_defaults(func=cmd_compensate)

    a = sub.add_parser("simulate", help="virtual cell Monte Carlo of paper 001's pyramid")
    a.add_argument("--trials", type=int, default=500)
    a.add_argument("--seed", type=int, default=1)
    a.add_argument("--machine", default="robonano-a0ib")
    a.add_argument("--plan", help="plan TOML (default: 3 bowls on the 20 mm blank)")
    a.add_argument("--repeatability", type=float, default=0.030,
                   help="robot pose repeatability RP (ISO 9283), mm (0.030)")
    a.add_argument("--rotation-sigma", type=float, default=0.02,
                   help="robot placement angle scatter, deg 1 sigma (0.02)")
    a.add_argument("--gripper-offset", default="0,0,0", help="systematic offset dx,dy,dz mm")
    a.add_argument("--gripper-rotation", default="0,0,0", help="systematic rotation a,b,c deg")
    a.add_argument("--probe-sigma", type=float, default=0.0005, help="probe noise, mm (0.0005)")
    g = a.add_mutually_exclusive_group()
    g.add_argument("--bowl-radius", type=float, help="fix the fitted bowl radius, mm")
    g.add_argument("--radius-per-bowl", action="store_true",
                   help="fit a radius per bowl (default: one for all bowls)")
    a.add_argument("--cutter-radius-error", type=float, default=0.0,
                   help="ball end mill radius error of the bowls, mm (0)")
    a.add_argument("--runout", type=float, default=0.0, help="radial run-out of the ball end mill, mm (0)")
    a.add_argument("--bowl-position-sigma", type=float, default=0.0,
                   help="ordinary machine's bowl position scatter, 1 sigma per axis, mm (0)")
    a.add_argument("--microscope-scale", type=float, default=0.0,
                   help="relative scale error of the width measurement (0)")
    a.add_argument("--reference", choices=("bottom", "centre"), default="bottom",
                   help="bowl height from bottom points (default) or centres")
    a.add_argument("--probe-drift", default="0,0,0",
                   help="drift of the probe against the blank over the probing dx,dy,dz mm (linear; 0,0,0)")
    a.add_argument("--repeat-first", action="store_true",
                   help="touch the first bowl again at the end and remove the fitted drift")
    a.add_argument("--mode", choices=("3axis", "5axis"), default="3axis")
    a.add_argument("-o", "--out", help="markdown table to write")
    a.add_argument("--png", help="PNG plot to write")
    a.set_defaults(func=cmd_simulate)
