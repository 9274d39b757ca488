"""G68 coordinate rotation in the plane (Fanuc, Haas, Siemens-like ROT aside).

``G68 X.. Y.. R..`` (G17; G18: Z X, G19: Y Z) turns every later position of the program about
the centre (program coordinates) by R deg, counter-clockwise seen from the plane's normal, until
G69.  The control rotates the words, then applies the work offset:

    reference = offset + c + Rot(R) (word - c)

`Program.position` holds G68 blocks in the *word* frame (``word + offset``, not rotated): the
rotation is an isometry of the plane, so arcs, increments and the rewriting stay as they are in
that frame, and a transform ``T`` of the reference frame becomes ``Rot^-1 T Rot`` there
(`conjugate`).  `to_reference` gives the positions the axes take.
"""
from __future__ import annotations

import numpy as np

#: plane -> the two axis letters (u, v) of the rotation, counter-clockwise from u to v
PLANE_AXES = {17: ("X", "Y"), 18: ("Z", "X"), 19: ("Y", "Z")}


def _rotate(program, P, blocks, sign):
    rot = program.rotation
    P = np.array(P, float)
    if rot is None or not len(P):
        return P
    blocks = np.asarray(blocks, np.int64)
    ang = rot[blocks, 0]
    on = ang != 0
    if not on.any():
        return P
    axes = program.axes
    off = np.asarray(program.offset)
    for pl in np.unique(np.asarray(program.plane)[blocks][on]):
        u, v = (axes.index(a) for a in PLANE_AXES[int(pl)])
        sel = np.flatnonzero(on & (np.asarray(program.plane)[blocks] == pl))
        b = blocks[sel]
        t = np.radians(ang[sel]) * sign
        c, s = np.cos(t), np.sin(t)
        cu, cv = rot[b, 1] + off[b, u], rot[b, 2] + off[b, v]
        du, dv = P[sel, u] - cu, P[sel, v] - cv
        P[sel, u] = cu + c * du - s * dv
        P[sel, v] = cv + s * du + c * dv
    return P


def to_reference(program, P, blocks=None):
    """Positions (M, n_axes) of `blocks` (default: every block, P as ``program.position``) from
    the word frame to the reference frame (the positions the axes take)."""
    return _rotate(program, P, np.arange(len(P)) if blocks is None else blocks, 1.0)


def to_words(program, P, blocks=None):
    """The inverse of `to_reference`."""
    return _rotate(program, P, np.arange(len(P)) if blocks is None else blocks, -1.0)


def conjugate(program, transform, blocks):
    """``transform`` (reference frame) as seen in the word frame for rows of `blocks`."""
    def tf(q):
        return to_words(program, transform(to_reference(program, q, blocks)), blocks)
    return tf


def has_rotation(program) -> bool:
    return program.rotation is not None and bool(np.any(program.rotation[:, 0] != 0))
