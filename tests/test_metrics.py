"""True-shape penetration by separating axes, checked against Drake's geometry queries."""

import numpy as np
import pytest
from pydrake.geometry import (
    Box,
    FramePoseVector,
    GeometryFrame,
    GeometryInstance,
    ProximityProperties,
    SceneGraph,
)
from pydrake.math import RigidTransform, RollPitchYaw

from godobject_drake.metrics import box_overlap, format_table


def drake_signed_distance(size_a, X_a, size_b, X_b):
    """Drake's signed distance between two boxes (GJK/EPA): negative when they overlap."""
    scene_graph = SceneGraph()
    source = scene_graph.RegisterSource("test")
    poses = FramePoseVector()
    for name, size, X in (("a", size_a, X_a), ("b", size_b, X_b)):
        frame = scene_graph.RegisterFrame(source, GeometryFrame(name))
        geometry = scene_graph.RegisterGeometry(
            source, frame, GeometryInstance(RigidTransform(), Box(*size), name)
        )
        scene_graph.AssignRole(source, geometry, ProximityProperties())
        poses.set_value(frame, X)
    context = scene_graph.CreateDefaultContext()
    scene_graph.get_source_pose_port(source).FixValue(context, poses)
    query = scene_graph.get_query_output_port().Eval(context)
    (pair,) = query.ComputeSignedDistancePairwiseClosestPoints()
    return pair.distance


def as_arrays(X):
    return X.translation()[None], X.rotation().matrix()[None]


