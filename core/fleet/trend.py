"""Parameters of every machine over time, and the warnings they raise.

A series is one machine's parameter of one effect on one output (x backlash_mm), night by night,
with its 1-sigma.  Two tests warn:

- **change**: a night's value against the reference, the inverse-variance mean of up to `window`
  earlier nights since the last change warned about.  It warns when
  |x - ref| > k * B * sqrt(sigma_x^2 + sigma_ref^2), B the Birge ratio of the reference nights
  (sqrt of their chi^2 per degree of freedom, at least 1, from 3 nights on): a diagnosis' sigma
  counts the noise of one recording; B widens it by the scatter seen from night to night (set-up,
  temperature) where that is larger.  After a warning the reference starts again from that night,
  so a step warns once and a steady growth every night it grows by more than the band.
- **limit**: a value outside [min, max] of a rule in the limits TOML.

A night whose diagnosis left some output unexplained (its residual above 3x the noise floor:
an effect missing from the model, or a model chosen wrongly on a recording that could not tell
two effects apart) is listed apart and takes no part in the change test, neither as the night
tested nor in a reference: its parameters were fitted with a model that does not describe the
recording, and their sigmas do not hold.  Limits still apply to it.

Parameters that describe the recording rather than the machine (the state at the start,
`initial_*`, a level, `offset_*`, except a time offset's, and the span of positions a profile was
fitted over, `range_*`) and parameters fixed by the model
(sigma exactly 0) are not trended; a servo lag is trended by kv (its tau_s is 1/kv).
"""
from __future__ import annotations

import fnmatch
import math
from dataclasses import dataclass, field

from .._io import InputError

DERIVED = {("servo_lag", "tau_s")}


@dataclass(frozen=True)
class Rule:
    """A limit: `parameter` (and optionally effect, machine, output, fnmatch patterns) must stay
    within [min, max] (the parameter's unit, mm/deg/s...)."""
    parameter: str
    effect: str = "*"
    machine: str = "*"
    output: str = "*"
    min: float = -math.inf
    max: float = math.inf

    def applies(self, s: "Series") -> bool:
        return all(fnmatch.fnmatchcase(v, p) for v, p in
                   ((s.parameter, self.parameter), (s.effect, self.effect),
                    (s.machine, self.machine), (s.output, self.output)))


@dataclass(frozen=True)
class Limits:
    """The change test's settings and the limit rules (a limits TOML)."""
    k: float = 5.0
    window: int = 5
    rules: tuple = ()


