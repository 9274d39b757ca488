"""`mtcomp cad features ...` (STEP/STL of the calibration features and the papers' parts) and
`mtcomp cad toolpath ...` (G-code through the compensation core, and a PNG).

Kept light: cadquery, matplotlib and the kinematics are imported when a command runs.
"""
from __future__ import annotations

import dataclasses
import time
from pathlib import Path

from .._io import InputError

FEATURES = {
    "groove-plate": ("GroovePlateLayout", "groove_plate", "groove calibration plate (paper 000)"),
    "bowl-blank": ("BowlBlankLayout", "bowl_blank", "blank with three R2 bowls (paper 001)"),
    "pyramid": ("PyramidLayout", "pyramid_part", "pyramid on the bowl blank (paper 001)"),
    "grating": ("GratingLayout", "concave_grating", "concave grating with V-microgrooves (paper 000)"),
    "plan-plate": (None, "plan_plate", "plate of a tool-setting grooving plan (--plan, --face)"),
}
TOOLPATHS = ("pyramid", "bowls", "probe-bowls", "groove-plate", "grating")


def _parse_params(items, cls, what: str) -> dict:
    """--param name=value (TOML values: 0.05, [1, 2], "text") checked against a layout's fields."""
    try:
        import tomllib
    except ModuleNotFoundError:  # Python 3.10
        import tomli as tomllib
    fields = {f.name: f.default for f in dataclasses.fields(cls)} if cls is not None else None
    out = {}
    for item in items or []:
        if "=" not in item:
            raise InputError(f"expected name=value, got {item!r}", field="--param")
        name, value = (s.strip() for s in item.split("=", 1))
        if fields is not None and name not in fields:
            raise InputError(f"{what} has no parameter {name!r}; parameters: {', '.join(sorted(fields))}",
                             field=f"--param {name}")
        try:
            v = tomllib.loads(f"v = {value}")["v"]
        except tomllib.TOMLDecodeError:
            raise InputError(f"cannot read value {value!r} (TOML syntax: 0.05, [1.0, 2.0])",
                             field=f"--param {name}") from None
        default = fields.get(name, dataclasses.MISSING) if fields is not None else dataclasses.MISSING
        number = (int, float)
        if isinstance(default, number) and (isinstance(v, bool) or not isinstance(v, number)):
            raise InputError(f"expected a number, got {value!r}", field=f"--param {name}")
        if isinstance(default, tuple) and not isinstance(v, list):
            raise InputError(f"expected a list such as [1.0, 2.0], got {value!r}", field=f"--param {name}")
        out[name] = tuple(tuple(x) if isinstance(x, list) else x for x in v) if isinstance(v, list) else v
    return out


def _layout(kind: str, params: list[str]):
    from . import layout as L
    cls = getattr(L, FEATURES[kind][0])
    try:
        return cls(**_parse_params(params, cls, kind))
    except TypeError as exc:
        raise InputError(str(exc), field="--param") from None


def cmd_features(args) -> int:
    if args.kind == "plan-plate":
        if not args.plan:
            raise InputError("plan-plate needs --plan PLAN.toml (mtcomp tool-setting plan)",
                             field="--plan")
        from ..setting.tool_plan import load_plan
        plan = load_plan(args.plan)
        layout = None
    else:
        layout = _layout(args.kind, args.param)
    outs = [Path(o) for o in args.out]
    for o in outs:
        _check_out_dir(o)
        if o.suffix.lower() not in (".step", ".stp", ".stl"):
            raise InputError("output must end in .step, .stp or .stl", field=str(o))
    t0 = time.perf_counter()
    from . import features as F
    from .export import export_step, export_stl
    t1 = time.perf_counter()
    if args.kind == "plan-plate":
        part = F.plan_plate(plan, args.face, args.thickness)
    else:
        part = getattr(F, FEATURES[args.kind][1])(layout)
    t2 = time.perf_counter()
    for o in outs:
        if o.suffix.lower() == ".stl":
            export_stl(part, o, tolerance=args.stl_tolerance)
        else:
            export_step(part, o, name=f"{args.kind}: {FEATURES[args.kind][2]}")
    t3 = time.perf_counter()
    bb = part.val().BoundingBox()
    print(f"{args.kind}: {FEATURES[args.kind][2]}")
    print(f"  volume {F.volume(part):.9f} mm^3, box x [{bb.xmin:.4f}, {bb.xmax:.4f}] "
          f"y [{bb.ymin:.4f}, {bb.ymax:.4f}] z [{bb.zmin:.4f}, {bb.zmax:.4f}] mm")
    print(f"  cadquery import {t1 - t0:.2f} s, build {t2 - t1:.3f} s, export {t3 - t2:.3f} s")
    for o in outs:
        print(f"  wrote {o}")
    return 0


