"""mtcomp.cell: Modbus TCP bridge to the PLC of the robot loading cell (docs/cell.md).

Modules: registers (the map and codecs), journal (append-only, fsync), cycle (state machine),
server (mtcomp as Modbus server), client (mtcomp polls a PLC server), plcsim (PLC + robot
simulator), virtual (the virtual cell's measurement step), cli. pymodbus is imported only when
a server, client or simulator starts.
"""


def __getattr__(name):
    # lazy, so that `import mtcomp.cell` stays light
    if name == "run_virtual_cell_once":
        from .server import run_virtual_cell_once
        return run_virtual_cell_once
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
