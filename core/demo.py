"""`mtcomp demo`: a virtual cell run end to end, summarised in one self-contained HTML page.

Stages (each prints its progress and timing; every number in the report is computed here;
the figures and the report are in ``demo_report``):
1. CadQuery builds the bowl blank and paper 001's pyramid (STEP).
2. Tool setting: paper 000's grooving experiment, virtually, with hidden true setting errors.
3. The PLC simulator loads a blank with the robot's placement error over Modbus TCP on
   loopback; mtcomp probes it virtually, fits the frame and writes the compensated program.
4. Co-simulation with the FMUs (native compensator, machine model) runs the finishing program
   with and without compensation.
5. The machined pyramid's widths and angles beside paper 001's Table 1.
6. The diagnosis names an effect the simulation left out of a co-simulated "recording".
7. The loop closed (mtcomp.model.story): the diagnosed effects go into the machine model, its
   re-simulation matches the recording, and the program compensated with them is co-simulated.
8. The programs the demo wrote are verified through the machine model (mtcomp.verify).
"""
from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

from ._io import atomic_write
from .demo_report import (plot_cosim, plot_diagnosis, plot_tool_setting,  # noqa: F401
                          plot_pyramid, render_summary_png, write_report)


class _Stages:
    """Numbered stages with their progress lines and times (s, wall clock of each stage)."""

    def __init__(self, total: int, stream=None):
        self.total, self.k = total, 0
        self.stream = stream or sys.stdout
        self.times = {}
        self.t0 = time.perf_counter()

    def _begin(self, title: str) -> None:
        self.k += 1
        self.stream.write(f"[{self.k}/{self.total}] {title} ...")
        self.stream.flush()

    def _end(self, title: str, dt: float, note: str = "") -> None:
        self.times[title] = dt
        self.stream.write(f" done in {dt:.1f} s{note}\n")
        self.stream.flush()

    def run(self, title, fn, *a, **kw):
        self._begin(title)
        t = time.perf_counter()
        out = fn(*a, **kw)
        self._end(title, time.perf_counter() - t)
        return out

    def wait(self, title, future):
        """A stage that ran in a worker process (`_timed`): its result and its own time."""
        self._begin(title)
        t = time.perf_counter()
        out, dt = future.result()
        waited = time.perf_counter() - t
        self._end(title, dt, f" (in a second process; waited {waited:.1f} s for it)" if waited > 0.05 else
                  " (in a second process, beside the stages before)")
        return out

    @property
    def wall(self) -> float:
        return time.perf_counter() - self.t0


def _timed(fn, *a):
    """Run a stage in a worker process: (result, seconds)."""
    t = time.perf_counter()
    out = fn(*a)
    return out, time.perf_counter() - t


def _background(workers: int):
    """A pool for the stages that depend on no other (the diagnosis and the closed loop): they
    run beside the CAD, tool-setting, cell and co-simulation stages, so a 2-core machine is
    busy on both cores.  Fresh interpreters (spawn), not forks: the cell stage starts threads
    (Modbus server), and a fork beside threads can hang."""
    import multiprocessing as mp
    from concurrent.futures import ProcessPoolExecutor
    return ProcessPoolExecutor(max_workers=workers, mp_context=mp.get_context("spawn"))


# --------------------------------------------------------------------------- stage 1: CAD
def stage_cad(out: Path) -> dict:
    from .cad_plugin import export, features
    from .cad_plugin.layout import pyramid_height
    d = out / "cad"
    d.mkdir(parents=True, exist_ok=True)
    blank = features.bowl_blank()
    pyr = features.pyramid_part()
    export.export_step(blank, d / "bowl_blank.step", name="bowl blank (paper 001)")
    export.export_step(pyr, d / "pyramid.step", name="pyramid on the bowl blank (paper 001)")
    h = pyramid_height(3.45, 164.81)
    return {"blank_volume": features.volume(blank), "pyramid_volume": features.volume(pyr),
            "pyramid_height_um": h * 1e3, "files": [d / "bowl_blank.step", d / "pyramid.step"]}


