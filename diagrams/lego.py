#!/usr/bin/env python3
"""The brick scene: grasp a 2x4 brick with a god-object and build with it.

    python diagrams/lego.py --metrics m.json --record r.html

The scene is diagrams/lego.yaml (docs/guide/brick_scene.md); every flag overrides
one of its fields (--help names them). The same run:
python -m godobject_drake run diagrams/lego.yaml.

This script is ``godobject run diagrams/lego.yaml`` with the same flags: every entry point builds
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
    return cli.scene_main(SCENARIO, argv, prog="python diagrams/lego.py", description=__doc__)


if __name__ == "__main__":
    sys.exit(main())
