"""Write a diagnosis' fitted effects in the machine model's own formats.

OUTDIR/errors.toml (+ errors_<AXIS>.csv): geometric and setting effects (docs/errors-format.md),
OUTDIR/dynamics.toml: servo kv and backlash per axis (mtcomp.model.dynamics),
OUTDIR/machine.ssv: an SSP 1.0 parameter set binding every scalar to the machine FMU's
parameter names, OUTDIR/model.toml: what each effect became, or why it has no home.
"""
from __future__ import annotations

import json
import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .._io import InputError, atomic_write, dump_toml, read_text
from ..errors import AxisErrorTable, ErrorSet, GeometricErrors, ToolSetting, WorkpieceSetting, save_errors
from ..machine import Machine, load_machine
from .axes import NoHome
from .dynamics import is_dynamics, save_dynamics
from .mapping import map_effect, merge_thermal

SSV = "http://ssp-standard.org/SSP1/SystemStructureParameterValues"
SSC = "http://ssp-standard.org/SSP1/SystemStructureCommon"
MAX_TABLE_ROWS = 20001
# SI definitions of the units the parameter set uses (SSP 1.0 ssc:Unit / ssc:BaseUnit)
_UNITS = {"mm": {"m": "1", "factor": "0.001"}, "deg": {"rad": "1", "factor": str(math.pi / 180)},
          "rad": {"rad": "1"}, "1/s": {"s": "-1"}, "s": {"s": "1"}, "K": {"K": "1"},
          "degC": {"K": "1", "offset": "273.15"}, "mm/K": {"m": "1", "K": "-1", "factor": "0.001"},
          "K.min": {"K": "1", "s": "1", "factor": "60"},
          "mm/s": {"m": "1", "s": "-1", "factor": "0.001"},
          "deg/s": {"rad": "1", "s": "-1", "factor": str(math.pi / 180)}}


def read_diagnosis(src) -> dict:
    """The diagnosis as a dict: a path to `mtcomp diagnose --json` output, a JSON string, a dict
    or a DiagnosisResult."""
    if hasattr(src, "to_dict"):
        return src.to_dict()
    if isinstance(src, dict):
        return src
    path = Path(src)
    text = read_text(path, what="diagnosis JSON")
    try:
        data = json.loads(text)
    except json.JSONDecodeError as exc:
        raise InputError(f"not valid JSON: {exc.msg}", path, exc.lineno) from None
    if not isinstance(data, dict) or not isinstance(data.get("effects"), list):
        raise InputError("expected the JSON of `mtcomp diagnose --json` with a list 'effects'", path,
                         field="effects")
    for i, e in enumerate(data["effects"]):
        if not isinstance(e, dict) or not isinstance(e.get("name"), str) or not isinstance(e.get("params"), dict):
            raise InputError("expected an object with 'name' and 'params'", path, field=f"effects[{i}]")
    return data


