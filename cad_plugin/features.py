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

import cadquery as cq
import numpy as np

from .._io import InputError
from ..kinematics import axis_rotation
from .export import export_step, export_stl  # noqa: F401  (re-exported for convenience)
from .layout import (BowlBlankLayout, GratingLayout, GroovePlateLayout, PyramidLayout,  # noqa: F401
                     pyramid_height, vgroove_section)

# Material left above the surface by the cutting bodies (a cutter must pass the surface, not
# touch it, or the boolean leaves slivers).  Not part of any analytic volume.
_CLEAR = 0.5

__all__ = [
    "vgroove", "bowl", "pyramid", "sphere_vgrooves", "register",
    "groove_plate", "bowl_blank", "pyramid_part", "concave_grating",
    "GroovePlateLayout", "BowlBlankLayout", "PyramidLayout", "GratingLayout",
    "vgroove_section", "pyramid_height", "volume", "plan_plate", "plan_tilts",
    "export_step", "export_stl",
]


# ---------------------------------------------------------------------------------- helpers
def _vec(p) -> cq.Vector:
    p = [float(c) for c in p]
    if len(p) == 2:
        p.append(0.0)
    return cq.Vector(*p)


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
        # Profile in the meridional plane at the groove's start, turned by -span/2 about n;
        # the revolution then sweeps +span about n.
        d0 = axis_rotation(n, math.radians(-span / 2.0)) @ d
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


def plan_tilts(plan) -> list[float]:
    """Tilt (deg) of the tool about the cutting direction for every groove of a tool-setting
    plan (mtcomp.setting.tool_plan.Plan), from the nominal kinematics of the plan's machine at
    the groove's (A, B, C): the angle from the face normal n to the tool axis v, positive
    towards d x n (d the cutting direction), as in tool_plan's CutGroove."""
    from ..kinematics import forward
    from ..machine import load_machine
    m = load_machine(plan.machine)
    tilts = []
    for g in plan.grooves:
        q = np.zeros((1, m.n_axes))
        for k, name in enumerate("ABC"):
            if name in m.axis_names:
                q[0, m.index(name)] = g.angles[k]
        v = forward(m, q).v[0]
        face = plan.face_of(g)
        n = np.asarray(face.normal, float)
        du, dv = g.direction
        d = du * np.asarray(face.eu, float) + dv * np.asarray(face.ev, float)
        tilts.append(math.degrees(math.atan2(v @ np.cross(d, n), v @ n)))
    return tilts


def plan_plate(plan, face: str = "top", thickness: float = 3.0) -> cq.Workplane:
    """Plate carrying the grooves that a tool-setting plan (mtcomp.setting.tool_plan) cuts on one
    of its faces ("top" or "side"), as the ideal machine cuts them: the plate is the plan's
    plate size centred on the face origin, `thickness` mm behind the face, in the workpiece
    frame.  Passes that coincide nominally (A = 0 and A = 180 deg) are cut once."""
    f = plan.faces[face]
    w, h = plan.options.plate
    grooves = [(g, t) for g, t in zip(plan.grooves, plan_tilts(plan)) if g.face == face]
    if not grooves:
        raise InputError(f"the plan has no grooves on face {face!r}", field="face")
    plane = cq.Plane(origin=tuple(f.origin), xDir=tuple(f.eu), normal=tuple(f.normal))
    wp = (cq.Workplane(plane).box(w, h, thickness, centered=(True, True, False))
          .translate(tuple(-thickness * np.asarray(f.normal, float))))
    wp = cq.Workplane(plane).add(wp.val()).newObject([])
    seen = set()
    for g, tilt in grooves:
        key = (tuple(np.round(g.start, 9)), tuple(np.round(g.end, 9)), round(tilt, 9), g.depth)
        if key in seen:
            continue
        seen.add(key)
        cut = vgroove(wp, [g.start, g.end], g.depth, plan.options.tip_angle, tilt, clean=False)
        wp = cq.Workplane(plane).add(cut.val()).newObject([])
    return _single(wp.newObject([wp.findSolid().clean()]))


def bowl_blank(layout: BowlBlankLayout = BowlBlankLayout()) -> cq.Workplane:
    """Plate with the three reference bowls of paper 001."""
    wp = _plate(layout.size, layout.size, layout.thickness)
    return _single(bowl(wp.pushPoints(list(layout.centres)), layout.bowl_radius,
                        layout.bowl_depth))


def pyramid_part(layout: PyramidLayout = PyramidLayout()) -> cq.Workplane:
    """Aluminium blank with the three reference bowls and the pyramid at its centre."""
    return _single(pyramid(_context(bowl_blank(layout.blank).val()), layout.width, layout.angle))


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
