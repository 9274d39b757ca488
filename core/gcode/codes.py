"""Address letters, G and M codes: what the reader follows, what it passes, what it refuses."""
from __future__ import annotations

INCH = 25.4
LINEAR = frozenset("XYZUVW")
CANONICAL = "XYZUVWABC"
ARC_WORDS = "IJKR"

#: G codes (x10) that are read and carry no geometry of their own, or whose geometry is read.
_G_MOTION = {0: 0, 10: 1, 20: 2, 30: 3}
_G_PLANE = {170: 17, 180: 18, 190: 19}
_G_UNITS = {200: 20, 210: 21, 700: 20, 710: 21}          # G70/G71: inch/mm (Siemens and others)
_G_DIST = {900: 90, 910: 91}
#: work offsets: G54..G59 and G54.1 (with P)
_G_WCS = {540: 54, 550: 55, 560: 56, 570: 57, 580: 58, 590: 59, 541: 541,
          # Haas additional work offsets: G154 P1-P99, and G110-G129 (the same as G154 P1-P20)
          1540: 154, **{g: g // 10 for g in range(1100, 1300, 10)}}
#: arc centre mode: G90.1 absolute I J K, G91.1 incremental (the default)
_G_ARC_DIST = {901: 90, 911: 91}
#: tool length compensation: G43 +H, G44 -H, G49 cancel; G43.4 tool centre point (the words
#: are the tool tip in the workpiece frame and the rotary angles, gcode.tcp)
#: Haas G234 (TCPC, tool centre point control, cancelled by G49) is its G43.4: the words are
#: the tool tip in the work frame and the rotary angles
#: LinuxCNC G43.1 Z<len> (dynamic tool length): the length is the block's Z word, not a table
#: entry; read as G43 with that length (G49 cancels)
_G_TOOL = {430: 43, 440: 44, 490: 49, 434: 434, 2340: 434, 431: 431}
#: canned drilling cycles (hole at X Y, R level, depth Z; G98 back to the initial level, G99
#: to R)
_G_CYCLE = {730: 73, 740: 74, 760: 76, **{g: g // 10 for g in range(810, 900, 10)}}
#: cutter radius compensation: G41 left, G42 right of the path, G40 cancel.  The control
#: offsets the programmed contour by the tool radius (D) in the active plane; mtcomp corrects
#: the programmed contour and bounds the error of doing so (commands.cutter_bound, docs/gcode.md)
#: G41.1/G42.1 (LinuxCNC dynamic compensation): D is the tool diameter, in the program
_G_CUTTER = {400: 40, 410: 41, 420: 42, 411: 411, 421: 421}
#: feed mode: G93 inverse time, G94 per minute, G95 per revolution
_G_FEED = {930: 93, 940: 94, 950: 95}
#: codes whose axis words are not moves: G92 (the current position gets these coordinates),
#: G52 local shift (values), G53 machine coordinates, G28
#: and G30 (via an intermediate point to a reference point), G50.1 (axes named to cancel
#: mirroring); after G53/G28/G30 the axes named are at a place the program does not know.
#: G92.4 A0 S0 is the Carvera (Smoothieware-based) A-axis "shrink": the A value is reduced to
#: 0-360 deg keeping the work offset, without a move (the Carvera controller sends it for its
#: Shrink button, "374 becomes 14"); A is unknown after it until written again (the value it
#: takes depends on the work offset and on how the firmware wraps negative angles)
_G_NONMOVE = {520: 52, 530: 53, 280: 28, 300: 30, 501: 501, 920: 92, 924: 924}
_G_HARMLESS = {
    40: "dwell", 90: "exact stop (one block)", 150: "polar coordinates cancel",
    80: "radius mode (LinuxCNC lathe: X words are radii, the default); look-ahead (Fanuc G08)",
    500: "scaling cancel", 610: "exact stop mode", 611: "inposition check mode",
    640: "cutting mode", 670: "macro modal call cancel", 690: "coordinate rotation cancel",
    800: "canned cycle cancel", 970: "constant spindle speed", 980: "cycle return to initial level",
    990: "cycle return to R level", 1030: "block look-ahead limit (Haas)",
    1870: "smoothness/accuracy setting (Haas)", 921: "G92 offsets cancel",
    922: "G92 offsets cancel (parameters kept)", 940: "feed per minute",
    # Fanuc G05.1 Q1 / Q0: AI contour control on / off (look-ahead feed control, the programmed
    # path kept); Q2/Q3 (smooth interpolation, nano smoothing) are refused in parse
    51: "AI contour control (Fanuc G05.1 Q1/Q0)",
    # Fanuc G05 P10000 / P0: AI (nano) high-precision contour control on / off, a look-ahead
    # acceleration and feed control that keeps the programmed path (16i/18i/30i); other G5
    # forms (high-speed cycle machining G05 P1..., LinuxCNC's cubic spline G5 X Y I J P Q,
    # Haas fine spindle control G5 R) move the axes and are refused in parse
    50: "AI high-precision contour control (Fanuc G05 P10000/P0)",
    # G96: the spindle speed follows the X (diameter) position; the axis positions do not
    # depend on it.  A correction of a few µm in X changes the speed by parts per million
    960: "constant surface speed (spindle speed only)",
}
#: Known G codes that change where the tool goes in a way this reader cannot follow.
_G_REFUSED = {
    70: "G7 diameter mode (LinuxCNC lathe): X words are diameters, not axis positions",
    290: "G29 returns from the reference point through an unknown intermediate point",
    720: "G72 (Haas: bolt holes along an angle; lathes: a facing cycle) is not supported",
    310: "G31 skip function: the end point depends on a probe signal",
    435: "G43.5 tool centre point with a tool vector (I J K) is not compensated: the control "
         "picks the rotary angles among several solutions by its own rules and the errors "
         "depend on that choice (post with G43.4 and rotary angles, which is compensated)",
    510: "G51 scaling changes the commanded positions in the control",
    511: "G51.1 mirror image changes the commanded positions in the control",
    682: "G68.2 tilted working plane transforms the axis words in the control",
    650: "G65 macro call: the macro's motion is not straight-line code in this file",
    660: "G66 modal macro call: the macro's motion is not straight-line code in this file",
}
_M_REFUSED = {
    98: "M98 calls a subprogram: expand the program first (gcode.flow.expand; mtcomp "
        "compensate does)",
    97: "M97 calls a local subprogram: expand the program first (gcode.flow.expand; mtcomp "
        "compensate does)",
    99: "M99 returns from a subprogram or jumps: expand the program first (gcode.flow.expand; "
        "mtcomp compensate does)",
    70: "M70 (a control-specific program-flow or macro code) is not followed",
    71: "M71 (a control-specific program-flow or macro code) is not followed",
    72: "M72 (a control-specific program-flow or macro code) is not followed",
}
#: LinuxCNC o-word program flow
O_WORDS = {"sub", "endsub", "call", "return", "if", "elseif", "else", "endif", "while",
           "endwhile", "do", "repeat", "endrepeat", "break", "continue"}
_CHAR_HINT = {
    "#": "macro variables (#) are not supported: mtcomp reads straight-line code; let the CAM "
         "system or control expand the macro",
    "[": "macro expressions ([ ]) are not supported", "]": "macro expressions ([ ]) are not supported",
    "=": "macro assignments are not supported",
    ":": "write the program number as O....", "*": "macro expressions are not supported",
    "(": "unbalanced '(' (comments may not nest and must close on their line)",
    ")": "unbalanced ')' (comments may not nest)", "%": "'%' only on a line of its own",
    "/": "block delete '/' only at the start of a block",
    "@": "LinuxCNC polar coordinates (@ distance, ^ angle) are not supported",
    "^": "LinuxCNC polar coordinates (@ distance, ^ angle) are not supported",
    "<": "LinuxCNC o<name> program flow: mtcomp compensate follows o<name> sub/endsub/call "
         "(gcode.flow.expand); other o-words are not followed",
}

#: Siemens (Sinumerik) instructions: frames, transformations, cycles, program flow.  Refused
#: with their name: they move the tool in ways the straight-line words do not say.
SIEMENS_WORDS = {
    "trans": "programmable frame translation", "atrans": "additive frame translation",
    "rot": "programmable frame rotation", "arot": "additive frame rotation",
    "rpl": "frame rotation in the plane", "scale": "frame scaling", "ascale": "frame scaling",
    "mirror": "frame mirroring", "amirror": "frame mirroring",
    "traori": "5-axis transformation (tool centre point)", "trafoof": "transformation off",
    "tracyl": "cylinder transformation", "transmit": "face transformation",
    "cycle": "machining cycle", "mcall": "modal subprogram call", "call": "subprogram call",
    "pcall": "subprogram call", "gotof": "jump", "gotob": "jump", "goto": "jump",
    "repeat": "program section repeat", "def": "variable definition", "proc": "subprogram",
    "if": "condition", "while": "loop", "for": "loop", "loop": "loop",
}


def siemens_hint(line: str) -> str | None:
    """What a Siemens instruction on this line is, or None when there is none."""
    import re
    for m in re.finditer(r"[A-Za-z_][A-Za-z_0-9]*", line):
        w = m.group().lower()
        key = "cycle" if re.fullmatch(r"cycle\d*", w) else w
        if key in SIEMENS_WORDS:
            return (f"Siemens {m.group().upper()} ({SIEMENS_WORDS[key]}) is not supported: mtcomp "
                    "reads straight-line code (G0-G3, offsets, canned cycles G73-G89); post the "
                    "program without frames, transformations and cycles")
    if re.match(r"^\s*(?:N\d+\s*)?R\d+\s*=", line):
        return ("Siemens R parameters (R<n>=) are not supported: mtcomp reads straight-line "
                "code; let the CAM system or control expand them")
    return None
