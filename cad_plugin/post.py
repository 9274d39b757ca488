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

import math
import re
from dataclasses import dataclass

import numpy as np

from .._io import InputError
from .toolpath import FEED, PROBE, RAPID, Toolpath


@dataclass(frozen=True)
class PostOptions:
    """Options of :func:`post` (docs/cad.md, "Post-processor").

    program_number: O word, 1-7999 (O8000-O8999 are the edit-protected and O9000-O9999 the
    macro range of a Fanuc control: a program posted there could overwrite a probing or tool
    change macro).  tcp: G43.4 tool-centre-point output instead of machine axes.
    line_numbers / line_start / line_step / line_max: N words (none if line_numbers is False),
    the first number, the increment, and the largest N the control takes (99999: the five
    digits of most controls).  N numbers never repeat: when the blocks do not fit with
    line_step, the step shrinks (down to 1); when they do not fit with step 1, the program has
    no N words (a header comment says so).  decimals: per-axis
    override {letter: n}; default from the axis resolution.  spindle: rpm for rotating tools
    (None: no spindle, e.g. a non-rotational tool or a probe).  coolant: M code switched on
    after the spindle and off (M09) at the end, e.g. "M08"; None: none.  work_offset: G54..G59.
    comment: free text in the header.  tool_length: write ``G43 H<tool>`` with the first move in
    machine-axes mode (the Z words are the tool edge; the control adds the length in H).
    rotary_feed: feed of feed moves that turn a rotary axis without TCP, where a Fanuc control
    spreads F over all axes with degrees counted as mm: "tool-tip" (default) writes per block
    the G94 F that gives the programmed feed at the tool tip, "inverse-time" writes G93 blocks
    with F = 1 / duration in 1/min, "axes" leaves F as programmed (tool tip slower or faster).
    plunge_feed: mm/min for moves into the material along the tool axis (None: the feed).
    preamble / tool_change / postamble: block templates, one block per line, with the fields
    {program} {tool} {work_offset} {spindle}; the postamble comes before M30.
    probe_log: probing programs record every skip position with a Fanuc macro (POPEN, DPRNT
    of the skip variables, PCLOS) in the format :func:`read_skip_log` reads.  skip_vars:
    {axis letter: macro variable number} of the skip positions; default X Y Z 5061-5063, the
    other axes 5064... in A B C order.
    retract: "G28" (default) writes G91 G28 Z0. before every tool change and before M30 (then
    G28 X0. Y0. and G90), "G53" writes G53 G00 Z0. (machine Z zero) instead, "none" nothing.
    protected_macro: probing programs position the probe near the part with this protected
    positioning macro (G65 P9810 X Y Z F: Renishaw Inspection Plus and compatible; the macro
    stops with an alarm if the stylus touches on the way); 0 writes plain G01 moves.  Every G31
    carries its own F, and the block after it raises macro alarm `missed_alarm` (#3000) when
    the skip position is the G31 end point, i.e. the stylus never touched.
    """
    program_number: int = 1000
    tcp: bool = False
    line_numbers: bool = True
    line_step: int = 10
    line_start: int | None = None
    line_max: int = 99999
    decimals: dict | None = None
    spindle: float | None = None
    coolant: str | None = None
    work_offset: str = "G54"
    comment: str = ""
    tool_length: bool = False
    rotary_feed: str = "tool-tip"
    plunge_feed: float | None = None
    preamble: str = "G21\nG17 G40 G49 G80 G90 G94\nG69 G15 G50.1\n{work_offset}"
    tool_change: str = "T{tool} M06"
    postamble: str = ""
    probe_log: bool = False
    skip_vars: dict | None = None
    retract: str = "G28"
    protected_macro: int = 9810
    missed_alarm: int = 91

    def __post_init__(self):
        if not 1 <= int(self.program_number) <= MAX_PROGRAM_NUMBER:
            raise InputError(f"program number must be 1..{MAX_PROGRAM_NUMBER} (O8000-O9999 are the "
                             f"control's protected and macro programs), got {self.program_number}",
                             field="program_number")
        if self.retract not in ("G28", "G53", "none"):
            raise InputError(f"retract must be G28, G53 or none, got {self.retract!r}", field="retract")
        if not (self.protected_macro == 0 or 9000 <= int(self.protected_macro) <= 9999):
            raise InputError(f"protected_macro must be a macro program 9000..9999 or 0, got "
                             f"{self.protected_macro}", field="protected_macro")
        if not 1 <= int(self.missed_alarm) <= 200:
            raise InputError(f"missed_alarm must be a macro alarm number 1..200, got {self.missed_alarm}",
                             field="missed_alarm")
        if self.work_offset not in ("G54", "G55", "G56", "G57", "G58", "G59"):
            raise InputError(f"work offset must be G54..G59, got {self.work_offset}",
                             field="work_offset")
        if self.rotary_feed not in ("tool-tip", "inverse-time", "axes"):
            raise InputError(f"rotary_feed must be tool-tip, inverse-time or axes, got "
                             f"{self.rotary_feed!r}", field="rotary_feed")
        start = self.line_step if self.line_start is None else self.line_start
        if self.line_step < 1 or start < 1 or self.line_max <= start:
            raise InputError("line numbers need step >= 1, start >= 1 and line_max > start",
                             field="line_numbers")
        if self.plunge_feed is not None and not self.plunge_feed > 0:
            raise InputError("plunge feed must be > 0 mm/min", field="plunge_feed")
        if self.coolant is not None and self.coolant.upper() not in ("M07", "M08"):
            raise InputError(f"coolant must be M07 or M08, got {self.coolant!r}", field="coolant")

    @property
    def first_line(self) -> int:
        return self.line_step if self.line_start is None else self.line_start


