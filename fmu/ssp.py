"""SSP 1.0 package wiring the compensator FMU to the machine FMU, for tools that import SSP.

The archive holds SystemStructure.ssd and both FMUs under resources/; every
`compensated.<AXIS>` output of the compensator drives `command.<AXIS>` of the machine.  The
compensator's `command.<AXIS>` inputs stay open (the NC side), with their start values from an
optional parameter set.  Format: docs/fmu.md.
"""
from __future__ import annotations

import zipfile
from pathlib import Path
from xml.etree import ElementTree as ET

from .._io import atomic_path

SSD = "http://ssp-standard.org/SSP1/SystemStructureDescription"
SSC = "http://ssp-standard.org/SSP1/SystemStructureCommon"
SSV = "http://ssp-standard.org/SSP1/SystemStructureParameterValues"

__all__ = ["write_ssp"]


def _connectors(comp, md, causalities):
    conns = ET.SubElement(comp, f"{{{SSD}}}Connectors")
    for v in md.modelVariables:
        if v.causality not in causalities:
            continue
        c = ET.SubElement(conns, f"{{{SSD}}}Connector", {"name": v.name, "kind": v.causality})
        attrs = {"unit": v.unit} if v.type == "Real" and getattr(v, "unit", None) else {}
        ET.SubElement(c, f"{{{SSC}}}{v.type}", attrs)


def write_ssp(path, compensator_fmu, machine_fmu, *, name: str = "mtcomp-cosim", stop_time: float = 1.0,
              commands: dict | None = None) -> Path:
    """Write an .ssp with the two FMUs wired compensator -> machine.

    commands: optional start values {axis letter: mm or deg} of the compensator's open
    `command.<AXIS>` inputs (written as the system's parameter set "commands").
    """
    from fmpy import read_model_description
    ET.register_namespace("ssd", SSD)
    ET.register_namespace("ssc", SSC)
    ET.register_namespace("ssv", SSV)
    mdc = read_model_description(str(compensator_fmu))
    mdm = read_model_description(str(machine_fmu))
    root = ET.Element(f"{{{SSD}}}SystemStructureDescription", {"version": "1.0", "name": name})
    system = ET.SubElement(root, f"{{{SSD}}}System", {"name": name})
    elements = ET.SubElement(system, f"{{{SSD}}}Elements")
    comp = ET.SubElement(elements, f"{{{SSD}}}Component", {
        "name": "compensator", "type": "application/x-fmu-sharedlibrary", "source": "resources/compensator.fmu"})
    _connectors(comp, mdc, ("input", "output"))
    if commands:
        pb = ET.SubElement(comp, f"{{{SSD}}}ParameterBindings")
        b = ET.SubElement(pb, f"{{{SSD}}}ParameterBinding")
        pv = ET.SubElement(b, f"{{{SSD}}}ParameterValues")
        ps = ET.SubElement(pv, f"{{{SSV}}}ParameterSet", {"version": "1.0", "name": "commands"})
        params = ET.SubElement(ps, f"{{{SSV}}}Parameters")
        for axis, value in commands.items():
            p = ET.SubElement(params, f"{{{SSV}}}Parameter", {"name": f"command.{axis}"})
            ET.SubElement(p, f"{{{SSV}}}Real", {"value": repr(float(value))})
    mach = ET.SubElement(elements, f"{{{SSD}}}Component", {
        "name": "machine", "type": "application/x-fmu-sharedlibrary", "source": "resources/machine.fmu"})
    _connectors(mach, mdm, ("input", "output"))
    connections = ET.SubElement(system, f"{{{SSD}}}Connections")
    machine_inputs = {v.name for v in mdm.modelVariables if v.causality == "input"}
    for v in mdc.modelVariables:
        if v.causality == "output" and v.name.startswith("compensated."):
            target = "command." + v.name.split(".", 1)[1]
            if target in machine_inputs:
                ET.SubElement(connections, f"{{{SSD}}}Connection", {
                    "startElement": "compensator", "startConnector": v.name,
                    "endElement": "machine", "endConnector": target})
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
