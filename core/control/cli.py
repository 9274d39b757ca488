"""`mtcomp control export|import`: the controls' own compensation files (docs/control.md)."""
from __future__ import annotations

import argparse
from pathlib import Path

from .._io import InputError


def register(sub) -> None:
    p = sub.add_parser("control", help="write or read a control's own compensation tables and kinematic "
                                       "parameters (LinuxCNC, Fanuc, Siemens, Heidenhain)")
    csub = p.add_subparsers(dest="control_command", metavar="ACTION")
    from . import CONTROLS
    e = csub.add_parser("export", help="pitch (bidirectional), straightness and rotary-axis locations in the "
                                       "control's files; what it cannot hold goes to remainder.toml")
    e.add_argument("--control", required=True, choices=CONTROLS)
    e.add_argument("--machine", required=True, help="preset name or machine TOML")
    e.add_argument("--errors", required=True, help="errors TOML (docs/errors-format.md)")
    e.add_argument("--reversal", action="append", default=[], metavar="FILE",
                   help="<axis>_reversal.csv from 'mtcomp geometric reversal' (repeatable): the pitch tables "
                        "then differ by direction of approach")
    e.add_argument("-o", "--output", required=True, help="output folder (created; files replaced atomically)")
    e.set_defaults(func=_export)
    i = csub.add_parser("import", help="read a control's files (and remainder.toml) back into an errors TOML")
    i.add_argument("--control", required=True, choices=CONTROLS)
    i.add_argument("--machine", required=True, help="preset name or machine TOML")
    i.add_argument("folder", help="folder of the control's files")
    i.add_argument("--no-remainder", action="store_true", help="ignore remainder.toml in the folder")
    i.add_argument("-o", "--output", required=True, help="errors TOML to write (tables and <axis>_reversal.csv beside it)")
    i.set_defaults(func=_import)
    r = csub.add_parser("remainder", help="what the NC program must still correct when the control already "
                                          "compensates what its files in a folder hold (no double compensation)")
    r.add_argument("--control", required=True, choices=CONTROLS)
    r.add_argument("--machine", required=True, help="preset name or machine TOML")
    r.add_argument("--errors", required=True, help="the machine's errors, measured with the control's compensation off")
    r.add_argument("--control-has", required=True, metavar="DIR",
                   help="folder of the control's compensation files (its remainder.toml is ignored)")
    r.add_argument("-o", "--output", required=True, help="errors TOML for 'mtcomp compensate --errors'")
    r.set_defaults(func=_remainder)
    p.set_defaults(func=lambda args: (p.print_help(), 2)[1])


def _export(args: argparse.Namespace) -> int:
    from . import export_control
    from .common import read_reversal_csv
    rev = {}
    for f in args.reversal:
        r = read_reversal_csv(f)
        if r.axis in rev:
            raise InputError(f"second reversal table for axis {r.axis}", f, field="--reversal")
        rev[r.axis] = r
    res = export_control(args.control, args.machine, args.errors, args.output, rev)
    print(res.summary(), end="")
    for f in res.files:
        print(f"wrote {f}")
    return 0


def _import(args: argparse.Namespace) -> int:
    from ..errors import save_errors
    from .._io import atomic_write
    from . import import_control
    errors, rev = import_control(args.control, args.machine, args.folder, remainder=not args.no_remainder)
    out = Path(args.output)
    save_errors(errors, out, meta={"read_by": f"mtcomp control import --control {args.control}"})
    print(f"wrote {out}")
    for ax, r in rev.items():
        f = atomic_write(out.parent / f"{out.stem}_{ax}_reversal.csv", r.to_csv())
        print(f"wrote {f} (reversal B = {r.B * 1e3:.4f} µm)")
    return 0


def _remainder(args: argparse.Namespace) -> int:
    from ..errors import load_errors, save_errors
    from ..machine import load_machine
    from . import import_control, remainder_after
    machine = load_machine(args.machine)
    errors = load_errors(args.errors, machine)
    held, rev = import_control(args.control, machine, args.control_has, remainder=False)
    rest, notes = remainder_after(machine, errors, held)
    for ax, t in held.geometric.tables.items():
        print(f"the control holds for axis {ax}: {', '.join(sorted(t.values))}")
    for k in sorted(held.geometric.location):
        print(f"the control holds {k}")
    for ax, r in rev.items():
        print(f"the control's {ax} tables differ by direction (reversal up to {r.B * 1e3:.3f} µm): "
              "the program cannot correct by direction, so nothing of it is left here")
    for n in notes:
        print(f"note: {n}")
    save_errors(rest, args.output, meta={"written_by": f"mtcomp control remainder --control {args.control}",
                                         "what": "errors minus what the control compensates: for mtcomp compensate"})
    print(f"wrote {args.output}")
    return 0
