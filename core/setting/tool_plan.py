"""Grooving plan for measuring tool setting errors (paper 000): grooves, NC programs, layout, sheet.

A plan is a list of straight V-grooves, each cut with fixed rotary angles on a plate face.  Three
tests, one per rotary axis of a 6-axis machine whose tool side carries A, B and C (the
robonano-ui preset; docs/tool-setting.md explains the geometry and why it was chosen):

* C test, top face (normal +Z), A = B = 0: a triangle whose sides are cut at C = 0, 120, 240 deg,
  each side along the tool's own cutting direction.  The edge offset perpendicular to C moves
  every side by a different vector, so the triangle does not close.
* A test, side face (normal +X), B = 90 deg so the tool axis lies along X: two grooves sharing a
  start point at A = 0, the same two at A = 180.  The offset perpendicular to A is mirrored, so
  the two patterns lie 2x that offset apart.
* B test, top face, A = C = 0: grooves along Y cut with depth of cut D at inclinations
  B = theta_1..theta_n.  The offset in the XZ plane changes depth (second order in dZ) and
  lateral position (first order in dZ) with theta.

Face coordinates: a point on a face is origin + u*eu + v*ev - depth*normal (mm).  Angles in deg.
"""
from __future__ import annotations

import csv
import io
import os
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from .._io import InputError, MtcompError, atomic_write, dump_toml, load_toml
from .. import validate as _validate

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from matplotlib.figure import Figure

TESTS = ("A", "B", "C")
FEATURES = ("start", "end")


@dataclass(frozen=True)
class Face:
    """A plate face: origin (mm) and unit vectors eu, ev (in-plane) and normal (outward), all in
    the workpiece frame."""
    name: str
    origin: tuple[float, float, float]
    eu: tuple[float, float, float]
    ev: tuple[float, float, float]
    normal: tuple[float, float, float]

    def point(self, uv, depth) -> np.ndarray:
        """Workpiece-frame points (N,3) mm of face coordinates uv (N,2) at depth (N,) below the face."""
        uv = np.atleast_2d(np.asarray(uv, float))
        depth = np.broadcast_to(np.asarray(depth, float), (uv.shape[0],))
        return (np.asarray(self.origin) + uv[:, :1] * np.asarray(self.eu) + uv[:, 1:2] * np.asarray(self.ev)
                - depth[:, None] * np.asarray(self.normal))

    def coords(self, p) -> np.ndarray:
        """(u, v, depth) (N,3) mm of workpiece-frame points p (N,3)."""
        d = np.atleast_2d(np.asarray(p, float)) - np.asarray(self.origin)
        return np.stack([d @ np.asarray(self.eu), d @ np.asarray(self.ev), -(d @ np.asarray(self.normal))], axis=1)

    @property
    def basis(self) -> np.ndarray:
        """Rows eu, ev, -normal: maps a workpiece-frame displacement to (du, dv, ddepth)."""
        return np.array([self.eu, self.ev, [-x for x in self.normal]], float)


#: The default faces: the plate top (B and C tests) and a face normal to +X (A test, tool along X).
DEFAULT_FACES = {
    "top": Face("top", (0.0, 0.0, 0.0), (1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0)),
    "side": Face("side", (0.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0), (1.0, 0.0, 0.0)),
}


@dataclass(frozen=True)
class Groove:
    """One straight groove.  start/end: face coordinates (u, v) mm in cutting order; depth: the
    programmed depth of cut D (mm); angles: (A, B, C) deg held while cutting."""
    id: str
    test: str
    face: str
    angles: tuple[float, float, float]
    start: tuple[float, float]
    end: tuple[float, float]
    depth: float

    @property
    def direction(self) -> np.ndarray:
        d = np.subtract(self.end, self.start)
        return d / np.linalg.norm(d)

    def point(self, feature: str) -> tuple[float, float]:
        if feature == "start":
            return self.start
        if feature == "end":
            return self.end
        raise KeyError(feature)


