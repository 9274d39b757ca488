"""`mtcomp cell serve|client|plc-sim`: thin wrappers over mtcomp.cell."""
from __future__ import annotations

import argparse
import importlib

from .._io import InputError


def register(subparsers) -> None:
    p = subparsers.add_parser("cell", help="Modbus TCP bridge to the robot loading cell's PLC",
                              description="Modbus TCP bridge to the PLC of the robot loading "
                                          "cell (register map: docs/cell.md).")
    sub = p.add_subparsers(dest="cell_command", metavar="CELL_COMMAND")
    p.set_defaults(func=lambda a: (p.print_help(), 2)[1])

    s = sub.add_parser("serve", help="serve the cell's registers (mtcomp is the Modbus server)")
    s.add_argument("--host", default="127.0.0.1",
                   help="address to bind (default 127.0.0.1; 0.0.0.0 only if you mean it)")
    s.add_argument("--port", type=int, default=5020,
                   help="TCP port (default 5020; the Modbus port 502 needs privileges)")
    s.add_argument("--unit-id", type=int, default=1,
                   help="Modbus unit id answered (default 1; 255 is always answered too)")
    s.add_argument("--allow", action="append", metavar="ADDR[/NET]",
                   help="peer allowed to write (the PLC's address; repeat or comma-separate; "
                        "default 127.0.0.1 and ::1)")
    _cycle_options(s)
    s.set_defaults(func=_serve)

    c = sub.add_parser("client", help="poll a PLC that is the Modbus server (client mode)")
    c.add_argument("--plc-host", required=True, help="the PLC's address")
    c.add_argument("--plc-port", type=int, default=502, help="the PLC's Modbus port (502)")
    c.add_argument("--base", type=int, default=0,
                   help="PLC holding register where the map starts (default 0)")
    c.add_argument("--poll", type=float, default=0.05, help="poll period in s (default 0.05)")
    c.add_argument("--unit-id", type=int, default=1,
                   help="unit id of the PLC's Modbus server (default 1)")
    _cycle_options(c)
    c.set_defaults(func=_serve)

    m = sub.add_parser("map", help="export the register map (CSV or JSON) for the PLC program",
                       description="The register map the server uses, as CSV (one row per field) or "
                                   "JSON (fields plus the codes of states, commands, faults).")
    m.add_argument("--format", choices=("csv", "json"), default="csv", help="output format (default csv)")
    m.add_argument("--word-order", choices=("big", "little"), default="big",
                   help="word order of 32-bit values the server is started with (default big)")
    m.add_argument("-o", "--output", help="file to write (default: standard output)")
    m.set_defaults(func=_map)

    q = sub.add_parser("plc-sim", help="play the PLC and the loading robot against a server")
    q.add_argument("--host", default="127.0.0.1")
    q.add_argument("--port", type=int, default=5020)
    q.add_argument("--cycles", type=int, default=1, help="load cycles to run (default 1)")
    q.add_argument("--word-order", choices=("big", "little"), default="big")
    q.add_argument("--first-part-id", type=int, default=1)
    q.add_argument("--program-id", type=int, default=100)
    q.add_argument("--seed", type=int, default=0,
                   help="seed of the simulated connection drops")
    q.add_argument("--disconnect-prob", type=float, default=0.0,
                   help="probability of dropping the connection around a request")
    q.add_argument("--poll", type=float, default=0.05, help="poll period in s (default 0.05)")
    q.add_argument("--unit-id", type=int, default=1, help="unit id to address (default 1)")
    q.set_defaults(func=_plc_sim)