# --------------------------------------------------------------------------- stage 2: tool setting
def stage_tool_setting(out: Path, seed: int) -> dict:
    from .machine import load_machine
    from .setting import tool as ts
    from .setting.tool_estimate import estimate
    m = load_machine("robonano-ui")
    rng = np.random.default_rng(seed)
    # hidden truth: the offset that reproduces paper 000's A distances, perturbed per run
    truth = np.asarray(ts.paper_offset()) + rng.normal(0, 0.01, 3)
    plan = ts.make_plan(m)
    meas = ts.simulate_grooving(m, tuple(truth), ts.MicroscopeNoise(0.001, 0.001), seed, plan=plan)
    est = estimate(m, meas)
    before = ts.table1_distances(plan, ts.cut_grooves(m, plan, tuple(truth)))
    after = ts.table1_distances(plan, ts.cut_grooves(m, plan, tuple(truth), compensation=est.errors()))
    png = out / "tool_setting.png"
    res = {"truth": truth, "estimate": np.asarray(est.tool_setting.offset), "sigma": np.asarray(est.sigma),
           "before": before, "after": after}
    plot_tool_setting(res, png)
    return {"truth": truth, "estimate": np.asarray(est.tool_setting.offset), "sigma": np.asarray(est.sigma),
            "before": before, "after": after, "png": png, "summary": est.summary()}


# --------------------------------------------------------------------------- stage 3: cell
def _finishing(machine, quick: bool):
    from .cad_plugin.post import PostOptions, post
    from .cad_plugin.toolpath import pyramid_finishing, to_axes
    path = pyramid_finishing(stepover=0.1 if quick else 0.05, step=0.05 if quick else 0.02)
    q = to_axes(machine, path)
    text = post(machine, path, q, PostOptions(program_number=100, comment="paper 001 pyramid finishing"))
    return path, q, text


def stage_cell(out: Path, seed: int, quick: bool) -> dict:
    from .cell.server import run_virtual_cell_once
    from .cell.virtual import VirtualCell
    from .machine import load_machine
    m = load_machine("robonano-a0ib")
    path, q, text = _finishing(m, quick)
    nc = out / "nc"
    nc.mkdir(parents=True, exist_ok=True)
    atomic_write(nc / "O0100.nc", text)
    journal = out / "cell" / "journal.jsonl"
    journal.parent.mkdir(parents=True, exist_ok=True)
    if journal.exists():
        journal.unlink()
    part = 1 + seed % 1000
    once = run_virtual_cell_once(journal, part_id=part, program_id=100, seed=seed,
                                 measure_and_compute=VirtualCell(seed=seed, nc_dir=str(nc), machine=m.name))
    res = once.result
    comp_file = nc / f"O{res.program_id:04d}.nc"
    return {"true_pose": np.asarray(once.true_pose, float), "est_pose": np.asarray(res.pose6, float),
            "sigma": np.asarray(res.sigma6, float), "go": once.go, "seq": once.result_seq,
            "program_id": res.program_id, "program": comp_file, "journal": journal,
            "path": path, "q": q, "nominal_program": nc / "O0100.nc"}


def _pose_errors(p6):
    from .errors import ErrorSet, WorkpieceSetting
    return ErrorSet(workpiece=WorkpieceSetting(tuple(p6[:3]), tuple(p6[3:])))


def stage_verify(cell: dict):
    """The finishing program the demo posted, run block by block through the machine against its
    blank (the bowl blank up to the pyramid's apex) with 0.2 mm rapid clearance."""
    from .cad_plugin.layout import pyramid_height
    from .machine import load_machine
    from .verify import Box, verify_program
    m = load_machine("robonano-a0ib")
    stock = Box((-10.0, -10.0, -5.0), (10.0, 10.0, pyramid_height(3.45, 164.81)))
    prog = Path(cell["nominal_program"])
    nominal = verify_program(m, prog.read_text(), filename=prog.name, stock=stock, clearance=0.2)
    # The cell's compensated program on the real machine (the hidden blank pose).
    comp = Path(cell["program"])
    verify_program(m, comp.read_text(), filename=comp.name, stock=stock, clearance=0.2,
                   errors=_pose_errors(cell["true_pose"]))
    return nominal