@dataclass(frozen=True)
class PlanOptions:
    """Options of `make_plan`.  Lengths mm, angles deg, feeds mm/min.  The defaults fit a
    20 x 20 mm brass plate: the C triangle and the B grooves on its top face, the A pattern on
    a 20 x 20 mm face normal to X (a second plate, or the same one on an angle plate)."""
    tests: tuple[str, ...] = TESTS
    depth: float = 0.1              # depth of cut D
    length: float = 4.0             # A and B groove length
    triangle_side: float = 6.0      # C test
    spacing: float = 2.0            # between B grooves
    b_angles: tuple[float, ...] = (0.0, 10.0, -10.0)   # theta_1 .. theta_n; the first is the reference
    b_depths: tuple[float, ...] = ()   # programmed depth per B groove (default: depth for all), mm
    repeat_first: bool = False      # cut the plan's first groove again at the end (drift, ISO 230-3)
    repeat_shift: tuple[float, float] = (0.0, -6.6)   # where the repeat lies against the first, mm
    c_angles: tuple[float, ...] = (0.0, 120.0, 240.0)
    a_angles: tuple[float, ...] = (0.0, 180.0)
    a_tilt: float = 90.0            # B angle that lays the tool axis along X for the A test
    feed: float = 50.0
    plunge_feed: float = 5.0
    clearance: float = 0.5          # retract above the face between plunge and cut
    safe: float = 5.0               # retract before rotary moves
    tip_angle: float = 90.0         # included angle of the V tool
    plate: tuple[float, float] = (20.0, 20.0)
    c_centre: tuple[float, float] = (-4.5, 0.0)   # triangle centroid on the top face
    b_origin: tuple[float, float] = (3.0, -2.0)   # start of the first B groove on the top face
    a_origin: tuple[float, float] = (-3.0, -3.0)  # shared start point of the A grooves (side face)

    def __post_init__(self):
        for name in ("depth", "length", "triangle_side", "spacing", "feed", "plunge_feed", "clearance", "safe"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and np.isfinite(v) and v > 0):
                raise InputError(f"expected a positive number, got {v!r}", field=name)
        if not 0 < self.tip_angle < 180:
            raise InputError(f"tip angle must lie in (0, 180) deg, got {self.tip_angle!r}", field="tip_angle")
        bad = [t for t in self.tests if t not in TESTS]
        if bad or not self.tests:
            raise InputError(f"tests must be some of {', '.join(TESTS)}, got {self.tests!r}", field="tests")
        if "B" in self.tests and (len(self.b_angles) < 2 or len(set(self.b_angles)) != len(self.b_angles)):
            raise InputError("the B test needs at least two distinct inclinations", field="b_angles")
        if "C" in self.tests and len(set(a % 360 for a in self.c_angles)) != len(self.c_angles):
            raise InputError("C angles must be distinct", field="c_angles")
        if self.b_depths and (len(self.b_depths) != len(self.b_angles)
                              or not all(np.isfinite(d) and d > 0 for d in self.b_depths)):
            raise InputError("expected one positive depth per B inclination", field="b_depths")
        if self.safe < self.clearance:
            raise InputError("safe retract must be at least the clearance", field="safe")


@dataclass(frozen=True)
class Plan:
    """A grooving plan: machine name, options, faces and grooves."""
    machine: str
    options: PlanOptions
    grooves: tuple[Groove, ...]
    faces: dict = field(default_factory=lambda: dict(DEFAULT_FACES), compare=False)

    def groove(self, gid: str) -> Groove:
        for g in self.grooves:
            if g.id == gid:
                return g
        raise KeyError(gid)

    @property
    def ids(self) -> tuple[str, ...]:
        return tuple(g.id for g in self.grooves)

    def tests(self) -> tuple[str, ...]:
        return tuple(t for t in TESTS if any(g.test == t for g in self.grooves))

    def face_of(self, g: Groove) -> Face:
        return self.faces[g.face]

    def features(self) -> list[tuple[str, str]]:
        """(groove id, feature) pairs to measure.  A point that coincides with one already listed
        for the same test and the same rotary angles (the shared start of the A grooves) is the
        same physical point and is listed once."""
        out, seen = [], []
        for g in self.grooves:
            for f in FEATURES:
                key = (g.test, g.face, g.angles, tuple(np.round(g.point(f), 9)))
                if key in seen:
                    continue
                seen.append(key)
                out.append((g.id, f))
        return out


