"""Reference bowls for workpiece setting (paper 001): plan, NC programs, probe touches, sphere fit.

A bowl is a spherical cavity plunged with a ball end mill of radius R into the blank's top face.
The workpiece frame of the design has its origin at the centre of the top face, z up, so a bowl of
depth h at (x, y) is the sphere of radius R centred at (x, y, R - h), cut below z = 0.

Touch probing: a probe ball of radius r inside the bowl touches its wall when the probe centre lies
on the concentric sphere of radius R - r.  The controller records the probe centre at trigger, so
that sphere is what we fit; the bowl radius is its radius plus r.  Sphere *centres* are used as the
material reference points: the lowest point of a bowl is not fixed in the material, it moves along
the wall by about R * alpha when the blank tilts by alpha (see docs/workpiece-setting.md).

Units: mm and deg at every interface.
"""
from __future__ import annotations

import csv
import io
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .._io import InputError, MtcompError

__all__ = [
    "Bowl", "BowlPlan", "plan_bowls", "roughing_program", "probing_program", "plan_to_dict",
    "plan_from_dict", "save_plan", "load_plan", "Touches", "read_touches", "write_touches",
    "touches_to_csv", "virtual_probe", "SphereFit", "BowlFit", "fit_sphere", "fit_bowls",
]


# --------------------------------------------------------------------------------------------
# Plan
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Bowl:
    """One bowl: integer id and the design position (x, y) of its axis on the top face, mm."""
    id: int
    x: float
    y: float


@dataclass(frozen=True)
class BowlPlan:
    """Everything needed to mill and to probe the reference bowls of one blank.

    blank: (lx, ly, lz) mm, top face at z = 0, centred on x = y = 0.
    tool_radius: ball end mill radius R (= nominal bowl radius), mm.  depth: bowl depth h, mm.
    probe_radius: probe tip radius r, mm.  directions: (m, 3) unit vectors from the sphere centre
    to the contact points; the probe approaches along them.  clearance: probe start distance from
    the wall, overtravel: how far past the nominal wall the probing move is programmed, mm.
    safe_z: rapid height above the top face, mm.  keepout_radius: radius around the part centre
    kept free of bowls (the finished part lives there), mm.
    """
    bowls: tuple[Bowl, ...]
    blank: tuple[float, float, float] = (20.0, 20.0, 5.0)
    tool_radius: float = 2.0
    depth: float = 1.0
    probe_radius: float = 0.5
    directions: tuple[tuple[float, float, float], ...] = ()
    clearance: float = 0.2
    overtravel: float = 0.1
    safe_z: float = 5.0
    keepout_radius: float = 3.0
    spindle_speed: float = 8000.0
    plunge_feed: float = 100.0
    probe_feed: float = 50.0

    @property
    def ids(self) -> tuple[int, ...]:
        return tuple(b.id for b in self.bowls)

    @property
    def centres(self) -> np.ndarray:
        """(n, 3) design sphere centres, mm."""
        zc = self.tool_radius - self.depth
        return np.array([[b.x, b.y, zc] for b in self.bowls], float)

    def centre_of(self, bowl_id: int) -> np.ndarray:
        for b, c in zip(self.bowls, self.centres):
            if b.id == bowl_id:
                return c
        raise InputError(f"bowl {bowl_id} is not in the plan (plan has bowls {list(self.ids)})",
                         field="bowl")

    @property
    def dirs(self) -> np.ndarray:
        """(m, 3) unit contact directions (sphere centre -> contact point)."""
        return np.array(self.directions, float).reshape(-1, 3)

    @property
    def probe_sphere_radius(self) -> float:
        """Radius of the sphere the probe centre lies on at trigger: R - r, mm."""
        return self.tool_radius - self.probe_radius

    @property
    def opening_radius(self) -> float:
        """Radius of the bowl's rim on the top face, mm."""
        R, h = self.tool_radius, self.depth
        return math.sqrt(max(R * R - (R - h) ** 2, 0.0))

    @property
    def rim_polar_angle(self) -> float:
        """Polar angle (from -z) of the rim seen from the sphere centre, deg."""
        return math.degrees(math.acos((self.tool_radius - self.depth) / self.tool_radius))


def _default_positions(n: int, blank, edge_distance: float) -> list[tuple[float, float]]:
    # Corners first (S1 origin, S2 along +x, S3 along +y as in paper 001's Fig. 4), then edge
    # midpoints: as far apart as the blank allows, which minimises the angular uncertainty.
    ax = blank[0] / 2 - edge_distance
    ay = blank[1] / 2 - edge_distance
    spots = [(-ax, -ay), (ax, -ay), (-ax, ay), (ax, ay), (0.0, -ay), (0.0, ay), (-ax, 0.0), (ax, 0.0)]
    if n > len(spots):
        raise InputError(f"at most {len(spots)} bowls can be placed automatically, got {n}; "
                         "give explicit positions", field="n")
    return spots[:n]


def default_directions(m: int, rim_polar: float, margin: float = 12.0) -> np.ndarray:
    """m contact directions: one at the bottom plus two rings (outer ring `margin` deg below the rim)."""
    if m < 1:
        raise InputError(f"touches per bowl must be >= 1, got {m}", field="touches")
    outer = rim_polar - margin
    if outer <= 5.0:
        raise InputError(f"bowl too shallow to probe: rim at {rim_polar:.1f} deg from the bottom, "
                         f"need more than {margin + 5:.0f} deg", field="depth")
    dirs = [(0.0, 0.0, -1.0)]
    rest = m - 1
    n1, n2 = rest // 2, rest - rest // 2
    for count, polar, phase in ((n1, outer / 2, 0.0), (n2, outer, 0.5)):
        for k in range(count):
            az = 2 * math.pi * (k + phase) / count
            th = math.radians(polar)
            dirs.append((math.sin(th) * math.cos(az), math.sin(th) * math.sin(az), -math.cos(th)))
    return np.array(dirs, float)


