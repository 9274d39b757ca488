"""What a column of a recording holds: its unit and quantity (kind), a kind guessed from its
name when it has no unit, the ISO 841 axis letter it refers to, and the stem of its name without
the words that say its role (command or measurement).

Units convert to the interface units mm, deg, s, degC, rpm, mm/s, deg/s, mm/s^2 and deg/s^2;
the kind of a unit-less column comes from its name (``x``, ``y_cmd`` -> length, ``b``, ``q1`` ->
angle, ``vx``, ``X1_ActualVelocity`` -> velocity, ``z_acc_cmd`` -> acceleration,
``t_spindle``/``temp2`` -> temperature, ``s``/``spindle`` -> speed; German, French and Spanish
words too), a guess that the diagnosis reports.
"""
from __future__ import annotations

import math
import re

from ..csvtable import UNITS as _BASE_UNITS

# unit -> (kind, factor, offset): value_in_interface_unit = value * factor + offset.  The base
# units are the project's one table (mtcomp.csvtable.UNITS, angles there in rad, here in deg);
# added here: units of rates, and spellings that recording tools write.
UNITS: dict[str, tuple[str, float, float]] = {
    u: (q, f * (180.0 / math.pi if q == "angle" else 1.0), o * (180.0 / math.pi if q == "angle" else 1.0))
    for u, (q, f, o) in _BASE_UNITS.items()}
UNITS.update({
    "inch": ("length", 25.4, 0.0), "\"": ("length", 25.4, 0.0), "mil": ("length", 0.0254, 0.0),
    "thou": ("length", 0.0254, 0.0), "mm": ("length", 1.0, 0.0),
    "grad": ("angle", 0.9, 0.0), "gon": ("angle", 0.9, 0.0), "rev": ("angle", 360.0, 0.0),
    "c": ("temperature", 1.0, 0.0), "°f": ("temperature", 5.0 / 9.0, -160.0 / 9.0),
    "degf": ("temperature", 5.0 / 9.0, -160.0 / 9.0),
    "rev/min": ("speed", 1.0, 0.0), "u/min": ("speed", 1.0, 0.0), "rev/s": ("speed", 60.0, 0.0),
    "arcsec": ("angle", 1.0 / 3600.0, 0.0), "arcmin": ("angle", 1.0 / 60.0, 0.0),
    "'": ("angle", 1.0 / 60.0, 0.0), "h": ("time", 3600.0, 0.0),
})
# velocities and accelerations of linear and rotary axes: every length/angle unit over s, min
for _u, (_k, _f, _) in list(UNITS.items()):
    if _k not in ("length", "angle"):
        continue
    _vk, _ak = ("velocity", "acceleration") if _k == "length" else ("angular_velocity",
                                                                       "angular_acceleration")
    # rev/s and rev/min stay spindle speeds
    UNITS.setdefault(_u + "/s", (_vk, _f, 0.0))
    UNITS.setdefault(_u + "/min", (_vk, _f / 60.0, 0.0))
    for _sq in ("/s^2", "/s2", "/s²", "/s/s", "/s**2"):
        UNITS.setdefault(_u + _sq, (_ak, _f, 0.0))
INTERFACE_UNIT = {"length": "mm", "angle": "deg", "time": "s", "temperature": "degC",
                  "speed": "rpm", "velocity": "mm/s", "angular_velocity": "deg/s",
                  "acceleration": "mm/s^2", "angular_acceleration": "deg/s^2", "other": ""}
KINDS = tuple(INTERFACE_UNIT)
# kinds an output can have (what the effect library acts on)
MOTION_KINDS = ("length", "angle", "velocity", "angular_velocity", "acceleration",
                "angular_acceleration")
_DERIVED = {"length": ("velocity", "acceleration"),
            "angle": ("angular_velocity", "angular_acceleration")}

_HEADER = re.compile(r"^\s*(?P<name>[^\[\(]+?)\s*(?:[\[\(]\s*(?P<unit>[^\]\)]*?)\s*[\]\)])?\s*$")
_LINEAR = re.compile(r"^(?:q_?|cmd_?|pos_?)?[xyzuvw](?:$|[_\-\s\d].*|_?(?:cmd|act|pos|nom|set).*)")
_ROTARY = re.compile(r"^(?:q_?|cmd_?|pos_?)?[abc](?:$|[_\-\s\d].*|_?(?:cmd|act|pos|nom|set).*)")
_JOINT = re.compile(r"^(?:q|joint|j|theta|th)_?\d*(?:$|_(?:cmd|act|set|nom|meas|des)\w*)")
_TEMP = re.compile(r"^(?:t[_\-\s\d].+|t[a-z]{2,}\d*|temp.*|.*temperature.*|.*_temp\w*|theta_.*)$")
_SPEED = re.compile(r"^(?:s|s\d|s_.*|spindle.*|.*rpm.*|n_spindle.*)$")
_TOKENS = re.compile(r"[A-Z]+(?![a-z])|[A-Z]?[a-z]+|\d+")
_VEL_WORDS = {"v", "vel", "velo", "velocity", "feedrate", "speed", "geschwindigkeit", "geschw",
              "vitesse", "velocidad", "velocita"}
