"""`mtcomp fmu build|ssp` and `mtcomp cosim`: thin command line over mtcomp.fmu."""
from __future__ import annotations

import argparse
from pathlib import Path


def _floats(text: str, what: str) -> tuple[float, ...]:
    from .._io import InputError
    try:
        return tuple(float(x) for x in text.split(","))
    except ValueError:
        raise InputError(f"expected comma-separated numbers, got {text!r}", field=what) from None


def _dynamics(args):
    from .build import MachineDynamics
    kv = _floats(args.kv, "--kv")
    bl = _floats(args.backlash, "--backlash")
    return MachineDynamics(kv=kv[0] if len(kv) == 1 else kv, backlash=bl[0] if len(bl) == 1 else bl,
                           noise=args.noise * 1e-6, seed=args.seed)


def _errors(path):
    from ..errors import ErrorSet, load_errors
    return load_errors(path) if path else ErrorSet()


def _build(args) -> int:
    from .build import build_compensator_fmu, build_machine_fmu
    errors = _errors(args.errors)
    windows = {"auto": None, "yes": True, "no": False}[args.win64]
    if args.kind == "compensator":
        out = build_compensator_fmu(args.machine, args.output, errors, compiler=args.compiler, fmi_version=args.fmi,
                                    windows=windows)
    else:
        out = build_machine_fmu(args.machine, args.output, errors, _dynamics(args), compiler=args.compiler,
                                fmi_version=args.fmi, windows=windows)
    print(f"wrote {out}")
    return 0


def _commands(text: str | None) -> dict | None:
    """--commands "C=20,B=10,X=5" -> {"C": 20.0, "B": 10.0, "X": 5.0}."""
    from .._io import InputError
    if not text:
        return None
    out = {}
    for item in text.split(","):
        axis, eq, value = item.partition("=")
        try:
            out[axis.strip()] = float(value)
        except ValueError:
            eq = ""
        if not eq or not axis.strip():
            raise InputError(f"expected AXIS=VALUE items separated by commas, got {item!r}", field="--commands")
    return out


def _ssp(args) -> int:
    import tempfile
    from .build import build_compensator_fmu, build_machine_fmu
    from .ssp import write_ssp
    commands = _commands(args.commands)
    true = _errors(args.errors)
    ident = _errors(args.compensate) if args.compensate else true
    with tempfile.TemporaryDirectory(prefix="mtcomp-ssp-") as td:
        c = build_compensator_fmu(args.machine, Path(td) / "compensator.fmu", ident, compiler=args.compiler,
                                  fmi_version=args.fmi)
        m = build_machine_fmu(args.machine, Path(td) / "machine.fmu", true, _dynamics(args), compiler=args.compiler,
                              fmi_version=args.fmi)
        out = write_ssp(args.output, c, m, layout=args.layout, commands=commands)
    print(f"wrote {out}")
    return 0


def _cosim(args) -> int:
    from .._io import InputError
    from .cosim import cosimulate
    prog = Path(args.program)
    if not prog.is_file():
        raise InputError("NC program not found", prog)
    from ..progress import Progress
    true = _errors(args.errors)
    ident = _errors(args.compensate) if args.compensate else None
    prefix = Path(args.out) if args.out else Path(prog.stem + ".cosim")
    if prefix.is_dir() or not prefix.parent.is_dir():
        raise InputError("output prefix must name a file in an existing folder", field="--out")
    res = cosimulate(prog, args.machine, true, ident, step=args.step, dynamics=_dynamics(args),
                     rapid=args.rapid, spindle_speed=args.spindle_speed, compiler=args.compiler,
                     progress=Progress("cosim (without, then with compensation)"))
    csv_path = res.to_csv(prefix.with_name(prefix.name + ".csv"), full=args.full_csv)
    png_path = prefix.with_name(prefix.name + ".png")
    res.plot(png_path)
    print(res.summary())
    rows = "every step" if args.full_csv else f"every {res.default_stride()}. step; --full-csv for all"
    print(f"wrote {csv_path} ({rows}) and {png_path}")
    return 0


