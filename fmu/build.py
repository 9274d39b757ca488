"""Build the native FMI 2.0 Co-Simulation FMUs: the compensator and the virtual machine.

One set of C sources (mtcomp/fmu/c) serves every machine: the machine description and the
geometric error tables travel as resource files written here from the Python `Machine` and
`ErrorSet`, the setting and location errors as parameters.  The archive carries its sources
(listed in <SourceFiles>) so an importer can rebuild the binary with `fmpy compile`; here the
linux64 binary is built through fmpy's cmake support (gcc).  Layout and variables: docs/fmu.md.
"""
from __future__ import annotations

import datetime as _dt
import hashlib
import html
import math
import os
import shutil
import sys
import tempfile
import uuid
import zipfile
from dataclasses import dataclass
from functools import lru_cache
from importlib import resources
from pathlib import Path
from xml.etree import ElementTree as ET

import numpy as np

from .._io import MtcompError, atomic_path
from ..errors import ErrorSet
from ..machine import Machine, load_machine

__all__ = ["build_compensator_fmu", "build_machine_fmu", "MachineDynamics", "Var", "write_model_description",
           "machine_resource_text", "C_SOURCES", "FmuBuildError", "cache_dir", "build_passthrough_fmu"]

# Value references: must match fmu/c/common.h, compensator.c and machine.c.
VR_CMD, VR_TOOL, VR_WP_T, VR_WP_A, VR_LOC = 0, 20, 23, 26, 40
VR_OUT, VR_TOL, VR_RESIDUAL = 10, 30, 31
IVR_MAXIT, IVR_ITERS = 0, 1
SVR_TABLES = 0
VR_SPINDLE, VR_KV, VR_BACKLASH, VR_TAU, VR_GAIN, VR_AMBIENT, VR_DRIFT, VR_NOISE = 9, 100, 110, 120, 121, 122, 123, 126
VR_P, VR_V, VR_TEMP, VR_ACT = 130, 133, 136, 140
VR_TIN, VR_EXCESS, VR_TREF, VR_DELAY, VR_BREAK, VR_COULOMB, VR_FTAU = 127, 128, 129, 150, 160, 170, 180
VR_GH, VR_GT = 190, 200
VR_VFC, VR_VFB, VR_VFS, VR_VEL = 210, 220, 230, 240
VR_EP, VR_EA1, VR_EPH1, VR_EA2, VR_EPH2 = 250, 260, 270, 280, 290
IVR_SEED, IVR_DRIVER, IVR_INTERP = 0, 1, 2
THERMAL_DRIVERS = {"spindle": 0, "temperature": 1, "time": 2}
# Parameter ranges enforced by the C code (common.h, machine.c); declared as min/max too.
MAX_TOOL_OFFSET, MAX_WP_TRANSLATION, MAX_WP_ANGLE, MAX_LOC_LINEAR, MAX_LOC_ANGLE = 50.0, 500.0, 30.0, 5.0, 0.05

C_SOURCES = {
    "compensator": ("fmi2_base.c", "common.c", "mtk.c", "compensator.c"),
    "machine": ("fmi2_base.c", "common.c", "mtk.c", "machine.c"),
    "passthrough": ("fmi2_base.c", "mtk.c", "passthrough.c"),   # the do-nothing benchmark baseline
}
C_HEADERS = ("model.h", "common.h", "mtk.h")
FMI2_HEADERS = ("fmi2Functions.h", "fmi2FunctionTypes.h", "fmi2TypesPlatform.h")
FMI3_HEADERS = ("fmi3Functions.h", "fmi3FunctionTypes.h", "fmi3PlatformTypes.h")
_XYZ = ("x", "y", "z")


class FmuBuildError(MtcompError):
    """The FMU could not be built (compiler missing, compilation failed)."""


@dataclass(frozen=True)
class Var:
    """One model variable of an FMI 2.0 modelDescription."""
    name: str
    vr: int
    causality: str                  # parameter | input | output
    description: str
    type: str = "Real"              # Real | Integer | String
    variability: str | None = None  # default: continuous for Real inputs/outputs, fixed/tunable params
    start: float | int | str | None = None
    unit: str | None = None
    display_unit: str | None = None
    min: float | None = None
    max: float | None = None
    depends_on: tuple[str, ...] | None = None   # outputs: inputs with direct feed-through (None: all)

    @property
    def effective_variability(self) -> str:
        if self.variability is not None:
            return self.variability
        if self.causality == "parameter":
            return "fixed"
        return "continuous" if self.type == "Real" else "discrete"

    def type_attributes(self) -> dict:
        """unit, displayUnit, min and max as XML attributes (FMI 2.0 puts them on the type
        element, FMI 3.0 on the variable)."""
        a = {}
        if self.type == "Real":
            if self.unit:
                a["unit"] = self.unit
            if self.display_unit:
                a["displayUnit"] = self.display_unit
        for key, value in (("min", self.min), ("max", self.max)):
            if value is not None:
                a[key] = _fmt(value) if self.type == "Real" else str(int(value))
        return a

    @property
    def initial(self) -> str | None:
        if self.causality == "parameter":
            return "exact"
        if self.causality == "output":
            return "calculated"
        return None


# name -> (base unit exponents, factor, offset, display units {name: (factor, offset)})
UNITS = {
    "mm": ({"m": 1}, 1e-3, 0.0, {"um": (1e3, 0.0), "nm": (1e6, 0.0)}),
    "deg": ({"rad": 1}, math.pi / 180.0, 0.0, {"arcsec": (3600.0, 0.0)}),
    "rad": ({"rad": 1}, 1.0, 0.0, {"urad": (1e6, 0.0)}),
    "s": ({"s": 1}, 1.0, 0.0, {}),
    "1/s": ({"s": -1}, 1.0, 0.0, {}),
    "mm/s": ({"m": 1, "s": -1}, 1e-3, 0.0, {}),
    "deg/s": ({"rad": 1, "s": -1}, math.pi / 180.0, 0.0, {}),
    "1/min": ({"s": -1}, 1.0 / 60.0, 0.0, {}),
    "degC": ({"K": 1}, 1.0, 273.15, {}),
    "mm/K": ({"m": 1, "K": -1}, 1e-3, 0.0, {"um/K": (1e3, 0.0)}),
    "K.min": ({"K": 1, "s": 1}, 60.0, 0.0, {}),
    "K": ({"K": 1}, 1.0, 0.0, {}),
    "1": ({}, 1.0, 0.0, {}),
}


def _unit_definitions(root: ET.Element, used) -> None:
    """<UnitDefinitions> of the units in `used` (same element in FMI 2.0 and 3.0)."""
    ud = ET.SubElement(root, "UnitDefinitions")
    for name in sorted(used):
        base, factor, offset, displays = UNITS[name]
        u = ET.SubElement(ud, "Unit", {"name": name})
        attrs = {k: str(e) for k, e in base.items()}
        if factor != 1.0:
            attrs["factor"] = repr(factor)
        if offset:
            attrs["offset"] = repr(offset)
        ET.SubElement(u, "BaseUnit", attrs)
        for dname, (dfac, doff) in displays.items():
            da = {"name": dname, "factor": repr(dfac)}
            if doff:
                da["offset"] = repr(doff)
            ET.SubElement(u, "DisplayUnit", da)


