"""The `mtcomp` command line: a thin layer over the library.

Each command group lives next to the code it drives and exposes ``register(subparsers)``;
this module only collects them, so the command groups can grow independently.
"""
from __future__ import annotations

import argparse
import errno
import importlib
import os
import sys
import traceback
from pathlib import Path

from . import __version__
from ._io import InputError, MtcompError

# The module of every command group; each defines register(subparsers).
COMMAND_MODULES = [
    "mtcomp.commands",            # compensate, machines
    "mtcomp.setting.tool_cli",    # tool-setting plan|simulate|estimate
    "mtcomp.setting.workpiece_cli",  # workpiece-setting plan|fit|compensate|simulate
    "mtcomp.geometric.cli",       # geometric iso230-2|build|map|table
    "mtcomp.fmu.cli",             # fmu build, cosim
    "mtcomp.cad_plugin.cli",      # cad features|toolpath
    "mtcomp.cell.cli",            # cell serve|plc-sim
    "mtcomp.diagnose.cli",        # diagnose
    "mtcomp.model.cli",           # model export|simulate|resimulate
    "mtcomp.demo",                # demo
    "mtcomp.control.cli",         # control export|import
    "mtcomp.fleet.cli",           # fleet diagnose|report
]


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="mtcomp",
        description="Machine-tool error compensation: measure setting and geometric errors, "
                    "model them, and rewrite NC programs so the part comes out right.")
    parser.add_argument("--version", action="version", version=f"mtcomp {__version__}")
    parser.add_argument("--debug", action="store_true",
                        help="on an internal error, print the traceback (accepted anywhere on the line)")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in COMMAND_MODULES:
        try:
            mod = importlib.import_module(name)
        except ModuleNotFoundError as exc:
            if exc.name == name:  # command group not shipped in this build
                continue
            raise
        mod.register(sub)
    return parser


# Options that name files or folders the command writes (argparse dest names).  Their parent
# folder must exist: a mistyped `-o /nonexist/x.nc` is refused instead of creating /nonexist.
# (nc_dir is an input folder for `cell serve`: the check is harmless there, its parent exists.)
OUTPUT_DESTS = ("output", "out", "outdir", "out_dir", "report", "png", "plot", "json", "journal", "nc_dir")


def _check_outputs(args) -> None:
    for dest in OUTPUT_DESTS:
        value = getattr(args, dest, None)
        for v in (value if isinstance(value, list) else [value]):
            if not isinstance(v, str):
                continue
            if not v.strip():
                raise InputError("expected a path, got an empty string", field=f"--{dest.replace('_', '-')}")
            parent = Path(v).parent
            if not parent.is_dir():
                what = "is not a folder" if parent.exists() else "does not exist"
                raise InputError(f"cannot write {v}: folder {parent} {what} (create it first)",
                                 field=f"--{dest.replace('_', '-')}")


def _os_error_text(exc: OSError) -> str:
    """One line for an operating-system error on a file (what happened to which path)."""
    name = exc.filename if exc.filename is not None else ""
    reason = {
        errno.EISDIR: "is a folder, expected a file name",
        errno.ENOTDIR: "a part of the path is a file, not a folder",
        errno.EEXIST: "already exists and is not a folder",
        errno.EACCES: "permission denied",
        errno.EPERM: "operation not permitted",
        errno.ENOSPC: "no space left on the device",
        errno.EROFS: "read-only file system",
        errno.ENOENT: "no such file or folder",
    }.get(exc.errno, exc.strerror or str(exc))
    return f"{name}: {reason}" if name else reason


def main(argv: list[str] | None = None) -> int:
    """Run one command.  Exit status: 0 success, 2 bad input or usage (one line on stderr), 3 an
    internal error (one line; the traceback with --debug, given anywhere on the command line),
    130 interrupted."""
    argv = list(sys.argv[1:] if argv is None else argv)
    cut = argv.index("--") if "--" in argv else len(argv)
    debug = "--debug" in argv[:cut]
    if debug:
        argv = [a for i, a in enumerate(argv) if not (i < cut and a == "--debug")]
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    prog = f"mtcomp {args.command}"
    try:
        _check_outputs(args)
        from ._heap import tune
        tune()                    # one job per process: reuse freed arrays (mtcomp._heap)
        rc = args.func(args)
    except MtcompError as exc:
        print(f"{prog}: error: {exc}", file=sys.stderr)
        if debug:
            traceback.print_exc()
        return 2
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:
        # the reader of our output went away (`mtcomp machines | head`): not an error
        try:
            os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        except OSError:
            pass
        return 0
    except OSError as exc:
        print(f"{prog}: error: {_os_error_text(exc)}", file=sys.stderr)
        if debug:
            traceback.print_exc()
        return 2
    except MemoryError:
        print(f"{prog}: error: out of memory (is an input file far larger than expected?)", file=sys.stderr)
        return 3
    except RecursionError:
        print(f"{prog}: error: input nested too deeply", file=sys.stderr)
        return 3
    except Exception as exc:  # noqa: BLE001 - the one place that turns a bug into one line
        if debug:
            traceback.print_exc()
        where = ""
        tb = traceback.extract_tb(exc.__traceback__)
        if tb:
            where = f" at {Path(tb[-1].filename).name}:{tb[-1].lineno}"
        text = str(exc).splitlines()[0][:200] if str(exc) else ""
        print(f"{prog}: internal error: {type(exc).__name__}{where}: {text} "
              f"(please report it{'' if debug else '; rerun with --debug for the traceback'})", file=sys.stderr)
        return 3
    return int(rc or 0)


if __name__ == "__main__":
    raise SystemExit(main())
