"""Program flow: subprogram calls followed by expanding them into the order a control runs them.

Fanuc ``M98 P<n>`` calls the program ``O<n>`` (in a file sent to the control: an O-numbered
block after the main program's M30/M02, ending in ``M99``); Haas ``M97 P<n>`` calls the local
subprogram starting at the block numbered ``N<n>`` of the same program, also ending in ``M99``.
Both take a fixed repeat count ``L`` (or ``K``); Fanuc's 8-digit ``P`` (``P30100``: 3 times
``O0100``) is read too.  A call block's own motion runs before the call, as on the controls.

`expand` writes the program as it runs (main program with each call replaced by the called
blocks; the flow words inside comments so that the reader passes them) with the source line of
every line; `fold` takes the rewritten expansion back to the file's structure when every run of
each subprogram block was rewritten to the same text (the errors are a rigid shift along the
calls: the subprogram body is compensated once), or else returns the expansion itself, calls
written out (docs/gcode.md, "Subprograms").  This is hand-written: no maintained library reads
Fanuc/Haas program flow.
"""
from __future__ import annotations

import bisect
import re
from dataclasses import dataclass

import numpy as np

from .._io import InputError

#: nesting levels followed (Fanuc allows 4 on older and 10 on newer controls)
MAX_DEPTH = 10
#: largest expansion (lines) written
MAX_LINES = 5_000_000

_HAS_FLOW = re.compile(r"[Mm][ \t]*0*9[789](?![0-9.])|[Oo][ \t]*(?:<[^>\n]*>|\d+)[ \t]*[Cc][Aa][Ll][Ll]")
#: LinuxCNC o-word lines: o<name> or o<number>, then the keyword and the rest
_OWORD = re.compile(r"^[ \t]*(?:[Nn][ \t]*\d+[ \t]*)?([Oo][ \t]*(?:<([^>\n]*)>|(\d+))[ \t]*([A-Za-z]+))(.*)$")
_WORD = re.compile(r"([A-Za-z])[ \t]*([-+]?(?:\d+\.?\d*|\.\d+))")
_COMMENT = re.compile(r"\([^)]*\)")
_MARK = "(\x02"
_MARKED = re.compile(r"\(\x02([^)]*)\)")
#: flow words the reader passes but the output keeps as written (a main program's final M99)
_KEEP = "(\x03"
_KEPT = re.compile(r"\(\x03([^)]*)\)")


@dataclass(frozen=True, eq=False)
class Flow:
    """A program with subprogram calls, expanded.  ``expanded``: the text in the order it runs
    (flow words in marker comments); ``origin`` (n,) 0-based source line of each expanded line;
    ``caller`` (n,) 0-based line of the outermost call that ran it (-1 in the main program);
    ``added_nl`` (n,) whether a line ending was added (the file's last line has none);
    ``calls`` the number of subprogram runs."""
    text: str
    expanded: str
    origin: np.ndarray
    caller: np.ndarray
    added_nl: np.ndarray
    calls: int
    trailer: str
    #: (first line index in ``text``, file name) of every file the expansion read: the program
    #: and, appended after it, the subprogram files it calls
    segments: tuple = ()
    main_lines: int = 0
    #: a main program ending in M99 (the control repeats it): ``expanded`` holds two runs, the
    #: first ``loop_len`` lines long; ``loop_line`` the M99's 0-based line (-1: no such M99)
    loop_len: int = 0
    loop_line: int = -1

    @property
    def external(self) -> bool:
        """Whether subprograms from other files were followed (the output then holds them
        written out: the control would run its own, uncompensated copies)."""
        return len(self.segments) > 1

    def where(self, origin: int) -> tuple[str, int]:
        """(file name, 1-based line) of a line index of ``text``."""
        k = bisect.bisect_right([s for s, _ in self.segments], origin) - 1
        start, name = self.segments[max(k, 0)]
        return name, origin - start + 1


def _lines(text):
    return re.findall(r"[^\n]*\n|[^\n]+\Z", text)


def _words(line):
    code = _COMMENT.sub(lambda m: " " * len(m.group()), line)
    i = code.find(";")
    if i >= 0:
        code = code[:i]
    return [(m.group(1).upper(), float(m.group(2)), m.start(), m.end()) for m in _WORD.finditer(code)]


