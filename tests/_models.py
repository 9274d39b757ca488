"""Shared test helpers: random error sets and poses of realistic size, an independent model."""
from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from mtcomp.errors import (AxisErrorTable, ErrorSet, GeometricErrors, ToolSetting, WorkpieceSetting,
                           component_names)


def random_commands(machine, n, rng, span=0.4, avoid_singular=True):
    """Commands inside `span` of each travel (rotary within +-60 deg); |B| >= 5 deg on 5-axis
    tables so that workpiece rotations stay away from the B = 0 singularity."""
    lo = np.array([max(a.limits[0], -60.0) if a.is_rotary else a.limits[0] * span for a in machine.axes])
    hi = np.array([min(a.limits[1], 60.0) if a.is_rotary else a.limits[1] * span for a in machine.axes])
    q = rng.uniform(lo, hi, (n, machine.n_axes))
    if avoid_singular and machine.n_rotary == 2:
        for k, a in enumerate(machine.axes):
            if a.is_rotary and a.name == "B":
                q[:, k] = np.where(np.abs(q[:, k]) < 5.0, np.copysign(5.0, q[:, k]) + q[:, k], q[:, k])
    return q


def random_errors(machine, rng, setting=1.0, trans=0.05, ang=100e-6, wp_angle=2.0, n_table=15,
                  tables=True, location=True):
    """Setting errors up to `setting` mm, geometric errors up to `trans` mm and `ang` rad."""
    tabs = {}
    if tables:
        for a in machine.axes:
            pos = np.linspace(a.limits[0], a.limits[1], n_table)
            vals = {}
            for j, name in enumerate(component_names(a.name)):
                amp = trans if j < 3 else ang
                vals[name] = rng.uniform(-amp, amp, n_table)
            tabs[a.name] = AxisErrorTable(a.name, pos, vals)
    loc = {}
    if location:
        for a in machine.axes:
            if a.is_rotary:
                for c in "XYZ":
                    loc[f"E{c}0{a.name}"] = float(rng.uniform(-trans, trans))
                for c in "ABC":
                    loc[f"E{c}0{a.name}"] = float(rng.uniform(-ang, ang))
            else:
                for c in "ABC":
                    if c != {"X": "A", "Y": "B", "Z": "C"}.get(a.name):
                        loc[f"E{c}0{a.name}"] = float(rng.uniform(-ang, ang))
    return ErrorSet(ToolSetting(tuple(rng.uniform(-setting, setting, 3))),
                    WorkpieceSetting(tuple(rng.uniform(-setting, setting, 3)),
                                     tuple(rng.uniform(-wp_angle, wp_angle, 3))),
                    GeometricErrors(tabs, loc))


def _h(R=np.eye(3), t=(0, 0, 0)):
    H = np.eye(4)
    H[:3, :3] = R
    H[:3, 3] = t
    return H


def independent_forward(machine, q, errors):
    """A per-point 4x4 implementation written from docs/model.md with scipy's Rotation, sharing
    no code with mtcomp.kinematics; returns (p, R) of one pose."""
    T = np.eye(4)
    geo = errors.geometric
    for ax, qi in zip(machine.axes, q):
        u = np.array(ax.direction)
        c = np.array(ax.location)
        d0 = np.array([geo.location.get(f"E{k}0{ax.name}", 0.0) for k in "XYZ"])
        e0 = np.array([geo.location.get(f"E{k}0{ax.name}", 0.0) for k in "ABC"])
        if ax.is_rotary:
            zero = e0 @ u
            u2 = Rotation.from_rotvec(e0 - zero * u).apply(u)
            c2 = c + d0
            M = _h(t=c2) @ _h(Rotation.from_rotvec(u2 * (np.radians(qi) + zero)).as_matrix()) @ _h(t=-c2)
        else:
            M = _h(t=Rotation.from_rotvec(e0).apply(u) * qi)
        E = np.eye(4)
        if ax.name in geo.tables:
            tab = geo.tables[ax.name]
            names = component_names(ax.name)
            v = [np.interp(qi, tab.position, tab.values[n]) if n in tab.values else 0.0 for n in names]
            E = _h(t=c) @ _h(t=v[:3]) @ _h(Rotation.from_rotvec(v[3:]).as_matrix()) @ _h(t=-c)
        moving_far = (ax.side == "tool") != ax.is_rotary  # error body is the child frame
        T = T @ (M @ E if moving_far else E @ M)
    tp = np.array(machine.tool_point) + np.array(errors.tool.offset)
    Rw = Rotation.from_euler("xyz", errors.workpiece.angles, degrees=True).as_matrix()
    W = _h(Rw, errors.workpiece.translation)
    T = np.linalg.inv(W) @ T
    return (T @ np.append(tp, 1.0))[:3], T[:3, :3]


def kernel_stats(tmp_path, script: str) -> dict:
    """Counters of a test build of the kernel (-DMTK_STATS, printed at exit as ``STATS name
    count ...``) after `script` has run in a child process on one thread; `script` is formatted
    with ``tests`` (this directory, for imports) and ``lib`` (the test build's path).  Skips
    without a C compiler."""
    import os
    import subprocess
    import sys

    import pytest

    from mtcomp import _kernel
    cc = _kernel.find_compiler()
    if not cc:
        pytest.skip("no C compiler")
    src = _kernel.source_dir()
    lib = tmp_path / ("libmtk-stats" + _kernel._SUFFIX)
    if not lib.exists():
        subprocess.run([cc, *_kernel.CFLAGS, "-DMTK_STATS",
                        *(str(src / f) for f in _kernel.SOURCES if f.endswith(".c")),
                        "-o", str(lib), "-lm"], check=True, capture_output=True)
    tests = os.path.dirname(os.path.abspath(__file__))
    run = subprocess.run([sys.executable, "-c", script.format(tests=tests, lib=str(lib))],
                         capture_output=True, text=True, env=dict(os.environ, MTCOMP_THREADS="1"),
                         check=True)
    words = run.stderr.split("STATS", 1)[1].split()
    return dict(zip(words[0::2], (int(w) for w in words[1::2])))
