"""Machine description: a serial kinematic chain of linear and rotary axes.

The axes are listed from the workpiece side to the tool side; the machine base sits between the
last workpiece-side axis and the first tool-side axis.  Every axis' motion is expressed as the
motion of the tool relative to the workpiece in the ISO 841 sense (a table that moves in -X gives
+X), so the nominal tool pose in the workpiece frame is the product of the axis motions in the
listed order.  Lengths in mm, angles in deg.  File format: docs/machine-format.md.
"""
from __future__ import annotations

import difflib
import math
import os
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path

import numpy as np

from ._io import InputError, load_toml_as, parse_toml
from .validate import check_keys, number, string, table, vector

AXIS_NAMES = ("X", "Y", "Z", "U", "V", "W", "A", "B", "C")
LINEAR_NAMES = ("X", "Y", "Z", "U", "V", "W")
ROTARY_NAMES = ("A", "B", "C")


@dataclass(frozen=True)
class Axis:
    """One machine axis.

    name: ISO 841 letter.  kind: "linear" or "rotary".  side: "workpiece" or "tool" (which
    branch of the chain carries it).  direction: unit vector of the positive motion of the tool
    relative to the workpiece (linear) or of the rotation axis, right-hand (rotary), at zero
    position of all axes.  location: mm; the rotation centre (rotary) or the reference point
    about which the axis' angular error motions act (linear; paper 004's virtual points).
    limits: travel (mm or deg).  resolution: command increment (mm or deg).
    """
    name: str
    kind: str
    side: str
    direction: tuple[float, float, float]
    location: tuple[float, float, float] = (0.0, 0.0, 0.0)
    limits: tuple[float, float] = (-np.inf, np.inf)
    resolution: float = 1e-6

    @property
    def is_rotary(self) -> bool:
        return self.kind == "rotary"

    @property
    def unit(self) -> str:
        return "deg" if self.is_rotary else "mm"

    @property
    def decimals(self) -> int:
        """Number of decimals that represents one resolution step."""
        return max(0, int(round(-np.log10(self.resolution))))


@dataclass(frozen=True)
class Machine:
    """A machine: axes from the workpiece side to the tool side, and the nominal tool.

    tool_point: mm, nominal tool edge point in the frame carried by the last tool-side axis (NC
    data is programmed with the edge on the rotation centres).  tool_axis: unit vector from the
    edge into the holder, in the same frame.
    """
    name: str
    axes: tuple[Axis, ...]
    tool_point: tuple[float, float, float] = (0.0, 0.0, 0.0)
    tool_axis: tuple[float, float, float] = (0.0, 0.0, 1.0)
    description: str = ""
    sources: str = ""
    extra: dict = field(default_factory=dict, compare=False, hash=False)

    @property
    def axis_names(self) -> tuple[str, ...]:
        return tuple(a.name for a in self.axes)

    @property
    def n_axes(self) -> int:
        return len(self.axes)

    @property
    def rotary_indices(self) -> tuple[int, ...]:
        return tuple(i for i, a in enumerate(self.axes) if a.is_rotary)

    @property
    def n_rotary(self) -> int:
        return len(self.rotary_indices)

    def axis(self, name: str) -> Axis:
        for a in self.axes:
            if a.name == name:
                return a
        raise KeyError(f"machine {self.name!r} has no axis {name!r}; axes: {', '.join(self.axis_names)}")

    def index(self, name: str) -> int:
        return self.axis_names.index(self.axis(name).name)

    @property
    def resolutions(self) -> np.ndarray:
        return np.array([a.resolution for a in self.axes])

    def to_dict(self) -> dict:
        return {
            "machine": {"name": self.name, "description": self.description, "sources": self.sources,
                        "tool_point": list(self.tool_point), "tool_axis": list(self.tool_axis), **self.extra},
            "axis": [{"name": a.name, "kind": a.kind, "side": a.side, "direction": list(a.direction),
                      "location": list(a.location), "limits": [float(x) for x in a.limits],
                      "resolution": a.resolution} for a in self.axes],
        }


# Travel limits, locations and tool points beyond this are not a machine tool (mm or deg).
MAX_EXTENT = 1e6
# Least command increments an NC control offers: powers of ten from 1 nm (or 1e-9 deg) to 1.
RESOLUTIONS = tuple(10.0 ** -k for k in range(10))


def _vec3(value, file, field_name, unit=False):
    v = vector(value, 3, file, field_name, max_abs=MAX_EXTENT, nonzero=unit)
    if unit:
        n = math.sqrt(sum(x * x for x in v))
        if n < 1e-12:
            raise InputError("direction must not be the zero vector", file, field=field_name)
        v = tuple(x / n for x in v)
    return v


def _resolution(value, file, field_name) -> float:
    """The command increment: a power of ten in [1e-9, 1].  A control's least input increment is
    always one (0.001, 0.0001, ... mm), and programs are written with that many decimals; a
    step such as 5e-6 has no decimal representation the control would read."""
    r = number(value, file, field_name, lo=0.0, lo_open=True, hi=1.0)
    for p in RESOLUTIONS:
        if abs(r - p) <= 1e-9 * p:
            return p
    raise InputError(f"resolution must be a power of ten from 1e-9 to 1 (the control's least command "
                     f"increment, e.g. 1e-6 mm or 1e-5 deg), got {value!r}", file, field=field_name)


_AXIS_KEYS = ("name", "kind", "side", "direction", "location", "limits", "resolution")


