"""CadQuery features: exact volumes against independent analytic values, plugin use, export."""
import math
import struct
import subprocess
import sys

import numpy as np
import pytest

cq = pytest.importorskip("cadquery")
from mtcomp import MtcompError  # noqa: E402
from mtcomp.cad_plugin import features as F  # noqa: E402
from mtcomp.cad_plugin.export import export_step, export_stl, import_step  # noqa: E402

REL = 1e-9


def cap(R, d):
    """Volume of a spherical cap of height d on a sphere of radius R."""
    return math.pi * d * d * (3 * R - d) / 3


# ------------------------------------------------------------- independent 2-D geometry
def clip(subject, clipper):
    """Sutherland-Hodgman: convex polygon `subject` clipped by convex CCW polygon `clipper`."""
    out = list(subject)
    for i in range(len(clipper)):
        a, b = np.asarray(clipper[i]), np.asarray(clipper[(i + 1) % len(clipper)])
        inp, out = out, []
        if not inp:
            break

        def inside(p):
            return (b[0] - a[0]) * (p[1] - a[1]) - (b[1] - a[1]) * (p[0] - a[0]) >= 0

        def cut(p, q):
            d1 = (b[0] - a[0]) * (p[1] - a[1]) - (b[1] - a[1]) * (p[0] - a[0])
            d2 = (b[0] - a[0]) * (q[1] - a[1]) - (b[1] - a[1]) * (q[0] - a[0])
            return p + (q - p) * (d1 / (d1 - d2))

        for j in range(len(inp)):
            p, q = np.asarray(inp[j - 1]), np.asarray(inp[j])
            if inside(q):
                if not inside(p):
                    out.append(cut(p, q))
                out.append(q)
            elif inside(p):
                out.append(cut(p, q))
    return out


def area(poly):
    if len(poly) < 3:
        return 0.0
    p = np.asarray(poly)
    return 0.5 * abs(np.dot(p[:, 0], np.roll(p[:, 1], -1)) - np.dot(p[:, 1], np.roll(p[:, 0], -1)))


def groove_rectangles(layout, z):
    """Horizontal sections (CCW rectangles) of every groove pass at height z (-depth <= z <= 0)."""
    D, half = layout.depth, math.radians(layout.angle) / 2
    rects = []
    for seg, tilt in layout.grooves():
        t = math.radians(tilt)
        p0, p1 = seg
        u = (p1 - p0) / np.linalg.norm(p1 - p0)
        left = np.array([-u[1], u[0]])
        # Flanks make half -/+ tilt with the vertical; the left flank leans by half + tilt.
        wl, wr = (D + z) * math.tan(half + t), (D + z) * math.tan(half - t)
        rects.append([p0 - wr * left, p1 - wr * left, p1 + wl * left, p0 + wl * left])
    return rects


def union_area(rects):
    """Area of a union of convex polygons with no triple overlaps (inclusion-exclusion)."""
    total = sum(area(r) for r in rects)
    for i in range(len(rects)):
        for j in range(i + 1, len(rects)):
            total -= area(clip(rects[i], rects[j]))
    return total


def test_groove_plate_volume_is_exact():
    L = F.GroovePlateLayout()
    solid = F.groove_plate(L).val()
    assert isinstance(solid, cq.Solid) and solid.isValid()
    # Each section area is a quadratic in (D + z): 3-point Gauss-Legendre integrates it exactly.
    x, w = np.polynomial.legendre.leggauss(3)
    zs = -L.depth / 2 + x * L.depth / 2
    removed = sum(wi * union_area(groove_rectangles(L, z)) for z, wi in zip(zs, w)) * L.depth / 2
    # The corners of pattern C and the shared start of pattern A do overlap.
    assert removed < sum(area(r) for r in groove_rectangles(L, 0.0)) * L.depth / 2 - 1e-6
    assert F.volume(solid) == pytest.approx(L.size**2 * L.thickness - removed, rel=REL)


def test_vgroove_tilted_section_is_asymmetric():
    left, right = F.vgroove_section(90.0, 0.05, 30.0)
    assert left == pytest.approx(0.05 * math.tan(math.radians(75)))
    assert right == pytest.approx(0.05 * math.tan(math.radians(15)))
    with pytest.raises(ValueError):
        F.vgroove_section(90.0, 0.05, 45.0)


def test_bowl_blank_volume_is_exact():
    L = F.BowlBlankLayout()
    solid = F.bowl_blank(L).val()
    expected = L.size**2 * L.thickness - 3 * cap(L.bowl_radius, L.bowl_depth)
    assert F.volume(solid) == pytest.approx(expected, rel=REL)


def test_pyramid_height_from_paper_001_angle():
    # 164.81 deg between opposite slopes -> slopes inclined 7.595 deg; h = 1.725 tan(7.595 deg).
    h = F.pyramid_height(3.45, 164.81)
    assert h == pytest.approx(1.725 * math.tan(math.radians(7.595)), rel=1e-15)
    assert 180 - 2 * math.degrees(math.atan2(h, 1.725)) == pytest.approx(164.81, abs=1e-12)


def test_pyramid_part_volume_is_exact():
    L = F.PyramidLayout()
    solid = F.pyramid_part(L).val()
    B = L.blank
    h = F.pyramid_height(L.width, L.angle)
    expected = B.size**2 * B.thickness + L.width**2 * h / 3 - 3 * cap(B.bowl_radius, B.bowl_depth)
    assert F.volume(solid) == pytest.approx(expected, rel=REL)
    bb = solid.BoundingBox()
    assert bb.zmax == pytest.approx(h, abs=1e-12)


