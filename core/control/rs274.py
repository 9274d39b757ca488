"""LinuxCNC's stand-alone interpreter `rs274` as an independent reader of LinuxCNC-dialect programs.

`rs274 -g prog.ngc` prints the canonical machining calls of a program; `canonical_moves` keeps
the end point of every STRAIGHT_TRAVERSE, STRAIGHT_FEED and ARC_FEED (X Y Z A B C in mm and deg,
printed to 4 decimals).  `compare` lines them up with mtcomp's reading of the same program
(`mtcomp.gcode`: subprogram calls expanded, canned cycles as their rapid / feed / retract
points): every end point mtcomp reads must come in rs274's sequence in the same order, and every
point rs274 adds (the pecks of G83, the intermediate levels of a cycle) must lie on the straight
path between the two matched points around it.  Positions agree when they differ by at most
half of rs274's last printed digit (0.00005 mm) plus the program's own resolution.
"""
from __future__ import annotations

import os
import re
import shutil
import subprocess
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

__all__ = ["available", "canonical_moves", "mtcomp_moves", "compare", "Comparison"]

_CALL = re.compile(r"^\s*\d+\s+N\S*\s+(STRAIGHT_TRAVERSE|STRAIGHT_FEED|ARC_FEED|SELECT_PLANE|"
                   r"USE_TOOL_LENGTH_OFFSET|USE_LENGTH_UNITS)\((.*)\)\s*$")
TOL = 0.5e-4 + 1e-9          # mm (deg): half of rs274's last printed digit


def available() -> bool:
    return shutil.which("rs274") is not None


def _plane_order(plane: str) -> tuple[int, int, int]:
    """ARC_FEED's (first_end, second_end, axis_end) columns among X Y Z in a plane."""
    return {"CANON_PLANE_XY": (0, 1, 2), "CANON_PLANE_XZ": (2, 0, 1), "CANON_PLANE_YZ": (1, 2, 0)}.get(plane, (0, 1, 2))


def canonical_moves(path: str | os.PathLike, subroutine_path: str | os.PathLike | None = None,
                    timeout: float = 30.0) -> np.ndarray:
    """(M, 6) end points, see `canonical_moves_and_tolerance`."""
    return canonical_moves_and_tolerance(path, subroutine_path, timeout)[0]


def canonical_moves_and_tolerance(path: str | os.PathLike, subroutine_path: str | os.PathLike | None = None,
                                  timeout: float = 30.0) -> tuple[np.ndarray, np.ndarray]:
    """(M, 6) end points X Y Z A B C of rs274's motion calls for a program file, of the gauge
    point: the canonical (tool tip) position plus the tool length offset in force, in mm (rs274
    prints inch programs in inch).  Runs rs274 in a
    temporary folder with a tool table of tools 1..99 (length 0) and, when given, the folder of
    subroutine files; raises RuntimeError with rs274's message when it stops on an error.
    Also returns (M,) the half printed digit of each point in mm: TOL, or 25.4 TOL in inch."""
    path = Path(path).resolve()
    with tempfile.TemporaryDirectory(prefix="mtcomp-rs274-") as tmp:
        tbl = Path(tmp) / "tool.tbl"
        tbl.write_text("".join(f"T{t} P{t} Z0 D0 ;\n" for t in range(1, 100)))
        ini = Path(tmp) / "rs274.ini"
        sub = Path(subroutine_path).resolve() if subroutine_path else path.parent
        ini.write_text(f"[RS274NGC]\nSUBROUTINE_PATH = {sub}\n")
        out = subprocess.run(["rs274", "-i", str(ini), "-t", str(tbl), "-g", str(path)], cwd=tmp,
                             capture_output=True, text=True, timeout=timeout, stdin=subprocess.DEVNULL)
    text = out.stdout + out.stderr
    moves, tols, plane, tlo, unit = [], [], "CANON_PLANE_XY", np.zeros(6), 1.0
    for line in text.splitlines():
        m = _CALL.match(line)
        if not m:
            continue
        kind, args = m.group(1), m.group(2)
        if kind == "SELECT_PLANE":
            plane = args.strip()
            continue
        if kind == "USE_LENGTH_UNITS":           # rs274 prints in the program's units: mm here
            unit = 25.4 if "INCH" in args else 1.0
            continue
        if kind == "USE_TOOL_LENGTH_OFFSET":     # "x y z, a b c, u v w"
            t = [float(x) for x in args.replace(",", " ").split()]
            tlo = np.array(t[:6]) * [unit, unit, unit, 1, 1, 1]
            continue
        v = [float(x) for x in args.split(",")]
        if kind == "ARC_FEED":
            e1, e2, _, _, _, e3 = v[:6]
            i1, i2, i3 = _plane_order(plane)
            xyz = [0.0] * 3
            xyz[i1], xyz[i2], xyz[i3] = e1, e2, e3
            moves.append(np.array(xyz + v[6:9]) * [unit, unit, unit, 1, 1, 1] + tlo)
        else:
            moves.append(np.array(v[:6]) * [unit, unit, unit, 1, 1, 1] + tlo)
        tols.append(TOL * unit)
    # rs274's own messages are the lines that are not numbered canonical calls (a COMMENT may
    # say "error" too)
    msgs = [ln.strip() for ln in text.splitlines() if ln.strip() and not re.match(r"^\s*\d+\s+N", ln)]
    bad = [m for m in msgs if re.search(r"[Ee]rror|Requested tool|Unable to open|not found", m)]
    if bad:
        raise RuntimeError(f"rs274 stopped on {path.name}: {bad[0]}")
    return np.asarray(moves, float).reshape(-1, 6), np.asarray(tols, float)


