"""`mtcomp geometric` commands end to end, on files, through the command group's parser."""
import argparse

import numpy as np
import pytest

from mtcomp import MtcompError
from mtcomp.errors import load_errors
from mtcomp.geometric import cli
from mtcomp.geometric.comptables import LatticeTable


def run(argv):
    parser = argparse.ArgumentParser(prog="mtcomp")
    sub = parser.add_subparsers(dest="command")
    cli.register(sub)
    args = parser.parse_args(argv)
    try:
        return args.func(args)
    except MtcompError as exc:  # what mtcomp.cli.main does
        print(f"error: {exc}")
        return 2


def test_simulate_build_map_table(tmp_path, capsys):
    s = str(tmp_path / "set.toml")
    assert run(["geometric", "simulate", "-o", s, "--step", "20", "--seed", "4"]) == 0
    assert run(["geometric", "iso230-2", str(tmp_path / "set_EXX.csv"), "--axis", "X"]) == 0
    out = capsys.readouterr().out
    assert "reversal value" in out
    assert (tmp_path / "set_EXX_iso230-2.png").exists()
    built = str(tmp_path / "built.toml")
    assert run(["geometric", "build", s, "-o", built]) == 0
    errs = load_errors(built)
    assert set(errs.geometric.tables) == {"X", "Y", "Z"}
    assert set(errs.geometric.location) == {"EC0Y", "EB0Z", "EA0Z"}
    assert run(["geometric", "map", built, "--step", "50", "-o", str(tmp_path / "vm")]) == 0
    assert (tmp_path / "vm.png").read_bytes()[:4] == b"\x89PNG"
    rows = (tmp_path / "vm.csv").read_text().splitlines()
    assert len(rows) == 2 + 13 * 9 * 7
    truth = str(tmp_path / "set_truth.toml")
    prog = tmp_path / "part.nc"
    prog.write_bytes(b"G90 G1 X10. Y20. Z-30. F1000\r\nX250. Y-150. Z-200.\r\nX-280. Y180. Z0.\r\n")
    assert run(["geometric", "table", built, "--truth", truth, "--lattice-step", "100",
                "--program", str(prog), "-o", str(tmp_path / "comp")]) == 0
    out = capsys.readouterr().out
    assert "model-based (corrected commands)" in out
    lat = LatticeTable.from_csv(tmp_path / "comp" / "lattice.csv")
    assert lat.correction.shape == (7, 5, 4, 3)
    assert np.abs(lat.correction).max() > 1e-3
    assert (tmp_path / "comp" / "comp_Z.csv").read_text().splitlines()[1].startswith("position,EXZ")
    # the rewritten program: corrected commands put the tool on the programmed points
    from mtcomp import gcode
    from mtcomp.kinematics import forward
    from mtcomp.machine import load_machine
    m = load_machine("vmc-moving-column")
    raw = (tmp_path / "comp" / "part_comp.nc").read_bytes()
    # CR LF kept, on the 3 blocks and the 6 lines of the provenance header (issue 31)
    assert raw.count(b"\r\n") == 9 and raw.count(b"\n") == 9
    new = gcode.parse(raw.decode(), axes=m.axis_names)
    want = np.array([[10, 20, -30], [250, -150, -200], [-280, 180, 0]], float)
    assert np.abs(new.position - want).max() > 1e-3          # the commands did move
    got = forward(m, new.position, errs).p
    assert np.abs(got - want).max() < 1e-4                    # rounding to the 0.1 µm resolution


def test_bad_run_exits_2_with_file_and_line(tmp_path, capsys):
    p = tmp_path / "bad.csv"
    p.write_text("target,cycle,direction,deviation\n0,1,+,0\n100,1,+,0.001\n50,1,+,0\n"
                 "100,1,-,0\n0,1,-,0\n")
    assert run(["geometric", "iso230-2", str(p)]) == 2
    out = capsys.readouterr().out
    assert "bad.csv:4 [target]: non-monotonic targets" in out
    assert not list(tmp_path.glob("bad_iso230-2*"))


def test_missing_set_file(tmp_path, capsys):
    assert run(["geometric", "build", str(tmp_path / "nope.toml"), "-o", str(tmp_path / "o.toml")]) == 2
    assert "file not found" in capsys.readouterr().out
    assert not (tmp_path / "o.toml").exists()


