"""The closed loop told end to end (the demo's stage and docs/model-loop.md): a machine with
effects its nominal model lacks -> recording -> diagnosis -> updated model (its re-simulation
matches the recording to about the noise) -> compensated program -> co-simulated part error.

The machine: vmc-moving-column with a squareness of X to Y (EC0Y), a backlash and a servo lag on
X and 20 nm sensor noise in the recording; the nominal model has none of them.  A second part
(`run_dynamics_story`, the demo runs both) tells the same story for the dynamic effects the
first machine has not: stick-slip friction at X's reversals and a thermal drift along z driven
by the program's spindle speed, on a circle test with S words; its part error is shown without
compensation, with each diagnosed effect compensated alone and with both.  Everything runs
through the machine FMU (mtcomp.fmu.cosim)."""
from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .._io import atomic_write

MACHINE = "vmc-moving-column"
#: zig-zag in X and Y at 10 mm/s: reversals of both axes (backlash), corners (servo lag)
PROGRAM = """G90 G1 F600
X0 Y0 Z0
X12 Y5
X-10 Y-8
X8 Y9
X-12 Y-4
X6 Y-9
X0 Y0
"""
SQUARENESS = 1.5e-4      # rad, EC0Y
BACKLASH_X = 0.004       # mm
KV_X = 60.0              # 1/s
NOISE = 2e-5             # mm


#: the second part: two turns and a half of a circle (r = 10 mm, F1200: X and Y reverse smoothly),
#: the spindle started at 3000 1/min and raised to 6000 1/min after the first turn
DYN_PROGRAM = """G90 G1 F1200
X0 Y0 Z0
S3000 M3
G3 X0 Y0 I0 J10
S6000
G3 X0 Y0 I0 J10
G3 X0 Y0 I0 J10
"""
BREAKAWAY_X = 0.003      # mm, friction.breakaway.X
FRICTION_TAU_X = 0.03    # s
THERMAL_TAU = 3.0        # s, thermal.time_constant (short: the program lasts 9.4 s)
THERMAL_GAIN = 1e-3      # K per 1/min
DRIFT_Z = 0.004          # mm/K along z