@dataclass(frozen=True)
class ModelExport:
    """What an export produced.  mapped: the effects with a home (mapping.Mapped); unmapped:
    (effect dict, reason) of those without; errors: the ErrorSet (geometric and setting
    effects); dynamics: the dynamics Params; step: the communication step used for kv (s)."""
    machine: str
    mapped: tuple
    unmapped: tuple
    errors: ErrorSet
    dynamics: tuple
    params: tuple            # every scalar Param (dynamics, location, setting)
    step: float | None
    files: dict = field(default_factory=dict)
    machine_obj: object = field(default=None, repr=False, compare=False)

    def subset(self, keep) -> "ModelExport":
        """The export restricted to the mapped effects at indices `keep` (files not rewritten);
        the others are listed as unmapped with the reason "dropped by the re-simulation"."""
        keep = set(keep)
        mapped = tuple(m for i, m in enumerate(self.mapped) if i in keep)
        dropped = tuple(({"name": m.effect, "output": m.output}, "dropped: the re-simulation fits the training "
                         "samples as well without it") for i, m in enumerate(self.mapped) if i not in keep)
        return _assemble(mapped, self.unmapped + dropped, self.machine_obj, self.step)

    def with_values(self, values: dict, sigmas: dict | None = None) -> "ModelExport":
        """The export with some scalar parameters replaced ({name: value}, optional {name: sigma})."""
        from dataclasses import replace as _r
        sigmas = sigmas or {}
        mapped = tuple(_r(m, params=tuple(_r(p, value=float(values.get(p.name, p.value)),
                                             sigma=sigmas.get(p.name, p.sigma)) for p in m.params))
                       for m in self.mapped)
        return _assemble(mapped, self.unmapped, self.machine_obj, self.step)

    @property
    def dynamics_values(self) -> dict:
        return {p.name: p.value for p in self.dynamics}

    def summary(self) -> str:
        lines = [f"model export for machine {self.machine}: {len(self.mapped)} effect(s) in the model, "
                 f"{len(self.unmapped)} without a home"]
        for m in self.mapped:
            what = [f"{p.name} = {p.value:.6g}" + (f" {p.unit}" if p.unit != "1" else "")
                    + (f" +/- {p.sigma:.2g}" if p.sigma is not None else "") for p in m.params] + [f"table {t.component}" for t in m.tables]
            lines.append(f"  {m.effect} on {m.output}: " + "; ".join(what))
            lines += [f"    note: {n}" for n in m.notes]
        for e, why in self.unmapped:
            lines.append(f"  {e.get('name')} on {e.get('output')}: NOT IN THE MODEL ({why})")
        for k, p in self.files.items():
            lines.append(f"  wrote {k}: {p}")
        return "\n".join(lines)


def _tables(mapped, machine: Machine) -> dict:
    """Sum the table functions per axis and component on one grid over the axis travel."""
    by_axis: dict = {}
    for m in mapped:
        for t in m.tables:
            by_axis.setdefault(t.axis, []).append(t)
    out = {}
    for axname, ts in by_axis.items():
        ax = next(a for a in machine.axes if a.name == axname)
        lo, hi = (float(v) for v in ax.limits)
        spacing = min(t.spacing for t in ts)
        n = 2 if not math.isfinite(spacing) else int(min(MAX_TABLE_ROWS, max(2, math.ceil((hi - lo) / spacing) + 1)))
        q = np.linspace(lo, hi, n)
        vals: dict = {}
        for t in ts:
            vals[t.component] = vals.get(t.component, 0.0) + np.asarray(t.fn(q), float)
        out[axname] = AxisErrorTable(axname, q, vals, source=f"diagnosis ({', '.join(sorted(vals))})")
    return out


def build_errors(params, tables: dict) -> ErrorSet:
    """ErrorSet of the setting and location Params and the tables."""
    tool = [0.0] * 3
    tr, ang = [0.0] * 3, [0.0] * 3
    loc = {}
    for p in params:
        if p.name.startswith("tool_setting.offset."):
            tool["xyz".index(p.name[-1])] += p.value
        elif p.name.startswith("workpiece_setting.translation."):
            tr["xyz".index(p.name[-1])] += p.value
        elif p.name.startswith("workpiece_setting.angle."):
            ang["abc".index(p.name[-1])] += p.value
        elif p.name.startswith("location."):
            k = p.name[len("location."):]
            loc[k] = loc.get(k, 0.0) + p.value
    return ErrorSet(ToolSetting(tuple(tool)), WorkpieceSetting(tuple(tr), tuple(ang)), GeometricErrors(tables, loc))


def machine_parameter_names(machine: Machine) -> set:
    """Parameter names of the machine FMU for this machine, read from its modelDescription
    (built without compiling)."""
    import tempfile

    from fmpy import read_model_description

    from ..fmu.build import build_machine_fmu
    with tempfile.TemporaryDirectory(prefix="mtcomp-model-") as d:
        path = build_machine_fmu(machine, Path(d) / "machine.fmu", compile_binary=False)
        md = read_model_description(str(path))
    return {v.name for v in md.modelVariables if v.causality == "parameter"}


