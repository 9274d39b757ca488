"""The compensated part program of one blank: numbered, written, verified, owned.

The cell never lets the PLC start a program it has not written and verified for the blank on
the machine (docs/cell.md, "Compensated programs"). This module holds the rules:

* numbering: the compensated program is ``program_id + offset``, which must fall in the shop's
  range for such programs (never wrapped into it): `target_number`;
* ownership: every program the cell writes carries a marker comment naming the output and
  source programs, the part id, the job number and a SHA-256 of the rest of the file. A file is
  replaced only if it is absent or carries an intact marker (the cell wrote it and nobody has
  edited it since); a shop program, or a cell program edited by hand, is never overwritten;
* writing: temporary file in the target directory, fsync, verification of the bytes on disk,
  then a rename that cannot clobber a file that appeared meanwhile;
* verification (`verify_program_bytes`): the marker is intact and names this blank, the text
  parses, and every block end point and arc sample lies within the machine's travel. A further
  check (for instance a gouge simulation) plugs in as ``extra_check(machine, path, text)``.

Failures are `CellFault`s carrying the fault code the PLC reads; nothing here ends in a
traceback.
"""
from __future__ import annotations

import hashlib
import os
import re
import tempfile
import zlib
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Callable

from .._io import MtcompError
from .registers import Fault

DEFAULT_OFFSET = 1000
# O8000-O9999 are the edit-protected ranges of Fanuc controls (macros, maker programs): the
# cell writes below them unless told otherwise
DEFAULT_RANGE = (1000, 7999)
MAX_PROGRAM = 9999

_MARK = re.compile(rb"\(MTCOMP-CELL O(\d{4,5}) FROM O(\d{4,5}) PART (\d+) JOB (\d+) "
                   rb"BODY ([0-9A-F]{16})\)\r?\n?")
_PROGRAM_WORD = re.compile(rb"^([ \t]*)[O:](\d+)")


class CellFault(MtcompError):
    """A measurement step's refusal with the fault code the PLC gets (registers.Fault)."""

    def __init__(self, code: Fault, what: str):
        self.code = Fault(code)
        super().__init__(what)


@dataclass(frozen=True)
class ProgramInfo:
    """A compensated program as written and verified: file path, program numbers, the blank it
    belongs to (part id, job number), checksums of the whole file (SHA-256 hex, CRC-32 as in
    zlib / IEEE 802.3), its size in bytes, its motion blocks and the machine it was checked on."""
    path: str
    program_id: int
    source_id: int
    part_id: int
    job_no: int
    sha256: str
    crc32: int
    size: int
    blocks: int
    machine: str
    machine_model: object = field(default=None, compare=False, repr=False)  # for `recheck`

    def to_dict(self) -> dict:
        d = {f.name: getattr(self, f.name) for f in fields(self) if f.name != "machine_model"}
        d["file"] = Path(self.path).name
        return d


@dataclass(frozen=True)
class Marker:
    program_id: int
    source_id: int
    part_id: int
    job_no: int


def program_file_name(program_id: int) -> str:
    """File name of program `program_id`: ``O`` and at least four digits (O0100.nc)."""
    return f"O{int(program_id):04d}.nc"


def target_number(program_id: int, offset: int = DEFAULT_OFFSET,
                  program_range: tuple[int, int] = DEFAULT_RANGE) -> int | None:
    """Number of the compensated program of part program `program_id`, or None when
    ``program_id + offset`` is not inside `program_range` (inclusive): numbers never wrap."""
    out = int(program_id) + int(offset)
    lo, hi = program_range
    return out if 0 < int(program_id) and lo <= out <= hi else None


def check_numbering(offset: int, program_range: tuple[int, int]) -> None:
    """Raise ValueError unless the offset and the range can be used at all."""
    lo, hi = (int(v) for v in program_range)
    if not 1 <= lo <= hi <= MAX_PROGRAM:
        raise ValueError(f"program range {lo}-{hi}: need 1 <= low <= high <= {MAX_PROGRAM}")
    if not 1 <= int(offset) < hi:
        raise ValueError(f"program offset {offset}: need 1 <= offset < {hi} (top of the range)")


