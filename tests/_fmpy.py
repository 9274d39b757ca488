"""Fixtures shared by the FMU test modules (imported into each: autouse there)."""
from __future__ import annotations

import os
from pathlib import Path

import pytest


@pytest.fixture(autouse=True)
def live_fmpy_logger():
    """fmpy's default callbacks go through a C proxy to the Python logger registered last, by
    any `simulate_fmu(logger=...)`; that logger dies when the call returns, and the next FMU that
    logs through the defaults crashes the process (fmpy 0.3.32).  Point the proxy at a logger that
    lives as long as the process, before and after every test of the importing module."""
    import fmpy
    from ctypes import byref
    from fmpy.fmi2 import fmi2CallbackFunctions, fmi2CallbackLoggerTYPE
    from fmpy.logging import addLoggerProxy
    if not hasattr(fmpy, "_mtcomp_test_logger"):
        fmpy._mtcomp_test_logger = fmi2CallbackLoggerTYPE(lambda env, name, status, category, message: None)

    def arm():   # a fresh struct each time: the proxy replaces the struct's logger by itself
        cb = fmi2CallbackFunctions()
        cb.logger = fmpy._mtcomp_test_logger
        addLoggerProxy(byref(cb))
        fmpy._mtcomp_test_callbacks = cb

    arm()
    yield
    arm()


@pytest.fixture(scope="module", autouse=True)
def binary_cache(tmp_path_factory):
    """A compiled-binary cache of the importing module only: each distinct source set is compiled
    once there (so the compilers are really exercised) and reused by its other builds."""
    old = os.environ.get("MTCOMP_CACHE_DIR")
    os.environ["MTCOMP_CACHE_DIR"] = str(tmp_path_factory.mktemp("cache"))
    yield Path(os.environ["MTCOMP_CACHE_DIR"])
    if old is None:
        os.environ.pop("MTCOMP_CACHE_DIR", None)
    else:
        os.environ["MTCOMP_CACHE_DIR"] = old
