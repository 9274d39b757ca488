"""`mtcomp cad features` / `mtcomp cad toolpath` end to end (in-process CLI)."""
import numpy as np
import pytest

pytest.importorskip("cadquery")
from mtcomp import gcode  # noqa: E402
from mtcomp.cad_plugin.export import import_step  # noqa: E402
from mtcomp.cad_plugin import features as F  # noqa: E402
from mtcomp.cli import main  # noqa: E402
from mtcomp.errors import load_errors  # noqa: E402
from mtcomp.kinematics import forward  # noqa: E402
from mtcomp.machine import load_machine  # noqa: E402


def test_features_writes_step_and_stl(tmp_path, capsys):
    step, stl = tmp_path / "blank.step", tmp_path / "blank.stl"
    assert main(["cad", "features", "bowl-blank", "-o", str(step), "-o", str(stl),
                 "--param", "bowl_depth=0.5"]) == 0
    expected = F.volume(F.bowl_blank(F.BowlBlankLayout(bowl_depth=0.5)))
    assert F.volume(import_step(step)) == pytest.approx(expected, rel=1e-9)
    # The STEP product carries the part's name (issue 19: no product name), unit mm.
    text = step.read_text()
    assert "PRODUCT('bowl-blank: blank with three R2 bowls (paper 001)'" in text
    assert "SI_UNIT(.MILLI.,.METRE.)" in text
    assert stl.stat().st_size > 84
    assert f"volume {expected:.9f}" in capsys.readouterr().out


def test_bad_parameter_exits_2_and_writes_nothing(tmp_path, capsys):
    out = tmp_path / "g.step"
    assert main(["cad", "features", "grating", "-o", str(out), "--param", "pitch=fine"]) == 2
    assert "pitch" in capsys.readouterr().err
    assert main(["cad", "features", "grating", "-o", str(tmp_path / "g.iges")]) == 2
    # a well-formed TOML value of the wrong type is refused too, for toolpaths as for features
    assert main(["cad", "toolpath", "grating", "-o", str(tmp_path / "g.nc"), "--param", 'depth="x"']) == 2
    assert "[--param depth]: expected a number" in capsys.readouterr().err
    assert main(["cad", "toolpath", "pyramid", "-o", str(tmp_path / "p.nc"), "--param", "size=1"]) == 2
    assert "pyramid has no parameter 'size'" in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []


def test_toolpath_compensated_program_and_check(tmp_path, capsys):
    (tmp_path / "err.toml").write_text(
        "[workpiece_setting]\ntranslation = [0.02, -0.01, 0.008]\nangles = [0.1, -0.2, 0.5]\n")
    nc, png = tmp_path / "pyr.nc", tmp_path / "pyr.png"
    assert main(["cad", "toolpath", "pyramid", "-o", str(nc), "--png", str(png),
                 "--errors", str(tmp_path / "err.toml"), "--stepover", "0.1", "--step", "0.05",
                 "--grid", "0.02"]) == 0
    out = capsys.readouterr().out
    assert "uncompensated program" in out and "width error max" in out
    m = load_machine("robonano-a0ib")
    q = gcode.parse(nc.read_text(), axes=m.axis_names).position
    err = load_errors(tmp_path / "err.toml")
    # The program puts the real ball where the CAD toolpath wants it.
    from mtcomp.cad_plugin.toolpath import Tool, pyramid_finishing
    tp = pyramid_finishing(tool=Tool("ball", 0.5), stepover=0.1, step=0.05)
    assert np.max(np.abs(forward(m, q, err).p - tp.p)) < 5e-6
    assert png.read_bytes()[:4] == b"\x89PNG"


def test_toolpath_grating_plain_axes(tmp_path):
    nc = tmp_path / "g.nc"
    assert main(["cad", "toolpath", "grating", "-m", "robonano-ui", "-o", str(nc),
                 "--png", str(tmp_path / "g.png"), "--param", "n_grooves=3"]) == 0
    prog = gcode.parse(nc.read_text(), axes=("X", "Y", "Z", "A", "B", "C"))
    # per groove: approach, 16 deg / 0.25 deg + 1 = 65 points on the groove, retract; between
    # grooves the rotary axes turn in a link of their own (retract, turn, move over) before the
    # approach rapid, so no rapid turns a rotary axis while it moves a linear one.
    n_link = prog.position.shape[0] - 3 * (1 + 65 + 1)
    assert 0 < n_link <= 2 * 3
    fast = np.nonzero(prog.motion == 0)[0][1:]  # from the second rapid on
    d = np.abs(prog.position[fast] - prog.position[fast - 1]) > 1e-9
    assert not np.any(d[:, 3:].any(axis=1) & d[:, :3].any(axis=1))