def plan_bowls(n: int = 3, *, blank=(20.0, 20.0, 5.0), tool_radius: float = 2.0,
               depth: float = 1.0, probe_radius: float = 0.5, touches: int = 9,
               positions=None, edge_distance: float = 3.0, margin: float = 0.5,
               keepout_radius: float = 3.0,
               clearance: float = 0.2, overtravel: float = 0.1, safe_z: float = 5.0) -> BowlPlan:
    """Plan n >= 3 bowls on a blank and the probing touches; all lengths in mm.

    `positions` ((n, 2) mm) overrides the automatic placement (corners, then edge midpoints, axes
    `edge_distance` from the blank's edges: (+-7, +-7) on the default 20 mm blank, as the CAD
    model's bowl blank).  Rims must stay `margin` from the edges, the part region and each other.
    Raises InputError when the geometry cannot work: too few bowls, bowls off the blank or
    overlapping or collinear, the probe as large as the bowl, a bowl deeper than a hemisphere
    (its walls would be the cutter's cylinder).
    """
    blank = tuple(float(v) for v in blank)
    if len(blank) != 3 or min(blank) <= 0:
        raise InputError(f"blank must be three positive sizes (lx, ly, lz) mm, got {blank}", field="blank")
    if tool_radius <= 0:
        raise InputError(f"tool radius must be > 0 mm, got {tool_radius}", field="tool_radius")
    if not 0 < depth <= tool_radius:
        raise InputError(f"depth must be in (0, tool radius = {tool_radius}] mm, got {depth}: a ball "
                         "end mill plunged deeper cuts a cylinder, not a sphere", field="depth")
    if depth >= blank[2]:
        raise InputError(f"depth {depth} mm is not less than the blank thickness {blank[2]} mm",
                         field="depth")
    if not 0 < probe_radius < 0.8 * tool_radius:
        raise InputError(f"probe radius must be in (0, 0.8 x tool radius = {0.8 * tool_radius:g}) mm, "
                         f"got {probe_radius} (paper 001: the bowl must be much larger than the probe)",
                         field="probe_radius")
    opening = math.sqrt(tool_radius ** 2 - (tool_radius - depth) ** 2)
    if positions is None:
        if n < 3:
            raise InputError(f"at least 3 bowls are needed to define a frame, got {n}", field="n")
        positions = _default_positions(n, blank, edge_distance)
    positions = np.asarray(positions, float).reshape(-1, 2)
    if len(positions) < 3:
        raise InputError(f"at least 3 bowls are needed to define a frame, got {len(positions)}",
                         field="positions")
    bowls = tuple(Bowl(i + 1, float(x), float(y)) for i, (x, y) in enumerate(positions))
    for b in bowls:
        if abs(b.x) + opening + margin > blank[0] / 2 or abs(b.y) + opening + margin > blank[1] / 2:
            raise InputError(f"bowl {b.id} at ({b.x:g}, {b.y:g}) with rim radius {opening:.3f} mm "
                             f"runs off the {blank[0]:g} x {blank[1]:g} mm blank", field="positions")
        if math.hypot(b.x, b.y) - opening - margin < keepout_radius:
            raise InputError(f"bowl {b.id} at ({b.x:g}, {b.y:g}) cuts into the part region "
                             f"(keep-out radius {keepout_radius:g} mm)", field="positions")
    for i, a in enumerate(bowls):
        for b in bowls[i + 1:]:
            if math.hypot(a.x - b.x, a.y - b.y) < 2 * opening + margin:
                raise InputError(f"bowls {a.id} and {b.id} overlap or nearly touch "
                                 f"(centres {math.hypot(a.x - b.x, a.y - b.y):.3f} mm apart, need "
                                 f"{2 * opening + margin:.3f})", field="positions")
    rim = math.degrees(math.acos((tool_radius - depth) / tool_radius))
    dirs = default_directions(touches, rim)
    plan = BowlPlan(bowls=bowls, blank=blank, tool_radius=float(tool_radius), depth=float(depth),
                    probe_radius=float(probe_radius),
                    directions=tuple(tuple(float(v) for v in d) for d in dirs),
                    clearance=float(clearance), overtravel=float(overtravel), safe_z=float(safe_z),
                    keepout_radius=float(keepout_radius))
    from .frame import check_bowl_geometry
    check_bowl_geometry(plan.centres, plan.ids, what="planned")
    return plan


# --------------------------------------------------------------------------------------------
# NC programs (ISO 6983 / Fanuc dialect, mm, absolute)
# --------------------------------------------------------------------------------------------
def _fmt(v: float, digits: int = 4) -> str:
    s = f"{v:.{digits}f}".rstrip("0").rstrip(".")
    return "0" if s in ("-0", "") else s


_f = _fmt


def _ax(v: float, digits: int = 4) -> str:
    """An axis word's number, always with a decimal point: a control set to read numbers without
    one in least input increments would take `X7` as 7 um (docs/gcode.md)."""
    s = _fmt(v, digits)
    return s if "." in s else s + "."


