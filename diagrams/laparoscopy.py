#!/usr/bin/env python3
"""The laparoscopy scene: a grasper through a trocar as an articulated god-object.

    python diagrams/laparoscopy.py --metrics m.json --record r.html

The grasper (models/laparoscopy/grasper.sdf) pivots about the insertion point
in the abdominal wall, slides and spins through the trocar and opens its
jaws; a 5-DoF laparoscopic interface gives ``yaw, pitch, insertion, roll,
jaw`` at 60 Hz. The scene is diagrams/laparoscopy.yaml (docs/guide/laparoscopy.md);
``--coupling`` picks the paper's per-body Cartesian springs or
joint-space PD (explicit, or implicit in SAP), ``--jaws imposed`` (the
paper's choice) or ``simulated``; every flag overrides a field (--help).

This script is ``godobject run diagrams/laparoscopy.yaml`` with the same flags: every entry point builds
the scene through one path (``godobject_drake.station.build.build_station``). The loop it wires,
device → coupling → plant → feedback → device, reads in ``godobject_drake/station/loop.py``;
``examples/compose_diagram.py`` composes the same parts by hand.
"""

import sys
from pathlib import Path

from godobject_drake import cli

SCENARIO = Path(__file__).with_suffix(".yaml")


def main(argv=None) -> int:
    """``godobject run`` on this scene's scenario, with the command line's flags (``--help``)."""
    return cli.scene_main(SCENARIO, argv, prog="python diagrams/laparoscopy.py", description=__doc__)


if __name__ == "__main__":
    sys.exit(main())
