"""Grooving plans designed for the estimate (paper 000): the B inclinations chosen by an optimal-design
criterion over the estimator's covariance, within the machine's travels and the plate.

The estimator (`tool_estimate.estimate`) is linear weighted least squares, so its covariance depends
on the plan and the microscope's sigmas only, never on the data:

    cov = [(A^T W A)^-1]_params,     A = [J N]  (parameter and per-test offset columns)

The B grooves are the only free choice that matters: the A pattern (0 and 180 deg) and the C
triangle (three equally spaced sides) are fixed by symmetry, while the B inclinations decide how
well t_x, t_z and, through t_x, the location errors of C and A (EX0C, EZ0A) are seen.  Depth
changes with B carry t_z only to second order (1 - cos theta) and lateral positions carry it to
first order (sin theta), so the larger the inclination the better, up to what a V tool can cut:
each flank must keep `min_flank` deg from the surface (|theta| <= tip / 2 - min_flank), the groove
must stay narrower than half the spacing, and B must stay within its travel.

Search: every pair of feasible inclinations beside the reference B = 0 (1 deg grid), scored by the
D criterion (log det of the parameters' covariance, the volume of the confidence ellipsoid) or the
A criterion (its trace, the mean variance); then, while a target 1-sigma is missed, the feasible
inclination that improves the score most is added (a greedy exchange step), as long as the plate
holds it.  The per-groove information does not depend on where on the plate the groove lies (the
tool-frame parameters enter through the rotary angles only), so the search adds precomputed
matrices; the covariance reported for the chosen plan is recomputed from the plan itself.
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from .._io import InputError
from .tool_model import COMPONENTS
from .tool_plan import Groove, Plan, PlanOptions, make_plan, groove_width

CRITERIA = ("D", "A")
#: Least angle (deg) between a tilted V tool's flank and the surface for a groove worth measuring.
MIN_FLANK = 15.0


def _nuisance_names(plan: Plan) -> list[str]:
    return [f"{t}:{c}" for t in plan.tests() for c in ("u", "v", "depth")]


def plan_information(machine, plan: Plan, sigma_pos: float, sigma_depth: float, names) -> tuple[np.ndarray, list]:
    """Fisher information (P+K, P+K) 1/mm^2 of a plan measured at every point in u, v and depth,
    with the parameters `names` and the per-test offsets (their names returned second)."""
    from .tool_estimate import _information
    nuis = _nuisance_names(plan)
    A = _information(machine, plan, plan.features(), sigma_pos, sigma_depth, nuis, tuple(names))
    return A.T @ A, nuis


def _profile(info: np.ndarray, P: int) -> np.ndarray:
    """Parameter covariance (P, P) with the nuisance block profiled out (batched over leading dims)."""
    return np.linalg.inv(info)[..., :P, :P]


def _score(cov: np.ndarray, criterion: str) -> np.ndarray:
    if criterion == "D":
        return np.linalg.slogdet(cov)[1]
    return np.trace(cov, axis1=-2, axis2=-1)


def predicted_covariance(machine, plan: Plan, sigma_pos: float = 0.001, sigma_depth: float = 0.001,
                         names=None) -> tuple[tuple, np.ndarray]:
    """(names, cov mm^2) the estimator will have for this plan at these microscope sigmas (mm).
    names default to the parameters `estimate` takes by default (the observable ones)."""
    from ..machine import load_machine
    from .tool_model import observable_parameters
    m = load_machine(machine)
    if names is None:
        names = tuple(observable_parameters(m, plan).estimated)
    info, _ = plan_information(m, plan, sigma_pos, sigma_depth, names)
    try:
        return tuple(names), _profile(info, len(names))
    except np.linalg.LinAlgError:
        raise InputError("singular geometry: the plan does not determine every parameter", field="plan") from None


#: Land left between neighbouring B grooves at their widest, mm.
LAND = 0.3


def b_depth(depth: float, theta, expected_offset: float):
    """Programmed depth (mm) of a B groove inclined by theta deg so that it is cut at least `depth`
    deep whatever the edge offset within `expected_offset` mm in the XZ plane: the edge height
    changes by sin(theta) t_x + (1 - cos(theta)) t_z, at most 2 r sin(|theta| / 2) for |t| <= r.
    Rounded up to 1 µm."""
    extra = 2.0 * expected_offset * np.sin(np.radians(np.abs(theta)) / 2.0)
    return np.ceil((depth + extra) * 1e3 - 1e-9) / 1e3


def feasible_b_angles(machine, options: PlanOptions, min_flank: float = MIN_FLANK, step: float = 1.0,
                      expected_offset: float = 0.5) -> np.ndarray:
    """B inclinations (deg, non-zero, on a `step` grid) a V tool can cut on the plate: both flanks at
    least `min_flank` deg from the surface, B within its travel, and the groove, programmed
    `b_depth` deep, leaves a land of LAND mm to its neighbours even at its deepest (an offset of
    `expected_offset` mm deepening it by as much again)."""
    from ..machine import load_machine
    m = load_machine(machine)
    lim = options.tip_angle / 2.0 - min_flank
    if lim <= 0:
        raise InputError(f"a {options.tip_angle:g} deg tool leaves no inclination with flanks {min_flank:g} deg "
                         "off the surface", field="min_flank")
    lo, hi = m.axis("B").limits if getattr(m.axis("B"), "limits", None) else (-180.0, 180.0)
    th = np.arange(-np.floor(lim / step) * step, lim + 1e-9, step)
    th = th[(th != 0) & (th >= lo) & (th <= hi)]
    deepest = 2 * b_depth(options.depth, th, expected_offset) - options.depth
    ok = groove_width(deepest, options.tip_angle, th) <= options.spacing - LAND
    return th[ok]


@dataclass(frozen=True)
class DesignedPlan:
    """The chosen plan, its predicted covariance (mm^2) of `names`, the criterion and the
    inclinations searched."""
    plan: Plan
    names: tuple
    cov: np.ndarray
    criterion: str
    sigma_pos: float
    sigma_depth: float
    searched: tuple
    target_sigma: float | None = None

    @property
    def sigma(self) -> np.ndarray:
        return np.sqrt(np.diag(self.cov))

    def summary(self) -> str:
        b = [g.angles[1] for g in self.plan.grooves if g.test == "B"]
        how = (f"designed for the estimate, {self.criterion}-optimal over {len(self.searched)} feasible B "
               "inclinations" if self.searched else "as given")
        lines = [f"Plan {how} (microscope sigma {self.sigma_pos * 1e3:g} µm position, "
                 f"{self.sigma_depth * 1e3:g} µm depth): B at " + ", ".join(f"{x:+g}" for x in b) + " deg",
                 "Predicted 1-sigma of every estimated error:"]
        for n, s in zip(self.names, self.sigma):
            flag = "" if self.target_sigma is None or s <= self.target_sigma else "  (above target)"
            lines.append(f"  {n:5s} {s * 1e3:7.3f} µm{flag}")
        return "\n".join(lines)


def design_plan(machine, options: PlanOptions | None = None, *, criterion: str = "D", sigma_pos: float = 0.001,
                sigma_depth: float = 0.001, target_sigma: float | None = None, min_flank: float = MIN_FLANK,
                max_b: int = 8, expected_offset: float = 0.5) -> DesignedPlan:
    """A plan whose B inclinations minimise the criterion ("D": log det, "A": trace of the
    parameters' covariance) with B = 0 as the reference groove, each inclined groove programmed
    deep enough for an edge offset up to expected_offset mm (`b_depth`); with target_sigma (mm) B grooves are
    added until every parameter's predicted 1-sigma is at most the target.  Raises InputError if the
    target cannot be met on the plate, naming the parameters and what limits them."""
    from ..machine import load_machine
    if criterion not in CRITERIA:
        raise InputError(f"expected a criterion D or A, got {criterion!r}", field="criterion")
    for name, v in (("sigma_pos", sigma_pos), ("sigma_depth", sigma_depth)):
        if not (np.isfinite(v) and v > 0):
            raise InputError(f"expected a positive sigma, mm, got {v!r}", field=name)
    if target_sigma is not None and not (np.isfinite(target_sigma) and target_sigma > 0):
        raise InputError(f"expected a positive target sigma, mm, got {target_sigma!r}", field="target_sigma")
    m = load_machine(machine)
    o = options or PlanOptions()
    if "B" not in o.tests:
        plan = make_plan(m, o)
        names, cov = predicted_covariance(m, plan, sigma_pos, sigma_depth)
        return _checked(DesignedPlan(plan, names, cov, criterion, sigma_pos, sigma_depth, (), target_sigma), False)
    if not (np.isfinite(expected_offset) and expected_offset >= 0):
        raise InputError(f"expected an offset bound >= 0 mm, got {expected_offset!r}", field="expected_offset")
    cand = feasible_b_angles(m, o, min_flank, expected_offset=expected_offset)
    if cand.size < 2:
        raise InputError("fewer than two feasible B inclinations: deepen the spacing or use a sharper tool",
                         field="b_angles")
    # the names and the information of everything but the B inclinations, from a reference plan
    ref = _plan_with(m, o, cand, [0, cand.size - 1], expected_offset)
    from .tool_estimate import _location_names
    names = COMPONENTS + _location_names(m, ref, "auto", None)[0]
    P = len(names)
    # the reference plan without its inclined B grooves: A, C and the B = 0 groove
    core = Plan(ref.machine, ref.options, tuple(g for g in ref.grooves if g.test != "B" or g.angles[1] == 0.0),
                ref.faces)
    base, nuis = plan_information(m, core, sigma_pos, sigma_depth, names)
    per = _per_inclination(m, ref, cand, sigma_pos, sigma_depth, names, nuis)
    # every pair beside the reference
    i, j = np.triu_indices(cand.size, 1)
    scores = _score(_profile(base + per[i] + per[j], P), criterion)
    k = int(np.argmin(scores))
    chosen = [int(i[k]), int(j[k])]
    plan = _plan_with(m, o, cand, chosen, expected_offset)
    while True:
        names_, cov = predicted_covariance(m, plan, sigma_pos, sigma_depth, names)
        done = target_sigma is None or np.all(np.sqrt(np.diag(cov)) <= target_sigma)
        if done or len(chosen) + 1 >= max_b:
            break
        info = base + per[chosen].sum(axis=0)
        free = [c for c in range(cand.size) if c not in chosen]
        s = _score(_profile(info[None] + per[free], P), criterion)
        nxt = chosen + [free[int(np.argmin(s))]]
        try:
            plan = _plan_with(m, o, cand, nxt, expected_offset)
        except InputError:   # the plate holds no more B grooves
            break
        chosen = nxt
    return _checked(DesignedPlan(plan, names_, cov, criterion, sigma_pos, sigma_depth, tuple(cand.tolist()),
                                 target_sigma), True)


def _plan_with(m, o: PlanOptions, cand, chosen, expected_offset) -> Plan:
    angles = (0.0,) + tuple(float(cand[c]) for c in sorted(chosen, key=lambda c: (abs(cand[c]), -cand[c])))
    depths = tuple(float(b_depth(o.depth, a, expected_offset)) for a in angles)
    return make_plan(m, replace(o, b_angles=angles, b_depths=depths))


def _groove_info(m, plan, g: Groove, sigma_pos, sigma_depth, names, nuis) -> np.ndarray:
    from .tool_estimate import _information
    p2 = Plan(plan.machine, plan.options, (g,), plan.faces)
    A = _information(m, p2, [(g.id, "start"), (g.id, "end")], sigma_pos, sigma_depth, nuis, tuple(names))
    return A.T @ A


def _per_inclination(m, ref: Plan, cand, sigma_pos, sigma_depth, names, nuis) -> np.ndarray:
    g0 = next(g for g in ref.grooves if g.test == "B")
    return np.array([_groove_info(m, ref, replace(g0, id=f"B{th:+g}", angles=(0.0, float(th), 0.0)),
                                  sigma_pos, sigma_depth, names, nuis) for th in cand])


def _checked(d: DesignedPlan, searched: bool) -> DesignedPlan:
    if d.target_sigma is None:
        return d
    over = [(n, s) for n, s in zip(d.names, d.sigma) if s > d.target_sigma]
    if not over:
        return d
    b_bound = {"t_x", "t_z", "EX0C", "EZ0A", "EX0B", "EZ0B"}
    why = []
    for n, s in over:
        lim = ("more B grooves than the plate holds or a finer microscope" if n in b_bound and searched
               else "a finer microscope or repeated A/C patterns (the B inclinations do not move it)")
        why.append(f"{n} {s * 1e3:.3f} µm (needs {lim})")
    raise InputError(f"target 1-sigma {d.target_sigma * 1e3:g} µm not reachable: " + "; ".join(why),
                     field="target_sigma")
