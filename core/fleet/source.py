"""Where a fleet's recordings are: a folder <machine>/<date>/sim.csv,rec.csv or a manifest CSV.

`plan(source, defaults)` returns the machine-nights (`Job`) to diagnose, each with its files and
its diagnose options.  Options come from the command line (`defaults`), then per machine from
`<machine>/diagnose.toml` (folder) or from the manifest's option columns.
"""
from __future__ import annotations

import datetime as _dt
import json
import re
from dataclasses import dataclass
from pathlib import Path

from .._io import InputError
from .adapter import OPTION_KEYS

# option columns of a manifest and keys of diagnose.toml -> diagnose() keyword; list options are
# written "x;y;z" in a manifest cell, units "vx=mm/s;vy=mm/s"
_LISTS = {"output": "outputs", "outputs": "outputs", "input": "inputs", "inputs": "inputs",
          "where": "where", "exclude_rows": "exclude_rows", "exclude-rows": "exclude_rows"}
_SCALARS = {"same_clock": "same_clock", "same-clock": "same_clock", "dt": "dt"}
_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._-]*$")


@dataclass(frozen=True)
class Job:
    """One machine-night: its recordings ((sim, rec) paths) and diagnose options (JSON text, so
    that a job is hashable and travels to a worker as it is)."""
    machine: str
    date: str
    recordings: tuple
    options_json: str = "{}"

    @property
    def options(self) -> dict:
        return json.loads(self.options_json)

    @property
    def key(self) -> str:
        return f"night-{self.machine}-{self.date}"


def check_date(text: str, where) -> str:
    try:
        return _dt.date.fromisoformat(text.strip()).isoformat()
    except ValueError:
        raise InputError(f"date {text!r}: expected an ISO date YYYY-MM-DD", where) from None


def check_machine(text: str, where) -> str:
    name = text.strip()
    if not _NAME.match(name):
        raise InputError(f"machine {text!r}: expected a name of letters, digits, '.', '_', '-' "
                         "(not starting with '.', '_' or '-')", where)
    return name


def _option(key: str, value, where) -> tuple[str, object]:
    """One option (manifest cell or TOML value) as a diagnose keyword and value."""
    k = key.strip().lower()
    if k in _LISTS:
        items = value if isinstance(value, list) else [s for s in str(value).split(";")]
        return _LISTS[k], [str(s).strip() for s in items if str(s).strip()]
    if k in ("unit", "units"):
        if isinstance(value, dict):
            return "units", {str(a): str(b) for a, b in value.items()}
        units = {}
        for item in str(value).split(";"):
            if not item.strip():
                continue
            col, sep, unit = item.partition("=")
            if not sep or not col.strip() or not unit.strip():
                raise InputError(f"unit {item!r}: expected COL=UNIT, e.g. vx=mm/s", where, field=key)
            units[col.strip()] = unit.strip()
        return "units", units
    if k == "same_clock" or k == "same-clock":
        if isinstance(value, bool):
            return "same_clock", value
        s = str(value).strip().lower()
        if s in ("", "0", "false", "no"):
            return "same_clock", False
        if s in ("1", "true", "yes"):
            return "same_clock", True
        raise InputError(f"same_clock {value!r}: expected true or false", where, field=key)
    if k == "dt":
        if str(value).strip() == "":
            return "dt", None
        try:
            dt = float(value)
        except (TypeError, ValueError):
            dt = float("nan")
        if not dt > 0 or dt == float("inf"):
            raise InputError(f"dt {value!r}: expected a logging period in s > 0", where, field=key)
        return "dt", dt
    raise InputError(f"unknown option {key!r} (expected one of output, input, unit, where, "
                     "exclude_rows, same_clock, dt)", where, field=key)


def _merge(defaults: dict, extra: dict) -> str:
    opts = {k: v for k, v in defaults.items() if k in OPTION_KEYS}
    opts.update({k: v for k, v in extra.items() if v not in (None, [], {}, "")})
    return json.dumps({k: opts[k] for k in sorted(opts) if opts[k] not in (None, [], {})},
                      sort_keys=True)


def _machine_options(mdir: Path) -> dict:
    f = mdir / "diagnose.toml"
    if not f.is_file():
        return {}
    from .._io import load_toml
    data = load_toml(f, what="machine options")
    return dict(_option(k, v, f) for k, v in data.items())


