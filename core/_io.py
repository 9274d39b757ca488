"""Shared input/output helpers: errors that name the file, line or field, and atomic writes."""
from __future__ import annotations

import errno
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
    import stat
    path = Path(path)
    if path.is_dir():  # say so by its name, not by the temporary file's
        raise IsADirectoryError(errno.EISDIR, "Is a directory", str(path))
    try:
        mode = os.stat(path).st_mode
    except (FileNotFoundError, NotADirectoryError):
        mode = None
    if mode is not None and not stat.S_ISREG(mode):
        # the rename would replace the node itself: run as root, `-o /dev/zero` turned the
        # machine's /dev/zero into a text file
        raise InputError("output exists and is not a regular file (a device, pipe or socket): "
                         "expected a file path", path)
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


def atomic_write(path: str | os.PathLike, data: str | bytes | bytearray | memoryview) -> Path:
    """Write text (UTF-8) or bytes (any bytes-like object) to `path` atomically (temp file in
    the same directory, fsync, rename)."""
    binary = not isinstance(data, str)
    with atomic_path(path) as tmp:
        mode = "wb" if binary else "w"
        kw = {} if binary else {"encoding": "utf-8", "newline": ""}
        with open(tmp, mode, **kw) as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())
    return Path(path)


# Text inputs larger than this are refused before they exhaust memory (bytes; an NC program of
# ten million blocks is about 300 MB).
MAX_TEXT_BYTES = 2 << 30


def read_bytes(path: str | os.PathLike, *, what: str = "file", max_bytes: int | None = None) -> bytes:
    """The bytes of a text file; a missing, binary (a NUL byte), oversized or device file
    becomes an InputError naming it."""
    import stat
    limit = MAX_TEXT_BYTES if max_bytes is None else int(max_bytes)
    try:
        st = os.stat(path)
        if stat.S_ISDIR(st.st_mode):
            raise InputError(f"{what} is a directory", path)
        if stat.S_ISCHR(st.st_mode) or stat.S_ISBLK(st.st_mode) or stat.S_ISSOCK(st.st_mode):
            # /dev/zero never ends, a terminal waits for typing: neither is an input file
            raise InputError(f"{what} is a device, not a regular file", path)
        chunks, size = [], 0
        with open(path, "rb") as fh:
            # a regular file in one read (no copy to join chunks), a pipe in chunks
            first = min(st.st_size, limit) + 1 if stat.S_ISREG(st.st_mode) else 1 << 20
            while True:
                chunk = fh.read(first)
                first = 1 << 20
                if not chunk:
                    break
                nul = chunk.find(b"\0")
                if nul >= 0:
                    raise InputError(f"not a text file (NUL byte at byte {size + nul})", path)
                size += len(chunk)
                if size > limit:
                    raise InputError(f"{what} is larger than {limit / 2**20:.0f} MiB", path)
                chunks.append(chunk)
    except FileNotFoundError:
        raise InputError(f"{what} not found", path) from None
    except IsADirectoryError:
        raise InputError(f"{what} is a directory", path) from None
    except PermissionError:
        raise InputError(f"{what} cannot be read (permission denied)", path) from None
    except NotADirectoryError:
        raise InputError(f"{what} not found (a part of the path is a file)", path) from None
    return chunks[0] if len(chunks) == 1 else b"".join(chunks)


def decode_text(data: bytes, path, encoding: str = "utf-8") -> str:
    """`data` decoded; bytes that are not `encoding` become an InputError naming `path` and the
    byte."""
    try:
        return data.decode(encoding)
    except UnicodeDecodeError as exc:
        raise InputError(f"not a text file (not UTF-8: {exc.reason} at byte {exc.start})", path) from None


def read_text(path: str | os.PathLike, *, newline: str | None = None, what: str = "file",
              encoding: str = "utf-8", max_bytes: int | None = None) -> str:
    """Read a UTF-8 text file; a missing, binary, oversized or device file becomes an InputError
    naming it.  newline="" keeps CR LF line endings byte for byte; newline=None turns CR LF and
    CR into LF (as `open` does).  encoding="utf-8-sig" drops a byte-order mark."""
    text = decode_text(read_bytes(path, what=what, max_bytes=max_bytes), path, encoding)
    if newline is None:
        text = text.replace("\r\n", "\n").replace("\r", "\n")
    return text


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


