"""CLI commands of the core: `mtcomp compensate` and `mtcomp machines`."""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from ._io import InputError, atomic_write
from .cliargs import positive_float
from .errors import ErrorSet, TableRangeError, load_errors
from .kinematics import ConvergenceError, LimitError, forward, retarget
from .machine import list_presets, load_machine
from .progress import Progress

CHUNK = 200_000


def compensate_program(text: str, machine, errors: ErrorSet, *, filename: str = "<string>",
                       chordal_tol: float = 1e-4, convert_inch: bool = False, progress=None):
    """Rewrite an NC program written for the ideal machine so that the real machine with
    `errors` cuts what the program meant.  Returns (new_text, report dict with max/RMS tool-edge
    errors in mm before and after, from the forward model)."""
    from . import gcode

    prog = gcode.parse(text, axes=machine.axis_names, filename=filename, convert_inch=convert_inch)
    n_blocks = len(prog)

    calls = [0]

    def transform(q):
        # gcode.rewrite calls this with [start, block ends 1..N, arc samples] first and, when
        # arcs are linearised, a second time with segment points only.
        first = calls[0] == 0
        calls[0] += 1
        out = np.empty_like(q)
        for s in range(0, len(q), CHUNK):
            try:
                out[s:s + CHUNK] = retarget(machine, q[s:s + CHUNK], errors)
            except (LimitError, ConvergenceError, TableRangeError) as exc:
                i = s + exc.index
                if first and 1 <= i <= n_blocks:
                    raise InputError(f"cannot compensate: {exc}", filename, int(prog.line[i - 1])) from None
                where = "an interior point of an arc" if first else "an interior point of a linearised arc"
                raise InputError(f"cannot compensate {where}: {exc}", filename) from None
            if progress:
                progress(min(s + CHUNK, len(q)), len(q))
        return out

    res = {a.name: a.resolution for a in machine.axes}
    new_text, out_line = gcode.rewrite_with_lines(prog, transform, resolution=res, chordal_tol=chordal_tol)
    # Check the result as the machine will run it: re-read the written program (rounded
    # numbers, linearised arcs) and put it through the forward model with the errors.
    target = forward(machine, prog.position)
    before = np.linalg.norm(forward(machine, prog.position, errors).p - target.p, axis=1)
    # (an error here is in the program mtcomp wrote, not in the input: say so)
    after_prog = gcode.parse(new_text, axes=machine.axis_names, filename=f"{filename} (compensated output)")
    # the output block that ends each input block (linearised arcs add lines after their block)
    idx = np.searchsorted(after_prog.line, out_line)
    after = np.linalg.norm(forward(machine, after_prog.position[idx], errors).p - target.p, axis=1)
    rms = lambda e: float(np.sqrt(np.mean(e**2))) if e.size else 0.0  # noqa: E731
    report = {"blocks": n_blocks, "lines": prog.n_lines,
              "before_max": float(before.max(initial=0)), "before_rms": rms(before),
              "after_max": float(after.max(initial=0)), "after_rms": rms(after)}
    return new_text, report


def _cmd_compensate(args) -> int:
    machine = load_machine(args.machine)
    errors = load_errors(args.errors, machine=machine)
    src = Path(args.program)
    from .gcode import read_program
    text = read_program(src)  # keeps CR LF byte for byte
    out = Path(args.output) if args.output else src.with_name(src.stem + "_comp" + src.suffix)
    new_text, rep = compensate_program(text, machine, errors, filename=str(src), chordal_tol=args.chordal_tol * 1e-3,
                                       convert_inch=args.inch, progress=Progress("compensating", args.progress))
    atomic_write(out, new_text)
    print(f"{src}: {rep['lines']} lines, {rep['blocks']} motion blocks on {machine.name} -> {out}")
    print(f"tool-edge error before compensation: max {rep['before_max'] * 1e3:10.3f} um   "
          f"RMS {rep['before_rms'] * 1e3:10.3f} um")
    print(f"tool-edge error after  compensation: max {rep['after_max'] * 1e6:10.3f} nm   "
          f"RMS {rep['after_rms'] * 1e6:10.3f} nm")
    return 0


def _cmd_machines(args) -> int:
    if args.name:
        m = load_machine(args.name)
        from ._io import dump_toml
        sys.stdout.write(dump_toml(m.to_dict()))
        return 0
    for name in list_presets():
        m = load_machine(name)
        chain = " ".join(f"{a.name}{'*' if a.side == 'workpiece' else ''}" for a in m.axes)
        print(f"{name:20s} {chain:16s} {m.description}")
    print("(* = axis on the workpiece side)")
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("compensate", help="rewrite an NC program for setting and geometric errors",
                       description="Rewrite a Fanuc-style NC program so that the real machine with the "
                                   "given errors cuts what the program meant; prints the tool-edge error "
                                   "before and after (forward model).")
    p.add_argument("program", help="NC program (G-code)")
    p.add_argument("--machine", "-m", required=True, help=f"preset ({', '.join(list_presets())}) or TOML file")
    p.add_argument("--errors", "-e", required=True, help="errors TOML (docs/errors-format.md)")
    p.add_argument("-o", "--output", help="output program (default: PROGRAM_comp.nc)")
    p.add_argument("--chordal-tol", type=positive_float, default=0.1, metavar="UM",
                   help="chordal tolerance for linearised arcs in um (default 0.1)")
    p.add_argument("--inch", action="store_true", help="accept G20 (inch) data and convert it to mm")
    p.add_argument("--progress", action="store_true", default=None, help="show a progress bar")
    p.set_defaults(func=_cmd_compensate)

    p = sub.add_parser("machines", help="list machine presets, or print one as TOML")
    p.add_argument("name", nargs="?", help="preset name or machine file")
    p.set_defaults(func=_cmd_machines)