def _toolpath(args):
    from . import toolpath as T
    if args.kind == "pyramid":
        lay = _layout("pyramid", args.param)
        tool = T.Tool("ball", radius=args.tool_radius or 0.5, number=args.tool_number)
        step = dict(stepover=args.stepover) if args.scallop is None else dict(scallop=args.scallop)
        if args.stepover is None and args.scallop is None:
            step = dict(stepover=0.02)
        return T.pyramid_finishing(lay.width, lay.angle, tool, step=args.step or 0.01, **step)
    if args.kind in ("bowls", "probe-bowls"):
        lay = _layout("bowl-blank", args.param)
        if args.kind == "bowls":
            tool = T.Tool("ball", radius=args.tool_radius or 0.5, number=args.tool_number)
            return T.bowl_milling(lay.centres, lay.bowl_radius, lay.bowl_depth, tool,
                                  stepover=args.stepover or 0.05, step=args.step or 0.05)
        probe = T.Tool("probe", radius=args.tool_radius or 0.25, number=args.tool_number)
        return T.bowl_probing(lay.centres, lay.bowl_radius, lay.bowl_depth, probe)
    if args.kind == "groove-plate":
        lay = _layout("groove-plate", args.param)
        return T.groove_plate_passes(lay, T.Tool("vtool", angle=lay.angle, number=args.tool_number))
    lay = _layout("grating", args.param)
    return T.grating_passes(lay.sphere_radius, lay.psi, lay.span, lay.depth,
                            T.Tool("vtool", angle=lay.angle, number=args.tool_number))


def _check_out_dir(path) -> None:
    """Outputs go into an existing folder: a typo must not create a directory tree."""
    parent = Path(path).parent
    if not parent.is_dir():
        raise InputError(f"folder {parent} does not exist", field=str(path))
    if Path(path).is_dir():
        raise InputError("is a folder; give a file name", field=str(path))


