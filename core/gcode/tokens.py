"""Tokenising an NC program: comments, words (letter + number), and what is wrong when a
token is neither."""
from __future__ import annotations

import re

import numpy as np

from .._io import InputError
from .codes import O_WORDS, siemens_hint

_PAREN_RE = re.compile(rb"\([^()\n]*\)")
_LINE_REST_RE = re.compile(rb"[^\n]*")


def _comment_spans(data: bytes, b: np.ndarray, first: int = 0) -> list:
    """Byte spans of comments: ``( ... )`` on one line, ``;`` to the end of the line and lines
    starting with ``%``.  Candidates come from numpy; only they are looked at in Python."""
    cand = np.flatnonzero((b == 40) | (b == 59) | (b == 37))
    spans = []
    end = 0
    for q in cand.tolist():
        if q < end:
            continue                                  # inside the previous comment
        c = data[q]
        if c == 40:
            m = _PAREN_RE.match(data, q)
            if m is None:
                continue                              # stays in the code: reported as unbalanced
            end = m.end()
        elif c == 59:
            end = _LINE_REST_RE.match(data, q).end()
        else:
            if q > first and data[q - 1] != 10:
                continue                              # '%' not at a line start: reported
            end = _LINE_REST_RE.match(data, q).end()
        spans.append((q, end))
    return spans


def _ascii(letter: str) -> int:
    return ord(letter) - 65


def _fail(what: str, line_index, filename: str):
    """Raise InputError for a 0-based line index (the message shows it 1-based)."""
    raise InputError(what, file=filename, line=int(line_index) + 1)



def _word_text(data: bytes, s, e) -> str:
    return data[int(s):int(e)].decode("utf-8", "replace")


def _word_error(code, lp, rs, re_, line_of, filename):
    """Find the first token that is not letter+number and say what it is."""
    # blanks between a letter and its number are read ("X 1.5"): a letter is followed, and a
    # number run preceded, by its partner at the next / previous character that is no blank
    # (a plain lp + 1 test named the X of "X 1.5 Y - 2.5" as the bad word, issue 31)
    nb = np.flatnonzero((code != 32) & (code != 9))
    nxt = np.searchsorted(nb, lp, side="right")
    nxt = np.where(nxt < len(nb), nb[np.minimum(nxt, len(nb) - 1)], -1)
    prv = np.searchsorted(nb, rs, side="left") - 1
    prv = np.where(prv >= 0, nb[np.maximum(prv, 0)], -1)
    ok_letter = np.isin(nxt, rs)
    ok_run = np.isin(prv, lp)
    p1 = lp[np.argmax(~ok_letter)] if (~ok_letter).any() else None
    p2 = rs[np.argmax(~ok_run)] if (~ok_run).any() else None
    if p1 is not None and (p2 is None or p1 < p2):
        e = p1
        while e < len(code) and 0 <= (int(code[e]) | 32) - 97 < 26:
            e += 1
        word = bytes(code[p1:e]).decode("latin-1")
        if len(word) > 1:
            what = f"unknown word {word!r}: expected an address letter followed by a number"
            ls = int(np.flatnonzero(code[:p1] == 10)[-1]) + 1 if (code[:p1] == 10).any() else 0
            le = p1 + int(np.argmax(np.r_[code[p1:] == 10, True]))
            text = bytes(code[ls:le]).decode("latin-1")
            oword = re.match(r"\s*(?:[Nn]\s*\d+\s*)?[Oo]\s*\d", text) is not None
            hint = None if oword else siemens_hint(text)
            if hint:
                what = hint
            elif word.lower() in O_WORDS:
                what = (f"LinuxCNC o-word program flow ({word!r}) is not supported: mtcomp reads "
                        "straight-line code; expand subroutines and loops first")
        else:
            what = f"address {word} without a number"
        _fail(what, line_of(p1), filename)
    j = int(np.searchsorted(rs, p2))
    e = re_[j]
    if j > 0 and re_[j - 1] - rs[j - 1] == 1 and code[rs[j - 1]] in (43, 45) and ok_run[j - 1]:
        # a sign standing alone before the number: "Y - 2.5"
        a = int(lp[np.searchsorted(lp, rs[j - 1]) - 1])
        _fail(f"malformed number in word {bytes(code[a:e]).decode('latin-1')!r}: a blank between "
              "the sign and the digits (expected the sign right before them, as Y-2.5)",
              line_of(p2), filename)
    _fail(f"number {bytes(code[p2:e]).decode('latin-1')!r} without an address letter",
          line_of(p2), filename)


