"""Verification of the grooving programs of a tool-setting plan on their plates.

Each test's program (`tool_plan.nc_programs`) is run through the machine model, rapids included
(`mtcomp.verify.verify_program`), against the plate of the face its grooves are cut in: a plate
of `plan.options.plate` (w x h mm) centred on the face origin, `thickness` mm deep below the face
(the plate's far side does not matter to the rapids above it).  Rapids keep `clearance` mm from
it, retracts out of the cut excepted.  A compensated program is verified on the machine with the
errors it was compensated for (the real machine), so its edge lands where the nominal one would.
The V tool is a point (its edge); its flanks and holder are not modelled.  Lengths mm.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

DEFAULT_CLEARANCE = 0.2   # mm, as `mtcomp verify`


@dataclass(frozen=True)
class FacePlate:
    """The plate under a `tool_plan.Face`: |u| <= w/2, |v| <= h/2, -thickness <= w <= 0 in the
    face frame (u along eu, v along ev, w along the outward normal), mm."""
    face: object
    size: tuple
    thickness: float = 5.0

    def distance(self, pts: np.ndarray) -> np.ndarray:
        """Signed distance (N,) mm, positive outside (exact: a box in the face frame)."""
        f = self.face
        frame = np.array([f.eu, f.ev, f.normal], float)
        local = (np.asarray(pts, float) - np.asarray(f.origin, float)) @ frame.T
        w, h = self.size
        c = np.array([0.0, 0.0, -self.thickness / 2])
        half = np.array([w / 2, h / 2, self.thickness / 2])
        d = np.abs(local - c) - half
        return np.linalg.norm(np.maximum(d, 0.0), axis=1) + np.minimum(d.max(axis=1), 0.0)

    def describe(self) -> str:
        return f"{self.size[0]:g} x {self.size[1]:g} mm plate under the {self.face.name} face"


def verify_grooving(machine, plan, programs: dict, errors=None, *, clearance: float = DEFAULT_CLEARANCE,
                    raise_on_violation: bool = True) -> dict:
    """Verify program text per test ({test: text}, as `nc_programs` returns) on `machine` (with
    `errors`: the real machine a compensated program is written for).  Returns {test:
    VerifyResult}; raises `VerifyError` naming the program and block unless raise_on_violation
    is False."""
    from ..verify import verify_program
    out = {}
    for test, text in programs.items():
        faces = sorted({g.face for g in plan.grooves if g.test == test})
        if len(faces) != 1:   # the default and every generated plan cut one test on one face
            continue
        stock = FacePlate(plan.faces[faces[0]], tuple(plan.options.plate))
        out[test] = verify_program(machine, text, filename=f"tool_setting_{test}.nc", stock=stock,
                                   clearance=clearance, errors=errors, retracts=True,
                                   raise_on_violation=raise_on_violation)
    return out
