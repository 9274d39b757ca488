"""Process memory settings for one large batch job: the CLI calls `tune` once per command.

Why: `mtcomp compensate` on a 1 M-line program allocates and frees a few GB of numpy temporaries
over its run.  With glibc's defaults every array above 32 MB is a fresh mapping, returned to the
system when freed, and every page of the next one costs a fault and its zeroing; numpy also asks
for transparent huge pages on large arrays, whose faults on a loaded machine add compaction.
The system time was 1.4-2.0 s of 4.1-4.5 s CPU; with freed arrays up to 64 MB reused from the
heap and no huge-page advice, about 0.5-0.7 s (docs/benchmarks.md, section gcode), for about
20 MB more peak resident memory (256 MB: 0.4-0.6 s, but 50 MB more).  Only the CLI calls this: importing the library never changes the allocator of
its host process.  Elsewhere than glibc (musl, macOS, Windows) only the numpy part applies.
"""
from __future__ import annotations

import ctypes
import sys

#: Arrays up to this size come from the heap, which keeps as much freed memory for reuse.
HEAP_REUSE_BYTES = 64 << 20
_M_TRIM_THRESHOLD, _M_MMAP_THRESHOLD = -1, -3     # glibc <malloc.h>
_state: dict = {}


def tune() -> dict:
    """Apply the settings (once; later calls return the first result): ``{"heap_reuse": bool,
    "huge_pages_off": bool}``, what could be applied."""
    if _state:
        return dict(_state)
    heap = False
    if sys.platform.startswith("linux"):
        try:
            mallopt = getattr(ctypes.CDLL(None), "mallopt", None)
            if mallopt is not None:
                mallopt.argtypes, mallopt.restype = [ctypes.c_int, ctypes.c_int], ctypes.c_int
                heap = bool(mallopt(_M_MMAP_THRESHOLD, HEAP_REUSE_BYTES)) and bool(
                    mallopt(_M_TRIM_THRESHOLD, HEAP_REUSE_BYTES))
        except (OSError, AttributeError):
            heap = False
    import numpy as np
    core = getattr(np, "_core", None) or getattr(np, "core", None)
    setter = getattr(getattr(core, "multiarray", None), "_set_madvise_hugepage", None)
    huge_off = False
    if setter is not None:
        setter(False)
        huge_off = True
    _state.update(heap_reuse=heap, huge_pages_off=huge_off)
    return dict(_state)
