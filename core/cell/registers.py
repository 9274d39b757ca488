"""The cell's Modbus register map, as data, and the codecs for its multi-register values.

Everything is a holding register (16 bit). Addresses are the zero-based protocol addresses
that go on the wire (the PLC's "40001" is address 0). The map has two blocks:

* PLC -> mtcomp, addresses 0..8: written by the PLC (function codes 6 and 16). A write that
  touches any other address is refused with Modbus exception 02 (ILLEGAL DATA ADDRESS); a value
  outside the field's range is refused with exception 03 (ILLEGAL DATA VALUE).
* mtcomp -> PLC, addresses 16..56: read-only for every client; the PLC reads the whole block
  with one function-3 request so that it always sees one consistent snapshot.

32-bit values span two registers. Their word order is configurable ("big": high word at the
lower address, ABCD; "little": low word first, CDAB, as many PLCs store REALs) and is reported
in register ``word_order`` so that an integrator can check the setting from the PLC side. Bytes
within a register are always big-endian, as Modbus requires.
"""
from __future__ import annotations

import struct
from dataclasses import dataclass
from enum import IntEnum

WORD_ORDERS = ("big", "little")
MAP_VERSION = 2


class State(IntEnum):
    """Cell states as reported in register ``state``."""
    IDLE = 0        # waiting for a blank and a START command
    MEASURING = 1   # probing the blank (on a real machine: waiting for the NC's probe file)
    COMPUTING = 2   # bowl fit, frame, compensated program being written
    READY = 3       # a result is presented and waits for the PLC's acknowledge
    FAULT = 4       # the cycle stopped; ``fault_code`` says why, RESET returns to IDLE


class Command(IntEnum):
    """Commands the PLC writes into ``command`` (executed when ``command_seq`` changes)."""
    NONE = 0
    START = 1   # blank is loaded and clamped: measure it
    ACK = 2     # result ``ack_seq`` has been taken over by the PLC
    RESET = 3   # leave FAULT (or abort a running measurement) and return to IDLE


class CommandStatus(IntEnum):
    """Outcome of the last command, in ``cmd_status`` (valid once ``cmd_seq_echo`` matches)."""
    OK = 0
    NOT_ALLOWED = 1        # command not allowed in the current state
    BLANK_NOT_LOADED = 2   # START while ``blank_loaded`` is 0
    BAD_ACK_SEQ = 3        # ACK for a result sequence number that is not the one presented
    BAD_PROGRAM_ID = 4     # START with program id 0, or its compensated number out of range
    JOURNAL_DOWN = 5       # the journal cannot be written: nothing is accepted
    NOT_READ = 6           # ACK from a connection that has not read the presented result
    NOT_OWNER = 7          # ACK from another connection than the one that started the job,
                           # while that one is still open


class Fault(IntEnum):
    """Fault codes in ``fault_code`` (state FAULT)."""
    NONE = 0
    MEASURE_TIMEOUT = 1   # probing + computation exceeded the configured timeout
    MEASURE_FAILED = 2    # the measurement step raised (missing probe file, fit failed, ...)
    BAD_RESULT = 3        # the measurement step returned non-finite or malformed values
    BLANK_REMOVED = 4     # the PLC cleared ``blank_loaded`` while the blank was being measured
    JOURNAL_FAILED = 5    # the journal could not be written; no result can be guaranteed
    PROGRAM_MISSING = 6   # the part program, its directory or the output directory is missing
    PROGRAM_EXISTS = 7    # the target file is not the cell's to replace (never overwritten)
    PROGRAM_FAILED = 8    # the program could not be compensated, written or verified


class NoGo(IntEnum):
    """Bits of ``nogo``: why ``go`` is 0 (0 = go)."""
    LIMITS = 1           # workpiece setting outside --limit-mm / --limit-deg
    UNCERTAINTY = 2      # translation uncertainty above the limit
    STEP = 4             # the measurement step flagged the blank (e.g. bowl residual alarm)
    NO_PROGRAM = 8       # no compensated program was written (no --nc-dir)
    NOT_VERIFIED = 16    # the program on disk failed the check right before publishing


@dataclass(frozen=True)
class Field:
    """One value of the map: `kind` is u16, u32 or f32; `plc_writes` marks the PLC -> mtcomp block.

    `lo`/`hi` bound the values the PLC may write (inclusive); `unit` is for the docs.
    """
    name: str
    address: int
    kind: str
    plc_writes: bool
    doc: str
    unit: str = ""
    lo: int | None = None
    hi: int | None = None

    @property
    def size(self) -> int:
        return 1 if self.kind == "u16" else 2


POSE_NAMES = ("dx", "dy", "dz", "a", "b", "c")
POSE_UNITS = ("mm", "mm", "mm", "deg", "deg", "deg")