def _cycle_options(s) -> None:
    s.add_argument("--journal", required=True, help="journal file (JSON lines, appended)")
    s.add_argument("--word-order", choices=("big", "little"), default="big",
                   help="order of the two registers of 32-bit values (default big = ABCD)")
    s.add_argument("--measure", metavar="MODULE:CALLABLE",
                   help="measurement step measure_and_compute(job) -> CellResult "
                        "(default: the virtual cell)")
    s.add_argument("--probe-inbox", metavar="DIR",
                   help="real machine: directory where the NC writes the touches CSV "
                        "<part_id>.csv (needs --plan); default: the virtual cell")
    s.add_argument("--plan", help="bowl plan TOML (mtcomp workpiece-setting plan)")
    s.add_argument("--probe-sigma", type=float,
                   help="real machine: probe noise 1 sigma in mm (default: from the residuals)")
    s.add_argument("--seed", type=int, default=0, help="virtual cell: random seed")
    s.add_argument("--probe-time", type=float, default=0.0,
                   help="virtual cell: simulated probing time in s")
    s.add_argument("--nc-dir", help="directory of part programs O0100.nc (O + 4 digits) to "
                                    "compensate (default: no program written, always NO-GO)")
    s.add_argument("--out-dir", help="where compensated programs go (default --nc-dir)")
    s.add_argument("--clearance", type=float, default=0.2,
                   help="compensated programs are verified on the plan's blank at the measured pose: "
                        "rapids keep this clearance from it, mm (default 0.2)")
    s.add_argument("--program-check", metavar="MODULE:CALLABLE",
                   help="further check of every compensated program, check(machine, path, text); "
                        "raise an MtcompError to refuse it")
    s.add_argument("--program-offset", type=int, default=1000,
                   help="compensated program number = program_id + this (default 1000)")
    s.add_argument("--program-range", default="1000-7999", metavar="LOW-HIGH",
                   help="numbers the compensated programs may take (default 1000-7999); a "
                        "START whose number falls outside is refused, never wrapped")
    s.add_argument("--machine", default="robonano-a0ib",
                   help="machine preset or TOML for the NC transform")
    s.add_argument("--measure-timeout", type=float, default=300.0,
                   help="fault MEASURE_TIMEOUT after this many s (default 300)")
    s.add_argument("--limit-mm", type=float, default=0.5, help="go/no-go limit |dx|,|dy|,|dz|")
    s.add_argument("--limit-deg", type=float, default=0.5, help="go/no-go limit |a|,|b|,|c|")
    s.add_argument("-v", "--verbose", action="store_true", help="log every state change")
    # benchmarks only: measures what the journal's fsync costs; loses the guarantee
    s.add_argument("--no-fsync", action="store_true", help=argparse.SUPPRESS)


def _load_measure(spec: str, field: str = "--measure"):
    mod, _, name = spec.partition(":")
    if not mod or not name:
        raise InputError(f"expected MODULE:CALLABLE, got {spec!r}", field=field)
    try:
        fn = getattr(importlib.import_module(mod), name)
    except (ImportError, AttributeError) as exc:
        raise InputError(f"cannot load {spec}: {exc}", field=field) from None
    if not callable(fn):
        raise InputError(f"{spec} is not callable", field=field)
    return fn


def _program_range(text: str) -> tuple[int, int]:
    lo, sep, hi = text.partition("-")
    try:
        rng = (int(lo), int(hi))
    except ValueError:
        raise InputError(f"expected LOW-HIGH (e.g. 1000-7999), got {text!r}",
                         field="--program-range") from None
    if not sep:
        raise InputError(f"expected LOW-HIGH, got {text!r}", field="--program-range")
    return rng


def build(args):
    """The measurement step and the cycle configuration the options describe."""
    from .cycle import CellConfig
    from .virtual import VirtualCell
    if not args.clearance >= 0:
        raise InputError(f"expected a clearance >= 0 mm, got {args.clearance}", field="--clearance")
    check = _load_measure(args.program_check, "--program-check") if args.program_check else None
    if args.measure:
        measure = _load_measure(args.measure)
    elif args.probe_inbox:
        if not args.plan:
            raise InputError("--probe-inbox needs --plan (the bowl plan TOML)", field="--plan")
        from .virtual import ProbeFileCell
        measure = ProbeFileCell(args.probe_inbox, args.plan, probe_sigma_mm=args.probe_sigma,
                                wait_s=args.measure_timeout, nc_dir=args.nc_dir,
                                out_dir=args.out_dir, machine=args.machine, program_check=check,
                                clearance=args.clearance)
    else:
        measure = VirtualCell(seed=args.seed, probe_time_s=args.probe_time, nc_dir=args.nc_dir,
                              out_dir=args.out_dir, machine=args.machine, program_check=check,
                              clearance=args.clearance)
    try:
        cfg = CellConfig(word_order=args.word_order, measure_timeout_s=args.measure_timeout,
                         limit_mm=args.limit_mm, limit_deg=args.limit_deg,
                         fsync=not args.no_fsync, program_offset=args.program_offset,
                         program_range=_program_range(args.program_range), program_check=check)
    except ValueError as exc:
        raise InputError(str(exc), field="--program-range") from None
    return measure, cfg


