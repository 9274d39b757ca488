"""Shared input/output helpers: errors that name the file, line or field, and atomic writes."""
from __future__ import annotations

import os
import tempfile
from contextlib import contextmanager
from pathlib import Path


class MtcompError(Exception):
    """Base class of every error mtcomp reports to a user (the CLI exits non-zero with its text)."""


class InputError(MtcompError, ValueError):
    """Bad input: the message names the file and line or field, and what was expected."""

    def __init__(self, what: str, file: str | os.PathLike | None = None, line: int | None = None,
                 field: str | None = None):
        self.what, self.file, self.line, self.field = what, file, line, field
        where = ""
        if file is not None:
            where = str(file)
            if line is not None:
                where += f":{line}"
        if field is not None:
            where = f"{where} [{field}]" if where else f"[{field}]"
        super().__init__(f"{where}: {what}" if where else what)


@contextmanager
def atomic_path(path: str | os.PathLike):
    """Yield a temporary path next to `path`; rename it onto `path` only if the block succeeds.

    Nothing is left behind on failure, so a crash never leaves a half-written output.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    os.close(fd)
    try:
        yield Path(tmp)
        # mkstemp creates 0600; give the output the permissions a plain open() would.
        mask = os.umask(0)
        os.umask(mask)
        os.chmod(tmp, 0o666 & ~mask)
        os.replace(tmp, path)
    except BaseException:
        try:
            os.unlink(tmp)
        except FileNotFoundError:
            pass
        raise


def atomic_write(path: str | os.PathLike, data: str | bytes) -> Path:
    """Write text or bytes to `path` atomically (temp file in the same directory, fsync, rename)."""
    with atomic_path(path) as tmp:
        mode = "wb" if isinstance(data, bytes) else "w"
        kw = {} if isinstance(data, bytes) else {"encoding": "utf-8", "newline": ""}
        with open(tmp, mode, **kw) as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())
    return Path(path)


def read_text(path: str | os.PathLike, *, newline: str | None = None, what: str = "file") -> str:
    """Read a UTF-8 text file; a missing or binary file becomes an InputError naming it.
    newline="" keeps CR LF line endings byte for byte."""
    try:
        with open(path, encoding="utf-8", newline=newline) as fh:
            return fh.read()
    except FileNotFoundError:
        raise InputError(f"{what} not found", path) from None
    except IsADirectoryError:
        raise InputError(f"{what} is a directory", path) from None
    except UnicodeDecodeError as exc:
        raise InputError(f"not a text file ({exc.reason} at byte {exc.start})", path) from None


def save_figure(fig, path: str | os.PathLike, dpi: int | None = None) -> Path:
    """Write a matplotlib figure as PNG atomically.  A `matplotlib.figure.Figure` renders with
    the Agg canvas whatever the session's backend; pyplot is neither imported nor switched, and a
    figure that pyplot manages is closed there (so a notebook does not show it twice)."""
    import sys
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png", **({} if dpi is None else {"dpi": dpi}))
    plt = sys.modules.get("matplotlib.pyplot")
    if plt is not None and getattr(fig.canvas, "manager", None) is not None:
        plt.close(fig)
    return Path(path)


def load_toml(path: str | os.PathLike) -> dict:
    """Read a TOML file; a syntax error becomes an InputError naming the file and line."""
    try:
        import tomllib
    except ModuleNotFoundError:  # Python 3.10
        import tomli as tomllib
    path = Path(path)
    text = read_text(path)
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        import re
        line = getattr(exc, "lineno", None)  # Python >= 3.14 only; older: parse the message
        if line is None:
            m = re.search(r"\(at line (\d+)", str(exc))
            line = int(m.group(1)) if m else None
        raise InputError(f"invalid TOML: {exc}", path, line) from None


def dump_toml(data: dict) -> str:
    import tomli_w
    return tomli_w.dumps(data)
