"""Provenance of a compensated program: a header comment that says what it was compensated
with, and the test that refuses to compensate such a program a second time."""
from __future__ import annotations

import re

#: First header line; its presence marks a program mtcomp has compensated.
MARKER = "MTCOMP COMPENSATED PROGRAM"
#: The cell's marker line (``(MTCOMP-CELL O1100 FROM O0100 PART ..)``, mtcomp.cell.program) is
#: its provenance header: a program carrying it is compensated too.
_MARK_RE = re.compile(r"MTCOMP COMPENSATED PROGRAM|\(MTCOMP-CELL O\d", re.IGNORECASE)
_MARK_RE_B = re.compile(rb"MTCOMP COMPENSATED PROGRAM|\(MTCOMP-CELL O\d", re.IGNORECASE)
_HEAD = 1 << 16
_PROGRAM_NUMBER_RE = re.compile(r"\s*[Oo]\d|\s*:\d")


def compensated_line(text: str | bytes, ascii: bool = False) -> int | None:
    """1-based line of the provenance marker if the program (its text, or its bytes: UTF-8)
    was written by mtcomp compensate.  ``ascii``: the bytes are known to be ASCII (not tested
    again)."""
    if not isinstance(text, str):
        if not (ascii or text.isascii()):
            # (any case, in Unicode's sense, as for the text)
            return compensated_line(bytes(text).decode("utf-8", "surrogateescape"))
        rx, marker = _MARK_RE_B, MARKER.encode()
        nl = b"\n"
    else:
        rx, marker, nl = _MARK_RE, MARKER, "\n"
    # mtcomp writes the header at the top: any case there; further down (a header pasted into
    # a longer program) the marker as written or all lower case, found by plain substring
    # search (a case-insensitive regex over a 40 MB program costs a third of a second)
    m = rx.search(text, 0, _HEAD)
    if m is not None:
        at = m.start()
    else:
        hits = [i for i in (text.find(marker, max(0, _HEAD - len(marker))),
                            text.find(marker.lower(), max(0, _HEAD - len(marker)))) if i >= 0]
        if not hits:
            return None
        at = min(hits)
    return text.count(nl, 0, at) + 1


def header_lines(items: list[tuple[str, str]]) -> list[str]:
    """Header text lines (without comment delimiters): the marker, then ``KEY value`` items.
    Parentheses in values become brackets (a comment cannot contain them)."""
    out = [f"{MARKER}: DO NOT COMPENSATE AGAIN"]
    for key, value in items:
        out.append(f"{key} {value}".replace("(", "[").replace(")", "]").replace("\n", " "))
    return out


def insert_header(text: str, lines: list[str]) -> tuple[str, int, int]:
    """Insert ``lines`` as comments near the top of the program: after a leading ``%`` line and
    after the program number line (``O1234``), where controls expect those, in the program's
    comment style (``( )``, or ``;`` when the program writes only ``;`` comments) and line
    ending.  Returns (new text, 0-based line index where the header starts, lines added)."""
    new, at, added, _ = _place_header(text, lines, ";" in text and "(" not in text)
    return new, at, added


def insert_header_bytes(buf: bytearray, lines: list[str]) -> tuple[int, int]:
    """`insert_header` into the program's bytes (UTF-8, undecodable bytes kept), in place:
    only the first lines are decoded, so a large program is not copied as text.  Returns (0-based
    line index where the header starts, lines added)."""
    head_end = buf.find(b"\n", min(len(buf), 1 << 16))
    head_end = len(buf) if head_end < 0 else head_end + 1
    head = bytes(buf[:head_end]).decode("utf-8", "surrogateescape")
    semicolon = buf.find(b";") >= 0 and buf.find(b"(") < 0
    _, at, added, (cut, block) = _place_header(head, lines, semicolon)
    if cut >= len(head) and head_end < len(buf):
        # the leading lines fill the first 64 kB: place the header on the whole text
        text = bytes(buf).decode("utf-8", "surrogateescape")
        _, at, added, (cut, block) = _place_header(text, lines, semicolon)
        head = text
    at_b = len(head[:cut].encode("utf-8", "surrogateescape"))
    buf[at_b:at_b] = block.encode("utf-8", "surrogateescape")
    return at, added