def _fmt_angle(a: float, signed: bool = False) -> str:
    return f"{a:+g}" if (signed and a) else f"{a:g}"


def make_plan(machine, options: PlanOptions | None = None) -> Plan:
    """Grooves of the calibration tests for a machine with A, B, C on the tool side (see module doc)."""
    from ..machine import load_machine
    m = load_machine(machine)
    o = options or PlanOptions()
    names = set(m.axis_names)
    need = {"X", "Y", "Z"} | set(o.tests)
    if "A" in o.tests:
        need.add("B")  # the A test lays the tool along X with B
    if not need <= names:
        raise MtcompError(f"machine {m.name!r} lacks axes {sorted(need - names)} needed for tests {o.tests}")
    for t in set(o.tests) | ({"B"} if "A" in o.tests else set()):
        if m.axis(t).side != "tool":
            raise MtcompError(f"the grooving tests need axis {t} on the tool side; on {m.name!r} it carries the "
                              "workpiece (use the workpiece-setting procedure for rotary tables)")
    D = o.depth
    grooves = []
    if "C" in o.tests:
        # Triangle: at C = c the cutting direction is the C = 0 direction (+Y, the B grooves' direction)
        # turned by c, so each side is cut with the same tool-relative direction.
        L = o.triangle_side
        dirs = [np.array([-np.sin(np.radians(c)), np.cos(np.radians(c))]) for c in o.c_angles]
        pts = [np.zeros(2)]
        for d in dirs:
            pts.append(pts[-1] + L * d)
        closed = np.allclose(pts[-1], pts[0], atol=1e-9)
        centre = np.mean(pts[:-1] if closed else pts, axis=0)
        shift = np.asarray(o.c_centre) - centre
        for k, c in enumerate(o.c_angles):
            grooves.append(Groove(f"C{_fmt_angle(c)}", "C", "top", (0.0, 0.0, float(c)),
                                  tuple(float(x) for x in np.round(pts[k] + shift, 9)),
                                  tuple(float(x) for x in np.round(pts[k + 1] + shift, 9)), D))
    if "A" in o.tests:
        s = np.asarray(o.a_origin, float)
        for a in o.a_angles:
            for j, d in enumerate(((1.0, 0.0), (0.0, 1.0)), 1):
                grooves.append(Groove(f"A{_fmt_angle(a)}-{j}", "A", "side", (float(a), float(o.a_tilt), 0.0),
                                      tuple(float(x) for x in s),
                                      tuple(float(x) for x in s + o.length * np.asarray(d)), D))
    if "B" in o.tests:
        u0, v0 = o.b_origin
        for k, b in enumerate(o.b_angles):
            u = u0 + k * o.spacing
            grooves.append(Groove(f"B{_fmt_angle(b, True)}", "B", "top", (0.0, float(b), 0.0),
                                  (float(u), float(v0)), (float(u), float(v0 + o.length)),
                                  float(o.b_depths[k]) if o.b_depths else D))
    if o.repeat_first and grooves:
        g0 = grooves[0]
        sh = np.asarray(o.repeat_shift, float)
        grooves.append(replace(g0, id=g0.id + "r", start=tuple(float(x) for x in np.round(np.add(g0.start, sh), 9)),
                               end=tuple(float(x) for x in np.round(np.add(g0.end, sh), 9))))
    ids = [g.id for g in grooves]
    if len(set(ids)) != len(ids):
        raise InputError("two grooves would get the same id (repeated angles)", field="angles")
    plan = Plan(m.name, o, tuple(grooves))
    _check_on_plate(plan)
    return plan


def cutting_times(plan: Plan) -> dict:
    """{groove id: tau}: when each groove is cut, as a fraction of the procedure (0 the first, 1 the
    last), taking the plan's order as the cutting order (the programs run test by test in it)."""
    n = len(plan.grooves)
    return {g.id: (k / (n - 1) if n > 1 else 0.0) for k, g in enumerate(plan.grooves)}


