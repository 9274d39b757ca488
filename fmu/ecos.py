"""The ecos co-simulation engine (PyPI `ecospy`) made usable from a plain pip install.

ecospy 0.7 ships `libecosc.so` and the `ecos` / `proxyfmu` executables, but:

* `libecosc.so` needs `libtbb.so.12` and finds it only on the system library path; the pip
  `tbb` wheel (a dependency of mtcomp's `[ecos]` extra) puts it in `<prefix>/lib`, which the
  loader does not search, so `import ecospy` fails with "libtbb.so.12: cannot open shared
  object file" (upstream; a process cannot change its own LD_LIBRARY_PATH);
* the wheel's executables lack the exec bit.

`load_ecospy()` loads the wheel's libtbb first (RTLD_GLOBAL: the soname is then satisfied for
libecosc) and imports ecospy; `ecos_command()` returns an executable copy of `ecos` (in the
mtcomp cache; site-packages may be read-only) and the environment that lets it find libtbb.
Written by hand: ecospy has no hook for either (checked against ecospy 0.7.2).
"""
from __future__ import annotations

import ctypes
import os
import shutil
import sys
from pathlib import Path

from .._io import MtcompError

__all__ = ["EcosUnavailable", "tbb_library_dir", "load_ecospy", "ecos_command"]


class EcosUnavailable(MtcompError):
    """ecospy, its binaries for this platform or libtbb are not installed."""


def tbb_library_dir() -> Path | None:
    """Folder holding libtbb.so.12: from the pip `tbb` distribution's file list, else
    `<prefix>/lib`; None when neither has it (then the system library path must)."""
    import importlib.metadata as md
    try:
        dist = md.distribution("tbb")
        for f in dist.files or ():
            if Path(str(f)).name.startswith("libtbb.so.12"):
                return Path(dist.locate_file(f)).resolve().parent
    except md.PackageNotFoundError:
        pass
    lib = Path(sys.prefix) / "lib"
    return lib if any(lib.glob("libtbb.so.12*")) else None


def _preload_tbb() -> None:
    if sys.platform != "linux":
        return
    d = tbb_library_dir()
    if d is None:
        return   # maybe on the system path (Debian libtbb12); the import says if not
    try:
        ctypes.CDLL(str(d / "libtbb.so.12"), mode=ctypes.RTLD_GLOBAL)
    except OSError as exc:
        raise EcosUnavailable(f"cannot load {d / 'libtbb.so.12'}: {exc}") from None


def load_ecospy():
    """Import and return the `ecospy` module, loading libtbb from the pip `tbb` wheel first."""
    if "ecospy" in sys.modules:
        return sys.modules["ecospy"]
    _preload_tbb()
    try:
        import ecospy
    except ImportError as exc:
        raise EcosUnavailable(f"ecospy is not usable: {exc} (pip install 'mtcomp[ecos]')") from None
    except OSError as exc:
        raise EcosUnavailable(f"ecospy cannot load its library: {exc} (pip install tbb, or the "
                              "system's libtbb12)") from None
    return ecospy


def _binaries() -> Path:
    import importlib.util
    spec = importlib.util.find_spec("ecospy")   # found without importing (its import loads libtbb)
    if spec is None or not spec.submodule_search_locations:
        raise EcosUnavailable("ecospy is not installed (pip install 'mtcomp[ecos]')")
    return Path(list(spec.submodule_search_locations)[0]) / "binaries"


def ecos_command(workdir: str | os.PathLike | None = None) -> tuple[Path, dict]:
    """(path of an executable `ecos`, environment to run it with).

    The wheel's `ecos`, `proxyfmu` and `libecosc.so` are copied once into `workdir` (default:
    the mtcomp cache folder, `ecos-<version>`) with the exec bit set; the environment adds the
    tbb library folder to LD_LIBRARY_PATH."""
    if sys.platform != "linux":
        raise EcosUnavailable("the ecos executable is driven from here on Linux only")
    src = _binaries()
    if not (src / "ecos").exists():
        raise EcosUnavailable(f"ecospy ships no Linux ecos executable in {src}")
    if workdir is None:
        import importlib.metadata as md
        from .build import cache_dir
        base = cache_dir()
        if base is None:
            raise EcosUnavailable("the mtcomp cache is off (MTCOMP_CACHE_DIR=off): give a workdir")
        workdir = base.parent / f"ecos-{md.version('ecospy')}"
    dst = Path(workdir)
    dst.mkdir(parents=True, exist_ok=True)
    for name in ("ecos", "proxyfmu", "libecosc.so"):
        f, out = src / name, dst / name
        if f.exists() and (not out.exists() or out.stat().st_size != f.stat().st_size):
            tmp = dst / f".{name}.tmp{os.getpid()}"
            shutil.copyfile(f, tmp)
            tmp.chmod(0o755)
            os.replace(tmp, out)
    env = dict(os.environ)
    d = tbb_library_dir()
    if d is not None:
        env["LD_LIBRARY_PATH"] = os.pathsep.join(p for p in (str(d), env.get("LD_LIBRARY_PATH", "")) if p)
    return dst / "ecos", env
