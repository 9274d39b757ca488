"""Tool setting errors by grooving (paper 000): virtual grooving and the measurement sheet.

The tool setting error is the vector t (mm) from the nominal tool point (the common rotation
centre of A, B, C) to the real tool edge, in the frame carried by C (`mtcomp.errors.ToolSetting`).
A groove cut with fixed rotary angles is the trace of the real edge, so it is the programmed
groove shifted by R(A, B, C) t; everything here goes through `mtcomp.kinematics.forward`.

Library entry points (re-exported here):

* `make_plan`, `write_plan` (tool_plan): grooves, NC programs, layout PNG, measurement sheet;
* `cut_grooves`, `simulate_grooving`: predicted grooves and synthetic microscope measurements;
* `read_measurements`, `measurements_csv`: the filled measurement sheet;
* `estimate` (tool_estimate): weighted least squares with covariance, plus the closed forms;
* `paper_experiment`: the paper's Table 1 experiment, virtually.
"""
from __future__ import annotations

import csv
import io
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .._io import InputError, MtcompError
from ..errors import rotation_matrix_xyz
from .tool_plan import (FEATURES, SHEET_COLUMNS, Groove, Plan, PlanOptions, commands_for_points,  # noqa: F401
                        groove_width, load_plan, make_plan, nc_programs, plot_layout, sheet_template,
                        write_plan)


def _errorset(errors):
    from ..errors import ErrorSet, ToolSetting
    if errors is None:
        return None
    if isinstance(errors, ErrorSet):
        return errors
    if isinstance(errors, ToolSetting):
        return ErrorSet(tool=errors)
    return ErrorSet(tool=ToolSetting(tuple(np.asarray(errors, float))))


# ---------------------------------------------------------------------------------------------
# Virtual grooving

@dataclass(frozen=True)
class CutGroove:
    """A groove as the real machine cuts it.  start/end: groove bottom (u, v) in the face frame,
    mm; depth: below the real surface, mm (after touching off at the test's first groove);
    width: at the surface, mm; tilt: tool axis tilt in the groove's cross-section, deg;
    cut: False if the edge never enters the material (depth <= 0)."""
    groove: Groove
    start: tuple[float, float]
    end: tuple[float, float]
    depth: float
    width: float
    tilt: float
    cut: bool

    def point(self, feature: str) -> tuple[float, float]:
        return self.start if feature == "start" else self.end


def programmed_commands(machine, plan: Plan, items) -> np.ndarray:
    """Axis commands (N, n_axes) of the programmed groove points (groove id, feature) at depth D."""
    from ..machine import load_machine
    m = load_machine(machine)
    pts, ang = [], []
    for gid, feat in items:
        g = plan.groove(gid)
        pts.append(plan.face_of(g).point(g.point(feat), g.depth)[0])
        ang.append(g.angles)
    return commands_for_points(m, np.array(pts), np.array(ang))


def cut_grooves(machine, plan: Plan, errors=None, compensation=None, touch_off: bool = True) -> tuple[CutGroove, ...]:
    """Predict the grooves cut on the real machine with `errors` (ErrorSet, ToolSetting or an
    offset (3,) mm) by the plan's programs, compensated for `compensation` (ErrorSet or None).

    touch_off: the surface is found with the real tool at each test's first groove orientation
    (as an operator does), so that groove has exactly the depth of cut D; otherwise the surface
    is the nominal face plane."""
    from ..kinematics import forward, retarget
    from ..machine import load_machine
    m = load_machine(machine)
    errs = _errorset(errors)
    items = [(g.id, f) for g in plan.grooves for f in FEATURES]
    q = programmed_commands(m, plan, items)
    if compensation is not None:
        q = retarget(m, q, _errorset(compensation), round_result=True)
    pose = forward(m, q, errs)
    out, ref_shift = [], {}
    for k, g in enumerate(plan.grooves):
        face = plan.face_of(g)
        c = face.coords(pose.p[2 * k:2 * k + 2])          # (2, 3): u, v, depth below the nominal face
        if touch_off and g.test not in ref_shift:
            ref_shift[g.test] = c[0, 2] - g.depth
        depth = float(np.mean(c[:, 2]) - (ref_shift.get(g.test, 0.0) if touch_off else 0.0))
        # Tilt of the tool axis in the cross-section plane (normal: the cut direction).
        v = pose.v[2 * k]
        d3 = pose.p[2 * k + 1] - pose.p[2 * k]
        d3 /= np.linalg.norm(d3)
        vp = v - (v @ d3) * d3
        n = np.asarray(face.normal)
        tilt = float(np.degrees(np.arctan2(np.cross(n, vp) @ d3, n @ vp)))
        width = float(groove_width(max(depth, 0.0), plan.options.tip_angle, tilt))
        out.append(CutGroove(g, tuple(map(float, c[0, :2])), tuple(map(float, c[1, :2])), depth, width, tilt,
                             depth > 0))
    return tuple(out)


