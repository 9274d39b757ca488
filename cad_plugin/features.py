"""CadQuery features for calibration and for the parts of papers 000 and 001.

Every feature is a plain function taking a ``cadquery.Workplane`` first and returning
``self.newObject([...])`` (CadQuery's plugin convention).  Importing this module attaches them
to ``cq.Workplane`` as methods (``wp.bowl(2, 1)``); they work with ``Workplane.invoke`` too:
``wp.invoke(lambda w: bowl(w, 2, 1))`` (invoke inspects
``__code__``, so it takes a function or lambda, not a functools.partial).

Frames and units: mm and deg.  Features are placed in the local coordinates of the current
workplane; the surface to cut into is the workplane plane itself (local z = 0) and material is
on the local -z side.  The part builders (:func:`groove_plate`, :func:`bowl_blank`,
:func:`pyramid_part`, :func:`concave_grating`) build in the workpiece frame: top face z = 0,
origin at the centre of the top face, material below.

Importing this module imports cadquery (about 3 s): keep it out of light code paths.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import cadquery as cq
import numpy as np

from .._io import InputError

# Material left above the surface by the cutting bodies (a cutter must pass the surface, not
# touch it, or the boolean leaves slivers).  Not part of any analytic volume.
_CLEAR = 0.5

__all__ = [
    "vgroove", "bowl", "pyramid", "sphere_vgrooves", "register",
    "groove_plate", "bowl_blank", "pyramid_part", "concave_grating",
    "GroovePlateLayout", "BowlBlankLayout", "PyramidLayout", "GratingLayout",
    "vgroove_section", "pyramid_height", "volume",
]


# ---------------------------------------------------------------------------------- helpers
def _vec(p) -> cq.Vector:
    p = [float(c) for c in p]
    if len(p) == 2:
        p.append(0.0)
    return cq.Vector(*p)


def _place(shape: cq.Shape, plane: cq.Plane) -> cq.Shape:
    """Move a shape built in local workplane coordinates into global coordinates."""
    return shape.moved(plane.location)


def _polygon_face(points) -> cq.Face:
    return cq.Face.makeFromWires(cq.Wire.makePolygon([_vec(p) for p in points], close=True))


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


# -------------------------------------------------------------------------- plugin functions
def vgroove(self: cq.Workplane, path, depth: float, angle: float = 90.0, tilt: float = 0.0,
            clean: bool = True) -> cq.Workplane:
    """Cut a V-groove along a polyline `path` into the solid on the stack.

    path: sequence of (x, y) points in the workplane (mm); each segment is cut as one straight
    pass of a non-rotational V tool (plunge to `depth`, feed, retract), so the groove ends are
    flat walls normal to the feed (the tool's rake face) and consecutive segments overlap at
    their common point.  angle: included angle of the tool, deg; tilt: rotation of the tool
    about the feed direction, deg (a B tilt when feeding along Y).  Points on the stack shift
    the whole path (one copy per point); with no points the path is used as given.
    """
    pts = np.asarray(path, dtype=float)
    if pts.ndim != 2 or pts.shape[0] < 2 or pts.shape[1] not in (2, 3):
        raise InputError("path must be at least two (x, y) points", field="path")
    left_w, right_w = vgroove_section(angle, depth, tilt)
    k = (depth + _CLEAR) / depth  # flanks extended up to _CLEAR above the surface
    prisms = []
    for p0, p1 in zip(pts[:-1, :2], pts[1:, :2]):
        d = p1 - p0
        length = float(np.hypot(*d))
        if length <= 0.0:
            raise InputError("path has two equal consecutive points", field="path")
        u = d / length
        left = np.array([-u[1], u[0]])
        apex = np.array([p0[0], p0[1], -depth])
        a = np.array([*(p0 + left * left_w * k), _CLEAR])
        b = np.array([*(p0 - left * right_w * k), _CLEAR])
        wire = cq.Wire.makePolygon([_vec(apex), _vec(a), _vec(b)], close=True)
        prisms.append(cq.Solid.extrudeLinear(wire, [], cq.Vector(u[0] * length, u[1] * length, 0)))
    tool = prisms[0].fuse(*prisms[1:]) if len(prisms) > 1 else prisms[0]
    return self.cutEach(lambda loc: tool.moved(loc), useLocalCoords=True, clean=clean)


def bowl(self: cq.Workplane, radius: float, depth: float, clean: bool = True) -> cq.Workplane:
    """Cut a spherical bowl (a ball end mill of `radius` plunged `depth` deep) at each stack point.

    Requires depth <= radius (deeper plunges cut with the shank too).  Volume pi d^2 (3R - d)/3.
    """
    if radius <= 0 or not 0 < depth <= radius:
        raise InputError(f"bowl needs 0 < depth <= radius, got radius {radius}, depth {depth}",
                         field="depth")
    ball = cq.Solid.makeSphere(radius, cq.Vector(0, 0, radius - depth), angleDegrees1=-90,
                               angleDegrees2=90)
    return self.cutEach(lambda loc: ball.moved(loc), useLocalCoords=True, clean=clean)


def _pyramid_solid(width: float, height: float) -> cq.Solid:
    w = width / 2.0
    base = [cq.Vector(-w, -w, 0), cq.Vector(w, -w, 0), cq.Vector(w, w, 0), cq.Vector(-w, w, 0)]
    apex = cq.Vector(0, 0, height)
    faces = [cq.Face.makeFromWires(cq.Wire.makePolygon(base[::-1], close=True))]
    for i in range(4):
        faces.append(cq.Face.makeFromWires(
            cq.Wire.makePolygon([base[i], base[(i + 1) % 4], apex], close=True)))
    return cq.Solid.makeSolid(cq.Shell.makeShell(faces)).fix()


def pyramid(self: cq.Workplane, width: float, angle: float, clean: bool = True) -> cq.Workplane:
    """Add a square pyramid (base `width` mm, `angle` deg between opposite slopes) at each point.

    The base lies on the workplane, edges along the local x and y axes, apex on local +z.
    Combined with the solid on the stack if there is one.
    """
    if width <= 0:
        raise InputError(f"pyramid width must be > 0 mm, got {width}", field="width")
    solid = _pyramid_solid(width, pyramid_height(width, angle))
    return self.eachpoint(lambda loc: solid.moved(loc), useLocalCoordinates=True,
                          combine=True, clean=clean)


def sphere_vgrooves(self: cq.Workplane, sphere_radius: float, psi, span: float, depth: float,
                    angle: float = 90.0, clean: bool = True) -> cq.Workplane:
    """Cut V-microgrooves into a concave sphere whose centre is at local (0, 0, sphere_radius).

    Each groove is an arc of a great circle in the plane through the centre that contains the
    local x axis, turned by psi_k (deg) about it; along the groove the tool stays normal to the
    surface (its axis through the sphere centre), so the groove is a V section of `depth` and
    included `angle` revolved about the plane's normal.  span: the groove's angular length
    (deg) about that normal, centred on the lowest point of the arc.
    """
    rs = float(sphere_radius)
    half = math.radians(angle) / 2.0
    vgroove_section(angle, depth)  # validates angle and depth
    centre = np.array([0.0, 0.0, rs])
    tools = []
    for p in np.atleast_1d(np.asarray(psi, dtype=float)):
        s, c = math.sin(math.radians(p)), math.cos(math.radians(p))
        d = np.array([0.0, s, -c])          # from the centre to the groove's mid point
        n = np.array([0.0, c, s])           # normal of the groove plane = revolution axis
        # Profile in the meridional plane at the groove's start, turned by -span/2 about n
        # (Rodrigues with n x d = -x); the revolution then sweeps +span about n.
        t0 = math.radians(-span / 2.0)
        d0 = math.cos(t0) * d - math.sin(t0) * np.array([1.0, 0.0, 0.0])
        apex = centre + (rs + depth) * d0
        top = centre + (rs - _CLEAR) * d0
        w = (depth + _CLEAR) * math.tan(half)
        wire = cq.Wire.makePolygon([_vec(apex), _vec(top + w * n), _vec(top - w * n)], close=True)
        tools.append(cq.Solid.revolve(wire, [], span, _vec(centre), _vec(centre + n)))
    tool = tools[0].fuse(*tools[1:]) if len(tools) > 1 else tools[0]
    return self.cutEach(lambda loc: tool.moved(loc), useLocalCoords=True, clean=clean)


_PLUGINS = {"vgroove": vgroove, "bowl": bowl, "pyramid": pyramid,
            "sphere_vgrooves": sphere_vgrooves}


def register() -> None:
    """Attach the plugin functions to ``cq.Workplane`` (done once on import)."""
    for name, fn in _PLUGINS.items():
        setattr(cq.Workplane, name, fn)


register()


def volume(shape, eps: float = 1e-9) -> float:
    """Volume of a shape or of a workplane's first object, mm^3, by adaptive integration.

    ``Shape.Volume()`` integrates with a fixed Gauss order: on revolved (conical) faces such as
    the grating's grooves it is off by several 1e-4 mm^3; the adaptive rule with relative `eps`
    is exact to rounding on planar, spherical and conical faces.
    """
    from OCP.BRepGProp import BRepGProp
    from OCP.GProp import GProp_GProps
    if isinstance(shape, cq.Workplane):
        shape = shape.val()
    props = GProp_GProps()
    BRepGProp.VolumeProperties_s(shape.wrapped, props, eps)
    return props.Mass()


# ------------------------------------------------------------------------------ part layouts
def _plate(size_x: float, size_y: float, thickness: float) -> cq.Workplane:
    """Plate with its top face at z = 0, centred on the origin, workplane on the top face."""
    return (cq.Workplane("XY").box(size_x, size_y, thickness, centered=(True, True, False))
            .translate((0, 0, -thickness)).faces(">Z").workplane(centerOption="ProjectedOrigin",
                                                                  origin=(0, 0, 0)))


@dataclass(frozen=True)
class GroovePlateLayout:
    """Groove calibration plate after paper 000 (tool setting of a non-rotational V tool).

    Plate `size` x `size` x `thickness` (brass), grooves `depth` deep cut by a tool of included
    `angle`; lengths in mm, angles in deg.  Three patterns:

    * A: two grooves of `length` sharing the start point `a_origin`, along +x and +y (cut once
      at A = 0 and once at A = 180 deg; nominally they coincide, a tool setting error splits them);
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


def _single(wp: cq.Workplane) -> cq.Workplane:
    """Workplane (XY, origin) with the part as its only object, a Solid when it is one."""
    shape = wp.val()
    solids = shape.Solids()
    return cq.Workplane("XY").add(solids[0] if len(solids) == 1 else shape)


def _context(shape: cq.Shape) -> cq.Workplane:
    """XY workplane at the origin with `shape` as context solid and an empty stack, so that
    the next feature cuts at the local origin instead of at the shape's centre."""
    return cq.Workplane("XY").add(shape).newObject([])


def groove_plate(layout: GroovePlateLayout = GroovePlateLayout()) -> cq.Workplane:
    """The groove calibration plate of paper 000 (see :class:`GroovePlateLayout`)."""
    wp = _plate(layout.size, layout.size, layout.thickness)
    for seg, tilt in layout.grooves():
        wp = _context(vgroove(wp, seg, layout.depth, layout.angle, tilt, clean=False).val())
    return _single(wp.newObject([wp.findSolid().clean()]))


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


def bowl_blank(layout: BowlBlankLayout = BowlBlankLayout()) -> cq.Workplane:
    """Plate with the three reference bowls of paper 001."""
    wp = _plate(layout.size, layout.size, layout.thickness)
    return _single(bowl(wp.pushPoints(list(layout.centres)), layout.bowl_radius,
                        layout.bowl_depth))


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


def pyramid_part(layout: PyramidLayout = PyramidLayout()) -> cq.Workplane:
    """Aluminium blank with the three reference bowls and the pyramid at its centre."""
    return _single(pyramid(_context(bowl_blank(layout.blank).val()), layout.width, layout.angle))


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


def concave_grating(layout: GratingLayout = GratingLayout()) -> cq.Workplane:
    """Cylindrical blank with a concave spherical top carrying V-microgrooves."""
    g = layout
    if g.aperture_radius >= g.sphere_radius:
        raise InputError("aperture radius must be below the sphere radius", field="aperture_radius")
    top = g.rim_height + _CLEAR  # above the rim: the sphere removes everything there
    blank = (cq.Workplane("XY").circle(g.aperture_radius).extrude(g.height + top)
             .translate((0, 0, -g.height)))
    ball = cq.Solid.makeSphere(g.sphere_radius, cq.Vector(0, 0, g.sphere_radius),
                               angleDegrees1=-90, angleDegrees2=90)
    wp = _context(blank.cut(ball).val())
    return _single(sphere_vgrooves(wp, g.sphere_radius, g.psi, g.span, g.depth, g.angle))