def repeated_grooves(plan: Plan) -> tuple:
    """Ids of grooves that repeat an earlier one (same test, face, angles, depth and cutting
    direction, another place): their difference shows the drift between the two cuts."""
    seen, out = [], []
    for g in plan.grooves:
        key = (g.test, g.face, g.angles, g.depth, tuple(np.round(g.direction, 9)))
        if key in seen:
            out.append(g.id)
        seen.append(key)
    return tuple(out)


def _check_on_plate(plan: Plan) -> None:
    w, h = plan.options.plate
    for g in plan.grooves:
        for f in FEATURES:
            u, v = g.point(f)
            if abs(u) > w / 2 or abs(v) > h / 2:
                raise InputError(f"groove {g.id} {f} point ({u:g}, {v:g}) mm lies outside the "
                                 f"{w:g} x {h:g} mm plate centred on the face origin", field="layout")


# ---------------------------------------------------------------------------------------------
# Programmed axis commands and NC programs

def commands_for_points(machine, points: np.ndarray, angles: np.ndarray) -> np.ndarray:
    """Axis commands (N, n_axes) that put the nominal tool point at workpiece-frame points (N,3) mm
    with rotary angles (N,3) (A, B, C) deg, on the ideal machine.

    The tool point is affine in the linear axes for fixed rotary angles, so three unit moves
    through the forward model give the exact map (no iteration)."""
    from ..kinematics import forward
    m = machine
    points = np.atleast_2d(np.asarray(points, float))
    angles = np.atleast_2d(np.asarray(angles, float))
    # Monte Carlo runs ask for the same programmed points thousands of times: memoise.
    key = (m, points.tobytes(), angles.tobytes(), points.shape)
    hit = _COMMAND_CACHE.get(key)
    if hit is not None:
        return hit.copy()
    n = points.shape[0]
    q = np.zeros((n, m.n_axes))
    for k, name in enumerate("ABC"):
        if name in m.axis_names:
            q[:, m.index(name)] = angles[:, k]
        elif np.any(angles[:, k] != 0):
            raise MtcompError(f"machine {m.name!r} has no {name} axis for angle {angles[:, k].max():g}")
    lin = [m.index(a) for a in "XYZ"]
    p0 = forward(m, q).p
    M = np.empty((n, 3, 3))
    for j, i in enumerate(lin):
        dq = q.copy()
        dq[:, i] += 1.0
        M[:, :, j] = forward(m, dq).p - p0
    x = np.linalg.solve(M, (points - p0)[..., None])[..., 0]
    q[:, lin] = x
    if len(_COMMAND_CACHE) > 256:
        _COMMAND_CACHE.clear()
    _COMMAND_CACHE[key] = q.copy()
    return q


_COMMAND_CACHE: dict = {}


@dataclass(frozen=True)
class Move:
    """One NC block: rapid (G00) or feed (G01) to commands q (n_axes,), with a comment."""
    rapid: bool
    q: tuple
    feed: float | None = None
    comment: str = ""
    groove: str = ""
    feature: str = ""


def program_moves(machine, plan: Plan, test: str) -> list[Move]:
    """Moves of one test's NC program: per groove, retract, orient, approach, plunge to the depth of
    cut at the start point, cut to the end point, retract."""
    from ..machine import load_machine
    m = load_machine(machine)
    o = plan.options
    moves: list[Move] = []
    for g in (g for g in plan.grooves if g.test == test):
        face = plan.face_of(g)
        uv = np.array([g.start, g.start, g.start, g.end, g.end, g.end])
        dep = np.array([-o.safe, -o.clearance, g.depth, g.depth, -o.clearance, -o.safe])
        pts = face.point(uv, dep)
        q = commands_for_points(m, pts, np.tile(g.angles, (6, 1)))
        moves += [
            Move(True, tuple(q[0]), None, f"groove {g.id}: orient A{g.angles[0]:g} B{g.angles[1]:g} "
                 f"C{g.angles[2]:g} above the start", g.id),
            Move(True, tuple(q[1]), None, "approach", g.id),
            Move(False, tuple(q[2]), o.plunge_feed, f"plunge to depth {g.depth:g} mm", g.id, "start"),
            Move(False, tuple(q[3]), o.feed, "cut", g.id, "end"),
            Move(False, tuple(q[4]), o.plunge_feed, "retract", g.id),
            Move(True, tuple(q[5]), None, "", g.id),
        ]
    return moves


