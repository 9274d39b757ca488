"""Reference bowls of paper 001: the plan (bowl positions, ball end mill, probe, contact directions)
and its TOML file.

The workpiece frame of the design has its origin at the centre of the top face, z up, so a bowl of
depth h at (x, y) is the sphere of radius R centred at (x, y, R - h), cut below z = 0.  Units: mm.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .._io import InputError
from ..validate import MAX_MAGNITUDE, _describe


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


def default_directions(m: int, rim_polar: float, margin: float = 12.0, inner: float = 0.5) -> np.ndarray:
    """m contact directions: one at the bottom plus two rings (outer ring `margin` deg below the rim,
    inner ring at `inner` times the outer ring's polar angle)."""
    if m < 1:
        raise InputError(f"touches per bowl must be >= 1, got {m}", field="touches")
    outer = rim_polar - margin
    if outer <= 5.0:
        raise InputError(f"bowl too shallow to probe: rim at {rim_polar:.1f} deg from the bottom, "
                         f"need more than {margin + 5:.0f} deg", field="depth")
    dirs = [(0.0, 0.0, -1.0)]
    rest = m - 1
    n1, n2 = rest // 2, rest - rest // 2
    if not 0 < inner < 1:
        raise InputError(f"inner ring must lie between the bottom and the outer ring (0 < inner < 1), got {inner}",
                         field="inner")
    for count, polar, phase in ((n1, outer * inner, 0.0), (n2, outer, 0.5)):
        for k in range(count):
            az = 2 * math.pi * (k + phase) / count
            th = math.radians(polar)
            dirs.append((math.sin(th) * math.cos(az), math.sin(th) * math.sin(az), -math.cos(th)))
    return np.array(dirs, float)


def plan_bowls(n: int = 3, *, blank=(20.0, 20.0, 5.0), tool_radius: float = 2.0,
               depth: float = 1.0, probe_radius: float = 0.5, touches: int = 9,
               positions=None, edge_distance: float = 3.0, margin: float = 0.5,
               keepout_radius: float = 3.0,
               clearance: float = 0.2, overtravel: float = 0.1, safe_z: float = 5.0,
               inner: float = 0.5) -> BowlPlan:
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
    dirs = default_directions(touches, rim, inner=inner)
    plan = BowlPlan(bowls=bowls, blank=blank, tool_radius=float(tool_radius), depth=float(depth),
                    probe_radius=float(probe_radius),
                    directions=tuple(tuple(float(v) for v in d) for d in dirs),
                    clearance=float(clearance), overtravel=float(overtravel), safe_z=float(safe_z),
                    keepout_radius=float(keepout_radius))
    from .frame import check_bowl_geometry
    check_bowl_geometry(plan.centres, plan.ids, what="planned")
    return plan




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


def _float_range(v) -> bool:
    """False for a TOML integer too large for a length (float() or isfinite() would overflow)."""
    return not isinstance(v, int) or abs(v) <= MAX_MAGNITUDE


def plan_from_dict(d: dict, file=None) -> BowlPlan:
    def num(key, default=None):
        v = d.get(key, default)
        if v is None:
            raise InputError("missing", file, field=key)
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            raise InputError(f"expected a number (mm), got {v!r}", file, field=key)
        if isinstance(v, int) and abs(v) > MAX_MAGNITUDE:   # TOML integers are unbounded
            raise InputError(f"expected a number of at most {MAX_MAGNITUDE:g} mm, got {_describe(v)}", file, field=key)
        return float(v)
    try:
        raw = d["bowls"]
    except KeyError:
        raise InputError("missing list of [[bowls]] (id, x, y)", file, field="bowls") from None
    if not isinstance(raw, list) or not raw:
        raise InputError(f"expected a list of [[bowls]] tables (id, x, y), got {raw!r:.40}", file, field="bowls")
    bowls = []
    for k, b in enumerate(raw):
        if not isinstance(b, dict) or not {"id", "x", "y"} <= set(b):
            raise InputError("each bowl needs an integer id and numbers x, y (mm)", file, field=f"bowls[{k}]")
        bid, x, y = b["id"], b["x"], b["y"]
        # an id must be a whole number: a float like 1.0 is taken, inf, nan, 1.5 or a string are not
        if isinstance(bid, bool) or not isinstance(bid, (int, float)) or not _float_range(bid) \
                or not math.isfinite(bid) or bid != int(bid) or not 0 < bid < 1e9:
            raise InputError(f"bowl id must be a positive integer below 1e9, got {_describe(bid)}", file,
                             field=f"bowls[{k}].id")
        for name, v in (("x", x), ("y", y)):
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not _float_range(v) \
                    or not math.isfinite(v) or abs(v) > 1e4:
                raise InputError(f"expected a finite position of at most 1e4 mm, got {_describe(v)}", file,
                                 field=f"bowls[{k}].{name}")
        bowls.append(Bowl(int(bid), float(x), float(y)))
    ids = [b.id for b in bowls]
    if len(set(ids)) != len(ids):
        raise InputError(f"bowl ids must be unique, got {ids}", file, field="bowls")
    raw_dirs = d.get("directions")
    if not raw_dirs:
        raise InputError("missing list of contact directions [[x, y, z], ...]", file, field="directions")
    if (not isinstance(raw_dirs, list)
            or not all(isinstance(r, list) and len(r) == 3
                       and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in r)
                       for r in raw_dirs)):
        raise InputError(f"expected a list of [x, y, z] unit vectors, got {raw_dirs!r:.60}", file,
                         field="directions")
    try:
        dirs = np.asarray(raw_dirs, float)
    except OverflowError:   # an integer beyond float range (TOML integers are unbounded)
        raise InputError("expected unit vectors, got a number beyond float range", file,
                         field="directions") from None
    norms = np.linalg.norm(dirs, axis=1)
    if np.any(np.abs(norms - 1) > 1e-6):
        raise InputError("every direction must be a unit vector", file, field="directions")
    blank = d.get("blank", [20.0, 20.0, 5.0])
    if (not isinstance(blank, list) or len(blank) != 3
            or not all(isinstance(v, (int, float)) and not isinstance(v, bool) and _float_range(v)
                       and v > 0 for v in blank)):
        raise InputError(f"expected three positive sizes [lx, ly, lz] mm, got {_describe(blank)}", file, field="blank")
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
    for key in ("tool_radius", "depth", "probe_radius", "clearance", "overtravel", "safe_z", "keepout_radius",
                "spindle_speed", "plunge_feed", "probe_feed"):
        v = getattr(plan, key)
        if not math.isfinite(v) or abs(v) > 1e6:
            raise InputError(f"expected a finite number of at most 1e6, got {v!r}", file, field=key)
    if not math.isfinite(sum(plan.blank)) or max(plan.blank) > 1e4:
        raise InputError(f"expected finite blank sizes of at most 1e4 mm, got {list(plan.blank)}", file, field="blank")
    return plan


def save_plan(plan: BowlPlan, path) -> Path:
    from .._io import atomic_write, dump_toml
    return atomic_write(path, dump_toml(plan_to_dict(plan)))


def load_plan(path) -> BowlPlan:
    from .._io import load_toml
    return plan_from_dict(load_toml(path), file=path)
