#!/usr/bin/env python3
"""The brick scene: grasp a 2x4 brick with a god-object and build with it.

    python diagrams/lego.py --metrics m.json --record r.html

The scene is diagrams/lego.yaml (README "Brick scene"); every flag overrides
one of its fields (--help names them). The same run:
python -m godobject_drake run diagrams/lego.yaml.
"""

import sys
from pathlib import Path

from pydrake.systems.framework import DiagramBuilder

from godobject_drake import cli
from godobject_drake.station import build as building
from godobject_drake.station.plant import add_plant

SCENARIO = Path(__file__).with_suffix(".yaml")


def build(scenario, meshcat=None):
    """The wiring: device → [haptic device] → coupling → plant, coupling → feedback → [haptic device]."""
    builder = DiagramBuilder()
    device = builder.AddNamedSystem(
        "device", building.make_device(scenario.device, seed=scenario.random_seed, meshcat=meshcat,
                                       workspace=scenario.workspace,
                                       duration_s=scenario.simulation.duration_s),  # a log: what it reaches
    )  # fmt: skip
    scene = add_plant(builder, scenario)  # baseplate, wall, 8 bricks; proxies touch true boxes
    god = scenario.god_object
    god_object = building.add_god_object(
        builder, scene.plant, device, god.gains, scenario.feedback, haptic=scenario.haptic,
        connect_forces=scenario.simulation.mode == "god_object", **building.coupling_options(god),
    )  # fmt: skip
    return building.finish(builder, scenario, scene, god_object, meshcat)  # logs, drawing, Build, checks


def main(argv=None) -> int:
    """The command line: the scenario's fields, overridden by flags (``--help``)."""
    return cli.main(argv, scenario=SCENARIO, build=build, description=__doc__)


if __name__ == "__main__":
    sys.exit(main())