def cmd_toolpath(args) -> int:
    import numpy as np
    for o in (args.out, args.png):
        if o:
            _check_out_dir(o)

    from ..errors import load_errors
    from ..machine import load_machine
    from . import check as C, post as P, toolpath as T
    from .._io import atomic_write
    from ..progress import StageLog
    log = StageLog(f"cad toolpath {args.kind}")
    machine = load_machine(args.machine)
    errors = load_errors(args.errors, machine=machine) if args.errors else None
    t0 = time.perf_counter()
    log("toolpath")
    path = _toolpath(args)
    t1 = time.perf_counter()
    log(f"machine axes of {len(path)} poses")
    q = T.to_axes(machine, path, errors)
    from ..verify import parse_stock, verify_program
    stock = parse_stock(args.stock) if args.stock else default_stock(args)
    log("safe rapid links")
    linked, q_linked = T.link_safely(machine, path, q, stock, args.clearance, errors=errors)
    log("post-processor")
    t2 = time.perf_counter()
    def template(value):
        return value.replace("\\n", "\n") if value is not None else None
    extra = {k: v for k, v in dict(
        preamble=template(args.preamble), postamble=template(args.postamble),
        tool_change=template(args.tool_change)).items() if v is not None}
    opts = P.PostOptions(program_number=args.program_number, tcp=args.tcp,
                         line_numbers=not args.no_line_numbers, spindle=args.spindle,
                         line_start=args.line_start, line_step=args.line_step,
                         line_max=args.line_max, tool_length=args.g43, retract=args.retract,
                         rotary_feed=args.rotary_feed, plunge_feed=args.plunge_feed,
                         coolant=args.coolant, probe_log=args.probe_log,
                         protected_macro=args.protected_macro, **extra)
    text = P.post(machine, linked, q_linked, opts, errors=errors,
                  errors_name=Path(args.errors).name if args.errors else "")
    t3 = time.perf_counter()
    print(f"{path.name}: {len(path)} poses, tool {path.tool.description}, machine {machine.name}")
    print(f"  toolpath {t1 - t0:.2f} s, axes{' (compensated)' if errors else ''} {t2 - t1:.2f} s, "
          f"post {t3 - t2:.2f} s; {len(linked) - len(path)} poses added for safe rapid links")
    # The emitted text itself is read back and run through the machine (with the errors it
    # was compensated for): what is verified is what the control gets.
    part = None
    if args.part:
        from ..verify import ShapeStock
        part = ShapeStock.from_step(args.part)
    log("verification")
    try:
        ver = verify_program(machine, P.motion_view(text, args.protected_macro), filename=str(args.out),
                             stock=stock, part=part,
                             clearance=args.clearance, errors=errors,
                             tool_radius=path.tool.radius if path.tool.kind != "vtool" else 0.0,
                             raise_on_violation=not args.warn_only)
    finally:
        log.done()
    print("  " + ver.summary().replace("\n", "\n  "))
    if path.tool.kind == "vtool":
        rk = np.abs(T.rake_error(machine, path, q, errors))
        worst = float(np.nanmax(rk)) if np.isfinite(rk).any() else float("nan")
        if not worst < 0.01:
            print(f"  WARNING: the rake face of the non-rotational tool is off the feed direction by up "
                  f"to {worst:.3f} deg ({int(np.sum(rk >= 0.01))} poses): {machine.name} cannot turn "
                  "the tool about its axis there")
    from ..kinematics import round_to_resolution
    qr = round_to_resolution(machine, q)
    if path.tool.kind == "ball" and path.name == "pyramid-finishing":
        target = C.pyramid_surface(path.meta["width"], path.meta["height"])
        extent = path.meta["width"] / 2 + 0.2
        form = C.form_error(machine, path, qr, errors, target, extent, grid=args.grid)
        meas = C.pyramid_widths_angles(machine, path, qr, errors)
        print(f"  virtual check ({'compensated, ' if errors else ''}forward model with "
              f"{'the same errors' if errors else 'no errors'}):")
        print("    " + form.summary())
        print("    " + meas.summary(path.meta["width"], path.meta["angle"]).replace("\n", "\n    "))
        if errors is not None:
            q0 = round_to_resolution(machine, T.to_axes(machine, path))   # as posted, like qr
            bad = C.pyramid_widths_angles(machine, path, q0, errors)
            bad_form = C.form_error(machine, path, q0, errors, target, extent, grid=args.grid)
            print("  uncompensated program on the same machine:")
            print("    " + bad_form.summary())
            print("    " + bad.summary(path.meta["width"], path.meta["angle"]).replace("\n", "\n    "))
        if args.png:
            C.plot_check(path, form, args.png, f"{path.name} on {machine.name}"
                         + (" (compensated)" if errors else ""))
    else:
        from ..kinematics import forward

        def deviation(qq):
            pose = forward(machine, qq, errors)
            dev = np.linalg.norm(pose.p - path.p, axis=1)
            # angle from the cross product: arccos loses everything below 1e-8 rad
            ang = np.arcsin(np.clip(np.linalg.norm(np.cross(pose.v, path.axis), axis=1), 0, 1))
            return (f"tool point deviation max {dev.max() * 1e3:.4f} µm, RMS "
                    f"{np.sqrt(np.mean(dev ** 2)) * 1e3:.4f} µm; tool axis deviation max "
                    f"{float(ang.max()) * 1e6:.3g} µrad")
        print(f"  forward model{' with the errors' if errors else ''} (command rounding only): "
              + deviation(qr))
        if errors is not None:
            print("  uncompensated: " + deviation(round_to_resolution(machine, T.to_axes(machine, path))))
        if args.png:
            C.plot_toolpath(path, args.png, f"{path.name} on {machine.name}", q=qr,
                            names=machine.axis_names)
    atomic_write(args.out, text)
    print(f"  wrote {args.out}" + (f" and {args.png}" if args.png else ""))
    return 0


def default_stock(args):
    """The blank of each toolpath kind as an analytic box (workpiece frame, mm)."""
    from ..verify import Box, CylinderZ, Intersection, SphereCavity
    if args.kind == "groove-plate":
        L = _layout("groove-plate", args.param)
        return Box((-L.size / 2, -L.size / 2, -L.thickness), (L.size / 2, L.size / 2, 0.0))
    if args.kind in ("bowls", "probe-bowls", "pyramid"):
        L = _layout("bowl-blank", args.param if args.kind != "pyramid" else [])
        top = 0.0
        if args.kind == "pyramid":
            from .layout import pyramid_height
            P = _layout("pyramid", args.param)
            top = pyramid_height(P.width, P.angle)
        return Box((-L.size / 2, -L.size / 2, -L.thickness), (L.size / 2, L.size / 2, top))
    L = _layout("grating", args.param)
    a, R = L.aperture_radius, L.sphere_radius
    rim = R - (R * R - a * a) ** 0.5
    return Intersection((CylinderZ(a, -L.height, rim), SphereCavity((0.0, 0.0, R), R)))