def _fmt(x: float) -> str:
    return repr(float(x)) if not float(x).is_integer() or abs(x) >= 1e15 else str(int(x)) + ".0"


def write_model_description(*, model_name: str, identifier: str, description: str, variables: list[Var],
                            sources: tuple[str, ...], guid: str, step: float = 1e-3, stop: float = 1.0) -> bytes:
    """modelDescription.xml (FMI 2.0 Co-Simulation) for native C sources: every Real with a
    unit, outputs listed under Outputs and InitialUnknowns so validators find the structure."""
    root = ET.Element("fmiModelDescription", {
        "fmiVersion": "2.0", "modelName": model_name, "guid": guid, "description": description,
        "author": "mtcomp", "version": _pkg_version(), "generationTool": f"mtcomp {_pkg_version()}",
        "generationDateAndTime": _dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ"),
        "variableNamingConvention": "structured", "numberOfEventIndicators": "0"})
    cs = ET.SubElement(root, "CoSimulation", {
        "modelIdentifier": identifier, "needsExecutionTool": "false",
        "canHandleVariableCommunicationStepSize": "true", "canInterpolateInputs": "false",
        "canBeInstantiatedOnlyOncePerProcess": "false", "canNotUseMemoryManagementFunctions": "true",
        "canGetAndSetFMUstate": "true", "canSerializeFMUstate": "true",
        "providesDirectionalDerivative": "false"})
    sf = ET.SubElement(cs, "SourceFiles")
    for s in sources:
        ET.SubElement(sf, "File", {"name": s})
    _unit_definitions(root, {v.unit for v in variables if v.unit})
    ET.SubElement(ET.SubElement(root, "LogCategories"), "Category",
                  {"name": "logStatusError", "description": "Calls the FMU rejects"})
    root[-1].append(ET.Element("Category", {"name": "logError", "description": "Invalid parameters or resources, failed evaluations"}))
    root[-1].append(ET.Element("Category", {"name": "logAll", "description": "Information"}))
    ET.SubElement(root, "DefaultExperiment", {"startTime": "0.0", "stopTime": _fmt(stop), "stepSize": repr(step)})
    mv = ET.SubElement(root, "ModelVariables")
    index = {}
    for i, v in enumerate(variables, 1):
        index[v.name] = i
        attrs = {"name": v.name, "valueReference": str(v.vr), "description": v.description, "causality": v.causality}
        attrs["variability"] = v.effective_variability
        if v.initial:
            attrs["initial"] = v.initial
        sv = ET.SubElement(mv, "ScalarVariable", attrs)
        ta = v.type_attributes()
        if v.start is not None and v.causality != "output":
            ta["start"] = (_fmt(v.start) if v.type == "Real" else str(int(v.start)) if v.type == "Integer"
                           else str(v.start))
        ET.SubElement(sv, v.type, ta)
    ms = ET.SubElement(root, "ModelStructure")
    outs = [v for v in variables if v.causality == "output"]
    o = ET.SubElement(ms, "Outputs")
    for v in outs:
        attrs = {"index": str(index[v.name])}
        if v.depends_on is not None:   # "" = no direct feed-through from any input
            attrs["dependencies"] = " ".join(str(index[d]) for d in v.depends_on)
            attrs["dependenciesKind"] = " ".join("dependent" for _ in v.depends_on)
        ET.SubElement(o, "Unknown", attrs)
    iu = ET.SubElement(ms, "InitialUnknowns")
    for v in outs:
        ET.SubElement(iu, "Unknown", {"index": str(index[v.name])})
    ET.indent(root)
    return b'<?xml version="1.0" encoding="UTF-8"?>\n' + ET.tostring(root, encoding="utf-8")


VR3_OFFSET = {"Real": 0, "Integer": 1000, "String": 2000}   # fmi3_base.c: references unique across types
VR3_TIME = 3000
_TYPE3 = {"Real": "Float64", "Integer": "Int32", "String": "String"}


def write_model_description3(*, model_name: str, identifier: str, description: str, variables: list[Var],
                             guid: str, step: float = 1e-3, stop: float = 1.0) -> bytes:
    """modelDescription.xml (FMI 3.0 Co-Simulation) of the same variables; value references are
    made unique across types as fmi3_base.c maps them, plus the independent variable `time`."""
    root = ET.Element("fmiModelDescription", {
        "fmiVersion": "3.0", "modelName": model_name, "instantiationToken": guid, "description": description,
        "author": "mtcomp", "version": _pkg_version(), "generationTool": f"mtcomp {_pkg_version()}",
        "generationDateAndTime": _dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ"),
        "variableNamingConvention": "structured"})
    ET.SubElement(root, "CoSimulation", {
        "modelIdentifier": identifier, "needsExecutionTool": "false",
        "canBeInstantiatedOnlyOncePerProcess": "false", "canGetAndSetFMUState": "true",
        "canSerializeFMUState": "true", "providesDirectionalDerivatives": "false",
        "canHandleVariableCommunicationStepSize": "true", "hasEventMode": "false",
        "providesIntermediateUpdate": "false", "canReturnEarlyAfterIntermediateUpdate": "false"})
    _unit_definitions(root, {v.unit for v in variables if v.unit} | {"s"})
    cats = ET.SubElement(root, "LogCategories")
    for n, d in (("logStatusError", "Calls the FMU rejects"),
                 ("logError", "Invalid parameters or resources, failed evaluations"), ("logAll", "Information")):
        ET.SubElement(cats, "Category", {"name": n, "description": d})
    ET.SubElement(root, "DefaultExperiment", {"startTime": "0.0", "stopTime": _fmt(stop), "stepSize": repr(step)})
    mv = ET.SubElement(root, "ModelVariables")
    ET.SubElement(mv, "Float64", {"name": "time", "valueReference": str(VR3_TIME), "causality": "independent",
                                  "variability": "continuous", "description": "Simulation time", "unit": "s"})
    for v in variables:
        attrs = {"name": v.name, "valueReference": str(VR3_OFFSET[v.type] + v.vr), "description": v.description,
                 "causality": v.causality}
        attrs["variability"] = v.effective_variability
        if v.initial:
            attrs["initial"] = v.initial
        attrs.update(v.type_attributes())
        start = v.start if v.causality != "output" else None
        if start is not None and v.type != "String":
            attrs["start"] = _fmt(start) if v.type == "Real" else str(int(start))
        el = ET.SubElement(mv, _TYPE3[v.type], attrs)
        if start is not None and v.type == "String":
            ET.SubElement(el, "Start", {"value": str(start)})
    ms = ET.SubElement(root, "ModelStructure")
    outs = [v for v in variables if v.causality == "output"]
    by_name = {v.name: v for v in variables}
    for v in outs:
        attrs = {"valueReference": str(VR3_OFFSET[v.type] + v.vr)}
        if v.depends_on is not None:
            attrs["dependencies"] = " ".join(str(VR3_OFFSET[by_name[d].type] + by_name[d].vr) for d in v.depends_on)
            attrs["dependenciesKind"] = " ".join("dependent" for _ in v.depends_on)
        ET.SubElement(ms, "Output", attrs)
    for v in outs:
        ET.SubElement(ms, "InitialUnknown", {"valueReference": str(VR3_OFFSET[v.type] + v.vr)})
    ET.indent(root)
    return b'<?xml version="1.0" encoding="UTF-8"?>\n' + ET.tostring(root, encoding="utf-8")


