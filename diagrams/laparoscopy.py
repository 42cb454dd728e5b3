#!/usr/bin/env python3
"""The laparoscopy scene: a grasper through a trocar as an articulated god-object.

    python diagrams/laparoscopy.py --metrics m.json --record r.html

The grasper (models/laparoscopy/grasper.sdf) pivots about the insertion point
in the abdominal wall, slides and spins through the trocar and opens its
jaws; a 5-DoF laparoscopic interface gives ``yaw, pitch, insertion, roll,
jaw`` at 60 Hz. The scene is diagrams/laparoscopy.yaml (README "Laparoscopy
scene"); ``--coupling`` picks the paper's per-body Cartesian springs or
joint-space PD (explicit, or implicit in SAP), ``--jaws imposed`` (the
paper's choice) or ``simulated``; every flag overrides a field (--help).
"""

import sys
from pathlib import Path

from pydrake.systems.framework import DiagramBuilder

from godobject_drake import cli
from godobject_drake.station import build as building
from godobject_drake.station.plant import add_plant

SCENARIO = Path(__file__).with_suffix(".yaml")


def build(scenario, meshcat=None):
    """The wiring: interface → coupling (kinematic copy of the tool) → plant; plant → feedback."""
    builder = DiagramBuilder()
    device = builder.AddNamedSystem(
        "device",
        building.make_device(scenario.device, meshcat=meshcat, duration_s=scenario.simulation.duration_s),
    )
    scene = add_plant(builder, scenario)  # organs, grasper through the trocar
    god_object = building.add_articulated(
        builder, scene, scenario.god_object, device, duration_s=scenario.simulation.duration_s,
        connect_forces=scenario.simulation.mode == "god_object",
    )  # fmt: skip
    return building.finish(builder, scenario, scene, god_object, meshcat)  # logs, drawing, Build, checks


def main(argv=None) -> int:
    """The command line: the scenario's fields, overridden by flags (``--help``)."""
    return cli.main(argv, scenario=SCENARIO, build=build, description=__doc__)


if __name__ == "__main__":
    sys.exit(main())