def cmd_verify(args) -> int:
    from ..errors import load_errors
    from ..machine import load_machine
    from .._io import read_text
    from ..verify import ShapeStock, VerifyError, parse_stock, verify_program
    machine = load_machine(args.machine)
    if not args.stock and not args.part:
        raise InputError("give --stock and/or --part", field="--stock")
    stock = parse_stock(args.stock) if args.stock else None
    part = ShapeStock.from_step(args.part) if args.part else None
    errors = load_errors(args.errors, machine=machine) if args.errors else None
    text = read_text(args.program, what="NC program")
    rates = None
    if args.rapid_rates:
        try:
            rates = {k.strip().upper(): float(v) for k, v in
                     (item.split("=") for item in args.rapid_rates.split(","))}
        except ValueError:
            raise InputError("expected A=RATE,... with numbers", field="--rapid-rates") from None
    from ..gcode.offsets import tool_lengths_of_options
    tools, offsets = tool_lengths_of_options(args, machine.axis_names)
    try:
        res = verify_program(machine, text, filename=str(args.program), stock=stock, part=part,
                             clearance=args.clearance, tolerance=args.tolerance, errors=errors,
                             tool_radius=args.tool_radius, step=args.step, raise_on_violation=False,
                             rapid_rates=rates, tool_lengths=tools, work_offsets=offsets,
                             tcp_rapids=args.tcp_rapids)
    except VerifyError as exc:  # not raised with raise_on_violation=False; kept for clarity
        res = exc.result
    print(res.summary(max_listed=20))
    if not res.ok and not args.warn_only:
        raise VerifyError(f"{len(res.violations)} block(s) fail; first: "
                          + res.violations[0].describe(res.clearance, res.tolerance), res)
    return 0