def write_build_description(identifier: str, sources: tuple[str, ...]) -> bytes:
    """sources/buildDescription.xml (FMI 3.0): how an importer compiles the sources."""
    root = ET.Element("fmiBuildDescription", {"fmiVersion": "3.0"})
    bc = ET.SubElement(root, "BuildConfiguration", {"modelIdentifier": identifier})
    sfs = ET.SubElement(bc, "SourceFileSet", {"language": "C99"})
    for s in sources:
        ET.SubElement(sfs, "SourceFile", {"name": s})
    ET.indent(root)
    return b'<?xml version="1.0" encoding="UTF-8"?>\n' + ET.tostring(root, encoding="utf-8")


def _pkg_version() -> str:
    from .. import __version__
    return __version__


def machine_resource_text(machine: Machine) -> str:
    """The machine description resource read by mtk_load_machine (docs/fmu.md)."""
    lines = ["# mtcomp machine description for the native FMU kernel; axes from the workpiece to the tool",
             "# axis NAME KIND SIDE direction(3) location(3, mm) travel-low travel-high resolution",
             "mtcomp-machine 1", f"name {machine.name}",
             "tool_point " + " ".join(repr(float(x)) for x in machine.tool_point),
             "tool_axis " + " ".join(repr(float(x)) for x in machine.tool_axis)]
    for a in machine.axes:
        lo, hi = (float(x) for x in a.limits)
        lim = [repr(x) if math.isfinite(x) else ("-1e300" if x < 0 else "1e300") for x in (lo, hi)]
        lines.append(f"axis {a.name} {a.kind} {a.side} " + " ".join(repr(float(x)) for x in a.direction) + " "
                     + " ".join(repr(float(x)) for x in a.location) + " " + " ".join(lim)
                     + f" {float(a.resolution)!r}")
    return "\n".join(lines) + "\n"


def _axis_unit(machine: Machine, i: int) -> tuple[str, str | None]:
    return ("deg", None) if machine.axes[i].is_rotary else ("mm", "um")


def _common_vars(machine: Machine) -> list[Var]:
    vs = []
    for i, a in enumerate(machine.axes):
        unit, _ = _axis_unit(machine, i)
        vs.append(Var(f"command.{a.name}", VR_CMD + i, "input",
                      f"Commanded position of axis {a.name} ({a.kind}, {a.side} side) as programmed, {unit}",
                      start=0.0, unit=unit))
    return vs


def _param_vars(machine: Machine, errors: ErrorSet, tables_spec: str) -> list[Var]:
    vs = []
    for k, c in enumerate(_XYZ):
        vs.append(Var(f"tool_setting.offset.{c}", VR_TOOL + k, "parameter",
                      f"Tool setting error: {c} of the vector from the nominal tool point to the real edge, "
                      "in the frame of the last tool-side axis", variability="tunable",
                      start=errors.tool.offset[k], unit="mm", display_unit="um",
                      min=-MAX_TOOL_OFFSET, max=MAX_TOOL_OFFSET))
    for k, c in enumerate(_XYZ):
        vs.append(Var(f"workpiece_setting.translation.{c}", VR_WP_T + k, "parameter",
                      f"Workpiece setting error: {c} of the real workpiece origin in the nominal workpiece frame",
                      variability="tunable", start=errors.workpiece.translation[k], unit="mm", display_unit="um",
                      min=-MAX_WP_TRANSLATION, max=MAX_WP_TRANSLATION))
    for k, c in enumerate("abc"):
        vs.append(Var(f"workpiece_setting.angle.{c}", VR_WP_A + k, "parameter",
                      f"Workpiece setting error: rotation {c} about {'XYZ'[k]} of the real workpiece frame "
                      "(R = Rz(c) Ry(b) Rx(a))", variability="tunable", start=errors.workpiece.angles[k],
                      unit="deg", display_unit="arcsec", min=-MAX_WP_ANGLE, max=MAX_WP_ANGLE))
    loc = errors.geometric.location
    for i, a in enumerate(machine.axes):
        for k, c in enumerate("XYZABC"):
            name = f"E{c}0{a.name}"
            lin = k < 3
            vs.append(Var(f"location.{name}", VR_LOC + 6 * i + k, "parameter",
                          f"Location error {name} (ISO 230-1) of axis {a.name}: "
                          + ("offset along " + c if lin else "rotation about " + c),
                          start=loc.get(name, 0.0), unit="mm" if lin else "rad",
                          display_unit="um" if lin else "urad",
                          min=-(MAX_LOC_LINEAR if lin else MAX_LOC_ANGLE), max=MAX_LOC_LINEAR if lin else MAX_LOC_ANGLE))
    vs.append(Var("geometric_tables", SVR_TABLES, "parameter",
                  "Component error tables as 'AXIS:path;...', paths relative to the resources folder "
                  "(CSV: position,E?AXIS..., mm and rad; empty: none)", type="String", start=tables_spec))
    return vs