def render_nc(machine, moves: list[Move], title: str) -> str:
    """G-code text (ISO 6983 words, mm and deg, absolute) of moves; every block states every axis."""
    from ..machine import load_machine
    m = load_machine(machine)
    lines = ["%", f"({title})", "(units mm, deg; tool edge programmed on the rotation centres)",
             "G21 G90 G94"]
    for mv in moves:
        words = ["G00" if mv.rapid else "G01"]
        for ax, val in zip(m.axes, mv.q):
            val = round(float(val), ax.decimals) + 0.0   # + 0.0: no "-0.00000" words
            words.append(f"{ax.name}{val:.{ax.decimals}f}")
        if not mv.rapid:
            words.append(f"F{mv.feed:g}")
        line = " ".join(words)
        if mv.comment:
            line += f" ({mv.comment})"
        lines.append(line)
    lines += ["M30", "%"]
    return "\n".join(lines) + "\n"


def nc_programs(machine, plan: Plan, compensation=None) -> dict[str, str]:
    """NC program text per test.  compensation: an ErrorSet; its programs are retargeted through
    `mtcomp.kinematics.retarget` so the real machine cuts the nominal grooves."""
    from ..kinematics import retarget
    from ..machine import load_machine
    m = load_machine(machine)
    out = {}
    for t in plan.tests():
        moves = program_moves(m, plan, t)
        title = f"mtcomp tool-setting grooving, test {t}, machine {m.name}"
        if compensation is not None:
            q = retarget(m, np.array([mv.q for mv in moves]), compensation, round_result=True)
            moves = [replace(mv, q=tuple(qq)) for mv, qq in zip(moves, q)]
            off = ", ".join(f"{x:.6f}" for x in compensation.tool.offset)
            title += f", compensated for tool setting offset ({off}) mm"
            loc = compensation.geometric.location
            if loc:
                title += " and " + ", ".join(f"{k} {v:.6f}" for k, v in loc.items()) + " mm"
        out[t] = render_nc(m, moves, title)
    return out


# ---------------------------------------------------------------------------------------------
# Plan file (TOML) and measurement sheet template (CSV)

SHEET_COLUMNS = ("groove", "feature", "test", "face", "a_deg", "b_deg", "c_deg",
                 "nominal_u_mm", "nominal_v_mm", "nominal_depth_mm", "u_mm", "v_mm", "depth_mm", "what")

_FACE_WORDS = {"top": "top face: u along +X, v along +Y", "side": "side face: u along +Y, v along +Z"}


def plan_to_toml(plan: Plan) -> str:
    o = plan.options
    data = {
        "plan": {"machine": plan.machine, "tests": list(o.tests), "depth_mm": o.depth,
                 "tip_angle_deg": o.tip_angle, "feed_mm_per_min": o.feed, "plunge_feed_mm_per_min": o.plunge_feed,
                 "clearance_mm": o.clearance, "safe_mm": o.safe, "plate_mm": list(o.plate)},
        "face": [{"name": f.name, "origin": list(f.origin), "eu": list(f.eu), "ev": list(f.ev),
                  "normal": list(f.normal)} for f in plan.faces.values()],
        "groove": [{"id": g.id, "test": g.test, "face": g.face, "angles_deg": list(g.angles),
                    "start_mm": list(g.start), "end_mm": list(g.end), "depth_mm": g.depth} for g in plan.grooves],
    }
    return ("# mtcomp tool-setting grooving plan (docs/tool-setting.md): face coordinates in mm, "
            "angles (A, B, C) in deg\n" + dump_toml(data))