def _tokenise(code: np.ndarray, line_start: np.ndarray, chunk: int = 1 << 18):
    """Split the (comment-blanked) code into words, in chunks that fit the cache; chunks end
    at line starts so no word is split.

    Returns letter positions, number runs [start, end) (``start = letter + 1`` when the code is
    well-formed, checked by the caller), per run the position of its point (-1 if none), per
    run whether it has more than one point, the 0-based line of each letter, the position of the first sign that does not lead
    its number (-1 if none) and of the first character that is none of letter, number, blank.
    """
    n = len(code)
    cuts = [0]
    while cuts[-1] < n:
        want = cuts[-1] + chunk
        if want >= n:
            cuts.append(n)
            break
        j = int(np.searchsorted(line_start, want))      # next line start at or after `want`
        cuts.append(int(line_start[j]) if j < len(line_start) else n)
    out = [[], [], [], [], [], []]
    bad_at = sign_at = -1
    u8 = np.uint8
    for a, b in zip(cuts[:-1], cuts[1:]):
        c = code[a:b]
        line0 = int(np.searchsorted(line_start, a, side="right")) - 1   # chunk starts a line
        letter = ((c | u8(32)) - u8(97)) < u8(26)
        numc = ((c - u8(43)) < u8(15)) & (c != 44) & (c != 47)     # + - . and digits
        if bad_at < 0:
            bad = ~(letter | numc | (c == 32) | ((c - u8(9)) < u8(5)))
            if bad.any():
                bad_at = a + int(np.argmax(bad))
        d = np.diff(numc.view(np.int8))
        lp = np.flatnonzero(letter)
        nstart = np.count_nonzero(d == 1) + int(len(c) > 0 and bool(numc[0]))
        rs = lp + 1
        if nstart != len(lp) or (len(rs) and (rs[-1] >= len(c) or not numc[rs].all())):
            # not well-formed: the exact run starts for the caller's error message
            rs = np.flatnonzero(d == 1) + 1
            if len(c) and numc[0]:
                rs = np.concatenate(([0], rs))
        re_ = np.flatnonzero(d == -1) + 1
        if len(c) and numc[-1]:
            re_ = np.concatenate((re_, [len(c)]))
        if sign_at < 0:
            # a sign anywhere but in front of its number follows a number character
            sg = np.flatnonzero((c == 45) | (c == 43))
            sg = sg[sg > 0]
            bad_s = numc[sg - 1]
            if bad_s.any():
                sign_at = a + int(sg[np.argmax(bad_s)])
        dpos = np.flatnonzero(c == 46)
        drun = np.searchsorted(rs, dpos, side="right") - 1
        dot = np.full(len(rs), -1, np.int64)
        dot[drun] = dpos + a
        two = np.zeros(len(rs), bool)
        two[drun[1:][drun[1:] == drun[:-1]]] = True
        out[0].append(lp + a)
        out[1].append(rs + a)
        out[2].append(re_ + a)
        out[3].append(dot)
        out[4].append(two)
        nlc = np.cumsum(c == 10, dtype=np.int32)                    # line of each letter
        out[5].append(nlc[lp] + np.int32(line0))
    empty = (np.zeros(0, np.int64),) * 4 + (np.zeros(0, bool), np.zeros(0, np.int32))
    return tuple(np.concatenate(o) if o else e for o, e in zip(out, empty)) + (sign_at, bad_at)

