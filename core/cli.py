"""The `mtcomp` command line: a thin layer over the library.

Each command group lives next to the code it drives and exposes ``register(subparsers)``;
this module only collects them, so the command groups can grow independently.
"""
from __future__ import annotations

import argparse
import importlib
import sys

from . import __version__
from ._io import MtcompError

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
    "mtcomp.demo",                # demo
]


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="mtcomp",
        description="Machine-tool error compensation: measure setting and geometric errors, "
                    "model them, and rewrite NC programs so the part comes out right.")
    parser.add_argument("--version", action="version", version=f"mtcomp {__version__}")
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


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    try:
        rc = args.func(args)
    except MtcompError as exc:
        print(f"mtcomp {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130
    return int(rc or 0)


if __name__ == "__main__":
    raise SystemExit(main())