MAX_PROGRAM_NUMBER = 7999   # O8000-O8999: edit-protected, O9000-O9999: macros (Fanuc)
MISSED_TOL = 0.001          # mm: a skip position this close to the G31 end point is no touch


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


def _template(text: str, fields: dict, what: str) -> list[str]:
    try:
        out = text.format(**fields)
    except (KeyError, IndexError, ValueError) as exc:
        raise InputError(f"template {text!r}: {exc}; fields: {', '.join('{' + k + '}' for k in fields)}",
                         field=what) from None
    return [ln.strip() for ln in out.splitlines() if ln.strip()]


def default_skip_vars(machine) -> dict:
    """Macro variables of the skip position per axis letter: X Y Z #5061-#5063 (Fanuc), then the
    other axes in A B C U V W order from #5064."""
    order = [a for a in "XYZABCUVW" if a in machine.axis_names]
    return {a: 5061 + k for k, a in enumerate(order)}


def _block_feeds(machine, path: Toolpath, q: np.ndarray, options: PostOptions):
    """Per point: ("G94"|"G93", F) of the move into it (None for rapids, probing, point 0)."""
    from ..kinematics import forward
    n = len(path)
    rot = list(machine.rotary_indices)
    lin = [i for i in range(machine.n_axes) if i not in rot]
    p = forward(machine, q).p
    dp = np.diff(p, axis=0)
    tip = np.linalg.norm(dp, axis=1)
    feed = np.full(n - 1, float(path.feed))
    if options.plunge_feed is not None:
        down = np.einsum("ij,ij->i", dp, -path.axis[1:])
        feed[(tip > 0) & (down > math.cos(math.radians(10.0)) * tip)] = options.plunge_feed
    dq = np.diff(q, axis=0)
    turns = np.any(dq[:, rot] != 0, axis=1) if rot else np.zeros(n - 1, bool)
    plain = ~turns | options.tcp | (options.rotary_feed == "axes") | (tip == 0)
    length = np.sqrt(np.sum(dq[:, lin] ** 2, axis=1) + np.sum(dq[:, rot] ** 2, axis=1))
    safe_tip = np.where(tip > 0, tip, 1.0)
    out = [None] * n
    for i in np.nonzero(path.motion[1:] == FEED)[0]:
        if plain[i]:
            out[i + 1] = ("G94", float(feed[i]))
        elif options.rotary_feed == "inverse-time":
            out[i + 1] = ("G93", float(feed[i] / safe_tip[i]))        # 1 / block duration, 1/min
        else:
            # Fanuc G94 with rotary axes: F is the feed along the vector of all axis moves, deg
            # counted as mm; this F gives the block the duration tip / feed.
            out[i + 1] = ("G94", float(feed[i] * length[i] / safe_tip[i]))
    return out


