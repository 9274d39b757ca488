"""Compensation into the control: the controls' own compensation tables and kinematic parameters.

`export_control` writes, for one control (linuxcnc, fanuc, siemens, heidenhain), the files that
control reads -- pitch tables per direction of approach, straightness where the control has a
cross-axis table, rotary-axis locations as the parameters of its 5-axis transformation -- plus
``remainder.toml``, the errors the control cannot hold (for the NC rewrite).  `import_control`
reads such a folder back into an `ErrorSet` (and the reversal tables), so a shop's existing
tables can start a calibration.  Formats, sources and limits: docs/control.md.
"""
from __future__ import annotations

import importlib
import os
from pathlib import Path

import numpy as np

from .._io import InputError
from ..errors import AxisErrorTable, ErrorSet, GeometricErrors, check_for_machine, load_errors, save_errors
from ..machine import Machine, load_machine
from .common import ControlLimitError, ExportResult, merge_errors, split_errors, write_files

__all__ = ["CONTROLS", "export_control", "import_control", "ControlLimitError", "ExportResult",
           "REMAINDER"]

CONTROLS = ("linuxcnc", "fanuc", "siemens", "heidenhain")
REMAINDER = "remainder.toml"


def _module(control: str):
    if control not in CONTROLS:
        raise InputError(f"unknown control {control!r}; expected one of {', '.join(CONTROLS)}", field="--control")
    return importlib.import_module(f"{__name__}.{control}")


def export_texts(control: str, machine: Machine | str, errors: ErrorSet, reversal: dict | None = None):
    """(files {name: text}, ExportResult without files): everything computed, nothing written."""
    machine = load_machine(machine)
    check_for_machine(errors, machine)
    mod = _module(control)
    split = split_errors(machine, errors, reversal)
    files, held_loc, held, notes, left_tables = mod.export(machine, split)
    left = {k: v for k, v in split.location.items() if k not in held_loc}
    rest_g = split.rest.geometric
    tables = dict(rest_g.tables)
    # every control here holds the pitch tables; straightness goes back where it has no table
    for (ax, d), (pos, v) in split.straightness.items():
        if not getattr(mod, "HOLDS_STRAIGHTNESS", False):
            tables[ax] = _with(tables.get(ax), ax, pos, {f"E{d}{ax}": v})
    for ax, (pos, vals) in left_tables.items():       # parts of a table the control cannot hold
        tables[ax] = _with(tables.get(ax), ax, pos, vals)
    loc = dict(rest_g.location)
    loc.update(left)
    remainder = ErrorSet(split.rest.tool, split.rest.workpiece, GeometricErrors(tables, loc))
    return files, ExportResult(mod.NAME, (), tuple(held), remainder, tuple(notes))


def _with(table, ax, pos, vals):
    if table is None:
        return AxisErrorTable(ax, pos, vals)
    if not np.array_equal(table.position, pos):
        raise InputError(f"components of axis {ax} on different positions", field=ax)
    return AxisErrorTable(ax, pos, {**dict(table.values), **vals})


def export_control(control: str, machine: Machine | str, errors: ErrorSet | str | os.PathLike,
                   directory: str | os.PathLike, reversal: dict | None = None) -> ExportResult:
    """Write the control's files and remainder.toml into `directory` (every file atomically,
    all computed and checked against the control's limits before the first is written)."""
    machine = load_machine(machine)
    if not isinstance(errors, ErrorSet):
        errors = load_errors(errors, machine)
    files, res = export_texts(control, machine, errors, reversal)
    written = list(write_files(directory, files))
    written.append(save_errors(res.remainder, Path(directory) / REMAINDER,
                               meta={"written_by": f"mtcomp control export --control {control}",
                                     "what": "errors the control's files do not hold: for the NC rewrite"}))
    # read back what was written: the rounding to the control's increments, as figures
    back, back_rev = import_control(control, machine, directory)
    return ExportResult(res.control, tuple(written), res.held, res.remainder, res.notes,
                        rounding_figures(errors, reversal, back, back_rev))


