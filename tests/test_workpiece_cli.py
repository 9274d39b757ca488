"""`mtcomp workpiece-setting plan|probe|fit|compensate|simulate` end to end."""
import numpy as np

from mtcomp import gcode
from mtcomp.cli import main
from mtcomp.errors import ErrorSet, WorkpieceSetting, load_errors
from mtcomp.kinematics import forward
from mtcomp.machine import load_machine

POSE = "0.02,-0.01,0.015,0.02,-0.03,0.2"
PROGRAM = "%\nO0100\nG21 G90 G17\nG00 X1. Y2. Z5.\nG01 Z0.1 F100.\nG01 X3. Y-2. Z0.05\nG00 Z5.\nM30\n%\n"


def _planned(tmp_path, *extra):
    assert main(["workpiece-setting", "plan", "-o", str(tmp_path / "plan.toml"), *extra]) == 0
    return tmp_path / "plan.toml"


def test_plan_probe_fit_compensate_round_trip(tmp_path, capsys):
    plan = _planned(tmp_path)
    assert (tmp_path / "plan-roughing.nc").exists() and (tmp_path / "plan-probing.nc").exists()
    touches = tmp_path / "touches.csv"
    assert main(["workpiece-setting", "probe", str(plan), "--pose", POSE, "-o", str(touches)]) == 0
    errors = tmp_path / "errors.toml"
    assert main(["workpiece-setting", "fit", str(plan), str(touches), "-o", str(errors),
                 "--report", str(tmp_path / "report.toml")]) == 0
    wp = load_errors(errors).workpiece
    from mtcomp._io import load_toml
    unc = load_toml(errors)["uncertainty"]
    cov = np.array(unc["workpiece_setting.covariance"])
    assert cov.shape == (6, 6) and np.allclose(cov, cov.T)
    np.testing.assert_allclose(np.sqrt(np.diag(cov)), unc["workpiece_setting.translation"]
                               + unc["workpiece_setting.angles"], rtol=1e-12)
    v = [float(x) for x in POSE.split(",")]
    np.testing.assert_allclose(wp.translation, v[:3], atol=1e-6)
    np.testing.assert_allclose(wp.angles, v[3:], atol=1e-5)
    # the errors file drives both the lead's general compensate and the paper-001 transform
    prog = tmp_path / "prog.nc"
    prog.write_text(PROGRAM)
    m = load_machine("robonano-a0ib")
    nominal = forward(m, gcode.parse(PROGRAM, axes=m.axis_names).position).p
    true = ErrorSet(workpiece=WorkpieceSetting(tuple(v[:3]), tuple(v[3:])))
    for cmd in (["compensate", str(prog), "-m", "robonano-a0ib", "-e", str(errors), "-o"],
                ["workpiece-setting", "compensate", str(prog), "--errors", str(errors), "-o"]):
        out = tmp_path / f"out{len(cmd)}.nc"
        assert main(cmd + [str(out)]) == 0
        q = gcode.parse(out.read_text(), axes=m.axis_names).position
        assert np.abs(forward(m, q, true).p - nominal).max() < 5e-6     # fit 1e-6 + rounding


def test_fit_with_a_touch_far_off_names_the_bowl_and_writes_nothing(tmp_path, capsys):
    plan = _planned(tmp_path)
    touches = tmp_path / "touches.csv"
    assert main(["workpiece-setting", "probe", str(plan), "--pose", POSE, "--noise", "0.0005",
                 "-o", str(touches)]) == 0
    lines = touches.read_text().splitlines()
    cells = lines[12].split(",")                                 # bowl 2, 3rd touch
    cells[3] = f"{float(cells[3]) - 0.2:.9f}"
    lines[12] = ",".join(cells)
    touches.write_text("\n".join(lines) + "\n")
    out = tmp_path / "errors.toml"
    rep = tmp_path / "report.toml"
    assert main(["workpiece-setting", "fit", str(plan), str(touches), "-o", str(out),
                 "--report", str(rep)]) == 2
    err = capsys.readouterr().err
    assert "bowl 2: line 13 is" in err and "off the bowl's sphere" in err
    assert not out.exists() and not rep.exists()