_FIELDS = [
    # PLC -> mtcomp
    Field("plc_heartbeat", 0, "u16", True, "PLC life counter (any value; shown for diagnosis)"),
    Field("command", 1, "u16", True, "0 none, 1 START, 2 ACK, 3 RESET", lo=0, hi=3),
    Field("command_seq", 2, "u16", True,
          "command sequence number: a command runs once, when this changes", lo=0, hi=65535),
    Field("blank_loaded", 3, "u16", True, "1 = robot has placed the blank and retracted",
          lo=0, hi=1),
    Field("part_id", 4, "u32", True, "part / blank id (echoed in the result)"),
    Field("program_id", 6, "u16", True, "NC program to compensate (1..9999, 0 = none)",
          lo=0, hi=9999),
    Field("ack_seq", 7, "u32", True, "result sequence number being acknowledged"),
    # mtcomp -> PLC
    Field("state", 16, "u16", False, "0 idle, 1 measuring, 2 computing, 3 ready, 4 fault"),
    Field("heartbeat", 17, "u16", False, "incremented every 100 ms while mtcomp runs"),
    Field("fault_code", 18, "u16", False, "see fault codes; 0 unless state is FAULT"),
    Field("cmd_seq_echo", 19, "u16", False, "command_seq of the last command handled"),
    Field("cmd_status", 20, "u16", False, "outcome of that command (0 = accepted)"),
    Field("result_seq", 21, "u32", False, "sequence number of the presented result, 0 = none"),
    Field("go", 23, "u16", False,
          "1 = go: run program_id_out, written and verified for this blank; 0 = no-go"),
    Field("part_id_out", 24, "u32", False, "part id the presented result belongs to"),
    Field("program_id_out", 26, "u16", False, "id of the compensated NC program"),
    Field("job_no", 27, "u16", False, "low 16 bits of the running/last job number"),
    *[Field(n, 28 + 2 * i, "f32", False, f"workpiece setting {n}", u)
      for i, (n, u) in enumerate(zip(POSE_NAMES, POSE_UNITS))],
    *[Field(f"s_{n}", 40 + 2 * i, "f32", False, f"standard uncertainty of {n} (1 sigma)", u)
      for i, (n, u) in enumerate(zip(POSE_NAMES, POSE_UNITS))],
    Field("word_order", 52, "u16", False, "0 = big (high word first), 1 = little"),
    Field("map_version", 53, "u16", False, f"register map version ({MAP_VERSION})"),
    Field("program_crc", 54, "u32", False, "CRC-32 of the compensated program file, 0 = none"),
    Field("nogo", 56, "u16", False, "why go is 0: bit mask of NoGo, 0 when go"),
]
FIELDS: dict[str, Field] = {f.name: f for f in _FIELDS}

PLC_BLOCK = (0, 9)          # [start, end) of the PLC-writable block
OUT_BLOCK = (16, 57)        # [start, end) of the mtcomp-written block
N_REGISTERS = OUT_BLOCK[1]  # addresses 0..56 exist; 9..15 read as 0 and are not writable


def encode_u32(value: int, word_order: str = "big") -> list[int]:
    """Two registers of an unsigned 32-bit integer."""
    hi, lo = (int(value) >> 16) & 0xFFFF, int(value) & 0xFFFF
    return [hi, lo] if _check_order(word_order) == "big" else [lo, hi]


def decode_u32(regs, word_order: str = "big") -> int:
    a, b = int(regs[0]), int(regs[1])
    return (a << 16 | b) if _check_order(word_order) == "big" else (b << 16 | a)


def encode_f32(value: float, word_order: str = "big") -> list[int]:
    """Two registers of an IEEE-754 binary32 value (rounded to nearest)."""
    hi, lo = struct.unpack(">HH", struct.pack(">f", float(value)))
    return [hi, lo] if _check_order(word_order) == "big" else [lo, hi]


def decode_f32(regs, word_order: str = "big") -> float:
    a, b = int(regs[0]), int(regs[1])
    hi, lo = (a, b) if _check_order(word_order) == "big" else (b, a)
    return struct.unpack(">f", struct.pack(">HH", hi, lo))[0]


def _check_order(word_order: str) -> str:
    if word_order not in WORD_ORDERS:
        raise ValueError(f"word order must be one of {WORD_ORDERS}, got {word_order!r}")
    return word_order


class RegisterImage:
    """The 57 registers as a plain list, with typed access by field name.

    Pure data: the Modbus server copies slices of `regs` into its responses, the cycle sets
    fields. Not thread-safe by itself; the server touches it only from its event loop.
    """

    def __init__(self, word_order: str = "big"):
        self.word_order = _check_order(word_order)
        self.regs = [0] * N_REGISTERS
        self.set("word_order", WORD_ORDERS.index(word_order))
        self.set("map_version", MAP_VERSION)

    def set(self, name: str, value) -> None:
        f = FIELDS[name]
        if f.kind == "u16":
            self.regs[f.address] = int(value) & 0xFFFF
        elif f.kind == "u32":
            self.regs[f.address:f.address + 2] = encode_u32(int(value) & 0xFFFFFFFF,
                                                            self.word_order)
        else:
            self.regs[f.address:f.address + 2] = encode_f32(value, self.word_order)

    def get(self, name: str):
        f = FIELDS[name]
        r = self.regs[f.address:f.address + f.size]
        if f.kind == "u16":
            return r[0]
        if f.kind == "u32":
            return decode_u32(r, self.word_order)
        return decode_f32(r, self.word_order)


