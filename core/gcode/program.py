"""The parsed program: original bytes (and text) and per-block arrays."""
from __future__ import annotations

import re
from dataclasses import dataclass
from functools import cached_property

import numpy as np

@dataclass(frozen=True, eq=False)
class Program:
    """A parsed NC program: the original bytes and vectorised arrays of its motion blocks.

    Per motion block (N rows, in program order): ``line`` 1-based source line, ``position``
    (N, n_axes) absolute modal end position in mm/deg (inch data converted), ``motion`` 0-3 for
    G0-G3 (-1: axis words before any motion code), ``plane`` 17/18/19, ``incremental`` (G91),
    ``inch`` (block in G20, converted), ``feed`` modal F in mm/min or mm/rev (NaN before the first
    F), ``present`` (N, n_axes) which axis words the block writes, ``ijk`` (N, 3) arc centre
    offsets I J K in mm (0 where not written), ``ijk_present`` (N, 3), ``radius`` (N,) R word in
    mm (NaN if none), ``start`` (n_axes,) the position before the first block.
    ``axis_known`` (N, n_axes) / ``start_known`` (n_axes,): whether the program (or the user's
    start) has fixed that axis by then; where not, ``position``/``start`` hold 0, a placeholder
    for simulations that nothing is compensated from.  ``known`` (N,): every axis known.
    ``idle_axes``: axes the program never writes, taken at 0.
    Arc blocks also have ``arc_centre`` (N, 3) and ``arc_sweep`` (N,) in rad (signed, positive
    counter-clockwise seen from the plane normal; NaN for linear blocks).
    """
    filename: str
    axes: tuple
    data: bytes                      # the program's bytes (`text` is their UTF-8 reading)
    line_start: np.ndarray
    line_end: np.ndarray
    # words (W): address letter (0..25), value, line index (0-based), letter and number span
    w_letter: np.ndarray
    w_value: np.ndarray
    w_line: np.ndarray
    w_pos: np.ndarray
    w_num: np.ndarray                # start of each word's number (after blanks)
    w_end: np.ndarray
    # motion blocks
    line: np.ndarray
    position: np.ndarray
    start: np.ndarray
    motion: np.ndarray
    plane: np.ndarray
    incremental: np.ndarray
    inch: np.ndarray
    feed: np.ndarray
    present: np.ndarray
    ijk: np.ndarray
    ijk_present: np.ndarray
    radius: np.ndarray
    arc_centre: np.ndarray
    arc_sweep: np.ndarray
    # word indices per block and column (axes then I J K R), -1 if absent
    col_word: np.ndarray
    motion_word: np.ndarray          # (N,) index of the block's own G0-G3 word, -1 if modal
    inch_g20_words: np.ndarray       # G20 words (replaced by G21 when converting)
    inch_f_words: np.ndarray         # F words written in inch mode (converted)
    axis_known: np.ndarray           # (N, n_axes)
    start_known: np.ndarray          # (n_axes,)
    known: np.ndarray                # (N,) all axes known at the block's end
    offset: np.ndarray               # (N, n_axes) program coordinates -> reference frame
    ijk_absolute: np.ndarray         # (N,) G90.1: I J K are the arc centre
    inverse_time: np.ndarray         # (N,) G93: F is an inverse time
    cycle: np.ndarray                # (N,) canned cycle code (73..89), 0 for other blocks
    cycle_data: np.ndarray           # (N, 7) cycles: initial level, R level, depth (mm,
                                     # reference frame), R and Z word values, G98/G99, first
                                     # block of the run
    cycle_repeat: np.ndarray = None  # (N,) canned cycle repeat count (Fanuc K, LinuxCNC/Haas L;
                                     # 1 without): the hole drilled that many times, in G91
                                     # stepping by the block's X Y words (position: the last)
    idle_axes: tuple = ()
    arc_tol: float = 0.02            # mm: accepted radius difference (start/end) of arcs
    notes: tuple = ()                # what was read with an assumption or passed uncompensated
    tcp: np.ndarray = None           # (N,) G43.4 tool centre point block: X Y Z are the tool tip
    tool_length: np.ndarray = None   # (N,) mm, tool length (H) of G43.4 blocks, 0 elsewhere
    offset_assumed: tuple = ()       # axes whose work offset differences were taken as 0
    frame: np.ndarray = None         # (n_axes,) the reference work offset's own value: where
                                     # the program origin is in machine coordinates (mm, deg;
                                     # NaN not given; zeros where no work offset is named)
    frame_line: int = 0              # line of the first work offset code (0: none)
    rotation: np.ndarray = None      # (N, 5) G68: angle deg (0: none), centre in program
                                     # coordinates, G68 line, block giving the centre (-1: words);
                                     # position is then in the unrotated word frame
    tool_tip: np.ndarray = None      # (N,) mm, the active tool's length: the tool tip is this far
                                     # along -tool_axis from the machine file's tool point
                                     # (G43 H: L, G44: -L, G43.4: L, 0 without; lengths not
                                     # given count 0; after a tool change before its G43:
                                     # the loaded tool's length, see tool_unknown)
    tool_unknown: np.ndarray = None  # (N,) blocks after a tool change, before its G43, whose
                                     # tool has no known length: tool_tip 0 (the gauge point);
                                     # only where a G43/G44/G43.4 follows the change

    cutter: np.ndarray = None        # (N,) 41/42: the block is under cutter radius compensation
                                     # G41/G42 (its end point offset by the control), 0: not
    cutter_d: np.ndarray = None      # (N,) the modal D number (NaN: none written yet)
    cutter_radius: np.ndarray = None  # (N,) mm, radius the program gives (G41.1/G42.1 D<diameter>
                                      # of LinuxCNC: D/2), NaN where the control's table gives it
    polar: np.ndarray = None         # (N,) G16 polar blocks writing X or Y: X is a radius, Y an
                                     # angle (deg) from the work origin (gcode.polar)
    polar_xy: np.ndarray = None      # (N, 2) their point in the program frame and units (NaN
                                     # where a word is not known yet; elsewhere NaN)

    @cached_property
    def text(self) -> str:
        """The program's text: its bytes read as UTF-8, undecodable bytes kept (surrogate
        escapes), decoded when first asked for (a program parsed from a str has that str)."""
        return self.data.decode("utf-8", "surrogateescape")

    @property
    def n_axes(self) -> int:
        return len(self.axes)

    @property
    def n_lines(self) -> int:
        return len(self.line_start)

    def __len__(self) -> int:
        return len(self.line)

    @property
    def lines(self) -> list[str]:
        """The original lines (split at LF only, as the line numbers count), with endings."""
        return re.findall(r"[^\n]*\n|[^\n]+\Z", self.text)

    @property
    def is_arc(self) -> np.ndarray:
        return (self.motion == 2) | (self.motion == 3)

    def summary(self) -> str:
        n_arc = int(self.is_arc.sum())
        return (f"{self.filename}: {self.n_lines} lines, {len(self)} motion blocks "
                f"({n_arc} arcs, {int(self.incremental.sum())} in G91), axes {' '.join(self.axes)}")



