"""Co-simulation outputs (issue 19 item 5, issue 16 item 5): cutting and rapid moves reported
apart, decimated CSV by default, progress, figures that leave the caller's matplotlib alone,
failures that name the step; the FMUs are built from the C sources and run for real."""
from __future__ import annotations

import csv
import os
from pathlib import Path

import numpy as np
import pytest

fmpy = pytest.importorskip("fmpy")
from mtcomp.errors import ErrorSet, ToolSetting, WorkpieceSetting  # noqa: E402
from mtcomp.fmu.build import MachineDynamics  # noqa: E402
from mtcomp.fmu.cosim import CosimFailed, cosimulate, interpolate_program  # noqa: E402
from mtcomp.machine import load_machine  # noqa: E402

SETTING = ErrorSet(ToolSetting((0.35, -0.20, 0.15)), WorkpieceSetting((0.10, -0.05, 0.02), (0.01, -0.02, 0.03)))
PROGRAM = "G90 G0 X0 Y0 Z0 B10 C0\nG0 X20 Y5\nG1 X30 F600\nG1 Y10 F600\nG0 X0\n"


from _fmpy import binary_cache, live_fmpy_logger  # noqa: E402,F401 (autouse fixtures of the FMU tests)


@pytest.fixture(scope="module")
def lagging(tmp_path_factory):
    """The program on a machine with 30 1/s servos: the rapids lag by millimetres."""
    calls = []
    res = cosimulate(PROGRAM, "robonano-a0ib", SETTING, step=2e-3, compiler="cc",
                     dynamics=MachineDynamics(kv=30.0), workdir=tmp_path_factory.mktemp("w"),
                     progress=lambda done, total: calls.append((done, total)))
    return res, calls


def test_interpolation_marks_the_rapids():
    m = load_machine("robonano-a0ib")
    t, q, rapid = interpolate_program("G90 G0 X10\nG1 X20 F600\n", m, 0.01, with_rapid=True)
    # 10 mm at the 3000 mm/min rapid rate = 0.2 s, then 10 mm at 600 mm/min = 1 s
    assert t[-1] == pytest.approx(1.2)
    assert rapid[1:20].all() and not rapid[21:].any()
    assert len(rapid) == len(t) == len(q)


def test_cutting_and_rapid_errors_are_reported_apart(lagging):
    res, _ = lagging
    rapid = res.is_rapid
    assert rapid.any() and (~rapid).any()
    e = res.error_compensated
    # following error = feed / kv: 50 mm/s / 30 1/s = 1.7 mm on a rapid, 10 mm/s / 30 = 0.33 mm
    # at F600 once the lag carried over from a rapid has died out
    assert e[rapid].max() == pytest.approx(50 / 30, rel=0.03)
    assert np.median(e[~rapid]) == pytest.approx(10 / 30, rel=0.03)
    assert res.max_compensated == pytest.approx(e[~rapid].max())
    text = res.summary()
    assert "cutting:" in text and "G0 rapids:" in text
    assert " um" not in text and "µm" in text
    # what is left after removing the lag is at rounding level, printed in nm, not "0.0000"
    assert "0.0000" not in text and " nm" in text


def test_progress_runs_to_the_end_over_both_runs(lagging):
    res, calls = lagging
    assert calls and calls[-1][0] == calls[-1][1] == 2 * len(res.t)
    assert all(b[0] >= a[0] for a, b in zip(calls, calls[1:]))


def test_csv_is_decimated_by_default_and_full_on_request(tmp_path):
    m = load_machine("vmc-moving-column")
    k = 25_000
    q = np.column_stack([np.linspace(0, 10, k), np.zeros(k), np.linspace(0, -5, k)])
    res = cosimulate(q, m, ErrorSet(ToolSetting((0.01, 0.0, 0.0))), step=1e-3, compiler="cc")
    assert res.default_stride() == 3
    rows = list(csv.reader(open(res.to_csv(tmp_path / "d.csv"))))
    assert "every 3. of 25000 steps" in ",".join(rows[0])
    assert len(rows) - 2 == 8334
    assert float(rows[3][0]) == pytest.approx(3e-3)       # steps 0, 3, 6, ... of the run
    full = list(csv.reader(open(res.to_csv(tmp_path / "f.csv", full=True))))
    assert len(full) - 2 == k and full[1][-4] == "rapid"
    # the compensation works on this path too: 10 µm tool offset gone to rounding level
    assert res.max_uncompensated == pytest.approx(0.01, rel=1e-6) and res.max_compensated < 1e-9


def test_figure_leaves_the_callers_backend_and_pyplot_alone(lagging, tmp_path):
    import matplotlib
    before = matplotlib.get_backend()
    import sys
    had_pyplot = "matplotlib.pyplot" in sys.modules
    res, _ = lagging
    fig = res.figure()
    assert type(fig).__name__ == "Figure"
    labels = [ax.get_ylabel() for ax in fig.axes]
    assert all("µm" in lab for lab in labels) and not any("(um)" in lab for lab in labels)
    assert isinstance(res.plot(tmp_path / "err.png"), type(fig))
    assert (tmp_path / "err.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert isinstance(res.plot(), type(fig))
    assert matplotlib.get_backend() == before
    if not had_pyplot:
        assert "matplotlib.pyplot" not in sys.modules
    else:
        import matplotlib.pyplot as plt
        assert not plt.get_fignums()


def test_a_failed_step_names_the_step_time_and_the_fmu_message(tmp_path):
    m = load_machine("vmc-moving-column")
    q = np.zeros((50, 3))
    q[30:, 0] = 1e4          # X far beyond the travel from step 30 on
    with pytest.raises(CosimFailed, match=r"step 30 \(t = 0\.03 s\).*command\.X.*outside the travel"):
        cosimulate(q, m, ErrorSet(), step=1e-3, compiler="cc", workdir=tmp_path)
    assert not list(Path(tmp_path).glob("*.csv"))


def test_the_stepping_loop_in_c_is_the_python_loop(tmp_path, monkeypatch):
    """The co-simulation steps the FMUs from C (fmu/c/cosim_loop.c in the kernel library); the
    Python loop, its fallback without the library, makes the same calls in the same order: the
    same commands, tool positions and axis positions bit for bit, with a lagging machine whose
    state carries from step to step."""
    from mtcomp import _kernel
    from mtcomp.fmu import build as b
    from mtcomp.fmu import cosim
    if not _kernel.available():
        pytest.skip("no kernel library")
    m = load_machine("robonano-a0ib")
    t, q = interpolate_program(PROGRAM, m, 2e-3)
    mach = b.build_machine_fmu(m, tmp_path / "m.fmu", SETTING, MachineDynamics(kv=30.0), compiler="cc")
    comp = b.build_compensator_fmu(m, tmp_path / "c.fmu", SETTING, compiler="cc")
    calls = []
    in_c = cosim._run(m, q, 2e-3, mach, comp, 0.0, lambda d, k: calls.append((d, k)))
    assert calls[-1] == (len(q), len(q)) and len(calls) < len(q) / 5   # one ctypes call per report
    monkeypatch.setattr(cosim, "_c_loop", lambda *a: None)
    in_py = cosim._run(m, q, 2e-3, mach, comp, 0.0)
    for a, c in zip(in_c, in_py):
        assert np.array_equal(a, c)
    assert np.max(np.abs(in_c[0] - q)) > 0.1     # the compensator acted (0.35 mm tool offset)