def _cycle_points(prog, row: int, before: np.ndarray) -> list[np.ndarray]:
    """Rapid to the hole at the current level, rapid to R, feed to the bottom, retract (G98:
    initial level, G99: R), for every repeat of a canned cycle row."""
    data = np.asarray(prog.cycle_data[row], float)
    initial, r_level, depth, g98 = data[0], data[1], data[2], data[5]
    pos = np.asarray(prog.position[row], float)
    reps = int(prog.cycle_repeat[row]) if prog.cycle_repeat is not None else 1
    zc = prog.axes.index("Z")
    out = []
    cur = before.copy()
    for k in range(reps):
        hole = pos.copy()
        if reps > 1 and np.asarray(prog.incremental[row]):
            step = (pos - before)
            step[zc] = 0.0
            hole = before + step * (k + 1) / reps
        hole_top = hole.copy()
        hole_top[zc] = cur[zc]
        out.append(hole_top)
        for z in (r_level, depth, initial if g98 == 98 else r_level):
            p = hole.copy()
            p[zc] = z
            out.append(p)
        cur = out[-1]
    return out


def mtcomp_moves(path: str | os.PathLike, axes=("X", "Y", "Z", "A", "B", "C"),
                 subroutine_path: str | os.PathLike | None = None) -> np.ndarray:
    """(N, 6) end points, see `mtcomp_moves_and_start`."""
    return mtcomp_moves_and_start(path, axes, subroutine_path)[0]


def mtcomp_moves_and_start(path: str | os.PathLike, axes=("X", "Y", "Z", "A", "B", "C"),
                           subroutine_path: str | os.PathLike | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(N, 6) end points over X Y Z A B C of mtcomp's reading of a program file: `position` (the
    gauge point: tool lengths applied; program frame, so the programs compared set no work
    offsets), canned cycles expanded into their points; and (6,) the start position (0 where
    the program has not fixed an axis, as rs274 starts)."""
    from ..gcode import flow, parse, read_program
    path = Path(path)
    text = read_program(path)
    search = [Path(subroutine_path)] if subroutine_path else [path.parent]
    fl = flow.expand(text, str(path), search=search)
    if fl is not None:
        text = fl.expanded
    prog = parse(text, axes=axes, filename=str(path))
    ref = np.asarray(prog.position, float)
    out, cur = [], np.asarray(prog.start, float)
    for i in range(len(prog.line)):
        if prog.cycle[i]:
            pts = _cycle_points(prog, i, cur)
            out += pts
            cur = pts[-1]
        else:
            out.append(ref[i])
            cur = ref[i]
    cols = [axes.index(a) if a in axes else None for a in "XYZABC"]
    arr = np.asarray(out, float).reshape(-1, len(axes))
    start = np.array([float(prog.start[c]) if c is not None else 0.0 for c in cols])
    return np.column_stack([arr[:, c] if c is not None else np.zeros(len(arr)) for c in cols]), start


def _dedupe_mask(p: np.ndarray) -> np.ndarray:
    keep = np.ones(len(p), bool)
    if len(p):
        keep[1:] = np.any(np.abs(np.diff(p, axis=0)) > TOL, axis=1)
    return keep


def _dedupe(p: np.ndarray) -> np.ndarray:
    return p[_dedupe_mask(p)]


def _on_segment(x, a, b, tol: float = TOL) -> bool:
    d = b - a
    n = float(d @ d)
    t = 0.0 if n == 0 else float(np.clip((x - a) @ d / n, 0.0, 1.0))
    return bool(np.max(np.abs(a + t * d - x)) <= tol)


@dataclass(frozen=True)
class Comparison:
    """mtcomp's points (n_mtcomp), rs274's (n_rs274), how many of mtcomp's were found in order
    (matched), rs274's points off the path between matches (extra_off_path), the largest
    difference of a matched point (max_diff, mm/deg) and the first disagreement (text)."""
    n_mtcomp: int
    n_rs274: int
    matched: int
    extra_off_path: int
    max_diff: float
    first: str = ""

    @property
    def differing(self) -> int:
        return (self.n_mtcomp - self.matched) + self.extra_off_path


def compare(path: str | os.PathLike, axes=("X", "Y", "Z", "A", "B", "C"),
            subroutine_path: str | os.PathLike | None = None, tol: float = 0.0) -> Comparison:
    """Line mtcomp's reading of a program up with rs274's (module docstring).  `tol` adds the
    program's resolution to the print tolerance (half of rs274's last digit, in inch for inch
    programs)."""
    ours, start = mtcomp_moves_and_start(path, axes, subroutine_path)
    ours = _dedupe(ours)
    theirs, tols = canonical_moves_and_tolerance(path, subroutine_path)
    keep = _dedupe_mask(theirs)
    theirs, tols = theirs[keep], tols[keep]
    j, matched, extra, worst, first = 0, 0, 0, 0.0, ""
    last = start          # a block without axis words is a move to where the axes are (rs274)
    for i, p in enumerate(ours):
        k = j
        while k < len(theirs) and np.max(np.abs(theirs[k] - p)) > tols[k] + tol:
            k += 1
        if k == len(theirs):
            first = first or f"mtcomp point {i} {np.round(p, 4).tolist()} not in rs274's sequence after its point {j}"
            continue
        for x, t in zip(theirs[j:k], tols[j:k]):
            if not _on_segment(x, last, p, t + tol):
                extra += 1
                first = first or f"rs274 point {np.round(x, 4).tolist()} off the path before mtcomp point {i}"
        worst = max(worst, float(np.max(np.abs(theirs[k] - p))))
        matched += 1
        last = theirs[k]
        j = k + 1
    for x in theirs[j:]:
        extra += 1
        first = first or f"rs274 point {np.round(x, 4).tolist()} after mtcomp's last"
    return Comparison(len(ours), len(theirs), matched, extra, worst, first)
