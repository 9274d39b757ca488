"""STEP and STL export of CadQuery shapes, written atomically (no half-written file on failure)."""
from __future__ import annotations

import os
from pathlib import Path

from .._io import MtcompError, atomic_path


def _shape(obj, path):
    """Accept a cq.Shape or a cq.Workplane (its first object); `path` names the output in errors."""
    import cadquery as cq
    if isinstance(obj, cq.Workplane):
        vals = [v for v in obj.vals() if isinstance(v, cq.Shape)]
        if not vals:
            raise MtcompError(f"{path}: the workplane carries no shape to export")
        return vals[0] if len(vals) == 1 else cq.Compound.makeCompound(vals)
    return obj


def export_step(shape, path: str | os.PathLike, name: str | None = None) -> Path:
    """Write `shape` (mm) to a STEP file (AP214, unit mm) whose product is called `name`
    (default: the file name without suffix), so CAD/CAM importers show a part name instead of
    an empty or generic one."""
    shape = _shape(shape, path)
    from OCP.IFSelect import IFSelect_RetDone
    from OCP.Interface import Interface_Static
    from OCP.STEPCAFControl import STEPCAFControl_Writer
    from OCP.STEPControl import STEPControl_AsIs
    from OCP.TCollection import TCollection_ExtendedString
    from OCP.TDataStd import TDataStd_Name
    from OCP.TDocStd import TDocStd_Document
    from OCP.XCAFDoc import XCAFDoc_DocumentTool
    name = name or Path(path).stem
    # The product name lives in an XCAF document: one label holding the shape, named.
    doc = TDocStd_Document(TCollection_ExtendedString("XmlOcaf"))
    label = XCAFDoc_DocumentTool.ShapeTool_s(doc.Main()).AddShape(shape.wrapped, False)
    TDataStd_Name.Set_s(label, TCollection_ExtendedString(name))
    Interface_Static.SetCVal_s("write.step.unit", "MM")
    writer = STEPCAFControl_Writer()
    if not writer.Transfer(doc, STEPControl_AsIs):
        raise MtcompError(f"{path}: STEP export failed (transfer)")
    with atomic_path(path) as tmp:
        status = writer.Write(str(tmp))
        if status != IFSelect_RetDone:
            raise MtcompError(f"{path}: STEP export failed ({status})")
    return Path(path)


def export_stl(shape, path: str | os.PathLike, tolerance: float = 1e-3,
               angular_tolerance: float = 0.1, ascii: bool = False) -> Path:
    """Write a triangulation of `shape` to STL: chordal `tolerance` mm, `angular_tolerance` rad."""
    shape = _shape(shape, path)
    with atomic_path(path) as tmp:
        if not shape.exportStl(str(tmp), tolerance=tolerance, angularTolerance=angular_tolerance,
                               ascii=ascii):
            raise MtcompError(f"{path}: STL export failed")
    return Path(path)


def import_step(path: str | os.PathLike):
    """Read a STEP file back as a cq.Shape (used to check exports)."""
    import cadquery as cq
    return cq.importers.importStep(str(path)).val()