def _mark(line, spans, mark=_MARK):
    for s, e in sorted(spans, reverse=True):
        line = line[:s] + mark + line[s:e] + ")" + line[e:]
    return line


def has_flow(text: str | bytes, ascii: bool = False) -> bool:
    """Whether the text (or its bytes, UTF-8; ``ascii``: known to be ASCII) has M97/M98/M99
    words or o-word calls (possibly only in comments: a quick test); the same answer as
    ``_HAS_FLOW.search(text)``."""
    # every match starts at an M or an O: str.find jumps to those letters and the pattern is
    # tried there only (a regex search steps through every character: 40x slower on long
    # programs); past _FIND_HITS letters the plain search takes over, so the worst case stays
    # the regex's
    from . import _ctok
    got = _ctok.has_flow(text, ascii)      # compiled: one pass over an ASCII text's bytes
    if got is not None:
        return got
    if not isinstance(text, str):
        text = bytes(text).decode("utf-8", "surrogateescape")
    hits = 0
    for c in "MmOo":
        i = text.find(c)
        while i >= 0:
            if _HAS_FLOW.match(text, i):
                return True
            hits += 1
            if hits > _FIND_HITS:
                return _HAS_FLOW.search(text) is not None
            i = text.find(c, i + 1)
    return False


_FIND_HITS = 20000


def _find_file(pattern: str, dirs, exclude) -> list:
    """Files in ``dirs`` (in order; the first directory with a match wins) whose name matches
    the regular expression ``pattern`` (case-insensitive)."""
    import os
    rx = re.compile(pattern, re.IGNORECASE)
    for d in dirs:
        try:
            names = sorted(os.listdir(d))
        except OSError:
            continue
        hits = [os.path.join(d, n) for n in names if rx.fullmatch(n)
                and os.path.isfile(os.path.join(d, n))
                and os.path.abspath(os.path.join(d, n)) != exclude]
        if hits:
            return hits
    return []


def _oword(line):
    """(name, keyword lower case, rest, span of the o-word and keyword) of a LinuxCNC o-word
    line, or None."""
    code = _COMMENT.sub(lambda m: " " * len(m.group()), line.rstrip("\r\n"))
    i = code.find(";")
    if i >= 0:
        code = code[:i]
    m = _OWORD.match(code)
    if m is None:
        return None
    name = (m.group(2).strip().lower() if m.group(2) is not None else str(int(m.group(3))))
    return name, m.group(4).lower(), m.group(5), (m.start(1), m.end(1))