def roughing_program(plan: BowlPlan, peck: float = 0.5) -> str:
    """3-axis program for the ordinary machining centre that plunges every bowl with the ball end mill.

    Programmed point: the ball end mill's tip (tool length measured to the tip), so the tip goes to
    z = -depth.  Plunging in pecks of `peck` mm with a full retract clears chips.
    """
    R, h = plan.tool_radius, plan.depth
    out = ["%", "O0001 (MTCOMP BOWLS ROUGHING)",
           f"(BALL END MILL R{_f(R)}, {len(plan.bowls)} BOWLS, DEPTH {_f(h)} MM, TIP PROGRAMMED)",
           "G21 G90 G17 G40 G49 G80", "G54", f"S{_f(plan.spindle_speed)} M03",
           f"G00 Z{_ax(plan.safe_z)}"]
    for b in plan.bowls:
        out.append(f"(BOWL {b.id})")
        out.append(f"G00 X{_ax(b.x)} Y{_ax(b.y)}")
        out.append("G00 Z0.5")
        z = 0.0
        while z > -h + 1e-9:
            z = max(z - peck, -h)
            out.append(f"G01 Z{_ax(z)} F{_f(plan.plunge_feed)}")
            if z > -h + 1e-9:
                out.append("G00 Z0.5")
                out.append(f"G00 Z{_ax(z + 0.05)}")
        out.append("G04 P500")
        out.append(f"G00 Z{_ax(plan.safe_z)}")
    out += ["M05", "M30", "%"]
    return "\n".join(out) + "\n"


def _move_arrays(plan: BowlPlan, aim=None):
    """Probing moves as arrays: bowl ids (K,), touch numbers (K,), start (K,3), end (K,3), approach (K,3)."""
    R, t = _aim_rt(aim)
    rho = plan.probe_sphere_radius
    cm = plan.centres @ R.T + t                     # (n, 3) aimed sphere centres
    dm = plan.dirs @ R.T                            # (m, 3) aimed directions
    n, m = len(cm), len(dm)
    C = np.repeat(cm, m, axis=0)
    D = np.tile(dm, (n, 1))
    ids = np.repeat(np.array(plan.ids, int), m)
    num = np.tile(np.arange(1, m + 1), n)
    return ids, num, C + (rho - plan.clearance) * D, C + (rho + plan.overtravel) * D, D


def touch_moves(plan: BowlPlan, aim=None) -> list[tuple[int, int, np.ndarray, np.ndarray, np.ndarray]]:
    """Probing moves: (bowl id, touch number, start point, end point, unit approach) in the machine frame.

    Probe-centre positions, mm.  The start point lies `clearance` inside the probe-centre sphere,
    the end point `overtravel` beyond it, both on the radial line through the sphere centre, so the
    probe ball never meets the rim (it stays inside the bowl's sphere).  `aim`, a WorkpieceSetting,
    places the moves on a blank already located coarsely (two-pass probing); None = nominal.
    """
    return [(int(i), int(j), s, e, d) for i, j, s, e, d in zip(*_move_arrays(plan, aim))]


def _aim_rt(aim):
    if aim is None:
        return np.eye(3), np.zeros(3)
    from .frame import pose_matrix
    return pose_matrix(aim)


def probing_program(plan: BowlPlan, aim=None) -> str:
    """Probing program for the ultraprecision machine (rotary axes at 0), probe-centre positions.

    For each bowl: rapid to safe height over the sphere centre, feed down to the sphere centre
    (in air or inside the bowl, h <= R), then for each touch a feed to the start point, a skip move
    (G31) along the approach direction, and a feed back to the sphere centre.  The controller logs
    the probe centre at trigger; together with bowl id and approach that is the touches CSV.
    """
    R, t = _aim_rt(aim)

    def _f(v, digits=6):  # nanometre resolution on the ultraprecision machine
        return _fmt(v, digits)

    def _a(v):
        return _ax(v, 6)
    out = ["%", "O0002 (MTCOMP BOWLS PROBING)",
           f"(PROBE TIP R{_f(plan.probe_radius)}, PROBE-CENTRE POSITIONS, {len(plan.dirs)} TOUCHES PER BOWL)",
           "G21 G90 G17 G40 G80", "G54"]
    moves = touch_moves(plan, aim)
    by_bowl: dict[int, list] = {}
    for mv in moves:
        by_bowl.setdefault(mv[0], []).append(mv)
    for b, c in zip(plan.bowls, plan.centres):
        cm = R @ c + t
        out.append(f"(BOWL {b.id})")
        out.append(f"G00 X{_a(cm[0])} Y{_a(cm[1])} Z{_a(plan.safe_z)}")
        out.append(f"G01 Z{_a(cm[2])} F{_f(plan.probe_feed * 4)}")
        for _, j, s, e, d in by_bowl[b.id]:
            out.append(f"(TOUCH {b.id}.{j} APPROACH {d[0]:.6f} {d[1]:.6f} {d[2]:.6f})")
            out.append(f"G01 X{_a(s[0])} Y{_a(s[1])} Z{_a(s[2])} F{_f(plan.probe_feed * 4)}")
            out.append(f"G31 X{_a(e[0])} Y{_a(e[1])} Z{_a(e[2])} F{_f(plan.probe_feed)}")
            out.append(f"G01 X{_a(cm[0])} Y{_a(cm[1])} Z{_a(cm[2])} F{_f(plan.probe_feed * 4)}")
        out.append(f"G00 Z{_a(plan.safe_z)}")
    out += ["M30", "%"]
    return "\n".join(out) + "\n"


