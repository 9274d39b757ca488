"""The virtual cell: a robot that places blanks with a random error, and a machine that probes
them, fits the bowls, builds the workpiece frame and reports the setting with its uncertainty.

Kept small and self-contained (numpy + scipy) so that the Modbus bridge can be demonstrated
and tested without the rest of mtcomp; the production bowl fit lives in the workpiece-setting
module. The geometry follows paper 001: a blank carries three spherical bowls; their sphere
centres S1, S2, S3 (not their lowest points, which move with tilt) define the frame: origin S1,
ex along S1->S2, ez normal to the plane of the three, ey = ez x ex.

The placement is a pure function of (part_id, seed), so the PLC simulator (which "places" the
blank) and the measuring side (which "probes" it) agree on the truth without sharing memory,
even in different processes.
"""
from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from .cycle import CellResult, Job

# Bowl sphere centres in the blank's own frame (mm): a 20 x 20 mm plate, bowls of radius 2 mm,
# 1 mm deep, so the centres sit 1 mm above the top face (z = 0).
BOWL_CENTRES = np.array([[-7.0, -7.0, 1.0], [7.0, -7.0, 1.0], [0.0, 7.0, 1.0]])
BOWL_RADIUS = 2.0


@dataclass(frozen=True)
class RobotModel:
    """Placement error of the loading robot + gripper, normal, independent per component.

    sigma_mm 0.010 per axis gives a pose repeatability RP (ISO 9283, mean + 3 s of the
    distance) of about 30 µm; sigma_deg is the tilt/twist scatter of the gripped blank;
    bias_mm a systematic offset of the taught loading position.
    """
    sigma_mm: float = 0.010
    sigma_deg: float = 0.02
    bias_mm: tuple = (0.0, 0.0, 0.0)


@dataclass(frozen=True)
class ProbeModel:
    """Touch probing of each bowl: `n_touch` points on the bowl's sphere, `tilt_deg` from the
    bottom, noise `sigma_mm` along the surface normal (1 µm 2 sigma -> 0.5 µm)."""
    n_touch: int = 8
    tilt_deg: float = 60.0
    sigma_mm: float = 0.0005
    duration_s: float = 0.0   # simulated probing time (the virtual machine's cycle time)


def robot_placement(part_id: int, seed: int = 0, robot: RobotModel = RobotModel()) -> np.ndarray:
    """True pose (dx, dy, dz mm, a, b, c deg) of blank `part_id` as the robot placed it."""
    rng = np.random.default_rng([int(seed), int(part_id), 1])
    lin = np.asarray(robot.bias_mm, float) + rng.normal(0.0, robot.sigma_mm, 3)
    ang = rng.normal(0.0, robot.sigma_deg, 3)
    return np.concatenate([lin, ang])


def rot(angles_deg) -> np.ndarray:
    """R = Rz(c) Ry(b) Rx(a), angles in deg (ISO 841, right-hand)."""
    a, b, c = np.radians(angles_deg)
    ca, sa, cb, sb, cc, sc = np.cos(a), np.sin(a), np.cos(b), np.sin(b), np.cos(c), np.sin(c)
    rx = np.array([[1, 0, 0], [0, ca, -sa], [0, sa, ca]])
    ry = np.array([[cb, 0, sb], [0, 1, 0], [-sb, 0, cb]])
    rz = np.array([[cc, -sc, 0], [sc, cc, 0], [0, 0, 1]])
    return rz @ ry @ rx


def angles_of(r: np.ndarray) -> np.ndarray:
    """Inverse of `rot` (deg), valid for |b| < 90 deg."""
    b = -np.arcsin(np.clip(r[2, 0], -1, 1))
    a = np.arctan2(r[2, 1], r[2, 2])
    c = np.arctan2(r[1, 0], r[0, 0])
    return np.degrees([a, b, c])


