"""SSP 1.0 package wiring the compensator FMU to the machine FMU, for tools that import SSP.

The archive holds SystemStructure.ssd and both FMUs under resources/; every
`compensated.<AXIS>` output of the compensator drives `command.<AXIS>` of the machine.  The
compensator's `command.<AXIS>` inputs stay open (the NC side), with their start values from an
optional parameter set.  Tested with fmpy's simulate_ssp, libcosim, ecos and fmucontainer; the
layout that serves all four is explained in write_ssp and docs/fmu.md.
"""
from __future__ import annotations

import zipfile
from pathlib import Path
from xml.etree import ElementTree as ET

from .._io import InputError, atomic_path

SSD = "http://ssp-standard.org/SSP1/SystemStructureDescription"
SSC = "http://ssp-standard.org/SSP1/SystemStructureCommon"
SSV = "http://ssp-standard.org/SSP1/SystemStructureParameterValues"

__all__ = ["write_ssp", "LAYOUTS", "ssc_type", "bound_parameters", "fmpy_parameter_set"]

# SSP 1.0 connector types of FMI variable types: SSP 1.0 knows Real, Integer, Boolean, String and
# Enumeration only, so an FMI 3.0 Float64 connector is an ssc:Real (an ssc:Float64 fails the
# schema: fmpy "This element is not expected", libcosim refuses the file).
_SSC_TYPES = {"Real": "Real", "Float64": "Real", "Float32": "Real", "Integer": "Integer",
              **{f"{s}Int{n}": "Integer" for s in ("", "U") for n in (8, 16, 32, 64)},
              "Boolean": "Boolean", "String": "String", "Enumeration": "Enumeration"}


def ssc_type(fmi_type: str) -> str:
    """SSP 1.0 connector type (ssc:...) of an FMI 2.0 or 3.0 variable type."""
    try:
        return _SSC_TYPES[fmi_type]
    except KeyError:
        raise InputError(f"FMI type {fmi_type} has no SSP 1.0 connector type", field="connector") from None


def _unit(v) -> str | None:
    """The variable's unit (FMI 2.0: on the variable or its declared type; FMI 3.0 the same)."""
    return getattr(v, "unit", None) or getattr(getattr(v, "declaredType", None), "unit", None)


def _connector(conns, v) -> None:
    c = ET.SubElement(conns, f"{{{SSD}}}Connector", {"name": v.name, "kind": v.causality})
    kind = ssc_type(v.type)
    attrs = {"unit": _unit(v)} if kind == "Real" and _unit(v) else {}
    ET.SubElement(c, f"{{{SSC}}}{kind}", attrs)


def _units(root, used: set[str]) -> None:
    """<ssd:Units>: every unit a connector names, with its SI base (SSP requires the definition
    of each unit used; the same definitions as the FMUs' UnitDefinitions)."""
    from .build import UNITS
    if not used:
        return   # an empty <ssd:Units/> is not allowed
    units = ET.SubElement(root, f"{{{SSD}}}Units")
    for name in sorted(used):
        base, factor, offset, _ = UNITS[name]
        u = ET.SubElement(units, f"{{{SSC}}}Unit", {"name": name})
        attrs = {k: str(e) for k, e in base.items()}
        if factor != 1.0:
            attrs["factor"] = repr(factor)
        if offset:
            attrs["offset"] = repr(offset)
        ET.SubElement(u, f"{{{SSC}}}BaseUnit", attrs)


LAYOUTS = ("components", "system")
SYSTEM_OUTPUTS = ("tool.", "tool_direction.", "actual.", "temperature")