def ssv_text(params, names: set | None = None, *, name: str = "diagnosed") -> bytes:
    """SSP 1.0 parameter set (.ssv) of Params, named by the machine FMU's parameter names (to be
    bound to the machine component).  names: the FMU's parameter names; a Param not among them
    is an error (the FMU would ignore it)."""
    ET.register_namespace("ssv", SSV)
    ET.register_namespace("ssc", SSC)
    root = ET.Element(f"{{{SSV}}}ParameterSet", {"version": "1.0", "name": name})
    ps = ET.SubElement(root, f"{{{SSV}}}Parameters")
    used = set()
    for p in params:
        if names is not None and p.name not in names:
            raise InputError(f"the machine FMU has no parameter {p.name!r}", field=p.name)
        el = ET.SubElement(ps, f"{{{SSV}}}Parameter", {"name": p.name})
        if getattr(p, "type", "Real") == "Integer":
            ET.SubElement(el, f"{{{SSV}}}Integer", {"value": str(int(p.value))})
        else:
            attrs = {"value": repr(float(p.value))}
            if p.unit in _UNITS:
                attrs["unit"] = p.unit
                used.add(p.unit)
            ET.SubElement(el, f"{{{SSV}}}Real", attrs)
        if p.sigma is not None and math.isfinite(p.sigma):
            # SSP 1.0 has no uncertainty attribute: it travels as an annotation
            ann = ET.SubElement(el, f"{{{SSC}}}Annotations")
            a = ET.SubElement(ann, f"{{{SSC}}}Annotation", {"type": "org.mtcomp.uncertainty"})
            ET.SubElement(a, "sigma", {"value": repr(float(p.sigma)), "unit": p.unit})
    if used:
        units = ET.SubElement(root, f"{{{SSV}}}Units")
        for u in sorted(used):
            un = ET.SubElement(units, f"{{{SSC}}}Unit", {"name": u})
            ET.SubElement(un, f"{{{SSC}}}BaseUnit", _UNITS[u])
    ET.indent(root)
    return b'<?xml version="1.0" encoding="UTF-8"?>\n' + ET.tostring(root, encoding="utf-8") + b"\n"


def read_ssv(path) -> dict:
    """{parameter name: value} of a .ssv parameter set (Real and Integer values)."""
    try:
        root = ET.parse(str(path)).getroot()
    except (ET.ParseError, OSError) as exc:
        raise InputError(f"not a readable XML parameter set ({exc})", path) from None
    out = {}
    for p in root.iter(f"{{{SSV}}}Parameter"):
        r = p.find(f"{{{SSV}}}Real")
        if r is not None:
            out[p.get("name")] = float(r.get("value"))
        i = p.find(f"{{{SSV}}}Integer")
        if i is not None:
            out[p.get("name")] = int(i.get("value"))
    return out


def map_diagnosis(diagnosis, machine, step: float | None = None, drivers: dict | None = None,
                  servo_interpolation: bool = False, velocity_peaks: dict | None = None):
    """(mapped, unmapped) for every effect of the diagnosis.  drivers: {driver column: its value
    at the start} (the thermal mapping needs the spindle speed at the start; 0 when not given).
    velocity_peaks: {velocity output v<AXIS>: SIM's peak |v| over the diagnosed span} (friction
    on a velocity output needs it: mapping.map_friction); default: from a DiagnosisResult's
    aligned SIM (`mtcomp diagnose --model`, close_loop), none from a JSON.

    The machine FMU has one thermal state: a second thermal drift on another output with the
    same driver adds its drift gain only (its own time constant, initial state and reference
    are the first one's: noted); with another driver it has no home."""
    data = read_diagnosis(diagnosis)
    machine = load_machine(machine)
    if velocity_peaks is None and getattr(diagnosis, "sim", None):
        # a DiagnosisResult carries SIM on its own grid: the peak the diagnosis took v_s from
        velocity_peaks = {o: float(np.max(np.abs(v))) for o, v in diagnosis.sim.items()
                          if len(o) > 1 and o[0] == "v" and o[1:] in machine.axis_names and len(v)}
    mapped, unmapped = [], []
    thermal = None
    for e in data["effects"]:
        try:
            m = map_effect(e, machine, step, drivers, servo_interpolation, velocity_peaks)
            if m.effect == "thermal_drift":
                if thermal is None:
                    thermal = m
                else:
                    m = merge_thermal(thermal, m)
            mapped.append(m)
        except NoHome as exc:
            unmapped.append((e, str(exc)))
    return tuple(mapped), tuple(unmapped)


