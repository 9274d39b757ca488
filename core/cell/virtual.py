"""Measurement steps built on mtcomp.setting.workpiece: the virtual cell (the default
`measure_and_compute`) and `ProbeFileCell`, which takes the probe data from the real NC.

The robot places blank `part_id` with the placement error of `setting.cellsim.RobotPlacement`
(ISO 9283 repeatability RP = 30 µm by default); the machine runs the probing program of the
bowl plan on it (`virtual_probe`, probe noise along each approach), the bowls' spheres are fitted
(`fit_bowls`), the paper-001 frame gives the workpiece setting with its covariance
(`frame_from_bowls`) and, when NC programs are configured, the part program is rewritten for
the real blank (`compensate_program`).

The placement is a pure function of (part_id, seed), so the PLC simulator (which "places" the
blank) and the measuring side (which "probes" it) agree on the truth without sharing memory,
even in different processes.
"""
from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .cycle import CellResult, Job


def _robot(robot):
    from ..setting.cellsim import RobotPlacement
    return RobotPlacement() if robot is None else robot


def robot_placement(part_id: int, seed: int = 0, robot=None) -> np.ndarray:
    """True pose (dx, dy, dz mm, a, b, c deg) of blank `part_id` as the robot placed it.

    `robot`: a `mtcomp.setting.cellsim.RobotPlacement` (default RP 30 µm, 0.02 deg).
    """
    rng = np.random.default_rng([int(seed), int(part_id), 1])
    pose = _robot(robot).sample(rng)
    return np.r_[pose.translation, pose.angles]


@dataclass(frozen=True)
class VirtualCell:
    """Default measurement step of the virtual cell (see the module docstring).

    probe_sigma_mm: probe noise, 1 sigma along the approach (1 µm 2 sigma -> 0.0005 mm);
    probe_time_s: simulated duration of the probing program; plan: a `BowlPlan` (default
    `plan_bowls(3)`: three R2 bowls on a 20 x 20 x 5 mm blank).

    With `nc_dir` set, the part program ``O<program_id:04d>.nc`` (O0100.nc) is read from it
    and the program compensated for the measured blank is written as ``O<job.out_program_id:04d>
    .nc`` (O1100.nc) to `out_dir` (default `nc_dir`), for `machine` (a preset name or TOML path),
    and verified (`program.write_program`), on the plan's blank at the measured pose with
    rapids `clearance` mm off it (None: no blank verification; `setting.blank_check`);
    `program_check(machine, path, text)` adds a check. Without `nc_dir` no program is written
    and the result is a no-go.
    """
    seed: int = 0
    robot: object = None
    probe_sigma_mm: float = 0.0005
    probe_time_s: float = 0.0
    plan: object = None
    nc_dir: str | None = None
    out_dir: str | None = None
    machine: str = "robonano-a0ib"
    program_check: object = None
    clearance: float | None = 0.2

    def __call__(self, job: Job) -> CellResult:
        from ..errors import WorkpieceSetting
        from ..setting.workpiece import plan_bowls, virtual_probe
        plan = self.plan if self.plan is not None else _default_plan(plan_bowls)
        truth = robot_placement(job.part_id, self.seed, self.robot)
        # probing noise differs per measurement (job number), the placement per part; a job
        # resumed after a restart probes with the same noise, so it reports the same result
        rng = np.random.default_rng([self.seed, job.part_id, job.job_no, 2])
        if self.probe_time_s > 0:
            time.sleep(self.probe_time_s)
        touches = virtual_probe(WorkpieceSetting(tuple(truth[:3]), tuple(truth[3:])), plan,
                                self.probe_sigma_mm, rng)
        if job.on_phase is not None:
            job.on_phase("computing")
        return result_from_touches(job, touches, plan, self.probe_sigma_mm, self.nc_dir,
                                   self.out_dir, self.machine, self.program_check, self.clearance)