@pytest.mark.parametrize("flag", ["--step", "--lattice-step"])
def test_non_positive_spacing(tmp_path, capsys, flag):
    cmd = "map" if flag == "--step" else "table"
    assert run(["geometric", cmd, "x.toml", flag, "0", "-o", str(tmp_path / "o")]) == 2
    assert f"[{flag}]" in capsys.readouterr().out


@pytest.mark.parametrize("args,flag", [(["--step", "0"], "--step"), (["--step", "-5"], "--step"),
                                       (["--noise", "-1", "0", "0"], "--noise"),
                                       (["--reversal", "nan"], "--reversal")])
def test_simulate_refuses_bad_spacing_and_noise(tmp_path, capsys, args, flag):
    assert run(["geometric", "simulate", *args, "-o", str(tmp_path / "s.toml")]) == 2
    assert f"[{flag}]" in capsys.readouterr().out
    assert not list(tmp_path.iterdir())


def test_bad_program_leaves_no_tables(tmp_path, capsys):
    s = str(tmp_path / "set.toml")
    assert run(["geometric", "simulate", "-o", s, "--step", "50"]) == 0
    assert run(["geometric", "build", s, "-o", str(tmp_path / "b.toml")]) == 0
    assert run(["geometric", "table", str(tmp_path / "b.toml"), "--program",
                str(tmp_path / "none.nc"), "-o", str(tmp_path / "out")]) == 2
    assert "NC program not found" in capsys.readouterr().out
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("cmd", [["map", "e.toml"], ["table", "e.toml"], ["simulate"]])
def test_machine_with_rotary_axes_is_refused_naming_the_option(tmp_path, capsys, cmd):
    assert run(["geometric", *cmd, "--machine", "robonano-ui", "-o", str(tmp_path / "o")]) == 2
    assert "[--machine]: machine robonano-ui has axes X Y Z A B C" in capsys.readouterr().out
    assert not list(tmp_path.iterdir())



@pytest.mark.parametrize("which", ["map", "table", "table-truth"])
def test_errors_of_axes_the_machine_lacks_are_refused(tmp_path, capsys, which):
    # vmc-moving-column has X Y Z: an A table error or EX0A used to be dropped without a word
    ok = tmp_path / "ok.toml"
    ok.write_text("[geometric.location]\nEC0Y = 1e-5\n")
    bad = tmp_path / "bad.toml"
    bad.write_text("[geometric.location]\nEC0Y = 1e-5\nEX0A = 1e-5\n")
    out = tmp_path / "out"
    argv = {"map": ["geometric", "map", str(bad), "-o", str(out), "--step", "200"],
            "table": ["geometric", "table", str(bad), "-o", str(out)],
            "table-truth": ["geometric", "table", str(ok), "--truth", str(bad), "-o", str(out)]}[which]
    assert run(argv) == 2
    msg = capsys.readouterr().out
    assert "location error EX0A of axis A" in msg and "bad.toml" in msg
    assert not out.exists() and not list(tmp_path.glob("out*"))


def test_table_program_is_verified_against_the_stock(tmp_path, capsys):
    # issue 14: the rewritten program is verified on the machine with the errors (the real one)
    err = tmp_path / "e.toml"
    err.write_text("[geometric.location]\nEC0Y = 1e-4\nEA0Z = 2e-4\n")
    prog = tmp_path / "part.nc"
    good = "G90 G0 X0 Y0 Z50.\nG0 X100. Y100.\nG0 Z0.3\nG1 Z-0.1 F100\nG1 X120.\nG0 Z50.\n"
    prog.write_text(good + "G0 X-100. Z-5.\n")
    out = tmp_path / "comp"
    argv = ["geometric", "table", str(err), "--program", str(prog), "--lattice-step", "200",
            "--stock", "box:-200,-200,-100,200,200,0", "-o", str(out)]
    assert run(argv) == 2
    # (line 13 of the written program: 7 after its 6 lines of provenance header, issue 31)
    assert "part_comp.nc: line 13 (G0 X-99.99" in capsys.readouterr().out and not out.exists()
    prog.write_text(good)
    assert run(argv) == 0
    text = capsys.readouterr().out
    assert "passed" in text and "1 rapid(s) start closer" in text
    assert "min rapid clearance 300 µm at line 9" in text      # the 0.3 mm approach (after the 6 header lines)
    assert run(argv[:-4] + ["-o", str(tmp_path / "c2")]) == 0
    assert "not verified against a stock" in capsys.readouterr().out
