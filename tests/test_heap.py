"""mtcomp._heap: the CLI sets the process's allocator up for one large job (freed arrays reused,
no huge-page advice on numpy arrays); importing the library leaves its host process alone."""
from __future__ import annotations

import os
import platform
import subprocess
import sys

import pytest


def _run(code: str) -> list[str]:
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120,
                       env={k: v for k, v in os.environ.items() if k != "NUMPY_MADVISE_HUGEPAGE"})
    assert r.returncode == 0, r.stderr
    return r.stdout.split()


def _hp():
    return ("import numpy as np; s = getattr(np, '_core', None) or np.core; "
            "f = s.multiarray._set_madvise_hugepage; old = f(True); ")


def test_library_import_leaves_the_process_settings_alone():
    bare = _run(_hp() + "print(old)")
    out = _run("import mtcomp, mtcomp.commands, mtcomp.gcode; from mtcomp import _heap; "
               + _hp() + "print(old, bool(_heap._state))")
    assert out == [bare[0], "False"]


def test_cli_command_applies_the_settings_once():
    out = _run("from mtcomp import cli, _heap; cli.main(['machines']); " + _hp()
               + "print(old, _heap._state['huge_pages_off'], _heap._state['heap_reuse'], _heap.tune() == _heap._state)")
    assert out[-4] == "False" and out[-3] == "True" and out[-1] == "True"
    if sys.platform.startswith("linux") and platform.libc_ver()[0] == "glibc":
        assert out[-2] == "True"