def expand(text: str | bytes, filename: str = "<string>", search=None,
           ascii: bool = False) -> Flow | None:
    """The program as it runs, calls expanded; None when it has no M97/M98/M99 block.
    Raises InputError naming the line for flow it does not follow: M99 in the main program
    (a jump to its start), M99 P (return to a block number), a called program or block number
    not in the file, a call without P, a repeat count 0 or not whole, recursion, nesting deeper
    than MAX_DEPTH, M30/M02 inside a subprogram, a subprogram without M99.

    ``search``: directories where subprograms not in the file are looked for (Fanuc ``M98
    P1234``: a file named ``O1234``, ``1234`` or ``O01234`` with any extension; LinuxCNC
    ``o<name> call``: ``name.ngc``); None: only the file itself.  Such a file is read as if it
    followed the program; `fold` then writes the calls out.  ``text`` may be the program's
    bytes (UTF-8; ``ascii``: known to be ASCII): decoded only where it has flow words (the
    expansion is text)."""
    import os
    if not has_flow(text, ascii):
        return None
    if not isinstance(text, str):
        text = bytes(text).decode("utf-8", "surrogateescape")
    lines = _lines(text)
    segments = [(0, str(filename))]
    main_len = len(lines)
    exclude = os.path.abspath(filename) if os.path.exists(str(filename)) else None
    dirs = list(search or ())

    def append_file(path):
        """Read a subprogram file after the program; the index of its first line."""
        from .parse import read_program
        sub = read_program(path)
        if sub.startswith("\ufeff"):
            sub = sub[1:]
        new = _lines(sub) or ["\n"]
        if lines and not lines[-1].endswith("\n"):
            no_nl.add(len(lines) - 1)
        at = len(lines)
        lines.extend(new)
        segments.append((at, str(path)))
        for k in range(at, len(lines)):
            w = _words(lines[k])
            info[k] = w
            mcodes[k] = frozenset(v for a, v, _, _ in w if a == "M")
            ow = _oword(lines[k])
            if ow is not None:
                owords[k] = ow
            if mcodes[k] & {97.0, 98.0, 99.0, 30.0, 2.0} or ow is not None:
                bisect.insort(flow_at, k)
        if not lines[-1].endswith("\n"):
            no_nl.add(len(lines) - 1)
        return at
    # only lines with an M or O word matter for the flow (N labels are looked up when an M97
    # needs one): read the words of those alone
    starts = np.cumsum([0] + [len(ln) for ln in lines[:-1]])

    def lines_with(pattern):
        hits = np.fromiter((m.start() for m in re.finditer(pattern, text)), np.int64)
        return np.unique(np.searchsorted(starts, hits, side="right") - 1).tolist()

    cand = lines_with(r"[MmOo]")
    info = dict.fromkeys(range(len(lines)), ())
    info.update((i, _words(lines[i])) for i in cand)
    mcodes = dict.fromkeys(range(len(lines)), frozenset())
    mcodes.update((i, {v for a, v, _, _ in info[i] if a == "M"}) for i in cand)
    owords = {}
    for i in cand:                       # o-word lines have an O (and o<name> a '<')
        if "<" in lines[i] or any(a == "O" for a, _, _, _ in info[i]):
            ow = _oword(lines[i])
            if ow is not None:
                owords[i] = ow
    if not any(mcodes[i] & {97.0, 98.0, 99.0} for i in cand) and \
            not any(ow[1] == "call" for ow in owords.values()):
        return None
    flow_at = sorted(set(i for i in cand if mcodes[i] & {97.0, 98.0, 99.0, 30.0, 2.0}) | set(owords))
    no_nl = {len(lines) - 1} if lines and not lines[-1].endswith("\n") else set()
    sub_at = {}                                  # o-word subroutine name -> its "sub" line
    for i, ow in owords.items():
        if ow[1] == "sub":
            sub_at.setdefault(ow[0], i)

    def fail(what, i):
        i = int(i)
        if i >= main_len:                          # a line of a subprogram file
            k = bisect.bisect_right([x for x, _ in segments], i) - 1
            raise InputError(what, file=segments[k][1], line=i - segments[k][0] + 1)
        raise InputError(what, file=filename, line=i + 1)

    for cc in "\x02\x03":
        if cc in text:
            fail(f"control character 0x{ord(cc):02x} in the program",
                 text[:text.index(cc)].count("\n"))
    o_at = {}
    for i in cand:
        for a, v, _, _ in info[i]:
            if a == "O":
                o_at.setdefault(v, i)

    def n_line(n, at):
        """The first line with the block number N<n> in the file holding line `at` (Haas looks
        an M97 label up in the program it runs in; None if none)."""
        pat = r"[Nn][ \t]*[+]?0*" + re.escape(f"{n:g}") + r"(?![0-9])"
        if at < main_len:
            found = lines_with(pat)
        else:                                      # a subprogram file: its own lines
            k = bisect.bisect_right([x for x, _ in segments], at) - 1
            hi = segments[k + 1][0] if k + 1 < len(segments) else len(lines)
            rx = re.compile(pat)
            found = [j for j in range(segments[k][0], hi) if rx.search(lines[j])]
        for i in found:
            if any(a == "N" and v == n for a, v, _, _ in _words(lines[i])):
                return i
        return None
    ends = [i for i in flow_at if mcodes[i] & {30.0, 2.0} and i < main_len]
    if ends:
        main_end = ends[0]
    else:
        first_o = min(o_at.values(), default=-1)
        later = [i for i in o_at.values() if i > max(first_o, 0)]
        main_end = (min(later) - 1) if later else len(lines) - 1
    nl = "\r\n" if "\r\n" in text else "\n"
    out, origin, caller, added = [], [], [], []
    n_calls = 0

    def emit(i, line, call):
        if not line.endswith("\n"):
            line += nl
            added.append(True)
        else:
            added.append(False)
        out.append(line)
        origin.append(i)
        caller.append(call)
        if len(out) > MAX_LINES:
            fail(f"the expanded program exceeds {MAX_LINES} lines: calls not followed", call)

    def call_target(i, w):
        m = 97.0 if 97.0 in mcodes[i] else 98.0
        if 97.0 in mcodes[i] and 98.0 in mcodes[i]:
            fail("M97 and M98 in one block", i)
        if {v for a, v, _, _ in w if a == "G"} & {4.0, 54.1, 65.0, 66.0}:
            fail(f"M{m:.0f} in a block with G4/G54.1/G65/G66, whose P is not a program number", i)
        p = [v for a, v, _, _ in w if a == "P"]
        if not p:
            fail(f"M{m:.0f} without P (the subprogram to call)", i)
        rep = [v for a, v, _, _ in w if a in "LK"]
        count = rep[0] if rep else 1.0
        if count != int(count) or count < 1:
            fail(f"repeat count {count:g} of M{m:.0f}: a whole number >= 1 expected", i)
        n = p[0]
        if m == 97.0:
            t = n_line(n, i)
            if t is None:
                fail(f"M97 P{n:g}: no block N{n:g} in this program"
                     + (" (its own file: M97 calls within the program it is in)"
                        if i >= main_len else ""), i)
            return t, int(count), f"N{n:g}", False
        if n not in o_at and n > 9999 and n == int(n) and (n % 10000) in o_at and not rep:
            count, n = n // 10000, n % 10000             # Fanuc: P<repeats><4-digit program>
        if n not in o_at and n == int(n) and n >= 0:
            hits = _find_file(rf"[Oo]?0*{int(n)}(\.[^.]*)?", dirs, exclude)
            if len(hits) > 1:
                fail(f"M98 P{n:g}: several files could be program O{n:g} "
                     f"({', '.join(os.path.basename(h) for h in hits)}): not guessing", i)
            if hits:
                at = append_file(hits[0])
                first_o = next((k for k in range(at, len(lines))
                                if any(a == "O" for a, _, _, _ in info[k])), None)
                if first_o is not None and not any(a == "O" and v == n for a, v, _, _ in info[first_o]):
                    fail(f"M98 P{n:g}: file {hits[0]} holds another program "
                         f"({lines[first_o].strip()})", i)
                o_at[n] = first_o if first_o is not None else at
        if n not in o_at:
            fail(f"M98 P{n:g}: program O{n:g} is neither in this file nor a file O{n:g}[.ext] "
                 "in " + ("the program's directory or --subprogram-path" if dirs else
                          "a directory searched (give the subprogram path)"), i)
        if o_at[n] <= main_end:
            fail(f"M98 P{n:g} calls the main program (recursion)", i)
        return o_at[n], int(count), f"O{n:g}", True

    def o_target(i, name, rest):
        """The "sub" line of the subroutine an o-word call runs (local, or name.ngc)."""
        if rest.strip():
            fail(f"o<{name}> call with arguments: parameters are macro variables, not followed", i)
        if name not in sub_at and not name.isdigit():
            hits = _find_file(re.escape(name) + r"\.ngc", dirs, exclude)
            if hits:
                at = append_file(hits[0])
                for k in range(at, len(lines)):
                    ow = owords.get(k)
                    if ow is not None and ow[1] == "sub":
                        sub_at.setdefault(ow[0], k)
                if name not in sub_at:
                    fail(f"o<{name}> call: file {hits[0]} has no o<{name}> sub", i)
        if name not in sub_at:
            fail(f"o<{name}> call: no o<{name}> sub in this file nor a file {name}.ngc in "
                 + ("the program's directory or --subprogram-path" if dirs else
                    "a directory searched (give the subprogram path)"), i)
        return sub_at[name]

    def skip_sub(i, name):
        for k in range(i + 1, len(lines)):
            ow = owords.get(k)
            if ow is not None and ow[0] == name and ow[1] == "endsub":
                return k
        fail(f"o<{name}> sub without o<{name}> endsub", i)

    def run(i, stack, call):
        entry = i
        while True:
            if i >= len(lines) or (not stack and i > main_end):
                if stack:
                    fail(f"subprogram {stack[-1]} has no M99 (return)", entry)
                return
            w, m = info[i], mcodes[i]
            if not (stack and i == entry) and not m & {97.0, 98.0, 99.0, 30.0, 2.0} \
                    and i not in owords:
                # plain lines up to the next flow line (or the main program's end): in bulk
                k = bisect.bisect_left(flow_at, i)
                end = flow_at[k] if k < len(flow_at) else len(lines)
                if not stack:
                    end = min(end, main_end + 1)
                for x in no_nl:                   # a line without its ending goes alone
                    if i <= x < end:
                        end = x
                if end > i:
                    out.extend(lines[i:end])
                    origin.extend(range(i, end))
                    caller.extend([call] * (end - i))
                    added.extend([False] * (end - i))
                    if len(out) > MAX_LINES:
                        fail(f"the expanded program exceeds {MAX_LINES} lines: calls not "
                             "followed", call)
                    i = end
                    continue
            ow = owords.get(i)
            if ow is not None:
                name, verb, rest, span = ow
                if verb == "call":
                    t = o_target(i, name, rest)
                    label = f"o<{name}>"
                    if label in stack:
                        fail(f"subroutine {label} calls itself (recursion is not followed)", i)
                    if len(stack) >= MAX_DEPTH:
                        fail(f"subprograms nested deeper than {MAX_DEPTH} levels", i)
                    emit(i, _mark(lines[i], [(span[0], len(lines[i].rstrip("\r\n")))]), call)
                    nonlocal n_calls
                    n_calls += 1
                    run(t, stack + [label], i if call < 0 else call)
                    i += 1
                    continue
                if verb == "sub" and stack and i == entry:
                    emit(i, _mark(lines[i], [(span[0], len(lines[i].rstrip("\r\n")))]), call)
                    i += 1
                    continue
                if verb == "sub":                 # a definition: not run where it stands
                    i = skip_sub(i, name) + 1
                    continue
                if verb == "endsub" and stack and stack[-1] == f"o<{name}>":
                    emit(i, _mark(lines[i], [(span[0], len(lines[i].rstrip("\r\n")))]), call)
                    return
                fail(f"LinuxCNC o-word '{verb}' (o<{name}>) is not followed: mtcomp follows "
                     "o<name> sub/endsub/call without arguments only", i)
            if m & {97.0, 98.0}:
                t, count, name, is_o = call_target(i, w)
                if name in stack:
                    fail(f"subprogram {name} calls itself (recursion is not followed)", i)
                if len(stack) >= MAX_DEPTH:
                    fail(f"subprograms nested deeper than {MAX_DEPTH} levels", i)
                spans = [(s, e) for a, v, s, e in w if (a == "M" and v in (97.0, 98.0)) or a in "PLK"]
                emit(i, _mark(lines[i], spans), call)
                for _ in range(count):
                    n_calls += 1
                    run(t, stack + [name], i if call < 0 else call)
            elif 99.0 in m:
                if not stack:
                    main_loop(i, w)
                    return
                if any(a == "P" for a, _, _, _ in w):
                    fail("M99 P (return to a block number of the caller) is not followed", i)
                spans = [(s, e) for a, v, s, e in w if a == "M" and v == 99.0]
                emit(i, _mark(lines[i], spans), call)
                return
            else:
                if stack and m & {30.0, 2.0}:
                    fail("M30/M02 inside a subprogram is not followed", i)
                line = lines[i]
                if stack and i == entry:
                    line = _mark(line, [(s, e) for a, v, s, e in w if a == "O"])
                emit(i, line, call)
            i += 1

    loop = []                                     # the line of a main program's final M99

    def main_loop(i, w):
        """M99 at the end of the main program: the control starts it again (Fanuc, Haas: bar
        feeders, repeated parts).  Kept as written; `fold` checks that every run is the same."""
        if any(a == "P" for a, _, _, _ in w):
            fail("M99 P in the main program (a jump to a block number) is not followed", i)
        # (up to the next O-numbered program: a file may hold programs after a main without M30)
        end = min([main_end + 1] + [k for k in o_at.values() if k > i])
        rest = (_COMMENT.sub("", ln).split(";")[0].strip() for ln in lines[i + 1:end])
        if any(r and r != "%" for r in rest):
            fail("M99 before the end of the main program (a jump back to its start, the "
                 "blocks after it never run): not followed; M99 as the main program's last "
                 "block (repeat the program) is", i)
        emit(i, _mark(lines[i], [(s, e) for a, v, s, e in w if a == "M" and v == 99.0], _KEEP),
             -1)
        loop.append(i)

    run(0, [], -1)
    loop_len = 0
    if loop:
        # run it again from the state the first run leaves: `fold` keeps the M99 only where
        # the second run is written the same as the first
        loop_len, first_calls = len(out), n_calls
        start = 0
        while start < main_end and lines[start].strip() == "%":
            start += 1
        run(start, [], -1)
        n_calls = first_calls
    last = lines[main_len - 1] if main_len else ""
    trailer = last if last.strip() == "%" and main_end < main_len - 1 else ""
    return Flow(text="".join(lines) if len(segments) > 1 else text, expanded="".join(out),
                origin=np.asarray(origin, np.int64),
                caller=np.asarray(caller, np.int64), added_nl=np.asarray(added, bool),
                calls=n_calls, trailer=trailer, segments=tuple(segments), main_lines=main_len,
                loop_len=loop_len, loop_line=loop[0] if loop else -1)


