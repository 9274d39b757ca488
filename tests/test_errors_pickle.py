"""Error sets cross process boundaries (the demo's second process, Dask workers): pickling keeps
them equal, tables and location errors included (a mappingproxy alone cannot be pickled)."""
import pickle

import numpy as np

from mtcomp.errors import AxisErrorTable, ErrorSet, GeometricErrors, WorkpieceSetting


def test_error_set_with_tables_pickles_to_an_equal_one():
    t = AxisErrorTable("X", [0.0, 50.0, 100.0], {"EXX": [0.0, 1e-3, 3e-3], "EBX": [0.0, 2e-6, 1e-6]})
    g = GeometricErrors(tables={"X": t}, location={"EC0Y": 5e-6})
    e = ErrorSet(workpiece=WorkpieceSetting((0.01, 0.0, -0.002), (0.0, 0.001, 0.0)), geometric=g)
    back = pickle.loads(pickle.dumps(e))
    tb = back.geometric.tables["X"]
    assert tb.axis == "X" and np.array_equal(tb.position, t.position)
    assert set(tb.values) == {"EXX", "EBX"} and np.array_equal(tb.values["EXX"], t.values["EXX"])
    assert dict(back.geometric.location) == {"EC0Y": 5e-6}
    assert back.workpiece == e.workpiece
    assert not tb.position.flags.writeable   # still frozen after the round trip
