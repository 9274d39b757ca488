"""Virtual probing of the bowls: the probing program run on a blank at a true pose, with probe
noise and the bowl-making errors of the ordinary machine."""
from __future__ import annotations

import math

import numpy as np

from .._io import InputError, MtcompError
from .bowl_nc import _move_arrays
from .bowl_plan import BowlPlan
from .bowl_touches import Touches


def virtual_probe(true_pose, plan: BowlPlan, noise_sigma: float = 0.0, rng=None, *,
                  aim=None, bowl_radius_error: float = 0.0) -> Touches:
    """Simulate the probing program on a blank whose real frame sits at `true_pose` (a WorkpieceSetting).

    Each probing move (start, unit approach, from `touch_moves(plan, aim)`) stops where the probe
    centre reaches the real bowl's probe-centre sphere (radius R + bowl_radius_error - r); the
    recorded point is that trigger point plus Gaussian noise of `noise_sigma` mm along the approach
    (pretravel scatter).  Raises MtcompError naming the bowl when a move would miss the bowl wall
    (blank too far from `aim`: probe once coarsely, then again with `aim` = the coarse result).
    """
    if not noise_sigma >= 0:
        raise InputError(f"probe noise must be >= 0 mm, got {noise_sigma}", field="noise")
    rng = np.random.default_rng(rng)
    from .frame import pose_matrix
    Rt, tt = pose_matrix(true_pose) if true_pose is not None else (np.eye(3), np.zeros(3))
    rho = plan.probe_sphere_radius + bowl_radius_error
    ids, num, S, _E, D = _move_arrays(plan, aim)
    Cr = (plan.centres @ Rt.T + tt)[np.repeat(np.arange(len(plan.bowls)), len(plan.dirs))]
    W = S - Cr
    # |w + lam d| = rho with lam > 0: the start point must be inside the sphere
    bq = np.einsum("ij,ij->i", W, D)
    cq = np.einsum("ij,ij->i", W, W) - rho * rho
    out = np.flatnonzero(cq >= 0)
    if out.size:
        k = int(out[0])
        raise MtcompError(f"bowl {ids[k]}: touch {num[k]} starts outside the bowl "
                          f"({math.sqrt(W[k] @ W[k]):.3f} mm from its centre, sphere radius "
                          f"{rho:.3f}); locate the blank coarsely first (aim)")
    lam = -bq + np.sqrt(bq * bq - cq)
    P = S + lam[:, None] * D
    # the contact point on the bowl wall must lie below the real top face (inside the cavity)
    contact = Cr + (P - Cr) * ((rho + plan.probe_radius) / rho)
    above = np.flatnonzero((contact - tt) @ Rt[:, 2] > -1e-3)
    if above.size:
        k = int(above[0])
        raise MtcompError(f"bowl {ids[k]}: touch {num[k]} would hit the rim or the top face, not "
                          "the bowl wall; locate the blank coarsely first (aim)")
    if noise_sigma > 0:
        P = P + rng.normal(0.0, noise_sigma, len(P))[:, None] * D
    return Touches(bowl=ids, points=P, approach=D)
