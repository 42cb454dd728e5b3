#!/usr/bin/env python3
"""The deformable-probe scene: a deformable god-object pressed on a block and around it.

    python diagrams/deformable_probe.py --shell fem --metrics m.json --record r.html

The probe is a rigid core (the god-object: coupled, simulated, not drawn,
not colliding) carrying a deformable shell (drawn, colliding), paper Fig. 4
and 8. ``--shell fem`` is Drake's FEM deformable body; ``--shell
mass_spring`` the paper's mass–spring net. ``--mode position`` imposes the
core's pose (the paper's first idea, which it rejects) and leaves only the
shell simulated. The scene is diagrams/deformable_probe.yaml (README
"Deformable probe"); every flag overrides a field (--help).
"""

import sys
from pathlib import Path

from pydrake.systems.framework import DiagramBuilder

from godobject_drake import cli
from godobject_drake.devices.sources import first_pose
from godobject_drake.station import build as building
from godobject_drake.station.plant import add_plant
from godobject_drake.systems.shell import add_deformable_god_object

SCENARIO = Path(__file__).with_suffix(".yaml")


def build(scenario, meshcat=None):
    """The wiring: device → coupling → core; the shell is held to the core and observed."""
    builder = DiagramBuilder()
    device = builder.AddNamedSystem(
        "device", building.make_device(scenario.device, seed=scenario.random_seed, meshcat=meshcat,
                                       workspace=scenario.workspace,
                                       duration_s=scenario.simulation.duration_s),  # a log: what it reaches
    )  # fmt: skip
    probe = scenario.god_object
    probe.gains.check(scenario.time_step)  # before meshing anything
    X_WC = first_pose(device)  # the probe starts at the device
    shells = []
    scene = add_plant(  # the block; the core and its shell go in before Finalize
        builder, scenario, before_finalize=lambda plant, scene_graph: shells.append(
            add_deformable_god_object(plant, scene_graph, probe.shell, probe.spec, X_WC, probe.name)),
    )  # fmt: skip
    god_object = building.add_deformable(
        builder, scene.plant, shells[0], device, probe.gains, scenario.feedback, haptic=scenario.haptic,
        connect_forces=scenario.simulation.mode == "god_object",
    )  # fmt: skip
    return building.finish(builder, scenario, scene, god_object, meshcat)  # logs, drawing, Build, checks


def main(argv=None) -> int:
    """The command line: the scenario's fields, overridden by flags (``--help``)."""
    return cli.main(argv, scenario=SCENARIO, build=build, description=__doc__)


if __name__ == "__main__":
    sys.exit(main())
