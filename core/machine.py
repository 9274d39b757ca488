"""Machine description: a serial kinematic chain of linear and rotary axes.

The axes are listed from the workpiece side to the tool side; the machine base sits between the
last workpiece-side axis and the first tool-side axis.  Every axis' motion is expressed as the
motion of the tool relative to the workpiece in the ISO 841 sense (a table that moves in -X gives
+X), so the nominal tool pose in the workpiece frame is the product of the axis motions in the
listed order.  Lengths in mm, angles in deg.  File format: docs/machine-format.md.
"""
from __future__ import annotations

import os
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path

import numpy as np

from ._io import InputError, load_toml

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


def _vec3(value, file, field_name, unit=False):
    try:
        v = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise InputError(f"expected 3 numbers, got {value!r}", file, field=field_name) from None
    if v.shape != (3,) or not np.all(np.isfinite(v)):
        raise InputError(f"expected 3 finite numbers, got {value!r}", file, field=field_name)
    if unit:
        n = np.linalg.norm(v)
        if n < 1e-12:
            raise InputError("direction must not be the zero vector", file, field=field_name)
        v = v / n
    return tuple(float(x) for x in v)


def machine_from_dict(data: dict, file: str | os.PathLike = "<dict>") -> Machine:
    """Build and validate a Machine from the TOML structure of docs/machine-format.md."""
    head = data.get("machine")
    if not isinstance(head, dict):
        raise InputError("missing [machine] table", file, field="machine")
    name = head.get("name")
    if not isinstance(name, str) or not name:
        raise InputError("expected a non-empty string", file, field="machine.name")
    raw_axes = data.get("axis")
    if not isinstance(raw_axes, list) or not raw_axes:
        raise InputError("expected at least one [[axis]] table", file, field="axis")
    axes = []
    seen_tool_side = False
    for i, ax in enumerate(raw_axes):
        f = f"axis[{i}]"
        if not isinstance(ax, dict):
            raise InputError("expected a table", file, field=f)
        unknown = set(ax) - {"name", "kind", "side", "direction", "location", "limits", "resolution"}
        if unknown:
            raise InputError(f"unknown keys {sorted(unknown)}", file, field=f)
        an = ax.get("name")
        if an not in AXIS_NAMES:
            raise InputError(f"axis name must be one of {', '.join(AXIS_NAMES)}, got {an!r}", file, field=f"{f}.name")
        if an in [a.name for a in axes]:
            raise InputError(f"axis {an} appears twice", file, field=f"{f}.name")
        kind = ax.get("kind", "rotary" if an in ROTARY_NAMES else "linear")
        if kind not in ("linear", "rotary"):
            raise InputError(f"kind must be 'linear' or 'rotary', got {kind!r}", file, field=f"{f}.kind")
        if (kind == "rotary") != (an in ROTARY_NAMES):
            raise InputError(f"axis {an} must be {'rotary' if an in ROTARY_NAMES else 'linear'} (ISO 841)",
                             file, field=f"{f}.kind")
        side = ax.get("side")
        if side not in ("workpiece", "tool"):
            raise InputError(f"side must be 'workpiece' or 'tool', got {side!r}", file, field=f"{f}.side")
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
        location = _vec3(ax.get("location", [0, 0, 0]), file, f"{f}.location")
        lim = ax.get("limits", [-np.inf, np.inf])
        try:
            lo, hi = (float(x) for x in lim)
        except (TypeError, ValueError):
            raise InputError(f"expected [low, high], got {lim!r}", file, field=f"{f}.limits") from None
        if not lo < hi or np.isnan(lo) or np.isnan(hi):
            raise InputError(f"expected low < high, got {lim!r}", file, field=f"{f}.limits")
        res = ax.get("resolution", 1e-5 if kind == "rotary" else 1e-6)
        if not isinstance(res, (int, float)) or not (0 < res <= 1) or not np.isfinite(res):
            raise InputError(f"expected a resolution in (0, 1], got {res!r}", file, field=f"{f}.resolution")
        axes.append(Axis(an, kind, side, direction, location, (lo, hi), float(res)))
    tool_point = _vec3(head.get("tool_point", [0, 0, 0]), file, "machine.tool_point")
    tool_axis = _vec3(head.get("tool_axis", [0, 0, 1]), file, "machine.tool_axis", unit=True)
    extra = {k: v for k, v in head.items() if k not in ("name", "description", "sources", "tool_point", "tool_axis")}
    return Machine(name, tuple(axes), tool_point, tool_axis, str(head.get("description", "")),
                   str(head.get("sources", "")), extra)


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
        with resources.as_file(res) as path:
            return machine_from_dict(load_toml(path), f"preset {spec_s}")
    path = Path(spec_s)
    if not path.exists():
        raise InputError(f"no such machine file or preset (presets: {', '.join(list_presets())})", spec_s)
    return machine_from_dict(load_toml(path), path)