def write_ssp(path, compensator_fmu, machine_fmu, *, name: str = "mtcomp-cosim", stop_time: float = 1.0,
              commands: dict | None = None, layout: str = "components") -> Path:
    """Write an .ssp with the two FMUs wired compensator -> machine.

    No single layout runs in every importer, so there are two (docs/fmu.md):

    - "components" (default; fmpy's simulate_ssp, libcosim, ecos): connectors only for the
      connected variables (compensator outputs, machine command inputs) and the machine's
      outputs.  The open inputs (the compensator's `command.<AXIS>`, the machine's
      `spindle_speed`) are not connectors: fmpy refuses unconnected input connectors, and
      libcosim and ecos refuse system connectors.  They keep their start values or the bound
      parameter values.
    - "system" (fmucontainer, fmpy): the open inputs and the machine's outputs are also
      connectors of the system, connected to the components; fmucontainer makes these the
      container FMU's inputs and outputs, fmpy drives them with its `input=` functions.
      libcosim ("Unable to create execution") and ecos ("No element named") reject it.

    commands: optional start values {axis letter: mm or deg} of the compensator's
    `command.<AXIS>` inputs (parameter set "commands" bound to the compensator).
    """
    if layout not in LAYOUTS:
        raise InputError(f"SSP layout must be one of {', '.join(LAYOUTS)}, got {layout!r}", field="layout")
    from fmpy import read_model_description
    ET.register_namespace("ssd", SSD)
    ET.register_namespace("ssc", SSC)
    ET.register_namespace("ssv", SSV)
    mdc = read_model_description(str(compensator_fmu))
    mdm = read_model_description(str(machine_fmu))
    machine_inputs = {v.name for v in mdm.modelVariables if v.causality == "input"}
    links = []
    for v in mdc.modelVariables:
        if v.causality == "output" and v.name.startswith("compensated."):
            target = "command." + v.name.split(".", 1)[1]
            if target in machine_inputs:
                links.append((v.name, target))
    used_units: set[str] = set()

    def declare(comp, variables):
        conns = ET.SubElement(comp, f"{{{SSD}}}Connectors")
        for v in variables:
            _connector(conns, v)
            if ssc_type(v.type) == "Real" and _unit(v):
                used_units.add(_unit(v))

    system_layout = layout == "system"
    open_c = [v for v in mdc.modelVariables if v.causality == "input"] if system_layout else []
    open_m = [v for v in mdm.modelVariables if v.causality == "input" and v.name not in {b for _, b in links}
              ] if system_layout else []
    outs_m = [v for v in mdm.modelVariables if v.causality == "output"]
    root = ET.Element(f"{{{SSD}}}SystemStructureDescription", {"version": "1.0", "name": name})
    system = ET.SubElement(root, f"{{{SSD}}}System", {"name": name})
    if system_layout:   # the system's own connectors come first (SSD schema order)
        declare(system, open_c + open_m + [v for v in outs_m if v.name.startswith(SYSTEM_OUTPUTS)])
    elements = ET.SubElement(system, f"{{{SSD}}}Elements")
    comp = ET.SubElement(elements, f"{{{SSD}}}Component", {
        "name": "compensator", "type": "application/x-fmu-sharedlibrary", "source": "resources/compensator.fmu"})
    linked_out = {a for a, _ in links}
    declare(comp, open_c + [v for v in mdc.modelVariables if v.name in linked_out])
    if commands:
        known = {v.name for v in mdc.modelVariables if v.causality == "input"}
        pb = ET.SubElement(comp, f"{{{SSD}}}ParameterBindings")
        b = ET.SubElement(pb, f"{{{SSD}}}ParameterBinding")
        pv = ET.SubElement(b, f"{{{SSD}}}ParameterValues")
        ps = ET.SubElement(pv, f"{{{SSV}}}ParameterSet", {"version": "1.0", "name": "commands"})
        params = ET.SubElement(ps, f"{{{SSV}}}Parameters")
        for axis, value in commands.items():
            if f"command.{axis}" not in known:
                raise InputError(f"the compensator has no axis {axis!r} (axes: "
                                 f"{' '.join(sorted(k.split('.', 1)[1] for k in known))})", field="commands")
            p = ET.SubElement(params, f"{{{SSV}}}Parameter", {"name": f"command.{axis}"})
            ET.SubElement(p, f"{{{SSV}}}Real", {"value": repr(float(value))})
    mach = ET.SubElement(elements, f"{{{SSD}}}Component", {
        "name": "machine", "type": "application/x-fmu-sharedlibrary", "source": "resources/machine.fmu"})
    linked_in = {b for _, b in links}
    declare(mach, open_m + [v for v in mdm.modelVariables if v.name in linked_in or v.causality == "output"])
    connections = ET.SubElement(system, f"{{{SSD}}}Connections")
    for v in open_c:
        ET.SubElement(connections, f"{{{SSD}}}Connection", {
            "startConnector": v.name, "endElement": "compensator", "endConnector": v.name})
    for v in open_m:
        ET.SubElement(connections, f"{{{SSD}}}Connection", {
            "startConnector": v.name, "endElement": "machine", "endConnector": v.name})
    for a, b in links:
        ET.SubElement(connections, f"{{{SSD}}}Connection", {
            "startElement": "compensator", "startConnector": a, "endElement": "machine", "endConnector": b})
    if system_layout:
        for v in outs_m:
            if v.name.startswith(SYSTEM_OUTPUTS):
                ET.SubElement(connections, f"{{{SSD}}}Connection", {
                    "startElement": "machine", "startConnector": v.name, "endConnector": v.name})
    _units(root, used_units)
    ET.SubElement(root, f"{{{SSD}}}DefaultExperiment", {"startTime": "0.0", "stopTime": repr(float(stop_time))})
    ET.indent(root)
    xml = b'<?xml version="1.0" encoding="UTF-8"?>\n' + ET.tostring(root, encoding="utf-8")
    path = Path(path)
    with atomic_path(path) as tmp:
        with zipfile.ZipFile(tmp, "w", zipfile.ZIP_DEFLATED) as zf:
            zf.writestr("SystemStructure.ssd", xml)
            zf.write(compensator_fmu, "resources/compensator.fmu")
            zf.write(machine_fmu, "resources/machine.fmu")
    return path