def intersection(a: CutGroove, b: CutGroove):
    """Crossing point (u, v) mm of the bottom lines of two cut grooves on the same face, or None
    if the segments do not cross (parallel or apart)."""
    if a.groove.face != b.groove.face:
        return None
    p, r = np.array(a.start), np.subtract(a.end, a.start)
    q, s = np.array(b.start), np.subtract(b.end, b.start)
    den = r[0] * s[1] - r[1] * s[0]
    if abs(den) < 1e-12 * np.linalg.norm(r) * np.linalg.norm(s):
        return None
    w = q - p
    ta = (w[0] * s[1] - w[1] * s[0]) / den
    tb = (w[0] * r[1] - w[1] * r[0]) / den
    if -1e-9 <= ta <= 1 + 1e-9 and -1e-9 <= tb <= 1 + 1e-9:
        return tuple(map(float, p + ta * r))
    return None


def table1_distances(plan: Plan, cuts) -> dict[str, tuple[float, float]]:
    """Groove distances like paper 000's Table 1, in mm, (du, dv) in the face frame.

    A: between the A = 0 and A = 180 copies of each groove (du from the grooves along v, dv from
    the grooves along u).  C: the gap where the triangle should close (start of its first side
    against the end of its last side)."""
    return {k: (float(abs(a)), float(abs(b))) for k, (a, b) in table1_signed(plan, cuts).items()}


def table1_signed(plan: Plan, cuts) -> dict[str, tuple[float, float]]:
    """`table1_distances` with signs (A: A = 180 copy minus A = 0 copy; C: first side's start
    minus last side's end), mm."""
    by = {c.groove.id: c for c in cuts}
    out = {}
    a = [g for g in plan.grooves if g.test == "A"]
    a0 = [g for g in a if g.angles[0] == min(x.angles[0] for x in a)]
    a1 = [g for g in a if g.angles[0] == max(x.angles[0] for x in a)]
    if a0 and a1 and a0[0].angles != a1[0].angles:
        du = dv = np.nan
        for g0 in a0:
            g1 = next((g for g in a1 if g.start == g0.start and g.end == g0.end), None)
            if g1 is None:
                continue
            d = np.subtract(by[g1.id].start, by[g0.id].start)
            if abs(g0.direction[0]) > abs(g0.direction[1]):   # along u: measures the v distance
                dv = d[1]
            else:
                du = d[0]
        out["A"] = (float(du), float(dv))
    c = [g for g in plan.grooves if g.test == "C"]
    if len(c) >= 2:
        d = np.subtract(by[c[0].id].start, by[c[-1].id].end)
        out["C"] = (float(d[0]), float(d[1]))
    return out


# ---------------------------------------------------------------------------------------------
# Measurements

#: Accepted 1-sigma of a measured value, mm: below 1e-9 the weights overflow the fit, above 10 mm
#: the value says nothing about a tool offset.
SIGMA_RANGE = (1e-9, 10.0)


