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
                  aim=None, bowl_radius_error: float = 0.0, cutter_radius_error: float = 0.0,
                  runout: float = 0.0, bowl_offsets=None) -> Touches:
    """Simulate the probing program on a blank whose real frame sits at `true_pose` (a WorkpieceSetting).

    The real bowls are what the ordinary machine cut (all mm, blank frame): the ball end mill's
    tip plunged to the planned depth at the planned (x, y) + `bowl_offsets` ((n, 3) per bowl,
    the ordinary machine's positioning errors; z moves the bottom), with a real radius R +
    `cutter_radius_error` and a radial run-out `runout` (the ball centre turns on a circle of that
    radius about the spindle axis).  So a cutter radius error moves the sphere centre up by the same
    amount, the bottom stays; run-out makes the cavity the union of the balls around the circle
    (a spindle torus: wider by the run-out at the sides, the same bottom to second order).
    `bowl_radius_error` changes the radius about the fixed planned centre (e.g. wear after the
    bottom was cut, or a probe ball radius error).

    Each probing move (start, unit approach, from `touch_moves(plan, aim)`) stops where the probe
    centre reaches the cavity shrunk by the probe radius; the recorded point is that trigger
    point plus Gaussian noise of `noise_sigma` mm along the approach (pretravel scatter).  Raises
    MtcompError naming the bowl when a move would miss the bowl wall (blank too far from `aim`:
    probe once coarsely, then again with `aim` = the coarse result).
    """
    if not noise_sigma >= 0:
        raise InputError(f"probe noise must be >= 0 mm, got {noise_sigma}", field="noise")
    for name, v in (("cutter_radius_error", cutter_radius_error), ("runout", runout),
                    ("bowl_radius_error", bowl_radius_error)):
        if not (isinstance(v, (int, float)) and math.isfinite(v) and abs(v) < 0.5 * plan.probe_sphere_radius):
            raise InputError(f"expected a finite {name.replace('_', ' ')} well below the bowl radius, mm, "
                             f"got {v!r}", field=name)
    if runout < 0:
        raise InputError(f"run-out must be >= 0 mm, got {runout}", field="runout")
    rng = np.random.default_rng(rng)
    from .frame import pose_matrix
    Rt, tt = pose_matrix(true_pose) if true_pose is not None else (np.eye(3), np.zeros(3))
    n_b = len(plan.bowls)
    off = np.zeros((n_b, 3)) if bowl_offsets is None else np.asarray(bowl_offsets, float)
    if off.shape != (n_b, 3) or not np.all(np.isfinite(off)):
        raise InputError(f"bowl offsets must be ({n_b}, 3) finite mm, got shape {off.shape}", field="bowl_offsets")
    rho = plan.probe_sphere_radius + bowl_radius_error + cutter_radius_error
    ids, num, S, _E, D = _move_arrays(plan, aim)
    # design-frame ball centres: the bottom stays at the planned depth, the centre rises by dR
    base = plan.centres + off + np.array([0.0, 0.0, cutter_radius_error])
    if runout > 0:
        # sampled circle of ball centres; the exit of the union along a ray from inside is the
        # farthest exit of the balls containing the start point (the cavity is star-shaped about
        # the axis for run-out << R); 720 samples leave < 1e-4 of the run-out
        th = np.linspace(0.0, 2 * np.pi, 720, endpoint=False)
        ring = runout * np.column_stack([np.cos(th), np.sin(th), np.zeros_like(th)])
    else:
        ring = np.zeros((1, 3))
    owner = np.repeat(np.arange(n_b), len(plan.dirs))
    best_lam = np.full(len(S), -np.inf)
    best_c = np.zeros_like(S)
    for r in ring:
        Cr = ((base + r) @ Rt.T + tt)[owner]
        W = S - Cr
        # |w + lam d| = rho with lam > 0: the start point must be inside the ball
        bq = np.einsum("ij,ij->i", W, D)
        cq = np.einsum("ij,ij->i", W, W) - rho * rho
        inside = cq < 0
        lam = np.where(inside, -bq + np.sqrt(np.maximum(bq * bq - cq, 0.0)), -np.inf)
        better = lam > best_lam
        best_lam[better] = lam[better]
        best_c[better] = Cr[better]
    out = np.flatnonzero(~np.isfinite(best_lam))
    if out.size:
        k = int(out[0])
        Cr = (base @ Rt.T + tt)[owner]
        W = S - Cr
        raise MtcompError(f"bowl {ids[k]}: touch {num[k]} starts outside the bowl "
                          f"({math.sqrt(W[k] @ W[k]):.3f} mm from its centre, sphere radius "
                          f"{rho:.3f}); locate the blank coarsely first (aim)")
    P = S + best_lam[:, None] * D
    # the contact point on the bowl wall must lie below the real top face (inside the cavity)
    contact = best_c + (P - best_c) * ((rho + plan.probe_radius) / rho)
    above = np.flatnonzero((contact - tt) @ Rt[:, 2] > -1e-3)
    if above.size:
        k = int(above[0])
        raise MtcompError(f"bowl {ids[k]}: touch {num[k]} would hit the rim or the top face, not "
                          "the bowl wall; locate the blank coarsely first (aim)")
    if noise_sigma > 0:
        P = P + rng.normal(0.0, noise_sigma, len(P))[:, None] * D
    return Touches(bowl=ids, points=P, approach=D)