def frame(centres: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Origin (3,) and axes (3x3, columns ex ey ez) of the frame of three sphere centres."""
    s1, s2, s3 = centres
    ex = (s2 - s1) / np.linalg.norm(s2 - s1)
    ez = np.cross(s2 - s1, s3 - s1)
    ez /= np.linalg.norm(ez)
    ey = np.cross(ez, ex)
    return s1, np.column_stack([ex, ey, ez])


def pose_from_centres(measured: np.ndarray, nominal: np.ndarray = BOWL_CENTRES) -> np.ndarray:
    """Setting (dx, dy, dz mm, a, b, c deg) mapping blank coordinates to the nominal frame:
    the measured frame is R (nominal frame) + t, so R = E E0^T and t = O - R O0."""
    o0, e0 = frame(nominal)
    o, e = frame(measured)
    r = e @ e0.T
    return np.concatenate([o - r @ o0, angles_of(r)])


def fit_sphere(points: np.ndarray, sigma_mm: float | None = None
               ) -> tuple[np.ndarray, float, np.ndarray, float]:
    """Least-squares sphere through `points` (N,3): centre, radius, centre covariance, rms
    residual. Algebraic start, then geometric Levenberg-Marquardt (scipy). The covariance uses
    the probe's known noise `sigma_mm` if given (a calibrated probe), else the residuals."""
    from scipy.optimize import least_squares
    a = np.column_stack([2 * points, np.ones(len(points))])
    sol = np.linalg.lstsq(a, (points ** 2).sum(1), rcond=None)[0]
    c0 = sol[:3]
    r0 = np.sqrt(sol[3] + c0 @ c0)

    def res(p):
        return np.linalg.norm(points - p[:3], axis=1) - p[3]
    fit = least_squares(res, np.append(c0, r0), method="lm")
    j = fit.jac
    dof = max(len(points) - 4, 1)
    s2 = float(fit.fun @ fit.fun) / dof if sigma_mm is None else sigma_mm ** 2
    cov = np.linalg.pinv(j.T @ j) * s2
    return fit.x[:3], float(fit.x[3]), cov[:3, :3], float(np.sqrt(np.mean(fit.fun ** 2)))


def probe_bowls(true_pose: np.ndarray, rng: np.random.Generator, probe: ProbeModel) -> list:
    """Touch points (mm, nominal frame) on each bowl of a blank placed at `true_pose`."""
    r, t = rot(true_pose[3:]), true_pose[:3]
    phi = np.linspace(0, 2 * np.pi, probe.n_touch, endpoint=False)
    th = np.radians(probe.tilt_deg)
    # directions from the sphere centre to the bowl surface (downwards, inside the bowl),
    # plus the bottom point
    d = np.column_stack([np.sin(th) * np.cos(phi), np.sin(th) * np.sin(phi),
                         -np.cos(th) * np.ones_like(phi)])
    d = np.vstack([d, [0.0, 0.0, -1.0]])
    out = []
    for c in BOWL_CENTRES:
        n = d @ r.T  # normals rotate with the blank
        pts = (r @ c + t) + BOWL_RADIUS * n + rng.normal(0, probe.sigma_mm, (len(d), 1)) * n
        out.append(pts)
    return out


def estimate_setting(touches: list, sigma_mm: float | None = None
                     ) -> tuple[np.ndarray, np.ndarray, dict]:
    """Pose, 1-sigma uncertainties (propagated from the sphere-fit covariances through the
    frame construction by a numerical Jacobian) and fit info from the bowls' touch points."""
    fits = [fit_sphere(p, sigma_mm) for p in touches]
    centres = np.array([f[0] for f in fits])
    cov_c = np.zeros((9, 9))
    for i, f in enumerate(fits):
        cov_c[3 * i:3 * i + 3, 3 * i:3 * i + 3] = f[2]
    pose = pose_from_centres(centres)
    h = 1e-6
    jac = np.empty((6, 9))
    flat = centres.ravel()
    for k in range(9):
        e = np.zeros(9)
        e[k] = h
        jac[:, k] = (pose_from_centres((flat + e).reshape(3, 3))
                     - pose_from_centres((flat - e).reshape(3, 3))) / (2 * h)
    cov = jac @ cov_c @ jac.T
    info = {"bowl_radius_mm": [round(f[1], 7) for f in fits],
            "rms_residual_mm": [round(f[3], 9) for f in fits]}
    return pose, np.sqrt(np.clip(np.diag(cov), 0, None)), info


@dataclass(frozen=True)
class VirtualCell:
    """Default `measure_and_compute`: probes the blank the robot placed for `job.part_id`.

    The compensated program id is `program_id + program_offset` (wrapped into 1..9999), the
    convention of the virtual cell's NC (a real cell would write the program to the NC).
    """
    seed: int = 0
    robot: RobotModel = RobotModel()
    probe: ProbeModel = ProbeModel()
    program_offset: int = 1000

    def __call__(self, job: Job) -> CellResult:
        truth = robot_placement(job.part_id, self.seed, self.robot)
        # probing noise differs per measurement (job), placement per part
        rng = np.random.default_rng([self.seed, job.part_id, job.job_no, 2])
        if self.probe.duration_s > 0:
            time.sleep(self.probe.duration_s)
        touches = probe_bowls(truth, rng, self.probe)
        if job.on_phase is not None:
            job.on_phase("computing")
        pose, sigma, info = estimate_setting(touches, self.probe.sigma_mm)
        prog = (job.program_id + self.program_offset - 1) % 9999 + 1
        return CellResult(tuple(pose), tuple(sigma), prog, True, info)