def load_toml(path: str | os.PathLike, *, what: str = "file") -> dict:
    """Read a TOML file; a syntax error becomes an InputError naming the file and line."""
    return parse_toml(read_text(Path(path), what=what), path)


def load_toml_as(path: str | os.PathLike, build, *, what: str = "file"):
    """Read a TOML file and build an object from it with ``build(data, path)``; an InputError
    of `build` that names a field but no line gets the field's line in the file.  The one way
    for a reader of a set-up file to report ``file:line [field]: what was expected``."""
    text = read_text(Path(path), what=what)
    try:
        return build(parse_toml(text, path), path)
    except InputError as exc:
        if exc.file is not None and str(exc.file) != str(path):
            raise  # about another file (a table the TOML names): already located
        raise locate_field(InputError(exc.what, path, exc.line, exc.field), text) from None


def parse_toml(text: str, path: str | os.PathLike = "<string>") -> dict:
    """Parse TOML text; a syntax error becomes an InputError naming `path` and the line."""
    try:
        import tomllib
    except ModuleNotFoundError:  # Python 3.10
        import tomli as tomllib
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        import re
        line = getattr(exc, "lineno", None)  # Python >= 3.14 only; older: parse the message
        if line is None:
            m = re.search(r"\(at line (\d+)", str(exc))
            line = int(m.group(1)) if m else None
        raise InputError(f"invalid TOML: {exc}", path, line) from None
    except RecursionError:  # thousands of nested arrays
        raise InputError("invalid TOML: nested too deeply", path) from None


def toml_lines(text: str) -> dict[str, int]:
    """Line (1-based) of every key and table header of a TOML text, by dotted path with array
    indices, e.g. ``axis[2].resolution`` -> 31, ``geometric.location.EC0Y`` -> 12.

    TOML parsers give values without positions; this light scanner lets an error about a field
    name its line.  It reads header lines and ``key =`` lines only (no multi-line strings or
    arrays), which is what hand-written set-up files contain; a field it cannot place has no line.
    """
    import re
    key_re = r'(?:[A-Za-z0-9_-]+|"[^"]*"|\'[^\']*\')'
    dotted = rf"{key_re}(?:\s*\.\s*{key_re})*"
    head_re = re.compile(rf"^\s*(\[\[?)\s*({dotted})\s*\]\]?\s*(?:#.*)?$")
    assign_re = re.compile(rf"^\s*({dotted})\s*=")

    def parts(k):
        return [p.strip().strip("'\"") for p in re.findall(key_re, k)]

    out: dict[str, int] = {}
    counts: dict[str, int] = {}
    prefix = ""
    for n, line in enumerate(text.split("\n"), 1):
        m = head_re.match(line)
        if m:
            name = ".".join(parts(m.group(2)))
            if m.group(1) == "[[":
                counts[name] = counts.get(name, -1) + 1
                prefix = f"{name}[{counts[name]}]"
            else:
                prefix = name
            out.setdefault(prefix, n)
            continue
        m = assign_re.match(line)
        if m:
            key = ".".join(parts(m.group(1)))
            out.setdefault(f"{prefix}.{key}" if prefix else key, n)
    return out


def locate_field(exc: "InputError", text: str) -> "InputError":
    """The same error with the line of its field filled in from the TOML text (when found)."""
    if exc.line is not None or not exc.field:
        return exc
    lines = toml_lines(text)
    f = exc.field
    while f:  # the field itself, else the nearest enclosing key or table that has a line
        if f in lines:
            return InputError(exc.what, exc.file, lines[f], exc.field)
        f = f[:f.rindex("[")] if f.endswith("]") else f.rpartition(".")[0]
    return exc


def dump_toml(data: dict) -> str:
    """TOML text of `data`; arrays of numbers or short strings on one line (`[0.0, 0.0, 1.0]`),
    as people write them, where tomli_w puts every element on a line of its own."""
    import re
    import tomli_w
    text = tomli_w.dumps(data)

    def inline(m):
        items = [ln.strip()[:-1] for ln in m.group(2).split("\n") if ln.strip()]
        one = f"{m.group(1)}[{', '.join(items)}]"
        return one if len(one) - one.rfind("\n") <= 100 else m.group(0)
    # an array whose element lines hold no brackets, braces or quotes-with-commas: scalars only
    short = re.sub(r"(= |^ +)\[\n((?: +[^\[\]{}\n\"']+,\n)+) *\]", inline, text, flags=re.M)
    if short != text and parse_toml(short) != parse_toml(text):  # never change a value
        return text
    return short