def limits_from(data: dict, path=None) -> Limits:
    """Limits from a TOML mapping:

        [change]
        k = 5.0          # warn beyond k combined sigmas
        window = 5       # nights in the reference
        [[limit]]
        parameter = "backlash_mm"   # fnmatch patterns: parameter, effect, machine, output
        output = "x"
        max = 0.010
    """
    known = {"change", "limit"}
    for key in data:
        if key not in known:
            raise InputError(f"unknown table {key!r} (expected [change] and [[limit]])", path, field=key)
    ch = data.get("change", {})
    if not isinstance(ch, dict):
        raise InputError("expected a table [change] with k and window", path, field="change")
    for key in ch:
        if key not in ("k", "window"):
            raise InputError(f"unknown key {key!r} (expected k, window)", path, field=f"change.{key}")
    k = ch.get("k", Limits.k)
    if isinstance(k, bool) or not isinstance(k, (int, float)) or not (0 < k < math.inf):
        raise InputError(f"k = {k!r}: expected a number of sigmas > 0", path, field="change.k")
    window = ch.get("window", Limits.window)
    if isinstance(window, bool) or not isinstance(window, int) or window < 1:
        raise InputError(f"window = {window!r}: expected a whole number of nights >= 1", path,
                         field="change.window")
    items = data.get("limit", [])
    if not isinstance(items, list):
        raise InputError("expected an array of tables [[limit]]", path, field="limit")
    rules = []
    for i, it in enumerate(items):
        where = f"limit[{i}]"
        if not isinstance(it, dict):
            raise InputError("expected a table", path, field=where)
        for key in it:
            if key not in ("parameter", "effect", "machine", "output", "min", "max"):
                raise InputError(f"unknown key {key!r} (expected parameter, effect, machine, "
                                 "output, min, max)", path, field=f"{where}.{key}")
        if not isinstance(it.get("parameter"), str) or not it["parameter"]:
            raise InputError("expected parameter = \"NAME\" (e.g. backlash_mm)", path,
                             field=f"{where}.parameter")
        for key in ("effect", "machine", "output"):
            if key in it and not isinstance(it[key], str):
                raise InputError(f"expected a text, got {it[key]!r}", path, field=f"{where}.{key}")
        bounds = {}
        for key in ("min", "max"):
            if key in it:
                v = it[key]
                if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                    raise InputError(f"expected a finite number, got {v!r}", path,
                                     field=f"{where}.{key}")
                bounds[key] = float(v)
        if not bounds:
            raise InputError("expected min and/or max", path, field=where)
        if bounds.get("min", -math.inf) > bounds.get("max", math.inf):
            raise InputError(f"min {bounds['min']} > max {bounds['max']}", path, field=where)
        rules.append(Rule(**{k: it[k] for k in ("parameter", "effect", "machine", "output")
                             if k in it}, **bounds))
    return Limits(float(k), int(window), tuple(rules))


def load_limits(path) -> Limits:
    from .._io import load_toml_as
    return load_toml_as(path, limits_from, what="limits")


@dataclass(frozen=True)
class Series:
    machine: str
    effect: str
    output: str
    parameter: str
    unit: str
    dates: tuple
    values: tuple
    sigmas: tuple
    explained: tuple = ()    # per date: the night's diagnosis explained every output

    def night_explained(self, i: int) -> bool:
        return self.explained[i] if self.explained else True

    @property
    def label(self) -> str:
        return f"{self.output} {self.effect}.{self.parameter}"


@dataclass(frozen=True)
class Warn:
    """A warning: `kind` "change" (value, reference and their combined sigma `band`) or "limit"
    (value beyond `limit`)."""
    machine: str
    date: str
    effect: str
    output: str
    parameter: str
    unit: str
    kind: str
    value: float
    sigma: float
    reference: float = math.nan
    band: float = math.nan
    limit: float = math.nan

    @property
    def key(self) -> tuple:
        return (self.machine, self.date, self.parameter)


@dataclass(frozen=True)
class Trends:
    series: tuple
    warnings: tuple
    errors: tuple          # (machine, date, reason) of nights that failed
    unexplained: tuple     # (machine, date, outputs, effects) of nights not fully explained
    machines: tuple
    dates: tuple
    limits: Limits = field(default_factory=Limits)


def trended(effect: str, parameter: str, sigma: float) -> bool:
    if (effect, parameter) in DERIVED:
        return False
    if parameter.startswith(("initial_", "range_")):
        return False
    if parameter.startswith("offset_") and effect != "time_offset":
        return False
    return not sigma == 0.0


def _columns(table) -> dict:
    return table.to_pydict() if hasattr(table, "to_pydict") else dict(table)


def unexplained_nights(table) -> list[tuple]:
    """(machine, date, outputs left unexplained, effects named) of the nights whose diagnosis
    left some output's residual above 3x its noise floor."""
    cols = _columns(table)
    nights: dict = {}
    per_night = cols.get("night_unexplained") or [None] * len(cols["machine"])
    for m, d, e, o, u, nu in zip(cols["machine"], cols["date"], cols["effect"], cols["output"],
                                 cols["unexplained"], per_night):
        outs, effs = nights.setdefault((m, d), (set(), set()))
        if e not in ("none", "error"):
            effs.add(f"{e}({o})")
        if nu is not None:
            outs.update(x for x in nu.split(",") if x)
        elif u:   # a dataset written before night_unexplained: the row's outputs
            outs.update(o.split(","))
    return [(m, d, ",".join(sorted(o)), ", ".join(sorted(e)))
            for (m, d), (o, e) in sorted(nights.items()) if o]


