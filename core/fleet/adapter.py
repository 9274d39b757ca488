"""The one place where the fleet calls the diagnosis: `diagnose_night`.

Everything else in mtcomp.fleet sees only the plain `NightResult` returned here, so a change of
`mtcomp.diagnose`'s signature or result object is fixed in this module alone.
"""
from __future__ import annotations

from dataclasses import dataclass

# diagnose() keywords a machine's options may set (the rest of its signature is not a per-machine
# option: settings and progress belong to the run)
OPTION_KEYS = ("outputs", "inputs", "units", "where", "exclude_rows", "same_clock", "dt")


@dataclass(frozen=True)
class EffectRow:
    """One named effect: parameters and 1-sigma keyed by names carrying their unit."""
    name: str
    outputs: tuple
    params: dict
    uncertainty: dict


@dataclass(frozen=True)
class NightResult:
    """What the fleet keeps of one machine-night's diagnosis (output units: those of `units`)."""
    outputs: tuple
    units: dict
    effects: tuple            # EffectRow
    rms_before: dict          # output -> RMS of REC - SIM
    rms_after: dict           # output -> RMS after the named effects
    holdout_before: dict      # output -> held-out RMS before
    holdout_after: dict       # output -> held-out RMS after (blocks predicted by the others' fit)
    noise_floor: dict
    unexplained: tuple        # outputs whose residual stays > 3x the noise floor
    samples: int


def diagnose_night(recordings, options: dict | None = None) -> NightResult:
    """Diagnose one machine-night: `recordings` is a sequence of (sim_path, rec_path).

    options: keywords of `mtcomp.diagnose.diagnose` (OPTION_KEYS).  One recording is diagnosed
    as `mtcomp diagnose --sim SIM --rec REC` would.  Several recordings of one night need the
    diagnosis of a corpus of recordings, which this version of mtcomp.diagnose does not offer:
    an InputError says so (this is where it will be called).
    """
    from .. import InputError
    from ..diagnose import diagnose
    recordings = list(recordings)
    if len(recordings) != 1:
        raise InputError(f"{len(recordings)} recordings for one machine-night: this version "
                         "diagnoses one SIM/REC pair per night (expected exactly one)",
                         recordings[0][0] if recordings else None)
    opts = {k: v for k, v in (options or {}).items() if k in OPTION_KEYS and v not in (None, [], {})}
    sim, rec = recordings[0]
    res = diagnose(str(sim), str(rec), **opts)
    fit = res.fit
    return NightResult(
        outputs=tuple(res.outputs), units=dict(res.units),
        effects=tuple(EffectRow(e.name, tuple(e.outputs), dict(e.params), dict(e.uncertainty))
                      for e in res.effects),
        rms_before=dict(fit["rms_before"]), rms_after=dict(fit["rms_after"]),
        holdout_before=dict(fit["holdout_rms_before"]), holdout_after=dict(fit["holdout_rms_after"]),
        noise_floor=dict(res.noise_floor),
        unexplained=tuple(u["output"] for u in res.unexplained),
        samples=int(res.alignment.get("samples", 0)))