def test_toolpath_deviation_is_reported_without_a_png(tmp_path, capsys):
    assert main(["cad", "toolpath", "grating", "-m", "robonano-ui", "-o", str(tmp_path / "g.nc"),
                 "--param", "n_grooves=1"]) == 0
    out = capsys.readouterr().out
    assert float(out.split("tool point deviation max ")[1].split(" µm")[0]) < 0.005
    assert sorted(p.name for p in tmp_path.iterdir()) == ["g.nc"]


def test_plan_plate_from_a_tool_setting_plan(tmp_path):
    from mtcomp.setting.tool_plan import make_plan, plan_to_toml
    plan = make_plan("robonano-ui")
    (tmp_path / "plan.toml").write_text(plan_to_toml(plan))
    out = tmp_path / "top.step"
    assert main(["cad", "features", "plan-plate", "--plan", str(tmp_path / "plan.toml"),
                 "-o", str(out)]) == 0
    assert F.volume(import_step(out)) == pytest.approx(F.volume(F.plan_plate(plan, "top")), rel=1e-9)


def test_grating_compensated_for_a_tool_setting_error(tmp_path, capsys):
    (tmp_path / "tool.toml").write_text("[tool_setting]\noffset = [0.490, 0.680, -0.012]\n")
    assert main(["cad", "toolpath", "grating", "-m", "robonano-ui", "-o", str(tmp_path / "g.nc"),
                 "--png", str(tmp_path / "g.png"), "--param", "n_grooves=2",
                 "--errors", str(tmp_path / "tool.toml")]) == 0
    out = capsys.readouterr().out
    # Uncompensated, the edge is off by the whole offset at every point (a rigid offset in the
    # tool frame); compensated, by the command rounding only.
    off = np.linalg.norm([490.0, 680.0, -12.0])
    unc = float(out.split("uncompensated: tool point deviation max ")[1].split(" µm")[0])
    assert unc == pytest.approx(off, abs=0.005)  # to the command rounding (1 nm, 1e-5 deg)
    comp = float(out.split("deviation max ")[1].split(" µm")[0])
    assert comp < 0.005


def test_outputs_into_missing_folders_or_onto_folders_are_refused(tmp_path, capsys):
    """Issue 19: `-o /nonexist/x.nc` created the folder; now a one-line error, nothing written."""
    missing = tmp_path / "nope" / "x.nc"
    assert main(["cad", "toolpath", "groove-plate", "-o", str(missing)]) == 2
    assert "does not exist" in capsys.readouterr().err and not (tmp_path / "nope").exists()
    assert main(["cad", "features", "bowl-blank", "-o", str(tmp_path)]) == 2
    assert main(["cad", "toolpath", "groove-plate", "-o", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err and err.count("error:") == 2


def test_stage_log_names_the_stage_and_clears_its_line():
    import io
    from mtcomp.progress import StageLog
    buf = io.StringIO()
    log = StageLog("cad toolpath pyramid", enabled=True, stream=buf)
    log("machine axes of 88704 poses")
    log("post")
    log.done()
    text = buf.getvalue()
    assert "\rcad toolpath pyramid: machine axes of 88704 poses ... (0 s)" in text
    assert text.endswith("\r") and "post ..." in text
    quiet = io.StringIO()
    StageLog("x", stream=quiet)("stage")   # not a terminal: nothing
    assert quiet.getvalue() == ""


@pytest.mark.parametrize("cmd", ["toolpath", "verify"])
def test_errors_of_axes_the_machine_lacks_are_refused(tmp_path, capsys, cmd):
    # a U table error on robonano-a0ib (C B X Y Z) was ignored: the program came out as if
    # compensated for it
    err = tmp_path / "e.toml"
    err.write_text("[geometric.location]\nEX0U = 0.001\n")
    out = tmp_path / "g.nc"
    if cmd == "toolpath":
        argv = ["cad", "toolpath", "groove-plate", "-o", str(out), "--errors", str(err)]
    else:
        out.write_text("G90 G00 X0 Y0 Z5. B0 C0\nM30\n")
        argv = ["verify", str(out), "-m", "robonano-a0ib", "--stock", "plane:0",
                "--errors", str(err)]
    assert main(argv) != 0
    msg = capsys.readouterr().err
    assert "location error EX0U of axis U" in msg and "e.toml" in msg
    if cmd == "toolpath":
        assert not out.exists()
