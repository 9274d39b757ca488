"""Append-only, fsync'ed journal of the cell: the single source of truth across restarts.

One JSON object per line (UTF-8, ``\\n``-terminated), written with ``write`` + ``fsync`` before
the effect becomes visible to the PLC (the Modbus response to a command, or the result in the
registers). Every record has ``n`` (1, 2, 3, ... without gaps), ``t`` (UTC, ISO 8601) and
``ev`` (the event); see docs/cell.md for the events and their fields.

Recovery: a crash can leave at most one torn record: the end of the file without its final
newline (each record goes out in one write with its newline last). It was never fsync'ed to
completion, so nothing depended on it; `Journal.open` cuts it off and logs a warning. Anything
else that is not a valid record, also a complete last line, is damage and reported as an
InputError naming the line and field: the journal is never "repaired" beyond a torn tail.
"""
from __future__ import annotations

import json
import logging
import os
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path

from .._io import InputError, MtcompError

log = logging.getLogger("mtcomp.cell")

EVENTS = ("boot", "command", "start", "phase", "result", "ack", "fault", "reset", "abort",
          "revoke")


class Journal:
    """An open journal file. `append` returns only after the record is on disk (if `fsync`)."""

    def __init__(self, path: Path, fd: int, records: list[dict], fsync: bool = True):
        self.path, self._fd, self.records, self.fsync = path, fd, records, fsync
        self.n = records[-1]["n"] if records else 0

    @classmethod
    def open(cls, path: str | os.PathLike, fsync: bool = True) -> "Journal":
        """Open (creating if needed) and read `path`; a torn last record is cut off."""
        path = Path(path)  # the directory must exist: a mistyped path is an error, not a new tree
        fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            _lock(fd, path)
            records, keep = read_records(path)
        except BaseException:
            os.close(fd)
            raise
        if keep is not None:
            os.ftruncate(fd, keep)
            os.fsync(fd)
        os.lseek(fd, 0, os.SEEK_END)
        return cls(path, fd, records, fsync)

    def append(self, ev: str, **data) -> dict:
        """Write one record durably and return it. Raises OSError if the disk refuses."""
        if ev not in EVENTS:
            raise ValueError(f"unknown journal event {ev!r}")
        rec = {"n": self.n + 1, "t": datetime.now(timezone.utc).isoformat(timespec="microseconds"),
               "ev": ev, **data}
        line = (json.dumps(rec, separators=(",", ":"), allow_nan=False) + "\n").encode()
        # One write of the whole line: a crash leaves either the full record or a torn tail.
        written = os.write(self._fd, line)
        if written != len(line):
            raise OSError(f"short write to {self.path}")
        if self.fsync:
            os.fsync(self._fd)
        self.n += 1
        self.records.append(rec)
        return rec

    def close(self) -> None:
        if self._fd >= 0:
            os.close(self._fd)
            self._fd = -1

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def _lock(fd: int, path: Path) -> None:
    """One writer per journal: a second mtcomp on the same file would interleave records.
    The lock (flock, POSIX) goes away with the process, also when it is killed."""
    try:
        import fcntl
    except ImportError:  # not POSIX: no lock
        return
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        raise MtcompError(f"journal {path} is in use by another mtcomp cell process") from None


def read_records(path: str | os.PathLike) -> tuple[list[dict], int | None]:
    """Parse a journal. Returns (records, keep) where `keep` is the byte length to truncate to
    if the last record is torn (None if the file is intact). A torn tail is skipped (it never
    took effect); truncating it is the caller's choice (`Journal.open` does).
    """
    path = Path(path)
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        return [], None
    records: list[dict] = []
    pos, lineno, keep = 0, 0, None
    while pos < len(data):
        end = data.find(b"\n", pos)
        lineno += 1
        last = end < 0 or end == len(data) - 1
        raw = data[pos:] if end < 0 else data[pos:end]
        if end < 0:  # the only tear a crash can leave: the record's own newline never made it
            keep = pos
            log.warning("%s:%d: torn last journal record dropped (%d bytes without their "
                        "newline)", path, lineno, len(raw))
            break
        try:
            rec = json.loads(raw.decode("utf-8"))
        except ValueError as exc:  # JSONDecodeError and UnicodeDecodeError are ValueErrors
            what = "last line" if last else "line"
            raise InputError(f"damaged journal record ({what} complete, so not a torn write: "
                             f"{exc}); restore the journal from a backup or remove the line by "
                             f"hand", path, lineno) from None
        check_record(rec, path, lineno)
        expected = records[-1]["n"] + 1 if records else 1
        if rec["n"] != expected:
            raise InputError(f"record number {rec['n']}, expected {expected}", path, lineno,
                             "n")
        records.append(rec)
        pos = end + 1
    return records, keep


def _is_int(v) -> bool:
    return isinstance(v, int) and not isinstance(v, bool)