def export_model(diagnosis, machine, outdir=None, *, step: float | None = None,
                 check_names: bool = True, drivers: dict | None = None,
                 servo_interpolation: bool = False, velocity_peaks: dict | None = None) -> ModelExport:
    """Map the diagnosis' effects onto the machine model and (with `outdir`) write the files.

    diagnosis: path of `mtcomp diagnose --json` output, its dict, or a DiagnosisResult.
    machine: preset name, TOML path or Machine.  step: the co-simulation's communication step
    (s), which the FMU's discrete servo needs to reproduce the fitted kv.  drivers: {driver
    column: value at the start} of the recording's thermal drivers (map_diagnosis).
    servo_interpolation: the model's servos are ramp invariant (servo.interpolation = 1 in
    SIM's dynamics): a diagnosed kv is written as it is, with servo.interpolation = 1.
    velocity_peaks: {velocity output v<AXIS>: SIM's peak |v| (mm/s, deg/s)} (map_diagnosis)."""
    machine = load_machine(machine)
    mapped, unmapped = map_diagnosis(diagnosis, machine, step, drivers, servo_interpolation, velocity_peaks)
    ex = _assemble(mapped, unmapped, machine, step)
    if outdir is not None:
        ex = write_export(ex, outdir, check_names=check_names)
    return ex


def _assemble(mapped, unmapped, machine, step) -> ModelExport:
    params = tuple(p for m in mapped for p in m.params)
    dyn = tuple(p for p in params if is_dynamics(p.name))
    other = tuple(p for p in params if p not in dyn)
    errors = build_errors(other, _tables(mapped, machine))
    return ModelExport(machine.name, tuple(mapped), tuple(unmapped), errors, dyn, params, step, {}, machine)


def write_export(ex: ModelExport, outdir, *, check_names: bool = True) -> ModelExport:
    """Write the files of an export into `outdir` (created); returns it with `files` set."""
    from dataclasses import replace
    machine, mapped, unmapped, step = ex.machine_obj, ex.mapped, ex.unmapped, ex.step
    params, dyn, errors = ex.params, ex.dynamics, ex.errors
    other = tuple(p for p in params if p not in dyn)
    files = {}
    out = Path(outdir)
    if not out.is_dir():
        out.mkdir(parents=True)
    names = machine_parameter_names(machine) if check_names else None
    for old in out.glob("errors_*.csv"):     # tables of an earlier export of this folder
        if old.stem[len("errors_"):] not in errors.geometric.tables:
            old.unlink()
    ssv = ssv_text(params, names)
    unc = {p.name: p.sigma for p in other if p.sigma is not None and math.isfinite(p.sigma)}
    for m in mapped:
        for t in m.tables:
            unc.update({f"{t.axis}.{t.component}.{k}": v for k, v in t.sigma.items()
                        if v is not None and math.isfinite(v)})
    files["errors"] = save_errors(errors, out / "errors.toml", uncertainty=unc or None,
                                  meta={"source": "mtcomp model export", "machine": machine.name})
    files["dynamics"] = save_dynamics(out / "dynamics.toml", dyn, step)
    files["ssv"] = atomic_write(out / "machine.ssv", ssv)
    files["manifest"] = atomic_write(out / "model.toml", _manifest(machine, mapped, unmapped, step))
    return replace(ex, files=files)


def _manifest(machine, mapped, unmapped, step) -> str:
    eff = []
    for m in mapped:
        d = {"name": m.effect, "output": m.output, "status": "in the model",
             "parameters": [p.name for p in m.params], "tables": [f"{t.axis}:{t.component}" for t in m.tables]}
        if m.notes:
            d["notes"] = list(m.notes)
        eff.append(d)
    for e, why in unmapped:
        eff.append({"name": str(e.get("name")), "output": str(e.get("output", "")),
                    "status": "dropped" if why.startswith("dropped") else "no home", "reason": why})
    from .identity import manifest_fields
    data = {"machine": machine.name, **manifest_fields(machine),
            "files": {"errors": "errors.toml", "dynamics": "dynamics.toml", "ssp_parameter_set": "machine.ssv"}}
    if step:
        data["step_s"] = float(step)
    data["effect"] = eff
    return "# mtcomp model export manifest (docs/model-loop.md)\n" + dump_toml(data)
