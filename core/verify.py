"""Verification of NC programs: run a whole program through the machine model and check the
tool against the stock (rapids keep a clearance) and the part (feeds do not gouge).

Every block is interpolated in axis space as a control without tool centre point control does
(G00 and G01 both linear in the axis commands; Fanuc parameter LRP = 1 for G00; G02/G03 on
their circle in the plane axes, the other axes linear), and the real tool point comes from
:func:`mtcomp.kinematics.forward` (nominal, or with an error set).  The samples along a block
lie at most ``step`` mm apart (measured on the tool point, refined until true), so every point
of the swept tool path lies within step/2 of a sample: the reported clearance is exact to
step/2 and a violation is declared when ``clearance_at_samples - step/2 < clearance``.

Checks (mm):
* rapid blocks (G00): signed distance of the tool to the **stock** >= ``clearance``;
* feed blocks (G01/G02/G03, not G31): the tool does not enter the **part** by more than
  ``tolerance`` (the finished shape; the cut itself touches it);
* G31 probing moves end past the surface by design and are not checked.

G43.4 tool-centre-point blocks are run as the machine runs them: the control's nominal inverse
of the written tip and angles (with the H tool length), then the forward model with the errors;
feeds move the tip straight, rapids are checked tip-straight and axis-linear (controls differ).
G68 rotation is applied; under G43/G44 H the tool tip, not the gauge point, is checked.

The tool is a point (the edge of a V tool) or a ball of ``tool_radius`` about the point
``tool_radius`` along the tool axis (ball end mill, probe).  The holder and the flanks of a V
tool are not modelled.  Stocks: :class:`Box` (analytic), :class:`HalfSpace` (a plane with
material below) and :class:`ShapeStock` (any CadQuery/OCP solid, e.g. from a STEP file, signed
distance through OCP's BRepExtrema and solid classifier).  Units mm, deg; reports in µm.
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass, field, replace

import numpy as np

from ._io import InputError, MtcompError

RAPID, FEED, PROBE = 0, 1, 2


class VerifyError(MtcompError):
    """A program fails the verification; `result` holds the full report."""

    def __init__(self, message: str, result: "VerifyResult"):
        self.result = result
        super().__init__(message)


# ----------------------------------------------------------------------------------- stocks
@dataclass(frozen=True)
class Box:
    """Axis-aligned box [lo, hi] in the workpiece frame, mm."""
    lo: tuple
    hi: tuple

    def __post_init__(self):
        lo, hi = np.asarray(self.lo, float), np.asarray(self.hi, float)
        if lo.shape != (3,) or hi.shape != (3,) or np.any(hi <= lo):
            raise InputError(f"box needs lo < hi in x, y, z, got {self.lo} {self.hi}", field="stock")

    def distance(self, pts: np.ndarray) -> np.ndarray:
        """Signed distance (N,) mm: positive outside, negative inside (exact for a box)."""
        lo, hi = np.asarray(self.lo, float), np.asarray(self.hi, float)
        c, h = (lo + hi) / 2, (hi - lo) / 2
        d = np.abs(np.asarray(pts, float) - c) - h
        out = np.linalg.norm(np.maximum(d, 0.0), axis=1)
        return out + np.minimum(d.max(axis=1), 0.0)

    def describe(self) -> str:
        return ("box x [{:g}, {:g}] y [{:g}, {:g}] z [{:g}, {:g}] mm"
                .format(self.lo[0], self.hi[0], self.lo[1], self.hi[1], self.lo[2], self.hi[2]))


@dataclass(frozen=True)
class HalfSpace:
    """Material below the plane z = `top` (workpiece frame), mm."""
    top: float = 0.0

    def distance(self, pts: np.ndarray) -> np.ndarray:
        return np.asarray(pts, float)[:, 2] - self.top

    def describe(self) -> str:
        return f"material below z = {self.top:g} mm"


@dataclass(frozen=True)
class CylinderZ:
    """Material in the cylinder about the z axis of `radius` between z0 and z1, mm."""
    radius: float
    z0: float
    z1: float

    def distance(self, pts: np.ndarray) -> np.ndarray:
        pts = np.asarray(pts, float)
        dr = np.hypot(pts[:, 0], pts[:, 1]) - self.radius
        dz = np.maximum(self.z0 - pts[:, 2], pts[:, 2] - self.z1)
        return np.hypot(np.maximum(dr, 0), np.maximum(dz, 0)) + np.minimum(np.maximum(dr, dz), 0)

    def describe(self) -> str:
        return f"cylinder R{self.radius:g} z [{self.z0:g}, {self.z1:g}] mm"


@dataclass(frozen=True)
class SphereCavity:
    """Material outside the sphere of `radius` about `centre` (a concave dish), mm."""
    centre: tuple
    radius: float

    def distance(self, pts: np.ndarray) -> np.ndarray:
        return self.radius - np.linalg.norm(np.asarray(pts, float) - np.asarray(self.centre, float), axis=1)

    def describe(self) -> str:
        return f"outside the sphere R{self.radius:g} about {tuple(self.centre)}"


@dataclass(frozen=True)
class Intersection:
    """Material common to several stocks.  The distance is the largest of theirs: exact inside,
    a lower bound outside (never larger than the true clearance, so a check stays safe)."""
    parts: tuple

    def distance(self, pts: np.ndarray) -> np.ndarray:
        return np.max([s.distance(pts) for s in self.parts], axis=0)

    def describe(self) -> str:
        return " and ".join(s.describe() for s in self.parts)


class ShapeStock:
    """A CadQuery Workplane/Shape or OCP TopoDS_Shape as stock or part.

    Signed distance per point through OCP (BRepExtrema_DistShapeShape for the distance,
    BRepClass3d_SolidClassifier for the sign), about a millisecond per point near the solid;
    points farther from the bounding box than `far` mm take the box distance (a lower bound,
    which is all a clearance check needs)."""

    def __init__(self, shape, name: str = "shape", far: float = 5.0):
        import cadquery as cq
        if isinstance(shape, cq.Workplane):
            shape = shape.val()
        self.shape = shape.wrapped if hasattr(shape, "wrapped") else shape
        bb = cq.Shape.cast(self.shape).BoundingBox()
        self.box = Box((bb.xmin, bb.ymin, bb.zmin), (bb.xmax, bb.ymax, bb.zmax))
        self.name, self.far = name, far

    @classmethod
    def from_step(cls, path) -> "ShapeStock":
        from pathlib import Path
        p = Path(path)
        if not p.is_file():
            raise InputError("STEP file not found", p)
        import cadquery as cq
        try:
            shape = cq.importers.importStep(str(p)).val()
        except Exception as exc:  # OCP raises its own types for unreadable files
            raise InputError(f"cannot read STEP: {exc}", p) from None
        return cls(shape, p.name)

    def distance(self, pts: np.ndarray, progress=None) -> np.ndarray:
        """Signed distance (mm, negative inside) of points (N, 3).  ``progress(done, total)``
        is called as the points near the solid are evaluated (they take the time)."""
        from OCP.BRepBuilderAPI import BRepBuilderAPI_MakeVertex
        from OCP.BRepClass3d import BRepClass3d_SolidClassifier
        from OCP.BRepExtrema import BRepExtrema_DistShapeShape
        from OCP.gp import gp_Pnt
        from OCP.TopAbs import TopAbs_IN
        pts = np.asarray(pts, float)
        d = self.box.distance(pts)
        near = np.nonzero(d < self.far)[0]
        classifier = BRepClass3d_SolidClassifier(self.shape)
        # the solid loaded once, each point as the second shape: 1.7x faster than a new
        # BRepExtrema_DistShapeShape per point (310 against 530 µs per point, 15 faces)
        ext = BRepExtrema_DistShapeShape()
        ext.LoadS1(self._boundary())
        for k, i in enumerate(near.tolist()):
            p = gp_Pnt(*map(float, pts[i]))
            ext.LoadS2(BRepBuilderAPI_MakeVertex(p).Vertex())
            ext.Perform()
            dist = ext.Value()
            classifier.Perform(p, 1e-7)
            d[i] = -dist if classifier.State() == TopAbs_IN else dist
            if progress is not None and k % 256 == 0:
                progress(k, len(near))
        if progress is not None:
            progress(len(near), len(near))
        return d

    def _boundary(self):
        """The solid's boundary (its shells as one compound): the distance from a point inside
        a solid to the solid is 0, so the depth of a gouge is the distance to the boundary (with
        the solid itself every point tool inside read -0 and no gouge was ever found)."""
        from OCP.BRep import BRep_Builder
        from OCP.TopAbs import TopAbs_SHELL
        from OCP.TopExp import TopExp_Explorer
        from OCP.TopoDS import TopoDS_Compound
        comp, builder = TopoDS_Compound(), BRep_Builder()
        builder.MakeCompound(comp)
        ex, n = TopExp_Explorer(self.shape, TopAbs_SHELL), 0
        while ex.More():
            builder.Add(comp, ex.Current())
            ex.Next()
            n += 1
        return comp if n else self.shape

    def describe(self) -> str:
        return f"solid {self.name} ({self.box.describe()})"


def parse_stock(spec: str):
    """Stock from the command line: ``box:x0,y0,z0,x1,y1,z1`` (mm), ``plane:Z`` (material below
    z = Z) or a STEP file name."""
    s = str(spec).strip()
    if s.lower().startswith("box:"):
        try:
            v = [float(x) for x in s[4:].split(",")]
        except ValueError:
            v = []
        if len(v) != 6:
            raise InputError(f"expected box:x0,y0,z0,x1,y1,z1 in mm, got {spec!r}", field="--stock")
        return Box(tuple(v[:3]), tuple(v[3:]))
    if s.lower().startswith("plane:"):
        try:
            return HalfSpace(float(s[6:]))
        except ValueError:
            raise InputError(f"expected plane:Z in mm, got {spec!r}", field="--stock") from None
    if s.lower().endswith((".step", ".stp")):
        return ShapeStock.from_step(s)
    raise InputError(f"stock must be box:x0,y0,z0,x1,y1,z1, plane:Z or a .step file, got {spec!r}",
                     field="--stock")


# ---------------------------------------------------------------------------------- sampling
def tcp_to_axes(machine, w: np.ndarray) -> np.ndarray:
    """Axis commands (N, n) for tool-centre-point words w (N, n): the linear columns hold the
    tool point X Y Z in the workpiece frame, the rotary columns the rotary angles, as a G43.4
    control reads them with its nominal kinematics.  The linear axes translate the tool point
    along their (rotated) directions, so one least-squares step is exact."""
    from .kinematics import forward_position
    w = np.asarray(w, float)
    lin = [i for i, a in enumerate(machine.axes) if not a.is_rotary]
    xyz = ["XYZ".index(machine.axes[i].name) for i in lin]
    q = w.copy()
    q[:, lin] = 0.0
    p0 = forward_position(machine, q)
    J = np.empty((len(w), 3, len(lin)))
    for k, i in enumerate(lin):
        dq = q.copy()
        dq[:, i] = 1.0
        J[:, :, k] = forward_position(machine, dq) - p0
    target = np.zeros((len(w), 3))
    target[:, xyz] = w[:, lin]
    q[:, lin] = np.einsum("nij,nj->ni", np.linalg.pinv(J), target - p0)
    return q


def _tool_points(machine, q: np.ndarray, errors, tool_radius: float, tcp: bool = False,
                 lengths=None) -> np.ndarray:
    """Tool points (M, 3) for axis positions q (M, n) (or G43.4 words with ``tcp``) with the
    tool lengths (M,) mm (None: 0, the machine file's tool point), through the forward model."""
    from .gcode.tcp import tool_machine
    from .kinematics import forward, forward_position
    q = np.asarray(q, float)
    L = np.zeros(len(q)) if lengths is None else np.broadcast_to(np.asarray(lengths, float), (len(q),))
    out = np.empty((len(q), 3))
    for Lv in np.unique(L):
        rows = np.flatnonzero(L == Lv) if len(np.unique(L)) > 1 else slice(None)
        m = tool_machine(machine, float(Lv))
        qr = tcp_to_axes(m, q[rows]) if tcp else q[rows]
        if tool_radius:
            pose = forward(m, qr, errors, strict=False)
            out[rows] = pose.p + tool_radius * pose.v
        else:   # positions only: the kernel builds no orientations
            out[rows] = forward_position(m, qr, errors, strict=False)
    return out


def _tip_words(machine, Q: np.ndarray, lengths) -> np.ndarray:
    """G43.4 words (tool tip, angles) of axis positions Q (M, n) on the nominal machine with the
    tool lengths (M,): what a control in tool centre point mode takes as the current point."""
    from .gcode.tcp import tool_machine
    from .kinematics import forward_position
    Q = np.asarray(Q, float)
    W = Q.copy()
    lin = [i for i, a in enumerate(machine.axes) if not a.is_rotary]
    xyz = ["XYZ".index(machine.axes[i].name) for i in lin]
    L = np.broadcast_to(np.asarray(lengths, float), (len(Q),))
    for Lv in np.unique(L):
        rows = np.flatnonzero(L == Lv)
        W[np.ix_(rows, lin)] = forward_position(tool_machine(machine, float(Lv)), Q[rows])[:, xyz]
    return W


def _axes_of(machine, q: np.ndarray, tcp, lengths) -> np.ndarray:
    """Axis positions of blocks: q itself, G43.4 rows (tcp mask) through the control's nominal
    inverse with their tool lengths."""
    q = np.asarray(q, float)
    tcp = np.asarray(tcp, bool)
    if not tcp.any():
        return q
    from .gcode.tcp import tool_machine
    Q = q.copy()
    L = np.asarray(lengths, float)
    for Lv in np.unique(L[tcp]):
        rows = np.flatnonzero(tcp & (L == Lv))
        Q[rows] = tcp_to_axes(tool_machine(machine, float(Lv)), q[rows])
    return Q


def _interpolate(qa, qb, frac, arc=None, rates=None):
    """Axis positions at fractions `frac` (M,) between block ends qa, qb (M, n): linear, or for
    arcs (centre (M, 2), sweep (M,), plane columns (M, 2)) on the circle.  rates (n,): every axis
    runs at its own rate and stops when it arrives (dog-leg rapids); frac is then the fraction
    of the block's time, the time of its slowest axis."""
    if rates is not None:
        t_axis = np.abs(qb - qa) / rates
        t_block = t_axis.max(axis=1, keepdims=True)
        f = np.where(t_axis > 0, np.minimum(1.0, frac[:, None] * t_block / np.where(t_axis > 0, t_axis, 1.0)), 1.0)
        return qa + f * (qb - qa)
    q = qa + frac[:, None] * (qb - qa)
    if arc is not None:
        centre, sweep, cols, is_arc = arc
        k = np.nonzero(is_arc)[0]
        if k.size:
            iu, iv = cols[k, 0], cols[k, 1]
            su, sv = qa[k, iu] - centre[k, 0], qa[k, iv] - centre[k, 1]
            r0, a0 = np.hypot(su, sv), np.arctan2(sv, su)
            eu, ev = qb[k, iu] - centre[k, 0], qb[k, iv] - centre[k, 1]
            r1 = np.hypot(eu, ev)
            a = a0 + frac[k] * sweep[k]
            r = r0 + frac[k] * (r1 - r0)  # a control spreads a small radius mismatch linearly
            q[k, iu] = centre[k, 0] + r * np.cos(a)
            q[k, iv] = centre[k, 1] + r * np.sin(a)
    return q


def sweep(machine, q: np.ndarray, blocks, errors=None, tool_radius: float = 0.0,
          step: float = 0.005, arcs=None, max_rounds: int = 12, tcp=False,
          rapid_rates=None, tool_length=None, space: str = "tip", lines=None):
    """Samples of the tool along the moves into `blocks` (indices i >= 1: the move q[i-1] -> q[i]).

    Returns (points (M,3) mm, owner (M,) block index, spacing (B,) largest distance between
    consecutive samples of each block, mm).  The number of samples of each block doubles until
    that spacing is <= step, so every point of the swept path is within step/2 of a sample.
    arcs: optional (centre (N,2), sweep (N,), plane columns (N,2), is_arc (N,)) per block.
    tcp: True or a mask (N,): those rows of q are tool-centre-point words (G43.4: tool tip in the
    workpiece frame, rotary angles), turned into axis positions by the control's nominal inverse
    (:func:`tcp_to_axes`) with the row's tool length (tool_length (N,) mm, default 0: the
    machine file's tool point; the tool point checked is the tip of that tool).  A move into a
    G43.4 row runs, with ``space="tip"``, linearly in the words (the control moves the tip
    straight and the rotary axes linearly, from the tip the previous pose gives with this
    block's tool); with ``space="joint"`` linearly in the axis positions (controls that move
    G00 under TCP axis by axis).  Other moves are linear in axis space.
    rapid_rates (n_axes,) mm/min and deg/min: the blocks are dog-leg rapids, each axis at its own
    rate (a control with non-linear rapid traverse, Fanuc LRP = 0); None: linear.
    A block that needs more than MAX_BLOCK_SAMPLES samples (a move of kilometres: a typing
    error such as R123456789012.5) is refused (InputError naming ``lines[block]``)."""
    blocks = np.asarray(blocks, int)
    q = np.asarray(q, float)
    if blocks.size == 0:
        return np.zeros((0, 3)), np.zeros(0, int), np.zeros(0)
    mask = np.broadcast_to(np.asarray(tcp, bool), (len(q),))
    L = (np.zeros(len(q)) if tool_length is None
         else np.broadcast_to(np.asarray(tool_length, float), (len(q),)))
    Q = _axes_of(machine, q, mask, L)
    in_tip = mask[blocks] & (space == "tip")
    # each move from A to B in its interpolation space (tip words or axis positions)
    A, B = Q[blocks - 1].copy(), Q[blocks].copy()
    if in_tip.any():
        A[in_tip] = _tip_words(machine, Q[blocks[in_tip] - 1], L[blocks[in_tip]])
        B[in_tip] = q[blocks[in_tip]]
    Lb = L[blocks]
    ends_a = _tool_points(machine, Q[blocks - 1], errors, tool_radius, lengths=Lb)
    ends_b = _tool_points(machine, Q[blocks], errors, tool_radius, lengths=Lb)
    n = np.maximum(1, np.ceil(np.linalg.norm(ends_b - ends_a, axis=1) / step)).astype(int)
    rot = list(machine.rotary_indices)
    if rot:  # rotary blocks: start from 8 samples per degree turned, refined below
        turn = np.abs(B[:, rot] - A[:, rot]).max(axis=1)
        n = np.maximum(n, np.ceil(turn * 8).astype(int))
    if arcs is not None:
        n = np.maximum(n, np.where(arcs[3][blocks], np.ceil(np.abs(arcs[1][blocks]) * 180).astype(int), 1))
    _refuse_sample_count(n, blocks, lines, step)
    for _ in range(max_rounds):
        owner = np.repeat(np.arange(len(blocks)), n + 1)
        start = np.repeat(np.cumsum(n + 1) - (n + 1), n + 1)
        frac = (np.arange(owner.size) - start) / np.repeat(n, n + 1)
        b = blocks[owner]
        sub = None if arcs is None else (arcs[0][b], arcs[1][b], arcs[2][b], arcs[3][b] & ~in_tip[owner])
        qs = _interpolate(A[owner], B[owner], frac, sub,
                          None if rapid_rates is None else np.asarray(rapid_rates, float))
        if in_tip.any():
            t = in_tip[owner]
            qs[t] = _axes_of(machine, qs[t], np.ones(int(t.sum()), bool), L[b[t]])
        pts = _tool_points(machine, qs, errors, tool_radius, lengths=L[b])
        gap = np.linalg.norm(np.diff(pts, axis=0), axis=1)
        gap[np.cumsum(n + 1)[:-1] - 1] = 0.0  # across two blocks
        spacing = np.zeros(len(blocks))
        np.maximum.at(spacing, owner[:-1], gap)
        bad = spacing > step * (1 + 1e-9)
        if not bad.any():
            break
        n = np.where(bad, n * np.maximum(2, np.ceil(spacing / step)).astype(int), n)
        _refuse_sample_count(n, blocks, lines, step)
    return pts, blocks[owner], spacing


#: Most samples one block may take (at 5 µm: 100 m of tool path; 1.6 GB of points).
MAX_BLOCK_SAMPLES = 20_000_000


def _refuse_sample_count(n, blocks, lines, step):
    """A block whose sampling would exceed MAX_BLOCK_SAMPLES is refused naming its line (a cycle
    level of 10**11 mm once sampled until the memory ran out, exit 3)."""
    big = np.flatnonzero(~(np.asarray(n, float) <= MAX_BLOCK_SAMPLES))
    if not len(big):
        return
    b = int(blocks[big[0]])
    raise InputError(f"the tool path of this block is {float(n[big[0]]) * step / 1e3:.4g} m long "
                     f"(more than {MAX_BLOCK_SAMPLES:,} samples {step * 1e3:g} µm apart): no machine "
                     "moves that far; a number is wrong",
                     line=b if lines is None else int(np.asarray(lines)[b]))


# ----------------------------------------------------------------------------------- results
@dataclass(frozen=True)
class Violation:
    """One block that fails: `kind` "rapid" (clearance to the stock) or "gouge" (into the part);
    `value` the clearance (rapid) or the signed distance to the part (gouge), mm; `point` the
    worst tool point (workpiece frame, mm); `block` row index, `line` source line (1-based)."""
    block: int
    line: int
    kind: str
    value: float
    point: tuple
    text: str = ""
    path: str = ""                   # "axis": a G43.4 rapid interpolated in axis space

    def describe(self, clearance: float, tolerance: float) -> str:
        where = f"line {self.line}" + (f" ({self.text.strip()})" if self.text else "")
        if self.path == "axis":
            where += " [G43.4 rapid, axes interpolated linearly]"
        x, y, z = self.point
        if self.kind == "rapid":
            what = ("the tool enters the stock" if self.value < 0 else "the tool passes the stock")
            return (f"{where}: rapid move: {what} at {_um(self.value)} (clearance "
                    f"{_um(clearance)} required) at x {x:.4f} y {y:.4f} z {z:.4f} mm")
        return (f"{where}: feed move gouges the part by {_um(-self.value)} (tolerance "
                f"{_um(tolerance)}) at x {x:.4f} y {y:.4f} z {z:.4f} mm")


def _um(mm: float) -> str:
    """A length in µm with the digits it needs (nm-level values keep them)."""
    v = mm * 1e3
    if abs(v) >= 100:
        return f"{v:.0f} µm"
    if abs(v) >= 1:
        return f"{v:.2f} µm"
    return f"{v * 1e3:.0f} nm"


@dataclass(frozen=True)
class VerifyResult:
    """Outcome of :func:`verify_commands` / :func:`verify_program` (lengths mm).

    min_clearance: smallest clearance of any rapid to the stock (inf without rapids or stock),
    min_clearance_line: its source line; min_part: smallest signed distance of a feed move to
    the part (inf without a part); violations: worst sample of every failing block."""
    name: str
    n_blocks: int
    n_samples: int
    step: float
    clearance: float
    tolerance: float
    min_clearance: float
    min_clearance_line: int
    min_part: float
    violations: tuple = field(default_factory=tuple)
    stock: str = ""
    part: str = ""
    retracts: int = 0
    warnings: tuple = ()            # what was checked with an assumption (e.g. the gauge point)

    @property
    def ok(self) -> bool:
        return not self.violations

    def summary(self, max_listed: int = 5) -> str:
        head = (f"verify {self.name}: {self.n_blocks} blocks, {self.n_samples} tool samples at most "
                f"{_um(self.step)} apart (clearances exact to {_um(self.step / 2)})")
        lines = [head]
        if self.stock:
            mc = ("no rapid move" if not math.isfinite(self.min_clearance) else
                  f"min rapid clearance {_um(self.min_clearance)} at line {self.min_clearance_line}")
            lines.append(f"  stock {self.stock}: {mc} (required {_um(self.clearance)})")
            if self.retracts:
                lines.append(f"  {self.retracts} rapid(s) start closer than that and move straight away "
                             "(retracts from the cut; not counted in the min)")
        if self.part:
            mp = ("no feed move" if not math.isfinite(self.min_part) else
                  f"feed moves reach {_um(-self.min_part)} into it" if self.min_part < 0 else
                  f"feed moves stay {_um(self.min_part)} off it at least")
            lines.append(f"  part {self.part}: {mp} (tolerance {_um(self.tolerance)})")
        for w in self.warnings:
            lines.append("  warning: " + w)
        if self.violations:
            lines.append(f"  {len(self.violations)} block(s) FAIL:")
            for v in self.violations[:max_listed]:
                lines.append("    " + v.describe(self.clearance, self.tolerance))
            if len(self.violations) > max_listed:
                lines.append(f"    ... and {len(self.violations) - max_listed} more")
        else:
            lines.append("  passed" + self.scope())
        return "\n".join(lines)

    def scope(self) -> str:
        """What was checked, where not everything was: " (rapids only: ...)" or "" (stock
        and part both given)."""
        if self.stock and not self.part:
            return (" (rapids only: the feed moves, the cut, were not checked; give the "
                    "finished part to check them)")
        if self.part and not self.stock:
            return " (feed moves only: the rapids were not checked; give the stock to check them)"
        return ""


def verify_commands(machine, q, motion, *, stock=None, clearance: float = 0.1, part=None,
                    tolerance: float = 5e-4, tool_radius: float = 0.0, errors=None,
                    step: float = 0.005, lines=None, texts=None, arcs=None, name: str = "program",
                    raise_on_violation: bool = True, tcp=False,
                    rapid_rates=None, retracts: bool = False, tool_length=None,
                    tcp_rapids: str = "both", known=None, progress=None) -> VerifyResult:
    """Verify axis commands q (N, n_axes) mm/deg with per-block motion codes (N,) (0 rapid,
    1 feed, 2 probe, 3 feed on an arc).

    The move into block 0 starts from an unknown position: only its end point is checked.
    known (N,): False for blocks whose pose the program has not fixed (placeholders in q): moves
    into or out of them are not checked; a known block after an unknown one is checked at its
    end point (where the move into it starts is unknown).
    stock/part: objects with ``distance(points) -> signed mm`` (Box, HalfSpace, ShapeStock);
    tool_radius: ball radius, mm (0: a point tool); errors: ErrorSet of the real machine (None:
    nominal); lines/texts: source line numbers and texts for the messages.  Raises VerifyError
    naming the first failing block (all are in ``.result``) unless raise_on_violation is False.
    tcp: True, or a mask (N,) of the rows of q that are G43.4 tool-centre-point words (tool tip
    in the workpiece frame, rotary angles; see :func:`sweep`), with tool_length (N,) mm (the
    tool point checked is that tool's tip).  Feeds under G43.4 move the tip straight (linear in
    the words); how a control moves G00 under G43.4 is a parameter of it (tip straight, or each
    axis linearly), so ``tcp_rapids="both"`` (default) checks a G43.4 rapid along both paths
    and reports the worse; "tip" or "joint" checks one.  rapid_rates: {axis letter:
    rate} (mm/min, deg/min) of a control with dog-leg rapids (each axis at its own rate); None:
    rapids interpolated linearly (LRP = 1).

    retracts: accept a rapid that starts closer to the stock than `clearance` (at the end of a
    cut, against the raw stock) if it moves away from the stock until it has the clearance: the
    signed distance grows by at least half the tool's travel between neighbouring samples (within
    60 deg of the surface normal), and never falls below the clearance afterwards.  Such blocks
    are counted in ``result.retracts`` and left out of the min clearance.
    """
    if stock is None and part is None:
        raise InputError("nothing to verify against: give a stock and/or a part", field="stock")
    if not step > 0 or not clearance >= 0 or not tolerance >= 0:
        raise InputError("step must be > 0 and clearance, tolerance >= 0 mm", field="step")
    q = np.asarray(q, float)
    motion = np.asarray(motion, int)
    if len(motion) != len(q):
        raise ValueError("q and motion disagree in length")
    lines = np.arange(1, len(q) + 1) if lines is None else np.asarray(lines, int)
    violations = []
    n_samples = 0
    min_c, min_c_line, min_p = math.inf, 0, math.inf
    n_retracts = 0

    def worst_per_block(pts, owner, dist, bad_mask, kind):
        out = []
        for b in np.unique(owner[bad_mask]):
            sel = np.nonzero(owner == b)[0]
            k = sel[np.argmin(dist[sel])]
            out.append(Violation(int(b), int(lines[b]), kind, float(dist[k]),
                                 tuple(float(x) for x in pts[k]),
                                 texts[b] if texts is not None else ""))
        return out

    kn = np.ones(len(q), bool) if known is None else np.asarray(known, bool)
    idx = np.arange(1, len(q))
    both_known = kn[1:] & kn[:-1]
    idx = idx[both_known]
    # blocks checked at their end point only: the first one, and known ones after unknown ones
    ends_only = np.flatnonzero(kn & ~np.r_[False, both_known])
    tmask = np.broadcast_to(np.asarray(tcp, bool), (len(q),))
    if tcp_rapids not in ("both", "tip", "joint"):
        raise InputError(f"tcp_rapids must be both, tip or joint, got {tcp_rapids!r}", field="tcp_rapids")
    rates = None
    if rapid_rates is not None:
        if tmask.any():
            raise InputError("dog-leg rapids and G43.4 output do not go together", field="rapid_rates")
        missing = [a for a in machine.axis_names if a not in rapid_rates]
        if missing or any(not float(v) > 0 for v in rapid_rates.values()):
            raise InputError(f"rapid rates > 0 needed for every axis; missing {missing}",
                             field="rapid_rates")
        rates = np.array([float(rapid_rates[a]) for a in machine.axis_names])
    L = (np.zeros(len(q)) if tool_length is None
         else np.broadcast_to(np.asarray(tool_length, float), (len(q),)))
    if stock is not None:
        rb = idx[motion[idx] == RAPID]
        # G43.4 rapids: the tip-space path and/or the axis-space path (see tcp_rapids)
        passes = [("tip" if tcp_rapids != "joint" else "joint", rb)]
        if tcp_rapids == "both" and tmask[rb].any():
            passes.append(("joint", rb[tmask[rb]]))
        retract_ok, bad_blocks = set(), set()
        for k_pass, (space, blocks) in enumerate(passes):
            pts, owner, _ = sweep(machine, q, blocks, errors, tool_radius, step, arcs, tcp=tmask,
                                  rapid_rates=rates, tool_length=L, space=space, lines=lines)
            e = ends_only[motion[ends_only] == RAPID] if k_pass == 0 else ends_only[:0]
            if len(e):                               # end points of moves from unknown starts
                pe = np.empty((len(e), 3))
                for flag in (False, True):
                    r = tmask[e] == flag
                    if r.any():
                        pe[r] = _tool_points(machine, q[e[r]], errors, tool_radius, flag, L[e[r]])
                pts = np.vstack([pe, pts])
                owner = np.concatenate([e, owner])
                o = np.argsort(owner, kind="stable")
                pts, owner = pts[o], owner[o]
            n_samples += len(pts)
            if not len(pts):
                continue
            dist = stock.distance(pts) - tool_radius
            bad = dist - step / 2 < clearance
            counted = np.ones(len(dist), bool)
            if retracts:
                for b in np.unique(owner[bad]):
                    sel = np.nonzero(owner == b)[0]
                    if b in e or len(sel) < 2 or not _departs(pts[sel], dist[sel], clearance, step):
                        continue
                    bad[sel] = False
                    counted[sel] = False
                    retract_ok.add(int(b))
            if counted.any():
                k = int(np.flatnonzero(counted)[np.argmin(dist[counted])])
                if dist[k] < min_c:
                    min_c, min_c_line = float(dist[k]), int(lines[owner[k]])
            found = worst_per_block(pts, owner, dist, bad, "rapid")
            if space == "joint" and tmask.any():
                found = [replace(v, path="axis") for v in found]
            for v in found:                  # one violation per block: the worst of the paths
                old = next((w for w in violations if w.block == v.block and w.kind == "rapid"), None)
                if old is None or v.value < old.value:
                    if old is not None:
                        violations.remove(old)
                    violations.append(v)
                bad_blocks.add(v.block)
        n_retracts = len(retract_ok - bad_blocks)
    if part is not None:
        fb = idx[(motion[idx] == FEED) | (motion[idx] == 3)]
        pts, owner, _ = sweep(machine, q, fb, errors, tool_radius, step, arcs, tcp=tmask,
                              tool_length=L, space="tip", lines=lines)
        n_samples += len(pts)
        if len(pts):
            dist = _part_distance(part, pts, progress) - tool_radius
            min_p = float(dist.min())
            violations += worst_per_block(pts, owner, dist, dist < -tolerance, "gouge")
    violations.sort(key=lambda v: v.block)
    res = VerifyResult(name, len(q), n_samples, step, clearance, tolerance, min_c, min_c_line, min_p,
                       tuple(violations), stock.describe() if stock is not None else "",
                       part.describe() if part is not None else "", n_retracts)
    if violations and raise_on_violation:
        raise VerifyError(f"{name}: " + violations[0].describe(clearance, tolerance)
                          + (f" (and {len(violations) - 1} more blocks)" if len(violations) > 1 else ""),
                          res)
    return res


def _part_distance(part, pts, progress):
    """part.distance(pts), with progress where the part takes it (ShapeStock: about 0.3 ms per
    point near the solid, minutes for a finishing program)."""
    if progress is not None:
        try:
            return part.distance(pts, progress=progress)
        except TypeError:                  # (stocks without progress: analytic, fast)
            pass
    return part.distance(pts)


def _departs(pts: np.ndarray, dist: np.ndarray, clearance: float, step: float) -> bool:
    """True if the samples of one rapid (in order) start within the clearance and move away from
    the stock: the distance grows by >= half the travel per sample until it reaches the
    clearance, and stays at or above it (to step/2) after that."""
    if dist[0] - step / 2 >= clearance:
        return False                       # it came closer later: an ordinary violation
    travel = np.linalg.norm(np.diff(pts, axis=0), axis=1)
    rise = np.diff(dist)
    short = dist - step / 2 < clearance
    if np.any(short[:-1] & (rise < 0.5 * travel - 1e-12)):
        return False
    reached = np.nonzero(~short)[0]
    return not reached.size or not short[reached[0]:].any()


# ---------------------------------------------------------------------------------- programs
#: Words and lines the reader of mtcomp.gcode refuses but that do not move the tool differently
#: in a verification: the skip move G31 runs (at most) to its end point, G43 H / G49 (the
#: program is written for the tool point, the length is in the H register), G93/G94 (feed only),
#: and macro output lines of a probing macro (POPEN, DPRNT, PCLOS, #-assignments).
_MACRO_LINE = re.compile(r"^\s*(?:N\d+\s*)?(?:POPEN|PCLOS|DPRNT\[.*\]|#\d+\s*=.*)\s*(?:\(.*\))?\s*$",
                         re.IGNORECASE)
_DROP_WORDS = re.compile(r"\bG(?:93|94)\b(?![.\d])", re.IGNORECASE)
_G31 = re.compile(r"\bG31\b(?![.\d])", re.IGNORECASE)


def _prepare(text: str) -> tuple[str, set]:
    """Program text the motion reader accepts, same line numbering, and the lines with G31."""
    out, probe_lines = [], set()
    for k, line in enumerate(text.split("\n"), 1):
        code = re.sub(r"\([^()]*\)", lambda m: " " * len(m.group()), line)
        if _MACRO_LINE.match(code):
            out.append("")
            continue
        if _G31.search(code):
            probe_lines.add(k)
            code = _G31.sub("G01", code)
        code = _DROP_WORDS.sub("", code)
        out.append(code)
    return "\n".join(out), probe_lines


def program_arcs(machine, prog, motion):
    """Arc data for :func:`sweep` (centre (N, 2) in the plane axes, sweep (N,), plane columns
    (N, 2), is_arc (N,)) of a parsed program, in the frame the axes move in (G68 applied)."""
    from .gcode.rotation import has_rotation, to_reference
    cols = np.zeros((len(prog), 2), int)
    cidx = np.zeros((len(prog), 2), int)
    xyz = {"X": 0, "Y": 1, "Z": 2}
    for k, pl in enumerate(np.asarray(prog.plane)):
        pair = {17: "XY", 18: "ZX", 19: "YZ"}[int(pl)]
        cols[k] = [machine.axis_names.index(a) if a in machine.axis_names else 0 for a in pair]
        cidx[k] = [xyz[a] for a in pair]
    centre3 = np.array(prog.arc_centre, float)
    if has_rotation(prog):
        # the centre turns with the words (G68 is a rotation: the sweep keeps its sign)
        C = np.array(prog.position, float)
        for a, j in xyz.items():
            if a in machine.axis_names:
                C[:, machine.axis_names.index(a)] = centre3[:, j]
        C = to_reference(prog, np.nan_to_num(C))
        for a, j in xyz.items():
            if a in machine.axis_names:
                centre3[:, j] = C[:, machine.axis_names.index(a)]
    centre = np.take_along_axis(centre3, cidx, axis=1)
    return centre, np.nan_to_num(np.asarray(prog.arc_sweep, float)), cols, motion == 3


def program_commands(machine, text: str, filename: str = "<string>", tool_lengths=None,
                     work_offsets=None):
    """Per motion block: words (N, n_axes: axis positions, or for G43.4 blocks tool tip and
    angles; G68 rotation applied), motion codes (N,), source lines (N,), line texts, arc data,
    the G43.4 mask (N,), the active tool length (N,) mm (G43/G44 H and G43.4: the tip checked is
    that far along -tool_axis from the machine file's tool point) and the known mask (N,), read
    through :func:`mtcomp.gcode.parse`."""
    from . import gcode
    from .gcode.rotation import to_reference
    clean, probe_lines = _prepare(text)
    prog = gcode.parse(clean, axes=machine.axis_names, filename=filename, tcp=True, rotation=True,
                       tool_lengths=tool_lengths, work_offsets=work_offsets)
    motion = np.asarray(prog.motion, int).copy()
    motion[motion < 0] = RAPID  # axis words before any motion code: the control's power-on G00
    motion[(motion == 2) | (motion == 3)] = 3
    probe = np.isin(prog.line, sorted(probe_lines))
    motion[probe] = PROBE
    # A block after G31 without its own motion word continues in the modal G00/G01 of before.
    raw = np.asarray(prog.motion_word) >= 0
    for i in np.nonzero(~raw & ~probe)[0]:
        if i > 0 and probe[i - 1]:
            j = i - 1
            while j >= 0 and probe[j]:
                j -= 1
            motion[i] = motion[j] if j >= 0 else RAPID
            probe[i] = False
    src = text.split("\n")
    arcs = program_arcs(machine, prog, motion) if (motion == 3).any() else None
    out = [to_reference(prog, prog.position), motion, np.asarray(prog.line, int), arcs,
           np.asarray(prog.tcp, bool), np.asarray(prog.tool_tip, float), np.asarray(prog.known),
           np.asarray(prog.tool_unknown, bool)]
    if "Z" in machine.axis_names and (np.asarray(prog.cycle) > 0).any():
        out = _cycle_moves(machine, prog, *out)
    q, motion, lines, arcs, tcp, length, known, unknown = out
    texts = [src[int(ln) - 1] if 0 < int(ln) <= len(src) else "" for ln in lines]
    return q, motion, lines, texts, arcs, tcp, length, known, unknown


def _cycle_moves(machine, prog, q, motion, lines, arcs, tcp, length, known, unknown):
    """Canned cycle blocks as the moves the control makes (Fanuc G73-G89, LinuxCNC G81-G89):
    rapid to the hole at the current level, rapid down to the R level, feed to the depth, out
    to the return level (G98 initial, G99 R; the block's own end position).  The way out is
    taken as a feed move (G85/G89 feed out; the others retract through the hole the feed just
    cut: checked against the part, not the stock).  Rows of the other per-block arrays are
    repeated.  Without this a cycle block was one point and its hole was never checked."""
    zk = machine.axis_names.index("Z")
    cyc = np.asarray(prog.cycle)
    data = np.asarray(prog.cycle_data)
    n = len(q)
    reps = np.where(cyc > 0, 4, 1)
    src = np.repeat(np.arange(n), reps)
    step = np.arange(len(src)) - np.repeat(np.cumsum(reps) - reps, reps)  # 0..3 within a hole
    Q = q[src].copy()
    M = motion[src].copy()
    hole = cyc[src] > 0
    rows = np.flatnonzero(hole)
    k = src[rows]
    zprev = np.where(k > 0, q[np.maximum(k - 1, 0), zk], data[k, 0])
    zr, zd = data[k, 1], data[k, 2]
    st = step[rows]
    Q[rows, zk] = np.select([st == 0, st == 1, st == 2], [zprev, zr, zd], q[k, zk])
    M[rows] = np.select([st <= 1, st == 2], [RAPID, FEED], FEED)
    ok = np.isfinite(Q[rows, zk])
    Q[rows[~ok], zk] = q[k[~ok], zk]                # (a level not known: the block's end)
    a = None
    if arcs is not None:
        a = tuple(x[src] for x in arcs)
        a[3][hole] = False
    return (Q, M, lines[src], a, tcp[src], length[src], known[src], unknown[src])


def gauge_point_warning(lines, tool_unknown, max_listed: int = 5) -> str:
    """The warning for blocks (source lines (N,)) checked at the gauge point because the tool
    loaded by a tool change has no known length until its G43 (``tool_unknown`` (N,)); "" if none."""
    mask = np.asarray(tool_unknown, bool)
    if not mask.any():
        return ""
    edges = np.flatnonzero(np.diff(np.concatenate([[0], mask.astype(np.int8), [0]])))
    runs = [(int(lines[a]), int(lines[b - 1])) for a, b in zip(edges[::2], edges[1::2])]
    text = ", ".join(f"{a}" if a == b else f"{a}-{b}" for a, b in runs[:max_listed])
    more = f" and {len(runs) - max_listed} more runs" if len(runs) > max_listed else ""
    return (f"line(s) {text}{more} (after a tool change, before its G43) were checked at the gauge "
            "point only: the loaded tool's length is not known, its tip is lower by that length "
            "(give --tool-lengths or --tool-table with the T number)")


def verify_program(machine, text: str, *, filename: str = "<string>", tool_lengths=None,
                   work_offsets=None, **kw) -> VerifyResult:
    """Read an NC program (text) for `machine` and :func:`verify_commands` it (same keywords).
    G43.4 blocks are read as tool-centre-point words with the tool lengths of their H
    (``tool_lengths`` {H: mm}; none given: 0, the machine file's tool point); under G43/G44 H
    the axes carry the length and the tool tip checked is that length down the tool axis; G68
    rotation is applied; blocks whose pose the program has not fixed yet are not checked (see `known`).
    Between a tool change and its G43 the tip of the loaded tool is checked (its length from
    ``tool_lengths`` by its T number); without that length the gauge point is, and
    ``VerifyResult.warnings`` says which lines."""
    q, motion, lines, texts, arcs, tcp, length, known, unknown = program_commands(
        machine, text, filename, tool_lengths, work_offsets)
    kw.setdefault("name", filename)
    if kw.get("part") is not None and "progress" not in kw:
        # the part check takes minutes on a finishing program: a bar on a terminal's stderr
        from .progress import Progress
        kw["progress"] = Progress(f"verify {filename}: feed moves against the part")
    warning = gauge_point_warning(lines, unknown)
    raise_on_violation = kw.pop("raise_on_violation", True)
    try:
        res = verify_commands(machine, q, motion, lines=lines, texts=texts, arcs=arcs, tcp=tcp,
                              tool_length=length, known=known, raise_on_violation=raise_on_violation,
                              **kw)
    except VerifyError as exc:
        if warning:
            exc.result = replace(exc.result, warnings=exc.result.warnings + (warning,))
        raise
    except InputError as exc:
        if exc.file is None and exc.line is not None:       # (a block's line: name the file)
            raise InputError(exc.what, filename, exc.line, exc.field) from None
        raise
    return replace(res, warnings=res.warnings + (warning,)) if warning else res
