"""A pythonfmu build of the compensator (the Python baseline of benchmarks/bench_fmu.py).

pythonfmu writes no units, no InitialUnknowns and no documentation/externalDependencies.txt;
the build adds units and the dependency note so `fmpy validate` reports no problem.  The FMU
needs a Python interpreter with mtcomp in the importing process (unlike the native FMUs).
"""
from __future__ import annotations

import shutil
import tempfile
import zipfile
from importlib import resources
from pathlib import Path
from xml.etree import ElementTree as ET

from .._io import atomic_path, dump_toml
from ..errors import ErrorSet, save_errors
from ..machine import Machine, load_machine
from .build import _unit_definitions

__all__ = ["build_python_compensator_fmu"]


def _patch_model_description(xml: bytes, machine: Machine) -> bytes:
    root = ET.fromstring(xml)
    units = {a.name: ("deg" if a.is_rotary else "mm") for a in machine.axes}
    holder = ET.Element("holder")
    _unit_definitions(holder, set(units.values()))   # the native FMUs' definitions
    # UnitDefinitions come right after the CoSimulation element (FMI 2.0 schema order)
    idx = [i for i, el in enumerate(root) if el.tag == "CoSimulation"][0]
    root.insert(idx + 1, holder[0])
    for sv in root.iter("ScalarVariable"):
        axis = sv.get("name").rsplit(".", 1)[-1]
        real = sv.find("Real")
        if real is not None and axis in units:
            real.set("unit", units[axis])
    ET.indent(root)
    return b'<?xml version="1.0" encoding="UTF-8"?>\n' + ET.tostring(root, encoding="utf-8")


def build_python_compensator_fmu(machine: Machine | str, out_path, errors: ErrorSet | None = None) -> Path:
    """Build the pythonfmu compensator for `machine` and `errors` (stored as resources)."""
    from pythonfmu.builder import FmuBuilder
    machine = load_machine(machine)
    errors = errors or ErrorSet()
    out_path = Path(out_path)
    with tempfile.TemporaryDirectory(prefix="mtcomp-pyfmu-") as td:
        td = Path(td)
        src = resources.files("mtcomp.fmu").joinpath("templates", "py_compensator.py")
        with resources.as_file(src) as p:
            shutil.copyfile(p, td / "py_compensator.py")
        (td / "machine.toml").write_text(dump_toml(machine.to_dict()), encoding="utf-8")
        save_errors(errors, td / "errors.toml")
        project = [td / "machine.toml", td / "errors.toml", *sorted(td.glob("errors_*.csv"))]
        built = FmuBuilder.build_FMU(td / "py_compensator.py", dest=td / "out", project_files=project)
        with zipfile.ZipFile(built) as zin, atomic_path(out_path) as tmp, \
                zipfile.ZipFile(tmp, "w", zipfile.ZIP_DEFLATED) as zout:
            for item in zin.infolist():
                data = zin.read(item.filename)
                if item.filename == "modelDescription.xml":
                    data = _patch_model_description(data, machine)
                zout.writestr(item, data)
            zout.writestr("documentation/externalDependencies.txt",
                          "Needs a Python 3 interpreter in the importing process with pythonfmu's runtime, numpy and "
                          "mtcomp installed (the model calls mtcomp.kinematics.retarget).\n")
    return out_path
