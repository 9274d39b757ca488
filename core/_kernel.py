"""The compiled kinematic kernel (fmu/c/mtk.c) called in batches from Python.

The same C source is compiled into the FMUs and, as a plain shared library (no Python headers),
loaded here through ctypes: arrays in, arrays out, one call per batch.  The library is looked
for, in order, next to this module (built at install time by setup.py), then in a per-user cache
keyed by the hash of the source (`~/.cache/mtcomp/kernel/<hash>/`, or $MTCOMP_CACHE_DIR), and
compiled there on first use with the C compiler ($CC, cc or gcc).  Without a compiler the
library uses its numpy reference implementation (mtcomp.kinematics) and says so once on stderr.
MTCOMP_KERNEL=numpy forces the numpy implementation, MTCOMP_KERNEL=cache ignores the library
installed with the package (only the per-user cache, built on first use).  A batch runs in chunks
of about CHUNK poses on min(cores, chunks) threads started in C (MTCOMP_THREADS, default: the CPUs
this process may use); the chunks do not depend on the number of threads, so neither do the results.

ctypes rather than a C extension: the kernel must build with nothing but gcc (no Python headers),
and ctypes releases the GIL during the call.
"""
from __future__ import annotations

import ctypes
import hashlib
import os
import shutil
import subprocess
import sys
import sysconfig
import tempfile
from pathlib import Path

import numpy as np

MAX_AXES = 9
#: Return codes of mtk.h
OK, E_RANGE, E_LIMIT, E_CONVERGE = 0, 3, 4, 5
CFLAGS = ("-O3", "-fno-math-errno", "-std=c99", "-fPIC", "-shared", "-DMTK_THREADS", "-pthread")

#: The kernel library's sources (fmu/c): the kinematic kernel, its batches on threads and the
#: co-simulation's stepping loop.
SOURCES = ("mtk.h", "mtk.c", "mtk_threads.c", "cosim_loop.c")
_SUFFIX = sysconfig.get_config_var("SHLIB_SUFFIX") or ".so"


def source_dir() -> Path:
    """Folder of mtk.c and mtk.h (package data of mtcomp.fmu, or the source tree)."""
    here = Path(__file__).resolve().parent
    for cand in (here.parent / "fmu" / "c", here / "fmu" / "c"):
        if (cand / "mtk.c").is_file():
            return cand
    import importlib.util
    spec = importlib.util.find_spec("mtcomp.fmu")
    if spec and spec.origin:
        return Path(spec.origin).parent / "c"
    return here / "fmu" / "c"


def source_hash(src: Path | None = None) -> str:
    """Hash of the kernel source and the compile flags: the key of a built library."""
    src = src or source_dir()
    h = hashlib.sha256()
    for name in SOURCES:
        h.update((src / name).read_bytes())
    h.update(" ".join(CFLAGS).encode())
    return h.hexdigest()[:16]


def library_name(digest: str) -> str:
    return f"libmtk-{digest}{_SUFFIX}"


def cache_dir() -> Path:
    base = os.environ.get("MTCOMP_CACHE_DIR")
    if base:
        return Path(base) / "kernel"
    xdg = os.environ.get("XDG_CACHE_HOME")
    return Path(xdg if xdg else Path.home() / ".cache") / "mtcomp" / "kernel"


def find_compiler() -> str | None:
    cc = os.environ.get("CC")
    if cc:
        return shutil.which(cc.split()[0]) and cc.split()[0]
    return shutil.which("cc") or shutil.which("gcc")


def compile_library(out: Path, src: Path | None = None, cc: str | None = None) -> Path:
    """Compile mtk.c into the shared library `out` (written atomically).  Raises OSError or
    RuntimeError (with the compiler's message) on failure."""
    src = src or source_dir()
    cc = cc or find_compiler()
    if not cc:
        raise OSError("no C compiler found (cc/gcc)")
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=".mtk-", suffix=_SUFFIX, dir=out.parent)
    os.close(fd)
    try:
        run = subprocess.run([cc, *CFLAGS, *(str(src / f) for f in SOURCES if f.endswith(".c")), "-o", tmp, "-lm"],
                             capture_output=True, text=True)
        if run.returncode:
            raise RuntimeError(f"compiling the kinematic kernel failed:\n{run.stderr[-2000:]}")
        os.replace(tmp, out)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)
    return out


