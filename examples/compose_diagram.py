"""Compose a diagram of one's own from the parts a scenario is built from: a brick grasped, lifted,
turned and pressed 1 cm into the baseplate; prints its height and the feedback force (docs:
"Compose your own diagram").

    python examples/compose_diagram.py

The loop's steps, in the order a sample travels (godobject_drake.station.loop), as build_station
makes them for a rigid tool (station.rigid_tool.add_god_object makes the same calls in one).
"""

from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder

from godobject_drake.config.device_files import Waypoint
from godobject_drake.config.gains import CouplingGains, FeedbackGains
from godobject_drake.config.scene import Haptic
from godobject_drake.devices.sources import ScriptedDevice
from godobject_drake.safeguards import install_safeguards
from godobject_drake.station import loop
from godobject_drake.station.haptic_chain import add_haptic_chain
from godobject_drake.station.plant import add_scene_from_directives

builder = DiagramBuilder()
scene = add_scene_from_directives(builder, "package://godobject_models/lego/lego.dmd.yaml", time_step=1e-3)
plant = scene.plant
path = [
    Waypoint(t=0.0, xyz=[-0.10, 0.0, 0.0048], grasp="brick_0"),
    Waypoint(t=0.5, xyz=[-0.10, 0.0, 0.0400], rpy_deg=[0, 0, 45], grasp="brick_0"),  # lift and turn
    Waypoint(t=1.0, xyz=[-0.10, 0.0, 0.0400], rpy_deg=[0, 0, 45], grasp="brick_0"),
    Waypoint(t=1.5, xyz=[-0.10, 0.0, -0.0052], rpy_deg=[0, 0, 45], grasp="brick_0"),  # 1 cm into the plate
]
device = builder.AddNamedSystem("device", ScriptedDevice(path))  # the device: its target
gains = CouplingGains(omega_n=40.0, zeta=1.0, omega_n_rot=120.0)
coupling = loop.add_coupling(builder, plant, device, gains)  # paper Eq. 2: the spring to the target
chain = add_haptic_chain(builder, Haptic(mode="none"), device, coupling)  # no simulated haptic device
feedback = loop.add_feedback(builder, chain, coupling, FeedbackGains(kd=20.0, gamma_d=0.2))  # Eq. 8
loop.connect_target(builder, chain, coupling)  # the device's pose is the target
loop.connect_forces(builder, plant, coupling)  # the coupling's wrench into the plant
loop.render_feedback(builder, device, chain, feedback, coupling)  # nothing renders it here
simulator = Simulator(builder.Build())
install_safeguards(simulator)  # wiring checked now; divergence, quaternion drift, Stop while it runs
brick = plant.GetBodyByName("brick", plant.GetModelInstanceByName("brick_0"))
simulator.AdvanceTo(1.0)
X_WB = plant.EvalBodyPoseInWorld(plant.GetMyContextFromRoot(simulator.get_context()), brick)
print("brick_0 lifted to z =", X_WB.translation()[2])
simulator.AdvanceTo(2.0)
F_Do_W = feedback.GetOutputPort("F_Do_W").Eval(feedback.GetMyContextFromRoot(simulator.get_context()))
print("on the plate, the device pushes the hand up with F_z =", F_Do_W[5], "N")