# --------------------------------------------------------------------------- stage 4: co-simulation
def stage_cosim(out: Path, cell: dict, quick: bool) -> dict:
    from .fmu.cosim import cosimulate
    from .gcode import parse
    from .machine import load_machine
    m = load_machine("robonano-a0ib")
    true_e = _pose_errors(cell["true_pose"])
    ident = _pose_errors(cell["est_pose"])
    prog = parse(Path(cell["program"]).read_text(), axes=m.axis_names)
    if quick:  # the first 400 blocks, one per 1 ms step
        q_nom = parse(Path(cell["nominal_program"]).read_text(), axes=m.axis_names).position[:400]
        res = cosimulate(q_nom, m, true_e, ident, step=1e-3, workdir=out / "fmu", compiler="cc")
    else:  # the whole program, interpolated at 1 ms honouring its feed rates
        res = cosimulate(Path(cell["nominal_program"]), m, true_e, ident, step=1e-3, workdir=out / "fmu",
                         compiler="cc")
    png = out / "cosim.png"
    res.to_csv(out / "cosim.csv")
    # The program the cell wrote, through the forward model with the true pose, block by block.
    from .kinematics import forward
    nominal = parse(Path(cell["nominal_program"]).read_text(), axes=m.axis_names).position
    cell_prog_err = np.linalg.norm(forward(m, prog.position, true_e).p - forward(m, nominal).p, axis=1)
    # What the probing left: the programmed path through the machine with the true pose and
    # with the estimated one (the compensator knows only the estimate).
    q_prog = np.asarray(res.q_programmed, float)
    expected = np.linalg.norm(forward(m, q_prog, true_e).p - forward(m, q_prog, ident).p, axis=1)
    from .setting.cellsim import PAPER_TARGET  # noqa: F401  (same part as stage 5)
    from .cad_plugin.layout import pyramid_height
    cutting = np.asarray(res.target, float)[:, 2] <= pyramid_height(3.45, 164.81) + 1e-3
    e_unc, e_cmp = np.asarray(res.error_uncompensated), np.asarray(res.error_compensated)
    split = {name: (float(e_unc[mask].max()) if mask.any() else float("nan"),
                    float(e_cmp[mask].max()) if mask.any() else float("nan"), int(mask.sum()))
             for name, mask in (("cutting", cutting), ("air", ~cutting))}
    out_d = {"res": res, "png": png, "cell_program_max": float(cell_prog_err.max()),
             "steps": len(res.t), "expected": expected, "cutting": cutting, "split": split}
    plot_cosim(out_d, png)
    return out_d


# --------------------------------------------------------------------------- stage 5: pyramid
def stage_pyramid(out: Path, cell: dict) -> dict:
    from .cad_plugin.check import pyramid_widths_angles
    from .gcode import parse
    from .machine import load_machine
    m = load_machine("robonano-a0ib")
    true_e = _pose_errors(cell["true_pose"])
    path, q = cell["path"], cell["q"]
    comp = parse(Path(cell["program"]).read_text(), axes=m.axis_names).position
    nominal = parse(Path(cell["nominal_program"]).read_text(), axes=m.axis_names).position
    # The posted program has one block per toolpath point after its header moves.
    off = len(nominal) - len(path)
    unc = pyramid_widths_angles(m, path, q, true_e)
    cmp_ = pyramid_widths_angles(m, path, comp[off:], true_e)
    return {"unc": unc, "comp": cmp_}