@dataclass(frozen=True)
class MachineDynamics:
    """Start values of the machine FMU's dynamic parameters (docs/model-loop.md, "The machine
    FMU's dynamics"; mtcomp.model.machine_ref is the same model in Python).

    kv: servo gain per axis in 1/s (0: ideal servo, at the command by the end of each step);
    interpolation: 0 the servo holds each command over the step, 1 it follows the command
    linearly from the previous step's (ramp invariant); backlash per axis in mm or deg (negative:
    an over-compensated backlash, the mirror of the play about the servo position);
    delay: transport delay of the commands (s); friction_breakaway, friction_coulomb per axis
    (mm or deg) and friction_tau (s): at a reversal static friction holds the slide until the
    drive has wound up by the breakaway distance, then it catches up with time constant tau to a
    lag of the Coulomb distance; glitch_height per axis (mm or deg) and glitch_time (s): the
    quadrant glitch in the diagnosis' spike form, a lag of height s exp(1 - s), s = (t -
    t_reversal)/glitch_time, against the new direction after each reversal of the drive's
    motion (glitch_time 0: none); velfriction_coulomb per axis (mm/s or deg/s, c),
    velfriction_viscous (1, b) and velfriction_vs (mm/s or deg/s, v_s; 0: sign): velocity
    friction of a velocity-mode axis, its actual velocity v - c tanh(v/v_s) - b v for the
    drive's velocity v, its position the integral of that (0: off); encoder_period per axis (mm or
    deg; 0: off), encoder_a1, encoder_a2 (mm or deg) and encoder_phase1, encoder_phase2 (deg): the
    encoder's cyclic error, a1 sin(2 pi p/period + phase1) + a2 sin(4 pi p/period + phase2) added
    to the actual position p the other elements give.  Thermal: thermal_driver "spindle" (T -> ambient + gain *
    spindle speed), "temperature" (T -> ambient + the change of the temperature input since the
    start) or "time" (T -> ambient: the initial excess relaxes) (or 0, 1, 2), time constant (s),
    gain (K per 1/min of spindle speed), ambient (degC), initial_excess (K: T at the start =
    ambient + excess), reference (degC, where the drift is zero; None: ambient) and drift of the
    tool edge in the tool frame (mm/K); noise: standard deviation (mm) of the tool edge
    measurement with its seed.
    """
    kv: tuple[float, ...] | float = 0.0
    backlash: tuple[float, ...] | float = 0.0
    thermal_time_constant: float = 600.0
    thermal_gain: float = 0.0
    ambient: float = 20.0
    drift: tuple[float, float, float] = (0.0, 0.0, 0.0)
    noise: float = 0.0
    seed: int = 1
    thermal_driver: str | int = "spindle"
    initial_excess: float = 0.0
    reference: float | None = None
    delay: float = 0.0
    friction_breakaway: tuple[float, ...] | float = 0.0
    friction_coulomb: tuple[float, ...] | float = 0.0
    friction_tau: tuple[float, ...] | float = 0.0
    interpolation: int = 0
    glitch_height: tuple[float, ...] | float = 0.0
    glitch_time: tuple[float, ...] | float = 0.0
    velfriction_coulomb: tuple[float, ...] | float = 0.0
    velfriction_viscous: tuple[float, ...] | float = 0.0
    velfriction_vs: tuple[float, ...] | float = 0.0
    encoder_period: tuple[float, ...] | float = 0.0
    encoder_a1: tuple[float, ...] | float = 0.0
    encoder_phase1: tuple[float, ...] | float = 0.0
    encoder_a2: tuple[float, ...] | float = 0.0
    encoder_phase2: tuple[float, ...] | float = 0.0

    def per_axis(self, value, n: int, name: str) -> tuple[float, ...]:
        if np.ndim(value) == 0:
            return (float(value),) * n
        v = tuple(float(x) for x in value)
        if len(v) != n:
            raise MtcompError(f"{name}: expected {n} values (one per axis), got {len(v)}")
        return v

    @property
    def driver_code(self) -> int:
        """thermal.driver of the FMU: 0 spindle speed, 1 temperature input, 2 none (time)."""
        d = self.thermal_driver
        if isinstance(d, str):
            if d not in THERMAL_DRIVERS:
                raise MtcompError(f"thermal_driver: expected one of {', '.join(THERMAL_DRIVERS)}, got {d!r}")
            return THERMAL_DRIVERS[d]
        if int(d) not in (0, 1, 2):
            raise MtcompError(f"thermal_driver: expected 0, 1 or 2, got {d!r}")
        return int(d)

    @property
    def reference_temperature(self) -> float:
        return float(self.ambient if self.reference is None else self.reference)


def _resources(machine: Machine, errors: ErrorSet, res: Path) -> str:
    res.mkdir(parents=True)
    (res / "machine.txt").write_text(machine_resource_text(machine), encoding="utf-8")
    items = []
    if errors.geometric.tables:
        (res / "tables").mkdir()
        for ax, t in errors.geometric.tables.items():
            if ax not in machine.axis_names:
                raise MtcompError(f"error table for axis {ax}, but machine {machine.name} has axes "
                                  f"{' '.join(machine.axis_names)}")
            (res / "tables" / f"{ax}.csv").write_text(t.to_csv(), encoding="utf-8")
            items.append(f"{ax}:tables/{ax}.csv")
    return ";".join(items)


def _documentation(doc: Path, title: str, summary: str, variables: list[Var], machine: Machine,
                   fmi_version: int = 2) -> None:
    doc.mkdir(parents=True)
    rows = "\n".join(
        f"<tr><td><code>{html.escape(v.name)}</code></td><td>{v.causality}</td><td>{v.type}</td>"
        f"<td>{html.escape(v.unit or '')}</td><td>{html.escape(v.description)}</td></tr>" for v in variables)
    axes = ", ".join(f"{a.name} ({a.kind}, {a.side} side)" for a in machine.axes)
    page = f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>{html.escape(title)}</title>