@dataclass(frozen=True)
class MicroscopeNoise:
    """Measurement noise (1 sigma, mm): position of the groove bottom in the face plane, depth."""
    position: float = 0.001
    depth: float = 0.001


@dataclass(frozen=True)
class PointMeasurement:
    """One measured groove point: (u, v) mm in the face frame (any origin per test) and depth mm
    below the surface; NaN where not measured.  sigma_*: 1-sigma (mm), None for the defaults."""
    groove: str
    feature: str
    u: float
    v: float
    depth: float
    sigma_pos: float | None = None
    sigma_depth: float | None = None
    line: int | None = None


@dataclass(frozen=True)
class GroovingMeasurements:
    """Measured groove points of a plan, with default sigmas (mm) for rows that give none."""
    plan: Plan
    points: tuple[PointMeasurement, ...]
    sigma_pos: float = 0.001
    sigma_depth: float = 0.001
    source: str = "<measurements>"

    def __post_init__(self):
        for name in ("sigma_pos", "sigma_depth"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and np.isfinite(v) and SIGMA_RANGE[0] <= v <= SIGMA_RANGE[1]):
                raise InputError(f"expected a sigma between {SIGMA_RANGE[0]:g} and {SIGMA_RANGE[1]:g} mm, got {v!r}",
                                 field=name)


def simulate_grooving(machine, tool_setting, noise: MicroscopeNoise | None = None, seed=None, *,
                      plan: Plan | None = None, compensation=None, frame_offset: float = 0.0,
                      frame_rotation: float = 0.0, frame_scale: float = 0.0, drift=None) -> GroovingMeasurements:
    """Synthetic microscope measurements of the grooves cut with the true `tool_setting`
    (ToolSetting, ErrorSet or offset (3,) mm): every point of the plan's measurement sheet, with
    Gaussian noise of `noise` (default 1 µm on positions and depths) from `seed`.  plan: default
    `make_plan(machine)`; compensation: ErrorSet the programs are compensated for.

    frame_offset: mm; each test is measured in a microscope frame whose origin is shifted by a
    uniform random (u, v) in +-frame_offset (the estimator must not depend on it), and turned by
    a uniform random angle in +-frame_rotation deg (about the face origin; `estimate(...,
    fit_rotation=True)` removes it).  frame_scale: relative scale error of the microscope's (u, v)
    readings (magnification), the same for every test (`estimate(..., fit_scale=True)` removes it).
    drift: (3,) mm, the tool's thermal drift against the workpiece (workpiece frame) over the whole
    procedure, linear in the cutting order (`tool_plan.cutting_times`): each groove lies shifted
    by tau * drift.
    Raises MtcompError if a groove would not be cut (depth <= 0): increase the depth of cut."""
    from ..machine import load_machine
    m = load_machine(machine)
    plan = plan or make_plan(m)
    noise = noise or MicroscopeNoise()
    for name, v, lim in (("frame_offset", frame_offset, 10.0), ("frame_rotation", frame_rotation, 45.0),
                         ("frame_scale", frame_scale, 0.1)):
        if not (isinstance(v, (int, float)) and np.isfinite(v) and abs(v) <= lim):
            raise InputError(f"expected a finite {name.replace('_', ' ')} of at most {lim:g} in size, got {v!r}",
                             field=name.replace("_", "-"))
    rng = np.random.default_rng(seed)
    cuts = {c.groove.id: c for c in cut_grooves(m, plan, tool_setting, compensation)}
    uncut = [c.groove.id for c in cuts.values() if not c.cut]
    if uncut:
        raise MtcompError(f"grooves {', '.join(uncut)} would not be cut (the edge stays above the surface): "
                          f"increase the depth of cut (now {plan.options.depth:g} mm)")
    origin = {t: rng.uniform(-frame_offset, frame_offset, 2) if frame_offset else np.zeros(2) for t in plan.tests()}
    turn = {}
    for t in plan.tests():
        a = rng.uniform(-frame_rotation, frame_rotation) if frame_rotation else 0.0
        turn[t] = rotation_matrix_xyz((0.0, 0.0, a))[:2, :2]     # in-plane turn of the face frame
    from .tool_plan import cutting_times
    tau = cutting_times(plan)
    drift = np.zeros(3) if drift is None else np.asarray(drift, float)
    if drift.shape != (3,) or not np.all(np.isfinite(drift)) or np.abs(drift).max() > 1.0:
        raise InputError(f"expected a drift of three finite mm values below 1 mm, got {drift!r}", field="drift")
    pts = []
    for gid, feat in plan.features():
        c = cuts[gid]
        test = c.groove.test
        shift = plan.face_of(c.groove).basis @ (tau[gid] * drift)      # (du, dv, ddepth)
        u, v = ((1.0 + frame_scale) * (turn[test] @ (np.asarray(c.point(feat)) + shift[:2])) + origin[test]
                + rng.normal(0.0, noise.position, 2))
        d = c.depth + shift[2] + rng.normal(0.0, noise.depth)
        pts.append(PointMeasurement(gid, feat, float(u), float(v), float(d)))
    # Noise-free synthesis still needs finite weights: use the machine's resolution scale.
    return GroovingMeasurements(plan, tuple(pts), noise.position or 1e-6, noise.depth or 1e-6, "<simulated>")