# --------------------------------------------------------------------------- stage 6: diagnosis
def stage_diagnose(out: Path, seed: int, quick: bool) -> dict:
    from .diagnose import diagnose
    from .errors import ErrorSet
    from .fmu.build import MachineDynamics
    from .machine import load_machine
    from .model.simulate import simulate
    m = load_machine("vmc-moving-column")
    rng = np.random.default_rng(seed)
    # A program of random moves and dwells on the 3-axis machine, 1 ms samples; each move has
    # a smooth (smoothstep) velocity profile at about 10 mm/s, as a jerk-limited control makes.
    n_moves = 6 if quick else 16
    pts = [np.zeros(3)]
    for _ in range(n_moves):
        pts.append(np.clip(pts[-1] + rng.uniform(-15, 15, 3), [-50, -50, -40], [50, 50, 0]))
    q = []
    for a, b in zip(pts[:-1], pts[1:]):
        tau = np.linspace(0, 1, int(np.linalg.norm(b - a) / 10.0 / 1e-3) + 2)[:, None]
        q.append(a + (3 * tau**2 - 2 * tau**3) * (b - a))
        q.append(np.repeat(b[None], int(rng.integers(100, 400)), axis=0))
    q = np.vstack(q)
    backlash = 0.004  # mm on X: the concealed effect
    d = out / "diagnose"
    # the machine FMU alone (the uncompensated run of a co-simulation, without the compensator
    # loop nobody looks at here): the ideal machine, and the real one with the concealed effect
    ideal = simulate(q, m, ErrorSet(), step=1e-3, workdir=d / "fmu_sim", compiler="cc")
    real = simulate(q, m, ErrorSet(), MachineDynamics(backlash=(backlash, 0.0, 0.0), noise=2e-5, seed=seed),
                    step=1e-3, workdir=d / "fmu_rec", compiler="cc")
    t = ideal.t
    sim = {"t": t, "x": ideal.p[:, 0], "y": ideal.p[:, 1],
           "z": ideal.p[:, 2], "cmd_x": q[:, 0], "cmd_y": q[:, 1], "cmd_z": q[:, 2]}
    # The "recording": its own clock (started 0.25 s after the simulation, 2.5 ms samples), um, a
    # temperature logged that does not matter.
    tr = np.arange(0.25, t[-1] - 0.1, 2.5e-3)
    rec = {"t": tr - 0.25}
    for j, c in enumerate("xyz"):
        rec[f"{c}[um]"] = np.interp(tr, t, real.p[:, j]) * 1e3
    rec["spindle_temp"] = 21.0 + 0.3 * np.sin(tr / 7.0)
    d.mkdir(parents=True, exist_ok=True)
    from .diagnose.synth import write_csv
    write_csv(d / "sim.csv", sim)
    write_csv(d / "rec.csv", rec)
    res = diagnose(d / "sim.csv", d / "rec.csv")
    png = d / "diagnose.png"
    plot_diagnosis(res, backlash, png)
    atomic_write(d / "diagnosis.json", res.to_json())
    return {"res": res, "png": png, "truth": {"name": "backlash", "axis": "X", "value_mm": backlash}}


# --------------------------------------------------------------------------- stage 7: the loop closed
def stage_model_loop(out: Path, seed: int, quick: bool) -> dict:
    """Both parts of the closed loop, one after the other (`--serial`)."""
    return join_model_loop(out, stage_loop_static(out, seed, quick), stage_loop_dynamics(out, seed))


def stage_loop_static(out: Path, seed: int, quick: bool):
    """The loop's first part (servo lag, backlash, squareness: mtcomp.model.story.run_story) and
    its figure."""
    from .model.story import run_story
    from .demo_report import plot_model_loop
    story = run_story(out / "model-loop", quick=quick, seed=seed, dynamics=False)
    plot_model_loop(story, out / "model-loop" / "model_loop.png")
    return story


def stage_loop_dynamics(out: Path, seed: int):
    """The loop's second part (friction and thermal drift: run_dynamics_story) and its figure;
    independent of the first, so it can run in a process of its own."""
    from .model.story import run_dynamics_story
    from .demo_report import plot_model_loop
    dyn = run_dynamics_story(out / "model-loop" / "dynamics", seed=seed)
    plot_model_loop(dyn, out / "model-loop" / "model_loop_dynamics.png")
    return dyn


def join_model_loop(out: Path, story, dyn) -> dict:
    """The two parts as one Story (its story.json rewritten with both)."""
    import json
    from dataclasses import replace
    story = replace(story, dynamics=dyn)
    atomic_write(out / "model-loop" / "story.json", json.dumps(story.to_dict(), indent=2) + "\n")
    r = {"story": story, "png": out / "model-loop" / "model_loop.png"}
    if dyn is not None:
        r["png_dynamics"] = out / "model-loop" / "model_loop_dynamics.png"
    return r


