"""Virtual machining check: run a program's axis commands through the forward model with an
error set, sample the envelope of the ball end mill, and compare the machined part with the CAD
target (form error max / RMS, a PNG), plus paper 001's pyramid measures (base widths and the
angle between opposite slopes).

The machine itself is never re-modelled here: the real tool poses come from
:func:`mtcomp.kinematics.forward`.  Units mm and deg (reports in µm).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .._io import MtcompError
from .toolpath import RAPID, Toolpath


def real_centres(machine, path: Toolpath, q: np.ndarray, errors=None) -> np.ndarray:
    """Ball centres (N,3) in the real workpiece frame when the machine with `errors` runs q."""
    from ..kinematics import forward
    if path.tool.kind not in ("ball", "probe"):
        raise MtcompError("the envelope check needs a ball tool")
    pose = forward(machine, q, errors)
    return pose.p + path.tool.radius * pose.v


def swept_centres(machine, path: Toolpath, q: np.ndarray, errors=None,
                  max_step: float = 0.005) -> np.ndarray:
    """Ball centres along every feed move, the axes interpolated linearly between blocks as the
    control does in G01 (no TCP), sampled at most `max_step` mm apart (nominal tool point)."""
    q = np.asarray(q, float)
    seg = np.nonzero(path.motion[1:] != RAPID)[0] + 1  # moves ending at point i
    length = np.linalg.norm(path.p[seg] - path.p[seg - 1], axis=1)
    k = np.maximum(1, np.ceil(length / max_step).astype(int))
    owner = np.repeat(seg, k)
    frac = (np.arange(k.sum()) - np.repeat(np.cumsum(k) - k, k) + 1) / np.repeat(k, k)
    qs = q[owner - 1] + frac[:, None] * (q[owner] - q[owner - 1])
    return real_centres(machine, path, qs, errors)


def ball_envelope(centres: np.ndarray, radius: float, xs: np.ndarray, ys: np.ndarray,
                  reach: float) -> np.ndarray:
    """Lower envelope of balls (the machined surface) on the regular grid xs x ys: (ny, nx)
    heights, NaN where no ball reaches.

    Only grid points within `reach` mm (horizontally) of a ball centre are lowered by it: the
    ball that cuts a point of a surface tilted by theta sits r sin(theta) away from it, every
    ball farther out leaves material above that point.  Each ball is splatted onto the grid
    cells of its reach disk, one vectorised pass per cell offset.
    """
    reach = min(reach, radius)
    gx, gy = xs[1] - xs[0], ys[1] - ys[0]
    z = np.full(len(ys) * len(xs), np.inf)
    ix0 = np.rint((centres[:, 0] - xs[0]) / gx).astype(np.int64)
    iy0 = np.rint((centres[:, 1] - ys[0]) / gy).astype(np.int64)
    kx, ky = int(math.ceil(reach / gx)) + 1, int(math.ceil(reach / gy)) + 1
    r2 = radius * radius
    for dj in range(-ky, ky + 1):
        iy = iy0 + dj
        oky = (iy >= 0) & (iy < len(ys))
        for di in range(-kx, kx + 1):
            ix = ix0 + di
            ok = oky & (ix >= 0) & (ix < len(xs))
            d2 = (xs[np.clip(ix, 0, len(xs) - 1)] - centres[:, 0]) ** 2 + \
                 (ys[np.clip(iy, 0, len(ys) - 1)] - centres[:, 1]) ** 2
            ok &= d2 <= reach * reach
            if not ok.any():
                continue
            zz = centres[ok, 2] - np.sqrt(r2 - d2[ok])
            np.minimum.at(z, iy[ok] * len(xs) + ix[ok], zz)
    z[~np.isfinite(z)] = np.nan
    return z.reshape(len(ys), len(xs))


@dataclass(frozen=True)
class ProbeRun:
    """Virtual probing: recorded (M,3) stylus-centre positions in the nominal workpiece frame as
    the control reports them (nominal kinematics of the axis positions at the skip), the bowl
    index of each touch, and the skip fraction along each G31 move (NaN: no touch)."""
    recorded: np.ndarray
    bowl: np.ndarray
    fraction: np.ndarray


def simulate_probing(machine, path: Toolpath, q: np.ndarray, errors=None) -> ProbeRun:
    """Run a :func:`~mtcomp.cad_plugin.toolpath.bowl_probing` program on the machine with
    `errors`: each G31 move (axes interpolated linearly) stops where the real stylus ball
    touches the real bowl (the CAD bowl in the real workpiece frame), and the control records
    its axis positions there.  Returns the positions through the nominal kinematics (what the
    control reports in workpiece coordinates)."""
    from ..kinematics import forward
    from .toolpath import PROBE
    q = np.asarray(q, float)
    r = path.tool.radius
    R0, d0 = path.meta["radius"], path.meta["depth"]
    bowls = np.array([[cx, cy, R0 - d0] for cx, cy in path.meta["centres"]])
    rho = R0 - r
    idx = np.nonzero(path.motion == PROBE)[0]
    qa, qb = q[idx - 1], q[idx]
    pa, pb = real_centres(machine, path, qa, errors), real_centres(machine, path, qb, errors)
    k = np.argmin(np.linalg.norm(path.centre[idx][:, None, :] - bowls[None], axis=2), axis=1)
    S = bowls[k]
    # The stylus centre moves (nearly) straight: |pa + s (pb - pa) - S| = rho, first root.
    d, w = pb - pa, pa - S
    A, B, Cc = (d * d).sum(1), 2 * (d * w).sum(1), (w * w).sum(1) - rho * rho
    disc = B * B - 4 * A * Cc
    s = (-B + np.sqrt(np.where(disc >= 0, disc, np.nan))) / (2 * A)  # leaving the air ball
    s = np.where((s >= 0) & (s <= 1), s, np.nan)
    # With the rotary axes standing still the stylus centre moves straight between the two
    # end points, so the root above is the exact skip point (checked below).
    rot = list(machine.rotary_indices)
    if rot and np.max(np.abs(qb[:, rot] - qa[:, rot]), initial=0.0) > 1e-9:
        raise MtcompError("a probing move turns a rotary axis; simulate_probing assumes it does not")
    qs = qa + np.nan_to_num(s)[:, None] * (qb - qa)
    nominal = forward(machine, qs)
    rec = nominal.p + r * nominal.v
    rec[np.isnan(s)] = np.nan
    return ProbeRun(rec, k, s)


@dataclass(frozen=True)
class FormCheck:
    """Machined surface against the CAD target on a grid: error = machined - target height, mm
    (positive: material left).  max is the largest |error|."""
    x: np.ndarray
    y: np.ndarray
    error: np.ndarray      # (ny, nx), NaN outside the machined region
    max: float
    rms: float
    min: float
    peak: float

    def summary(self) -> str:
        return (f"form error against the CAD target: max |e| {self.max * 1e3:.4f} µm, "
                f"RMS {self.rms * 1e3:.4f} µm (from {self.min * 1e3:+.4f} to "
                f"{self.peak * 1e3:+.4f} µm, {np.isfinite(self.error).sum()} grid points)")


def pyramid_surface(width: float, height: float):
    """Target height function z(x, y) of the pyramid on the flat z = 0 (workpiece frame)."""
    w = width / 2.0

    def z(x, y):
        return np.maximum(0.0, height * (1.0 - np.maximum(np.abs(x), np.abs(y)) / w))
    return z


def form_error(machine, path: Toolpath, q: np.ndarray, errors, target, extent: float,
               grid: float = 0.01) -> FormCheck:
    """Form error of the surface cut by `path` run as commands q on the machine with `errors`.

    The cutter is swept along every feed move (axes interpolated between blocks, samples at
    most grid/2 apart).  target: z(x, y) of the CAD surface; extent: half-size of the square
    region checked, mm; grid: sampling step, mm.
    """
    c = swept_centres(machine, path, q, errors, max_step=grid / 2)
    r = path.tool.radius
    n = path.normal[path.cutting]
    tilt = math.acos(min(1.0, float(np.min(n[:, 2]))))
    spacing = max(grid, path.meta.get("stepover", grid))
    # The ball cutting a point sits r sin(tilt) from it when a pass runs right there, and at
    # most half a stepover farther otherwise; errors tilt the surface a little more.
    reach = r * math.sin(tilt + math.radians(1.0)) + 0.5 * spacing + grid
    xs = np.arange(-extent, extent + grid / 2, grid)
    X, Y = np.meshgrid(xs, xs)
    zm = ball_envelope(c, r, xs, xs, reach)
    e = zm - target(X, Y)
    fin = e[np.isfinite(e)]
    if not fin.size:
        raise MtcompError("no grid point lies in the machined region")
    return FormCheck(xs, xs, e, float(np.max(np.abs(fin))), float(np.sqrt(np.mean(fin ** 2))),
                     float(fin.min()), float(fin.max()))


@dataclass(frozen=True)
class PyramidMeasure:
    """Paper 001's measures of the machined pyramid: base widths W1..W4 (edge lengths between
    the base corners on the datum plane z = 0, mm) and the angles between the opposite slopes
    S1&S2 (facing -x, +x) and S3&S4 (facing -y, +y), deg; plane normals (4,3) and offsets."""
    widths: np.ndarray
    angles: np.ndarray
    normals: np.ndarray
    offsets: np.ndarray

    def summary(self, width: float | None = None, angle: float | None = None) -> str:
        w = " ".join(f"W{i + 1} {v * 1e3:.4f}" for i, v in enumerate(self.widths))
        a = f"S1&S2 {self.angles[0]:.5f}  S3&S4 {self.angles[1]:.5f}"
        out = f"widths [µm]: {w}\nangles [deg]: {a}"
        if width is not None:
            out += (f"\nwidth error max {np.max(np.abs(self.widths - width)) * 1e3:.4f} µm"
                    f" (target {width * 1e3:g} µm)")
        if angle is not None:
            out += f"; angle error max {np.max(np.abs(self.angles - angle)):.5f} deg (target {angle:g})"
        return out


def _slope_normals(width: float, height: float) -> np.ndarray:
    w = width / 2.0
    k = 1.0 / math.hypot(w, height)
    return np.array([[-height, 0, w], [height, 0, w], [0, -height, w], [0, height, w]]) * k


def pyramid_widths_angles(machine, path: Toolpath, q: np.ndarray, errors=None) -> PyramidMeasure:
    """Base widths and slope angles of the pyramid cut by a :func:`pyramid_finishing` path.

    Every ball that touched a slope in its interior is tangent to the machined slope, so the
    slope is the plane through those real ball centres moved by the tool radius along its
    normal; scallops between passes do not bias it.  The base corners are where adjacent slopes
    meet the datum plane z = 0 of the real workpiece frame (the blank's top face)."""
    width, height = path.meta["width"], path.meta["height"]
    c = real_centres(machine, path, q, errors)
    r = path.tool.radius
    nominal = _slope_normals(width, height)
    normals, offsets = [], []
    for n0 in nominal:
        sel = path.cutting & (np.linalg.norm(path.normal - n0, axis=1) < 1e-9)
        if sel.sum() < 3:
            raise MtcompError("too few contacts on a pyramid slope to fit it")
        pts = c[sel]
        m = pts.mean(0)
        n = np.linalg.svd(pts - m, full_matrices=False)[2][2]
        n = n if n @ n0 > 0 else -n
        normals.append(n)
        offsets.append(n @ m - r)  # plane n.x = offset of the machined slope
    N, D = np.array(normals), np.array(offsets)

    def corner(i, j):
        A = np.array([N[i], N[j], [0.0, 0.0, 1.0]])
        return np.linalg.solve(A, [D[i], D[j], 0.0])
    # slopes: 0 -x, 1 +x, 2 -y, 3 +y; corners counter-clockwise from (-x, -y)
    P = [corner(0, 2), corner(1, 2), corner(1, 3), corner(0, 3)]
    widths = np.array([np.linalg.norm(P[(k + 1) % 4] - P[k]) for k in range(4)])
    ang = lambda a, b: 180.0 - math.degrees(math.acos(np.clip(N[a] @ N[b], -1, 1)))  # noqa: E731
    return PyramidMeasure(widths, np.array([ang(0, 1), ang(2, 3)]), N, D)


def _save(fig, out, title: str) -> None:
    """Title, layout, and the PNG written atomically when `out` is given."""
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    if out is not None:
        from .._io import save_figure
        save_figure(fig, out, dpi=120)


def _top_view(ax, path: Toolpath, size: float):
    """Top view of a toolpath: every move in grey, cutting points coloured by tip z (mm)."""
    cut = path.cutting
    ax.plot(path.p[:, 0], path.p[:, 1], lw=0.3, color="0.6")
    sc = ax.scatter(path.p[cut, 0], path.p[cut, 1], c=path.p[cut, 2], s=size, cmap="viridis")
    ax.set_aspect("equal")
    ax.set_xlabel("x [mm]")
    ax.set_ylabel("y [mm]")
    return sc


def plot_check(path: Toolpath, form: FormCheck, out=None, title: str = ""):
    """The toolpath (top view, cutting moves) and the form error map in µm; written as PNG to
    `out` if given.  Returns the matplotlib Figure (no pyplot state, backend untouched)."""
    from matplotlib.figure import Figure
    fig = Figure(figsize=(11, 4.8))
    a0, a1 = fig.subplots(1, 2)
    _top_view(a0, path, 0.5)
    a0.set_title(f"toolpath {path.name} ({len(path)} poses), colour: tip z")
    im = a1.imshow(form.error * 1e3, origin="lower", cmap="coolwarm",
                   extent=[form.x[0], form.x[-1], form.y[0], form.y[-1]])
    fig.colorbar(im, ax=a1, label="machined − target [µm]")
    a1.set_xlabel("x [mm]")
    a1.set_title(f"form error: max {form.max * 1e3:.3f} µm, RMS {form.rms * 1e3:.3f} µm")
    _save(fig, out, title)
    return fig


def plot_toolpath(path: Toolpath, out=None, title: str = "", q: np.ndarray | None = None,
                  names=()):
    """Top view of the toolpath (cutting points coloured by tip z) and, if given, the axis
    commands over the block index; PNG to `out` if given.  Returns the Figure."""
    from matplotlib.figure import Figure
    fig = Figure(figsize=(11 if q is not None else 6, 4.8))
    axs = fig.subplots(1, 2 if q is not None else 1)
    a0 = axs[0] if q is not None else axs
    fig.colorbar(_top_view(a0, path, 1.0), ax=a0, label="tip z [mm]")
    a0.set_title(f"{path.name}: {len(path)} poses, {path.tool.description}")
    if q is not None:
        a1 = axs[1]
        for k, name in enumerate(names):
            a1.plot(q[:, k], lw=0.8, label=f"{name} [{'deg' if name in 'ABC' else 'mm'}]")
        a1.set_xlabel("block")
        a1.set_title("axis commands")
        a1.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0), frameon=False)
    _save(fig, out, title)
    return fig