def resolution_formats(resolution, axes) -> dict:
    """Per axis letter (decimals, multiple): the axis resolution is ``multiple * 10**-decimals``
    (1e-6 -> (6, 1), 5e-6 -> (6, 5), 0.0005 -> (4, 5)).  ``resolution``: mapping letter ->
    resolution (mm or deg) or a number of decimals (int); default 1e-6 mm for linear axes,
    1e-5 deg for rotary ones."""
    out = {a: ((6 if a in "XYZUVW" else 5), 1) for a in axes}
    if resolution is None:
        return out
    for a, r in dict(resolution).items():
        a = a.upper()
        if a not in out:
            raise ValueError(f"resolution names axis {a!r}, not one of {axes}")
        if isinstance(r, (int, np.integer)) and not isinstance(r, bool):
            d, m = int(r), 1
        else:
            r = float(r)
            if not (r > 0 and np.isfinite(r)):
                raise ValueError(f"resolution of {a} must be a positive number, got {r}")
            for d in range(0, 10):
                m = round(r * 10 ** d)
                if m >= 1 and abs(m * 10.0 ** -d - r) <= 1e-9 * r:
                    break
            else:
                raise ValueError(f"resolution of {a} ({r:g}) is not a whole number of units of the "
                                 "9th decimal")
        if not 0 <= d <= 9:
            raise ValueError(f"resolution of {a}: 0 to 9 decimals supported, got {d}")
        out[a] = (d, int(m))
    return out
