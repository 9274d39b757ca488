"""Error model: tool setting, workpiece setting and geometric errors (ISO 230-1 / 230-7 names).

Every part is a frozen dataclass in mm and deg (angles of setting errors) or mm and rad
(geometric component errors, as interferometer software and controller tables give them).
Errors are expressed in the sense of the tool relative to the workpiece.  File formats:
docs/errors-format.md.
"""
from __future__ import annotations

import io
import os
import re
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType

import numpy as np

from ._io import InputError, MtcompError, atomic_write, dump_toml, load_toml_as
from .csvtable import read_csv
from .validate import check_keys, number, string, table, vector

_LIN = "XYZ"
_ANG = "ABC"
_LOC_RE = re.compile(r"^E([XYZABC])0([XYZUVWABC])$")
_COMP_RE = re.compile(r"^E[XYZABC][XYZUVWABC]$")
_AXES = ("X", "Y", "Z", "U", "V", "W", "A", "B", "C")

# Magnitude limits of error values: larger values are not errors of a machine but a different
# machine (put them into its description).  Translational errors and setting offsets in mm,
# angular geometric errors in rad; table positions in mm or deg.
MAX_TRANSLATIONAL = 1000.0
MAX_ANGULAR = 0.1
MAX_POSITION = 1e6


class TableRangeError(MtcompError):
    """An axis position lies outside the range covered by its error table."""

    def __init__(self, axis: str, index: int, value: float, lo: float, hi: float):
        self.axis, self.index, self.value = axis, index, value
        super().__init__(f"axis {axis} position {value:.6f} (point {index}) is outside its error "
                         f"table range [{lo:g}, {hi:g}]")


def rotation_matrix_xyz(angles_deg) -> np.ndarray:
    """R = Rz(c) Ry(b) Rx(a) for angles (a, b, c) in deg about the fixed X, Y, Z axes."""
    a, b, c = np.radians(np.asarray(angles_deg, dtype=float))
    ca, sa, cb, sb, cc, sc = np.cos(a), np.sin(a), np.cos(b), np.sin(b), np.cos(c), np.sin(c)
    rx = np.array([[1, 0, 0], [0, ca, -sa], [0, sa, ca]])
    ry = np.array([[cb, 0, sb], [0, 1, 0], [-sb, 0, cb]])
    rz = np.array([[cc, -sc, 0], [sc, cc, 0], [0, 0, 1]])
    return rz @ ry @ rx


def angles_from_matrix(r: np.ndarray) -> np.ndarray:
    """Inverse of `rotation_matrix_xyz`: (a, b, c) in deg with b in [-90, 90]; r may be a
    stack (..., 3, 3), giving (..., 3)."""
    b = np.arcsin(np.clip(-r[..., 2, 0], -1.0, 1.0))
    a = np.arctan2(r[..., 2, 1], r[..., 2, 2])
    c = np.arctan2(r[..., 1, 0], r[..., 0, 0])
    return np.degrees(np.stack([a, b, c], axis=-1))


@dataclass(frozen=True)
class ToolSetting:
    """Tool setting error: vector (mm) from the nominal tool point (on the rotation centres) to
    the real tool edge point, in the frame carried by the last tool-side axis."""
    offset: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def __post_init__(self):
        v = np.asarray(self.offset, dtype=float)
        if v.shape != (3,) or not np.all(np.isfinite(v)):
            raise InputError(f"expected 3 finite numbers in mm, got {self.offset!r}", field="tool_setting.offset")
        object.__setattr__(self, "offset", tuple(float(x) for x in v))

    @property
    def is_zero(self) -> bool:
        return not any(self.offset)