def series_of(table) -> list[Series]:
    """The trended series of a dataset table (pyarrow Table or a mapping of columns)."""
    cols = _columns(table)
    bad = {(m, d) for m, d, _, _ in unexplained_nights(cols)}
    groups: dict = {}
    for m, d, e, o, p, u, v, s in zip(cols["machine"], cols["date"], cols["effect"], cols["output"],
                                      cols["parameter"], cols["unit"], cols["value"], cols["sigma"]):
        if e in ("none", "error") or v is None or not math.isfinite(v) or not trended(e, p, s):
            continue
        groups.setdefault((m, e, o, p, u), {})[d] = (v, s if s is not None else math.nan)
    out = []
    for (m, e, o, p, u), byd in sorted(groups.items()):
        ds = sorted(byd)
        out.append(Series(m, e, o, p, u, tuple(ds), tuple(byd[d][0] for d in ds),
                          tuple(byd[d][1] for d in ds), tuple((m, d) not in bad for d in ds)))
    return out


def _reference(ref: list) -> tuple[float, float, float]:
    """Inverse-variance mean, its sigma, and the Birge ratio (>= 1; 1 below 3 values)."""
    w = [1.0 / (s * s) for _, s in ref]
    sw = sum(w)
    mean = sum(wi * x for wi, (x, _) in zip(w, ref)) / sw
    birge = 1.0
    if len(ref) >= 3:
        chi2 = sum(((x - mean) / s) ** 2 for x, s in ref) / (len(ref) - 1)
        birge = max(1.0, math.sqrt(chi2))
    return mean, math.sqrt(1.0 / sw), birge


def change_warnings(s: Series, k: float, window: int) -> list[Warn]:
    out = []
    ref: list = []
    for i, (d, x, sx) in enumerate(zip(s.dates, s.values, s.sigmas)):
        if not (math.isfinite(sx) and sx > 0) or not s.night_explained(i):
            continue
        if ref:
            mean, sm, birge = _reference(ref[-window:])
            band = birge * math.sqrt(sx * sx + sm * sm)
            if abs(x - mean) > k * band:
                out.append(Warn(s.machine, d, s.effect, s.output, s.parameter, s.unit, "change",
                                x, sx, mean, band))
                ref = []
        ref.append((x, sx))
    return out


def limit_warnings(s: Series, rules) -> list[Warn]:
    out = []
    for r in rules:
        if not r.applies(s):
            continue
        for d, x, sx in zip(s.dates, s.values, s.sigmas):
            if x > r.max or x < r.min:
                out.append(Warn(s.machine, d, s.effect, s.output, s.parameter, s.unit, "limit",
                                x, sx, limit=r.max if x > r.max else r.min))
    return out


def trends(table, limits: Limits | None = None) -> Trends:
    """Series and warnings (sorted by machine, date, parameter) of a dataset table."""
    limits = limits or Limits()
    series = series_of(table)
    warns = []
    for s in series:
        warns += change_warnings(s, limits.k, limits.window)
        warns += limit_warnings(s, limits.rules)
    warns.sort(key=lambda w: (w.machine, w.date, w.output, w.parameter, w.kind))
    cols = _columns(table)
    errors = sorted({(m, d, st) for m, d, e, st in zip(cols["machine"], cols["date"], cols["effect"],
                                                       cols["status"]) if e == "error"})
    return Trends(tuple(series), tuple(warns), tuple(errors), tuple(unexplained_nights(cols)),
                  tuple(sorted(set(cols["machine"]))), tuple(sorted(set(cols["date"]))), limits)