def machine_from_dict(data: dict, file: str | os.PathLike = "<dict>") -> Machine:
    """Build and validate a Machine from the TOML structure of docs/machine-format.md.

    Every value is checked once here (types, ranges, shapes, finiteness, unknown keys); a
    rejection is an InputError naming the file and field."""
    data = table(data, file, "<top>")
    check_keys(data, ("machine", "axis"), file, None)
    if "machine" not in data:
        raise InputError("missing [machine] table", file, field="machine")
    head = table(data["machine"], file, "machine")
    if "name" not in head:
        raise InputError("missing name (a non-empty string)", file, field="machine.name")
    name = string(head["name"], file, "machine.name", max_len=200)
    description = string(head.get("description", ""), file, "machine.description", nonempty=False)
    sources = string(head.get("sources", ""), file, "machine.sources", nonempty=False)
    raw_axes = data.get("axis")
    if not isinstance(raw_axes, list) or not raw_axes:
        raise InputError("expected at least one [[axis]] table", file, field="axis")
    axes = []
    seen_tool_side = False
    for i, ax in enumerate(raw_axes):
        f = f"axis[{i}]"
        ax = table(ax, file, f)
        check_keys(ax, _AXIS_KEYS, file, f)
        if "name" not in ax:
            raise InputError(f"missing name (one of {', '.join(AXIS_NAMES)})", file, field=f"{f}.name")
        an = ax["name"]
        if not isinstance(an, str) or an not in AXIS_NAMES:
            raise InputError(f"axis name must be one of {', '.join(AXIS_NAMES)}, got {an!r}", file, field=f"{f}.name")
        if an in [a.name for a in axes]:
            raise InputError(f"axis {an} appears twice", file, field=f"{f}.name")
        kind = string(ax.get("kind", "rotary" if an in ROTARY_NAMES else "linear"), file, f"{f}.kind",
                      choices=("linear", "rotary"))
        if (kind == "rotary") != (an in ROTARY_NAMES):
            raise InputError(f"axis {an} must be {'rotary' if an in ROTARY_NAMES else 'linear'} (ISO 841)",
                             file, field=f"{f}.kind")
        if "side" not in ax:
            raise InputError("missing side ('workpiece' or 'tool')", file, field=f"{f}.side")
        side = string(ax["side"], file, f"{f}.side", choices=("workpiece", "tool"))
        # One base: every workpiece-side axis is listed before every tool-side axis.
        if side == "tool":
            seen_tool_side = True
        elif seen_tool_side:
            raise InputError("broken axis chain: a workpiece-side axis follows a tool-side axis "
                             "(list axes from the workpiece to the tool, workpiece side first)",
                             file, field=f"{f}.side")
        if "direction" not in ax:
            raise InputError("missing direction", file, field=f"{f}.direction")
        direction = _vec3(ax["direction"], file, f"{f}.direction", unit=True)
        location = _vec3(ax.get("location", [0.0, 0.0, 0.0]), file, f"{f}.location")
        lim = ax.get("limits", [-math.inf, math.inf])
        if not isinstance(lim, list) or len(lim) != 2:
            raise InputError(f"expected [low, high], got {lim!r}", file, field=f"{f}.limits")
        lo, hi = (number(x, file, f"{f}.limits[{j}]", allow_inf=True, max_abs=MAX_EXTENT,
                         unit="deg" if kind == "rotary" else "mm") for j, x in enumerate(lim))
        if not lo < hi:
            raise InputError(f"expected low < high, got {lim!r}", file, field=f"{f}.limits")
        res = _resolution(ax.get("resolution", 1e-5 if kind == "rotary" else 1e-6), file, f"{f}.resolution")
        axes.append(Axis(an, kind, side, direction, location, (lo, hi), res))
    tool_point = _vec3(head.get("tool_point", [0.0, 0.0, 0.0]), file, "machine.tool_point")
    tool_axis = _vec3(head.get("tool_axis", [0.0, 0.0, 1.0]), file, "machine.tool_axis", unit=True)
    known = ("name", "description", "sources", "tool_point", "tool_axis")
    extra = {k: v for k, v in head.items() if k not in known}
    for k in extra:  # metadata keys are free, but a misspelt tool_point must not fall back to the default
        close = difflib.get_close_matches(k, known, n=1, cutoff=0.75)
        if close:
            raise InputError(f"unknown key {k!r}: did you mean {close[0]!r}? (other keys are kept as "
                             f"metadata, but not ones this close to a known key)", file, field=f"machine.{k}")
    return Machine(name, tuple(axes), tool_point, tool_axis, description, sources, extra)


def list_presets() -> list[str]:
    """Names of the shipped machine presets."""
    return sorted(p.name[:-5] for p in resources.files("mtcomp.presets").iterdir() if p.name.endswith(".toml"))


def load_machine(spec: str | os.PathLike | Machine) -> Machine:
    """Load a machine from a preset name (see `list_presets`) or a TOML file path."""
    if isinstance(spec, Machine):
        return spec
    spec_s = str(spec)
    if spec_s in list_presets():
        res = resources.files("mtcomp.presets").joinpath(spec_s + ".toml")
        return machine_from_dict(parse_toml(res.read_text(encoding="utf-8"), f"preset {spec_s}"),
                                 f"preset {spec_s}")
    path = Path(spec_s)
    if not path.exists():
        raise InputError(f"no such machine file or preset (presets: {', '.join(list_presets())})", spec_s)
    return load_toml_as(path, machine_from_dict, what="machine file")