@dataclass(frozen=True)
class WorkpieceSetting:
    """Pose of the real workpiece frame in the nominal one: x_nominal = R x_real + translation.

    translation in mm; angles (a, b, c) in deg about X, Y, Z with R = Rz(c) Ry(b) Rx(a).
    """
    translation: tuple[float, float, float] = (0.0, 0.0, 0.0)
    angles: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def __post_init__(self):
        for name in ("translation", "angles"):
            v = np.asarray(getattr(self, name), dtype=float)
            if v.shape != (3,) or not np.all(np.isfinite(v)):
                raise InputError(f"expected 3 finite numbers, got {getattr(self, name)!r}",
                                 field=f"workpiece_setting.{name}")
            object.__setattr__(self, name, tuple(float(x) for x in v))

    @property
    def matrix(self) -> np.ndarray:
        return rotation_matrix_xyz(self.angles)

    @property
    def is_zero(self) -> bool:
        return not any(self.translation) and not any(self.angles)

    @classmethod
    def from_frame(cls, rotation: np.ndarray, translation) -> "WorkpieceSetting":
        return cls(tuple(np.asarray(translation, float)), tuple(angles_from_matrix(np.asarray(rotation, float))))


def component_names(axis: str) -> tuple[str, ...]:
    """ISO 230-1 component error names of one axis, e.g. X -> EXX EYX EZX EAX EBX ECX."""
    return tuple(f"E{d}{axis}" for d in _LIN + _ANG)