def run(out: str | Path = "mtcomp-demo", quick: bool = False, seed: int = 7, stream=None,
        parallel: bool = True) -> dict:
    """Run every stage, write `out/report.html`; returns the stage results.

    parallel: the diagnosis and the closed loop (independent of the other stages) run in a
    second process beside the rest; False runs every stage here, one after the other."""
    out = Path(out)
    if out.exists() and not out.is_dir():
        from ._io import InputError
        raise InputError("the output folder is an existing file; give a folder name", field="--out")
    if not out.parent.is_dir():
        from ._io import InputError
        raise InputError(f"folder {out.parent} does not exist", field="--out")
    out.mkdir(exist_ok=True)
    st = _Stages(9, stream)
    r = {}
    cpu0 = _cpu_seconds()
    with (_background(3) if parallel else _Serial()) as pool:
        # the long, independent stages start first, each in a process of its own (the closed loop
        # in its two parts); the rest runs here
        diag = pool.submit(_timed, stage_diagnose, out, seed, quick)
        loop = pool.submit(_timed, stage_loop_static, out, seed, quick)
        loop_dyn = pool.submit(_timed, stage_loop_dynamics, out, seed)
        r["cad"] = st.run("CAD: bowl blank and pyramid (CadQuery, STEP)", stage_cad, out)
        r["tool"] = st.run("tool setting: virtual grooving, estimate with uncertainty", stage_tool_setting, out,
                           seed)
        r["cell"] = st.run("cell: PLC simulator + Modbus TCP + probing + frame + program", stage_cell, out, seed,
                           quick)
        r["cosim"] = st.run("co-simulation: compensator FMU -> machine FMU (fmpy)", stage_cosim, out, r["cell"],
                            quick)
        r["pyramid"] = st.run("pyramid widths and angles vs paper 001 Table 1", stage_pyramid, out, r["cell"])
        r["diagnose"] = st.wait("diagnosis: a recording with a concealed effect", diag)
        r["loop"] = st.wait("closing the loop: diagnosed model, compensated program",
                            _Joined(join_model_loop, out, loop, loop_dyn))
    r["verify"] = st.run("verify the programs the demo wrote", stage_verify, r["cell"])
    st.cpu = _cpu_seconds() - cpu0
    r["report"] = st.run("report", write_report, out, r, quick, st.times, st.wall, st.cpu)
    render_summary_png(r, out / "summary.png", st.wall)
    (stream or sys.stdout).write(f"report: {r['report']}\n"
                                 f"total {st.wall:.1f} s wall, {_cpu_seconds() - cpu0:.1f} s CPU "
                                 f"(both processes)\n")
    return r


class _Joined:
    """A future of fn(*args, results of the futures): (result, the longer of their times)."""

    def __init__(self, fn, out, *futures):
        self.fn, self.out, self.futures = fn, out, futures

    def result(self):
        got = [f.result() for f in self.futures]
        return self.fn(self.out, *(g[0] for g in got)), max(g[1] for g in got)


def _cpu_seconds() -> float:
    """CPU time of this process and of its finished children (the stage workers), s."""
    import os
    t = os.times()
    return t.user + t.system + t.children_user + t.children_system


class _Serial:
    """The pool's interface, running each job at once in this process (`--serial`)."""

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False

    def submit(self, fn, *a):
        # run when the result is asked for (`_Stages.wait`), so the stages keep their order
        from concurrent.futures import Future

        class _Later(Future):
            def result(self, timeout=None):
                if not self.done():
                    self.set_result(fn(*a))
                return super().result(timeout)
        return _Later()


def _cmd(args) -> int:
    r = run(args.out, args.quick, args.seed, parallel=not args.serial)
    from .demo_report import cosim_cutting, diagnosis_verdict
    cut_u, cut_c = cosim_cutting(r["cosim"])
    print(f"tool setting: |estimate - truth| = {np.linalg.norm(r['tool']['estimate'] - r['tool']['truth']) * 1e3:.2f} µm")
    # the same figures, under the same names, as the report's summary
    print(f"co-simulation: tool-edge error, max while cutting {cut_u * 1e3:.2f} µm without, "
          f"{cut_c * 1e3:.3f} µm with compensation")
    ok, said = diagnosis_verdict(r["diagnose"])
    print(f"diagnosis: {'right' if ok else 'WRONG'}: {said}")
    return 0


def register(sub) -> None:
    p = sub.add_parser("demo", help="run the virtual cell end to end and write an HTML report",
                       description="The whole system on realistic virtual data: CAD, tool setting, robot "
                                   "loading over Modbus, FMU co-simulation, pyramid check, diagnosis.")
    p.add_argument("--out", default="mtcomp-demo", help="output folder (default: mtcomp-demo)")
    p.add_argument("--quick", action="store_true", help="smaller stages (for tests, < 30 s)")
    p.add_argument("--seed", type=int, default=7,
                   help="seed of every random draw (hidden errors, noise), default 7: same seed, same report")
    p.add_argument("--serial", action="store_true",
                   help="run every stage in this process, one after the other (default: the diagnosis "
                        "and the closed loop run in a second process beside the others)")
    p.set_defaults(func=_cmd)
