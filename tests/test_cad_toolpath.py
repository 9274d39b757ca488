"""Toolpaths: every cutting point on the tool-offset surface of the real CadQuery solid (OCP
distance queries), and machine axes that reproduce the poses, nominal and compensated."""
import numpy as np
import pytest

cq = pytest.importorskip("cadquery")
from OCP.BRepBuilderAPI import BRepBuilderAPI_MakeVertex  # noqa: E402
from OCP.BRepExtrema import BRepExtrema_DistShapeShape  # noqa: E402
from OCP.gp import gp_Pnt  # noqa: E402

from mtcomp.cad_plugin import features as F, toolpath as T  # noqa: E402
from mtcomp.errors import ErrorSet, ToolSetting, WorkpieceSetting  # noqa: E402
from mtcomp.kinematics import forward  # noqa: E402
from mtcomp.machine import load_machine  # noqa: E402

TOL = 1e-7  # mm: stated tolerance of every toolpath point on its offset surface


def distances(points, shape):
    out = []
    for p in np.asarray(points, float):
        v = BRepBuilderAPI_MakeVertex(gp_Pnt(*p)).Vertex()
        d = BRepExtrema_DistShapeShape(v, shape.wrapped)
        assert d.IsDone()
        out.append(d.Value())
    return np.array(out)


def pick(mask, k, seed=0):
    idx = np.nonzero(mask)[0]
    return np.random.default_rng(seed).choice(idx, size=min(k, idx.size), replace=False)


@pytest.fixture(scope="module")
def pyramid_solid():
    return F.pyramid_part().val()


def test_pyramid_finishing_balls_touch_the_cad_surface(pyramid_solid):
    tool = T.Tool("ball", radius=0.5)
    tp = T.pyramid_finishing(tool=tool, stepover=0.05, step=0.02)
    idx = pick(tp.cutting, 150)
    d = distances(tp.centre[idx], pyramid_solid)
    assert np.max(np.abs(d - tool.radius)) < TOL
    # Points on all four slopes, on the flat and on ridges/apex are among them.
    nz = tp.normal[tp.cutting]
    assert np.sum(np.isclose(nz[:, 2], 1.0)) > 0 and np.sum(nz[:, 2] < 0.999) > 0


def test_scallop_option_sets_the_stepover():
    tp = T.pyramid_finishing(tool=T.Tool("ball", radius=0.5), scallop=1e-4, step=0.05)
    s = T.scallop_stepover(0.5, 1e-4)
    assert tp.meta["stepover"] == s and s == pytest.approx(2 * np.sqrt(2 * 0.5 * 1e-4 - 1e-8))
    assert tp.meta["stepover"] >= np.max(np.diff(np.unique(tp.p[tp.cutting, 1])))
    with pytest.raises(ValueError):
        T.pyramid_finishing(stepover=0.1, scallop=1e-4)


def test_bowl_milling_and_probing_on_offset_spheres():
    L = F.BowlBlankLayout()
    solid = F.bowl_blank(L).val()
    tool = T.Tool("ball", radius=0.5)
    tp = T.bowl_milling(L.centres, L.bowl_radius, L.bowl_depth, tool, stepover=0.2, step=0.2)
    idx = pick(tp.cutting, 100)
    assert np.max(np.abs(distances(tp.centre[idx], solid) - tool.radius)) < TOL
    probe = T.Tool("probe", radius=0.25)
    pp = T.bowl_probing(L.centres, L.bowl_radius, L.bowl_depth, probe, approach=0.2,
                        overtravel=0.1)
    touch = pp.motion == T.PROBE
    assert touch.sum() == 3 * (1 + 2 * 6)
    contacts = T.probe_contacts(pp)
    assert np.max(np.abs(distances(contacts, solid) - probe.radius)) < TOL
    # Each probing move starts 0.2 mm off along the normal and runs 0.1 mm past the contact.
    start = np.nonzero(touch)[0] - 1
    dirs = pp.centre[touch] - pp.centre[start]
    assert np.allclose(np.linalg.norm(dirs, axis=1), 0.3)
    assert np.allclose(dirs / 0.3, -pp.normal[touch], rtol=0, atol=1e-12)
    assert np.allclose(np.linalg.norm(contacts - pp.centre[start], axis=1), 0.2)


def test_grating_tool_edge_on_groove_bottom_and_normal_to_the_surface():
    g = F.GratingLayout()
    solid = F.concave_grating(g).val()
    tp = T.grating_passes(g.sphere_radius, g.psi, g.span, g.depth, T.Tool("vtool", angle=g.angle))
    idx = pick(tp.cutting, 60)
    # The edge traces the groove bottom: on the solid's boundary edges.
    edges = cq.Compound.makeCompound(solid.Edges())
    assert np.max(distances(tp.p[idx], edges)) < TOL
    centre = np.array([0, 0, g.sphere_radius])
    to_centre = centre - tp.p[idx]
    to_centre /= np.linalg.norm(to_centre, axis=1, keepdims=True)
    assert np.allclose(tp.axis[idx], to_centre, rtol=0, atol=1e-12)
    # The rake face faces the feed.
    feed = np.diff(tp.p, axis=0)[idx - 1]
    feed /= np.linalg.norm(feed, axis=1, keepdims=True)
    assert np.min(np.einsum("ij,ij->i", feed, tp.R[idx, :, 0])) > 0.9999


def test_groove_plate_edges_on_groove_bottoms():
    L = F.GroovePlateLayout()
    solid = F.groove_plate(L).val()
    tp = T.groove_plate_passes(L)
    edges = cq.Compound.makeCompound(solid.Edges())
    idx = np.nonzero(tp.cutting)[0]
    assert np.max(distances(tp.p[idx], edges)) < TOL


def test_axes_reproduce_grating_poses_nominal_and_compensated():
    m = load_machine("robonano-ui")
    g = F.GratingLayout()
    tp = T.grating_passes(g.sphere_radius, g.psi, g.span, g.depth, T.Tool("vtool"))
    q = T.to_axes(m, tp)
    pose = forward(m, q)
    assert np.max(np.abs(pose.p - tp.p)) < 1e-9
    assert np.max(np.abs(pose.R - tp.R)) < 1e-9  # full tool frame: the rake face too
    # The rotary axes really carry the orientation (A and B tilts vary along the grooves).
    assert np.ptp(q[:, m.index("A")]) > 5 and np.ptp(q[:, m.index("B")]) > 10
    err = ErrorSet(tool=ToolSetting((0.005, -0.003, 0.01)),
                   workpiece=WorkpieceSetting((0.02, -0.01, 0.005), (0.01, -0.02, 0.05)))
    qc = T.to_axes(m, tp, err)
    real = forward(m, qc, err)
    assert np.max(np.abs(real.p - tp.p)) < 1e-9
    assert np.max(np.abs(real.R - tp.R)) < 1e-9
    assert np.max(np.abs(forward(m, q, err).p - tp.p)) > 1e-3  # uncompensated misses


def test_rotary_axes_stay_continuous_along_the_grating():
    m = load_machine("robonano-ui")
    g = F.GratingLayout()
    tp = T.grating_passes(g.sphere_radius, g.psi, g.span, g.depth, T.Tool("vtool"))
    q = T.to_axes(m, tp)
    rot = list(m.rotary_indices)
    # Same orientation can be written C = -180 or +180: the path never swaps within a run.
    assert np.max(np.abs(np.diff(q[:, rot], axis=0))) < 20.0
