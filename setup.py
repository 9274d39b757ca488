"""Build hook: compile the kinematic kernel (fmu/c/mtk.c) into a plain shared library next to
mtcomp._kernel, and the G-code tokenizer and formatter (core/gcode/_tok.c) next to
mtcomp.gcode._ctok, at install time, with the C compiler the FMUs need anyway ($CC, cc or gcc).
Without a compiler the install goes on: the library is then built on first use into the per-user
cache, or mtcomp runs its numpy implementation (core/_kernel.py).  Metadata: pyproject.toml."""
import hashlib
import os
import shutil
import subprocess
import sysconfig
from pathlib import Path

from setuptools import setup
from setuptools.command.build_py import build_py

# Must match core/_kernel.py (CFLAGS, SOURCES, source_hash, library_name); tests/test_kernel.py checks it.
CFLAGS = ("-O3", "-fno-math-errno", "-std=c99", "-fPIC", "-shared", "-DMTK_THREADS", "-pthread")
SOURCES = ("mtk.h", "mtk.c", "mtk_threads.c", "cosim_loop.c")
SRC = Path(__file__).resolve().parent / "fmu" / "c"


# Must match core/gcode/_ctok.py (CFLAGS, packaged_name); tests/test_gcode_tokenizer.py checks it.
TOK_CFLAGS = ("-O3", "-std=c99", "-fPIC", "-shared")
TOK_SRC = Path(__file__).resolve().parent / "core" / "gcode" / "_tok.c"


def tok_name() -> str:
    h = hashlib.sha256(TOK_SRC.read_bytes() + " ".join(TOK_CFLAGS).encode()).hexdigest()[:16]
    return f"libmtctok-{h}{sysconfig.get_config_var('SHLIB_SUFFIX') or '.so'}"


def kernel_name() -> str:
    h = hashlib.sha256()
    for name in SOURCES:
        h.update((SRC / name).read_bytes())
    h.update(" ".join(CFLAGS).encode())
    return f"libmtk-{h.hexdigest()[:16]}{sysconfig.get_config_var('SHLIB_SUFFIX') or '.so'}"


class BuildWithKernel(build_py):
    def run(self):
        super().run()
        cc = os.environ.get("CC", "").split()[:1] or [shutil.which("cc") or shutil.which("gcc") or ""]
        if not cc[0] or getattr(self, "editable_mode", False):
            return  # editable installs build on first use into the cache
        out = Path(self.build_lib) / "mtcomp" / kernel_name()
        out.parent.mkdir(parents=True, exist_ok=True)
        run = subprocess.run([cc[0], *CFLAGS, *(str(SRC / f) for f in SOURCES if f.endswith(".c")), "-o", str(out), "-lm"],
                             capture_output=True, text=True)
        if run.returncode:
            print(f"mtcomp: the kinematic kernel was not compiled ({run.stderr.strip()[:200]}); "
                  "it is built on first use or the numpy implementation runs")
        tok = Path(self.build_lib) / "mtcomp" / "gcode" / tok_name()
        tok.parent.mkdir(parents=True, exist_ok=True)
        run = subprocess.run([cc[0], *TOK_CFLAGS, str(TOK_SRC), "-o", str(tok)], capture_output=True, text=True)
        if run.returncode:
            print(f"mtcomp: the G-code tokenizer was not compiled ({run.stderr.strip()[:200]}); "
                  "it is built on first use or the numpy tokenizer runs")


try:   # setuptools >= 70.1 has bdist_wheel; older ones take it from the wheel package
    from setuptools.command.bdist_wheel import bdist_wheel
except ImportError:  # pragma: no cover
    from wheel.bdist_wheel import bdist_wheel


class PlatformWheel(bdist_wheel):
    """The wheel carries the compiled kernel and tokenizer (ELF on Linux) when a compiler was
    found: tag it for this platform, not py3-none-any.  They are loaded with ctypes, so they
    depend on no Python ABI: py3-none-<platform>.  Without them (no compiler) the wheel is pure."""

    def finalize_options(self):
        super().finalize_options()
        self.root_is_pure = False

    def get_tag(self):
        _, _, plat = super().get_tag()
        return "py3", "none", plat


setup(cmdclass={"build_py": BuildWithKernel, "bdist_wheel": PlatformWheel})