def fold(flow: Flow, new_expanded: str, filename="<string>") -> tuple[str, str]:
    """The rewritten expansion in the file's structure: ("once", text) when every run of every
    source line was rewritten to the same text (subprograms compensated once, calls kept);
    else ("expanded", text): the expansion with the calls written out, the flow words left as
    comments and the subprogram definitions dropped.  A main program ending in M99 (two runs
    in the expansion) keeps its M99; raises InputError (``filename``) when its second run is
    not written the same as its first (the control would repeat the first run's words from
    another state)."""
    new = _lines(new_expanded)
    if len(new) == len(flow.origin) and not flow.external:
        src = _lines(flow.text)
        nl_len = 2 if "\r\n" in flow.text else 1
        got: dict[int, str] = {}
        same = True
        for j, ln in enumerate(new):
            ln = _KEPT.sub(r"\1", _MARKED.sub(r"\1", ln))
            if flow.added_nl[j]:
                ln = ln[:-nl_len]
            if got.setdefault(int(flow.origin[j]), ln) != ln:
                same = False
                break
        if same:
            return "once", "".join(got.get(i, s) for i, s in enumerate(src))
    if flow.loop_len:
        first, again = new[:flow.loop_len], new[flow.loop_len:]
        if len(new) != len(flow.origin) or not _repeats(first, again):
            raise InputError("M99 at the end of the main program repeats it, but the repetition "
                             "does not run the same compensated blocks as the first run (it "
                             "starts where the first run ends: incremental moves, unknown "
                             "positions or modes left set); not followed", file=filename,
                             line=flow.loop_line + 1)
        new_expanded = "".join(first)
    return "expanded", _KEPT.sub(r"\1", new_expanded.replace(_MARK, "(")) + flow.trailer


def _repeats(first, again):
    """Whether the lines ``again`` are the end of ``first`` (the second run of a main program
    skips its leading '%' lines)."""
    return len(again) <= len(first) and first[len(first) - len(again):] == again


def remap_error(flow: Flow, exc: InputError, filename) -> InputError:
    """An InputError about a line of the expansion, about the source line instead."""
    if exc.line is None or str(exc.file) != str(filename) or not 1 <= exc.line <= len(flow.origin):
        return exc
    j = exc.line - 1
    what = exc.what
    if flow.caller[j] >= 0:
        what += f" (in a subprogram run by the call on line {int(flow.caller[j]) + 1})"
    if flow.segments:
        file, line = flow.where(int(flow.origin[j]))
        if file != str(filename):
            return InputError(what, file=file, line=line, field=exc.field)
    return InputError(what, file=exc.file, line=int(flow.origin[j]) + 1, field=exc.field)
