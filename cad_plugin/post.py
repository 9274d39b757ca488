"""Fanuc-style post-processor for 3- to 6-axis machines.

Turns a :class:`~mtcomp.cad_plugin.toolpath.Toolpath` into NC text.  Two output styles:

* machine axes (default): every block carries the axis commands of the machine (linear axes in
  mm, rotary axes in deg) as computed by the kinematics, optionally compensated for an error
  set, so the control runs them as they are;
* tool centre point (``tcp=True``, Fanuc G43.4 style): X Y Z are the tool point in the workpiece
  frame and the rotary words are the rotary axis angles; the control converts them with its
  own (nominal) kinematics.  Compensated TCP output writes the tool point that the control's
  nominal kinematics turns into the compensated axis commands.

Numbers are rounded to the axis resolution and written with that many decimals.  The header
names the program, machine, tool, units and whether (and with which errors) the program is
compensated.  The format is described in docs/cad.md.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._io import InputError
from .toolpath import FEED, PROBE, RAPID, Toolpath


@dataclass(frozen=True)
class PostOptions:
    """program_number: O word (1-9999).  tcp: G43.4 tool-centre-point output instead of machine
    axes.  line_numbers / line_step: N words.  decimals: per-axis override {letter: n}; default
    from the axis resolution.  spindle: rpm for rotating tools (None: no spindle, e.g. a
    non-rotational tool or a probe).  work_offset: G54..G59.  comment: free text in the header."""
    program_number: int = 1000
    tcp: bool = False
    line_numbers: bool = True
    line_step: int = 10
    decimals: dict | None = None
    spindle: float | None = None
    work_offset: str = "G54"
    comment: str = ""

    def __post_init__(self):
        if not 1 <= int(self.program_number) <= 9999:
            raise InputError(f"program number must be 1..9999, got {self.program_number}",
                             field="program_number")
        if self.work_offset not in ("G54", "G55", "G56", "G57", "G58", "G59"):
            raise InputError(f"work offset must be G54..G59, got {self.work_offset}",
                             field="work_offset")


def _clean(text: str) -> str:
    """Comment text Fanuc accepts: no parentheses, upper case."""
    return text.replace("(", "[").replace(")", "]").upper()


def _fmt(value: float, decimals: int) -> str:
    s = f"{value:.{decimals}f}"
    if decimals == 0:
        s += "."
    return "0." + "0" * decimals if s.lstrip("-").strip("0.") == "" else s


def axis_words(machine, q: np.ndarray, tcp: bool) -> tuple[list[str], np.ndarray]:
    """Letters and values (N, n) written per block: the axis commands, or in TCP mode the tool
    point in the workpiece frame under the nominal kinematics plus the rotary angles."""
    letters = list(machine.axis_names)
    values = np.array(q, float)
    if tcp:
        from ..kinematics import forward
        p = forward(machine, q).p  # nominal: what the control's own kinematics will do
        lin = [i for i, a in enumerate(machine.axes) if not a.is_rotary]
        names = [machine.axes[i].name for i in lin]
        if sorted(names) != ["X", "Y", "Z"]:
            raise InputError("TCP output needs linear axes X, Y and Z", field="tcp")
        for i in lin:
            values[:, i] = p[:, "XYZ".index(machine.axes[i].name)]
    return letters, values


def post(machine, path: Toolpath, q: np.ndarray | None = None, options: PostOptions = PostOptions(),
         errors=None, errors_name: str = "") -> str:
    """NC program text for `path` on `machine`.

    q: axis commands (N, n_axes) if already computed; otherwise from
    :func:`mtcomp.cad_plugin.toolpath.to_axes` with `errors` (None: uncompensated).
    """
    from ..kinematics import check_limits, round_to_resolution
    from .toolpath import to_axes
    if q is None:
        q = to_axes(machine, path, errors)
    q = round_to_resolution(machine, np.asarray(q, float))
    check_limits(machine, q)
    letters, values = axis_words(machine, q, options.tcp)
    dec = {a.name: a.decimals for a in machine.axes}
    dec.update({k.upper(): int(v) for k, v in (options.decimals or {}).items()})
    unknown = set(dec) - set(letters)
    if unknown:
        raise InputError(f"decimals given for axes {sorted(unknown)} the machine does not have",
                         field="decimals")

    lines: list[str] = []
    n = [0]

    def block(text: str) -> None:
        if options.line_numbers:
            n[0] += options.line_step
            lines.append(f"N{n[0]} {text}")
        else:
            lines.append(text)

    tool = path.tool
    comp = (f"COMPENSATED FOR {errors_name or 'GIVEN ERRORS'}" if errors is not None
            else "NOT COMPENSATED")
    lines += ["%", f"O{int(options.program_number):04d} ({_clean(path.name or 'MTCOMP')})",
              f"(MACHINE {_clean(machine.name)} AXES {' '.join(machine.axis_names)})",
              f"(TOOL T{tool.number} {_clean(tool.description)})",
              "(UNITS MM DEG MM/MIN)",
              "(OUTPUT " + ("TOOL CENTRE POINT G43.4" if options.tcp else "MACHINE AXES")
              + ", " + _clean(comp) + ")",
              f"({len(path)} POSES FROM MTCOMP CAD_PLUGIN)"]
    if options.comment:
        lines.append(f"({_clean(options.comment)})")
    block(f"G21 G90 G94 G17 G40 G49 G80 {options.work_offset}")
    block(f"T{tool.number} M06")
    if options.spindle:
        block(f"S{int(round(options.spindle))} M03")
    if options.tcp:
        block(f"G43.4 H{tool.number}")

    strs = [[_fmt(v, dec[a]) for v in values[:, k]] for k, a in enumerate(letters)]
    last = [None] * len(letters)
    last_g = None
    last_f = None
    for i in range(len(path)):
        m = int(path.motion[i])
        axes = [(k, a + strs[k][i]) for k, a in enumerate(letters)
                if strs[k][i] != last[k] or (m == PROBE and k == 0)]
        if not axes:
            continue  # no motion: nothing to write, modal state unchanged
        g = {RAPID: "G00", FEED: "G01", PROBE: "G31"}[m]
        words = [g] if (m == PROBE or g != last_g) else []
        last_g = None if m == PROBE else g  # G31 is one-shot: the next block restates G01/G00
        for k, w in axes:
            words.append(w)
            last[k] = strs[k][i]
        if m != RAPID and path.feed != last_f:
            words.append(f"F{path.feed:g}")
            last_f = path.feed
        block(" ".join(words))
    if options.tcp:
        block("G49")
    if options.spindle:
        block("M05")
    block("M30")
    lines.append("%")
    return "\n".join(lines) + "\n"