def measurements_csv(meas: GroovingMeasurements, comment: str = "") -> str:
    """The filled measurement sheet (same columns as the template)."""
    plan = meas.plan
    buf = io.StringIO()
    buf.write("# mtcomp tool-setting measurement sheet (docs/tool-setting.md): groove bottom u, v in the face "
              "frame and depth below the surface, mm\n")
    if comment:
        for line in comment.splitlines():
            buf.write(f"# {line}\n")
    w = csv.writer(buf, lineterminator="\n")
    extra = any(p.sigma_pos is not None or p.sigma_depth is not None for p in meas.points)
    w.writerow(SHEET_COLUMNS + (("sigma_pos_mm", "sigma_depth_mm") if extra else ()))
    cell = lambda x: "" if x is None or not np.isfinite(x) else f"{x:.7f}"  # noqa: E731
    for p in meas.points:
        g = plan.groove(p.groove)
        u0, v0 = g.point(p.feature)
        row = [p.groove, p.feature, g.test, g.face, f"{g.angles[0]:g}", f"{g.angles[1]:g}", f"{g.angles[2]:g}",
               f"{u0:.6f}", f"{v0:.6f}", f"{g.depth:.6f}", cell(p.u), cell(p.v), cell(p.depth), ""]
        if extra:
            row += [cell(p.sigma_pos), cell(p.sigma_depth)]
        w.writerow(row)
    return buf.getvalue()


_REQUIRED = ("groove", "feature", "u_mm", "v_mm", "depth_mm")


