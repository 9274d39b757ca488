"""`mtcomp demo --quick`: the whole system on virtual data (CAD, tool setting, Modbus cell,
FMU co-simulation, pyramid check, diagnosis), checked against the truths it hides."""
import json
import subprocess
import sys

import numpy as np


def test_demo_quick(tmp_path):
    out = tmp_path / "demo"
    r = subprocess.run([sys.executable, "-m", "mtcomp", "demo", "--quick", "--out", str(out)],
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-3000:]
    for k in range(1, 8):
        assert f"[{k}/7]" in r.stdout
    html = (out / "report.html").read_text()
    assert html.count("data:image/png;base64,") >= 3 and "<script" not in html
    assert (out / "cad" / "pyramid.step").stat().st_size > 1000
    # The diagnosis names the concealed backlash.
    diag = json.loads((out / "diagnose" / "diagnosis.json").read_text())
    assert "backlash" in [e["name"] for e in diag["effects"]]
    # The co-simulation: compensation removes most of the placement error.
    data = np.genfromtxt(out / "cosim.csv", delimiter=",", names=True, skip_header=1)
    assert data["error_compensated_um"].max() < 0.2 * data["error_uncompensated_um"].max()
    # The compensated program the cell wrote exists and differs from the nominal one.
    assert (out / "nc" / "O1100.nc").read_text() != (out / "nc" / "O0100.nc").read_text()