def bound_parameters(ssp_path, parameter_set: str | None = None) -> dict[str, float | int | str]:
    """The values an SSP's parameter bindings give its components: {"<component>.<parameter>":
    value}, from the inline ssv:ParameterSet elements (of the set named `parameter_set`, or all).
    fmpy's simulate_ssp does not apply SSD bindings: hand these to it (`fmpy_parameter_set`)."""
    ns = {"ssd": SSD, "ssv": SSV}
    with zipfile.ZipFile(ssp_path) as z:
        root = ET.fromstring(z.read("SystemStructure.ssd"))
    out: dict = {}
    for comp in root.iter(f"{{{SSD}}}Component"):
        for ps in comp.findall("ssd:ParameterBindings/ssd:ParameterBinding/ssd:ParameterValues/ssv:ParameterSet", ns):
            if parameter_set is not None and ps.get("name") != parameter_set:
                continue
            for p in ps.findall("ssv:Parameters/ssv:Parameter", ns):
                for el in p:
                    kind, value = el.tag.split("}")[1], el.get("value")
                    out[f"{comp.get('name')}.{p.get('name')}"] = (
                        float(value) if kind in ("Real", "Float64", "Float32") else
                        int(value) if kind.startswith(("Integer", "Int", "UInt", "Enumeration")) else
                        value.lower() == "true" if kind == "Boolean" else value)
    return out


def fmpy_parameter_set(values: dict):
    """`values` ({"<component>.<parameter>": value}, e.g. from `bound_parameters`) in the form
    fmpy's simulate_ssp takes as `parameter_set=` (an object with `.parameters`, each with
    `.name` and `.value`; it does not accept a dict)."""
    from types import SimpleNamespace
    return SimpleNamespace(parameters=[SimpleNamespace(name=k, value=v) for k, v in values.items()])
