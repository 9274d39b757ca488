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
            export_step(part, o)
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


def cmd_toolpath(args) -> int:
    import numpy as np

    from ..errors import load_errors
    from ..machine import load_machine
    from . import check as C, post as P, toolpath as T
    from .._io import atomic_write
    machine = load_machine(args.machine)
    errors = load_errors(args.errors) if args.errors else None
    t0 = time.perf_counter()
    path = _toolpath(args)
    t1 = time.perf_counter()
    q = T.to_axes(machine, path, errors)
    t2 = time.perf_counter()
    opts = P.PostOptions(program_number=args.program_number, tcp=args.tcp,
                         line_numbers=not args.no_line_numbers, spindle=args.spindle)
    text = P.post(machine, path, q, opts, errors=errors,
                  errors_name=Path(args.errors).name if args.errors else "")
    t3 = time.perf_counter()
    print(f"{path.name}: {len(path)} poses, tool {path.tool.description}, machine {machine.name}")
    print(f"  toolpath {t1 - t0:.2f} s, axes{' (compensated)' if errors else ''} {t2 - t1:.2f} s, "
          f"post {t3 - t2:.2f} s")
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
            ang = np.degrees(np.arccos(np.clip(np.einsum("ij,ij->i", pose.v, path.axis), -1, 1)))
            return dev.max() * 1e3, float(np.sqrt(np.mean(dev ** 2))) * 1e3, ang.max()
        d = deviation(qr)
        print(f"  forward model{' with the errors' if errors else ''}: tool point deviation max "
              f"{d[0]:.4f} um, RMS {d[1]:.4f} um; tool axis off by {d[2]:.6f} deg at most")
        if errors is not None:
            d0 = deviation(round_to_resolution(machine, T.to_axes(machine, path)))
            print(f"  uncompensated: tool point deviation max {d0[0]:.4f} um, RMS {d0[1]:.4f} um; "
                  f"tool axis off by {d0[2]:.6f} deg at most")
        if args.png:
            C.plot_toolpath(path, args.png, f"{path.name} on {machine.name}", q=qr,
                            names=machine.axis_names)
    atomic_write(args.out, text)
    print(f"  wrote {args.out}" + (f" and {args.png}" if args.png else ""))
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
    t.add_argument("--program-number", type=int, default=1000)
    t.add_argument("--no-line-numbers", action="store_true")
    t.add_argument("--spindle", type=float, help="spindle speed, rpm (rotating tools)")
    t.add_argument("--tool-number", type=int, default=1)
    t.add_argument("--tool-radius", type=float, help="ball / probe radius, mm")
    t.add_argument("--stepover", type=float, help="mm between passes")
    t.add_argument("--scallop", type=float, help="scallop height, mm (pyramid; instead of stepover)")
    t.add_argument("--step", type=float, help="mm between points along a pass")
    t.add_argument("--grid", type=float, default=0.01, help="virtual check grid, mm")
    t.add_argument("--param", action="append", metavar="NAME=VALUE", help="layout parameter")
    t.set_defaults(func=cmd_toolpath)


