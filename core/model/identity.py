"""Which machine a model belongs to, and the refusal to use it on another one.

A model folder (`mtcomp model export`) holds parameters named by axis letters and effects fitted
along one kinematic chain: on another machine the same names can mean other physics (X on the
workpiece side of one machine is on the tool side of another), so `model ssp`, `model
compensate` and `model resimulate` compare the machine the model was made for with the one
they are given: name, axes, and the chain (per axis, from the workpiece to the tool: kind,
side, direction).  The identity is written into model.toml by the export; an SSP archive's
machine FMU carries it in resources/machine.txt (mtcomp.fmu.build.machine_resource_text).
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from .._io import InputError


@dataclass(frozen=True)
class MachineIdentity:
    """name; axes (letters, workpiece to tool); chain: one "NAME kind side dx,dy,dz" per axis
    (directions rounded to 6 decimals; None when the source does not say)."""
    name: str
    axes: tuple | None = None
    chain: tuple | None = None

    def describe(self) -> str:
        return f"{self.name} (axes {' '.join(self.axes)})" if self.axes else self.name


def _axis_link(name, kind, side, direction) -> str:
    d = ",".join(f"{float(v):.6g}" if abs(float(v)) > 1e-9 else "0" for v in direction)
    return f"{name} {kind} {side} {d}"


def identity_of(machine) -> MachineIdentity:
    """The identity of a Machine (or preset name / TOML path)."""
    from ..machine import load_machine
    m = load_machine(machine)
    return MachineIdentity(m.name, tuple(m.axis_names),
                           tuple(_axis_link(a.name, a.kind, a.side, a.direction) for a in m.axes))


def identity_from_resource(text: str) -> MachineIdentity | None:
    """The identity in a machine FMU's resources/machine.txt (None when it names no machine)."""
    name, axes, chain = None, [], []
    for line in text.splitlines():
        w = line.split()
        if len(w) >= 2 and w[0] == "name":
            name = line.split(None, 1)[1].strip()
        elif len(w) >= 7 and w[0] == "axis":
            axes.append(w[1])
            chain.append(_axis_link(w[1], w[2], w[3], w[4:7]))
    return MachineIdentity(name, tuple(axes), tuple(chain)) if name else None


def manifest_fields(machine) -> dict:
    """The model.toml keys that identify the machine (besides `machine`, its name)."""
    ident = identity_of(machine)
    return {"machine_axes": list(ident.axes), "machine_chain": list(ident.chain)}


def identity_of_model(folder) -> MachineIdentity | None:
    """The identity recorded in a model folder's model.toml (None without one: a folder written
    by hand or before the identity was recorded; the name alone for older exports)."""
    from .._io import parse_toml, read_text
    path = Path(folder) / "model.toml"
    if not path.is_file():
        return None
    data = parse_toml(read_text(path, what="model manifest"), path)
    name = data.get("machine")
    if not isinstance(name, str):
        raise InputError("expected machine = \"NAME\" (the machine the model was exported for)", path,
                         field="machine")
    axes, chain = data.get("machine_axes"), data.get("machine_chain")
    return MachineIdentity(name, tuple(str(a) for a in axes) if isinstance(axes, list) else None,
                           tuple(str(c) for c in chain) if isinstance(chain, list) else None)


def mismatch(model: MachineIdentity, target: MachineIdentity) -> list:
    """What differs between the model's machine and the target machine (empty: the same)."""
    out = []
    if model.name != target.name:
        out.append(f"name {model.name!r} vs {target.name!r}")
    if model.axes is not None and target.axes is not None and model.axes != target.axes:
        out.append(f"axes {' '.join(model.axes)} vs {' '.join(target.axes)}")
    elif model.chain is not None and target.chain is not None and model.chain != target.chain:
        diff = [f"{a} vs {b}" for a, b in zip(model.chain, target.chain) if a != b]
        out.append("kinematic chain (axis kind side direction): " + "; ".join(diff))
    return out


def check_model_machine(folder, machine, *, what: str) -> None:
    """Refuse (InputError, exit 2) to use the model in `folder` on another machine than the one
    it was exported for.  what: the command, for the message."""
    model = identity_of_model(folder)
    if model is None:
        return
    target = identity_of(machine)
    diff = mismatch(model, target)
    if diff:
        raise InputError(f"the model was exported for machine {model.describe()}, not for {target.describe()} "
                         f"({'; '.join(diff)}): {what} refuses to apply one machine's model to another; "
                         "export the diagnosis again for this machine", Path(folder) / "model.toml", field="machine")
