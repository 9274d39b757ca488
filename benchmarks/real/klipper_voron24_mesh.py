"""Bed meshes of Voron 2.4 (inductive probe, bed trammed by quad gantry levelling) from its Klipper configuration backups
(0x3333/klipper_voron2.4, printer.cfg; no licence stated: the data stay out of the repository).

    python benchmarks/real/klipper_voron24_mesh.py --src SNAPSHOT --out CORPUS

Every distinct saved `[bed_mesh default]` in the file's history is one case: the probe's
readings at rest on a grid of the bed, against a flat bed in the gantry's plane.  The expected
effects (tilt: squareness of z; form: straightness of z) follow from each mesh's own figures by
the rule in _klipper_mesh.py, fixed before any diagnosis ran on them.
"""
from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import Snapshot, cli  # noqa: E402
from _klipper_mesh import convert_repo  # noqa: E402

SOURCE = "klipper_voron24_mesh"
URL = "https://github.com/0x3333/klipper_voron2.4"


def convert(snap: Snapshot, out: Path) -> list:
    return convert_repo(SOURCE, snap, out, rel="printer.cfg", url=URL, authors="Tercio Gaudencio Filho (0x3333)",
                        licence="none stated (not redistributed)", printer="a Voron 2.4 (inductive probe, bed trammed by quad gantry levelling)")


if __name__ == "__main__":
    src, out = cli(SOURCE, __doc__)
    convert(Snapshot(src), out)