def _body_hash(body: bytes) -> str:
    return hashlib.sha256(body).hexdigest()[:16].upper()


def read_marker(data: bytes) -> Marker | None:
    """The cell's marker of a program file's bytes, or None if there is none or the rest of the
    file no longer matches it (edited since the cell wrote it)."""
    end = 0
    for _ in range(4):  # the marker follows at most "%", the program number and one blank line
        k = data.find(b"\n", end)
        end = len(data) if k < 0 else k + 1
        if k < 0:
            break
    m = _MARK.search(data, 0, end)
    if m is None or (m.start() and data[m.start() - 1:m.start()] != b"\n"):
        return None
    body = data[:m.start()] + data[m.end():]
    if _body_hash(body) != m.group(5).decode():
        return None
    return Marker(*(int(m.group(i)) for i in range(1, 5)))


def _with_marker(text: str, out_id: int, src_id: int, part_id: int, job_no: int) -> bytes:
    """Renumber the program word (O0100 -> O1100: a control that takes the number from the file
    must not load it over the part program) and insert the marker line after it."""
    data = text.encode("utf-8", "surrogateescape")
    lines = re.findall(rb"[^\n]*\n|[^\n]+\Z", data)   # LF only, as read_marker counts
    at = 0
    for i, ln in enumerate(lines[:3]):
        s = ln.strip()
        if s == b"%" or not s:
            at = i + 1
            continue
        m = _PROGRAM_WORD.match(ln)
        if m:
            lines[i] = m.group(1) + b"O" + f"{out_id:04d}".encode() + ln[m.end():]
            at = i + 1
        break
    eol = b"\r\n" if lines and lines[0].endswith(b"\r\n") else b"\n"
    if at and not lines[at - 1].endswith(b"\n"):
        lines[at - 1] += eol
    body = b"".join(lines)
    mark = (f"(MTCOMP-CELL O{out_id:04d} FROM O{src_id:04d} PART {part_id} JOB {job_no} "
            f"BODY {_body_hash(body)})").encode() + eol
    return b"".join(lines[:at]) + mark + b"".join(lines[at:])


def owned_by_cell(path: Path) -> Marker | None:
    """The marker of an existing file the cell may replace, else None."""
    try:
        with open(path, "rb") as fh:
            return read_marker(fh.read())
    except OSError:
        return None


def verify_program_bytes(data: bytes, machine, *, name: str, out_id: int, part_id: int,
                         job_no: int, min_blocks: int = 1,
                         extra_check: Callable | None = None, path=None) -> int:
    """Check a compensated program's bytes; return its motion blocks. Raises CellFault
    (PROGRAM_FAILED) naming `name` and what is wrong."""
    import numpy as np

    from .. import gcode
    from .._io import InputError
    from ..kinematics import LimitError, check_limits
    mark = read_marker(data)
    if mark is None:
        raise CellFault(Fault.PROGRAM_FAILED, f"{name}: no intact mtcomp cell marker (changed "
                                              f"after it was written?)")
    if (mark.program_id, mark.part_id, mark.job_no) != (out_id, part_id, job_no):
        raise CellFault(Fault.PROGRAM_FAILED,
                        f"{name} belongs to O{mark.program_id:04d}, part {mark.part_id}, job "
                        f"{mark.job_no}, not to O{out_id:04d}, part {part_id}, job {job_no}")
    try:
        text = data.decode("utf-8")
        prog = gcode.parse(text, axes=machine.axis_names, filename=name)
    except UnicodeDecodeError as exc:
        raise CellFault(Fault.PROGRAM_FAILED, f"{name}: not UTF-8 text ({exc.reason})") from None
    except InputError as exc:
        raise CellFault(Fault.PROGRAM_FAILED, f"written program does not parse: {exc}") from None
    if len(prog) < min_blocks:
        raise CellFault(Fault.PROGRAM_FAILED, f"{name}: {len(prog)} motion blocks, the part "
                                              f"program has {min_blocks}")
    q = np.asarray(prog.position, float)
    pts = np.vstack([q, _arc_samples(prog, machine)]) if len(q) else q
    try:
        if not np.all(np.isfinite(pts)):
            raise CellFault(Fault.PROGRAM_FAILED, f"{name}: non-finite axis positions")
        check_limits(machine, pts)
    except LimitError as exc:
        k = exc.index if exc.index < len(q) else None
        where = f"line {int(prog.line[k])}" if k is not None else "an arc"
        raise CellFault(Fault.PROGRAM_FAILED, f"{name} {where}: {exc}".replace(
            f" (point {exc.index})", "")) from None
    if extra_check is not None:
        try:
            extra_check(machine, path, text)
        except MtcompError as exc:
            raise CellFault(Fault.PROGRAM_FAILED, f"{name}: {exc}") from None
    return len(prog)


