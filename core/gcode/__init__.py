"""NC programs (Fanuc-style and the dialects CAM systems write): read, then rewrite axis words.

`parse` reads a whole program into numpy arrays (one row per motion block: absolute modal end
position over the machine's axes in mm/deg, motion mode, plane, feed, arc data, source line);
`rewrite` maps every commanded position through a vectorised ``transform`` and splices new axis
words into the original text, leaving every other byte alone.  `write` gives the text back.

Modules: ``tokens`` (comments and words), ``codes`` (which G/M codes are followed, passed or
refused), ``parse`` (modal state, positions), ``arcs`` (circle geometry, keep or linearise),
``rewrite`` (new words spliced into the bytes), ``textops`` (vectorised number parsing and
formatting), ``flow`` (M98/M97/M99 subprogram calls expanded in run order and folded back), ``tcp``
(G43.4 tool centre point words compensated in tool-tip coordinates), ``rotation`` (G68 in the
plane), ``offsets`` (tool tables, offsets files, G10 in the program).  What is read, what is refused and why is described in docs/gcode.md.
"""
from .codes import ARC_WORDS, CANONICAL, INCH, LINEAR
from .parse import parse, read_program, read_program_8bit, read_program_bytes, write
from .program import Program
from .rewrite import rewrite, rewrite_with_lines

__all__ = ["ARC_WORDS", "CANONICAL", "INCH", "LINEAR", "Program", "parse", "read_program",
           "read_program_8bit", "read_program_bytes", "rewrite", "rewrite_with_lines", "write"]