class _Errors(ctypes.Structure):
    """mtk_errors of mtk.h"""
    _fields_ = [("tool", ctypes.c_double * 3), ("wp_t", ctypes.c_double * 3), ("wp_a", ctypes.c_double * 3),
                ("loc", (ctypes.c_double * 6) * MAX_AXES), ("use_tables", ctypes.c_int)]


class _Options(ctypes.Structure):
    """mtk_options of mtk.h"""
    _fields_ = [("tol", ctypes.c_double), ("max_iter", ctypes.c_int), ("pole_tol", ctypes.c_double),
                ("continuation", ctypes.c_int), ("run_in", ctypes.c_long)]


class CosimLoop(ctypes.Structure):
    """mtk_cosim of fmu/c/cosim_loop.c: the co-simulation's stepping loop in C (mtcomp.fmu.cosim).
    Instances, functions (fmi2SetReal, fmi2GetReal, fmi2DoStep) and arrays as plain addresses."""
    _fields_ = [(f, ctypes.c_void_p) for f in ("comp", "c_set", "c_get", "c_step", "c_in", "c_out",
                                               "mach", "m_set", "m_get", "m_step", "m_in", "m_out")] + \
               [("n", ctypes.c_int), ("n_out", ctypes.c_int), ("step", ctypes.c_double),
                ("q", ctypes.c_void_p), ("qc", ctypes.c_void_p), ("out", ctypes.c_void_p)]


#: What mtk_cosim_steps reports as failed (its return value modulo 8; the step is the quotient).
COSIM_FAILED = {1: "compensator", 2: "machine command", 3: "compensator step", 4: "machine step"}

_D = ctypes.POINTER(ctypes.c_double)
_I = ctypes.POINTER(ctypes.c_int)


def _bind(lib: ctypes.CDLL) -> ctypes.CDLL:
    vp, c_long = ctypes.c_void_p, ctypes.c_long
    lib.mtk_model_new.restype = vp
    lib.mtk_model_new.argtypes = [ctypes.c_int, ctypes.c_char_p, _I, _I, _D, _D, _D, _D, _D, _D, _D]
    lib.mtk_model_set_table.restype = ctypes.c_int
    lib.mtk_model_set_table.argtypes = [vp, ctypes.c_int, ctypes.c_int, _D, _D]
    lib.mtk_free.restype = None
    lib.mtk_free.argtypes = [vp]
    lib.mtk_forward_batch.restype = c_long
    lib.mtk_forward_batch.argtypes = [vp, ctypes.POINTER(_Errors), c_long, _D, _D, _D, ctypes.c_int, _I]
    lib.mtk_retarget_batch.restype = c_long
    lib.mtk_retarget_batch.argtypes = [vp, ctypes.POINTER(_Errors), c_long, _D, _D, ctypes.POINTER(_Options),
                                       _D, _I, _I]
    lib.mtk_compensate_batch.restype = c_long
    lib.mtk_compensate_batch.argtypes = [vp, ctypes.POINTER(_Errors), c_long, _D, _D, _D, _D,
                                         ctypes.POINTER(_Options), _D, _I, _I]
    lib.mtk_forward_batch_mt.restype = c_long
    lib.mtk_forward_batch_mt.argtypes = [vp, ctypes.POINTER(_Errors), c_long, _D, _D, _D, ctypes.c_int, _I,
                                         ctypes.c_int]
    if hasattr(lib, "mtk_check_batch_mt"):   # (a library of an earlier version, as a bench's baseline, has none)
        lib.mtk_check_batch_mt.restype = c_long
        lib.mtk_check_batch_mt.argtypes = [vp, ctypes.POINTER(_Errors), c_long, _D, _D, _D, _D, ctypes.c_int,
                                           _I, ctypes.c_int]
    lib.mtk_compensate_batch_mt.restype = c_long
    lib.mtk_compensate_batch_mt.argtypes = [vp, ctypes.POINTER(_Errors), c_long, _D, _D, _D, _D,
                                            ctypes.POINTER(_Options), _D, _I, _I, ctypes.c_int]
    lib.mtk_cosim_steps.restype = c_long
    lib.mtk_cosim_steps.argtypes = [ctypes.POINTER(CosimLoop), c_long, c_long]
    lib.mtk_threads.restype = ctypes.c_int
    lib.mtk_threads.argtypes = [c_long, ctypes.c_int]
    return lib