def _fmt_feed(f: float) -> str:
    """F word: up to 4 significant decimals, never in exponent form."""
    s = f"{f:.4f}".rstrip("0")
    return s + "0" if s.endswith(".") else s


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
    probing = bool(np.any(path.motion == PROBE))
    skip_vars = dict(options.skip_vars or default_skip_vars(machine))
    if options.probe_log and probing:
        missing = [a for a in letters if a not in skip_vars]
        if missing:
            raise InputError(f"no skip variable for axes {missing}", field="skip_vars")

    body: list[str] = []          # the blocks, numbered once all are known (_number)
    block = body.append

    tool = path.tool
    fields = {"program": int(options.program_number), "tool": tool.number,
              "work_offset": options.work_offset,
              "spindle": int(round(options.spindle)) if options.spindle else 0}
    comp = (f"COMPENSATED FOR {errors_name or 'GIVEN ERRORS'}" if errors is not None
            else "NOT COMPENSATED")
    head = ["%", f"O{int(options.program_number):04d} ({_clean(path.name or 'MTCOMP')})",
            f"(MACHINE {_clean(machine.name)} AXES {' '.join(machine.axis_names)})",
            f"(TOOL T{tool.number} {_clean(tool.description)})",
            "(UNITS MM DEG MM/MIN)",
            "(OUTPUT " + ("TOOL CENTRE POINT G43.4" if options.tcp else "MACHINE AXES")
            + ", " + _clean(comp) + ")",
            f"({len(path)} POSES FROM MTCOMP CAD_PLUGIN)"]
    if errors is not None:
        # the provenance marker: `mtcomp compensate` and every other writer refuse this
        # program unless --force (its axes already carry the errors' correction)
        from ..gcode.provenance import header_lines
        head += [f"({ln})" for ln in header_lines([("ERRORS", _clean(errors_name or "given"))])]
    if options.comment:
        head.append(f"({_clean(options.comment)})")
    if options.probe_log and probing:
        head.append("(SKIP POSITIONS: " + " ".join(f"{a}#{skip_vars[a]}" for a in letters)
                    + "; DPRNT LINES T<BOWL> I J K <AXES> D<DISTANCE TO G31 END>)")
    if probing:
        head.append(f"(PROBING: MACRO ALARM {options.missed_alarm} IF A G31 ENDS WITHOUT TOUCH"
                    + (f"; G65 P{options.protected_macro} PROTECTED MOVES" if options.protected_macro else "")
                    + ")")
    for b in _template(options.preamble, fields, "preamble"):
        block(b)
    for b in _retract(machine, options, end=False):
        block(b)
    for b in _template(options.tool_change, fields, "tool_change"):
        block(b)
    if options.spindle:
        block(f"S{int(round(options.spindle))} M03")
    if options.coolant:
        block(options.coolant.upper())
    if options.probe_log and probing:
        block("POPEN")

    feeds = _block_feeds(machine, path, q, options)
    strs = [[_fmt(v, dec[a]) for v in values[:, k]] for k, a in enumerate(letters)]
    last = [None] * len(letters)
    last_g = None
    last_f = None
    feed_mode = "G94"
    length_on = not (options.tool_length or options.tcp)
    length_word = f"G43.4 H{tool.number}" if options.tcp else f"G43 H{tool.number}"
    rotary = {machine.axes[k].name for k in machine.rotary_indices}
    protected = probing and options.protected_macro
    centres = path.meta.get("centres")
    for i in range(len(path)):
        m = int(path.motion[i])
        axes = [(k, a + strs[k][i]) for k, a in enumerate(letters) if strs[k][i] != last[k]]
        if not axes:
            continue  # no motion: nothing to write, modal state unchanged
        if protected and m == FEED and length_on and feed_mode == "G94" and \
                all(letters[k] in "XYZ" and letters[k] not in rotary for k, _ in axes):
            # near the part with the probe: the macro stops with an alarm on an unexpected touch
            block(f"G65 P{options.protected_macro} "
                  + " ".join(a + strs[k][i] for k, a in enumerate(letters) if a in "XYZ")
                  + f" F{_fmt_feed(feeds[i][1])}")
            for k, _ in axes:
                last[k] = strs[k][i]
            last_g = last_f = None   # the macro leaves its own modal G code and F
            continue
        g = {RAPID: "G00", FEED: "G01", PROBE: "G31"}[m]
        words = []
        mode = feeds[i][0] if feeds[i] is not None else None
        if mode is not None and mode != feed_mode:
            words.append(mode)
            feed_mode = mode
        if m == PROBE or g != last_g:
            words.append(g)
        last_g = None if m == PROBE else g  # G31 is one-shot: the next block restates G01/G00
        if not length_on:
            words.append(length_word)    # with the first move, as the control expects it
            length_on = True
        for k, w in axes:
            words.append(w)
            last[k] = strs[k][i]
        if m == PROBE:
            words.append(f"F{_fmt_feed(path.feed)}")   # never modal: a G31 states its feed
            last_f = None
        elif feeds[i] is not None:
            f = feeds[i][1]
            if mode == "G93" or f != last_f:   # G93: F on every block
                words.append(f"F{_fmt_feed(f)}")
                last_f = f if mode != "G93" else None
        if m == PROBE and options.probe_log:
            a = -path.normal[i]
            bowl = 1
            if centres:
                c = np.asarray(centres, float)
                bowl = int(np.argmin(np.linalg.norm(c - path.p[i, :2], axis=1))) + 1
            block(f"#100={bowl}")
            for k, v in zip((101, 102, 103), a):
                block(f"#{k}={v:.6f}")
        block(" ".join(words))
        if m == PROBE:
            block(_missed_touch(letters, [strs[k][i] for k in range(len(letters))], skip_vars))
            block(f"IF[#104LT{MISSED_TOL}]THEN#3000={options.missed_alarm}(PROBE DID NOT TOUCH)")
        if m == PROBE and options.probe_log:
            vals = "*".join(f"{a}#{skip_vars[a]}[{_int_digits(machine, a)}"
                            f"{min(dec[a], 8 - _int_digits(machine, a))}]" for a in letters)
            block(f"DPRNT[T#100[30]*I#101[16]*J#102[16]*K#103[16]*{vals}*D#104[35]]")
    if feed_mode == "G93":
        block("G94")
    if options.probe_log and probing:
        block("PCLOS")
    if options.coolant:
        block("M09")
    if options.spindle:
        block("M05")
    for b in _retract(machine, options, end=True, cancel_length=options.tcp or options.tool_length):
        block(b)
    for b in _template(options.postamble, fields, "postamble"):
        block(b)
    block("M30")
    numbered, note = _number(body, options)
    return "\n".join(head + ([note] if note else []) + numbered + ["%"]) + "\n"