# --------------------------------------------------------------------------------------------
# Plan file (TOML)
# --------------------------------------------------------------------------------------------
def plan_to_dict(plan: BowlPlan) -> dict:
    return {
        "format": "mtcomp-bowl-plan-1",
        "blank": list(plan.blank), "tool_radius": plan.tool_radius, "depth": plan.depth,
        "probe_radius": plan.probe_radius, "clearance": plan.clearance,
        "overtravel": plan.overtravel, "safe_z": plan.safe_z, "keepout_radius": plan.keepout_radius,
        "spindle_speed": plan.spindle_speed, "plunge_feed": plan.plunge_feed,
        "probe_feed": plan.probe_feed,
        "bowls": [{"id": b.id, "x": b.x, "y": b.y} for b in plan.bowls],
        "directions": [list(d) for d in plan.directions],
    }


def plan_from_dict(d: dict, file=None) -> BowlPlan:
    def num(key, default=None):
        v = d.get(key, default)
        if v is None:
            raise InputError("missing", file, field=key)
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            raise InputError(f"expected a number (mm), got {v!r}", file, field=key)
        return float(v)
    try:
        raw = d["bowls"]
    except KeyError:
        raise InputError("missing list of [[bowls]] (id, x, y)", file, field="bowls") from None
    bowls = []
    for k, b in enumerate(raw):
        try:
            bowls.append(Bowl(int(b["id"]), float(b["x"]), float(b["y"])))
        except (KeyError, TypeError, ValueError):
            raise InputError("each bowl needs integer id and numbers x, y (mm)", file,
                             field=f"bowls[{k}]") from None
    ids = [b.id for b in bowls]
    if len(set(ids)) != len(ids):
        raise InputError(f"bowl ids must be unique, got {ids}", file, field="bowls")
    dirs = np.asarray(d.get("directions", []), float).reshape(-1, 3) if d.get("directions") else None
    if dirs is None or len(dirs) == 0:
        raise InputError("missing list of contact directions [[x, y, z], ...]", file, field="directions")
    norms = np.linalg.norm(dirs, axis=1)
    if np.any(np.abs(norms - 1) > 1e-6):
        raise InputError("every direction must be a unit vector", file, field="directions")
    blank = d.get("blank", [20.0, 20.0, 5.0])
    if (not isinstance(blank, list) or len(blank) != 3
            or not all(isinstance(v, (int, float)) and not isinstance(v, bool) and v > 0 for v in blank)):
        raise InputError(f"expected three positive sizes [lx, ly, lz] mm, got {blank!r}", file, field="blank")
    plan = BowlPlan(bowls=tuple(bowls), blank=tuple(float(v) for v in blank),
                    tool_radius=num("tool_radius"), depth=num("depth"),
                    probe_radius=num("probe_radius"),
                    directions=tuple(tuple(float(v) for v in r) for r in dirs),
                    clearance=num("clearance", 0.2), overtravel=num("overtravel", 0.1),
                    safe_z=num("safe_z", 5.0), keepout_radius=num("keepout_radius", 3.0),
                    spindle_speed=num("spindle_speed", 8000.0), plunge_feed=num("plunge_feed", 100.0),
                    probe_feed=num("probe_feed", 50.0))
    if plan.tool_radius <= 0:
        raise InputError(f"tool radius must be > 0 mm, got {plan.tool_radius:g}", file, field="tool_radius")
    if not 0 < plan.depth <= plan.tool_radius:
        raise InputError(f"depth must be in (0, tool radius = {plan.tool_radius:g}] mm, got {plan.depth:g}",
                         file, field="depth")
    if not 0 < plan.probe_radius < plan.tool_radius:
        raise InputError(f"probe radius {plan.probe_radius} must be in (0, tool radius "
                         f"{plan.tool_radius}) mm", file, field="probe_radius")
    return plan


def save_plan(plan: BowlPlan, path) -> Path:
    from .._io import atomic_write, dump_toml
    return atomic_write(path, dump_toml(plan_to_dict(plan)))


def load_plan(path) -> BowlPlan:
    from .._io import load_toml
    return plan_from_dict(load_toml(path), file=path)


# --------------------------------------------------------------------------------------------
# Touches
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Touches:
    """Probe touches: bowl id (m,), probe centre at trigger (m, 3) mm, unit approach (m, 3).

    `lines` (m,) are the source line numbers (CSV) so errors can point at them (0 = synthetic).
    """
    bowl: np.ndarray
    points: np.ndarray
    approach: np.ndarray
    lines: np.ndarray = field(default=None)
    source: str | None = None

    def __post_init__(self):
        if self.lines is None:
            object.__setattr__(self, "lines", np.zeros(len(self.bowl), int))

    def of(self, bowl_id: int) -> np.ndarray:
        return np.flatnonzero(self.bowl == bowl_id)


TOUCH_COLUMNS = ("bowl", "x", "y", "z", "ax", "ay", "az")


def touches_to_csv(t: Touches) -> str:
    buf = io.StringIO()
    buf.write("# probe touches: bowl id, probe centre at trigger x y z (mm), unit approach ax ay az\n")
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(TOUCH_COLUMNS)
    for b, p, a in zip(t.bowl, t.points, t.approach):
        w.writerow([int(b)] + [f"{v:.9f}" for v in p] + [f"{v:.9f}" for v in a])
    return buf.getvalue()


def write_touches(t: Touches, path) -> Path:
    from .._io import atomic_write
    return atomic_write(path, touches_to_csv(t))


