"""Reference bowls for workpiece setting (paper 001): plan, NC programs, probe touches, sphere fit.

The concepts live in their own modules (bowl_plan, bowl_nc, bowl_touches, bowl_probe, bowl_fit);
this module gathers their public names.

A bowl is a spherical cavity plunged with a ball end mill of radius R into the blank's top face.
The workpiece frame of the design has its origin at the centre of the top face, z up, so a bowl of
depth h at (x, y) is the sphere of radius R centred at (x, y, R - h), cut below z = 0.

Touch probing: a probe ball of radius r inside the bowl touches its wall when the probe centre lies
on the concentric sphere of radius R - r.  The controller records the probe centre at trigger, so
that sphere is what we fit; the bowl radius is its radius plus r.  Sphere *centres* are used as the
material reference points: the lowest point of a bowl is not fixed in the material, it moves along
the wall by about R * alpha when the blank tilts by alpha (see docs/workpiece-setting.md).

Units: mm and deg at every interface.
"""
from __future__ import annotations

from .bowl_fit import BowlFit, SphereFit, fit_bowls, fit_sphere  # noqa: F401
from .bowl_nc import probing_program, roughing_program, touch_moves  # noqa: F401
from .bowl_plan import (Bowl, BowlPlan, default_directions, load_plan, plan_bowls, plan_from_dict,  # noqa: F401
                        plan_to_dict, save_plan)
from .bowl_probe import virtual_probe  # noqa: F401
from .bowl_touches import TOUCH_COLUMNS, Touches, read_touches, touches_to_csv, write_touches  # noqa: F401

__all__ = [
    "Bowl", "BowlPlan", "plan_bowls", "roughing_program", "probing_program", "plan_to_dict",
    "plan_from_dict", "save_plan", "load_plan", "Touches", "read_touches", "write_touches",
    "touches_to_csv", "virtual_probe", "SphereFit", "BowlFit", "fit_sphere", "fit_bowls",
]
