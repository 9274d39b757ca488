"""Bed meshes of grumat's Voron Trident 250 (grumat/voron-trident-250_config, backup/printer.cfg;
MIT licence: a short excerpt is committed under tests/data/real/grumat_bed_mesh/).

    python benchmarks/real/grumat_bed_mesh.py --src SNAPSHOT --out CORPUS

Every distinct saved `[bed_mesh default]` in the history of the backed-up printer.cfg (the
newest four) is one case: the probe's readings at rest on a 5x5 grid of the bed, against a
flat bed in the gantry's plane.  The expected effects (tilt: squareness of z; form:
straightness of z) follow from each mesh's own figures by the rule in _klipper_mesh.py, fixed
before any diagnosis ran on them.  The same author's probe benchmark is the source
grumat_zprobe: both share the family's split.
"""
from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import Snapshot, cli  # noqa: E402
from _klipper_mesh import convert_repo  # noqa: E402

SOURCE = "grumat_bed_mesh"
URL = "https://github.com/grumat/voron-trident-250_config"


def convert(snap: Snapshot, out: Path) -> list:
    return convert_repo(SOURCE, snap, out, rel="backup/printer.cfg", url=URL, authors="grumat",
                        licence="MIT", printer="grumat's Voron Trident 250 (inductive probe, 5x5 grid)")


if __name__ == "__main__":
    src, out = cli(SOURCE, __doc__)
    convert(Snapshot(src), out)