def test_too_few_touches_and_collinear_plan_are_refused(tmp_path, capsys):
    plan = _planned(tmp_path)
    touches = tmp_path / "touches.csv"
    main(["workpiece-setting", "probe", str(plan), "--pose", POSE, "-o", str(touches)])
    lines = touches.read_text().splitlines()
    keep = [ln for ln in lines if not ln.startswith("3,")] + \
        [ln for ln in lines if ln.startswith("3,")][:3]
    touches.write_text("\n".join(keep) + "\n")
    assert main(["workpiece-setting", "fit", str(plan), str(touches), "-o",
                 str(tmp_path / "e.toml")]) == 2
    assert "bowl 3: 3 touches, at least 5 needed" in capsys.readouterr().err
    assert not (tmp_path / "e.toml").exists()
    sub = tmp_path / "sub"
    sub.mkdir()  # outputs go into existing folders only (the CLI refuses a missing parent)
    assert main(["workpiece-setting", "plan", "-o", str(sub / "p.toml"),
                 "--positions=-7,6;0,6.05;7,6.1"]) == 2
    assert "collinear" in capsys.readouterr().err
    assert not sub.exists() or not any(sub.iterdir())


def test_simulate_writes_table_and_png(tmp_path, capsys):
    md, png = tmp_path / "sim.md", tmp_path / "sim.png"
    assert main(["workpiece-setting", "simulate", "--trials", "10", "--gripper-offset",
                 "0.05,0,0.01", "-o", str(md), "--png", str(png)]) == 0
    text = md.read_text()
    assert "| W4 um | 3450 | 3448.4 |" in text and "gripper offset (0.05, 0.0, 0.01)" in text
    assert png.read_bytes()[:4] == b"\x89PNG"


def test_second_pass_probing_program_is_aimed_at_the_coarse_pose(tmp_path):
    from mtcomp.errors import save_errors
    coarse = tmp_path / "coarse.toml"
    save_errors(ErrorSet(workpiece=WorkpieceSetting((0.8, -0.3, 0.0), (0.0, 0.0, 0.0))), coarse)
    _planned(tmp_path, "--aim", str(coarse), "--probing", str(tmp_path / "second.nc"),
             "--positions=-7,-7;7,-7;-7,7")
    text = (tmp_path / "second.nc").read_text()
    assert "G00 X-6.2 Y-7.3 Z5" in text and "G00 X7.8 Y-7.3 Z5" in text


def test_compensate_refuses_an_errors_file_without_a_workpiece_setting(tmp_path, capsys):
    from mtcomp.errors import ToolSetting, save_errors
    errors = save_errors(ErrorSet(tool=ToolSetting((0.1, 0.0, 0.0))), tmp_path / "tool.toml")
    prog = tmp_path / "p.nc"
    prog.write_text(PROGRAM)
    out = tmp_path / "out.nc"
    assert main(["workpiece-setting", "compensate", str(prog), "--errors", str(errors), "-o", str(out)]) == 2
    assert "tool.toml [workpiece_setting]: no [workpiece_setting] section" in capsys.readouterr().err
    assert not out.exists()


