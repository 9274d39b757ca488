"""Every plotting function returns a matplotlib Figure, writes a file only when given a path, and
leaves pyplot and the user's backend alone (run in a fresh interpreter, where pyplot was never
imported)."""
from __future__ import annotations

import subprocess
import sys
import textwrap

import pytest

pytest.importorskip("matplotlib")

_SCRIPT = textwrap.dedent("""
    import os, sys
    import numpy as np
    import matplotlib
    backend = dict.__getitem__(matplotlib.rcParams, "backend")   # get_backend() would import pyplot
    from matplotlib.figure import Figure
    from mtcomp.machine import load_machine

    def figures():
        from mtcomp.geometric import iso230_2 as iso, volumetric as vol, synthetic
        t = np.linspace(0.0, 100.0, 6)
        rng = np.random.default_rng(1)
        run = iso.PositioningRun(t, 1e-3 * rng.normal(size=(5, 6)), 1e-3 * rng.normal(size=(5, 6)) + 2e-3, axis="X")
        yield "iso230_2.plot", lambda p: iso.plot(iso.evaluate(run), p)
        vmc = load_machine("vmc-moving-column")
        errs = synthetic.make_synthetic(vmc, seed=11, min_wavelength=250.0, run_step=25.0).errors()
        vmap = vol.error_map(vmc, errs, vol.volume_grid(vmc, 100.0))
        yield "volumetric.plot_map", lambda p: vol.plot_map(vmap, p)
        from mtcomp.setting.tool_plan import make_plan, plot_layout
        from mtcomp.setting.tool import paper_offset, simulate_grooving
        from mtcomp.setting import tool_estimate as te
        m = load_machine("robonano-ui")
        plan = make_plan(m)
        yield "tool_plan.plot_layout", lambda p: plot_layout(plan, p)
        meas = simulate_grooving(m, paper_offset(), plan=plan, seed=7)
        est = te.estimate(m, meas)
        yield "tool_estimate.plot_report", lambda p: te.plot_report(m, meas, est, p)
        from mtcomp.setting.cellsim import CellConfig, simulate_cell
        res = simulate_cell(CellConfig(trials=8, seed=2))
        yield "cellsim.CellResult.plot", lambda p: res.plot(p)

    out = sys.argv[1]
    for name, draw in figures():
        before = set(os.listdir(out))
        fig = draw(None)
        assert isinstance(fig, Figure), (name, type(fig))
        assert set(os.listdir(out)) == before and not os.listdir("."), name + " wrote a file unasked"
        png = os.path.join(out, name + ".png")
        fig = draw(png)
        assert isinstance(fig, Figure), (name, type(fig))
        with open(png, "rb") as fh:
            assert fh.read(8) == b"\\x89PNG\\r\\n\\x1a\\n", name
        assert "matplotlib.pyplot" not in sys.modules, name + " imported pyplot"
        print("ok", name)
    assert dict.__getitem__(matplotlib.rcParams, "backend") == backend
""")


def test_every_plot_function_returns_a_figure_and_writes_only_when_asked(tmp_path):
    out = tmp_path / "out"
    cwd = tmp_path / "cwd"
    out.mkdir()
    cwd.mkdir()
    script = tmp_path / "figs.py"
    script.write_text(_SCRIPT, encoding="utf-8")
    run = subprocess.run([sys.executable, str(script), str(out)], cwd=cwd, capture_output=True, text=True,
                         timeout=300)
    assert run.returncode == 0, run.stderr[-3000:]
    assert run.stdout.count("ok ") == 5, run.stdout


def test_cosim_result_figure_is_typed():
    import typing

    from mtcomp.fmu.cosim import CosimResult
    hints = typing.get_type_hints(CosimResult.figure, globalns={**vars(sys.modules[CosimResult.__module__]),
                                                                "Figure": __import__("matplotlib.figure").figure.Figure})
    assert hints["return"].__name__ == "Figure"
    assert typing.get_type_hints(CosimResult.plot, globalns={
        **vars(sys.modules[CosimResult.__module__]),
        "Figure": __import__("matplotlib.figure").figure.Figure})["return"].__name__ == "Figure"
