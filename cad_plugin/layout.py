"""Layouts of the calibration features and of the papers' parts, and their closed-form
geometry.  Pure Python and numpy (no CadQuery): toolpaths and checks use these without loading
the CAD kernel.  Units mm and deg; workpiece frame with the top face at z = 0, material below.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from .._io import InputError


def vgroove_section(angle: float, depth: float, tilt: float = 0.0) -> tuple[float, float]:
    """Half-widths (left, right) at the surface of a V-groove section, mm.

    The tool's included angle is `angle` (deg), its edge is `depth` below the surface and the
    tool is turned by `tilt` (deg) about the feed direction (right-hand sense).  "Left" is
    z x feed.  A tilted tool cuts an asymmetric V whose flanks make angle/2 -/+ tilt with
    the surface normal.
    """
    half = math.radians(angle) / 2.0
    t = math.radians(tilt)
    if not 0.0 < angle < 180.0:
        raise InputError(f"included angle must be in (0, 180) deg, got {angle}", field="angle")
    if depth <= 0.0:
        raise InputError(f"depth must be > 0 mm, got {depth}", field="depth")
    if half + abs(t) >= math.pi / 2:
        raise InputError(f"|tilt| must be below 90 - angle/2 = {90 - angle / 2} deg, got {tilt}",
                         field="tilt")
    # Rotating the tool by +t about the feed u turns its axis towards -left (u x z = -left).
    return depth * math.tan(half + t), depth * math.tan(half - t)


def pyramid_height(width: float, angle: float) -> float:
    """Height (mm) of a square pyramid of base `width` whose opposite slopes meet at `angle` deg.

    The angle between opposite slopes, measured through the material across the apex, is
    180 deg - 2 beta with beta the slope inclination: h = width/2 * tan(beta).
    """
    if not 0.0 < angle < 180.0:
        raise InputError(f"slope angle must be in (0, 180) deg, got {angle}", field="angle")
    beta = math.radians((180.0 - angle) / 2.0)
    return width / 2.0 * math.tan(beta)



@dataclass(frozen=True)
class GroovePlateLayout:
    """Groove calibration plate after paper 000 (tool setting of a non-rotational V tool).

    Plate `size` x `size` x `thickness` (brass), grooves `depth` deep cut by a tool of included
    `angle`; lengths in mm, angles in deg.  Three patterns:

    * A: two grooves of `length` sharing the start point `a_origin`, along +x and +y: the shape
      of the A test's pattern.  The A test itself needs the tool along the A axis, cutting at
      A = 0 and again at A = 180 deg on a face normal to X (mtcomp.setting.tool_plan, see
      features.plan_plate); with no setting error both cuts coincide, so the nominal part
      carries one pair;
    * C: an equilateral triangle of side `c_side` centred on `c_centre`, one side per C position
      (0, 120, 240 deg);
    * B: parallel grooves along +y of `length`, at x = `b_x` offsets from `b_origin`, cut with the
      tool turned by `b_tilts` about the feed direction (B = 0, theta2, theta3).
    """
    size: float = 20.0
    thickness: float = 3.0
    depth: float = 0.05
    angle: float = 90.0
    length: float = 4.0
    a_origin: tuple[float, float] = (-8.0, 2.0)
    c_centre: tuple[float, float] = (4.5, 4.5)
    c_side: float = 6.0
    b_origin: tuple[float, float] = (0.0, -8.0)
    b_x: tuple[float, ...] = (-4.0, 0.0, 4.0)
    b_tilts: tuple[float, ...] = (0.0, 30.0, -30.0)

    def grooves(self) -> list[tuple[np.ndarray, float]]:
        """Every straight pass as (2x2 array of start/end xy, tilt deg)."""
        out = []
        a = np.asarray(self.a_origin, float)
        out.append((np.array([a, a + [self.length, 0.0]]), 0.0))
        out.append((np.array([a, a + [0.0, self.length]]), 0.0))
        c = np.asarray(self.c_centre, float)
        r = self.c_side / math.sqrt(3.0)
        corners = [c + r * np.array([math.cos(math.radians(90 + 120 * i)),
                                     math.sin(math.radians(90 + 120 * i))]) for i in range(3)]
        for i in range(3):
            out.append((np.array([corners[i], corners[(i + 1) % 3]]), 0.0))
        b = np.asarray(self.b_origin, float)
        for dx, tilt in zip(self.b_x, self.b_tilts):
            p = b + [dx, 0.0]
            out.append((np.array([p, p + [0.0, self.length]]), float(tilt)))
        return out


@dataclass(frozen=True)
class BowlBlankLayout:
    """Bowl blank after paper 001: three bowls cut by a ball end mill (radius R2 in the paper).

    Bowl centres S1, S2, S3 (xy, mm) define the workpiece frame: S1 origin side, S1S2 along x,
    S1S3 along y.  Defaults: 20 x 20 x 5 mm aluminium plate, bowls 1 mm deep.
    """
    size: float = 20.0
    thickness: float = 5.0
    bowl_radius: float = 2.0
    bowl_depth: float = 1.0
    centres: tuple[tuple[float, float], ...] = ((-7.0, -7.0), (7.0, -7.0), (-7.0, 7.0))


@dataclass(frozen=True)
class PyramidLayout:
    """Paper 001's pyramid: base `width` (3450 um), `angle` (164.81 deg) between opposite
    slopes, on the bowl blank's top face at its centre.  Height follows from the angle."""
    width: float = 3.45
    angle: float = 164.81
    blank: BowlBlankLayout = field(default_factory=BowlBlankLayout)

    @property
    def height(self) -> float:
        return pyramid_height(self.width, self.angle)


@dataclass(frozen=True)
class GratingLayout:
    """Concave reflection grating after paper 000: V-microgrooves on a concave sphere.

    A cylindrical blank of `aperture_radius` whose top is the concave sphere of
    `sphere_radius` (lowest point at the origin), `height` of material below that point.
    `n_grooves` grooves `pitch` apart at the lowest point (angular pitch pitch/R about the x
    axis through the sphere centre), each spanning `span` deg of its great circle, `depth` deep,
    tool included `angle` deg.  Lengths in mm.
    """
    sphere_radius: float = 20.0
    aperture_radius: float = 5.0
    height: float = 3.0
    n_grooves: int = 9
    pitch: float = 0.5
    span: float = 16.0
    depth: float = 0.02
    angle: float = 90.0

    @property
    def psi(self) -> np.ndarray:
        """Angles of the groove planes about the x axis through the sphere centre, deg."""
        k = np.arange(self.n_grooves) - (self.n_grooves - 1) / 2.0
        return np.degrees(k * self.pitch / self.sphere_radius)

    @property
    def rim_height(self) -> float:
        r, a = self.sphere_radius, self.aperture_radius
        return r - math.sqrt(r * r - a * a)
