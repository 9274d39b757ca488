"""The whole loop in one call: recording -> diagnosis -> model export -> (prune) -> re-simulation.

Used by the tests and benchmarks/model_loop.py; the CLI runs the same steps one command each.
"""
from __future__ import annotations

import tempfile
from dataclasses import dataclass
from pathlib import Path

from ..machine import load_machine
from .simulate import OUTPUTS, Signals, compare, prune, signals_csv, simulate, velocity_axis  # noqa: F401


@dataclass(frozen=True)
class LoopResult:
    """diagnosis (DiagnosisResult), export (ModelExport, after pruning), result (ResimResult on
    the held-out samples), train_until (s): the diagnosis saw only t < train_until."""
    diagnosis: object
    export: object
    result: object
    train_until: float
    prune_log: tuple = ()


def close_loop(rec: Signals, nominal: Signals, *, program, machine, errors=None, dynamics=None, step: float,
               train: float = 0.6, outputs=None, do_prune: bool = True, do_refine: bool = False,
               refine_stride: int = 4, workdir=None, compiler: str = "cmake", do_complete: bool = False) -> LoopResult:
    """Diagnose REC against the nominal SIM on the first `train` fraction of the samples, export
    the effects into the model, prune them through the model on the same samples (and with
    do_refine refit their scalars through it, every `refine_stride`-th training sample),
    re-simulate and compare on the rest (held out).  errors/dynamics: the nominal model's.
    outputs: the outputs to diagnose (default: x, y, z); velocity outputs v<AXIS> (the axes'
    actual velocities) are written to both CSVs when named, and compared in the re-simulation.
    do_complete: try the backlash of every reversing axis the model lacks, refitted through the
    model with everything else and kept only when samples the fit did not see agree
    (mtcomp.model.complete)."""
    from ..diagnose import diagnose
    from .export import export_model
    machine = load_machine(machine)
    tmp = tempfile.TemporaryDirectory(prefix="mtcomp-loop-") if workdir is None else None
    wd = Path(tmp.name if tmp else workdir)
    try:
        n_train = int(train * len(rec.t))
        vaxes = [a for a in (velocity_axis(o, machine.axis_names) for o in (outputs or ())) if a]
        (wd / "sim.csv").write_text(signals_csv(nominal, machine, vaxes))
        lines = signals_csv(rec, machine, vaxes).splitlines()
        (wd / "rec.csv").write_text("\n".join(lines[:1 + n_train]) + "\n")
        # the programmed angles are in both files (signals_csv): inputs of the effects, not outputs
        angles = [a.name.lower() for a in machine.axes if a.is_rotary]
        # so are the logged drivers of the thermal drift (spindle speed, temperature)
        angles += [k for k in rec.inputs]
        diag = diagnose(str(wd / "sim.csv"), str(wd / "rec.csv"), outputs=outputs, inputs=angles or None)
        t_split = float(rec.t[n_train])
        # v_s of friction on a velocity output (2 % of SIM's peak speed) from the diagnosis' own
        # aligned SIM (export_model's default for a DiagnosisResult)
        ex = export_model(diag, machine, None, step=step, drivers={k: float(v[0]) for k, v in rec.inputs.items()},
                          servo_interpolation=bool(getattr(dynamics, "interpolation", 0)))
        rec_out = {o: rec.p[:, k] for k, o in enumerate(OUTPUTS)}
        rec_out.update({f"v{a}": rec.output(f"v{a}") for a in vaxes})
        log: list = []
        drv = {"spindle_speed": rec.inputs.get("spindle_speed", 0.0), "temperature": rec.inputs.get("temperature")}
        if do_prune and ex.mapped:
            ex = prune(ex, rec.t, rec_out, program=program, machine=machine, errors=errors, dynamics=dynamics,
                       step=step, train_until=t_split, noise_floor=diag.noise_floor, compiler=compiler, log=log,
                       **drv)
        if do_refine and ex.params:
            from .simulate import refine
            ex = refine(ex, rec.t, rec_out, program=program, machine=machine, errors=errors, dynamics=dynamics,
                        step=step, train_until=t_split, noise_floor=diag.noise_floor, compiler=compiler,
                        stride=refine_stride, log=log, **drv)
        if do_complete:
            from .complete import complete
            ex = complete(ex, rec.t, rec_out, program=program, machine=machine, q=rec.q, log=log, errors=errors,
                          dynamics=dynamics, step=step, train_until=t_split, noise_floor=diag.noise_floor,
                          compiler=compiler, stride=refine_stride, **drv)
        from dataclasses import replace

        from ..errors import ErrorSet
        from ..fmu.build import MachineDynamics
        from .simulate import _updated_model
        base_dyn = replace(dynamics or MachineDynamics(), noise=0.0)
        e, d = _updated_model(ex, machine, errors or ErrorSet(), base_dyn, True)
        upd = simulate(program, machine, e, d, step=step, compiler=compiler, **drv)
        res = compare(rec.t, rec_out, nominal, upd, heldout_from=t_split, noise_floor=diag.noise_floor)
        return LoopResult(diag, ex, res, t_split, tuple(log))
    finally:
        if tmp:
            tmp.cleanup()
