"""Probe (issue 31): the god-object's spring as SAP's PD-controlled actuators on a 6-joint "hand"
chain (3 prismatic + 3 revolute, no geometry), welded to the held brick by a weld constraint that
is switched on in the context (``SetConstraintActiveStatus``), so grasping any body needs no
change of the plant. Measurement only, not a coupling of the library.

    python analysis/probe_implicit_hand.py H[,H...] [HAND_LINK_MASS_KG] [SAP_NEAR_RIGID_THRESHOLD]

Prints the brick's position along the shipped path and its deepest penetration. Measured with
Drake 1.51.1 (docs/design.md "What Drake does here"): with links of 1e-5 kg the hand follows the
target but the brick never moves, whatever the near-rigid threshold (1, 0.01, 0 give the same
trajectory to the last digit); with 1e-3 kg (43 % of the brick) it is carried along the whole
path at h = 1 ms (grasp, wall, climb, release on brick_1; 0.69 mm deepest) and 2 ms (0.26 mm),
but at 5 ms it is dragged along the table without being lifted, and at 10 ms it never moves,
though the run stays stable. The weld is regularized near-rigid on the lighter body's mass and
the step, so a light hand couples nothing and the coupling weakens as the step grows: a hand
welded on does not buy a larger step.
"""

import sys
import time

import numpy as np
from pydrake.all import (
    AbstractValue,
    ConstantVectorSource,
    DiagramBuilder,
    LeafSystem,
    PdControllerGains,
    PrismaticJoint,
    RevoluteJoint,
    RigidTransform,
    RollPitchYaw,
    Simulator,
    SpatialInertia,
)

from godobject_drake.config import scenario as sc
from godobject_drake.station.plant import add_plant

HAND_MASS = float(sys.argv[2]) if len(sys.argv) > 2 else 1e-5
BETA = float(sys.argv[3]) if len(sys.argv) > 3 else 1.0


def build(h, duration, omega_n=40.0, zeta=1.0, omega_r=120.0, cap_m=0.05):
    s = sc.shipped_scenario("lego")
    s.plant.time_step = h
    s.plant.sap_near_rigid_threshold = BETA
    builder = DiagramBuilder()
    parts = {}

    def before(plant, sg):
        hand = plant.AddModelInstance("hand")
        M = SpatialInertia.SolidSphereWithMass(HAND_MASS, 1e-3)
        links = [plant.AddRigidBody(f"L{i}", hand, M) for i in range(6)]
        axes = np.eye(3)
        parent = plant.world_body()
        joints = []
        for i in range(3):
            joints.append(
                plant.AddJoint(PrismaticJoint(f"p{i}", parent.body_frame(), links[i].body_frame(), axes[i]))
            )
            parent = links[i]
        for i in range(3):
            joints.append(
                plant.AddJoint(
                    RevoluteJoint(f"r{i}", parent.body_frame(), links[3 + i].body_frame(), axes[i])
                )
            )
            parent = links[3 + i]
        brick = plant.GetBodyByName("brick", plant.GetModelInstanceByName("brick_0"))
        Mb = brick.default_spatial_inertia()
        m = Mb.get_mass()
        p_cm = Mb.get_com()
        I_cm = Mb.CalcRotationalInertia().ShiftToCenterOfMass(m, p_cm).CopyToFullMatrix3()
        kp, kd = m * omega_n**2, 2 * zeta * m * omega_n
        Ibar = float(np.trace(I_cm)) / 3
        kpr, kdr = Ibar * omega_r**2, 2 * zeta * Ibar * omega_r
        for i, j in enumerate(joints):
            a = plant.AddJointActuator(f"a{i}", j, effort_limit=(kp * cap_m if i < 3 else kpr * 0.5))
            a.set_controller_gains(PdControllerGains(p=kp if i < 3 else kpr, d=kd if i < 3 else kdr))
        X_BQ = RigidTransform(p_cm)
        cid = plant.AddWeldConstraint(links[5], RigidTransform(), brick, X_BQ)
        parts.update(hand=hand, links=links, joints=joints, brick=brick, cid=cid, m=m, p_cm=p_cm)

    scene = add_plant(builder, s, before)
    plant = scene.plant
    dev = builder.AddSystem(s.device.make(duration_s=duration))
    # desired state from the device: T = D X_DG, G's COM target; X_DG from the rest pose
    ctx0 = plant.CreateDefaultContext()
    X_WB0 = plant.EvalBodyPoseInWorld(ctx0, parts["brick"])
    p_cm = parts["p_cm"]

    class Desired(LeafSystem):
        def __init__(self):
            super().__init__()
            self.X = self.DeclareAbstractInputPort("X_WD", AbstractValue.Make(RigidTransform()))
            self.V = self.DeclareVectorInputPort("V_WD", 6)
            self.X_DG = None
            self.DeclareVectorOutputPort("xd", 12, self.calc, {self.X.ticket(), self.V.ticket()})
            self.calls = 0

        def calc(self, c, out):
            self.calls += 1
            X_WD = self.X.Eval(c)
            if self.X_DG is None:
                self.X_DG = X_WD.inverse() @ X_WB0
            X_WT = X_WD @ self.X_DG
            p = X_WT @ p_cm
            rpy = RollPitchYaw(X_WT.rotation()).vector()
            V = self.V.Eval(c)
            v = V[3:] + np.cross(V[:3], p - X_WD.translation())
            out.SetFromVector(np.concatenate([p, rpy, v, np.zeros(3)]))

    des = builder.AddSystem(Desired())
    builder.Connect(dev.GetOutputPort("X_WD"), des.X)
    builder.Connect(dev.GetOutputPort("V_WD"), des.V)
    builder.Connect(des.get_output_port(), plant.get_desired_state_input_port(parts["hand"]))
    g = 9.81
    ff = np.zeros(6)
    ff[2] = (parts["m"] + 4 * HAND_MASS) * g
    src = builder.AddSystem(ConstantVectorSource(ff))
    builder.Connect(src.get_output_port(), plant.get_actuation_input_port(parts["hand"]))
    diagram = builder.Build()
    return diagram, plant, scene, parts, des, X_WB0


