"""Toolpaths for the calibration features and the papers' parts, and their machine axes.

A :class:`Toolpath` is a sequence of tool poses in the workpiece frame (the CAD frame of
:mod:`mtcomp.cad_plugin.features`: top face z = 0, material below): the controlled tool point
``p`` (the tool edge of a V tool, the tip of a ball end mill or probe), the tool frame ``R``
(columns x_t, y_t, tool axis; the tool axis points from the edge into the holder, x_t is the
direction the rake face faces for a non-rotational tool), a motion code per point (rapid, feed,
probe), and the unit normal of the target surface at the contact (NaN where the tool does not
touch).  Units mm, deg, mm/min.

Pure numpy: no CadQuery here.  :func:`to_axes` turns a toolpath into machine axis commands
through :mod:`mtcomp.kinematics` (nominal inverse kinematics, or compensated for an error set).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from .._io import InputError, MtcompError
from ..kinematics import axis_rotation

RAPID, FEED, PROBE = 0, 1, 2


@dataclass(frozen=True)
class Tool:
    """kind: "vtool" (non-rotational V tool, included `angle` deg), "ball" (ball end mill of
    `radius` mm) or "probe" (touch probe, stylus ball `radius` mm).  number: T word."""
    kind: str
    radius: float = 0.0
    angle: float = 90.0
    number: int = 1
    name: str = ""

    def __post_init__(self):
        if self.kind not in ("vtool", "ball", "probe"):
            raise InputError(f"tool kind must be vtool, ball or probe, got {self.kind!r}", field="tool")
        if self.kind != "vtool" and not self.radius > 0:
            raise InputError(f"{self.kind} radius must be > 0 mm, got {self.radius}", field="tool.radius")

    @property
    def description(self) -> str:
        if self.name:
            return self.name
        if self.kind == "vtool":
            return f"non-rotational V tool {self.angle:g} deg"
        return f"{'ball end mill' if self.kind == 'ball' else 'touch probe'} R{self.radius:g}"


@dataclass(frozen=True)
class Toolpath:
    """Tool poses in the workpiece frame (see the module docstring)."""
    p: np.ndarray                      # (N,3) controlled tool point, mm
    R: np.ndarray                      # (N,3,3) tool frame, columns x_t, y_t, tool axis
    motion: np.ndarray                 # (N,) RAPID / FEED / PROBE: how the tool moves TO the point
    normal: np.ndarray                 # (N,3) target surface normal at the contact, NaN if none
    tool: Tool
    feed: float = 100.0                # mm/min
    name: str = ""
    meta: dict = field(default_factory=dict, compare=False)

    def __post_init__(self):
        n = len(self.p)
        for a, shape in ((self.p, (n, 3)), (self.R, (n, 3, 3)), (self.motion, (n,)),
                         (self.normal, (n, 3))):
            if np.shape(a) != shape:
                raise ValueError(f"toolpath arrays disagree: expected {shape}, got {np.shape(a)}")

    def __len__(self) -> int:
        return len(self.p)

    @property
    def axis(self) -> np.ndarray:
        """Tool axis directions (N,3), from the edge into the holder."""
        return self.R[:, :, 2]

    @property
    def centre(self) -> np.ndarray:
        """Ball centres (N,3) for ball tools and probes (tip + radius * axis)."""
        return self.p + self.tool.radius * self.axis

    @property
    def cutting(self) -> np.ndarray:
        """Mask of points reached by a feed (or probing) move that touch the target surface."""
        return (self.motion != RAPID) & np.isfinite(self.normal[:, 0])


def _frames(feed_dir: np.ndarray, axis: np.ndarray) -> np.ndarray:
    """Tool frames (N,3,3) with tool axis `axis` and x_t the feed direction made normal to it."""
    axis = axis / np.linalg.norm(axis, axis=1, keepdims=True)
    x = feed_dir - np.einsum("ni,ni->n", feed_dir, axis)[:, None] * axis
    x /= np.linalg.norm(x, axis=1, keepdims=True)
    return np.stack([x, np.cross(axis, x), axis], axis=2)


class _Builder:
    """Accumulates moves; rotation matrices per point."""

    def __init__(self):
        self.p, self.R, self.m, self.n = [], [], [], []

    def add(self, p, R, motion, normal=None):
        p = np.atleast_2d(np.asarray(p, float))
        k = len(p)
        R = np.asarray(R, float)
        self.p.append(p)
        self.R.append(np.broadcast_to(R, (k, 3, 3)) if R.ndim == 2 else R)
        self.m.append(np.full(k, motion))
        nn = np.full((k, 3), np.nan) if normal is None else np.broadcast_to(
            np.asarray(normal, float), (k, 3))
        self.n.append(nn)

    def build(self, tool, feed, name, **meta) -> Toolpath:
        return Toolpath(np.vstack(self.p), np.concatenate(self.R).copy(),
                        np.concatenate(self.m), np.vstack(self.n).copy(), tool, feed, name, meta)


def _samples(length: float, step: float) -> np.ndarray:
    n = max(1, int(math.ceil(length / step - 1e-9)))
    return np.linspace(0.0, 1.0, n + 1)


# ----------------------------------------------------------------------------- V-grooves
def vgroove_passes(segments, depth: float, tool: Tool, tilts=None, safe: float = 1.0,
                   step: float = 0.5, feed: float = 50.0, name: str = "vgrooves") -> Toolpath:
    """Straight V-grooves on the plane z = 0: per segment ((x0,y0),(x1,y1)) approach above the
    start, plunge along the tool axis to `depth`, feed to the end (points every `step` mm),
    retract.  The tool's rake face faces the feed; `tilts` (deg, per segment) turn the tool about
    the feed direction (B tilts when feeding along Y), which the rotary axes carry."""
    if tool.kind != "vtool":
        raise InputError("V-grooves need a vtool", field="tool")
    b = _Builder()
    segs = [np.asarray(s, float) for s in segments]
    tilts = np.zeros(len(segs)) if tilts is None else np.asarray(tilts, float)
    for (p0, p1), tilt in zip(segs, tilts):
        u = np.array([*(p1 - p0), 0.0])
        length = float(np.linalg.norm(u))
        u /= length
        v = axis_rotation(u, math.radians(tilt)) @ [0.0, 0.0, 1.0]   # tool axis: +z turned about u
        R = _frames(u[None], v[None])[0]
        start, end = np.array([*p0, -depth]), np.array([*p1, -depth])
        b.add(start + safe * v, R, RAPID)
        s = _samples(length, step)
        line = start + np.outer(s, end - start)
        # Plunge (no surface contact yet), then the cut along the groove bottom line.
        b.add(line[0], R, FEED)
        b.add(line[1:], R, FEED, normal=v)
        b.add(end + safe * v, R, FEED)
    return b.build(tool, feed, name, depth=depth)


def groove_plate_passes(layout=None, tool: Tool | None = None, **kw) -> Toolpath:
    """V-groove passes of the groove calibration plate (see features.GroovePlateLayout)."""
    if layout is None:
        from .layout import GroovePlateLayout
        layout = GroovePlateLayout()
    tool = tool or Tool("vtool", angle=layout.angle)
    g = layout.grooves()
    return vgroove_passes([s for s, _ in g], layout.depth, tool, [t for _, t in g],
                          name="groove-plate", **kw)


def grating_passes(sphere_radius: float, psi, span: float, depth: float, tool: Tool,
                   safe: float = 0.5, step_deg: float = 0.25, feed: float = 20.0,
                   name: str = "grating") -> Toolpath:
    """V-microgrooves on the concave sphere (centre (0, 0, R)) of features.sphere_vgrooves.

    Along each groove the tool axis stays on the surface normal (through the sphere centre) and
    the rake face faces the feed direction, so every point has its own orientation: the rotary
    axes carry it.  The tool edge runs on the groove bottom, `depth` below the surface."""
    if tool.kind != "vtool":
        raise InputError("grating grooves need a vtool", field="tool")
    rs = float(sphere_radius)
    c0 = np.array([0.0, 0.0, rs])
    b = _Builder()
    for p in np.atleast_1d(np.asarray(psi, float)):
        s, c = math.sin(math.radians(p)), math.cos(math.radians(p))
        d = np.array([0.0, s, -c])
        n = np.array([0.0, c, s])
        half = math.radians(span / 2.0)
        t = np.linspace(-half, half, max(2, int(math.ceil(span / step_deg)) + 1))
        # Direction from the centre: d turned by t about n; n x d = -x, so the groove runs from
        # +x to -x as t grows (same sense as the CAD revolution); the feed direction is the
        # derivative, n x d turned by t.
        Rt = axis_rotation(n, t)
        dirs = Rt @ d
        tang = Rt @ np.cross(n, d)
        tip = c0 + (rs + depth) * dirs
        R = _frames(tang, -dirs)
        b.add(tip[0] - (safe + depth) * dirs[0], R[0], RAPID)
        b.add(tip[0], R[0], FEED)
        b.add(tip[1:], R[1:], FEED, normal=-dirs[1:])
        b.add(tip[-1] - (safe + depth) * dirs[-1], R[-1], FEED)
    return b.build(tool, feed, name, depth=depth, sphere_radius=rs)


# ---------------------------------------------------------------------------------- bowls
def bowl_milling(centres, radius: float, depth: float, tool: Tool, stepover: float = 0.05,
                 step: float = 0.05, safe: float = 1.0, feed: float = 200.0,
                 name: str = "bowls") -> Toolpath:
    """Finish the spherical bowls of features.bowl with a smaller ball end mill.

    Per bowl a spiral from the rim to the bottom: the ball centre stays on the sphere of
    radius (radius - tool radius) about the bowl's sphere centre (x, y, radius - depth); the
    contact point advances by `stepover` mm of arc per turn, points every `step` mm."""
    if tool.kind != "ball" or tool.radius >= radius:
        raise InputError("bowl milling needs a ball end mill smaller than the bowl", field="tool")
    rt, R0 = tool.radius, radius
    rim = math.acos((R0 - depth) / R0)       # polar angle of the rim (from the -z pole)
    b = _Builder()
    I = np.eye(3)
    for cx, cy in np.asarray(centres, float):
        cs = np.array([cx, cy, R0 - depth])
        turns = rim * R0 / stepover
        n = max(8, int(math.ceil(2 * math.pi * R0 * math.sin(rim) * turns / step)))
        s = np.linspace(0.0, 1.0, n + 1)
        theta = rim * (1.0 - s)               # contact polar angle: rim -> bottom
        phi = 2 * math.pi * turns * s
        nrm = np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi),
                        -np.cos(theta)], axis=1)  # outward from the sphere centre (into material)
        centre = cs + (R0 - rt) * nrm
        tip = centre - [0.0, 0.0, rt]
        b.add(tip[0] + [0, 0, safe + depth], I, RAPID)
        b.add(tip, I, FEED, normal=-nrm)
        b.add(tip[-1] + [0, 0, safe + depth], I, FEED)
    return b.build(tool, feed, name, radius=radius, depth=depth)


def bowl_probing(centres, radius: float, depth: float, probe: Tool, polar=(0.0, 25.0, 40.0),
                 n_azimuth: int = 6, approach: float = 0.2, overtravel: float = 0.1,
                 safe: float = 1.0, feed: float = 20.0, name: str = "bowl-probing") -> Toolpath:
    """Touch-probe each bowl (paper 001) at the bottom and on rings at `polar` angles (deg from
    the bowl's axis, `n_azimuth` points per ring).

    Each probing move (G31) runs along the surface normal from `approach` mm off the surface
    to `overtravel` mm past the nominal contact, so a blank that sits off by less than that
    still triggers the skip.  At the nominal contact the stylus centre is on the sphere of
    radius (radius - probe radius): :func:`probe_contacts` gives those points.  Fit sphere
    centres, not the lowest points (which move with the tilt of the blank)."""
    if probe.kind != "probe" or probe.radius >= radius:
        raise InputError("bowl probing needs a probe smaller than the bowl", field="tool")
    rim = math.degrees(math.acos((radius - depth) / radius))
    if max(polar) + math.degrees(math.asin(min(1.0, probe.radius / radius))) >= rim:
        raise InputError(f"probing ring at {max(polar)} deg leaves the bowl (rim at {rim:.2f} deg)",
                         field="polar")
    b = _Builder()
    I = np.eye(3)
    for cx, cy in np.asarray(centres, float):
        cs = np.array([cx, cy, radius - depth])
        b.add(cs + [0, 0, safe - radius + depth + probe.radius], I, RAPID)
        for th in polar:
            phis = [0.0] if th == 0 else np.arange(n_azimuth) * 360.0 / n_azimuth
            for ph in phis:
                t, f = math.radians(th), math.radians(ph)
                nrm = np.array([math.sin(t) * math.cos(f), math.sin(t) * math.sin(f), -math.cos(t)])
                contact_c = cs + (radius - probe.radius) * nrm
                start_c = contact_c - approach * nrm
                b.add(start_c - [0, 0, probe.radius], I, FEED)
                b.add(contact_c + overtravel * nrm - [0, 0, probe.radius], I, PROBE, normal=-nrm)
                b.add(start_c - [0, 0, probe.radius], I, FEED)
        b.add(cs + [0, 0, safe - radius + depth + probe.radius], I, FEED)
    return b.build(probe, feed, name, radius=radius, depth=depth, approach=approach,
                   overtravel=overtravel, centres=[tuple(map(float, c)) for c in centres])


def probe_contacts(path: Toolpath) -> np.ndarray:
    """Nominal stylus-centre contacts (M,3) of the probing moves of a :func:`bowl_probing` path:
    the G31 end points moved back by the overtravel along the surface normal."""
    touch = path.motion == PROBE
    return path.centre[touch] + path.meta.get("overtravel", 0.0) * path.normal[touch]


# -------------------------------------------------------------------------------- pyramid
def pyramid_triangles(width: float, height: float, margin: float) -> np.ndarray:
    """Triangles (M,3,3) of the pyramid's four slopes and of the surrounding flat z = 0 (a
    square `margin` mm wider on each side), in the workpiece frame."""
    w, m = width / 2.0, width / 2.0 + margin
    apex = np.array([0.0, 0.0, height])
    base = np.array([[-w, -w, 0], [w, -w, 0], [w, w, 0], [-w, w, 0]], float)
    tris = [[base[i], base[(i + 1) % 4], apex] for i in range(4)]
    sq = np.array([[-m, -m, 0], [m, -m, 0], [m, m, 0], [-m, m, 0]], float)
    tris += [[sq[0], sq[1], sq[2]], [sq[0], sq[2], sq[3]]]
    return np.array(tris)


def drop_ball(xy: np.ndarray, triangles: np.ndarray, r: float) -> tuple[np.ndarray, np.ndarray]:
    """Drop a ball of radius r at each (x, y) onto triangles: the ball-centre height (N,) and
    the unit contact normal (N,3) at the highest contact.  Exact: the ball touches a facet
    interior, an edge or a vertex, and the centre height is the maximum over all of them.
    (Written here because no maintained Python package does exact drop-cutter on meshes.)"""
    xy = np.asarray(xy, float)
    N = len(xy)
    best = np.full(N, -np.inf)
    cpt = np.zeros((N, 3))  # contact point of the best candidate

    def take(z, contact):
        better = z > best
        best[better] = z[better]
        cpt[better] = contact[better]

    for tri in triangles:
        a, b_, c = tri
        n = np.cross(b_ - a, c - a)
        n /= np.linalg.norm(n)
        if n[2] < 0:
            n = -n
        if n[2] > 1e-12:  # facet interior: centre = contact + r n
            q = xy - r * n[:2]
            zc = a[2] - (n[0] * (q[:, 0] - a[0]) + n[1] * (q[:, 1] - a[1])) / n[2]
            # barycentric test of the contact's projection
            v0, v1 = (b_ - a)[:2], (c - a)[:2]
            w = q - a[:2]
            den = v0[0] * v1[1] - v1[0] * v0[1]
            l1 = (w[:, 0] * v1[1] - v1[0] * w[:, 1]) / den
            l2 = (v0[0] * w[:, 1] - w[:, 0] * v0[1]) / den
            inside = (l1 >= 0) & (l2 >= 0) & (l1 + l2 <= 1)
            z = np.where(inside, zc + r * n[2], -np.inf)
            take(z, np.column_stack([q, zc]))
        for p0, p1 in ((a, b_), (b_, c), (c, a)):
            e = p1 - p0
            exy = e[:2]
            wxy = xy - p0[:2]
            # |w - (w.e/|e|^2) e|^2 = r^2 with w = (wxy, z - p0z): quadratic in z.
            ee = e @ e
            A = 1.0 - e[2] ** 2 / ee
            if A < 1e-14:
                continue  # vertical edge: only its end points can be touched
            we = wxy @ exy
            Bq = -2.0 * we * e[2] / ee
            C = (wxy ** 2).sum(1) - we ** 2 / ee - r * r
            disc = Bq * Bq - 4 * A * C
            ok = disc >= 0
            dz = (-Bq + np.sqrt(np.where(ok, disc, 0))) / (2 * A)
            tpar = (we + dz * e[2]) / ee
            ok &= (tpar >= 0) & (tpar <= 1)
            z = np.where(ok, p0[2] + dz, -np.inf)
            take(z, p0 + np.clip(tpar, 0, 1)[:, None] * e)
        for v in (a, b_, c):
            d2 = ((xy - v[:2]) ** 2).sum(1)
            ok = d2 <= r * r
            z = np.where(ok, v[2] + np.sqrt(np.where(ok, r * r - d2, 0)), -np.inf)
            take(z, np.broadcast_to(v, (N, 3)))
    if not np.all(np.isfinite(best)):
        raise MtcompError("drop_ball: points outside the surface")
    nrm = np.column_stack([xy, best]) - cpt
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    return best, nrm


def scallop_stepover(radius: float, scallop: float) -> float:
    """Stepover (mm) that leaves scallops of `scallop` mm between passes of a ball of `radius`
    on a flat surface: s = 2 sqrt(2 r h - h^2)."""
    if not 0 < scallop < radius:
        raise InputError(f"scallop height must be in (0, tool radius), got {scallop}", field="scallop")
    return 2.0 * math.sqrt(2.0 * radius * scallop - scallop ** 2)


def _refine_passes(xs: np.ndarray, ys: np.ndarray, tris: np.ndarray, r: float, tol: float,
                   rounds: int = 30) -> list[np.ndarray]:
    """Per pass y, the x positions where straight moves between consecutive ball centres stay
    within `tol` (mm, checked at segment midpoints) of the exact drop-cutter height."""
    x = np.tile(np.asarray(xs, float), len(ys))
    y = np.repeat(np.asarray(ys, float), len(xs))
    z = drop_ball(np.column_stack([x, y]), tris, r)[0]
    for _ in range(rounds):
        same = y[:-1] == y[1:]
        xm = 0.5 * (x[:-1] + x[1:])
        seg = np.nonzero(same)[0]
        zm = drop_ball(np.column_stack([xm[seg], y[seg]]), tris, r)[0]
        bad = np.abs(zm - 0.5 * (z[seg] + z[seg + 1])) > tol
        if not bad.any():
            break
        at = seg[bad] + 1
        x, y, z = np.insert(x, at, xm[seg][bad]), np.insert(y, at, y[seg][bad]), np.insert(z, at, zm[bad])
    cuts = np.nonzero(y[1:] != y[:-1])[0] + 1
    return np.split(x, cuts)


def pyramid_finishing(width: float = 3.45, angle: float = 164.81, tool: Tool | None = None,
                      stepover: float | None = None, scallop: float | None = None,
                      step: float = 0.01, tolerance: float = 1e-5, margin: float = 0.3,
                      safe: float = 0.5, feed: float = 300.0,
                      name: str = "pyramid-finishing") -> Toolpath:
    """Zig-zag raster finishing of paper 001's pyramid (and `margin` mm of the flat around it)
    with a vertical ball end mill: passes along x, `stepover` mm apart in y (or the stepover
    that leaves `scallop` mm on the flat), points every `step` mm along a pass.

    Ball-centre heights come from an exact drop-cutter, so every point's ball touches the CAD
    surface; segments are halved where the straight move between two points would leave the
    tool-offset surface by more than `tolerance` mm (over the ridges the chord would gouge, in
    the concave base corner it would leave material)."""
    from .layout import pyramid_height
    tool = tool or Tool("ball", radius=0.5, name="ball end mill R0.5")
    if tool.kind != "ball":
        raise InputError("pyramid finishing needs a ball end mill", field="tool")
    if (stepover is None) == (scallop is None):
        raise InputError("give exactly one of stepover or scallop", field="stepover")
    if scallop is not None:
        stepover = scallop_stepover(tool.radius, scallop)
    h = pyramid_height(width, angle)
    tris = pyramid_triangles(width, h, margin + tool.radius)
    lim = width / 2.0 + margin
    ys = np.linspace(-lim, lim, int(math.ceil(2 * lim / stepover)) + 1)
    xs = np.linspace(-lim, lim, int(math.ceil(2 * lim / step)) + 1)
    b = _Builder()
    I = np.eye(3)
    for k, (y, x) in enumerate(zip(ys, _refine_passes(xs, ys, tris, tool.radius, tolerance))):
        x = x if k % 2 == 0 else x[::-1]
        xy = np.column_stack([x, np.full_like(x, y)])
        zc, nrm = drop_ball(xy, tris, tool.radius)
        tip = np.column_stack([xy, zc - tool.radius])
        if k == 0:
            b.add(tip[0] + [0, 0, safe + h], I, RAPID)
        b.add(tip, I, FEED, normal=nrm)
    b.add(tip[-1] + [0, 0, safe + h], I, FEED)
    return b.build(tool, feed, name, width=width, angle=angle, height=h, stepover=stepover,
                   margin=margin)


# --------------------------------------------------------------------------- machine axes
def _rotary_seed(machine, R_target: np.ndarray, full: bool = False) -> np.ndarray:
    """Rotary angles (deg) whose nominal orientation is closest to R_target (3,3) on a 30 deg
    grid over the rotary axes' travel; the kinematics' solver refines them.  full: compare the
    whole tool frame even where the machine sets only the tool direction (a non-rotational
    tool: of the branches that reach the direction, the one nearest the rake orientation)."""
    from ..kinematics import forward
    rot = list(machine.rotary_indices)
    grids = []
    for i in rot:
        lo, hi = machine.axes[i].limits
        g = np.arange(-180.0, 180.0 + 1e-9, 30.0)
        grids.append(g[(g >= lo) & (g <= hi)])
    mesh = np.array(np.meshgrid(*grids, indexing="ij")).reshape(len(rot), -1).T
    q = np.zeros((len(mesh), machine.n_axes))
    q[:, rot] = mesh
    pose = forward(machine, q)
    if machine.n_rotary >= 3 or full:
        err = np.linalg.norm(pose.R - R_target[None], axis=(1, 2))
    else:
        err = np.linalg.norm(pose.v - (R_target @ np.asarray(machine.tool_axis))[None], axis=1)
    # Among near-equal candidates prefer small angles.
    score = err + 1e-3 * np.abs(mesh).sum(1) / 360.0
    return mesh[int(np.argmin(score))]


def _pinv_solve(machine, q0: np.ndarray, target_p: np.ndarray) -> np.ndarray:
    """Move the linear axes so that the nominal tool point reaches target_p for the given rotary
    angles: linear axes translate the tool point along their (possibly rotated) directions, so
    one least-squares step is exact."""
    from ..kinematics import forward
    lin = [i for i, a in enumerate(machine.axes) if not a.is_rotary]
    p0 = forward(machine, q0).p
    J = np.empty((len(q0), 3, len(lin)))
    for k, i in enumerate(lin):
        dq = q0.copy()
        dq[:, i] += 1.0
        J[:, :, k] = forward(machine, dq).p - p0
    q = q0.copy()
    q[:, lin] += np.einsum("nij,nj->ni", np.linalg.pinv(J), target_p - p0)
    return q


def to_axes(machine, path: Toolpath, errors=None) -> np.ndarray:
    """Machine axis commands (N, n_axes) in mm and deg that put the tool at the toolpath poses.

    errors None: nominal inverse kinematics; an ErrorSet: commands compensated through
    mtcomp.kinematics.compensate (the real machine with those errors then reaches the poses).
    Position and tool direction are matched on machines with one or two rotary axes, the full
    tool frame (the rake face of a non-rotational tool) with three.  Rotary angles follow the
    path by continuation: a seed from a coarse grid wherever the orientation jumps (between
    passes), the previous solution otherwise.
    """
    from ..kinematics import Pose, compensate
    n = len(path)
    tool_axis = np.asarray(machine.tool_axis, float)
    # The machine's tool frame: tool axis = machine.tool_axis, x_t = the rake direction of a
    # non-rotational tool (rake_direction); the toolpath's frames carry the same columns.
    M = machine_tool_frame(machine)
    R = path.R @ M.T
    rot = list(machine.rotary_indices)
    if not rot and np.max(np.abs(path.axis - tool_axis)) > 1e-9:
        raise MtcompError(f"machine {machine.name} has no rotary axis to tilt the tool")
    q0 = np.zeros((n, machine.n_axes))
    a = 0
    while rot and a < n:
        # Anchor: solve one point exactly from a grid seed, use it for the following points
        # until the orientation has turned by more than about 12 deg.
        qa = np.zeros((1, machine.n_axes))
        qa[0, rot] = _rotary_seed(machine, R[a], full=path.tool.kind == "vtool")
        qa = _pinv_solve(machine, qa, path.p[a:a + 1])
        qa = compensate(machine, Pose(path.p[a:a + 1], R[a:a + 1], machine.tool_axis), None, qa)
        d = np.linalg.norm(R[a:] - R[a], axis=(1, 2))
        jump = np.nonzero(d > 0.3)[0]
        b = a + (int(jump[0]) if jump.size else n - a)
        q0[a:b, rot] = qa[0, rot]
        a = b
    q0 = _pinv_solve(machine, q0, path.p)
    target = Pose(path.p, R, machine.tool_axis)
    q = compensate(machine, target, None, q0)
    if path.tool.kind == "vtool" and machine.n_rotary < 3:
        q = _align_rake(machine, q, R, path.p)
    q = _unwrap(machine, q)
    if errors is not None:
        q = compensate(machine, target, errors, q)
    return q


def rake_direction(machine) -> np.ndarray:
    """Unit direction (3,) the rake face of a non-rotational tool faces, in the machine's tool
    frame with every rotary axis at 0: ``rake_direction = [x, y, z]`` in the machine TOML's
    [machine] table if given; else machine x on machines with three rotary axes (they set the
    full tool frame), else the direction of the first rotary axis normal to the tool axis (a
    tilt of that axis then turns the tool about the feed, as paper 000's B-tilted grooves need),
    else machine x.  Always made normal to the tool axis."""
    ta = np.asarray(machine.tool_axis, float)
    given = machine.extra.get("rake_direction")
    if given is not None:
        d = np.asarray(given, float)
        if d.shape != (3,) or np.linalg.norm(np.cross(d, ta)) < 1e-6:
            raise InputError("rake_direction must be 3 numbers not along the tool axis",
                             field="machine.rake_direction")
    else:
        d = np.array([1.0, 0.0, 0.0]) if abs(ta[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
        if machine.n_rotary < 3:
            for i in machine.rotary_indices:
                u = np.asarray(machine.axes[i].direction, float)
                if abs(u @ ta) < 1e-9:
                    d = u
                    break
    d = d - (d @ ta) * ta
    return d / np.linalg.norm(d)


def machine_tool_frame(machine) -> np.ndarray:
    """(3,3) columns: rake direction, tool axis x rake, tool axis (machine tool frame)."""
    ta = np.asarray(machine.tool_axis, float)
    return _frames(rake_direction(machine)[None], ta[None])[0]


def rake_error(machine, path: Toolpath, q: np.ndarray, errors=None) -> np.ndarray:
    """Angle (N,) deg about the tool axis between the rake direction the machine reaches with
    commands q and the toolpath's x_t (the feed direction for a V tool); NaN where the tool
    axis itself is off by more than 1 deg."""
    from ..kinematics import forward
    pose = forward(machine, q, errors)
    M = machine_tool_frame(machine)
    got = np.einsum("nij,j->ni", pose.R, M[:, 0])
    want, v = path.R[:, :, 0], path.axis
    ang = np.degrees(np.arctan2(np.einsum("ni,ni->n", np.cross(got, want), v),
                                np.einsum("ni,ni->n", got, want)))
    off = np.einsum("ni,ni->n", pose.v, v) < math.cos(math.radians(1.0))
    return np.where(off, np.nan, ang)


def _align_rake(machine, q: np.ndarray, R_target: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Machines that set only the tool direction (fewer than three rotary axes): where a rotary
    axis turns the workpiece (or tool) about the tool axis itself (B = 0 on a B-C table, the
    pole), that axis is free for the direction; turn it so the rake face faces the feed, then
    move the linear axes to keep the tool point.  Elsewhere the direction fixes the rotary
    angles and the rake stays where the kinematics puts it (see rake_error)."""
    from ..kinematics import forward
    M = machine_tool_frame(machine)
    q = q.copy()

    def state(qq):
        pose = forward(machine, qq)
        got = np.einsum("nij,j->ni", pose.R, M[:, 0])
        want = np.einsum("nij,j->ni", R_target, M[:, 0])
        v = pose.v
        phi = np.arctan2(np.einsum("ni,ni->n", np.cross(got, want), v), np.einsum("ni,ni->n", got, want))
        return v, phi

    v0, phi = state(q)
    done = np.zeros(len(q), bool)
    for i in machine.rotary_indices:
        d = 1e-3  # deg
        qd = q.copy()
        qd[:, i] += d
        v1, phi1 = state(qd)
        spin = -(phi1 - phi) / math.radians(d)          # d(rake angle)/d(q_i), 1 or -1 at a pole
        still = np.linalg.norm(v1 - v0, axis=1) < 1e-9 * d
        k = still & (np.abs(np.abs(spin) - 1) < 1e-6) & ~done & (np.abs(phi) > 1e-12)
        if k.any():
            q[k, i] += np.degrees(phi[k]) / spin[k]
            done |= k
    if done.any():
        q[done] = _pinv_solve(machine, q[done], p[done])
    return q


def _unwrap(machine, q: np.ndarray) -> np.ndarray:
    """Rotary angles made continuous along the path (no 360 deg turn between neighbours that
    stand for the same orientation), then shifted by the whole number of turns that keeps them
    closest to zero; left as solved if that does not fit the travel."""
    q = q.copy()
    for i in machine.rotary_indices:
        lo, hi = machine.axes[i].limits
        u = np.degrees(np.unwrap(np.radians(q[:, i])))
        turns = np.arange(-3, 4)
        worst = [np.max(np.abs(u + 360.0 * k)) for k in turns]
        u = u + 360.0 * turns[int(np.argmin(worst))]
        if np.all((u >= lo + 1e-6) & (u <= hi - 1e-6)):
            q[:, i] = u
    return q


# ------------------------------------------------------------------------------ safe links
def retract_axis(machine) -> int:
    """Index of the linear axis that moves the tool away from the workpiece along the tool
    axis (rotary axes at 0): the retract axis of the links between passes."""
    ta = np.asarray(machine.tool_axis, float)
    for i, a in enumerate(machine.axes):
        if not a.is_rotary and abs(abs(np.asarray(a.direction, float) @ ta) - 1) < 1e-9:
            return i
    raise MtcompError(f"machine {machine.name}: no linear axis along the tool axis to retract")


def link_safely(machine, path: Toolpath, q: np.ndarray, stock=None, clearance: float = 0.2,
                step: float = 0.005, errors=None) -> tuple[Toolpath, np.ndarray]:
    """Rapid links that keep `clearance` mm from the stock, rotary moves at a safe height.

    Every rapid block that turns a rotary axis, or whose straight axis interpolation would come
    closer than `clearance` to the stock, becomes: retract along the tool axis (the retract
    axis alone), turn the rotary axes there, move the other linear axes, then the original
    rapid down to the approach point.  The retract height is the lowest of the block's two
    heights raised by 0, 1, 2, 5, 10 ... mm at which all four moves keep the clearance
    (checked with :func:`mtcomp.verify.sweep`, tool radius included); without a stock, the
    top of the retract axis' travel less 1 mm.  Returns the new toolpath (inserted poses:
    motion RAPID, nominal forward pose, no contact normal) and its axis commands."""
    from ..kinematics import forward
    from ..verify import sweep
    q = np.asarray(q, float)
    z = retract_axis(machine)
    rot = list(machine.rotary_indices)
    res = machine.resolutions
    lo, hi = machine.axes[z].limits
    sign = 1.0 if np.asarray(machine.axes[z].direction, float) @ np.asarray(machine.tool_axis, float) > 0 else -1.0
    r = path.tool.radius if path.tool.kind in ("ball", "probe") else 0.0

    def clear(qs) -> bool:
        if stock is None:
            return True
        pts, _, _ = sweep(machine, qs, np.arange(1, len(qs)), errors, r, step)
        return bool(np.all(stock.distance(pts) - r - step / 2 >= clearance))

    inserts = {}
    for i in np.nonzero(path.motion == RAPID)[0]:
        if i == 0:
            continue
        a, b = q[i - 1], q[i]
        turns = bool(rot) and np.any(np.abs(b[rot] - a[rot]) > res[rot] / 2)
        if not turns and clear(np.array([a, b])):
            continue
        base = max(a[z], b[z]) if sign > 0 else min(a[z], b[z])
        heights = ([hi - 1.0 if sign > 0 else lo + 1.0] if stock is None else
                   [base + sign * h for h in (0, 1, 2, 5, 10, 20, 50, 100, 200)])
        for h in heights:
            if not lo <= h <= hi:
                continue
            up, turn, over = a.copy(), a.copy(), b.copy()
            up[z] = turn[z] = over[z] = h
            turn[rot] = b[rot]
            seq = np.array([a, up, turn, over, b])
            if clear(seq):
                inserts[int(i)] = seq[1:4]
                break
        else:
            raise MtcompError(f"pose {i}: no retract height within the travel of "
                              f"{machine.axes[z].name} keeps {clearance:g} mm from the stock "
                              "for this rapid link")
    if not inserts:
        return path, q
    M = machine_tool_frame(machine)
    b = _Builder()
    qs = []
    last = 0
    for i in sorted(inserts):
        sl = slice(last, i)
        b.add(path.p[sl], path.R[sl], 0)
        b.m[-1] = path.motion[sl].copy()
        b.n[-1] = path.normal[sl]
        qs.append(q[sl])
        pose = forward(machine, inserts[i])
        b.add(pose.p, pose.R @ M, RAPID)
        qs.append(inserts[i])
        last = i
    b.add(path.p[last:], path.R[last:], 0)
    b.m[-1] = path.motion[last:].copy()
    b.n[-1] = path.normal[last:]
    qs.append(q[last:])
    return b.build(path.tool, path.feed, path.name, **path.meta), np.vstack(qs)