@pytest.mark.parametrize("seed", range(16))
def test_penetration_depth_matches_drake_signed_distance(seed):
    """Overlapping: SAT depth = −(Drake's signed distance). Apart: SAT gap ≤ the distance.

    (Drake's point-pair penetration is not the reference: for box-box it may
    report a deeper, non-minimal depth, by 66 % for seed 6 of this draw.)
    """
    rng = np.random.default_rng(seed)
    size_a, size_b = rng.uniform(0.01, 0.05, 3), rng.uniform(0.01, 0.05, 3)
    X_a = RigidTransform(RollPitchYaw(rng.uniform(-np.pi, np.pi, 3)), rng.uniform(-0.005, 0.005, 3))
    X_b = RigidTransform(
        RollPitchYaw(rng.uniform(-np.pi, np.pi, 3)), rng.uniform(-0.02, 0.02, 3) * (1 + seed // 8)
    )
    ours = box_overlap(*as_arrays(X_a), size_a / 2, *as_arrays(X_b), size_b / 2)[0]
    distance = drake_signed_distance(size_a, X_a, size_b, X_b)
    if distance < 0:
        assert ours == pytest.approx(-distance, rel=1e-9, abs=1e-12)
    else:
        assert 0 <= -ours <= distance + 1e-12


def test_brick_on_wall_by_hand():
    # A brick (31.8 × 15.8 × 9.6 mm) pushed 1 mm into the −x face of the 8 mm wall.
    brick, wall = np.array([0.0318, 0.0158, 0.0096]) / 2, np.array([0.008, 0.2, 0.048]) / 2
    R = np.eye(3)[None]
    centre = np.array([[-0.004 - 0.0159 + 0.001, 0, 0.02]])
    assert box_overlap(centre, R, brick, np.array([[0, 0, 0.024]]), R, wall)[0] == pytest.approx(0.001)
    # 3 mm clear of it: the separating axis reports −3 mm.
    centre[0, 0] -= 0.004
    assert box_overlap(centre, R, brick, np.array([[0, 0, 0.024]]), R, wall)[0] == pytest.approx(-0.003)


def test_table_lists_every_run():
    text = format_table([{"mode": "god_object", "max_penetration_m": 1e-4}, {"mode": "position"}])
    assert text.splitlines()[0].split() == ["metric", "god_object", "position"]
    assert "0.0001" in text and "None" in text


def test_a_long_warning_is_wrapped_within_its_column():
    """A 500-character warning (the real-time one) made its row 500 characters wide; now it is
    wrapped to TEXT_WIDTH (72) in its own column, its words all there in order, and the rows
    after it keep their place."""
    warning = " ".join(f"word{i:03d}" for i in range(63))  # 503 characters
    text = format_table([{"mode": "god_object", "realtime_warning": warning, "seed": 0}])
    lines = text.splitlines()
    assert max(map(len, lines)) <= len("realtime_warning") + 2 + 72 and len(warning) > 500
    at = next(i for i, line in enumerate(lines) if line.startswith("realtime_warning"))
    column = lines[at].index("word000")
    follow = [line for line in lines[at + 1 :] if line[:column].strip() == ""]
    assert " ".join([lines[at][column:], *(line[column:] for line in follow)]).split() == warning.split()
    # 9 words of 7 characters and their spaces fill 71 of 72: 63 words on 7 lines
    assert len(follow) == 6 and lines[at + 7].split() == ["seed", "0"]


# -- shapes other than boxes: Drake's signed distance, half spaces by support function ------------------


def box_against(obstacle, X_WO, box_center, rpy=(0.0, 0.0, 0.0)):
    """A free 5 cm box at ``box_center`` (roll-pitch-yaw ``rpy``) and a welded ``obstacle``: the
    box's true-shape overlap with it, measured as the run's metrics measure it."""
    from pydrake.multibody.plant import AddMultibodyPlantSceneGraph, CoulombFriction
    from pydrake.multibody.tree import SpatialInertia
    from pydrake.systems.framework import DiagramBuilder

    from godobject_drake.metrics import TrueShapeMetrics

    builder = DiagramBuilder()
    plant, _ = AddMultibodyPlantSceneGraph(builder, 1e-3)
    body = plant.AddRigidBody("cube", SpatialInertia.SolidBoxWithMass(0.2, 0.05, 0.05, 0.05))
    plant.RegisterCollisionGeometry(body, RigidTransform(), Box(0.05, 0.05, 0.05), "cube", CoulombFriction())
    plant.RegisterCollisionGeometry(plant.world_body(), X_WO, obstacle, "obstacle", CoulombFriction())
    plant.Finalize()
    diagram = builder.Build()
    context = plant.CreateDefaultContext()
    plant.SetFreeBodyPose(context, body, RigidTransform(RollPitchYaw(*rpy), box_center))
    x = plant.GetPositionsAndVelocities(context)[None]
    shapes = TrueShapeMetrics(plant, diagram.GetSubsystemByName("scene_graph"), diagram)
    return float(shapes.overlaps(int(body.index()), x)[0, 0])


def test_a_box_into_a_cylinder_by_drakes_signed_distance():
    # A 3 cm post at the origin; the cube's face 5 mm inside it (face at x = −0.025, surface at −0.03),
    # then 5 mm clear of it. Drake's box-cylinder distance is iterative (EPA): 0.1 µm of tolerance.
    from pydrake.geometry import Cylinder

    post = Cylinder(0.03, 0.2)
    assert box_against(post, RigidTransform(), [-0.05, 0.0, 0.0]) == pytest.approx(0.005, abs=1e-7)
    assert box_against(post, RigidTransform(), [-0.06, 0.0, 0.0]) == pytest.approx(-0.005, abs=1e-7)


def test_a_box_into_a_half_space_by_its_lowest_corner():
    # Drake's signed distance takes only spheres against a half space; the metric uses the box's
    # support function: tilted 45° about x, the cube's lowest edge is 2.5 √2 cm below its centre.
    from pydrake.geometry import HalfSpace

    assert box_against(HalfSpace(), RigidTransform(), [0, 0, 0.02]) == pytest.approx(0.005, abs=1e-12)
    tilted = box_against(HalfSpace(), RigidTransform(), [0, 0, 0.03], rpy=(np.pi / 4, 0, 0))
    assert tilted == pytest.approx(0.025 * np.sqrt(2) - 0.03, abs=1e-12)
    raised = RigidTransform([0, 0, 0.01])  # the half space's surface at z = 1 cm
    assert box_against(HalfSpace(), raised, [0, 0, 0.03]) == pytest.approx(0.005, abs=1e-12)


@pytest.mark.parametrize("shape", ["sphere", "cylinder", "capsule", "ellipsoid"])
def test_half_space_support_matches_drake_where_drake_can_tell(shape):
    """For a sphere Drake's signed distance to a half space exists; for the other shapes the support
    function is checked against Drake's signed distance to a large thin box standing in for it."""
    from pydrake.geometry import Capsule, Cylinder, Ellipsoid, HalfSpace, Sphere

    from godobject_drake.metrics import half_space_overlap

    shapes = {"sphere": Sphere(0.03), "cylinder": Cylinder(0.02, 0.08), "capsule": Capsule(0.02, 0.06),
              "ellipsoid": Ellipsoid(0.02, 0.03, 0.04)}  # fmt: skip
    X_WG = RigidTransform(RollPitchYaw(0.3, -0.5, 0.8), [0.01, -0.02, 0.025])
    ours = half_space_overlap(shapes[shape], X_WG, RigidTransform())
    # Drake: the same shape against a 10 m x 10 m x 1 m box whose top face is z = 0.
    scene_graph = SceneGraph()
    source = scene_graph.RegisterSource("test")
    poses = FramePoseVector()
    for name, geometry, X in (
        ("g", shapes[shape], X_WG),
        ("floor", Box(10, 10, 1), RigidTransform([0, 0, -0.5])),
    ):
        frame = scene_graph.RegisterFrame(source, GeometryFrame(name))
        gid = scene_graph.RegisterGeometry(source, frame, GeometryInstance(RigidTransform(), geometry, name))
        scene_graph.AssignRole(source, gid, ProximityProperties())
        poses.set_value(frame, X)
    context = scene_graph.CreateDefaultContext()
    scene_graph.get_source_pose_port(source).FixValue(context, poses)
    (pair,) = scene_graph.get_query_output_port().Eval(context).ComputeSignedDistancePairwiseClosestPoints()
    assert ours == pytest.approx(-pair.distance, abs=1e-6)
    assert ours > 0.0  # it does dip in: the check compares a penetration, not two clearances
    assert half_space_overlap(Box(0.1, 0.1, 0.1), RigidTransform(), RigidTransform()) == pytest.approx(0.05)
    assert half_space_overlap(HalfSpace(), RigidTransform(), RigidTransform()) is None