def rounding_figures(errors: ErrorSet, reversal: dict | None, back: ErrorSet, back_rev: dict) -> dict:
    """Largest difference between the errors exported and read back: translational (µm) and
    angular (µrad) table components and location errors, and the reversal (µm)."""
    lin = ang = 0.0
    for ax, t in errors.geometric.tables.items():
        tb = back.geometric.tables.get(ax)
        for k, v in t.values.items():
            w = tb.values.get(k) if tb is not None else None
            d = float(np.max(np.abs(v - (w if w is not None else 0.0))))
            if k[1] in "XYZ":
                lin = max(lin, d)
            else:
                ang = max(ang, d)
    for k, v in errors.geometric.location.items():
        d = abs(v - back.geometric.location.get(k, 0.0))
        if k[1] in "XYZ":
            lin = max(lin, d)
        else:
            ang = max(ang, d)
    rev = 0.0
    for ax, r in (reversal or {}).items():
        b = back_rev.get(ax)
        t = errors.geometric.tables[ax].position
        want = np.interp(t, r.position, r.reversal_i)
        got = b.reversal_i if b is not None else np.zeros(t.size)
        rev = max(rev, float(np.max(np.abs(want - got))))
    return {"largest rounding to the control's increments":
            f"{lin * 1e3:.4f} µm (tables and locations), {ang * 1e6:.4f} µrad (angles), "
            f"{rev * 1e3:.4f} µm (reversal)"}


def import_control(control: str, machine: Machine | str, directory: str | os.PathLike,
                   remainder: bool = True) -> tuple[ErrorSet, dict]:
    """(ErrorSet, {axis: ReversalTable}) from a folder of the control's files; remainder.toml is
    added when present (and `remainder`)."""
    machine = load_machine(machine)
    d = Path(directory)
    if not d.is_dir():
        raise InputError("expected a folder of the control's files", d)
    mod = _module(control)
    pitch, straight, location = mod.read(machine, d)
    rest = load_errors(d / REMAINDER, machine) if remainder and (d / REMAINDER).exists() else None
    return merge_errors(pitch, straight, location, rest)


def remainder_after(machine: Machine | str, errors: ErrorSet, held: ErrorSet) -> tuple[ErrorSet, list]:
    """What a program must still correct when the control already compensates `held` (e.g. the
    import of its existing tables): errors - held, component by component, with `held`'s tables
    interpolated at the error tables' positions and held at their ends (as the controls do).

    `errors` are the machine's errors with the control's compensation off; components that come
    out exactly 0 are dropped.  Returns (ErrorSet, notes)."""
    machine = load_machine(machine)
    g, h = errors.geometric, held.geometric
    notes, tables = [], {}
    for ax in sorted(set(g.tables) | set(h.tables), key="XYZUVWABC".index):
        te, th = g.tables.get(ax), h.tables.get(ax)
        pos = te.position if te is not None else th.position
        vals = {k: np.asarray(v, float) for k, v in (te.values.items() if te is not None else ())}
        if th is not None:
            if te is not None and (th.range[0] > pos[0] or th.range[1] < pos[-1]):
                notes.append(f"axis {ax}: the control's table covers {th.range[0]:g} .. {th.range[1]:g}, "
                             f"the errors {pos[0]:g} .. {pos[-1]:g}: its end values are taken beyond")
            for k, v in th.values.items():
                vals[k] = vals.get(k, 0.0) - np.interp(pos, th.position, v)
        vals = {k: v for k, v in vals.items() if np.any(v != 0)}
        if vals:
            tables[ax] = AxisErrorTable(ax, pos, vals)
    loc = dict(g.location)
    for k, v in h.location.items():
        loc[k] = loc.get(k, 0.0) - v
    loc = {k: v for k, v in loc.items() if v != 0}
    return ErrorSet(errors.tool, errors.workpiece, GeometricErrors(tables, loc)), notes