def _missed_touch(letters, target, skip_vars) -> str:
    """#104 = distance (mm, summed over X Y Z) of the skip position from the G31 end point: the
    control stops a G31 at its end point when the skip signal never comes."""
    terms = [f"ABS[#{skip_vars[a]}-[{v}]]" for a, v in zip(letters, target) if a in "XYZ"]
    return "#104=" + "+".join(terms)


def _retract(machine, options: PostOptions, end: bool, cancel_length: bool = False) -> list[str]:
    """Blocks that take the spindle to a safe height before a tool change (and at the end, the
    table to the load position): G91 G28 Z0. (reference point through the current position)
    or G53 G00 Z0. (machine zero).  `cancel_length`: G49 on the Z block, where the reference
    return makes cancelling the length offset safe (never on a block that moves down)."""
    g49 = "G49 " if cancel_length else ""
    if options.retract == "none" or "Z" not in machine.axis_names:
        return [g49.strip()] if cancel_length else []
    if options.retract == "G53":
        return [f"{g49}G53 G00 Z0."]
    out = [f"{g49}G91 G28 Z0."]
    xy = [a for a in "XY" if a in machine.axis_names]
    if end and xy:
        out.append("G28 " + " ".join(f"{a}0." for a in xy))
    return out + ["G90"]


def _number(body: list[str], options: PostOptions) -> tuple[list[str], str | None]:
    """N words that never repeat: the given step, else the largest step that fits below
    line_max, else none (and a header comment)."""
    if not options.line_numbers or not body:
        return body, None
    first, step, n = options.first_line, options.line_step, len(body)
    if first + step * (n - 1) > options.line_max:
        step = (options.line_max - first) // (n - 1) if n > 1 else step
        if step < 1:
            return body, f"(NO N NUMBERS: {n} BLOCKS DO NOT FIT BELOW N{options.line_max})"
    return [f"N{first + step * k} {b}" for k, b in enumerate(body)], None


def motion_view(text: str, protected_macro: int = 9810) -> str:
    """The program as a straight-line motion reader sees it: a protected positioning call
    ``G65 P<macro> X Y Z F`` becomes the ``G01 X Y Z F`` move the macro makes, and the
    missed-touch check after each G31 (``#104=...``, ``IF[...]THEN#3000=...``), which moves
    nothing, becomes an empty line (line numbers stay those of the program).  What `mtcomp.verify` checks of a probing program."""
    out = []
    call = re.compile(rf"^(N\d+\s+)?G65\s+P{int(protected_macro)}\b\s*")
    skip = re.compile(r"^(N\d+\s+)?(#104=|IF\[#104)")
    for line in text.splitlines():
        if skip.match(line):
            out.append("")   # kept as an empty line: errors keep the program's line numbers
            continue
        m = call.match(line)
        out.append(f"{m.group(1) or ''}G01 {line[m.end():]}" if m else line)
    return "\n".join(out) + "\n"