def read_measurements(path: str | os.PathLike, plan: Plan, sigma_pos: float = 0.001,
                      sigma_depth: float = 0.001) -> GroovingMeasurements:
    """Read and validate a filled measurement sheet against its plan.

    Read by `mtcomp.csvtable` (docs/csv-format.md).  Every problem is an InputError naming the
    file, the line and the column: unknown groove ids or features, angles that differ from the
    plan's, numbers that are not plain finite decimals of at most 1e6 mm, duplicate points, and
    grooves of the plan without any measured value."""
    from ..csvtable import read_csv
    path = Path(path)
    # short rows are padded: a sheet filled in a spreadsheet often drops trailing empty cells
    tab = read_csv(path, what="measurement", pad=True)
    missing = [c for c in _REQUIRED if not tab.has(c)]
    if missing:
        raise tab.error(f"missing columns {missing}; expected at least {', '.join(_REQUIRED)}")
    ids = plan.ids
    pts, seen = [], {}

    def number(r, col, positive=False):
        """The cell in mm (NaN if empty, None without the column): a plain finite number of at
        most 1e6 mm (docs/csv-format.md)."""
        if not tab.has(col):
            return None
        x = tab.number(r, col, unit="mm", max_abs=1e6, empty=np.nan)
        if positive and not np.isnan(x) and not SIGMA_RANGE[0] <= x <= SIGMA_RANGE[1]:
            raise tab.error(f"{tab.cell(r, col)!r}: expected a sigma between {SIGMA_RANGE[0]:g} and "
                            f"{SIGMA_RANGE[1]:g} mm", r, col)
        return x

    for r, n in enumerate(tab.lines):
        gid, feat = tab.cell(r, "groove"), tab.cell(r, "feature")
        if gid not in ids:
            raise InputError(f"unknown groove id {gid!r}; the plan has {', '.join(ids)}", path, n, "groove")
        if feat not in FEATURES:
            raise InputError(f"unknown feature {feat!r}; expected {' or '.join(FEATURES)}", path, n, "feature")
        g = plan.groove(gid)
        for k, col in enumerate(("a_deg", "b_deg", "c_deg")):
            a = tab.number(r, col, unit="deg", max_abs=1e6, empty=np.nan) if tab.has(col) else None
            if a is not None and not np.isnan(a) and abs(a - g.angles[k]) > 1e-6:
                raise InputError(f"inconsistent angles: {col} = {a:g} but the plan cuts groove {gid} at "
                                 f"{'ABC'[k]} = {g.angles[k]:g} deg", path, n, col)
        if tab.has("test") and tab.cell(r, "test") and tab.cell(r, "test") != g.test:
            raise InputError(f"groove {gid} belongs to test {g.test}, not {tab.cell(r, 'test')!r}", path, n, "test")
        key = (gid, feat)
        if key in seen:
            raise InputError(f"{gid} {feat} measured twice (first on line {seen[key]})", path, n, "groove")
        seen[key] = n
        u, v, d = (number(r, c) for c in ("u_mm", "v_mm", "depth_mm"))
        sp, sd = number(r, "sigma_pos_mm", True), number(r, "sigma_depth_mm", True)
        sp = None if sp is None or np.isnan(sp) else sp
        sd = None if sd is None or np.isnan(sd) else sd
        if np.isnan(u) != np.isnan(v):
            raise InputError("give both u_mm and v_mm of a point, or neither", path, n,
                             "v_mm" if np.isnan(v) else "u_mm")
        if np.isnan(u) and np.isnan(d):
            continue  # row left empty: not measured
        pts.append(PointMeasurement(gid, feat, u, v, d, sp, sd, n))
    measured = {p.groove for p in pts}
    for g in plan.grooves:
        if g.id not in measured:
            rows = [str(seen[(g.id, f)]) for f in FEATURES if (g.id, f) in seen]
            shared = [f for f in FEATURES if (g.id, f) not in seen]
            where = f"its rows (line {', '.join(rows)}) are empty" if rows else "it has no row"
            raise InputError(f"missing groove {g.id} (test {g.test}): {where}; measure "
                             f"{' and '.join(shared if not rows else FEATURES)} point(s), or remove the groove "
                             "from the plan", path, int(rows[0]) if rows else None, "groove")
    return GroovingMeasurements(plan, tuple(pts), sigma_pos, sigma_depth, str(path))


# ---------------------------------------------------------------------------------------------
# The paper's experiment, virtually

#: Paper 000, Table 1: groove distances (du, dv) in µm against the A and C axes, cut with the
#: original and with the compensated NC data.
PAPER_ORIGINAL = {"A": (490.04, 680.12), "C": (108.97, 852.81)}
PAPER_COMPENSATED = {"A": (4.06, 2.97), "C": (0.74, 1.40)}


def paper_offset() -> tuple[float, float, float]:
    """The tool setting error (mm) of the virtual reproduction of paper 000's Table 1: |t_y| =
    du/2 and |t_x| = dv/2 of the A distances (490.04 and 680.12 µm), signs chosen as in
    `paper_truth`.  t_z, which Table 1 does not give: 0.2 mm (assumed)."""
    return (0.68012 / 2, 0.49004 / 2, 0.2)