def _serve(args) -> int:
    import asyncio
    import logging
    import signal
    import sys
    from pathlib import Path
    from .cycle import Cycle
    from .server import LOOPBACK, CellServer, is_loopback_host, parse_allow
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING,
                        format="%(asctime)s %(name)s %(levelname)s %(message)s")
    port = args.plc_port if args.cell_command == "client" else args.port
    if not 0 <= port <= 65535:
        raise InputError(f"port {port} outside 0..65535", field="--port")
    if not 0 <= args.unit_id <= 255:
        raise InputError(f"unit id {args.unit_id} outside 0..255", field="--unit-id")
    for opt, d in (("--nc-dir", args.nc_dir), ("--out-dir", args.out_dir)):
        if d is not None and not Path(d).is_dir():
            raise InputError("directory does not exist", d, field=opt)
    allow = LOOPBACK
    if args.cell_command == "serve":
        if args.allow:
            allow = parse_allow(args.allow)
        if not is_loopback_host(args.host):
            print(f"mtcomp cell: warning: listening on {args.host}, not loopback: Modbus has no "
                  f"authentication; writes are accepted only from "
                  f"{', '.join(map(str, parse_allow(allow)))}"
                  + ("" if args.allow else " (give the PLC's address with --allow)"),
                  file=sys.stderr, flush=True)
    measure, cfg = build(args)

    async def main():
        try:
            cycle = Cycle(args.journal, measure, cfg)
        except OSError as exc:
            raise InputError(f"cannot use the journal: {exc}", args.journal) from None
        if args.cell_command == "client":
            from .client import CellClient
            server = await CellClient(cycle, args.plc_host, args.plc_port, args.base,
                                      args.poll, device_id=args.unit_id).start()
            print(f"mtcomp cell: polling the PLC at {args.plc_host}:{args.plc_port} from "
                  f"register {args.base}, journal {args.journal}", flush=True)
        else:
            server = CellServer(cycle, args.host, args.port, args.unit_id, allow)
            try:
                await server.start()
            except (OSError, RuntimeError) as exc:
                raise InputError(f"cannot listen on {args.host}:{args.port}: {exc}",
                                 field="--port") from None
            print(f"mtcomp cell: serving on {args.host}:{server.port}, journal {args.journal}",
                  flush=True)
        if not args.measure and not args.nc_dir:
            print("mtcomp cell: no --nc-dir: no compensated programs are written, so every "
                  "result is a NO-GO (nogo bit NO_PROGRAM)", flush=True)
        stop = asyncio.Event()
        loop = asyncio.get_running_loop()
        for sig in (signal.SIGINT, signal.SIGTERM):
            loop.add_signal_handler(sig, stop.set)
        await stop.wait()
        await server.stop()

    asyncio.run(main())
    return 0


def _map(args) -> int:
    import sys
    from .._io import atomic_write
    from .registers import register_map_csv, register_map_json
    text = (register_map_json if args.format == "json" else register_map_csv)(args.word_order)
    if args.output:
        atomic_write(args.output, text)
    else:
        sys.stdout.write(text)
    return 0


def _plc_sim(args) -> int:
    import asyncio
    from .plcsim import PlcSim

    from .registers import Fault, NoGo

    def fault_text(code: int) -> str:
        try:
            return f"fault {code} {Fault(code).name}"
        except ValueError:
            return f"fault {code}"

    def nogo_text(bits: int) -> str:
        names = [b.name for b in NoGo if bits & b]
        return f" ({', '.join(names) or bits})" if bits else ""

    seen = {"results": 0, "faults": 0}

    def show(i, rep):
        if len(rep.results) > seen["results"]:
            r = rep.results[-1]
            pose = " ".join(f"{v:+.6f}" for v in r.pose)
            prog = f"program O{r.program_id:04d}" if r.program_id else "no program"
            print(f"cycle {i}: result {r.result_seq} part {r.part_id} {prog} "
                  f"{'GO' if r.go else 'NO-GO' + nogo_text(r.nogo)} pose {pose}", flush=True)
        elif len(rep.faults) > seen["faults"]:
            part, code = rep.faults[-1]
            print(f"cycle {i}: no result for part {part}: {fault_text(code)}"
                  f"{' (see the journal for why)' if code else ''}", flush=True)
        else:
            print(f"cycle {i}: no result", flush=True)
        seen["results"], seen["faults"] = len(rep.results), len(rep.faults)

    plc = PlcSim(args.host, args.port, word_order=args.word_order,
                 first_part_id=args.first_part_id, program_id=args.program_id,
                 disconnect_prob=args.disconnect_prob, seed=args.seed, poll_s=args.poll,
                 device_id=args.unit_id)
    rep = asyncio.run(plc.run(args.cycles, show))
    print(rep.summary())
    for status, n in sorted(_count(rep.rejected).items()):
        print(f"  command {status[0]} refused {n} time(s): {status[1]}")
    return 0 if rep.duplicates == 0 and len(rep.results) == rep.cycles else 1


def _count(items) -> dict:
    out: dict = {}
    for it in items:
        out[it] = out.get(it, 0) + 1
    return out


def main(argv=None) -> int:
    """Stand-alone entry (``python -m mtcomp.cell.cli serve ...``), same as ``mtcomp cell``."""
    import sys
    from .._io import MtcompError
    parser = argparse.ArgumentParser(prog="mtcomp")
    register(parser.add_subparsers(dest="command"))
    args = parser.parse_args(["cell", *(sys.argv[1:] if argv is None else argv)])
    try:
        return int(args.func(args) or 0)
    except MtcompError as exc:
        print(f"mtcomp cell: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    raise SystemExit(main())
