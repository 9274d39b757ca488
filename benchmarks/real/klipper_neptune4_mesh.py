"""Bed meshes of an Elegoo Neptune 4 (inductive probe, 11x11 grid) from its Klipper configuration backups
(AlexWH10/Klipper_Backup_Neptune_4; printer.cfg and Klipper's printer-<date>.cfg backups; no licence stated: the data
stay out of the repository).

    python benchmarks/real/klipper_neptune4_mesh.py --src SNAPSHOT --out CORPUS

Every distinct saved `[bed_mesh default]` (the newest four) is one case: the probe's readings
at rest on a grid of the bed, against a flat bed in the gantry's plane.  The expected effects
(tilt: squareness of z; form: straightness of z) follow from each mesh's own figures by the
rule in _klipper_mesh.py, fixed before any diagnosis ran on them.
"""
from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import Snapshot, cli  # noqa: E402
from _klipper_mesh import convert_repo  # noqa: E402

SOURCE = "klipper_neptune4_mesh"
URL = "https://github.com/AlexWH10/Klipper_Backup_Neptune_4"


def convert(snap: Snapshot, out: Path) -> list:
    return convert_repo(SOURCE, snap, out, rel="printer.cfg", url=URL, authors="AlexWH10",
                        licence="none stated (not redistributed)", printer="an Elegoo Neptune 4 (inductive probe, 11x11 grid)",
                        use_backups=True)


if __name__ == "__main__":
    src, out = cli(SOURCE, __doc__)
    convert(Snapshot(src), out)