_state: dict = {}


def load(quiet: bool = False) -> ctypes.CDLL | None:
    """The kernel library, built on first use; None (numpy fallback) without a compiler."""
    if "lib" in _state:
        return _state["lib"]
    lib = None
    reason = ""
    if os.environ.get("MTCOMP_KERNEL", "").lower() == "numpy":
        _state["lib"] = None
        _state["reason"] = "MTCOMP_KERNEL=numpy"
        return None
    try:
        src = source_dir()
        digest = source_hash(src)
        name = library_name(digest)
        candidates = [Path(__file__).resolve().parent / name, cache_dir() / digest / name]
        if os.environ.get("MTCOMP_KERNEL", "").lower() == "cache":
            candidates = candidates[1:]  # as without the install-time build
        path = next((p for p in candidates if p.is_file()), None)
        if path is None:
            path = compile_library(cache_dir() / digest / name, src)
        lib = _bind(ctypes.CDLL(str(path)))
        _state["path"] = path
    except (OSError, RuntimeError) as exc:
        reason = str(exc).splitlines()[0]
        lib = None
    _state["lib"] = lib
    _state["reason"] = reason
    if lib is None and not quiet:
        sys.stderr.write(f"mtcomp: compiled kinematic kernel unavailable ({reason}); using the slower numpy "
                         "implementation\n")
    return lib


def available() -> bool:
    """True if the compiled kernel is in use."""
    return load(quiet=True) is not None


# ------------------------------------------------------------------------------------ model cache

class _Model:
    """An mtk_model built from a Machine and the tables of an ErrorSet (freed with the object)."""

    def __init__(self, lib, machine, tables):
        self.lib = lib
        n = machine.n_axes
        names = "".join(a.name for a in machine.axes).encode()
        rot = (ctypes.c_int * n)(*[int(a.is_rotary) for a in machine.axes])
        side = (ctypes.c_int * n)(*[int(a.side == "tool") for a in machine.axes])
        arr = lambda v: np.ascontiguousarray(v, dtype=float)  # noqa: E731
        d = arr([a.direction for a in machine.axes])
        lc = arr([a.location for a in machine.axes])
        lo = arr([a.limits[0] for a in machine.axes])
        hi = arr([a.limits[1] for a in machine.axes])
        # check_limits' tolerance: half a resolution step
        sl = arr([0.5 * a.resolution for a in machine.axes])
        tp, ta = arr(machine.tool_point), arr(machine.tool_axis)
        self.ptr = lib.mtk_model_new(n, names, rot, side, *(_p(x) for x in (d, lc, lo, hi, sl, tp, ta)))
        if not self.ptr:
            raise MemoryError("mtk_model_new failed")
        for k, a in enumerate(machine.axes):
            t = tables.get(a.name)
            if t is not None:
                pos = arr(t.position)
                val = arr(t._stack)
                if lib.mtk_model_set_table(self.ptr, k, pos.size, _p(pos), _p(val)) != OK:
                    raise MemoryError("mtk_model_set_table failed")

    def __del__(self):
        if getattr(self, "ptr", None):
            self.lib.mtk_free(self.ptr)
            self.ptr = None


def _p(a: np.ndarray):
    return a.ctypes.data_as(_D)


_models: dict = {}


def model(lib, machine, errors):
    """The cached C model of `machine` with the tables of `errors` (keyed by identity; the key
    objects are held so that ids are not reused)."""
    tables = dict(errors.geometric.tables) if errors is not None else {}
    key = (id(machine), tuple(sorted((k, id(t)) for k, t in tables.items())))
    hit = _models.get(key)
    if hit is not None:
        return hit[0]
    if len(_models) > 32:
        _models.clear()
    m = _Model(lib, machine, tables)
    _models[key] = (m, machine, tables)
    return m