class AxisErrorTable:
    """Component errors of one axis over its position (ISO 230-1 names).

    position: strictly increasing, mm (linear axis) or deg (rotary).  values: name -> array of
    the same length; E?{axis} translational components in mm, EA/EB/EC{axis} angular in rad.
    Missing components are zero.  Linear interpolation between points; outside the range is an
    error (`TableRangeError`).
    """
    axis: str
    position: np.ndarray
    values: MappingProxyType

    def __init__(self, axis: str, position, values: dict, source: str = "<table>"):
        pos = np.asarray(position, dtype=float)
        names = component_names(axis)
        if pos.ndim != 1 or pos.size < 2:
            raise InputError("an error table needs at least two positions", source, field="position")
        if not np.all(np.isfinite(pos)):
            raise InputError("positions must be finite numbers", source, field="position")
        bad = np.nonzero(np.diff(pos) <= 0)[0]
        if bad.size:
            raise InputError(f"positions must increase strictly (row {bad[0] + 2} is {pos[bad[0] + 1]:g} "
                             f"after {pos[bad[0]]:g})", source, field="position")
        vals = {}
        for k, v in values.items():
            if k not in names:
                raise InputError(f"unknown component {k!r} for axis {axis}; expected {', '.join(names)}",
                                 source, field=k)
            arr = np.asarray(v, dtype=float)
            if arr.shape != pos.shape or not np.all(np.isfinite(arr)):
                raise InputError(f"expected {pos.size} finite values", source, field=k)
            arr.setflags(write=False)
            vals[k] = arr
        pos.setflags(write=False)
        stack = np.zeros((pos.size, 6))
        for j, name in enumerate(names):
            if name in vals:
                stack[:, j] = vals[name]
        object.__setattr__(self, "_stack", stack)
        object.__setattr__(self, "axis", axis)
        object.__setattr__(self, "position", pos)
        object.__setattr__(self, "values", MappingProxyType(vals))

    def __setattr__(self, *_):  # immutable like the frozen dataclasses (arrays are read-only too)
        raise AttributeError("AxisErrorTable is frozen")

    def __reduce__(self):
        # pickled by its constructor's arguments (a mappingproxy cannot be pickled): what runs
        # in another process (the demo's second process, Dask workers) gets an equal table
        return (AxisErrorTable, (self.axis, np.array(self.position), {k: np.array(v) for k, v in self.values.items()}))

    def __repr__(self):
        return f"AxisErrorTable({self.axis!r}, {self.position.size} points {self.range}, {sorted(self.values)})"

    def __eq__(self, other):
        return (isinstance(other, AxisErrorTable) and self.axis == other.axis
                and np.array_equal(self.position, other.position)
                and self.values.keys() == other.values.keys()
                and all(np.array_equal(self.values[k], other.values[k]) for k in self.values))

    __hash__ = None

    @property
    def range(self) -> tuple[float, float]:
        return float(self.position[0]), float(self.position[-1])

    def evaluate(self, q: np.ndarray, strict: bool = True) -> tuple[np.ndarray, np.ndarray]:
        """Translational (N,3) mm and angular (N,3) rad error at positions q (N,).

        strict=False holds the end values outside the range (used only for intermediate
        iterates of `compensate`, whose result is checked strictly)."""
        q = np.asarray(q, dtype=float)
        lo, hi = self.range
        out = (q < lo - 1e-12) | (q > hi + 1e-12) | ~np.isfinite(q)
        if strict and np.any(out):
            i = int(np.argmax(out))
            raise TableRangeError(self.axis, i, float(q[i]), lo, hi)
        # One bracket search for all six components (np.interp would search six times).
        pos = self.position
        j = np.clip(np.searchsorted(pos, q, side="right") - 1, 0, pos.size - 2)
        f = np.clip((q - pos[j]) / (pos[j + 1] - pos[j]), 0.0, 1.0)[:, None]
        stack = self._stack
        v = stack[j] + f * (stack[j + 1] - stack[j])
        return v[:, :3], v[:, 3:]

    def to_csv(self) -> str:
        names = [n for n in component_names(self.axis) if n in self.values]
        buf = io.StringIO()
        buf.write(f"# ISO 230-1 component errors of axis {self.axis}: position in "
                  f"{'deg' if self.axis in _ANG else 'mm'}, E?{self.axis} in mm, EA/EB/EC{self.axis} in rad\n")
        buf.write(",".join(["position"] + names) + "\n")
        for i, p in enumerate(self.position):
            row = [repr(float(p))] + [repr(float(self.values[n][i])) for n in names]
            buf.write(",".join(row) + "\n")
        return buf.getvalue()

    @classmethod
    def from_csv(cls, path: str | os.PathLike, axis: str | None = None) -> "AxisErrorTable":
        """Read one axis' table (docs/errors-format.md). The axis is taken from the header names.

        Header units are converted (``position [deg]``, ``EXX [um]``, ``EAX [urad]``); without a
        unit, position is in mm (deg for a rotary axis), E?K in mm and EA/EB/ECK in rad."""
        t = read_csv(path, what="error table")
        cols = t.names
        if cols[0] != "position":
            raise t.error(f"first column must be 'position', got {cols[0]!r}")
        names = cols[1:]
        bad = [c for c in names if not _COMP_RE.match(c)]
        if bad:
            raise t.error(f"unknown column {bad[0]!r}; expected ISO 230-1 component names "
                          f"E<X|Y|Z|A|B|C><axis>, e.g. EXX,EYX,EZX,EAX,EBX,ECX", None, bad[0])
        axes = sorted({c[-1] for c in names})
        if axis is None:
            if len(axes) != 1:
                raise t.error(f"columns must name one axis (e.g. EXX,EYX,...), got {', '.join(names) or 'none'}")
            axis = axes[0]
        comps = component_names(axis)
        for c in names:
            if c not in comps:
                raise t.error(f"unknown column {c!r}; expected some of {', '.join(comps)}", None, c)
        if len(t) < 2:
            raise InputError("an error table needs at least two rows", t.source)
        rotary = axis in _ANG
        pos = t.numbers("position", unit="deg" if rotary else "mm", max_abs=MAX_POSITION)
        for k in range(1, len(pos)):
            if pos[k] <= pos[k - 1]:
                raise t.error(f"positions must increase strictly ({pos[k]:g} after {pos[k - 1]:g})", k, "position")
        vals = {c: t.numbers(c, unit="rad" if c[1] in _ANG else "mm",
                             max_abs=MAX_ANGULAR if c[1] in _ANG else MAX_TRANSLATIONAL) for c in names}
        return cls(axis, pos, vals, source=t.source)