def decode_outputs(regs, word_order: str = "big", start: int = OUT_BLOCK[0]) -> dict:
    """Decode a read of the mtcomp -> PLC block (registers from address `start`) into a dict.

    `pose` and `sigma` come back as tuples of six floats (mm, mm, mm, deg, deg, deg).
    """
    def val(name):
        f = FIELDS[name]
        r = regs[f.address - start:f.address - start + f.size]
        if f.kind == "u16":
            return int(r[0])
        return decode_u32(r, word_order) if f.kind == "u32" else decode_f32(r, word_order)
    out = {f.name: val(f.name) for f in _FIELDS
           if not f.plc_writes and f.kind != "f32"}
    out["pose"] = tuple(val(n) for n in POSE_NAMES)
    out["sigma"] = tuple(val(f"s_{n}") for n in POSE_NAMES)
    return out


def check_plc_write(address: int, values) -> tuple[int, str] | None:
    """Validate a PLC write of `values` starting at `address`.

    Returns None when the write is acceptable, else (Modbus exception code, reason):
    2 = ILLEGAL DATA ADDRESS (outside the PLC block), 3 = ILLEGAL DATA VALUE (out of range).
    Multi-register fields may be written partially (the PLC owns both words).
    """
    n = len(values)
    if n == 0 or address < PLC_BLOCK[0] or address + n > PLC_BLOCK[1]:
        return 2, (f"write to {address}..{address + n - 1}: the PLC may write only "
                   f"{PLC_BLOCK[0]}..{PLC_BLOCK[1] - 1}")
    for i, v in enumerate(values):
        v = int(v)
        a = address + i
        if not 0 <= v <= 0xFFFF:
            return 3, f"register {a}: {v} is not a 16-bit value"
        f = _FIELD_AT.get(a)
        if f is not None and f.kind == "u16" and (
                (f.lo is not None and v < f.lo) or (f.hi is not None and v > f.hi)):
            return 3, f"register {a} ({f.name}): {v} outside {f.lo}..{f.hi}"
    return None


_FIELD_AT = {f.address: f for f in _FIELDS}


# -- the map as a table for PLC programmers ----------------------------------------------------

MAP_COLUMNS = ("name", "address", "plc_address", "registers", "type", "iec_type", "access",
               "unit", "min", "max", "description")
_IEC = {"u16": "UINT", "u32": "UDINT", "f32": "REAL"}


def register_map(word_order: str = "big") -> list[dict]:
    """The register map, one row per field, from the table the server uses (`FIELDS`).

    `address` is the zero-based protocol address, `plc_address` the 4xxxx notation
    (40001 = address 0); `access` is "rw" for the PLC -> mtcomp block (the PLC writes it),
    "r" for the mtcomp -> PLC block; 32-bit values span `registers` = 2 in `word_order`."""
    _check_order(word_order)
    rows = []
    for f in _FIELDS:
        rng_lo = f.lo if f.lo is not None else (0 if f.kind != "f32" else None)
        rng_hi = f.hi if f.hi is not None else {"u16": 0xFFFF, "u32": 0xFFFFFFFF}.get(f.kind)
        rows.append({"name": f.name, "address": f.address, "plc_address": 40001 + f.address,
                     "registers": f.size, "type": f.kind, "iec_type": _IEC[f.kind],
                     "access": "rw" if f.plc_writes else "r", "unit": f.unit,
                     "min": rng_lo, "max": rng_hi, "description": f.doc})
    return rows


def _enum_table(enum) -> dict:
    return {m.name: int(m) for m in enum}


def register_map_json(word_order: str = "big") -> str:
    """The map as JSON: version, word order, blocks, fields and the codes of every enumeration."""
    import json
    doc = {"map_version": MAP_VERSION, "word_order": word_order,
           "byte_order": "big (Modbus)", "function_codes": {"read": [3, 4, 23], "write": [6, 16, 23]},
           "plc_block": {"start": PLC_BLOCK[0], "count": PLC_BLOCK[1] - PLC_BLOCK[0]},
           "out_block": {"start": OUT_BLOCK[0], "count": OUT_BLOCK[1] - OUT_BLOCK[0]},
           "fields": register_map(word_order),
           "enums": {"state": _enum_table(State), "command": _enum_table(Command),
                     "cmd_status": _enum_table(CommandStatus), "fault_code": _enum_table(Fault),
                     "nogo_bits": _enum_table(NoGo)}}
    return json.dumps(doc, indent=2) + "\n"


def register_map_csv(word_order: str = "big") -> str:
    """The map as CSV (one header row, then one row per field; empty cells for no limit)."""
    import csv
    import io
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=MAP_COLUMNS, lineterminator="\n")
    w.writeheader()
    for row in register_map(word_order):
        w.writerow({k: ("" if v is None else v) for k, v in row.items()})
    return buf.getvalue()