<style>body{{font-family:sans-serif;max-width:60em;margin:2em auto}}td,th{{border-bottom:1px solid #ccc;padding:2px 6px;text-align:left}}</style>
</head><body>
<h1>{html.escape(title)}</h1>
<p>{html.escape(summary)}</p>
<p>Machine <b>{html.escape(machine.name)}</b>: axes from the workpiece to the tool: {html.escape(axes)}.
Units: mm, deg, s, degC; geometric error angles in rad. Every axis motion is the motion of the tool relative to
the workpiece (ISO 841).</p>
<p>FMI {fmi_version}.0 Co-Simulation, native C (no Python at run time). The C sources are in <code>sources/</code>
(rebuild for another platform with <code>fmpy compile</code>); the machine description and the geometric
error tables are in <code>resources/</code>. Invalid parameters (NaN, out of range, missing or malformed
resource tables) make the FMU return fmi{fmi_version}Error with a log message naming the variable or file.</p>
<h2>Variables</h2>
<table><tr><th>Name</th><th>Causality</th><th>Type</th><th>Unit</th><th>Description</th></tr>
{rows}
</table>
<p>Generated by mtcomp {html.escape(_pkg_version())}; see docs/fmu.md in the mtcomp sources.</p>
</body></html>
"""
    (doc / "index.html").write_text(page, encoding="utf-8")
    (doc / "externalDependencies.txt").write_text(
        "This FMU has no external dependencies: it needs no tool, licence, network access or Python\n"
        "interpreter. The binary links only the C runtime and libm. Everything it reads is inside the\n"
        "archive: resources/machine.txt and the error tables under resources/tables/.\n", encoding="utf-8")


def _copy_sources(kind: str, src_dir: Path, fmi_version: int = 2) -> tuple[str, ...]:
    src_dir.mkdir(parents=True)
    here = resources.files("mtcomp.fmu").joinpath("c")
    files = C_SOURCES[kind] if fmi_version == 2 else ("fmi3_base.c",) + C_SOURCES[kind]
    for name in files + C_HEADERS:
        with resources.as_file(here.joinpath(name)) as p:
            shutil.copyfile(p, src_dir / name)
    try:
        import fmpy
    except ImportError:  # pragma: no cover - fmpy is a dependency of the fmu extra
        raise FmuBuildError("fmpy is needed to build FMUs (pip install mtcomp[fmu])") from None
    ccode = Path(fmpy.__file__).parent / "c-code"
    for h in FMI2_HEADERS + (FMI3_HEADERS if fmi_version == 3 else ()):
        shutil.copyfile(ccode / h, src_dir / h)
    # model.h reads the FMI version from here: an FMI 3 binary keeps its FMI 2 layer unexported,
    # whoever compiles the sources (this build, `fmpy compile`, an importer's own toolchain).
    (src_dir / "mtcomp_fmi.h").write_text(f"#define MTCOMP_FMI_VERSION {fmi_version}\n", encoding="ascii")
    return files


# Only the FMI functions leave the binary: with the kernel's and the model's functions exported, a
# second mtcomp FMU loaded with RTLD_GLOBAL in the same process would have its calls bound to the
# first one's copies (another model's value references).  The FMI headers mark the fmi2*/fmi3*
# functions visibility("default"); everything else is hidden.
HIDDEN = ("-fvisibility=hidden",)


def _compile(unzipdir: Path, compiler: str = "cmake") -> None:
    """Compile the binary for this platform from the archive's sources, quietly (the compiler
    output is kept for errors).  compiler="cmake": fmpy's CMake project, the same build
    `fmpy compile` runs; "cc": one direct call of the C compiler (gcc), several times faster."""
    import subprocess
    import fmpy
    from fmpy.build import create_cmake_settings
    if compiler == "cc":
        import sysconfig
        cc = os.environ.get("CC") or shutil.which("cc") or shutil.which("gcc")
        if not cc:
            raise FmuBuildError("no C compiler found (cc/gcc)")
        if fmpy.system != "linux":
            raise FmuBuildError('compiler="cc" builds linux binaries only; use compiler="cmake"')
        md = fmpy.read_model_description(unzipdir)
        ident = md.coSimulation.modelIdentifier
        files = [str(unzipdir / "sources" / f) for f in md.buildConfigurations[0].sourceFileSets[0].sourceFiles]
        platform = fmpy.platform if md.fmiVersion == "2.0" else fmpy.platform_tuple
        out = unzipdir / "binaries" / platform / f"{ident}{sysconfig.get_config_var('SHLIB_SUFFIX') or '.so'}"
        out.parent.mkdir(parents=True, exist_ok=True)
        cmd = [cc, "-shared", "-fPIC", "-O2", "-std=c99", *HIDDEN, "-I", str(unzipdir / "sources"), *files, "-o", str(out), "-lm"]
        try:
            run = subprocess.run(cmd, capture_output=True, text=True)
        except OSError as exc:
            raise FmuBuildError(f"cannot run the C compiler {cc}: {exc}") from None
        if run.returncode:
            raise FmuBuildError(f"compiling the FMU failed:\n{run.stderr[-3000:]}")
        return
    if compiler != "cmake":
        raise FmuBuildError(f"compiler must be 'cmake' or 'cc', got {compiler!r}")
    if shutil.which("cmake") is None:
        raise FmuBuildError("cmake not found (pip install cmake): needed to compile the FMU")
    source_dir = Path(fmpy.__file__).parent / "c-code"
    with tempfile.TemporaryDirectory(prefix="mtcomp-fmu-build-") as bd:
        # -lm at the end of the link line: the kernel uses libm and plain C hosts may not load it.
        create_cmake_settings(unzipdir, bd, cmake_options={"CMAKE_C_STANDARD_LIBRARIES:STRING": "-lm",
                                                           "CMAKE_C_VISIBILITY_PRESET:STRING": "hidden"})
        for cmd in (["cmake", "-S", str(source_dir), "-B", bd],
                    ["cmake", "--build", bd, "--target", "install", "--config", "Release"]):
            run = subprocess.run(cmd, capture_output=True, text=True)
            if run.returncode:
                raise FmuBuildError(f"compiling the FMU failed ({' '.join(cmd[:2])}):\n{run.stdout[-3000:]}"
                                    f"{run.stderr[-3000:]}")


WIN64_CC = "x86_64-w64-mingw32-gcc"


def _compile_win64(root: Path, identifier: str, files: tuple[str, ...], fmi_version: int) -> None:
    """Cross-compile the win64 DLL with mingw-w64 (Debian gcc-mingw-w64-x86-64): the same
    sources, libgcc linked statically so the DLL imports only KERNEL32 and msvcrt."""
    import subprocess
    cc = shutil.which(WIN64_CC)
    if cc is None:
        raise FmuBuildError(f"{WIN64_CC} not found: install mingw-w64 (Debian: gcc-mingw-w64-x86-64) "
                            "for win64 binaries")
    plat = "win64" if fmi_version == 2 else "x86_64-windows"
    out = root / "binaries" / plat / f"{identifier}.dll"
    out.parent.mkdir(parents=True, exist_ok=True)
    src = root / "sources"
    cmd = [cc, "-shared", "-O2", "-std=c99", "-I", str(src), *(str(src / f) for f in files), "-o", str(out),
           "-static-libgcc", "-Wl,--no-insert-timestamp"]
    run = subprocess.run(cmd, capture_output=True, text=True)
    if run.returncode:
        raise FmuBuildError(f"cross-compiling the win64 binary failed:\n{run.stderr[-3000:]}")


def cache_dir() -> Path | None:
    """Folder of the compiled-binary cache: $MTCOMP_CACHE_DIR, else $XDG_CACHE_HOME/mtcomp or
    ~/.cache/mtcomp; MTCOMP_CACHE_DIR=off disables the cache."""
    env = os.environ.get("MTCOMP_CACHE_DIR")
    if env is not None:
        return None if env.strip().lower() in ("", "off", "0", "none") else Path(env) / "fmu-binaries"
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "mtcomp" / "fmu-binaries"


def _binaries_key(root: Path, identifier: str, compiler: str, windows: bool) -> str:
    """Hash of everything that determines the binaries: the archive's sources (the C files,
    headers and build description; the machine, errors and GUID live in resources/ and the
    modelDescription, not in the binary), the identifier, the compiler route, flags and targets."""
    import platform as _pf
    h = hashlib.sha256()
    for f in sorted((root / "sources").rglob("*")):
        if f.is_file():
            h.update(f.relative_to(root).as_posix().encode() + b"\0" + f.read_bytes() + b"\0")
    for part in (identifier, compiler, " ".join(HIDDEN), f"win64={windows}", sys.platform, _pf.machine(),
                 os.environ.get("CC", ""), str(shutil.which(WIN64_CC) if windows else "")):
        h.update(part.encode() + b"\0")
    return h.hexdigest()[:32]


def _binaries(root: Path, identifier: str, files: tuple[str, ...], fmi_version: int, compiler: str,
              windows: bool) -> None:
    """binaries/ of the archive: from the cache when the same sources were compiled before
    (a co-simulation builds the same two FMUs for every run), else compiled and cached."""
    cache = cache_dir()
    key = _binaries_key(root, identifier, compiler, windows)
    hit = cache / key / "binaries" if cache else None
    if hit is not None and hit.is_dir():
        shutil.copytree(hit, root / "binaries", dirs_exist_ok=True)
        return
    _compile(root, compiler)
    if windows:
        _compile_win64(root, identifier, files, fmi_version)
    if cache is None:
        return
    try:   # publish atomically: a half-copied entry is never seen under its key
        cache.mkdir(parents=True, exist_ok=True)
        tmp = Path(tempfile.mkdtemp(prefix=f".{key}-", dir=cache))
        shutil.copytree(root / "binaries", tmp / "binaries")
        try:
            os.replace(tmp, cache / key)
        except OSError:   # another process cached the same key first
            shutil.rmtree(tmp, ignore_errors=True)
    except OSError:
        pass   # a read-only or full cache folder only costs the next build its compile


def _model_png(kind: str, machine: Machine) -> bytes:
    """model.png: the FMU's icon (a block with its name and axes), drawn with a matplotlib
    Figure (no pyplot, the caller's backend untouched)."""
    return _icon(kind, machine.name, tuple(machine.axis_names))


@lru_cache(maxsize=32)
def _icon(kind: str, name: str, axes: tuple[str, ...]) -> bytes:
    import io
    from matplotlib.figure import Figure
    from matplotlib.patches import FancyBboxPatch
    fig = Figure(figsize=(2.0, 2.0), dpi=100)
    ax = fig.add_axes((0, 0, 1, 1))
    ax.set_axis_off()
    ax.set_xlim(0, 1)
    ax.set_ylim(0, 1)
    colour = "#1f5fa0" if kind == "compensator" else "#2e7d32"
    ax.add_patch(FancyBboxPatch((0.08, 0.08), 0.84, 0.84, boxstyle="round,pad=0.0,rounding_size=0.08",
                                facecolor=colour, edgecolor="none"))
    ax.text(0.5, 0.74, "mtcomp", color="white", ha="center", va="center", fontsize=15, weight="bold")
    ax.text(0.5, 0.54, kind, color="white", ha="center", va="center", fontsize=12)
    ax.text(0.5, 0.34, " ".join(axes), color="white", ha="center", va="center", fontsize=12, family="monospace")
    ax.text(0.5, 0.18, name, color="#dde8f5", ha="center", va="center", fontsize=7)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", transparent=True)
    return buf.getvalue()


def _zip(folder: Path, out: Path) -> Path:
    with atomic_path(out) as tmp:
        with zipfile.ZipFile(tmp, "w", zipfile.ZIP_DEFLATED) as zf:
            for p in sorted(folder.rglob("*")):
                if p.is_file():
                    zf.write(p, p.relative_to(folder).as_posix())
    return out


def _start_values(variables: list[Var], guid: str) -> str:
    """resources/start.txt: the FMU's GUID and the parameters' start values, read by the C code
    at instantiation so its defaults are the modelDescription's start values and an importer
    passing another FMU's GUID is refused."""
    lines = ["# GUID of modelDescription.xml, then parameter start values: kind value-reference value",
             f"guid {guid}"]
    for v in variables:
        if v.causality != "parameter" or v.start is None:
            continue
        if v.type == "Real":
            lines.append(f"r {v.vr} {float(v.start)!r}")
        elif v.type == "Integer":
            lines.append(f"i {v.vr} {int(v.start)}")
        else:
            if "\n" in str(v.start):
                raise MtcompError(f"{v.name}: start value must be one line")
            lines.append(f"s {v.vr} {v.start}")
    return "\n".join(lines) + "\n"


def _guid(*parts: str) -> str:
    h = hashlib.sha256("\0".join(parts).encode()).hexdigest()
    return "{" + str(uuid.UUID(h[:32])) + "}"


def _build(kind: str, machine: Machine, errors: ErrorSet, out_path, identifier: str, title: str, summary: str,
           extra_vars, compile_binary: bool, compiler: str, fmi_version: int = 2,
           windows: bool | None = None, with_parameters: bool = True) -> Path:
    if fmi_version not in (2, 3):
        raise MtcompError(f"fmi_version must be 2 or 3, got {fmi_version!r}")
    out_path = Path(out_path)
    with tempfile.TemporaryDirectory(prefix="mtcomp-fmu-") as td:
        root = Path(td) / "fmu"
        tables_spec = _resources(machine, errors, root / "resources")
        variables = _common_vars(machine) + extra_vars + (_param_vars(machine, errors, tables_spec)
                                                          if with_parameters else [])
        for v in variables:   # the C code refuses these values; refuse to build such an FMU
            lo = -math.inf if v.min is None else v.min
            hi = math.inf if v.max is None else v.max
            if v.type != "String" and v.start is not None and not lo <= v.start <= hi:
                raise MtcompError(f"{v.name} = {v.start!r} is outside [{v.min}, {v.max}], the range the FMU accepts")
        guid = _guid(kind, identifier, str(fmi_version), machine_resource_text(machine), repr(variables))
        (root / "resources" / "start.txt").write_text(_start_values(variables, guid), encoding="utf-8")
        sources = _copy_sources(kind, root / "sources", fmi_version)
        if fmi_version == 2:
            md = write_model_description(model_name=f"{title} ({machine.name})", identifier=identifier,
                                         description=summary, variables=variables, sources=sources, guid=guid)
        else:
            md = write_model_description3(model_name=f"{title} ({machine.name})", identifier=identifier,
                                          description=summary, variables=variables, guid=guid)
            (root / "sources" / "buildDescription.xml").write_bytes(write_build_description(identifier, sources))
        (root / "modelDescription.xml").write_bytes(md)
        _documentation(root / "documentation", f"{title}: {machine.name}", summary, variables, machine, fmi_version)
        (root / "model.png").write_bytes(_model_png(kind, machine))
        if compile_binary:
            if windows is None:
                windows = shutil.which(WIN64_CC) is not None
            elif windows and shutil.which(WIN64_CC) is None:
                raise FmuBuildError(f"{WIN64_CC} not found: install mingw-w64 (Debian: gcc-mingw-w64-x86-64) "
                                    "for win64 binaries")
            files = C_SOURCES[kind] if fmi_version == 2 else ("fmi3_base.c",) + C_SOURCES[kind]
            _binaries(root, identifier, files, fmi_version, compiler, windows)
        return _zip(root, out_path)


def build_compensator_fmu(machine: Machine | str, out_path, errors: ErrorSet | None = None, *,
                          identifier: str = "mtcomp_compensator", compile_binary: bool = True,
                          compiler: str = "cmake", fmi_version: int = 2, windows: bool | None = None) -> Path:
    """Build the compensator FMU for `machine` (preset name, TOML path or Machine).

    Inputs `command.<AXIS>` (programmed commands), outputs `compensated.<AXIS>` = mtcomp.kinematics
    .retarget of the inputs under the errors; `errors` gives the start values of the setting and
    location parameters and the geometric tables stored as resources.  fmi_version 2 (default) or 3
    (FMI 3.0 Co-Simulation from the same sources).  windows: also cross-compile a win64 binary
    with mingw-w64 (None: when `x86_64-w64-mingw32-gcc` is installed).  Compiled binaries are
    cached by source hash (`cache_dir()`).  Returns the path written.
    """
    machine = load_machine(machine)
    errors = errors or ErrorSet()
    extra = []
    feed = tuple(f"command.{a.name}" for a in machine.axes)   # an algebraic block: every output
    for i, a in enumerate(machine.axes):                      # depends directly on every command
        unit, _ = _axis_unit(machine, i)
        extra.append(Var(f"compensated.{a.name}", VR_OUT + i, "output",
                         f"Compensated command of axis {a.name} for the real machine, {unit}", unit=unit,
                         depends_on=feed))
    extra += [
        Var("residual", VR_RESIDUAL, "output", "Largest residual of the compensation (position, mm; orientation "
            "scaled by 100 mm/rad)", unit="mm", display_unit="nm", depends_on=feed),
        Var("iterations", IVR_ITERS, "output", "Gauss-Newton iterations used at the last evaluation, summed "
            "over the restarts from rotary seeds",
            type="Integer", variability="discrete", depends_on=feed),
        Var("tolerance", VR_TOL, "parameter", "Convergence tolerance of the compensation iteration: it stops when "
            "no axis moves by more than this in one iteration (mm; a rotary axis step in deg is compared with "
            "the same number)", variability="tunable", start=1e-10, unit="mm", min=1e-15, max=1e-3),
        Var("max_iterations", IVR_MAXIT, "parameter", "Iteration limit of the compensation", type="Integer",
            variability="tunable", start=60, min=1, max=1000),
    ]
    summary = ("Machine-tool error compensator: turns programmed axis commands into the commands that put the "
               "real tool edge (with tool setting, workpiece setting and geometric errors) where the ideal "
               "machine would have put it.")
    return _build("compensator", machine, errors, out_path, identifier, "mtcomp compensator", summary, extra,
                  compile_binary, compiler, fmi_version, windows)


def build_passthrough_fmu(machine: Machine | str, out_path, *, identifier: str = "mtcomp_passthrough",
                          compiler: str = "cmake", windows: bool | None = None) -> Path:
    """Build the do-nothing FMU: the compensator's inputs and outputs, outputs = inputs, the same
    FMI wrapper and no kinematics (the baseline of benchmarks/bench_fmu.py)."""
    machine = load_machine(machine)
    feed = tuple(f"command.{a.name}" for a in machine.axes)
    extra = [Var(f"compensated.{a.name}", VR_OUT + i, "output", f"Copy of command.{a.name}, "
                 + _axis_unit(machine, i)[0], unit=_axis_unit(machine, i)[0], depends_on=(feed[i],))
             for i, a in enumerate(machine.axes)]
    summary = "Do-nothing FMU with the compensator's interface (outputs = inputs): a benchmark baseline."
    return _build("passthrough", machine, ErrorSet(), out_path, identifier, "mtcomp passthrough", summary, extra,
                  True, compiler, 2, windows, with_parameters=False)


def build_machine_fmu(machine: Machine | str, out_path, errors: ErrorSet | None = None,
                      dynamics: MachineDynamics | None = None, *, identifier: str = "mtcomp_machine",
                      compile_binary: bool = True, compiler: str = "cmake",
                      fmi_version: int = 2, windows: bool | None = None) -> Path:
    """Build the virtual machine FMU (native C): axis commands and spindle speed in; real tool edge
    position and direction in the real workpiece frame, actual axis positions and temperature out.
    `errors` are the machine's true errors (start values and table resources), `dynamics` the
    servo, backlash, thermal and noise start values."""
    machine = load_machine(machine)
    errors = errors or ErrorSet()
    dyn = dynamics or MachineDynamics()
    n = machine.n_axes
    kv = dyn.per_axis(dyn.kv, n, "kv")
    bl = dyn.per_axis(dyn.backlash, n, "backlash")
    brk = dyn.per_axis(dyn.friction_breakaway, n, "friction_breakaway")
    cou = dyn.per_axis(dyn.friction_coulomb, n, "friction_coulomb")
    ftau = dyn.per_axis(dyn.friction_tau, n, "friction_tau")
    gh = dyn.per_axis(dyn.glitch_height, n, "glitch_height")
    gt = dyn.per_axis(dyn.glitch_time, n, "glitch_time")
    vfc = dyn.per_axis(dyn.velfriction_coulomb, n, "velfriction_coulomb")
    vfb = dyn.per_axis(dyn.velfriction_viscous, n, "velfriction_viscous")
    vfs = dyn.per_axis(dyn.velfriction_vs, n, "velfriction_vs")
    enc = {f: dyn.per_axis(getattr(dyn, f"encoder_{f}"), n, f"encoder_{f}")
           for f in ("period", "a1", "phase1", "a2", "phase2")}
    extra = [Var("spindle_speed", VR_SPINDLE, "input", "Spindle speed driving the thermal drift (thermal.driver = 0), "
                 "1/min", start=0.0, unit="1/min", min=0.0, max=1e6),
             Var("temperature_input", VR_TIN, "input", "Logged temperature driving the thermal drift (thermal.driver "
                 "= 1): the machine temperature follows its change since the start", start=20.0, unit="degC",
                 min=-50.0, max=200.0)]
    for k, c in enumerate(_XYZ):
        extra.append(Var(f"tool.{c}", VR_P + k, "output",
                         f"{c} of the real tool edge in the real workpiece frame (with sensor noise)",
                         unit="mm", display_unit="um", depends_on=()))
    for k, c in enumerate(_XYZ):
        extra.append(Var(f"tool_direction.{c}", VR_V + k, "output",
                         f"{c} of the tool axis direction (unit vector from the edge into the holder)", unit="1",
                         depends_on=()))
    extra.append(Var("temperature", VR_TEMP, "output", "Machine temperature driving the thermal drift", unit="degC",
                     depends_on=()))
    for i, a in enumerate(machine.axes):
        unit, disp = _axis_unit(machine, i)
        extra.append(Var(f"actual.{a.name}", VR_ACT + i, "output",
                         f"Actual position of axis {a.name} after servo lag and backlash, {unit}", unit=unit,
                         depends_on=()))
    for i, a in enumerate(machine.axes):
        unit, _ = _axis_unit(machine, i)
        extra.append(Var(f"v.{a.name}", VR_VEL + i, "output",
                         f"Actual velocity of axis {a.name} over the last step: the drive's mean velocity less the "
                         f"velocity friction (velfriction.*), {unit}/s", unit=f"{unit}/s", depends_on=()))
    for i, a in enumerate(machine.axes):
        extra.append(Var(f"servo.kv.{a.name}", VR_KV + i, "parameter",
                         f"Position loop gain of axis {a.name} (first-order servo); 0 = ideal servo "
                         "(at the command by the end of each step)",
                         start=kv[i], unit="1/s", min=0.0, max=1e4))
    for i, a in enumerate(machine.axes):
        unit, disp = _axis_unit(machine, i)
        extra.append(Var(f"backlash.{a.name}", VR_BACKLASH + i, "parameter",
                         f"Backlash (play width) of axis {a.name}, {unit}; negative: an over-compensated "
                         "backlash, the mirror of the play of width |b| about the servo position (leads the "
                         "command by |b|/2)", start=bl[i], unit=unit,
                         display_unit=disp, min=-1.0, max=1.0))
    extra.append(Var("servo.interpolation", IVR_INTERP, "parameter",
                     "Command of the servos over a step: 0 held (zero-order hold), 1 linear from the previous "
                     "step's command (ramp invariant: no half-step shift of the response)", type="Integer",
                     start=int(dyn.interpolation), min=0, max=1))
    extra.append(Var("delay", VR_DELAY, "parameter", "Transport delay: every axis acts on the command given this "
                     "long before (linear between steps; at most the FMU's command history of 191 steps)",
                     start=float(dyn.delay), unit="s", min=0.0, max=1.0))
    for i, a in enumerate(machine.axes):
        unit, disp = _axis_unit(machine, i)
        extra.append(Var(f"friction.breakaway.{a.name}", VR_BREAK + i, "parameter",
                         f"Friction of axis {a.name} at reversals: static friction over the drive stiffness, the "
                         f"wind-up at which the slide breaks away after the motion reversed, {unit}",
                         start=brk[i], unit=unit, display_unit=disp, min=0.0, max=1.0))
    for i, a in enumerate(machine.axes):
        unit, disp = _axis_unit(machine, i)
        extra.append(Var(f"friction.coulomb.{a.name}", VR_COULOMB + i, "parameter",
                         f"Coulomb friction of axis {a.name} over the drive stiffness: the slide's lag against the "
                         f"direction of motion once it slides (0 with an integrating velocity loop), {unit}",
                         start=cou[i], unit=unit, display_unit=disp, min=0.0, max=1.0))
    for i, a in enumerate(machine.axes):
        extra.append(Var(f"friction.tau.{a.name}", VR_FTAU + i, "parameter",
                         f"Time constant with which the slide of axis {a.name} catches up after breaking away",
                         start=ftau[i], unit="s", min=0.0, max=100.0))
    for i, a in enumerate(machine.axes):
        unit, disp = _axis_unit(machine, i)
        extra.append(Var(f"glitch.height.{a.name}", VR_GH + i, "parameter",
                         f"Quadrant glitch of axis {a.name} (spike form): peak lag against the new direction after "
                         f"a reversal of the drive's motion, height * s exp(1 - s), s = t / glitch.time, {unit}",
                         start=gh[i], unit=unit, display_unit=disp, min=-1.0, max=1.0))
    for i, a in enumerate(machine.axes):
        extra.append(Var(f"glitch.time.{a.name}", VR_GT + i, "parameter",
                         f"Time from a reversal of axis {a.name} to the peak of its quadrant glitch (0: no glitch)",
                         start=gt[i], unit="s", min=0.0, max=100.0))
    for i, a in enumerate(machine.axes):
        unit, _ = _axis_unit(machine, i)
        extra.append(Var(f"velfriction.coulomb.{a.name}", VR_VFC + i, "parameter",
                         f"Velocity friction of axis {a.name} (a velocity-mode axis, proportional velocity loop): "
                         f"Coulomb velocity loss c, v_act = v - c tanh(v/vs) - viscous v (0: off), {unit}/s",
                         start=vfc[i], unit=f"{unit}/s", min=-1e4, max=1e4))
    for i, a in enumerate(machine.axes):
        extra.append(Var(f"velfriction.viscous.{a.name}", VR_VFB + i, "parameter",
                         f"Velocity friction of axis {a.name}: viscous velocity loss per unit velocity (0: off)",
                         start=vfb[i], unit="1", min=-1.0, max=1.0))
    for i, a in enumerate(machine.axes):
        unit, _ = _axis_unit(machine, i)
        extra.append(Var(f"velfriction.vs.{a.name}", VR_VFS + i, "parameter",
                         f"Velocity friction of axis {a.name}: speed over which the Coulomb loss turns with the "
                         f"direction, tanh(v/vs) (0: sign(v)), {unit}/s", start=vfs[i], unit=f"{unit}/s",
                         min=0.0, max=1e6))
    for i, a in enumerate(machine.axes):
        unit, disp = _axis_unit(machine, i)
        extra.append(Var(f"encoder.period.{a.name}", VR_EP + i, "parameter",
                         f"Signal period of the encoder of axis {a.name} for its cyclic error (encoder.a1/a2, "
                         f"phase1/2) added to the actual position p: a1 sin(2 pi p/period + phase1) + a2 "
                         f"sin(4 pi p/period + phase2) (0: none), {unit}", start=enc["period"][i], unit=unit,
                         min=0.0, max=1000.0))
        for h in (1, 2):
            extra.append(Var(f"encoder.a{h}.{a.name}", (VR_EA1 if h == 1 else VR_EA2) + i, "parameter",
                             f"Encoder cyclic error of axis {a.name}: amplitude of harmonic {h}, {unit}",
                             start=enc[f"a{h}"][i], unit=unit, display_unit=disp, min=-1.0, max=1.0))
            extra.append(Var(f"encoder.phase{h}.{a.name}", (VR_EPH1 if h == 1 else VR_EPH2) + i, "parameter",
                             f"Encoder cyclic error of axis {a.name}: phase of harmonic {h} at p = 0",
                             start=enc[f"phase{h}"][i], unit="deg", min=-720.0, max=720.0))
    extra += [
        Var("thermal.driver", IVR_DRIVER, "parameter", "Driver of the machine temperature: 0 spindle speed "
            "(ambient + gain * spindle_speed), 1 temperature_input (ambient + its change since the start), 2 none "
            "(ambient: the initial excess relaxes over time)", type="Integer", start=dyn.driver_code, min=0, max=2),
        Var("thermal.initial_excess", VR_EXCESS, "parameter", "Machine temperature at the start above ambient",
            start=float(dyn.initial_excess), unit="K", min=-100.0, max=100.0),
        Var("thermal.reference", VR_TREF, "parameter", "Machine temperature at which the thermal drift is zero",
            start=dyn.reference_temperature, unit="degC", min=-50.0, max=100.0),
        Var("thermal.time_constant", VR_TAU, "parameter", "Time constant of the machine temperature", start=dyn.thermal_time_constant,
            unit="s", min=1e-3, max=1e6),
        Var("thermal.gain", VR_GAIN, "parameter", "Steady temperature rise per unit spindle speed", start=dyn.thermal_gain,
            unit="K.min", min=0.0, max=1.0),
        Var("thermal.ambient", VR_AMBIENT, "parameter", "Ambient temperature (the machine starts at ambient + thermal.initial_excess)", start=dyn.ambient,
            unit="degC", min=-50.0, max=100.0),
    ]
    for k, c in enumerate(_XYZ):
        extra.append(Var(f"thermal.drift.{c}", VR_DRIFT + k, "parameter",
                         f"Tool edge drift along tool-frame {c} per kelvin above thermal.reference", start=dyn.drift[k],
                         unit="mm/K", display_unit="um/K", min=-1.0, max=1.0))
    extra += [
        Var("noise.sigma", VR_NOISE, "parameter", "Standard deviation of the tool edge measurement noise",
            start=dyn.noise, unit="mm", display_unit="nm", min=0.0, max=1.0),
        Var("noise.seed", IVR_SEED, "parameter", "Seed of the measurement noise", type="Integer", start=int(dyn.seed)),
    ]
    summary = ("Virtual multi-axis machine tool with tool setting, workpiece setting and geometric errors, transport "
               "delay, first-order servos, backlash, friction at reversals, thermal drift and sensor noise; the same "
               "forward model as mtcomp.kinematics.")
    return _build("machine", machine, errors, out_path, identifier, "mtcomp machine", summary, extra, compile_binary,
                  compiler, fmi_version, windows)