def _g31_end_points(program: str, letters) -> list[dict]:
    """End points {X, Y, Z: mm} of the G31 blocks of a posted program, in order (modal axis
    words carried from the blocks before; macro and comment text ignored)."""
    word = re.compile(r"(?<![#\[A-Z])([XYZ])([-+]?(?:\d+\.?\d*|\.\d+))")
    pos: dict = {}
    out = []
    for line in program.splitlines():
        s = re.sub(r"^\s*N\d+\s*", "", re.sub(r"\([^)]*\)", "", line.upper()))
        if s.lstrip().startswith(("#", "IF", "DPRNT", "%")):
            continue
        pos.update({a: float(v) for a, v in word.findall(s) if a in letters})
        if re.search(r"\bG31\b", s):
            out.append({a: pos[a] for a in "XYZ" if a in pos})
    return out


def _int_digits(machine, letter: str) -> int:
    """Integer digits of a DPRNT field [ab] for an axis: enough for its travel.  Fanuc allows
    a + b <= 8, so the decimals give way where the travel needs three digits (10 nm, far below
    a probe's repeatability)."""
    lo, hi = machine.axis(letter).limits
    return max(1, len(str(int(max(abs(lo), abs(hi))))))


def read_skip_log(text: str, machine, probe_radius: float, filename: str = "<string>",
                  program: str | None = None):
    """Touches from the skip-position log a ``probe_log`` program writes (DPRNT lines ``T<bowl>
    I<ax> J<ay> K<az> <axis letter><value> ... [D<distance>]``, spaces and leading zeros as the
    control prints them; other lines are ignored).

    A G31 whose skip signal never came stops at its end point, and the control reports that
    point as the skip position: it is not a touch.  Such a line is refused (with its line
    number) when its D (the distance of the skip position from the G31 end point, which the
    posted program prints) is below 1 µm, or, for logs without D, when `program` (the posted
    program text) is given and the k-th line's X Y Z equal the k-th G31's end point.

    The skip positions are axis positions: the probe centre in the nominal workpiece frame is
    the nominal forward model of those positions plus `probe_radius` along the tool axis, which
    is what the touches CSV holds (docs/workpiece-setting.md).  Returns
    :class:`mtcomp.setting.workpiece.Touches`; write it with ``write_touches``."""
    from ..kinematics import forward
    from ..setting.workpiece import Touches
    word = re.compile(r"([A-Z])\s*([-+]?\s*(?:\d+\.?\d*|\.\d+))")
    bowls, approach, qs, src = [], [], [], []
    letters = list(machine.axis_names)
    ends = _g31_end_points(program, letters) if program is not None else None
    for k, line in enumerate(text.splitlines(), 1):
        s = line.strip().upper()
        if not s.startswith("T"):
            continue
        vals = {}
        for letter, num in word.findall(s):
            vals[letter] = float(num.replace(" ", ""))
        need = ["T", "I", "J", "K", *letters]
        missing = [x for x in need if x not in vals]
        if missing:
            raise InputError(f"skip log line without {', '.join(missing)}", filename, k)
        a = np.array([vals["I"], vals["J"], vals["K"]])
        if not np.linalg.norm(a) > 0:
            raise InputError("approach direction I J K is zero", filename, k, "I")
        if "D" in vals and vals["D"] < MISSED_TOL:
            raise InputError(f"missed touch: the skip position is the G31 end point (D{vals['D']:g} mm)",
                             filename, k, "D")
        if ends is not None:
            if len(bowls) >= len(ends):
                raise InputError(f"more skip positions than the program's {len(ends)} G31 moves", filename, k)
            end = ends[len(bowls)]
            if all(abs(vals[a] - v) < MISSED_TOL for a, v in end.items()):
                raise InputError("missed touch: the skip position is the end point of G31 move "
                                 f"{len(bowls) + 1} of the program", filename, k)
        bowls.append(int(round(vals["T"])))
        approach.append(a / np.linalg.norm(a))
        qs.append([vals[x] for x in letters])
        src.append(k)
    if not bowls:
        raise InputError("no skip positions (lines T<bowl> I J K and the axes)", filename)
    pose = forward(machine, np.array(qs, float))
    centre = pose.p + probe_radius * pose.v
    return Touches(np.array(bowls), centre, np.array(approach), np.array(src), filename)