def _arc_samples(prog, machine, n: int = 33):
    """Axis positions along every arc (33 per arc) so that an arc bulging out of the travel
    between two end points inside it is caught."""
    import numpy as np
    names = list(machine.axis_names)
    q = np.asarray(prog.position, float)
    arcs = np.flatnonzero(prog.is_arc)
    if not arcs.size or not all(a in names for a in "XYZ"):
        return np.empty((0, q.shape[1]))
    xyz = [names.index(a) for a in "XYZ"]
    out = []
    t = np.linspace(0.0, 1.0, n)
    for k in arcs:
        prev = q[k - 1] if k else np.asarray(prog.start, float)
        cu, cv, cw = {17: (0, 1, 2), 18: (2, 0, 1), 19: (1, 2, 0)}[int(prog.plane[k])]
        c = np.asarray(prog.arc_centre[k], float)
        sweep = float(prog.arc_sweep[k])
        if not np.isfinite(sweep) or not np.all(np.isfinite(c)):
            continue
        u0, v0 = prev[xyz[cu]] - c[cu], prev[xyz[cv]] - c[cv]
        r, a0 = np.hypot(u0, v0), np.arctan2(v0, u0)
        s = np.repeat(prev[None], n, 0) + t[:, None] * (q[k] - prev)[None]   # other axes linear
        s[:, xyz[cu]] = c[cu] + r * np.cos(a0 + sweep * t)
        s[:, xyz[cv]] = c[cv] + r * np.sin(a0 + sweep * t)
        out.append(s)
    return np.vstack(out) if out else np.empty((0, q.shape[1]))


def file_checksums(data: bytes) -> tuple[str, int]:
    return hashlib.sha256(data).hexdigest(), zlib.crc32(data) & 0xFFFFFFFF