def register(subparsers) -> None:
    p = subparsers.add_parser("cad", help="CAD features (STEP/STL) and toolpaths (G-code)",
                              description="CadQuery calibration features and the papers' parts, "
                                          "their toolpaths and Fanuc-style G-code.")
    sub = p.add_subparsers(dest="cad_command", metavar="SUBCOMMAND", required=True)
    f = sub.add_parser("features", help="write a feature/part as STEP and/or STL",
                       description="Build a part and write it (format from the file suffix).")
    f.add_argument("kind", choices=sorted(FEATURES))
    f.add_argument("-o", "--out", action="append", required=True,
                   help="output file (.step/.stp/.stl); repeat for several")
    f.add_argument("--param", action="append", metavar="NAME=VALUE",
                   help="layout parameter (docs/cad.md), TOML value, e.g. depth=0.05")
    f.add_argument("--plan", help="plan-plate: tool-setting plan TOML (mtcomp tool-setting plan)")
    f.add_argument("--face", default="top", choices=("top", "side"), help="plan-plate: face")
    f.add_argument("--thickness", type=float, default=3.0, help="plan-plate: plate thickness, mm")
    f.add_argument("--stl-tolerance", type=float, default=1e-3, help="STL chordal tolerance, mm")
    f.set_defaults(func=cmd_features)

    t = sub.add_parser("toolpath", help="toolpath -> G-code (optionally compensated) and a PNG",
                       description="Generate a toolpath, convert it to machine axes through the "
                                   "kinematics (compensated with --errors) and write G-code.")
    t.add_argument("kind", choices=TOOLPATHS)
    t.add_argument("-m", "--machine", default="robonano-a0ib", help="preset name or machine TOML")
    t.add_argument("-o", "--out", required=True, help="G-code output file")
    t.add_argument("--png", help="PNG: virtual check (pyramid) or toolpath and axes plot")
    t.add_argument("--errors", help="errors TOML: compensate the program for these errors")
    t.add_argument("--tcp", action="store_true", help="G43.4 tool-centre-point output")
    t.add_argument("--program-number", type=int, default=1000,
                   help="O number, 1..7999 (O8000-O9999: the control's protected and macro programs)")
    t.add_argument("--no-line-numbers", action="store_true")
    t.add_argument("--line-start", type=int, help="first N number (default: the step)")
    t.add_argument("--line-step", type=int, default=10, help="N increment (default 10)")
    t.add_argument("--line-max", type=int, default=99999,
                   help="largest N the control takes (default 99999); N numbers never repeat: the "
                        "step shrinks, or the program has none, when the blocks do not fit")
    t.add_argument("--retract", choices=("G28", "G53", "none"), default="G28",
                   help="Z retract before the tool change and M30: G91 G28 Z0. (default) or G53 G00 Z0.")
    t.add_argument("--g43", action="store_true",
                   help="G43 H<tool> with the first move (machine-axes output; length in H)")
    t.add_argument("--rotary-feed", default="tool-tip", choices=("tool-tip", "inverse-time", "axes"),
                   help="feed of moves that turn rotary axes without TCP: per-block F that keeps "
                        "the tool-tip feed (default), G93 inverse time, or F as programmed")
    t.add_argument("--plunge-feed", type=float, help="feed of plunges along the tool axis, mm/min")
    t.add_argument("--coolant", choices=("M07", "M08"), help="coolant on after the tool change")
    t.add_argument("--preamble", help="preamble blocks ('\\n' between blocks; fields {program} "
                                      "{tool} {work_offset} {spindle})")
    t.add_argument("--tool-change", help="tool change blocks (default 'T{tool} M06')")
    t.add_argument("--postamble", help="blocks before M30")
    t.add_argument("--protected-macro", type=int, default=9810, metavar="P",
                   help="probe-bowls: positioning moves near the part as G65 P<P> protected moves "
                        "(default 9810, Renishaw Inspection Plus; 0: plain G01)")
    t.add_argument("--probe-log", action="store_true",
                   help="probe-bowls: record skip positions with POPEN/DPRNT (read_skip_log)")
    t.add_argument("--spindle", type=float, help="spindle speed, rpm (rotating tools)")
    t.add_argument("--tool-number", type=int, default=1)
    t.add_argument("--tool-radius", type=float, help="ball / probe radius, mm")
    t.add_argument("--stepover", type=float, help="mm between passes")
    t.add_argument("--scallop", type=float, help="scallop height, mm (pyramid; instead of stepover)")
    t.add_argument("--step", type=float, help="mm between points along a pass")
    t.add_argument("--grid", type=float, default=0.01, help="virtual check grid, mm")
    t.add_argument("--param", action="append", metavar="NAME=VALUE", help="layout parameter")
    t.add_argument("--stock", help="stock for the verification: box:x0,y0,z0,x1,y1,z1 (mm), "
                                   "plane:Z or a STEP file (default: the part's blank)")
    t.add_argument("--part", help="STEP of the finished part: feed moves must not gouge it")
    t.add_argument("--clearance", type=float, default=0.2,
                   help="least distance of rapid moves from the stock, mm (default 0.2)")
    t.add_argument("--warn-only", action="store_true",
                   help="write the program even if the verification fails (prints the failures)")
    t.set_defaults(func=cmd_toolpath)

    v = subparsers.add_parser(
        "verify", help="simulate an NC program through the machine model against stock and part",
        description="Run every block (rapids included, axes interpolated linearly as the control "
                    "does) through the machine's forward model and check rapids against the stock "
                    "with a clearance and feeds against the part (docs/verify.md).")
    v.add_argument("program", help="NC program (.nc)")
    v.add_argument("-m", "--machine", required=True, help="preset name or machine TOML")
    v.add_argument("--stock", help="box:x0,y0,z0,x1,y1,z1 (mm), plane:Z or a STEP file")
    v.add_argument("--part", help="STEP of the finished part (feed moves must not gouge it)")
    v.add_argument("--clearance", type=float, default=0.2, help="rapid clearance, mm (default 0.2)")
    v.add_argument("--tolerance", type=float, default=5e-4,
                   help="allowed depth of feed moves into the part, mm (default 0.0005)")
    v.add_argument("--tool-radius", type=float, default=0.0,
                   help="ball radius of the tool, mm (0: the tool point, e.g. a V tool's edge)")
    v.add_argument("--errors", help="errors TOML of the real machine (default: nominal)")
    v.add_argument("--step", type=float, default=0.005, help="largest sample spacing, mm")
    v.add_argument("--warn-only", action="store_true", help="report failures, exit 0")
    v.add_argument("--rapid-rates", metavar="A=RATE,...",
                   help="dog-leg rapids: each axis at its own rate (mm/min, deg/min), e.g. "
                        "X=10000,Y=10000,Z=5000,B=3600,C=3600; default: linear rapids")
    from ..gcode.offsets import add_tool_length_options
    add_tool_length_options(v)
    v.add_argument("--tcp-rapids", choices=("both", "tip", "joint"), default="both",
                   help="how the control moves G00 under G43.4: check both paths (default), the "
                        "tip straight (tip) or every axis linearly (joint)")
    v.set_defaults(func=cmd_verify)