def _place_header(text: str, lines: list[str], semicolon: bool):
    """insert_header's work: (new text, line index, lines added, (character offset, header
    text))."""
    first = text.split("\n", 1)[0]
    eol = "\r\n" if first.endswith("\r") else "\n"
    comments = [f"; {ln}" if semicolon else f"({ln})" for ln in lines]
    # only the first lines are looked at: no split of a whole (possibly huge) program
    n = len(text)

    def line(cut):                                     # the LF-terminated line at `cut`
        j = text.find("\n", cut)
        return text[cut:] if j < 0 else text[cut:j + 1]
    at = last = 0
    # a byte-order mark stays the first character of the file (the header after it: a mark
    # in the middle of a program is a stray character to a control, and no longer a mark)
    cut = 1 if text.startswith("\ufeff") else 0
    while cut < n and not line(cut).strip():
        last = len(line(cut))
        cut += last
        at += 1
    if cut < n and line(cut).strip().startswith("%"):
        last = len(line(cut))
        cut += last
        at += 1
    if cut < n and _PROGRAM_NUMBER_RE.match(line(cut)):
        last = len(line(cut))
        cut += last
        at += 1
    if at and text[cut - 1] != "\n":
        # the program ends on that line without a line break: the header goes before it, so
        # that strip_header gives the program back byte for byte (no line break is added)
        cut -= last
        at -= 1
    block = "".join(c + eol for c in comments)
    return (text[:cut] + block + text[cut:] if text else block), at, len(comments), (cut, block)


# (matched at a position: no "^", which would not match after a byte-order mark)
_HEADER_LINE_RE = re.compile(r"(\(|; )([A-Z0-9]+ |MTCOMP COMPENSATED PROGRAM)[^\n]*\n")


def strip_header(text: str) -> str:
    """The program without mtcomp's provenance header (to compare a compensated program with
    its source, or to compensate the source again)."""
    at = compensated_line(text)
    if at is None:
        return text
    start = 1 if text.startswith("\ufeff") else 0      # (the header follows a byte-order mark)
    for _ in range(at - 1):
        start = text.index("\n", start) + 1
    end = start
    while True:
        m = _HEADER_LINE_RE.match(text, end)
        if m is None or (end > start and m.group(2).strip() not in _KEYS):
            break
        end = m.end()
    return text[:start] + text[end:]


_KEYS = {"VERSION", "ERRORS", "MACHINE", "DATE", "SOURCE", "OPTIONS"}


# ------------------------------------------------------------------- the rule for every writer
def check_nc_write(text: str | bytes | None = None, *, filename: str = "<string>",
                   output=None, inputs=(), force: bool = False, what: str = "compensate") -> None:
    """The one provenance rule for every command that writes an NC program (compensate,
    workpiece-setting compensate, geometric table --program, model compensate, the CAM post,
    the cell): refuse, before any work, (a) an output path that is one of the inputs (the
    source would be overwritten: no ``--force`` lifts this) and (b) a source program that
    carries mtcomp's provenance header, unless ``force`` (its errors would be applied twice).

    text: the source program (text or bytes; None: no source program, only the paths checked).
    output / inputs: paths (None entries ignored).  Raises InputError naming the file (and the
    header's line)."""
    from .._io import InputError
    if output is not None:
        out = _canonical(output)
        for src in inputs:
            if src is not None and _canonical(src) == out:
                raise InputError("the output is the input: writing it would overwrite the source "
                                 "program; give another output file", str(output), field="-o")
    if text is None or force:
        return
    done = compensated_line(text)
    if done is not None:
        raise InputError(f"this program was already compensated by mtcomp (provenance header); "
                         f"to {what} it would apply errors on top of the ones it was "
                         f"compensated for: use the original program, or --force", filename, done)


def _canonical(path):
    """A path as the file system resolves it (symbolic links, '..', a second name of the same
    file by hard link: device and inode)."""
    import os
    p = os.path.realpath(os.fspath(path))
    try:
        st = os.stat(p)
        return ("inode", st.st_dev, st.st_ino)
    except OSError:
        return ("path", os.path.normcase(p))


def stamp(text: str, items: list[tuple[str, str]]) -> str:
    """``text`` with mtcomp's provenance header (`header_lines` of ``items``) inserted where
    controls expect comments (`insert_header`)."""
    return insert_header(text, header_lines(items))[0]


def writer_items(command: str, *, errors=None, machine: str | None = None, source=None,
                 options: str = "") -> list[tuple[str, str]]:
    """The header items every writer of NC gives (`stamp`): mtcomp's version and the
    command, the errors file with its SHA-256, the machine, the date (UTC), the source program
    and the options."""
    import hashlib
    from datetime import datetime, timezone
    from pathlib import Path
    from .. import __version__
    items = [("VERSION", f"mtcomp {__version__} {command}")]
    if errors is not None:
        h = hashlib.sha256(Path(errors).read_bytes()).hexdigest()
        items.append(("ERRORS", f"{Path(errors).name} SHA256 {h}"))
    if machine:
        items.append(("MACHINE", machine))
    items.append(("DATE", datetime.now(timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ")))
    if source is not None:
        items.append(("SOURCE", Path(source).name))
    if options:
        items.append(("OPTIONS", options))
    return items