@dataclass(frozen=True)
class GeometricErrors:
    """Geometric errors: component tables per axis and constant location errors.

    location: ISO 230-1/230-7 location errors E{X,Y,Z}0{axis} (mm) and E{A,B,C}0{axis} (rad),
    e.g. squareness EC0Y, EB0Z, EA0Z; rotary axis offsets EX0C, EY0C, tilts EA0C, EB0C and the
    zero-position error EC0C.
    """
    tables: MappingProxyType = field(default_factory=lambda: MappingProxyType({}))
    location: MappingProxyType = field(default_factory=lambda: MappingProxyType({}))

    def __post_init__(self):
        tables = dict(self.tables)
        for k, t in tables.items():
            if not isinstance(t, AxisErrorTable) or t.axis != k:
                raise InputError(f"table for axis {k} must be an AxisErrorTable of that axis", field=f"tables.{k}")
        loc = {}
        for k, v in dict(self.location).items():
            if not _LOC_RE.match(k):
                raise InputError(f"unknown location error {k!r}; expected names like EC0Y, EX0C",
                                 field=f"location.{k}")
            loc[k] = _location_value(k, v, None, f"location.{k}")
        object.__setattr__(self, "tables", MappingProxyType(tables))
        object.__setattr__(self, "location", MappingProxyType(loc))

    def __reduce__(self):
        # by value, like AxisErrorTable: a mappingproxy cannot be pickled
        return (GeometricErrors, (dict(self.tables), dict(self.location)))

    @property
    def is_zero(self) -> bool:
        return not self.tables and not any(self.location.values())

    def location_of(self, axis: str) -> tuple[np.ndarray, np.ndarray]:
        """(translation mm (3,), rotation rad (3,)) location error of one axis."""
        d = np.array([self.location.get(f"E{c}0{axis}", 0.0) for c in _LIN])
        e = np.array([self.location.get(f"E{c}0{axis}", 0.0) for c in _ANG])
        return d, e


@dataclass(frozen=True)
class ErrorSet:
    """All errors of one machine set-up."""
    tool: ToolSetting = field(default_factory=ToolSetting)
    workpiece: WorkpieceSetting = field(default_factory=WorkpieceSetting)
    geometric: GeometricErrors = field(default_factory=GeometricErrors)

    @property
    def is_zero(self) -> bool:
        return self.tool.is_zero and self.workpiece.is_zero and self.geometric.is_zero


def _location_value(name: str, value, file, field_name: str) -> float:
    ang = name[1] in _ANG
    return number(value, file, field_name, max_abs=MAX_ANGULAR if ang else MAX_TRANSLATIONAL,
                  unit="rad" if ang else "mm")


def errors_from_dict(data: dict, file: str | os.PathLike = "<dict>", base: Path | None = None) -> ErrorSet:
    """Build an ErrorSet from the TOML structure of docs/errors-format.md.

    Every value is checked here, once: types, shapes, finiteness, magnitudes (setting errors
    within MAX_TRANSLATIONAL mm / 360 deg, geometric ones within MAX_TRANSLATIONAL mm and
    MAX_ANGULAR rad), axis letters and unknown keys; a rejection is an InputError naming the
    file and field."""
    data = table(data, file, "<top>")
    check_keys(data, ("tool_setting", "workpiece_setting", "geometric", "uncertainty", "meta"), file, None)
    for k in ("uncertainty", "meta"):
        if k in data:
            table(data[k], file, k)
    tool = ToolSetting()
    wp = WorkpieceSetting()
    geo = GeometricErrors()
    if "tool_setting" in data:
        ts = table(data["tool_setting"], file, "tool_setting")
        check_keys(ts, ("offset", "sigma"), file, "tool_setting")
        if "sigma" in ts:
            vector(ts["sigma"], 3, file, "tool_setting.sigma", lo=0.0, max_abs=MAX_TRANSLATIONAL, unit="mm")
        tool = ToolSetting(vector(ts.get("offset", [0.0] * 3), 3, file, "tool_setting.offset",
                                  max_abs=MAX_TRANSLATIONAL, unit="mm"))
    if "workpiece_setting" in data:
        ws = table(data["workpiece_setting"], file, "workpiece_setting")
        check_keys(ws, ("translation", "angles", "sigma"), file, "workpiece_setting")
        if "sigma" in ws:
            vector(ws["sigma"], (1, 6), file, "workpiece_setting.sigma", lo=0.0, max_abs=MAX_TRANSLATIONAL)
        wp = WorkpieceSetting(
            vector(ws.get("translation", [0.0] * 3), 3, file, "workpiece_setting.translation",
                   max_abs=MAX_TRANSLATIONAL, unit="mm"),
            vector(ws.get("angles", [0.0] * 3), 3, file, "workpiece_setting.angles", max_abs=360.0, unit="deg"))
    if "geometric" in data:
        g = table(data["geometric"], file, "geometric")
        check_keys(g, ("tables", "location"), file, "geometric")
        tables = {}
        for ax, rel in table(g.get("tables", {}), file, "geometric.tables").items():
            f = f"geometric.tables.{ax}"
            if ax not in _AXES:
                raise InputError(f"unknown axis {ax!r}; expected one of {', '.join(_AXES)}", file, field=f)
            rel = string(rel, file, f)
            p = Path(rel)
            if not p.is_absolute() and base is not None:
                p = base / p
            if p.is_dir():
                raise InputError(f"{rel!r} is a directory; expected the CSV file of axis {ax}", file, field=f)
            t = AxisErrorTable.from_csv(p)
            if t.axis != ax:
                raise InputError(f"table {rel} holds axis {t.axis}, not {ax}", file, field=f)
            tables[ax] = t
        loc = {}
        for k, v in table(g.get("location", {}), file, "geometric.location").items():
            f = f"geometric.location.{k}"
            if not _LOC_RE.match(k):
                raise InputError(f"unknown location error {k!r}; expected names like EC0Y, EX0C", file, field=f)
            loc[k] = _location_value(k, v, file, f)
        geo = GeometricErrors(tables, loc)
    return ErrorSet(tool, wp, geo)