@dataclass(frozen=True)
class Story:
    """Numbers and signals of one run: truth {parameter: value}; loop (mtcomp.model.loop.LoopResult);
    rec, nominal, updated (Signals); part {"none"|"geometric"|"+backlash"|"+servo": {"max", "rms"} mm};
    folder: where the files are; outputs: the tool edge coordinates the figure shows; dynamics:
    the second part (a Story of `run_dynamics_story`) or None."""
    truth: dict
    loop: object
    rec: object
    nominal: object
    updated: object
    part: dict
    folder: Path
    program: str
    outputs: tuple = ("x",)
    dynamics: object = None

    def fitted(self) -> dict:
        return {p.name: (p.value, p.sigma) for p in self.loop.export.params}

    def to_dict(self) -> dict:
        """The numbers (mm, 1/s, rad): truth, fitted (value, sigma), held-out RMS before/after per
        output, noise floors, part errors."""
        res = self.loop.result
        d = {"machine": MACHINE, "truth": self.truth,
             "fitted": {k: list(v) for k, v in self.fitted().items()},
             "heldout_rms": res.heldout_rms, "noise": NOISE, "train_until_s": self.loop.train_until,
             "part_error": self.part}
        if self.dynamics is not None:
            d["dynamics"] = self.dynamics.to_dict()
        return d

    def summary(self) -> str:
        res = self.loop.result
        f = self.fitted()
        lines = ["closing the loop on " + MACHINE + ":"]
        for k, v in self.truth.items():
            got = f.get(k)
            lines.append(f"  {k}: truth {v:.6g}, model {got[0]:.6g} +/- {got[1]:.2g}" if got else
                         f"  {k}: truth {v:.6g}, not in the model")
        for o in self.outputs:
            lines.append(f"  held-out RMS of REC - model on {o}: original {res.heldout_rms['before'][o] * 1e3:.3g} µm, "
                         f"updated {res.heldout_rms['after'][o] * 1e6:.3g} nm (noise {NOISE * 1e6:.0f} nm)")
        for k, v in self.part.items():
            lines.append(f"  part error, compensation {k}: max {v['max'] * 1e3:.3g} µm, RMS {v['rms'] * 1e3:.3g} µm")
        if self.dynamics is not None:
            lines.append(self.dynamics.summary().replace("closing the loop on", "and for friction and thermal drift on"))
        return "\n".join(lines)

    def figure(self):
        """One figure: x deviation from the programmed path over time (µm) of the recording, the
        original and the updated model; REC - updated model (nm) with the noise; the part error
        of the program compensated without and with the diagnosed effects."""
        from matplotlib.figure import Figure
        no = len(self.outputs)
        fig = Figure(figsize=(11, 4.2 + 3.0 * no), layout="constrained")
        gs = fig.add_gridspec(1 + no, 2, height_ratios=(1.3,) * no + (1,))
        t = self.rec.t
        for r, o in enumerate(self.outputs):
            k = "xyz".index(o)
            ax = fig.add_subplot(gs[r, :])
            ideal = self.nominal.p[:, k]   # the nominal model is the programmed path
            ax.plot(t, (self.rec.p[:, k] - ideal) * 1e3, color="0.55", lw=2.2, label="recording")
            ax.plot(t, (self.nominal.p[:, k] - ideal) * 1e3, color="tab:red", lw=1, label="original model")
            ax.plot(self.updated.t, (self.updated.p[:, k] - ideal[:len(self.updated.t)]) * 1e3, color="tab:blue",
                    lw=0.8, ls="--", label="updated model (re-simulated)")
            ax.axvspan(self.loop.train_until, t[-1], color="0.92", zorder=0)
            ax.set_xlabel("t [s]  (shaded: held out from the diagnosis)")
            ax.set_ylabel(f"{o} − programmed {o} [µm]")
            ax.set_title(f"tool edge {o}: recording, original and updated model", fontsize=10)
            ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8, frameon=False)
        res = self.loop.result
        ax = fig.add_subplot(gs[no, 0])
        worst = max(self.outputs, key=lambda o: res.heldout_rms["after"][o])
        for o in self.outputs:
            ax.plot(res.t, (res.rec[o] - res.updated[o]) * 1e6, lw=0.5, label=o)
        ax.axhline(0, color="k", lw=0.5)
        ax.set_xlabel("t [s]")
        ax.set_ylabel(f"{', '.join(self.outputs)} error [nm]")
        if no > 1:
            ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8, frameon=False)
        ax.set_title(f"recording − updated model: held-out RMS {res.heldout_rms['after'][worst] * 1e6:.1f} nm "
                     f"on {worst} (noise {NOISE * 1e6:.0f} nm)", fontsize=9)
        ax = fig.add_subplot(gs[no, 1])
        names = list(self.part)
        x = np.arange(len(names))
        ax.bar(x - 0.2, [self.part[k]["max"] * 1e3 for k in names], 0.4, color="tab:red", label="max")
        ax.bar(x + 0.2, [self.part[k]["rms"] * 1e3 for k in names], 0.4, color="tab:blue", label="RMS")
        ax.set_yscale("log")
        label = {"+backlash": "+ backlash", "+servo": "+ servo\nfeed-forward", "+friction": "+ friction\nspikes",
                 "+thermal": "+ thermal\noffsets", "friction": "friction\nonly", "thermal": "thermal\nonly",
                 "friction+thermal": "friction\n+ thermal"}
        ax.set_xticks(x, [label.get(k, k) for k in names], fontsize=8)
        ax.set_ylabel("part error [µm]")
        ax.set_title("co-simulated part error by compensation", fontsize=9)
        ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8, frameon=False)
        return fig


# The story asks for the servo feed-forward (`model compensate --max-feed`): by default the
# compensation writes no feed above the program's fastest, and the lag's lead needs more
# (docs/model-loop.md, "What model compensate writes").  1 m/s: the machine's rapid range.
ASKED_FEED = 60000.0