def test_compensate_refuses_to_drop_the_tool_setting_of_the_errors_file(tmp_path, capsys):
    """Issue 14: [tool_setting] of the errors file was silently dropped."""
    from mtcomp.errors import ToolSetting, save_errors
    errors = save_errors(ErrorSet(tool=ToolSetting((0.1, 0.0, 0.0)),
                                  workpiece=WorkpieceSetting((0.01, 0.0, 0.0), (0.0, 0.0, 0.0))),
                         tmp_path / "both.toml")
    prog = tmp_path / "p.nc"
    prog.write_text(PROGRAM)
    out = tmp_path / "out.nc"
    assert main(["workpiece-setting", "compensate", str(prog), "--errors", str(errors), "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert "[tool_setting]" in err and "mtcomp compensate" in err and "--workpiece-only" in err
    assert not out.exists()
    assert main(["workpiece-setting", "compensate", str(prog), "--errors", str(errors), "-o", str(out),
                 "--workpiece-only"]) == 0
    assert out.exists()


def test_compensate_refuses_errors_of_axes_the_machine_lacks(tmp_path, capsys):
    # an EX0U on a machine without U was ignored: the program came out compensated for the
    # workpiece setting only, with exit 0, even with --workpiece-only
    err = tmp_path / "e.toml"
    err.write_text("[workpiece_setting]\ntranslation = [0.01, 0, 0]\nangles = [0, 0, 0]\n"
                   "[geometric.location]\nEX0U = 0.001\n")
    prog = tmp_path / "p.nc"
    prog.write_text(PROGRAM)
    out = tmp_path / "o.nc"
    rc = main(["workpiece-setting", "compensate", str(prog), "--errors", str(err), "--workpiece-only",
               "-o", str(out)])
    msg = capsys.readouterr().err
    assert rc != 0 and not out.exists()
    assert "location error EX0U of axis U" in msg and "robonano-a0ib" in msg and "e.toml" in msg


def _fitted(tmp_path, pose=POSE):
    """Plan, virtual probing at `pose` and fit: (plan path, errors path)."""
    plan = _planned(tmp_path)
    touches = tmp_path / "touches.csv"
    assert main(["workpiece-setting", "probe", str(plan), "--pose", pose, "-o", str(touches)]) == 0
    errors = tmp_path / "errors.toml"
    assert main(["workpiece-setting", "fit", str(plan), str(touches), "-o", str(errors)]) == 0
    return plan, errors


def _um(text, what):
    import re
    m = re.search(what + r" (-?[\d.]+) µm", text)
    assert m, text
    return float(m.group(1))


def test_compensated_program_is_verified_on_the_blank_of_the_fit(tmp_path, capsys):
    # issue 14 item 1: the emitted program is verified; a rapid through the blank is an error
    # naming the block, and nothing is written unless --warn-only
    _, errors = _fitted(tmp_path, "0.05,-0.03,0.1,0.02,-0.03,0.2")
    capsys.readouterr()
    prog = tmp_path / "p.nc"
    prog.write_text("%\nO0100\nG21 G90 G17\nG00 X-5. Y-5. Z0.3\nG00 X5. Y4.\nG01 Z-0.1 F100.\n"
                    "G01 X-4.\nG00 Z2.\nG00 X0 Y0\nG00 Z-0.5\nM30\n%\n")
    out = tmp_path / "o.nc"
    argv = ["workpiece-setting", "compensate", str(prog), "--errors", str(errors), "-o", str(out)]
    assert main(argv) != 0 and not out.exists()
    err = capsys.readouterr().err
    assert "1 block(s) fail" in err and "line 10 (G00 X" in err and "enters the stock" in err
    assert main(argv + ["--warn-only"]) == 0 and out.exists()
    text = capsys.readouterr().out
    assert "plan.toml (plan of the fit)" in text and "FAIL" in text
    # without the bad rapid it passes; the clearance of the compensated program on the real
    # blank is the one the program was written with (0.3 mm), to the command rounding; the
    # rapid back out of the cut (line 8) is a retract
    prog.write_text(prog.read_text().replace("G00 Z-0.5\n", ""))
    out.unlink()
    assert main(argv) == 0 and out.exists()
    text = capsys.readouterr().out
    assert "passed" in text and "1 rapid(s) start closer" in text
    assert abs(_um(text, "min rapid clearance") - 300.0) < 0.05, text
    # the uncompensated program on the same blank has another clearance: the check is not vacuous
    from mtcomp.errors import load_errors as le
    from mtcomp.setting.blank_check import plan_stock, verify_on_blank
    from mtcomp.setting.bowls import load_plan
    res = verify_on_blank(load_machine("robonano-a0ib"), prog.read_text(), le(errors).workpiece,
                          plan_stock(load_plan(tmp_path / "plan.toml")), raise_on_violation=False)
    assert abs(res.min_clearance * 1e3 - 300.0) > 50


def test_compensate_stock_and_clearance_options(tmp_path, capsys):
    _, errors = _fitted(tmp_path)
    prog = tmp_path / "p.nc"
    prog.write_text("G21 G90\nG00 X0 Y0 Z0.3\nG00 X3.\nM30\n")
    out = tmp_path / "o.nc"
    base = ["workpiece-setting", "compensate", str(prog), "--errors", str(errors), "-o", str(out)]
    capsys.readouterr()
    assert main(base + ["--clearance", "0.5"]) != 0 and not out.exists()
    assert "2 block(s) fail" in capsys.readouterr().err     # both rapids are 0.3 mm over it
    # a taller stock given by hand: the rapid passes 0.3 - 0.2 mm over it, below 0.2
    assert main(base + ["--stock", "box:-10,-10,-5,10,10,0.2"]) != 0
    assert main(base + ["--clearance", "nan"]) != 0
    assert main(base + ["--no-verify"]) == 0 and out.exists()
    assert "not verified" in capsys.readouterr().err


def test_plan_programs_are_verified_on_the_blank(tmp_path, capsys):
    # issue 14: both programs the plan emits pass the verification on the plan's blank; the
    # roughing program's way back into a peck is a feed (a rapid there went into the raw blank)
    _planned(tmp_path)
    text = capsys.readouterr().out
    assert text.count("  passed") == 2 and "verify roughing program" in text
    assert "min rapid clearance 500 µm at line 10" in text          # G00 Z0.5 over the blank
    rough = (tmp_path / "plan-roughing.nc").read_text()
    assert "G00 Z-0.45" not in rough and "G01 Z-0.45 F" in rough
    # a larger clearance than the programs keep: an error naming the block, nothing written
    out = tmp_path / "p2.toml"
    assert main(["workpiece-setting", "plan", "-o", str(out), "--clearance", "0.6"]) != 0
    assert "roughing program: line 10 (G00 Z0.5)" in capsys.readouterr().err
    assert not list(tmp_path.glob("p2*"))
