#!/usr/bin/env python3
"""The deformable-probe scene: a deformable god-object pressed on a block and around it.

    python diagrams/deformable_probe.py --shell fem --metrics m.json --record r.html

The probe is a rigid core (the god-object: coupled, simulated, not drawn,
not colliding) carrying a deformable shell (drawn, colliding), paper Fig. 4
and 8. ``--shell fem`` is Drake's FEM deformable body; ``--shell
mass_spring`` the paper's mass–spring net. ``--mode position`` imposes the
core's pose (the paper's first idea, which it rejects) and leaves only the
shell simulated. The scene is diagrams/deformable_probe.yaml (docs/guide/deformable.md);
every flag overrides a field (--help).

This script is ``godobject run diagrams/deformable_probe.yaml`` with the same flags: every entry point builds
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
    return cli.scene_main(SCENARIO, argv, prog="python diagrams/deformable_probe.py", description=__doc__)


if __name__ == "__main__":
    sys.exit(main())