#: What the virtual reproduction of paper 000's Table 1 takes from the paper and what it assumes.
PAPER_ASSUMPTIONS = (
    "from the paper: the four original distances of Table 1 (A: 490.04, 680.12 µm; C: 108.97, 852.81 µm), "
    "the test patterns as the text describes them (two grooves sharing a start point cut at A = 0, the same two "
    "after A is turned by 180 deg; a 'triangle shape' for C; B grooves at inclinations theta), a 90 deg V tool, "
    "1 nm / 0.00001 deg resolution",
    "mtcomp's reading, not the paper's text: the A grooves are cut on a side face with B = 90 deg (the text says "
    "'fed on X-Y plane', where A = 180 would turn the tool away from the surface); the triangle's sides are cut "
    "at C = 0, 120, 240 deg (the text says 'triangle shape' only); the B reference groove at B = 0 (the text "
    "lists A = theta_1, B = theta_2, B = theta_3)",
    "assumed: the A distances come from the tool offset against the A axis and the C distances from the offset "
    "against the C axis; the difference between the two is a C axis line off the A/B centre (EX0C, EY0C), solved so "
    "that all four distances are met exactly (the paper gives no signs: the smallest C offset of the four sign "
    "choices is taken); four values and four unknowns (t_x, t_y, EX0C, EY0C), so the match of the original "
    "distances is exact by construction and tests nothing",
    "assumed: t_z = 0.2 mm (Table 1 has no B result), EZ0A = 0, the groove lengths, layout and depth of cut of "
    "mtcomp's default plan, a laser confocal microscope with 1 µm (1 sigma) noise on positions and depths and no "
    "scale error, a perfectly rigid machine with no other geometric errors",
    "not modelled: the V tool's nose radius, tool wear, burrs at the groove crossings, thermal drift between "
    "the cuts; the microscope's magnification error is left out of this reproduction (a scale error s changes "
    "every distance by s times it; `estimate(..., fit_scale=True)` fits it per test)",
)


def paper_truth(machine="robonano-ui", plan: Plan | None = None):
    """The hidden errors (ErrorSet, mm) of the virtual reproduction of paper 000's Table 1: the tool
    offset `paper_offset()` and a C axis location error (EX0C, EY0C) solved so that the default
    plan's four original groove distances equal the Table's exactly (see PAPER_ASSUMPTIONS)."""
    from ..errors import ErrorSet, GeometricErrors, ToolSetting
    from ..machine import load_machine
    m = load_machine(machine)
    plan = plan or make_plan(m)
    t = ToolSetting(paper_offset())

    def gap(cx, cy):
        e = ErrorSet(tool=t, geometric=GeometricErrors(location={"EX0C": cx, "EY0C": cy}))
        return np.array(table1_signed(plan, cut_grooves(m, plan, e))["C"])

    g0 = gap(0.0, 0.0)
    G = np.stack([gap(1.0, 0.0) - g0, gap(0.0, 1.0) - g0], axis=1)   # exact: the gap is affine in (EX0C, EY0C)
    target = np.array(PAPER_ORIGINAL["C"]) * 1e-3
    best = min((np.linalg.solve(G, np.array(sg) * target - g0) for sg in ((1, 1), (1, -1), (-1, 1), (-1, -1))),
               key=np.linalg.norm)
    loc = {"EX0C": float(np.round(best[0], 9)), "EY0C": float(np.round(best[1], 9))}
    return ErrorSet(tool=t, geometric=GeometricErrors(location=loc))