def load_plan(path: str | os.PathLike) -> Plan:
    """Read a plan TOML written by `plan_to_toml` (or edited by hand: drop grooves you skip)."""
    path = Path(path)
    d = load_toml(path)
    head = d.get("plan")
    if not isinstance(head, dict) or "machine" not in head:
        raise InputError("missing [plan] table with a machine name", path, field="plan")
    if not isinstance(head["machine"], str) or not head["machine"].strip():
        raise InputError(f"expected a machine preset name or file, got {head['machine']!r}", path,
                         field="plan.machine")

    def num(x, fld, n=None):
        flat = x if isinstance(x, (list, tuple)) else [x]
        if any(isinstance(v, bool) or not isinstance(v, (int, float)) for v in flat):
            raise InputError(f"expected {'a list of ' + str(n) + ' numbers' if n else 'a number'}, got {x!r}",
                             path, field=fld)
        try:
            a = np.asarray(x, float)
        except OverflowError:   # an integer beyond float range (TOML integers are unbounded)
            a = np.full(np.shape(x), np.inf)
        if (n is not None and a.shape != (n,)) or (n is None and a.shape != ()) or not np.all(np.isfinite(a)) \
                or np.any(np.abs(a) > 1e6):
            raise InputError(f"expected {n or 1} finite number(s) of at most 1e6 (mm, deg), got {x!r}", path,
                             field=fld)
        return a

    def tables(key):
        v = d.get(key, [])
        if not isinstance(v, list) or not all(isinstance(x, dict) for x in v):
            raise InputError(f"expected [[{key}]] tables, got {type(v).__name__} {v!r:.40}", path, field=key)
        return v

    def text(g, k, fld):
        v = g[k]
        if not isinstance(v, str) or not v.strip():
            raise InputError(f"expected a non-empty string, got {v!r}", path, field=f"{fld}.{k}")
        return v

    faces = {}
    for i, f in enumerate(tables("face")):
        try:
            vecs = [num(f[k], f"face[{i}].{k}", 3) for k in ("origin", "eu", "ev", "normal")]
            name = text(f, "name", f"face[{i}]")
        except KeyError as exc:
            raise InputError(f"missing key {exc}", path, field=f"face[{i}]") from None
        frame = np.array(vecs[1:])
        if not np.allclose(frame @ frame.T, np.eye(3), atol=1e-6) or np.linalg.det(frame) < 0:
            raise InputError("eu, ev, normal must be orthonormal unit vectors (right-handed: normal = eu x ev)",
                             path, field=f"face[{i}]")
        faces[name] = Face(name, *[tuple(map(float, v)) for v in vecs])
    faces = faces or dict(DEFAULT_FACES)
    grooves = []
    for i, g in enumerate(tables("groove")):
        fld = f"groove[{i}]"
        try:
            gid, test, face = text(g, "id", fld), text(g, "test", fld), text(g, "face", fld)
            ang = num(g["angles_deg"], f"{fld}.angles_deg", 3)
            st, en = num(g["start_mm"], f"{fld}.start_mm", 2), num(g["end_mm"], f"{fld}.end_mm", 2)
            dep = float(num(g["depth_mm"], f"{fld}.depth_mm"))
        except KeyError as exc:
            raise InputError(f"missing key {exc}", path, field=fld) from None
        if not dep > 0:
            raise InputError(f"expected a positive depth of cut, mm, got {dep!r}", path, field=f"{fld}.depth_mm")
        if test not in TESTS:
            raise InputError(f"test must be one of {', '.join(TESTS)}, got {test!r}", path, field=f"{fld}.test")
        if face not in faces:
            raise InputError(f"unknown face {face!r}; faces: {', '.join(faces)}", path, field=f"{fld}.face")
        if np.allclose(st, en):
            raise InputError("start and end coincide", path, field=fld)
        if gid in [x.id for x in grooves]:
            raise InputError(f"groove id {gid!r} appears twice", path, field=f"{fld}.id")
        grooves.append(Groove(gid, test, face, tuple(map(float, ang)), tuple(map(float, st)),
                              tuple(map(float, en)), dep))
    if not grooves:
        raise InputError("the plan has no [[groove]] tables", path, field="groove")
    angles = {t: tuple(dict.fromkeys(g.angles[i] for g in grooves if g.test == t))
              for t, i in (("A", 0), ("B", 1), ("C", 2))}
    try:
        o = _options_from_head(head, grooves, angles)
    except InputError as exc:
        raise InputError(exc.what, path, field=exc.field) from None
    return Plan(str(head["machine"]), o, tuple(grooves), faces)