def _dyn_args(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("machine dynamics (machine FMU)")
    g.add_argument("--kv", default="0", help="servo gain(s) in 1/s, one value or one per axis (0: ideal servo)")
    g.add_argument("--backlash", default="0", help="backlash in mm/deg, one value or one per axis")
    g.add_argument("--noise", type=float, default=0.0, help="tool edge measurement noise, 1 sigma in nm")
    g.add_argument("--seed", type=int, default=1, help="noise seed")


def register(subparsers) -> None:
    fmu = subparsers.add_parser("fmu", help="build the native compensator and machine FMUs (FMI 2.0 or 3.0)",
                                description="Build FMI 2.0 (or, with --fmi 3, FMI 3.0) Co-Simulation FMUs from "
                                            "the C sources (docs/fmu.md).")
    fsub = fmu.add_subparsers(dest="fmu_command", metavar="COMMAND")
    b = fsub.add_parser("build", help="build a compensator or machine FMU")
    b.add_argument("kind", choices=("compensator", "machine"))
    b.add_argument("--machine", required=True, help="preset name or machine TOML")
    b.add_argument("--errors", help="errors TOML (start values of the parameters, tables as resources)")
    b.add_argument("-o", "--output", required=True, help="FMU file to write")
    b.add_argument("--compiler", choices=("cmake", "cc"), default="cmake",
                   help="cmake: fmpy's CMake build (default); cc: one direct gcc call")
    b.add_argument("--fmi", type=int, choices=(2, 3), default=2, help="FMI version (default 2.0)")
    b.add_argument("--win64", choices=("auto", "yes", "no"), default="auto",
                   help="also cross-compile a win64 binary with mingw-w64 (auto: when x86_64-w64-mingw32-gcc "
                        "is installed; yes: required)")
    _dyn_args(b)
    b.set_defaults(func=_build)
    s = fsub.add_parser("ssp", help="SSP file wiring a compensator FMU to a machine FMU")
    s.add_argument("--machine", required=True, help="preset name or machine TOML")
    s.add_argument("--errors", help="true errors of the machine (errors TOML)")
    s.add_argument("--compensate", help="errors the compensator corrects (default: the true ones)")
    s.add_argument("-o", "--output", required=True, help="SSP file to write")
    s.add_argument("--commands", help="start values of the compensator's commands, e.g. C=20,B=10,X=5 "
                                      "(mm, deg; parameter set 'commands')")
    s.add_argument("--layout", choices=("components", "system"), default="components",
                   help="components: for fmpy, libcosim and ecos (default); system: open inputs and machine "
                        "outputs as system connectors, for fmucontainer and fmpy (docs/fmu.md)")
    s.add_argument("--fmi", type=int, choices=(2, 3), default=2,
                   help="FMI version of both FMUs (default 2; 3 runs in ecos, not in fmpy's simulate_ssp "
                        "or libcosim 0.0.6)")
    s.add_argument("--compiler", choices=("cmake", "cc"), default="cmake")
    _dyn_args(s)
    s.set_defaults(func=_ssp)
    fmu.set_defaults(func=lambda args: (fmu.print_help(), 2)[1])

    c = subparsers.add_parser("cosim", help="co-simulate NC program -> compensator FMU -> machine FMU",
                              description="Interpolate an NC program at the communication step, run it through "
                                          "the compensator and machine FMUs with fmpy as the master, and report the "
                                          "tool edge error with and without compensation (CSV + PNG).")
    c.add_argument("program", help="NC program")
    c.add_argument("--machine", required=True, help="preset name or machine TOML")
    c.add_argument("--errors", required=True, help="true errors of the machine (errors TOML)")
    c.add_argument("--compensate", help="identified errors the compensator corrects (default: the true ones)")
    c.add_argument("--step", type=float, default=1e-3, help="communication step in s (default 0.001)")
    c.add_argument("--rapid", type=float, default=3000.0, help="G0 rate in mm/min (default 3000)")
    c.add_argument("--spindle-speed", type=float, default=0.0, help="spindle speed in 1/min (thermal drift)")
    c.add_argument("--out", help="output prefix (default: PROGRAM.cosim): writes PREFIX.csv and PREFIX.png")
    c.add_argument("--full-csv", action="store_true",
                   help="write every step to the CSV (default: decimated to at most 10 000 rows)")
    c.add_argument("--compiler", choices=("cmake", "cc"), default="cmake")
    _dyn_args(c)
    c.set_defaults(func=_cosim)
