"""Null cases: pairs whose honest diagnosis names no effect of the machine (synth.null_case).

    python benchmarks/diagnose_null.py [SEEDS_PER_KIND]

White noise, 20 random-walk inputs, a SIM at 10 Hz coarser than its path's corners, and REC on
a clock of its own: a name is a false alarm.  A `time_offset` found on separate clocks is clock
alignment, not a name of the machine.  Prints one line per case and the total.
"""
from __future__ import annotations

import sys
import time


def names(res) -> list:
    """What the diagnosis names as physics of the machine."""
    return [n for n in res.names if n != "time_offset"]


def main(per_kind: int = 10) -> int:
    from mtcomp.diagnose import diagnose, synth
    false = total = 0
    c0 = time.process_time()
    for kind in synth.NULL_KINDS:
        for seed in range(per_kind):
            case = synth.null_case(kind, seed)
            res = diagnose(case.sim, case.rec)
            got = names(res)
            total += 1
            false += bool(got)
            print(f"{kind:16s} seed {seed:2d}: {', '.join(got) or '-'}", flush=True)
    print(f"null cases with a name: {false} of {total}  ({time.process_time() - c0:.1f} s CPU)")
    return 0


if __name__ == "__main__":
    sys.exit(main(int(sys.argv[1]) if len(sys.argv) > 1 else 10))
