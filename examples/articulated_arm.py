"""Any tree model as an articulated god-object: a 4-DoF arm driven to a joint-space goal, its
passive wrist left free (docs: "One call for any tree model").

    python examples/articulated_arm.py
"""

import numpy as np
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder

from godobject_drake.config.gains import CouplingGains
from godobject_drake.devices.sources import JointDevice
from godobject_drake.station.loop import add_joint_coupling
from godobject_drake.station.plant import add_scene_from_directives

builder = DiagramBuilder()
plant = add_scene_from_directives(
    builder, "package://godobject_models/arm/arm.dmd.yaml", time_step=1e-3
).plant
goal = np.array([0.3, -0.2, 0.4, 0.6])  # shoulder roll, pitch, yaw (ball joint); elbow (rad)
device = builder.AddNamedSystem(
    "device", JointDevice(lambda t: goal * min(t / 0.5, 1.0), ["roll", "pitch", "yaw", "elbow"])
)
coupling = add_joint_coupling(
    builder,
    plant,
    "arm",
    ["shoulder", "elbow"],
    coupling="cartesian",
    gains=CouplingGains(omega_n=60.0, zeta=1.0, omega_n_rot=60.0),
    device_period_s=device.period_s,
    q_reference=np.zeros(4),
)
for name in ("q_device", "v_device"):
    builder.Connect(device.GetOutputPort(name), coupling.GetInputPort(name))
simulator = Simulator(builder.Build())
simulator.AdvanceTo(2.0)
q = plant.GetPositions(plant.GetMyContextFromRoot(simulator.get_context()))
print("elbow at", q[3], "rad; passive wrist at", q[4], "rad")
