"""Thermal offset compensation from the diagnosed thermal model (docs/model-loop.md, "Feeding
the compensation").

The machine FMU moves the tool edge by drift (T - T_ref) along the tool frame, T one machine
temperature (degC) with T' = (T_target - T)/tau (mtcomp.model.machine_ref.temperature).  What
drives T decides what a rewritten program can do:

- spindle speed (driver 0, T_target = ambient + gain |S|): the program's own S words (with M3,
  M4, M5, M2/M30) and its timeline (feeds, rapids) give S(t), so T(t) and the growth are
  predicted along the program and subtracted from the axis commands (`spindle_profile`,
  `predicted_temperature`, `thermal_correction`);
- none (driver 2, "time": the initial excess relaxes, a warm-up or cool-down): the same from the
  program time, the program starting at the model's t = 0;
- a logged temperature (driver 1): the future temperature is not in the program.  The control
  applies the law online from its sensor; `control_parameters` gives its parameters (gain per K,
  reference, time constant, initial state) and `control_offsets` is the law itself (causal: the
  offset at step k uses the readings up to k only).

Written by hand: the thermal model is mtcomp's own; no library predicts it from NC words.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .._io import InputError

#: address letters as the tokenizer numbers them (A = 0)
_S, _M = ord("S") - ord("A"), ord("M") - ord("A")
DRIVERS = {0: "spindle_speed", 1: "temperature", 2: "time"}


@dataclass(frozen=True)
class ThermalModel:
    """The machine FMU's thermal parameters (docs/model-loop.md): driver 0 spindle speed, 1
    logged temperature, 2 time; time_constant (s), gain (K per 1/min), ambient (degC),
    initial_excess (K), reference (degC, where the drift is zero), drift (3,) mm/K along the
    tool frame."""
    driver: int
    time_constant: float
    gain: float
    ambient: float
    initial_excess: float
    reference: float
    drift: tuple

    @classmethod
    def from_dynamics(cls, dyn) -> "ThermalModel | None":
        """From an mtcomp.fmu.build.MachineDynamics; None when it has no drift."""
        if not any(float(v) for v in dyn.drift):
            return None
        return cls(dyn.driver_code, float(dyn.thermal_time_constant), float(dyn.thermal_gain), float(dyn.ambient),
                   float(dyn.initial_excess), dyn.reference_temperature, tuple(float(v) for v in dyn.drift))

    def machine_dynamics(self):
        from ..fmu.build import MachineDynamics
        return MachineDynamics(thermal_driver=self.driver, thermal_time_constant=self.time_constant,
                               thermal_gain=self.gain, ambient=self.ambient, initial_excess=self.initial_excess,
                               reference=self.reference, drift=self.drift)


# ---------------------------------------------------------------- the program's spindle speed

def block_end_times(prog, machine, *, rapid: float = 3000.0, max_arc_step_deg: float = 1.0) -> np.ndarray:
    """(N,) time (s) at which each motion block of the parsed program ends, on the timeline of
    mtcomp.fmu.cosim.interpolate_program (the same lengths and rates: feed moves at F over
    sqrt(sum of squared axis moves), arcs as chords of at most max_arc_step_deg, G0 at `rapid`
    over the longest axis move)."""
    from ..fmu.cosim import block_points
    ix = {a: k for k, a in enumerate(machine.axis_names)}
    prev = np.asarray(prog.start, float)
    t = 0.0
    out = np.empty(len(prog))
    for b in range(len(prog)):
        end = np.asarray(prog.position[b], float)
        motion = int(prog.motion[b])
        seg = block_points(prog, b, prev, ix, max_arc_step_deg)
        rate = rapid if motion == 0 else float(prog.feed[b])
        last = prev
        for pnt in seg:
            d = pnt - last
            length = float(np.sqrt(np.sum(d ** 2)))
            if motion == 0 and length:
                length = float(np.max(np.abs(d)))
            if length > 0:
                t += length / rate * 60.0
            last = pnt
        out[b] = t
        prev = end
    return out


def spindle_states(prog) -> np.ndarray:
    """(N,) signed spindle speed (1/min; + M3, - M4, 0 stopped) in effect during each motion
    block: S is modal, M3/M4 start the spindle at the current S, M5, M2 and M30 stop it; the
    words of a block's own line act before its motion (as controls execute S and M3 first).
    The spindle is stopped before the first M3/M4."""
    order = np.argsort(prog.w_line, kind="stable")
    letters, values, lines = prog.w_letter[order], prog.w_value[order], prog.w_line[order]
    out = np.zeros(len(prog))
    s, sense = 0.0, 0.0
    w = 0
    for b in range(len(prog)):
        last_line = int(prog.line[b]) - 1     # 0-based line of the block
        while w < len(lines) and lines[w] <= last_line:
            if letters[w] == _S:
                s = float(values[w])
            elif letters[w] == _M:
                code = float(values[w])
                if code == 3:
                    sense = 1.0
                elif code == 4:
                    sense = -1.0
                elif code in (5, 2, 30):
                    sense = 0.0
            w += 1
        out[b] = sense * s
    return out


def spindle_profile(program, machine, step: float, *, rapid: float = 3000.0) -> np.ndarray:
    """(K,) signed spindle speed (1/min) at each sample of the program on the timeline of
    mtcomp.fmu.cosim.interpolate_program (sample t on the block that ends at or after t; t = 0 on
    the first block).  program: text, path or parsed Program."""
    from .. import gcode
    from ..fmu.cosim import interpolate_program
    from ..machine import load_machine
    machine = load_machine(machine)
    if isinstance(program, gcode.Program):
        prog = program
    else:
        from .._io import read_text
        name = "<string>" if "\n" in str(program) else str(program)
        text = program if name == "<string>" else read_text(program, what="NC program")
        prog = gcode.parse(text, axes=machine.axis_names, filename=name)
    t, _ = interpolate_program(prog, machine, step, rapid=rapid)
    ends = block_end_times(prog, machine, rapid=rapid)
    j = np.minimum(np.searchsorted(ends, t - 1e-9 * step, side="left"), len(ends) - 1)
    return spindle_states(prog)[j]


# ---------------------------------------------------------------- prediction and correction

def predicted_temperature(thermal: ThermalModel, K: int, step: float, spindle=None, *, lead: float = 0.0) -> np.ndarray:
    """(K,) machine temperature (degC) the axes meet when they act on command row k: the FMU's
    temperature at the end of step k + lead/step (lead: the transport delay, s), linear between
    steps; the spindle speed (1/min per sample, its magnitude heats) held at its last value
    beyond the end.  Driver 1 (logged temperature) cannot be predicted: InputError."""
    from .machine_ref import temperature
    if thermal.driver == 1:
        raise InputError("a thermal drift driven by a logged temperature cannot be predicted from the program: "
                         "the control applies it online (control_parameters)", field="thermal.driver")
    extra = int(math.ceil(lead / step)) + 1 if lead > 0 else 0
    s = np.abs(np.broadcast_to(np.asarray(0.0 if spindle is None else spindle, float), (K,)))
    if extra:
        s = np.concatenate([s, np.full(extra, s[-1])])
    T = temperature(K + extra, step, thermal.machine_dynamics(), s)
    if not lead:
        return T
    k = np.arange(K) * step + lead
    return np.interp(k, np.arange(K + extra) * step, T)


def thermal_offsets(machine, w: np.ndarray, thermal: ThermalModel, T: np.ndarray, errors=None) -> np.ndarray:
    """(K, 3) growth of the tool edge (mm, real workpiece frame) at commands w (K, n) and
    temperatures T (K,): R(w) drift (T - T_ref), R the tool frame (as the machine FMU adds it)."""
    from ..kinematics import forward
    pose = forward(machine, w, errors, strict=False)
    return np.einsum("nij,j->ni", pose.R, np.asarray(thermal.drift, float)) * (np.asarray(T) - thermal.reference)[:, None]


def thermal_correction(machine, w: np.ndarray, offsets: np.ndarray, errors=None, *, iterations: int = 2) -> np.ndarray:
    """Axis commands (K, n) that move the tool edge by -offsets (K, 3) from where w (K, n) puts
    it: the linear axes only (they move the edge without turning the tool), Newton steps with
    the position Jacobian of the full model (finite differences over 0.01 mm)."""
    from ..kinematics import forward
    lin = [i for i, a in enumerate(machine.axes) if not a.is_rotary]
    if len(lin) != 3:
        raise InputError(f"thermal compensation needs three linear axes, machine {machine.name} has {len(lin)}",
                         field="machine")
    w = np.asarray(w, float)
    target = forward(machine, w, errors, strict=False).p - offsets
    u = w.copy()
    hstep = 0.01
    for _ in range(iterations):
        p = forward(machine, u, errors, strict=False).p
        J = np.empty((len(u), 3, 3))
        for c, i in enumerate(lin):
            up = u.copy()
            up[:, i] += hstep
            J[:, :, c] = (forward(machine, up, errors, strict=False).p - p) / hstep
        du = np.linalg.solve(J, (target - p)[:, :, None])[:, :, 0]
        u[:, lin] += du
    return u


# ---------------------------------------------------------------- the control's parameters (logged temperature)

def control_parameters(thermal: ThermalModel, machine) -> dict:
    """The TOML structure of the control's thermal compensation for a drift driven by a logged
    temperature (docs/model-loop.md): temperatures relative to the sensor's reading at program
    start, so the law needs no absolute calibration."""
    return {"thermal_compensation": {
        "machine": machine.name,
        "driver": "temperature",
        "sensor": "temperature [degC]",
        "time_constant_s": float(thermal.time_constant),
        "gain_mm_per_K": [float(v) for v in thermal.drift],
        "reference_K": float(thermal.reference - thermal.ambient),
        "initial_excess_K": float(thermal.initial_excess),
        "law": "D(0) = initial_excess_K; each step h: D += (u - u_start - D) (1 - exp(-h/time_constant_s)); "
               "offset = -gain_mm_per_K (D - reference_K) along the tool frame x, y, z (mm)",
    }}


def control_file_text(params: dict) -> str:
    """The TOML text of `control_parameters` with its header."""
    from .._io import dump_toml
    head = ("# mtcomp thermal compensation for the control (docs/model-loop.md): the drift follows a logged\n"
            "# temperature the program cannot know; the control applies this law online from its sensor\n")
    return head + dump_toml(params)


def control_offsets(params: dict, sensor: np.ndarray, step: float) -> np.ndarray:
    """(K, 3) tool-frame offsets (mm) the control adds at each step from the sensor readings
    (K,) degC, by the law of `control_parameters` (causal: step k uses readings 0..k)."""
    p = params.get("thermal_compensation", params)
    u = np.asarray(sensor, float)
    g = -math.expm1(-step / float(p["time_constant_s"]))
    D = float(p["initial_excess_K"])
    out = np.empty(len(u))
    for k in range(len(u)):
        D += (u[k] - u[0] - D) * g
        out[k] = D
    return -np.outer(out - float(p["reference_K"]), np.asarray(p["gain_mm_per_K"], float))