def _scan_folder(root: Path, defaults: dict) -> list[Job]:
    jobs = []
    for mdir in sorted(p for p in root.iterdir() if p.is_dir() and not p.name.startswith((".", "_"))):
        machine = check_machine(mdir.name, mdir)
        mopts = _machine_options(mdir)
        for ddir in sorted(p for p in mdir.iterdir() if p.is_dir() and not p.name.startswith((".", "_"))):
            date = check_date(ddir.name, ddir)
            pairs = _pairs(ddir)
            jobs.append(Job(machine, date, pairs, _merge(defaults, mopts)))
    if not jobs:
        raise InputError("no recordings: expected folders <machine>/<date>/ holding sim.csv and "
                         "rec.csv", root)
    return jobs


def _pairs(ddir: Path) -> tuple:
    """sim.csv/rec.csv, or several sim_<name>.csv/rec_<name>.csv pairs of one night."""
    if (ddir / "sim.csv").is_file() or (ddir / "rec.csv").is_file():
        for f in ("sim.csv", "rec.csv"):
            if not (ddir / f).is_file():
                raise InputError(f"{f} missing (expected sim.csv and rec.csv)", ddir)
        return ((str(ddir / "sim.csv"), str(ddir / "rec.csv")),)
    sims = {p.name[4:]: p for p in ddir.glob("sim_*.csv")}
    recs = {p.name[4:]: p for p in ddir.glob("rec_*.csv")}
    if not sims and not recs:
        raise InputError("no recording (expected sim.csv and rec.csv, or sim_<name>.csv and "
                         "rec_<name>.csv pairs)", ddir)
    lone = sorted(set(sims) ^ set(recs))
    if lone:
        raise InputError(f"{'sim' if lone[0] in sims else 'rec'}_{lone[0]} has no partner "
                         "(expected sim_<name>.csv and rec_<name>.csv pairs)", ddir)
    return tuple((str(sims[k]), str(recs[k])) for k in sorted(sims))


def _scan_manifest(path: Path, defaults: dict) -> list[Job]:
    import csv
    from .._io import read_text
    text = read_text(path, what="manifest")
    rows = list(csv.reader(text.splitlines()))
    rows = [(i + 1, r) for i, r in enumerate(rows) if r and not r[0].lstrip().startswith("#")]
    if not rows:
        raise InputError("empty manifest (expected a header machine,date,sim,rec)", path)
    hline, header = rows[0]
    header = [h.strip() for h in header]
    need = [c for c in ("machine", "date", "sim", "rec") if c not in header]
    if need:
        raise InputError(f"header lacks column(s) {', '.join(need)} (expected machine,date,sim,rec "
                         "and option columns)", path, hline)
    base = path.parent
    nights: dict = {}
    for line, r in rows[1:]:
        if len(r) != len(header):
            raise InputError(f"{len(r)} values, expected {len(header)} (as the header)", path, line)
        cell = dict(zip(header, r))
        machine = check_machine(cell["machine"], f"{path}:{line}")
        date = check_date(cell["date"], f"{path}:{line}")
        files = []
        for c in ("sim", "rec"):
            f = Path(cell[c].strip())
            f = f if f.is_absolute() else base / f
            if not f.is_file():
                raise InputError(f"{c} file {cell[c]!r} not found", path, line, field=c)
            files.append(str(f))
        extra = dict(_option(k, v, f"{path}:{line}") for k, v in cell.items()
                     if k not in ("machine", "date", "sim", "rec") and v.strip())
        opts = _merge(defaults, extra)
        prev = nights.setdefault((machine, date), ([], opts))
        if prev[1] != opts:
            raise InputError(f"options differ from an earlier row of {machine} {date} (one "
                             "machine-night is diagnosed with one set of options)", path, line)
        prev[0].append(tuple(files))
    return [Job(m, d, tuple(v[0]), v[1]) for (m, d), v in sorted(nights.items())]


def plan(source, defaults: dict | None = None) -> list[Job]:
    """The machine-nights of a folder or a manifest CSV, sorted by machine and date."""
    source = Path(source)
    defaults = dict(defaults or {})
    if source.is_dir():
        return _scan_folder(source, defaults)
    if source.is_file():
        return _scan_manifest(source, defaults)
    raise InputError("not found (expected a folder <machine>/<date>/sim.csv,rec.csv or a "
                     "manifest CSV)", source)