def read_touches(path) -> Touches:
    """Read a touches CSV (columns bowl,x,y,z,ax,ay,az; '#' comments); errors name file and line."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8", errors="replace")  # bad bytes fail as cells
    except FileNotFoundError:
        raise InputError("file not found", path) from None
    rows, header = [], None
    for lineno, line in enumerate(text.splitlines(), 1):
        s = line.strip()
        if not s or s.startswith("#"):
            continue
        cells = [c.strip() for c in next(csv.reader([s]))]
        if header is None:
            header = [c.lower() for c in cells]
            missing = [c for c in TOUCH_COLUMNS if c not in header]
            if missing:
                raise InputError(f"header must contain columns {','.join(TOUCH_COLUMNS)}; missing "
                                 f"{','.join(missing)}", path, lineno)
            continue
        if len(cells) != len(header):
            raise InputError(f"expected {len(header)} values, got {len(cells)}", path, lineno)
        rec = dict(zip(header, cells))
        try:
            bid = int(rec["bowl"])
        except ValueError:
            raise InputError(f"bowl id must be an integer, got {rec['bowl']!r}", path, lineno,
                             "bowl") from None
        vals = []
        for c in TOUCH_COLUMNS[1:]:
            try:
                v = float(rec[c])
            except ValueError:
                raise InputError(f"expected a number, got {rec[c]!r}", path, lineno, c) from None
            if not math.isfinite(v):
                raise InputError(f"expected a finite number, got {rec[c]!r}", path, lineno, c)
            vals.append(v)
        a = np.array(vals[3:])
        na = np.linalg.norm(a)
        if na < 1e-9:
            raise InputError("approach vector is zero", path, lineno, "ax")
        rows.append((bid, vals[:3], a / na, lineno))
    if not rows:
        raise InputError("no touches in file", path)
    return Touches(bowl=np.array([r[0] for r in rows], int),
                   points=np.array([r[1] for r in rows], float),
                   approach=np.array([r[2] for r in rows], float),
                   lines=np.array([r[3] for r in rows], int), source=str(path))


def virtual_probe(true_pose, plan: BowlPlan, noise_sigma: float = 0.0, rng=None, *,
                  aim=None, bowl_radius_error: float = 0.0) -> Touches:
    """Simulate the probing program on a blank whose real frame sits at `true_pose` (a WorkpieceSetting).

    Each probing move (start, unit approach, from `touch_moves(plan, aim)`) stops where the probe
    centre reaches the real bowl's probe-centre sphere (radius R + bowl_radius_error - r); the
    recorded point is that trigger point plus Gaussian noise of `noise_sigma` mm along the approach
    (pretravel scatter).  Raises MtcompError naming the bowl when a move would miss the bowl wall
    (blank too far from `aim`: probe once coarsely, then again with `aim` = the coarse result).
    """
    if not noise_sigma >= 0:
        raise InputError(f"probe noise must be >= 0 mm, got {noise_sigma}", field="noise")
    rng = np.random.default_rng(rng)
    from .frame import pose_matrix
    Rt, tt = pose_matrix(true_pose) if true_pose is not None else (np.eye(3), np.zeros(3))
    rho = plan.probe_sphere_radius + bowl_radius_error
    ids, num, S, _E, D = _move_arrays(plan, aim)
    Cr = (plan.centres @ Rt.T + tt)[np.repeat(np.arange(len(plan.bowls)), len(plan.dirs))]
    W = S - Cr
    # |w + lam d| = rho with lam > 0: the start point must be inside the sphere
    bq = np.einsum("ij,ij->i", W, D)
    cq = np.einsum("ij,ij->i", W, W) - rho * rho
    out = np.flatnonzero(cq >= 0)
    if out.size:
        k = int(out[0])
        raise MtcompError(f"bowl {ids[k]}: touch {num[k]} starts outside the bowl "
                          f"({math.sqrt(W[k] @ W[k]):.3f} mm from its centre, sphere radius "
                          f"{rho:.3f}); locate the blank coarsely first (aim)")
    lam = -bq + np.sqrt(bq * bq - cq)
    P = S + lam[:, None] * D
    # the contact point on the bowl wall must lie below the real top face (inside the cavity)
    contact = Cr + (P - Cr) * ((rho + plan.probe_radius) / rho)
    above = np.flatnonzero((contact - tt) @ Rt[:, 2] > -1e-3)
    if above.size:
        k = int(above[0])
        raise MtcompError(f"bowl {ids[k]}: touch {num[k]} would hit the rim or the top face, not "
                          "the bowl wall; locate the blank coarsely first (aim)")
    if noise_sigma > 0:
        P = P + rng.normal(0.0, noise_sigma, len(P))[:, None] * D
    return Touches(bowl=ids, points=P, approach=D)


# --------------------------------------------------------------------------------------------
# Sphere fit
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class SphereFit:
    """Fit of one bowl.  centre (3,) mm; radius: bowl radius (probe-centre sphere + probe), mm;
    cov: covariance of (cx, cy, cz, rho) mm^2 (rho = probe-centre sphere radius; 3x3 when the
    radius was fixed, padded with zeros); residuals (m,) radial distances of all touches from the
    fitted sphere, mm (rejected ones included); used (m,) bool; rejected: source lines/indices of
    rejected touches; sigma: probe noise used for cov, mm; lines: source lines of the touches."""
    bowl: int
    centre: np.ndarray
    radius: float
    cov: np.ndarray
    residuals: np.ndarray
    used: np.ndarray
    sigma: float
    lines: np.ndarray
    fixed_radius: bool = False

    @property
    def centre_cov(self) -> np.ndarray:
        return self.cov[:3, :3]

    @property
    def rms(self) -> float:
        r = self.residuals[self.used]
        return float(np.sqrt(np.mean(r * r)))

    @property
    def rejected(self) -> tuple[int, ...]:
        return tuple(int(i) for i in np.flatnonzero(~self.used))


@dataclass(frozen=True)
class BowlFit:
    """Sphere fits of all bowls; `warnings` lists rejected touches and other notes for the user.

    shared_cov: (3n, 3n) covariance of all centres when one radius was fitted for all bowls."""
    fits: tuple[SphereFit, ...]
    probe_radius: float
    sigma: float
    sigma_known: bool
    warnings: tuple[str, ...] = ()
    shared_cov: np.ndarray | None = None

    @property
    def ids(self) -> tuple[int, ...]:
        return tuple(f.bowl for f in self.fits)

    @property
    def shared_radius(self) -> bool:
        return self.shared_cov is not None

    @property
    def centre_cov_full(self) -> np.ndarray:
        """(3n, 3n) covariance of all centres, mm^2 (block diagonal unless the radius is shared)."""
        if self.shared_cov is not None:
            return self.shared_cov
        n = len(self.fits)
        out = np.zeros((3 * n, 3 * n))
        for i, f in enumerate(self.fits):
            out[3 * i:3 * i + 3, 3 * i:3 * i + 3] = f.centre_cov
        return out

    @property
    def centres(self) -> np.ndarray:
        return np.array([f.centre for f in self.fits])

    @property
    def centre_covs(self) -> np.ndarray:
        return np.array([f.centre_cov for f in self.fits])

    def summary(self) -> str:
        src = "given" if self.sigma_known else "pooled from residuals"
        shared = ", one radius for all bowls" if self.shared_radius else ""
        lines = [f"bowl sphere fits (probe radius {self.probe_radius:g} mm, probe noise "
                 f"{self.sigma * 1e3:.3f} um {src}{shared})",
                 " bowl        cx mm        cy mm        cz mm    radius mm  s(c) um  rms um  touches"]
        for f in self.fits:
            sd = np.sqrt(np.clip(np.diag(f.centre_cov), 0, None)) * 1e3
            lines.append(f" {f.bowl:4d} {f.centre[0]:12.6f} {f.centre[1]:12.6f} {f.centre[2]:12.6f} "
                         f"{f.radius:12.6f} {sd.max():8.3f} {f.rms * 1e3:7.3f}  "
                         f"{int(f.used.sum())}/{len(f.used)}")
        lines += [f"warning: {w}" for w in self.warnings]
        return "\n".join(lines)


def _algebraic_sphere(p: np.ndarray) -> tuple[np.ndarray, float]:
    # |p|^2 = 2 c.p + (rho^2 - |c|^2) is linear in (c, k): a good start for the geometric fit.
    A = np.column_stack([2 * p, np.ones(len(p))])
    b = np.einsum("ij,ij->i", p, p)
    sol, *_ = np.linalg.lstsq(A, b, rcond=None)
    c = sol[:3]
    return c, math.sqrt(max(sol[3] + c @ c, 1e-12))


def fit_sphere(points: np.ndarray, radius: float | None = None, x0=None):
    """Geometric least-squares sphere through points (m, 3) mm (scipy, Levenberg-Marquardt).

    radius=None fits the radius too (needs m >= 4), else it is held fixed (m >= 3).
    Returns (centre (3,), rho, residuals (m,), jacobian (m, 4 or 3)).
    """
    from scipy.optimize import leastsq
    p = np.asarray(points, float)
    if x0 is None:
        if len(p) >= 4:
            c0, r0 = _algebraic_sphere(p)
        else:
            c0, r0 = p.mean(axis=0), radius
        if not np.all(np.isfinite(c0)):
            c0 = p.mean(axis=0)
    else:
        c0, r0 = np.asarray(x0[:3], float), float(x0[3]) if len(x0) > 3 else radius
    free = radius is None

    def res(x):
        d = np.linalg.norm(p - x[:3], axis=1)
        return d - (x[3] if free else radius)

    def jac(x):
        d = p - x[:3]
        n = np.linalg.norm(d, axis=1)[:, None]
        J = -d / n
        return np.column_stack([J, -np.ones(len(p))]) if free else J

    # Levenberg-Marquardt (MINPACK through scipy.optimize.leastsq: the thin wrapper matters in
    # Monte Carlo loops) from the algebraic start converges in a few steps; it needs at least as
    # many touches as unknowns, which the callers check with a clear message.
    x0v = np.r_[c0, r0] if free else np.asarray(c0, float)
    x, ier = leastsq(res, x0v, Dfun=jac, xtol=1e-14, ftol=1e-15, maxfev=400)
    if ier not in (1, 2, 3, 4):
        raise MtcompError(f"sphere fit did not converge (MINPACK code {ier})")
    rho = float(x[3]) if free else float(radius)
    return x[:3].copy(), rho, res(x), jac(x)


def _cov(J: np.ndarray, sigma: float) -> np.ndarray:
    JTJ = J.T @ J
    return sigma * sigma * np.linalg.inv(JTJ)


def _shared_fit(done, touches, gross_limit, limit, src, probe_radius):
    """Joint fit of all bowl centres with one probe-centre radius over the touches kept.

    Returns the updated per-bowl records, (J^T J)^-1 of (c_1 .. c_n, rho), SSR and dof.
    """
    from scipy.optimize import leastsq
    n = len(done)
    pts = [touches.points[touches.of(bid)] for bid, *_ in done]
    used = [rec[4] for rec in done]
    P = np.concatenate([p[u] for p, u in zip(pts, used)])
    owner = np.concatenate([np.full(int(u.sum()), b) for b, u in enumerate(used)])
    x0 = np.r_[np.concatenate([rec[1] for rec in done]), np.mean([rec[2] for rec in done])]

    def res(x):
        C = x[:3 * n].reshape(n, 3)[owner]
        return np.sqrt(((P - C) ** 2).sum(axis=1)) - x[-1]

    def jac(x):
        C = x[:3 * n].reshape(n, 3)[owner]
        D = P - C
        D /= np.sqrt((D * D).sum(axis=1))[:, None]
        J = np.zeros((len(P), 3 * n + 1))
        for a in range(3):
            J[np.arange(len(P)), 3 * owner + a] = -D[:, a]
        J[:, -1] = -1.0
        return J

    x, ier = leastsq(res, x0, Dfun=jac, xtol=1e-14, ftol=1e-15, maxfev=400)
    if ier not in (1, 2, 3, 4):
        raise MtcompError(f"joint sphere fit did not converge (MINPACK code {ier})")
    J = jac(x)
    inv = np.linalg.inv(J.T @ J)
    r = res(x)
    if np.max(np.abs(r)) > limit:
        # name the bowl whose own radius is furthest from the others'
        radii = np.array([rec[2] for rec in done])
        b = int(np.argmax(np.abs(radii - np.median(radii))))
        own = ", ".join(f"{rec[0]}: {rec[2] + probe_radius:.4f}" for rec in done)
        raise InputError(f"bowl {done[b][0]}: the bowls do not share one radius (own fits, bowl: "
                         f"radius mm: {own}; joint misfit up to {np.max(np.abs(r)) * 1e3:.2f} um > "
                         f"{limit * 1e3:.2f} um): cut with another tool? fit a radius per bowl",
                         src, field="bowl")
    out = []
    for b, (bid, _c, _rho, _resid, u, lines, _J) in enumerate(done):
        c = x[3 * b:3 * b + 3]
        resid = np.sqrt(((pts[b] - c) ** 2).sum(axis=1)) - x[-1]
        far = np.flatnonzero(np.abs(resid) > gross_limit)
        if len(far):
            j = far[np.argmax(np.abs(resid[far]))]
            where = f"line {int(lines[j])}" if lines[j] else f"touch {j + 1}"
            raise InputError(f"bowl {bid}: {where} is {resid[j] * 1e3:.1f} um off the sphere with "
                             f"the radius shared by all bowls (limit {gross_limit * 1e3:.0f} um): "
                             "was this bowl cut with another tool?", src, field="bowl")
        out.append((bid, c.copy(), float(x[-1]), resid, u, lines, None))
    return out, inv, float(r @ r), len(P) - (3 * n + 1)


def fit_bowls(touches: Touches, probe_radius: float, *, probe_sigma: float | None = None,
              bowl_radius: float | None = None, shared_radius: bool = True, k: float = 5.0,
              gross_limit: float = 0.05, bowls=None) -> BowlFit:
    """Fit every bowl's sphere from its touches, with the probe radius accounted for.

    probe_sigma: probe noise (1 sigma along the approach, mm); None pools it from the residuals.
    bowl_radius: fix the bowl radius (mm) instead of fitting it.  shared_radius (default): fit one
    radius for all bowls (one ball end mill cut them all): the bowls' centre heights then no longer
    carry independent radius errors, which cuts the tilt uncertainty several times; the centres
    become correlated (BowlFit.centre_cov_full).  Robustness: a touch whose
    leave-one-out residual exceeds k sigma is rejected (at most one per bowl, with a warning);
    any touch still beyond k sigma after that, or one more than `gross_limit` mm off its sphere
    (the probe hit the rim, the top face or another bowl), is an error naming the bowl and line.
    bowls: ids to fit (default all ids in the touches, sorted).
    """
    if probe_radius <= 0:
        raise InputError(f"probe radius must be > 0 mm, got {probe_radius}", field="probe_radius")
    if not k > 0:
        raise InputError(f"outlier threshold must be > 0 sigma, got {k}", field="k")
    src = touches.source
    ids = sorted(set(int(b) for b in touches.bowl)) if bowls is None else list(bowls)
    npar = 4 if bowl_radius is None else 3
    fixed_rho = None if bowl_radius is None else bowl_radius - probe_radius
    if fixed_rho is not None and fixed_rho <= 0:
        raise InputError(f"bowl radius {bowl_radius} must exceed the probe radius {probe_radius}",
                         field="bowl_radius")
    warnings: list[str] = []
    raw = []
    for bid in ids:
        idx = touches.of(bid)
        m = len(idx)
        if m < npar + 1:
            raise InputError(f"bowl {bid}: {m} touches, at least {npar + 1} needed (a sphere with "
                             f"{'free' if npar == 4 else 'fixed'} radius has {npar} unknowns, plus "
                             "one to see the fit's residual)", src, field="bowl")
        p = touches.points[idx]
        # degenerate touch sets (all in one spot or on one circle) leave the sphere undetermined
        sv = np.linalg.svd(p - p.mean(axis=0), compute_uv=False)
        if sv[1] < 1e-3 * max(sv[0], 1e-12) or sv[0] < 1e-6:
            raise InputError(f"bowl {bid}: touches are coincident or collinear; spread them over "
                             "the bowl wall", src, field="bowl")
        if npar == 4 and sv[2] < 1e-3 * sv[0]:
            raise InputError(f"bowl {bid}: touches are coplanar (one circle); a sphere with free "
                             "radius needs touches at two or more depths", src, field="bowl")
        c, rho, r, J = fit_sphere(p, fixed_rho)
        raw.append((bid, idx, p, c, rho, r, J))
    if probe_sigma is not None:
        if not probe_sigma >= 0:
            raise InputError(f"probe noise must be >= 0 mm, got {probe_sigma}", field="probe_sigma")
        thr_sigma = float(probe_sigma)
    else:
        # robust pooled scale for the outlier decisions: one bad touch must not inflate it
        allr = np.concatenate([r for *_, r, _J in raw])
        dof = sum(len(r) - npar for *_, r, _J in raw)
        s_pool = math.sqrt(float(allr @ allr) / dof)
        mad = 1.4826 * float(np.median(np.abs(allr))) * math.sqrt(len(allr) / dof)
        thr_sigma = min(s_pool, 2 * mad) if mad > 0 else s_pool
    # resolution floor: decisions against a zero noise estimate would flag rounding
    thr_sigma = max(thr_sigma, 1e-6)
    done = []
    for bid, idx, p, c, rho, r, J in raw:
        m = len(idx)
        used = np.ones(m, bool)
        lines = touches.lines[idx]
        where = lambda j: (f"line {int(lines[j])}" if lines[j] else f"touch {j + 1}")  # noqa: E731
        need = bool(np.max(np.abs(r)) > k * thr_sigma)
        if need or probe_sigma is None:
            # leave-one-out: the outlier's own residual is shrunk by its leverage in the full fit
            # (with an estimated scale it can hide completely), so judge each touch against the
            # sphere of the others
            best = None
            if m - 1 >= npar:
                for j in range(m):
                    keep = np.arange(m) != j
                    cj, rhoj, rj, _ = fit_sphere(p[keep], fixed_rho, x0=np.r_[c, rho])
                    out = abs(np.linalg.norm(p[j] - cj) - rhoj)
                    worst_rest = float(np.max(np.abs(rj)))
                    if best is None or worst_rest < best[1] - 1e-12 or \
                            (abs(worst_rest - best[1]) <= 1e-12 and out > best[2]):
                        best = (j, worst_rest, out, cj, rhoj)
            can = best is not None and m - 1 >= npar + 1 and best[1] <= k * thr_sigma
            if need and not can:
                jw = int(np.argmax(np.abs(r)))
                raise InputError(f"bowl {bid}: touches disagree with one sphere by up to "
                                 f"{np.max(np.abs(r)) * 1e3:.2f} um at {where(jw)} (noise "
                                 f"{thr_sigma * 1e3:.3f} um, limit {k:g} sigma): more than one bad "
                                 "touch, or too few touches to reject one", src, field="bowl")
            if can and (need or best[2] > k * thr_sigma):
                j, worst_rest, out, cj, rhoj = best
                used[j] = False
                warnings.append(f"bowl {bid}: {where(j)} rejected, {out * 1e3:.2f} um off the "
                                f"sphere of the other touches ({out / thr_sigma:.1f} sigma)")
                c, rho, _r, _J = fit_sphere(p[used], fixed_rho, x0=np.r_[cj, rhoj])
        resid = np.linalg.norm(p - c, axis=1) - rho
        far = np.flatnonzero(np.abs(resid) > gross_limit)
        if len(far):
            j = far[np.argmax(np.abs(resid[far]))]
            raise InputError(f"bowl {bid}: {where(j)} is {resid[j] * 1e3:.1f} um off the bowl's "
                             f"sphere (limit {gross_limit * 1e3:.0f} um): the probe did not touch "
                             "this bowl's wall (rim, top face, wrong bowl id?)", src, field="bowl")
        d = p[used] - c
        Ju = -d / np.linalg.norm(d, axis=1)[:, None]
        if fixed_rho is None:
            Ju = np.column_stack([Ju, -np.ones(len(d))])
        if np.linalg.cond(Ju) > 1e8:
            raise InputError(f"bowl {bid}: touches do not determine the sphere (ill-conditioned)",
                             src, field="bowl")
        done.append((bid, c, rho, resid, used, lines, Ju))
    if probe_sigma is not None:
        sigma, known = float(probe_sigma), True
    else:
        ssr = sum(float(d[3][d[4]] @ d[3][d[4]]) for d in done)
        dof = sum(int(d[4].sum()) - npar for d in done)
        sigma, known = math.sqrt(ssr / dof), False
    full = None
    if shared_radius and fixed_rho is None and len(done) > 1:
        done, full, ssr, dof = _shared_fit(done, touches, gross_limit, k * thr_sigma, src,
                                           probe_radius)
        if probe_sigma is None:
            sigma = math.sqrt(ssr / dof)
    fits = []
    for b, (bid, c, rho, resid, used, lines, Ju) in enumerate(done):
        if full is not None:
            sel = [3 * b, 3 * b + 1, 3 * b + 2, 3 * len(done)]
            cov = sigma * sigma * full[np.ix_(sel, sel)]
        else:
            cov = _cov(Ju, sigma)
        if fixed_rho is not None:
            cov = np.pad(cov, ((0, 1), (0, 1)))
        fits.append(SphereFit(bowl=bid, centre=c, radius=rho + probe_radius, cov=cov,
                              residuals=resid, used=used, sigma=sigma, lines=lines,
                              fixed_radius=fixed_rho is not None))
    if full is not None:
        n3 = 3 * len(done)
        return BowlFit(fits=tuple(fits), probe_radius=float(probe_radius), sigma=sigma,
                       sigma_known=known, warnings=tuple(warnings),
                       shared_cov=sigma * sigma * full[:n3, :n3])
    return BowlFit(fits=tuple(fits), probe_radius=float(probe_radius), sigma=sigma,
                   sigma_known=known, warnings=tuple(warnings))