def teleport(plant, pc, parts, X_WB):
    X_WC = RigidTransform(X_WB.rotation(), X_WB @ parts["p_cm"])
    q = np.concatenate([X_WC.translation(), RollPitchYaw(X_WC.rotation()).vector()])
    for j, qi in zip(parts["joints"], q, strict=True):
        j.set_translation(pc, qi) if isinstance(j, PrismaticJoint) else j.set_angle(pc, qi)


def penetration(plant, pc, parts, sg_query):
    q = plant.get_geometry_query_input_port().Eval(pc)
    ids = set(plant.GetCollisionGeometriesForBody(parts["brick"]))
    d = 0.0
    for pair in q.ComputePointPairPenetration():
        if pair.id_A in ids or pair.id_B in ids:
            d = max(d, pair.depth)
    return d


def run(h, duration=8.5, measure=True):
    diagram, plant, _, parts, des, X_WB0 = build(h, duration)
    sim = Simulator(diagram)
    root = sim.get_mutable_context()
    pc = plant.GetMyMutableContextFromRoot(root)
    for cid in plant.GetConstraintIds():
        plant.SetConstraintActiveStatus(pc, cid, cid == parts["cid"])
    teleport(plant, pc, parts, X_WB0)
    sim.Initialize()
    n = round(duration / h)
    release = round(7.5 / h)
    maxpen, pen_at, maxv = 0.0, 0.0, 0.0
    wall = 0.0
    traj = []
    k = 0
    while k < n:
        stop = min(n, release) if k < release else n
        step = 1 if measure else stop - k
        t0 = time.perf_counter()
        sim.AdvanceTo((k + step) * h)
        wall += time.perf_counter() - t0
        k += step
        if k == release:
            plant.SetConstraintActiveStatus(pc, parts["cid"], False)
        if measure:
            d = penetration(plant, pc, parts, None)
            if d > maxpen:
                maxpen, pen_at = d, k * h
            X = plant.EvalBodyPoseInWorld(pc, parts["brick"])
            traj.append(X.translation().copy())
            v = plant.GetVelocities(pc)
            maxv = max(maxv, float(np.max(np.abs(v))))
    ok = bool(np.all(np.isfinite(plant.GetPositions(pc))))
    for tt in (0.5, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 7.4, 8.4):
        i = min(len(traj) - 1, round(tt / h) - 1)
        if traj:
            print(tt, np.round(traj[i], 4))
    return dict(
        h=h,
        finite=ok,
        max_penetration_m=maxpen,
        at=pen_at,
        wall_s=wall,
        us_per_step=wall / n * 1e6,
        max_speed=maxv,
        desired_calls=des.calls,
        final=traj[-1] if traj else None,
    )


if __name__ == "__main__":
    for h in [float(x) for x in sys.argv[1].split(",")]:
        r = run(h, measure=True)
        print({k: (round(v, 6) if isinstance(v, float) else v) for k, v in r.items()}, flush=True)