def groove_on_sphere_volume(Rs, D, angle, span_deg):
    """Pappus: span * integral of rho over the section {|h| <= (Rs+D-rho) T, rho^2+h^2 >= Rs^2}."""
    T = math.tan(math.radians(angle) / 2)
    a, b = 1 + 1 / T**2, -2 * (Rs + D) / T
    c = (Rs + D) ** 2 - Rs**2
    hs = (-b - math.sqrt(b * b - 4 * a * c)) / (2 * a)  # flank meets the sphere
    P = Rs + D

    # integrand 0.5 * ((P - h/T)^2 - Rs^2 + h^2), antiderivative:
    def F_(h):
        return 0.5 * (-(T / 3) * (P - h / T) ** 3 - Rs**2 * h + h**3 / 3)

    return math.radians(span_deg) * 2 * (F_(hs) - F_(0.0))


def test_concave_grating_volume_is_exact():
    g = F.GratingLayout()
    solid = F.concave_grating(g).val()
    assert solid.isValid()
    zr = g.rim_height
    blank = math.pi * g.aperture_radius**2 * (g.height + zr) - cap(g.sphere_radius, zr)
    grooves = g.n_grooves * groove_on_sphere_volume(g.sphere_radius, g.depth, g.angle, g.span)
    assert F.volume(solid) == pytest.approx(blank - grooves, rel=REL)
    # The grooves are there: a plain blank would differ by far more than the tolerance.
    assert grooves / blank > 1e-5


def test_plugin_methods_and_invoke_agree():
    base = cq.Workplane("XY").box(10, 10, 4).faces(">Z").workplane()
    a = F.volume(base.pushPoints([(-2, 0), (2, 0)]).bowl(1.5, 0.5).val())
    b = F.volume(base.pushPoints([(-2, 0), (2, 0)]).invoke(
        lambda w: F.bowl(w, radius=1.5, depth=0.5)).val())
    assert a == b == pytest.approx(400 - 2 * cap(1.5, 0.5), rel=REL)
    g = F.volume(base.vgroove([(-4, 3), (4, 3)], depth=0.1, angle=60).val())
    assert g == pytest.approx(400 - 8 * 0.1**2 * math.tan(math.radians(30)), rel=REL)
    p = F.volume(base.pyramid(2.0, 150.0).val())
    assert p == pytest.approx(400 + 4 * F.pyramid_height(2.0, 150.0) / 3, rel=REL)


def test_step_round_trip_and_stl(tmp_path):
    part = F.pyramid_part()
    vol = F.volume(part)
    step = export_step(part, tmp_path / "pyramid.step")
    back = import_step(step)
    assert F.volume(back) == pytest.approx(vol, rel=REL)
    stl = export_stl(part, tmp_path / "pyramid.stl", tolerance=1e-3)
    data = stl.read_bytes()
    n = struct.unpack("<I", data[80:84])[0]
    assert len(data) == 84 + 50 * n
    tri = np.frombuffer(data[84:], dtype=np.dtype([("n", "<f4", 3), ("v", "<f4", (3, 3)),
                                                    ("a", "<u2")]))["v"].astype(float)
    mesh_vol = np.einsum("ij,ij->i", tri[:, 0], np.cross(tri[:, 1], tri[:, 2])).sum() / 6
    # Chordal error 1 um on the bowls only: the mesh volume is close, not exact.
    assert mesh_vol == pytest.approx(vol, rel=1e-4)


def test_failed_export_leaves_no_file(tmp_path):
    with pytest.raises(MtcompError, match="empty.step: the workplane carries no shape"):
        export_step(cq.Workplane("XY"), tmp_path / "empty.step")
    assert list(tmp_path.iterdir()) == []


def test_package_import_stays_light():
    code = ("import sys, mtcomp, mtcomp.cad_plugin, mtcomp.cad_plugin.cli, mtcomp.cad_plugin.layout; "
            "assert 'cadquery' not in sys.modules and 'OCP' not in sys.modules")
    subprocess.run([sys.executable, "-c", code], check=True)


@pytest.mark.parametrize("face", ["top", "side"])
def test_plate_of_the_tool_setting_plan(face):
    from mtcomp.setting.tool_plan import groove_width, make_plan
    plan = make_plan("robonano-ui")
    tilts = dict(zip(plan.ids, F.plan_tilts(plan)))
    # B grooves (along +Y at B = theta) are tilted by theta about the cutting direction.
    assert tilts["B+10"] == pytest.approx(10.0) and tilts["B-10"] == pytest.approx(-10.0)
    assert tilts["C120"] == pytest.approx(0.0, abs=1e-12) and tilts["A180-1"] == pytest.approx(0.0, abs=1e-12)
    solid = F.plan_plate(plan, face).val()
    w, h = plan.options.plate
    D = plan.options.depth
    # Independent: sections in face coordinates as in the flat-plate test.
    passes = {(g.start, g.end, round(tilts[g.id], 9)) for g in plan.grooves if g.face == face}
    lay = type("L", (), {"depth": D, "angle": plan.options.tip_angle,
                         "grooves": lambda self: [(np.array([s, e]), t) for s, e, t in passes]})()
    x, wts = np.polynomial.legendre.leggauss(3)
    removed = sum(wi * union_area(groove_rectangles(lay, -D / 2 + xi * D / 2))
                  for xi, wi in zip(x, wts)) * D / 2
    assert F.volume(solid) == pytest.approx(w * h * 3.0 - removed, rel=REL)
    # ... and the groove widths agree with the tool-setting module's formula.
    bb_removed = sum(groove_width(D, 90.0, t) * D / 2 * np.hypot(*np.subtract(e, s))
                     for s, e, t in passes)
    assert removed < bb_removed  # overlaps at shared points are removed once