def result_from_touches(job: Job, touches, plan, probe_sigma_mm, nc_dir=None, out_dir=None,
                        machine="robonano-a0ib", program_check=None,
                        clearance: float | None = 0.2) -> CellResult:
    """Bowl fit, paper-001 frame and (with `nc_dir`) the compensated, verified program: the part
    of the step shared by the virtual cell and the real machine (`ProbeFileCell`).

    The program is verified on the plan's blank at the measured pose (every block, rapids
    included, through the machine model with that workpiece setting; rapids keep `clearance` mm
    from the blank, retracts from the cut excepted: `setting.blank_check`), then by
    `program_check` if given.  clearance None leaves out the blank verification."""
    from ..setting.workpiece import fit_bowls, frame_from_bowls
    from .program import CellFault, program_file_name, target_number, write_program
    from .registers import Fault
    fit = fit_bowls(touches, plan.probe_radius, probe_sigma=probe_sigma_mm)
    est = frame_from_bowls(fit, plan, file=touches.source)
    prog = job.out_program_id or target_number(job.program_id)
    if prog is None:
        raise CellFault(Fault.PROGRAM_FAILED, f"no compensated program number for program "
                                              f"{job.program_id} in the default range")
    info = {"method": est.method, "warnings": list(est.warnings),
            "bowl_rms_mm": [float(f.rms) for f in fit.fits]}
    if touches.source:
        info["touches_file"] = Path(touches.source).name
    written = None
    if nc_dir is not None:
        from ..machine import load_machine
        checks, results = [], []
        if clearance is not None:
            from ..setting.blank_check import BlankCheck, plan_stock
            checks.append(BlankCheck(est.pose, plan_stock(plan), clearance, results=results))
        if program_check is not None:
            checks.append(program_check)
        written = write_program(load_machine(machine),
                                Path(nc_dir) / program_file_name(job.program_id),
                                Path(out_dir or nc_dir) / program_file_name(prog), est.pose,
                                source_id=job.program_id, out_id=prog, part_id=job.part_id,
                                job_no=job.job_no, extra_check=_all_of(checks) if checks else None)
        info["blocks"] = written.blocks
        info["program_file"] = Path(written.path).name
        if results:
            res = results[-1]
            info["min_clearance_mm"] = res.min_clearance if np.isfinite(res.min_clearance) else None
            info["clearance_mm"] = res.clearance
            info["retracts"] = res.retracts
    return CellResult(tuple(float(v) for v in est.params), tuple(float(v) for v in est.std),
                      prog, not est.warnings, info, written)


@dataclass(frozen=True)
class ProbeFileCell:
    """Measurement step for a real machine: the NC runs the probing program and writes the
    touches (CSV of `mtcomp.setting.workpiece.read_touches`: bowl,x,y,z,ax,ay,az) into `inbox`
    as ``pattern`` (fields part_id, job_no, program_id). The step waits for that file (its
    size unchanged for `settle_s`; writers should better write a temporary name and rename),
    claims it by renaming it to ``<name>.job<job_no>`` (so a later job never reuses it, and a
    job resumed after a restart finds it again), fits the bowls of `plan` (a plan TOML) and
    writes the compensated program as `VirtualCell` does. Gives up after `wait_s` (set it no
    longer than the cycle's measure timeout). probe_sigma_mm None pools the noise from the
    fit residuals.
    """
    inbox: str
    plan: str
    pattern: str = "{part_id}.csv"
    probe_sigma_mm: float | None = None
    poll_s: float = 0.2
    settle_s: float = 0.5
    wait_s: float = 300.0
    nc_dir: str | None = None
    out_dir: str | None = None
    machine: str = "robonano-a0ib"
    program_check: object = None
    clearance: float | None = 0.2

    def __call__(self, job: Job) -> CellResult:
        import os
        from .._io import MtcompError
        from ..setting.workpiece import load_plan, read_touches
        plan = load_plan(self.plan)
        src = Path(self.inbox) / self.pattern.format(part_id=job.part_id, job_no=job.job_no,
                                                     program_id=job.program_id)
        claimed = src.with_name(f"{src.name}.job{job.job_no}")
        deadline = time.monotonic() + self.wait_s
        size = None
        while not claimed.exists():
            now = src.stat().st_size if src.exists() else None
            if now is not None and now == size:
                os.replace(src, claimed)
                break
            if time.monotonic() > deadline:
                raise MtcompError(f"no probe data {src} within {self.wait_s} s")
            size = now
            time.sleep(self.settle_s if now is not None else self.poll_s)
        touches = read_touches(claimed)
        if job.on_phase is not None:
            job.on_phase("computing")
        return result_from_touches(job, touches, plan, self.probe_sigma_mm, self.nc_dir,
                                   self.out_dir, self.machine, self.program_check, self.clearance)


def _all_of(checks):
    def check(machine, path, text):
        for c in checks:
            c(machine, path, text)
    return check


_PLAN = {}


def _default_plan(plan_bowls):
    # planning checks the geometry; do it once per process
    if "p" not in _PLAN:
        _PLAN["p"] = plan_bowls(3)
    return _PLAN["p"]