def run_story(out, *, quick: bool = False, seed: int = 7, step: float = 2e-3, compiler: str = "cc",
              dynamics: bool = True) -> Story:
    """Run the loop end to end into folder `out` (created): sim.csv and rec.csv with their
    provenance, the program, the model folder, the compensated programs; with `dynamics` the
    second part too (friction and thermal drift, `run_dynamics_story`, into out/dynamics)."""
    from ..errors import ErrorSet, GeometricErrors
    from ..fmu.build import MachineDynamics
    from .compensate import compensate_with_model, compensation_stages, model_dynamics, part_error
    from ..machine import load_machine
    from .export import write_export
    from .loop import close_loop
    from .simulate import _updated_model, simulate, write_signals
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    # one program for both: a shorter one leaves the backlash and the squareness to the
    # diagnosis' stand-ins (quadrant glitch); quick refits on fewer samples
    program = PROGRAM
    prog_path = out / "part.nc"
    prog_path.write_text(program)
    true_err = ErrorSet(geometric=GeometricErrors({}, {"EC0Y": SQUARENESS}))
    true_dyn = MachineDynamics(kv=(KV_X, 0.0, 0.0), backlash=(BACKLASH_X, 0.0, 0.0))
    truth = {"servo.kv.X": KV_X, "backlash.X": BACKLASH_X, "location.EC0Y": SQUARENESS}
    from dataclasses import replace
    nominal = simulate(program, MACHINE, None, None, step=step, compiler=compiler)
    rec = simulate(program, MACHINE, true_err, replace(true_dyn, noise=NOISE, seed=seed), step=step,
                   compiler=compiler)
    write_signals(out / "sim.csv", nominal, MACHINE, program=prog_path, step=step)
    write_signals(out / "rec.csv", rec, MACHINE, program=prog_path, step=step)
    lr = close_loop(rec, nominal, program=program, machine=MACHINE, step=step, train=0.6, do_prune=True,
                    do_refine=True, refine_stride=8 if quick else 4, compiler=compiler)
    write_export(lr.export, out / "model")
    e, d = _updated_model(lr.export, load_machine(MACHINE), ErrorSet(), MachineDynamics(), True)
    updated = simulate(program, MACHINE, e, d, step=step, compiler=compiler)
    # compensate with the model, switch by switch; the machine runs noise-free (part error)
    dyn_m = model_dynamics(lr.export.dynamics_values, MACHINE, step)
    part = {}
    # the stages of `model compensate --cosim`: + friction / + thermal too if the updated model had them
    for name, kw in compensation_stages(dyn_m, MACHINE):
        text = program if kw is None else compensate_with_model(program, MACHINE, lr.export.errors, dyn_m,
                                                                max_feed=ASKED_FEED, **kw)[0]
        if kw is not None:
            (out / f"part-{name.strip('+')}.nc").write_text(text)
        sig = simulate(text, MACHINE, true_err, true_dyn, step=step, compiler=compiler)
        pe = part_error(program, sig, MACHINE)
        part[name] = {"max": pe["max"], "rms": pe["rms"], "reach": pe["reach"]}
    dyn_story = run_dynamics_story(out / "dynamics", seed=seed, step=step, compiler=compiler) if dynamics else None
    story = Story(truth, lr, rec, nominal, updated, part, out, program, dynamics=dyn_story)
    atomic_write(out / "story.json", json.dumps(story.to_dict(), indent=2) + "\n")
    return story


