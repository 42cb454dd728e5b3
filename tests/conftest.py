"""Shared fixtures: a one-body plant for unit tests, the brick-scene script."""

import argparse
from pathlib import Path

import numpy as np
import pytest
from pydrake.geometry import SceneGraph
from pydrake.multibody.plant import MultibodyPlant
from pydrake.multibody.tree import RotationalInertia, SpatialInertia, UnitInertia
from pydrake.systems.framework import DiagramBuilder

from godobject_drake.runner import load_scene_script

REPO = Path(__file__).resolve().parent.parent


load_script = load_scene_script  # a script of the clone, imported by path


@pytest.fixture(scope="session")
def lego():
    return load_script("diagrams/lego.py")


def lego_args(*argv: str) -> argparse.Namespace:
    """The brick scene's flags as its command line parses them."""
    return load_script("diagrams/lego.py").make_parser().parse_args([*argv, "--no-progress"])


def add_free_boxes(
    builder: DiagramBuilder, time_step: float, masses=(0.5,), inertia_diag=(1e-3, 2e-3, 3e-3), gravity=True
):
    """A plant with free bodies (no geometry), finalized. Returns (plant, bodies)."""
    plant = MultibodyPlant(time_step)
    if not gravity:
        plant.mutable_gravity_field().set_gravity_vector([0.0, 0.0, 0.0])
    scene_graph = builder.AddSystem(SceneGraph())
    plant.RegisterAsSourceForSceneGraph(scene_graph)
    builder.AddSystem(plant)
    builder.Connect(
        plant.get_geometry_pose_output_port(), scene_graph.get_source_pose_port(plant.get_source_id())
    )
    builder.Connect(scene_graph.get_query_output_port(), plant.get_geometry_query_input_port())
    bodies = []
    for i, m in enumerate(masses):
        M = SpatialInertia(m, np.zeros(3), UnitInertia(*(np.array(inertia_diag) / m)))
        expected = RotationalInertia(*inertia_diag).CopyToFullMatrix3()
        assert np.allclose(M.CalcRotationalInertia().CopyToFullMatrix3(), expected)
        bodies.append(plant.AddRigidBody(f"body_{i}", M))
    plant.Finalize()
    return plant, bodies
