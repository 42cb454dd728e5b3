"""Compose a diagram of one's own from the parts: a brick grasped, lifted, turned and pressed
1 cm into the baseplate; prints its height and the feedback force (docs: "Compose your own diagram").

    python examples/compose_diagram.py
"""

from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder

from godobject_drake.config.device_files import Waypoint
from godobject_drake.config.gains import CouplingGains, FeedbackGains
from godobject_drake.devices.sources import ScriptedDevice
from godobject_drake.safeguards import install_safeguards
from godobject_drake.station.plant import add_scene_from_directives
from godobject_drake.station.rigid_tool import add_god_object

builder = DiagramBuilder()
scene = add_scene_from_directives(builder, "package://godobject_models/lego/lego.dmd.yaml", time_step=1e-3)
plant = scene.plant
path = [
    Waypoint(t=0.0, xyz=[-0.10, 0.0, 0.0048], grasp="brick_0"),
    Waypoint(t=0.5, xyz=[-0.10, 0.0, 0.0400], rpy_deg=[0, 0, 45], grasp="brick_0"),  # lift and turn
    Waypoint(t=1.0, xyz=[-0.10, 0.0, 0.0400], rpy_deg=[0, 0, 45], grasp="brick_0"),
    Waypoint(t=1.5, xyz=[-0.10, 0.0, -0.0052], rpy_deg=[0, 0, 45], grasp="brick_0"),  # 1 cm into the plate
]
device = builder.AddNamedSystem("device", ScriptedDevice(path))
gains = CouplingGains(omega_n=40.0, zeta=1.0, omega_n_rot=120.0)
god = add_god_object(builder, plant, device, gains, FeedbackGains(kd=20.0, gamma_d=0.2))  # N/m, N·s/m
simulator = Simulator(builder.Build())
install_safeguards(simulator)  # wiring checked now; divergence, quaternion drift, Stop while it runs
brick = plant.GetBodyByName("brick", plant.GetModelInstanceByName("brick_0"))
simulator.AdvanceTo(1.0)
X_WB = plant.EvalBodyPoseInWorld(plant.GetMyContextFromRoot(simulator.get_context()), brick)
print("brick_0 lifted to z =", X_WB.translation()[2])
simulator.AdvanceTo(2.0)
F_Do_W = god.feedback.GetOutputPort("F_Do_W").Eval(god.feedback.GetMyContextFromRoot(simulator.get_context()))
print("on the plate, the device pushes the hand up with F_z =", F_Do_W[5], "N")