def paper_experiment(machine="robonano-ui", offset=None, noise: MicroscopeNoise | None = None, seed=None,
                     plan: Plan | None = None, locations="auto"):
    """One virtual run of paper 000's experiment: cut with the true errors (default `paper_truth`;
    `offset` may be an ErrorSet, a ToolSetting or a (3,) offset), measure with noise, estimate the
    tool offset and the observable rotary-axis location errors, cut again with compensated
    programs.  Returns (estimate, original distances, compensated distances); distances as in
    `table1_distances` (mm).  `paper_reproduction` adds the fitted model's distances."""
    from ..machine import load_machine
    m = load_machine(machine)
    plan = plan or make_plan(m)
    truth = paper_truth(m, plan) if offset is None else _errorset(offset)
    meas = simulate_grooving(m, truth, noise, seed, plan=plan)
    est = estimate(m, meas, locations=locations)
    before = table1_distances(plan, cut_grooves(m, plan, truth))
    after = table1_distances(plan, cut_grooves(m, plan, truth, compensation=est.errors()))
    return est, before, after


@dataclass(frozen=True)
class PaperReproduction:
    """The virtual reproduction of paper 000's Table 1 (all distances mm).  truth: the hidden
    ErrorSet; estimate: the fit; original: distances cut with the truth; fitted: the same
    distances predicted by the fitted model alone; compensated: cut with the truth by programs
    compensated for the fit; tool_only: compensated for a fit of the tool offset alone (the
    method without location errors); assumptions: PAPER_ASSUMPTIONS."""
    truth: object
    estimate: object
    original: dict
    fitted: dict
    compensated: dict
    tool_only: dict
    assumptions: tuple = PAPER_ASSUMPTIONS

    def rows(self) -> list[tuple]:
        """(label, original µm, paper µm, fitted model µm, compensated µm, paper µm, tool offset
        only µm) per Table 1 distance."""
        out = []
        for ax in ("A", "C"):
            for j, c in enumerate(("dx", "dy")):
                out.append((f"against {ax}: {c}", self.original[ax][j] * 1e3, PAPER_ORIGINAL[ax][j],
                            self.fitted[ax][j] * 1e3, self.compensated[ax][j] * 1e3, PAPER_COMPENSATED[ax][j],
                            self.tool_only[ax][j] * 1e3))
        return out

    def summary(self) -> str:
        lines = ["Paper 000, Table 1, reproduced virtually (µm):",
                 f"  {'distance':<16}{'original':>10}{'paper':>10}{'fitted':>10}{'compens.':>10}{'paper':>8}"
                 f"{'t only':>10}"]
        for r in self.rows():
            lines.append(f"  {r[0]:<16}{r[1]:10.2f}{r[2]:10.2f}{r[3]:10.2f}{r[4]:10.2f}{r[5]:8.2f}{r[6]:10.2f}")
        lines.append("  (original: cut with the hidden errors; fitted: predicted by the fitted model; compens.: cut "
                     "with programs compensated for the fit; t only: compensated for the tool offset alone)")
        lines.append("Assumptions:")
        lines += [f"  - {a}" for a in self.assumptions]
        return "\n".join(lines)


def paper_reproduction(machine="robonano-ui", seed=0, noise: MicroscopeNoise | None = None,
                       plan: Plan | None = None) -> PaperReproduction:
    """Paper 000's Table 1 from one fitted model: cut with `paper_truth`, measure with 1 µm noise,
    fit tool offset and location errors, and report the four distances as cut, as the fitted
    model predicts them, and after compensation (with the fit, and with a tool-offset-only fit)."""
    from ..machine import load_machine
    m = load_machine(machine)
    plan = plan or make_plan(m)
    noise = noise or MicroscopeNoise(0.001, 0.001)
    truth = paper_truth(m, plan)
    meas = simulate_grooving(m, truth, noise, seed, plan=plan)
    est = estimate(m, meas)
    est0 = estimate(m, meas, locations=())
    return PaperReproduction(
        truth, est,
        table1_distances(plan, cut_grooves(m, plan, truth)),
        table1_distances(plan, cut_grooves(m, plan, est.errors())),
        table1_distances(plan, cut_grooves(m, plan, truth, compensation=est.errors())),
        table1_distances(plan, cut_grooves(m, plan, truth, compensation=est0.errors())))


from .tool_estimate import ToolSettingEstimate, estimate  # noqa: E402,F401  (public API)
