"""Verification of a program compensated for a workpiece setting, on the blank where it really is.

A program rewritten for the measured pose of a blank (`workpiece.compensate_text`) runs on a
machine whose blank sits at that pose.  It is verified as the control will run it: every block,
rapids included, through the machine model *with* the workpiece setting error
(`mtcomp.verify.verify_program(errors=ErrorSet(workpiece=pose))`), so the tool points come out
in the frame of the real blank, and checked against the blank: rapids keep `clearance` from it,
except retracts (a rapid that starts at the end of a cut and moves straight away from the blank,
`verify_commands(retracts=True)`): part programs retract from the cut at rapid.
Where no part shape is given, feed moves are not checked (they cut the blank by design).

The blank of a bowl plan is the box ``lx x ly x lz`` with its top face at z = 0, centred on
x = y = 0 (`BowlPlan.blank`).  Lengths mm, angles deg.
"""
from __future__ import annotations

from dataclasses import dataclass

DEFAULT_CLEARANCE = 0.2   # mm, as `mtcomp verify`


def plan_stock(plan):
    """The blank of a `BowlPlan` as a `mtcomp.verify.Box` (workpiece frame, mm)."""
    from ..verify import Box
    lx, ly, lz = (float(v) for v in plan.blank)
    return Box((-lx / 2, -ly / 2, -lz), (lx / 2, ly / 2, 0.0))


def verify_on_blank(machine, text: str, pose, stock, *, clearance: float = DEFAULT_CLEARANCE,
                    tool_radius: float = 0.0, part=None, filename: str = "<program>",
                    raise_on_violation: bool = True, tool_lengths=None):
    """Verify compensated program `text` on `machine` with the blank at `pose` (a
    WorkpieceSetting); `stock`/`part` in the blank's own frame (mm).  Returns the
    `mtcomp.verify.VerifyResult`; raises `VerifyError` naming the first failing block unless
    raise_on_violation is False."""
    from ..errors import ErrorSet
    from ..verify import verify_program
    return verify_program(machine, text, filename=filename, stock=stock, part=part,
                          clearance=clearance, tool_radius=tool_radius,
                          errors=ErrorSet(workpiece=pose), raise_on_violation=raise_on_violation,
                          retracts=True, tool_lengths=tool_lengths)


@dataclass(frozen=True)
class BlankCheck:
    """A cell `program_check` (``check(machine, path, text)``) that verifies the compensated
    program on the blank at `pose` against `stock` with `clearance` (mm); a failure raises
    `VerifyError` (an MtcompError: the cell faults with PROGRAM_FAILED and names the block).
    `results` collects the VerifyResults (for the journal's min clearance)."""
    pose: object
    stock: object
    clearance: float = DEFAULT_CLEARANCE
    tool_radius: float = 0.0
    results: list = None

    def __call__(self, machine, path, text):
        # the cell names the file in its fault; `path` may still be the temporary name
        res = verify_on_blank(machine, text, self.pose, self.stock, clearance=self.clearance,
                              tool_radius=self.tool_radius, filename="on the measured blank")
        if self.results is not None:
            self.results.append(res)
        return res


@dataclass(frozen=True)
class Inflated:
    """`stock` grown by `radius` mm: a ball tool of that radius *centred* on the programmed point
    (a probing program programs the probe centre) is a point tool against it."""
    stock: object
    radius: float

    def distance(self, pts):
        return self.stock.distance(pts) - self.radius

    def describe(self) -> str:
        return f"{self.stock.describe()} (for a probe ball R{self.radius:g} about the programmed point)"


def verify_plan_programs(plan, roughing: str, probing: str, *, clearance: float = DEFAULT_CLEARANCE,
                         roughing_machine="vmc-moving-column", probing_machine="robonano-a0ib",
                         raise_on_violation: bool = True):
    """Verify the two programs of a bowl plan on its nominal blank: the roughing program (ball end
    mill of `plan.tool_radius`, tip programmed) on the ordinary machining centre, the probing
    program (probe ball of `plan.probe_radius`, centre programmed; G31 moves are not checked) on
    the ultraprecision machine.  Rapids keep `clearance` mm, retracts out of the cut excepted.
    Returns (roughing result, probing result)."""
    from ..machine import load_machine
    from ..verify import verify_program
    stock = plan_stock(plan)
    kw = dict(clearance=clearance, retracts=True, raise_on_violation=raise_on_violation)
    rough = verify_program(load_machine(roughing_machine), roughing, filename="roughing program",
                           stock=stock, tool_radius=plan.tool_radius, **kw)
    probe = verify_program(load_machine(probing_machine), probing, filename="probing program",
                           stock=Inflated(stock, plan.probe_radius), **kw)
    return rough, probe