def write_program(machine, source: Path, target: Path, pose, *, source_id: int, out_id: int,
                  part_id: int, job_no: int, mode: str = "auto",
                  extra_check: Callable | None = None) -> ProgramInfo:
    """Compensate part program `source` for the blank at `pose` (a WorkpieceSetting) into
    `target`: refuse what must not be touched, verify the bytes before they get the final name.

    Fault codes: PROGRAM_MISSING (source or a directory missing), PROGRAM_EXISTS (target is not
    the cell's to replace), PROGRAM_FAILED (cannot compensate, write or verify)."""
    from .. import gcode
    from .._io import InputError
    from ..setting.workpiece import compensate_text
    source, target = Path(source), Path(target)
    for d, what in ((source.parent, "NC program directory"), (target.parent, "output directory")):
        if not d.is_dir():
            raise CellFault(Fault.PROGRAM_MISSING, f"{what} {d} does not exist")
    if not source.is_file():
        raise CellFault(Fault.PROGRAM_MISSING, f"part program {source} does not exist")
    try:
        text = gcode.read_program(source)
    except (InputError, OSError) as exc:
        raise CellFault(Fault.PROGRAM_MISSING, f"cannot read the part program: {exc}") from None
    mark = read_marker(text.encode("utf-8", "surrogateescape"))
    if mark is not None:
        raise CellFault(Fault.PROGRAM_FAILED,
                        f"{source} is itself a compensated program (the cell wrote it for part "
                        f"{mark.part_id}): compensate the part program, not its output")
    from ..gcode.provenance import check_nc_write
    try:
        check_nc_write(text, filename=str(source), output=target, inputs=(source,))
    except InputError as exc:
        raise CellFault(Fault.PROGRAM_FAILED, f"{exc}") from None
    _check_replaceable(target, out_id)
    try:
        new, n_src = compensate_text(machine, text, pose, filename=str(source), mode=mode)
    except MtcompError as exc:
        raise CellFault(Fault.PROGRAM_FAILED, f"cannot compensate for this blank: {exc}") from None
    data = _with_marker(new, out_id, source_id, part_id, job_no)
    # By hand, not _io.atomic_write: that one replaces whatever is there, and a file that
    # appears between the ownership check and the rename must not be clobbered.
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".tmp", dir=target.parent)
    except OSError as exc:
        raise CellFault(Fault.PROGRAM_FAILED, f"cannot write in {target.parent}: {exc}") from None
    tmp = Path(tmp)
    try:
        try:
            with os.fdopen(fd, "wb") as fh:
                fh.write(data)
                fh.flush()
                os.fsync(fh.fileno())
            os.chmod(tmp, 0o644)
            on_disk = tmp.read_bytes()     # verify what the disk holds, not what we meant
        except OSError as exc:
            raise CellFault(Fault.PROGRAM_FAILED, f"cannot write {target}: {exc}") from None
        blocks = verify_program_bytes(on_disk, machine, name=target.name, out_id=out_id,
                                      part_id=part_id, job_no=job_no, min_blocks=n_src,
                                      extra_check=extra_check, path=tmp)
        _place(tmp, target, out_id)
    finally:
        try:
            tmp.unlink()
        except FileNotFoundError:
            pass
    sha, crc = file_checksums(on_disk)
    return ProgramInfo(str(target), out_id, source_id, part_id, job_no, sha, crc, len(on_disk),
                       blocks, machine.name, machine)


def _check_replaceable(target: Path, out_id: int) -> None:
    """Absent, or the cell's own intact program of this number (not a copy of another)."""
    if target.is_dir():
        raise CellFault(Fault.PROGRAM_EXISTS, f"{target} is a directory")
    mark = owned_by_cell(target) if target.exists() else None
    if target.exists() and (mark is None or mark.program_id != out_id):
        raise CellFault(Fault.PROGRAM_EXISTS,
                        f"{target} exists and was not written by the mtcomp cell (or was edited "
                        f"since): it is never overwritten; move it or choose another program "
                        f"range")


def _place(tmp: Path, target: Path, out_id: int) -> None:
    """Give the verified file its name: link (fails if a file appeared) when the target is
    absent, rename over it only when it is the cell's own."""
    try:
        if target.exists():
            _check_replaceable(target, out_id)
            os.replace(tmp, target)
        else:
            try:
                os.link(tmp, target)
            except FileExistsError:
                _check_replaceable(target, out_id)
                os.replace(tmp, target)
        dfd = os.open(target.parent, os.O_RDONLY)
        try:
            os.fsync(dfd)
        finally:
            os.close(dfd)
    except OSError as exc:
        raise CellFault(Fault.PROGRAM_FAILED, f"cannot write {target}: {exc}") from None


def recheck(info: ProgramInfo, machine=None, extra_check: Callable | None = None) -> str | None:
    """Re-verify a program right before its result is published: the file on disk is the one
    written (same SHA-256), its marker names this blank, it parses and stays in the travel.
    Returns None if it holds, else the reason (for the journal)."""
    from ..machine import load_machine
    path = Path(info.path)
    try:
        data = path.read_bytes()
    except OSError as exc:
        return f"{path.name} cannot be read: {exc.strerror or exc}"
    if file_checksums(data)[0] != info.sha256:
        return f"{path.name} changed after it was verified"
    try:
        m = machine if machine is not None else (info.machine_model or load_machine(info.machine))
        verify_program_bytes(data, m, name=path.name, out_id=info.program_id,
                             part_id=info.part_id, job_no=info.job_no, min_blocks=1,
                             extra_check=extra_check, path=path)
    except MtcompError as exc:
        return str(exc)
    return None
