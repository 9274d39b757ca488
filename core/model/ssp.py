"""Bind the exported parameter set (.ssv) to the machine component of an SSP archive.

`mtcomp fmu ssp` (mtcomp.fmu.ssp.write_ssp) writes the compensator + machine system; this adds
the diagnosed parameters to it: the .ssv goes into the archive as `resources/<name>.ssv` and
its parameter set is bound inline to the `machine` component (an `ssd:ParameterBinding` with
`ssd:ParameterValues`, the form the importers checked in docs/fmu.md apply), so an SSP importer
runs the updated machine.
"""
from __future__ import annotations

import zipfile
import xml.etree.ElementTree as ET
from pathlib import Path

from .._io import InputError, atomic_path

SSD = "http://ssp-standard.org/SSP1/SystemStructureDescription"
SSC = "http://ssp-standard.org/SSP1/SystemStructureCommon"
SSV = "http://ssp-standard.org/SSP1/SystemStructureParameterValues"


def bind_parameter_set(ssp_in, ssv_path, ssp_out, *, component: str = "machine", set_name: str | None = None) -> Path:
    """Write `ssp_out`: `ssp_in` with the parameter set of `ssv_path` bound to `component`.

    set_name: the name of the bound set (default: the .ssv's, "diagnosed").  The ecos CLI applies
    the sets of one name per run (`--parameterSet NAME`): name it like the compensator's
    "commands" set of `mtcomp fmu ssp` to have both applied together."""
    for prefix, ns in (("ssd", SSD), ("ssc", SSC), ("ssv", SSV)):
        ET.register_namespace(prefix, ns)
    try:
        ssv_root = ET.parse(str(ssv_path)).getroot()
    except (ET.ParseError, OSError) as exc:
        raise InputError(f"not a readable XML parameter set ({exc})", ssv_path) from None
    if ssv_root.tag != f"{{{SSV}}}ParameterSet":
        raise InputError("expected an SSP 1.0 ssv:ParameterSet", ssv_path)
    try:
        with zipfile.ZipFile(ssp_in) as zf:
            entries = {n: zf.read(n) for n in zf.namelist()}
    except (zipfile.BadZipFile, OSError) as exc:
        raise InputError(f"not an SSP archive (zip): {exc}", ssp_in) from None
    if "SystemStructure.ssd" not in entries:
        raise InputError("no SystemStructure.ssd in the SSP archive", ssp_in)
    try:
        root = ET.fromstring(entries["SystemStructure.ssd"])
    except ET.ParseError as exc:
        raise InputError(f"SystemStructure.ssd is not valid XML ({exc})", ssp_in) from None
    comp = next((c for c in root.iter(f"{{{SSD}}}Component") if c.get("name") == component), None)
    if comp is None:
        raise InputError(f"the SSP has no component {component!r}", ssp_in)
    _check_component_machine(entries, comp, ssv_root, Path(ssv_path), Path(ssp_in))
    pbs = comp.find(f"{{{SSD}}}ParameterBindings")
    if pbs is None:
        pbs = ET.Element(f"{{{SSD}}}ParameterBindings")
        # schema order: Connectors, ElementGeometry, ParameterBindings, ...
        after = [i for i, ch in enumerate(comp) if ch.tag in (f"{{{SSD}}}Connectors", f"{{{SSD}}}ElementGeometry")]
        comp.insert(after[-1] + 1 if after else 0, pbs)
    pb = ET.SubElement(pbs, f"{{{SSD}}}ParameterBinding")
    pv = ET.SubElement(pb, f"{{{SSD}}}ParameterValues")
    if set_name:
        ssv_root.set("name", str(set_name))
    pv.append(ssv_root)
    ET.indent(root)
    entries["SystemStructure.ssd"] = (b'<?xml version="1.0" encoding="UTF-8"?>\n'
                                      + ET.tostring(root, encoding="utf-8"))
    entries[f"resources/{Path(ssv_path).name}"] = Path(ssv_path).read_bytes()
    out = Path(ssp_out)
    with atomic_path(out) as tmp:
        with zipfile.ZipFile(tmp, "w", zipfile.ZIP_DEFLATED) as zf:
            for n, data in entries.items():
                zf.writestr(n, data)
    return out


def _component_fmu(entries: dict, comp, ssp_in: Path) -> zipfile.ZipFile | None:
    """The component's FMU (a zip inside the SSP archive), None when the SSP does not hold it."""
    import io
    src = comp.get("source") or ""
    if src not in entries:
        return None
    try:
        return zipfile.ZipFile(io.BytesIO(entries[src]))
    except zipfile.BadZipFile:
        raise InputError(f"{src} in the SSP archive is not an FMU (zip)", ssp_in) from None


def _check_component_machine(entries: dict, comp, ssv_root, ssv_path: Path, ssp_in: Path) -> None:
    """Refuse to bind a parameter set to the FMU of another machine: the machine the model was
    exported for (model.toml beside the .ssv) must be the one the component's FMU simulates
    (its resources/machine.txt: name, axes, chain), and every parameter of the set must be one
    of the FMU's (an unknown name would be ignored by the importer, silently)."""
    from .identity import identity_from_resource, identity_of_model, mismatch
    fmu = _component_fmu(entries, comp, ssp_in)
    if fmu is None:
        return
    with fmu:
        names = set(fmu.namelist())
        target = (identity_from_resource(fmu.read("resources/machine.txt").decode("utf-8", "replace"))
                  if "resources/machine.txt" in names else None)
        md = fmu.read("modelDescription.xml") if "modelDescription.xml" in names else None
    model = identity_of_model(ssv_path.parent)
    if model is not None and target is not None:
        diff = mismatch(model, target)
        if diff:
            raise InputError(f"the parameter set was exported for machine {model.describe()}, but the SSP's "
                             f"{comp.get('name')} component simulates {target.describe()} ({'; '.join(diff)}): "
                             "refusing to bind one machine's model to another", ssv_path, field="machine")
    if md is None:
        return
    try:
        mroot = ET.fromstring(md)
    except ET.ParseError:
        raise InputError(f"the {comp.get('name')} FMU's modelDescription.xml is not valid XML", ssp_in) from None
    # FMI 2 ScalarVariable, FMI 3 Float64/Int32/...: every variable element carries its causality
    params = {v.get("name") for v in mroot.iter() if v.get("causality") == "parameter"}
    unknown = sorted(p.get("name") for p in ssv_root.iter(f"{{{SSV}}}Parameter") if p.get("name") not in params)
    if unknown:
        raise InputError(f"the SSP's {comp.get('name')} FMU has no parameter {', '.join(unknown[:5])}"
                         + (f" (and {len(unknown) - 5} more)" if len(unknown) > 5 else "")
                         + ": the set belongs to another machine's model", ssv_path, field="machine")
