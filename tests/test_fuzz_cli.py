"""Property test of the core command line (`compensate`, `machines`): any combination of options
and values ends with exit status 0 or 2, one error line and no traceback, and no half-written
output.  In process, seeded and derandomized, a few seconds in CI."""
import contextlib
import io

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from mtcomp.cli import main

FUZZ = settings(max_examples=40, derandomize=True, deadline=None, database=None,
                suppress_health_check=[HealthCheck.too_slow])

PROGRAM = "O0001\nG21 G90 G17\nG0 X0 Y0 Z5. B0 C0\nG1 Z0 F100\nX1. Y0.5 C10.\nG2 X2. Y0 I0.5 J-0.5\nM30\n"


@pytest.fixture(scope="module")
def work(tmp_path_factory):
    d = tmp_path_factory.mktemp("fuzz-cli")
    (d / "p.nc").write_text(PROGRAM)
    (d / "e.toml").write_text("[tool_setting]\noffset = [0.01, -0.02, 0.005]\n")
    (d / "bad.toml").write_text("[geometric.location]\nEX0U = 1\n")
    (d / "afile").write_text("x")
    (d / "adir").mkdir()
    return d


# "@/" stands for the work folder
PATHS = ["@/" + n for n in ("p.nc", "e.toml", "bad.toml", "afile", "adir", "missing.nc", "out.nc",
                                  "adir/out.nc", "nodir/out.nc")] + ["", "/dev/null", "/dev/zero", "-"]
VALUES = ["0", "-1", "nan", "inf", "1e400", "0.1", "abc", "robonano-a0ib", "robonano-ui", "vmc-moving-column",
          "no-such"]
OPTIONS = ["-m", "--machine", "-e", "--errors", "-o", "--output", "--chordal-tol", "--inch", "--progress",
           "--debug", "--help", "--", "--bogus"]


@FUZZ
@given(st.sampled_from(["compensate", "machines"]),
       st.lists(st.one_of(st.sampled_from(PATHS), st.sampled_from(VALUES), st.sampled_from(OPTIONS)), max_size=8))
def test_cli_options_never_crash(work, command, argv):
    argv = [a.replace("@/", f"{work}/") for a in argv]
    for p in work.rglob("out.nc"):
        p.unlink()
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            rc = main([command, *argv])
        except SystemExit as exc:  # argparse: usage error or --help
            rc = exc.code
    e = err.getvalue()
    assert rc in (0, 2), e
    assert "Traceback" not in e and "internal error" not in e, e
    if rc == 2:
        assert "error:" in e
    assert not [p for p in work.rglob("*.tmp")], "half-written output left behind"
    assert not (work / "nodir").exists()


@pytest.mark.slow
def test_fuzz_campaign_harness_counts(tmp_path):
    """benchmarks/fuzz.py end to end on two core surfaces: every input is counted once, none of
    them gives a traceback, a hang or a half-written output, and failures keep a reproducer."""
    import sys
    from pathlib import Path
    root = Path(__file__).resolve().parent.parent
    sys.path.insert(0, str(root / "benchmarks"))
    try:
        import fuzz
    finally:
        sys.path.remove(str(root / "benchmarks"))
    res = fuzz.campaign(6, 3, 20.0, ["errors-csv", "machine-toml", "cli-options"], tmp_path / "repro", 3000)
    assert set(res) == {"errors-csv", "machine-toml", "cli-options"}
    for name, c in res.items():
        assert c["tried"] == 6 == c["accepted"] + c["refused"] + c["tracebacks"] + c["hangs"], (name, c)
        assert c["tracebacks"] == c["hangs"] == c["half_written"] == 0, (name, c["kinds"])
    assert res["errors-csv"]["refused"] > 0  # the mutations reach the reader's checks


@pytest.mark.slow
def test_fuzz_workers_give_the_same_counts_as_one_process(tmp_path):
    """--jobs splits the surfaces over forked workers; each surface has its own seeded generator,
    so the counts (all but CPU time) are those of a single-process run, and --merge of two partial
    --json runs reports the union."""
    import argparse
    import json
    import sys
    from pathlib import Path
    root = Path(__file__).resolve().parent.parent
    sys.path.insert(0, str(root / "benchmarks"))
    try:
        import fuzz
    finally:
        sys.path.remove(str(root / "benchmarks"))
    names = ["errors-csv", "machine-toml", "cell-journal"]
    one = fuzz.campaign(5, 4, 20.0, names, None, 3000)
    a = argparse.Namespace(per_surface=5, seed=4, timeout=20.0, repro_dir=None, memory_mb=3000,
                           show=False, jobs=2)
    two = fuzz.parallel_campaign(a, names)
    assert list(two) == names
    strip = lambda r: {n: {k: v for k, v in c.items() if k != "cpu"} for n, c in r.items()}  # noqa: E731
    assert strip(two) == strip(one)
    meta = dict(per_surface=5, seed=4, timeout=20.0, wall=1.0, jobs=1)
    for i, part in enumerate((["errors-csv"], ["machine-toml", "cell-journal"])):
        (tmp_path / f"{i}.json").write_text(json.dumps({"meta": meta, "results": {n: one[n] for n in part}}))
    assert fuzz.merge([tmp_path / "0.json", tmp_path / "1.json"], no_docs=True) == 0