def run_dynamics_story(out, *, seed: int = 7, step: float = 2e-3, compiler: str = "cc") -> Story:
    """The second part into folder `out`: a vmc-moving-column with stick-slip friction on X
    (breakaway 3 µm, catch-up 30 ms) and a thermal drift along z (4 µm/K, 3 s, 1 K per 1000 1/min
    of the spindle), the spindle following the program's S words (logged in SIM and REC as the
    driver); diagnosed on the first 60 %, exported, pruned, re-simulated (no refinement: the
    thermal sigmas are the diagnosis' conditional ones, docs/model-loop.md); the program
    compensated without, with each effect alone and with both (`model compensate`'s friction and
    thermal switches), each co-simulated on the machine (noise-free)."""
    from dataclasses import replace

    import numpy as np

    from ..errors import ErrorSet
    from ..fmu.build import MachineDynamics
    from ..machine import load_machine
    from .compensate import compensate_with_model, model_dynamics, part_error
    from .export import write_export
    from .loop import close_loop
    from .simulate import _updated_model, simulate, write_signals
    from .thermal_comp import spindle_profile
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    program = DYN_PROGRAM
    prog_path = out / "circle.nc"
    prog_path.write_text(program)
    sp = np.abs(spindle_profile(program, MACHINE, step))
    true_dyn = MachineDynamics(friction_breakaway=(BREAKAWAY_X, 0.0, 0.0), friction_tau=(FRICTION_TAU_X, 0.0, 0.0),
                               thermal_gain=THERMAL_GAIN, thermal_time_constant=THERMAL_TAU, drift=(0.0, 0.0, DRIFT_Z))
    truth = {"friction.breakaway.X": BREAKAWAY_X, "friction.tau.X": FRICTION_TAU_X,
             "thermal.time_constant": THERMAL_TAU, "thermal.drift.z": DRIFT_Z}
    nominal = simulate(program, MACHINE, None, None, step=step, compiler=compiler, spindle_speed=sp)
    rec = simulate(program, MACHINE, None, replace(true_dyn, noise=NOISE, seed=seed), step=step, compiler=compiler,
                   spindle_speed=sp)
    write_signals(out / "sim.csv", nominal, MACHINE, program=prog_path, step=step)
    write_signals(out / "rec.csv", rec, MACHINE, program=prog_path, step=step)
    lr = close_loop(rec, nominal, program=program, machine=MACHINE, step=step, train=0.6, do_prune=True,
                    do_refine=False, compiler=compiler)
    write_export(lr.export, out / "model")
    e, d = _updated_model(lr.export, load_machine(MACHINE), ErrorSet(), MachineDynamics(), True)
    updated = simulate(program, MACHINE, e, d, step=step, compiler=compiler, spindle_speed=sp)
    dyn_m = model_dynamics(lr.export.dynamics_values, MACHINE, step)
    part = {}
    for name, kw in (("none", None), ("friction", dict(friction=True, thermal=False)),
                     ("thermal", dict(friction=False, thermal=True)), ("friction+thermal", dict(friction=True,
                                                                                                  thermal=True))):
        text = program if kw is None else compensate_with_model(program, MACHINE, lr.export.errors, dyn_m,
                                                                max_feed=ASKED_FEED, **kw)[0]
        if kw is not None:
            (out / f"circle-{name.replace('+', '-')}.nc").write_text(text)
        s2 = np.abs(spindle_profile(text, MACHINE, step))
        sig = simulate(text, MACHINE, None, true_dyn, step=step, compiler=compiler,
                       spindle_speed=s2 if s2.any() else 0.0)
        pe = part_error(program, sig, MACHINE)
        k = min(len(sig.t), len(nominal.t))
        # beside the part error: the largest deviation from the ideal machine's run of the same
        # program (the interpolator's 1 deg chords, sagitta 0.38 µm on r = 10 mm, are in both), in
        # the circle's plane (friction) and along z (thermal drift)
        dp = np.abs(sig.p[:k] - nominal.p[:k])
        part[name] = {"max": pe["max"], "rms": pe["rms"], "reach": pe["reach"], "dev": float(dp.max()),
                      "dev_xy": float(dp[:, :2].max()), "dev_z": float(dp[:, 2].max())}
    story = Story(truth, lr, rec, nominal, updated, part, out, program, outputs=("x", "z"))
    atomic_write(out / "story.json", json.dumps(story.to_dict(), indent=2) + "\n")
    return story