_ACC_WORDS = {"acc", "accel", "acceleration", "beschleunigung", "besch", "aceleracion",
              "accelerazione"}
# words of other conventions (German, French, Spanish; drive parameters): position, angle,
# spindle speed, temperature
_POS_WORDS = {"pos", "position", "lage", "weg", "istposition", "sollposition", "posicion",
              "posizione", "cote", "coord", "coordinate", "displacement", "disp"}
_ANGLE_WORDS = {"winkel", "angle", "angulo", "joint", "gelenk", "articulation", "achswinkel"}
_SPEED_WORDS = {"drehzahl", "spindeldrehzahl", "broche", "rpm", "husillo", "mandrino"}
_TEMP_WORDS = {"temperatur", "temperature", "temp", "temperatura"}


def _tokens(name: str) -> list[str]:
    """Lower-case words of a column name: `X1_CommandVelocity` -> ['x', '1', 'command', 'velocity']."""
    return [w.lower() for w in _TOKENS.findall(name)]


def kind_from_name(key: str) -> str:
    """Guess the kind of a unit-less column from its name (the last resort; reported)."""
    low = key.lower()
    if low in ("t", "time"):
        return "time"
    words = _tokens(key)
    if _TEMP.match(low) and not _LINEAR.match(low):
        return "temperature"
    rate = _rate_word(words)
    if rate:
        # `vx_cmd`, `cmd_vx`, `vx1_act`, `v_x`, `ax_cmd`, `a_x`: a rate of an axis, whatever
        # words of role stand beside it (before, the axis letter in `vx`/`ax` made them lengths,
        # and `a_x` an angular acceleration of the A axis)
        which, letter = rate
        return _DERIVED["angle" if letter in "abc" else "length"][0 if which == "v" else 1]
    base = "angle" if _ROTARY.match(low) or _JOINT.match(low) else "length"
    has_axis = bool(_LINEAR.match(low) or _ROTARY.match(low) or _JOINT.match(low)
                    or _axis_in_words(words))
    if any(w in _ACC_WORDS for w in words) or re.match(r"^(?:acc|a)_?[xyzuvw]\d?$", low):
        if has_axis or re.match(r"^(?:acc|a)_?[xyzuvw]", low):
            return _DERIVED[base][1]
    if any(w in _VEL_WORDS for w in words) or re.match(r"^v_?[xyzabc]\d?$", low):
        if "spindle" not in words and (has_axis or re.match(r"^v_?[xyzabc]", low)):
            return _DERIVED["angle" if re.match(r"^v_?[abc]", low) else base][0]
    if _SPEED.match(low) and not (_axis_in_words(words) and not {"speed", "rpm", "n"} & set(words)):
        # a spindle's acceleration (`S_acc`, `spindle_accel`) is not a speed: no kind of the
        # library holds rpm/s, so it stays a generic input
        return "other" if set(words) & _ACC_WORDS else "speed"
    if _axis_in_words(words) in tuple("xyz") and len(words) <= 3:
        return "length"
    if _LINEAR.match(low):
        return "length"
    if _ROTARY.match(low) or _JOINT.match(low):
        return "angle"
    if _TEMP.match(low):
        return "temperature"
    wset = set(words)
    if wset & _TEMP_WORDS:
        return "temperature"
    if wset & _SPEED_WORDS:
        return "speed"
    if wset & _ANGLE_WORDS:
        return "angle"
    if wset & _POS_WORDS:
        # `Pos_Act`, `act_pos`, `Istposition_B`: a rotary axis letter makes it an angle
        return "angle" if _axis_in_words(words) in ("a", "b", "c") else "length"
    return "other"


def _rate_word(words) -> tuple[str, str] | None:
    """('v' or 'a', axis letter) when the name holds a rate of an axis: a word `vx`, `va`, `ax`
    (an acceleration only of a linear axis: `ab`, `ac` say nothing), or starts `v`/`a` then a
    single axis letter (`v_x_cmd`, `a_y`)."""
    for w in words:
        if len(w) == 2 and w[0] == "v" and w[1] in "xyzuvwabc":
            return "v", w[1]
        if len(w) == 2 and w[0] == "a" and w[1] in "xyzuvw":
            return "a", w[1]
    if len(words) >= 2 and words[0] in ("v", "a") and len(words[1]) == 1 and words[1] in "xyzuvw":
        return words[0], words[1]
    return None


