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

__all__ = ["write_ssp", "LAYOUTS"]


def _connector(conns, v) -> None:
    c = ET.SubElement(conns, f"{{{SSD}}}Connector", {"name": v.name, "kind": v.causality})
    attrs = {"unit": v.unit} if v.type == "Real" and getattr(v, "unit", None) else {}
    ET.SubElement(c, f"{{{SSC}}}{v.type}", attrs)


def _units(root, used: set[str]) -> None:
    """<ssd:Units>: every unit a connector names, with its SI base (SSP requires the definition
    of each unit used; the same definitions as the FMUs' UnitDefinitions)."""
    from .build import UNITS
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
            if v.type == "Real" and getattr(v, "unit", None):
                used_units.add(v.unit)

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