# [plan] keys of the file -> PlanOptions fields (with the defaults of a plan written by hand)
_HEAD_KEYS = {"depth_mm": ("depth", 0.1), "tip_angle_deg": ("tip_angle", 90.0),
              "feed_mm_per_min": ("feed", 50.0), "plunge_feed_mm_per_min": ("plunge_feed", 5.0),
              "clearance_mm": ("clearance", 0.5), "safe_mm": ("safe", 5.0)}


def _options_from_head(head: dict, grooves, angles) -> PlanOptions:
    kw = {}
    for key, (name, default) in _HEAD_KEYS.items():
        v = head.get(key, default)
        # validate.number: never a bool or a string, and a TOML integer beyond float range is
        # refused before float() could overflow
        kw[name] = _validate.number(v, None, f"plan.{key}")
    plate = head.get("plate_mm", [20.0, 20.0])
    if (not isinstance(plate, (list, tuple)) or len(plate) != 2
            or not all(isinstance(v, (int, float)) and not isinstance(v, bool)
                       and (not isinstance(v, int) or v <= _validate.MAX_MAGNITUDE) and v > 0 for v in plate)):
        raise InputError(f"expected two positive sizes [w, h] mm, got {_validate._describe(plate)}",
                         field="plan.plate_mm")
    try:
        return PlanOptions(tests=tuple(t for t in TESTS if any(g.test == t for g in grooves)),
                           plate=tuple(float(v) for v in plate), a_angles=angles["A"],
                           b_angles=angles["B"], c_angles=angles["C"], **kw)
    except InputError as exc:   # name the key of the file, not the option
        key = next((k for k, (n, _) in _HEAD_KEYS.items() if n == exc.field), None)
        # angles and tests come from the [[groove]] tables
        raise InputError(exc.what, field=f"plan.{key}" if key else "groove") from None


def sheet_template(plan: Plan) -> str:
    """The measurement sheet (CSV): one row per groove point to measure, measured cells empty."""
    buf = io.StringIO()
    buf.write("# mtcomp tool-setting measurement sheet (docs/tool-setting.md). Fill u_mm, v_mm, depth_mm:\n"
              "# the groove bottom (deepest line, the tool edge trace) at the named point, in the face frame\n"
              "# (any origin per test), and the depth below the plate surface. Leave a cell empty if not measured.\n")
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(SHEET_COLUMNS)
    for gid, feat in plan.features():
        g = plan.groove(gid)
        u, v = g.point(feat)
        what = (f"{feat} point of groove {gid} ({_FACE_WORDS.get(g.face, g.face)}); "
                f"bottom position u v and depth")
        w.writerow([gid, feat, g.test, g.face, f"{g.angles[0]:g}", f"{g.angles[1]:g}", f"{g.angles[2]:g}",
                    f"{u:.6f}", f"{v:.6f}", f"{g.depth:.6f}", "", "", "", what])
    return buf.getvalue()


def groove_width(depth, tip_angle: float, tilt: float = 0.0):
    """Width (mm) at the surface of a V-groove of depth (mm) cut by a tool of included angle
    tip_angle (deg) whose axis is tilted by `tilt` deg in the groove's cross-section plane:
    depth * (tan(tip/2 + tilt) + tan(tip/2 - tilt)); 2 * depth * tan(tip/2) untilted."""
    h, t = np.radians(tip_angle / 2.0), np.radians(tilt)
    return np.asarray(depth) * (np.tan(h + t) + np.tan(h - t))


def groove_top_centre_offset(depth, tip_angle: float, tilt: float = 0.0):
    """Offset (mm) of the midpoint between a V-groove's two top edges from its bottom line,
    depth * (tan(tip/2 + tilt) - tan(tip/2 - tilt)) / 2, towards d x n (d the cutting direction,
    n the face normal) for a positive tilt.  Zero for an untilted tool; 36 µm for D = 0.1 mm,
    tip 90 deg, tilt 10 deg: measure the bottom line on inclined grooves, or correct by this."""
    h, t = np.radians(tip_angle / 2.0), np.radians(tilt)
    return np.asarray(depth) * (np.tan(h + t) - np.tan(h - t)) / 2.0