def _axis_in_words(words) -> str | None:
    for w in words:
        if len(w) == 1 and w in "xyzabc":
            return w
        if len(w) == 2 and w[0] in "va" and w[1] in "xyzabc":
            return w[1]
    return None


def axis_letter(key: str, kind: str) -> str | None:
    """The ISO 841 axis letter a motion column refers to (``x_cmd``, ``vx``, ``X1_ActualVelocity``
    -> 'x'), or None (joint angles, unnamed signals)."""
    low = key.lower()
    m = re.match(r"^(?:q_?|cmd_?|pos_?)?([xyzabc])(?:$|[^a-z]|_?(?:cmd|act|pos|nom|set))", low)
    letter = m.group(1) if m else _axis_in_words(_tokens(key))
    if letter is None:
        return None
    linear = kind in ("length", "velocity", "acceleration")
    rotary = kind in ("angle", "angular_velocity", "angular_acceleration")
    if linear and letter in "xyz":
        return letter
    if rotary and letter in "abc":
        return letter
    return None


_SCALED = re.compile(r"^(?P<n>[0-9]*\.?[0-9]+(?:e[+-]?[0-9]+)?)\s*\*?\s*(?P<u>[^0-9].*)$")


def _unit_of(unit: str | None):
    """(kind, factor, offset) of a unit string, or None when unknown.  A unit may be scaled,
    ``0.5um`` or ``1e-4 mm``: counts of an encoder or a scale with that resolution."""
    if unit is None:
        return None
    u = unit.lower().replace(" ", "")
    hit = UNITS.get(u)   # as written first: `arcsec` is no arc-s
    u = u.replace("sec", "s").replace("inches", "inch")
    hit = hit or UNITS.get(u)
    if hit is None:
        m = _SCALED.match(u)
        if m and float(m.group("n")) > 0:
            base = UNITS.get(m.group("u"))
            if base is not None and base[2] == 0.0:
                return base[0], base[1] * float(m.group("n")), 0.0
    return hit


# words that say a column's role (command or measurement), not what it measures: `X_cmd` and
# `X_act`, `Soll_X` and `Ist_X`, `cmd_pos` and `act_pos`, `X1_CommandPosition` and
# `X1_ActualPosition` name the same quantity of the same axis
_ROLE_WORDS = {"cmd", "command", "commanded", "set", "setpoint", "soll", "sollwert", "nom",
               "nominal", "des", "desired", "ref", "reference", "target", "dem", "demand",
               "consigne", "cons", "sim", "simulated", "model", "act", "actual", "ist", "istwert",
               "meas", "measured", "fb", "feedback", "mes", "mesure", "mesuree", "reel", "reelle",
               "real", "rec", "recorded", "enc", "encoder", "scale", "lin", "rot", "motor", "load",
               "value", "wert", "valeur", "val"}


# the role words that say "what was asked for" and "what was measured" (a subset of the above;
# `lin`, `rot`, `motor`, `load`, `value` say neither)
_COMMAND_WORDS = {"cmd", "command", "commanded", "set", "setpoint", "soll", "sollwert", "nom",
                  "nominal", "des", "desired", "ref", "reference", "target", "dem", "demand",
                  "consigne", "cons", "sim", "simulated", "model"}
_MEASURED_WORDS = {"act", "actual", "ist", "istwert", "meas", "measured", "fb", "feedback", "mes",
                   "mesure", "mesuree", "reel", "reelle", "real", "rec", "recorded", "enc", "encoder",
                   "scale"}


def role(name: str) -> str | None:
    """'command' or 'measured' when a column's name says which it is (``X1_CommandVelocity``,
    ``x_act``, ``Istposition``), else None; a name with words of both roles says neither."""
    words = {w for pair in _role_split(name) for w in pair if w}
    cmd, meas = bool(words & _COMMAND_WORDS), bool(words & _MEASURED_WORDS)
    return "command" if cmd and not meas else ("measured" if meas and not cmd else None)


def _role_split(name: str) -> list[tuple[str, str | None]]:
    """The name's lower-case words, a German compound's role prefix split off:
    ``Istposition_X`` -> [('position', 'ist'), ('x', None)]."""
    out = []
    for w in _tokens(name):
        pre = next((p for p in ("ist", "soll") if w.startswith(p) and len(w) > len(p) + 2), None)
        out.append((w[len(pre):], pre) if pre else (w, None))
    return out


def stem(name: str) -> str:
    """A column's name without the words that say its role, lower case: what a command and its
    measurement have in common (``X_cmd`` / ``x_act`` -> 'x'; ``Pos_Act`` -> 'pos')."""
    return "_".join(w for w, _ in _role_split(name) if w not in _ROLE_WORDS)