def _is_num(v) -> bool:
    import math
    return (isinstance(v, (int, float)) and not isinstance(v, bool)
            and math.isfinite(v))


_JOB = {"job_no": _is_int, "part_id": _is_int, "program_id": _is_int}
_SIX = (lambda v: isinstance(v, list) and len(v) == 6 and all(map(_is_num, v)),
        "a list of 6 finite numbers")
_INT = (_is_int, "an integer")
# required fields per event, with their check and what the check expects
_SCHEMA = {
    "boot": {"state": (lambda v: v in ("idle", "busy", "ready", "fault"),
                       "idle, busy, ready or fault"), "result_seq": _INT},
    "command": {"cmd_seq": _INT, "command": _INT, "status": _INT},
    "start": {"cmd_seq": _INT, "job": (lambda v: _job_ok(v), "a job {job_no, part_id, "
                                                            "program_id} of integers")},
    "phase": {},
    "result": {"result_seq": _INT, "job": (lambda v: _job_ok(v), "a job {job_no, part_id, "
                                                                "program_id} of integers"),
               "pose": _SIX, "sigma": _SIX, "program_id": _INT,
               "go": (lambda v: isinstance(v, bool), "true or false")},
    "ack": {"cmd_seq": _INT, "result_seq": _INT},
    "fault": {"code": _INT},
    "reset": {"cmd_seq": _INT},
    "abort": {"cmd_seq": _INT},
    "revoke": {"result_seq": _INT, "nogo": _INT},
}


def _job_ok(v) -> bool:
    return isinstance(v, dict) and all(k in v and f(v[k]) for k, f in _JOB.items())


def check_record(rec, path, lineno: int) -> None:
    """Raise InputError naming the line and field unless `rec` is a well-formed record."""
    if not isinstance(rec, dict):
        raise InputError("not a journal record (expected a JSON object)", path, lineno)
    if not _is_int(rec.get("n")) or rec["n"] < 1:
        raise InputError("missing or not a positive integer", path, lineno, "n")
    ev = rec.get("ev")
    if not isinstance(ev, str) or ev not in _SCHEMA:   # a list or object is unhashable
        raise InputError(f"unknown event {ev!r}, expected one of {', '.join(EVENTS)}", path,
                         lineno, "ev")
    if not isinstance(rec.get("t"), str):
        raise InputError("missing or not a time stamp", path, lineno, "t")
    for name, (ok, what) in _SCHEMA[ev].items():
        if name not in rec:
            raise InputError(f"{ev} record without {name!r}", path, lineno, name)
        if not ok(rec[name]):
            raise InputError(f"{ev} record: expected {what}, got {rec[name]!r}", path, lineno,
                             name)


@dataclass
class Recovered:
    """What the journal says about the cell: the state to resume from after a restart."""
    state: str = "idle"               # idle | busy | ready | fault
    job: dict | None = None           # the running job (busy) or the job of the result (ready)
    result: dict | None = None        # the presented, not yet acknowledged result (ready)
    fault: int = 0
    last_result: dict | None = None   # the last result ever journaled (acknowledged or not)
    cmd_seq: int = 0                  # command_seq of the last command handled
    cmd_status: int = 0
    job_no: int = 0                   # highest job number used
    result_seq: int = 0               # highest result sequence number used
    results: list[dict] = field(default_factory=list)
    acked: set = field(default_factory=set)


def replay(records: list[dict]) -> Recovered:
    """Fold the records into the cell's state (pure function of the journal)."""
    r = Recovered()
    for rec in records:
        ev = rec["ev"]
        if "cmd_seq" in rec:  # every command the PLC sent, accepted or rejected
            r.cmd_seq, r.cmd_status = rec["cmd_seq"], rec.get("status", 0)
        if ev == "start":
            r.state, r.job, r.result, r.fault = "busy", rec["job"], None, 0
            r.job_no = max(r.job_no, rec["job"]["job_no"])
        elif ev == "result":
            r.state, r.result, r.last_result = "ready", rec, rec
            r.result_seq = max(r.result_seq, rec["result_seq"])
            r.results.append(rec)
        elif ev == "revoke":  # a presented GO whose program failed its check at a restart
            def revoked(res):
                if res is None or res["result_seq"] != rec["result_seq"]:
                    return res
                return {**res, "go": False, "nogo": res.get("nogo", 0) | rec["nogo"]}
            r.result, r.last_result = revoked(r.result), revoked(r.last_result)
        elif ev == "ack":
            r.acked.add(rec["result_seq"])
            r.state, r.result, r.job = "idle", None, None
        elif ev == "fault":
            r.state, r.fault, r.result, r.job = "fault", rec["code"], None, None
        elif ev in ("reset", "abort"):
            r.state, r.fault, r.job, r.result = "idle", 0, None, None
    return r