def write_plan(machine, plan: Plan, outdir: str | os.PathLike, png: bool = True,
               clearance: float = 0.2, report=None) -> list[Path]:
    """Write plan.toml, one NC program per test (tool_setting_<T>.nc), measurements.csv and layout.png.

    The programs are verified on their plates first (`tool_verify.verify_grooving`, rapids
    `clearance` mm off): a violation raises VerifyError and nothing is written.  `report(results)`
    gets the {test: VerifyResult}."""
    from ..machine import load_machine
    from .tool_verify import verify_grooving
    outdir = Path(outdir)
    progs = nc_programs(machine, plan)
    results = verify_grooving(load_machine(machine), plan, progs, clearance=clearance)
    if report is not None:
        report(results)
    files = {"plan.toml": plan_to_toml(plan), "measurements.csv": sheet_template(plan)}
    files.update({f"tool_setting_{t}.nc": txt for t, txt in progs.items()})
    written = [atomic_write(outdir / name, txt) for name, txt in files.items()]
    if png:
        plot_layout(plan, outdir / "layout.png")
        written.append(outdir / "layout.png")
    return written


def plot_layout(plan: Plan, path=None, cuts=None, title: str | None = None) -> Figure:
    """Layout drawing (a Figure; PNG at `path` only when given): plate outline, nominal grooves with their ids and widths, and, if
    given, the predicted real grooves `cuts` (from `mtcomp.setting.tool.cut_grooves`)."""
    from matplotlib.figure import Figure
    from matplotlib.patches import Rectangle
    from .._io import save_figure
    faces = [f for f in plan.faces if any(g.face == f for g in plan.grooves)]
    fig = Figure(figsize=(6 * len(faces), 6))
    axs = fig.subplots(1, len(faces), squeeze=False)
    w, h = plan.options.plate
    colours = {"A": "tab:blue", "B": "tab:green", "C": "tab:red"}
    for ax, fname in zip(axs[0], faces):
        ax.add_patch(Rectangle((-w / 2, -h / 2), w, h, fill=False, lw=1.0, color="0.3"))
        labels: dict = {}
        for g in (g for g in plan.grooves if g.face == fname):
            labels.setdefault((g.start, g.end), []).append(g.id)
        for g in (g for g in plan.grooves if g.face == fname):
            lw_mm = float(groove_width(g.depth, plan.options.tip_angle))
            xs, ys = zip(g.start, g.end)
            ax.plot(xs, ys, color=colours[g.test], lw=max(1.0, lw_mm * 20), alpha=0.35 if cuts else 0.9,
                    solid_capstyle="butt")
            ax.annotate("", xy=g.end, xytext=g.start, arrowprops=dict(arrowstyle="->", color=colours[g.test], lw=0.8))
            mid = np.add(g.start, g.end) / 2
            off = 0.6 * np.array([-g.direction[1], g.direction[0]])
            ids = labels.pop((g.start, g.end), None)
            if ids:  # grooves cut along the same path (A = 0 and 180) share one label
                ax.text(*(mid + off), " / ".join(ids), fontsize=8, ha="center", va="center", color=colours[g.test])
        if cuts:
            for c in (c for c in cuts if c.groove.face == fname):
                ax.plot([c.start[0], c.end[0]], [c.start[1], c.end[1]], color="k", lw=0.8)
        ax.set_aspect("equal")
        ax.set_xlim(-w / 2 - 1, w / 2 + 1)
        ax.set_ylim(-h / 2 - 1, h / 2 + 1)
        ax.set_xlabel("u [mm]")
        ax.set_ylabel("v [mm]")
        ax.set_title(_FACE_WORDS.get(fname, fname), fontsize=9)
        ax.grid(alpha=0.3)
    fig.suptitle(title or f"tool-setting grooving plan, machine {plan.machine} "
                 f"(D = {plan.options.depth:g} mm, tip {plan.options.tip_angle:g} deg)", fontsize=10)
    fig.tight_layout()
    if path is not None:
        save_figure(fig, path, dpi=110)
    return fig