def c_errors(machine, errors) -> _Errors:
    e = _Errors()
    e.use_tables = 1
    if errors is None:
        return e
    e.tool[:] = errors.tool.offset
    e.wp_t[:] = errors.workpiece.translation
    e.wp_a[:] = errors.workpiece.angles
    for k, a in enumerate(machine.axes):
        d, r = errors.geometric.location_of(a.name)
        e.loc[k][:] = [*d, *r]
    return e


# ------------------------------------------------------------------------------------ batch calls

#: Poses per chunk of a batch (mtk.h MTK_CHUNK) and poses solved again before a chunk so that it
#: starts with the path's state, the previous pose's correction (MTK_RUN_IN).
CHUNK = 4096
RUN_IN = 16


def threads() -> int:
    """Threads a long batch runs on: $MTCOMP_THREADS (a positive integer; anything else is
    ignored), else the CPUs this process may use."""
    env = os.environ.get("MTCOMP_THREADS", "").strip()
    if env.isdigit() and int(env) > 0:
        return min(int(env), 64)
    try:
        return max(1, min(len(os.sched_getaffinity(0)), 64))
    except AttributeError:  # not on Linux
        return max(1, min(os.cpu_count() or 1, 64))


def forward(lib, machine, q: np.ndarray, errors, strict: bool, orientation: bool = True):
    """(p (N,3), R (N,3,3) or None without `orientation`, first bad index or -1)."""
    q = np.ascontiguousarray(q, dtype=float)
    n = q.shape[0]
    p = np.empty((n, 3))
    R = np.empty((n, 3, 3)) if orientation else None
    m = model(lib, machine, errors)
    e = c_errors(machine, errors)
    bad_axis = ctypes.c_int(-1)
    bad = lib.mtk_forward_batch_mt(m.ptr, ctypes.byref(e), n, _p(q), _p(p), None if R is None else _p(R),
                                   int(strict), ctypes.byref(bad_axis), threads())
    return p, R, int(bad) if bad >= 0 else -1


def check(lib, machine, q_prog: np.ndarray, q_emit: np.ndarray, errors, strict: bool):
    """(before (N,), after (N,), first bad index or -1): the real tool edge's distance (mm) from the
    ideal one at q_prog, at q_prog and at q_emit (mtk_check_batch)."""
    q_prog = np.ascontiguousarray(q_prog, dtype=float)
    q_emit = np.ascontiguousarray(q_emit, dtype=float)
    n = q_prog.shape[0]
    before = np.empty(n)
    after = np.empty(n)
    m = model(lib, machine, errors)
    e = c_errors(machine, errors)
    bad_axis = ctypes.c_int(-1)
    bad = lib.mtk_check_batch_mt(m.ptr, ctypes.byref(e), n, _p(q_prog), _p(q_emit), _p(before), _p(after),
                                 int(strict), ctypes.byref(bad_axis), threads())
    return before, after, int(bad) if bad >= 0 else -1


def solve(lib, machine, errors, q0: np.ndarray, *, target=None, tol: float, max_iter: int,
          pole_tolerance: float, continuation: bool):
    """retarget (target None: the ideal poses of q0) or compensate in C, in chunks on threads.
    Returns (q, residual (N,), status (N,), info (N,))."""
    q0 = np.ascontiguousarray(q0, dtype=float)
    n = q0.shape[0]
    q = np.empty_like(q0)
    res = np.empty(n)
    status = np.empty(n, dtype=np.intc)
    info = np.empty(n, dtype=np.intc)
    m = model(lib, machine, errors)
    e = c_errors(machine, errors)
    opt = _Options(float(tol), int(max_iter), float(pole_tolerance), int(bool(continuation)), 0)
    if target is not None:
        tp = np.ascontiguousarray(target.p, dtype=float)
        tR = np.ascontiguousarray(target.R, dtype=float)
        pt, pR = _p(tp), _p(tR)
    else:
        pt = pR = None
    lib.mtk_compensate_batch_mt(m.ptr, ctypes.byref(e), n, pt, pR, _p(q0), _p(q), ctypes.byref(opt), _p(res),
                                status.ctypes.data_as(_I), info.ctypes.data_as(_I), threads())
    return q, res, status, info
