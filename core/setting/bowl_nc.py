"""NC programs for the reference bowls: roughing on the ordinary machine and probing on the
ultraprecision machine (ISO 6983 / Fanuc dialect, mm, absolute), and the probing moves."""
from __future__ import annotations

import numpy as np

from .bowl_plan import BowlPlan


def _fmt(v: float, digits: int = 4) -> str:
    s = f"{v:.{digits}f}".rstrip("0").rstrip(".")
    return "0" if s in ("-0", "") else s


_f = _fmt


def _ax(v: float, digits: int = 4) -> str:
    """An axis word's number, always with a decimal point: a control set to read numbers without
    one in least input increments would take `X7` as 7 µm (docs/gcode.md)."""
    s = _fmt(v, digits)
    return s if "." in s else s + "."


def roughing_program(plan: BowlPlan, peck: float = 0.5) -> str:
    """3-axis program for the ordinary machining centre that plunges every bowl with the ball end mill.

    Programmed point: the ball end mill's tip (tool length measured to the tip), so the tip goes to
    z = -depth.  Plunging in pecks of `peck` mm with a full retract clears chips.  The way back
    down into the hole is a feed move: a rapid would pass the verification against the raw blank
    (`setting.blank_check.verify_plan_programs`) only by knowing what the peck has cut.
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
                out.append(f"G01 Z{_ax(z + 0.05)} F{_f(plan.plunge_feed)}")
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


def probing_program(plan: BowlPlan, aim=None, repeat_first: bool = False) -> str:
    """Probing program for the ultraprecision machine (rotary axes at 0), probe-centre positions.

    For each bowl: rapid to safe height over the sphere centre, feed down to the sphere centre
    (in air or inside the bowl, h <= R), then for each touch a feed to the start point, a skip move
    (G31) along the approach direction, and a feed back to the sphere centre.  The controller logs
    the probe centre at trigger; together with bowl id and approach that is the touches CSV.
    repeat_first: visit the first bowl again at the end (its touches a second time), so that
    `fit` sees and removes the drift over the probing (`bowl_drift`).
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
    order = list(zip(plan.bowls, plan.centres))
    for k, (b, c) in enumerate(order + order[:1] if repeat_first else order):
        cm = R @ c + t
        out.append(f"(BOWL {b.id})" if k < len(order) else f"(BOWL {b.id} AGAIN: DRIFT CHECK)")
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