def check_for_machine(errors: ErrorSet, machine, file: str | os.PathLike | None = None) -> ErrorSet:
    """Refuse geometric errors of axes the machine does not have (a table or a location error
    such as EX0U, EC0W or EX0A on a machine without U, W or A): they would be ignored, and the
    program come out unchanged.  Returns `errors`."""
    names = tuple(machine.axis_names)
    have = f"machine {machine.name!r} has axes {' '.join(names)}"
    for ax in errors.geometric.tables:
        if ax not in names:
            raise InputError(f"error table for axis {ax}, but {have}", file, field=f"geometric.tables.{ax}")
    for k in errors.geometric.location:
        if k[-1] not in names:
            raise InputError(f"location error {k} of axis {k[-1]}, but {have}", file,
                             field=f"geometric.location.{k}")
    return errors


def load_errors(path: str | os.PathLike, machine=None) -> ErrorSet:
    """Read an errors TOML file (tables referenced by relative path are read from its folder).

    With a machine (a Machine or anything `load_machine` takes), errors of axes it does not
    have are refused (`check_for_machine`)."""
    path = Path(path)
    if machine is not None:
        from .machine import load_machine
        machine = load_machine(machine)

    def build(data, file):
        errors = errors_from_dict(data, file, path.parent)
        return errors if machine is None else check_for_machine(errors, machine, file)
    return load_toml_as(path, build, what="errors file")


def save_errors(errors: ErrorSet, path: str | os.PathLike, *, uncertainty: dict | None = None,
                meta: dict | None = None) -> Path:
    """Write an errors TOML (and one CSV per geometric table next to it), all atomically.

    uncertainty: optional 1-sigma values to record, e.g. {"tool_setting.offset": [..]} (not read back).
    """
    path = Path(path)
    data: dict = {}
    if meta:
        data["meta"] = meta
    if not errors.tool.is_zero:
        data["tool_setting"] = {"offset": list(errors.tool.offset)}
    if not errors.workpiece.is_zero:
        data["workpiece_setting"] = {"translation": list(errors.workpiece.translation),
                                     "angles": list(errors.workpiece.angles)}
    g = errors.geometric
    if not g.is_zero:
        data["geometric"] = {}
        if g.tables:
            data["geometric"]["tables"] = {}
            for ax, t in g.tables.items():
                name = f"{path.stem}_{ax}.csv"
                atomic_write(path.parent / name, t.to_csv())
                data["geometric"]["tables"][ax] = name
        if g.location:
            data["geometric"]["location"] = dict(g.location)
    if uncertainty:
        data["uncertainty"] = uncertainty
    header = ("# mtcomp errors file (docs/errors-format.md): mm, deg for setting errors; "
              "geometric tables in mm and rad\n")
    return atomic_write(path, header + dump_toml(data))
