"""Probe (issue 31): the god-object's spring integrated implicitly by SAP, as compliant distance
constraints between a carrier body and the held brick. Measurement only, not a coupling of the
library.

    python analysis/probe_implicit_springs.py H[,H...] [CAP_M] [REST_M] [--time]

The carrier (a 6-joint chain: 3 prismatic, then yaw, pitch, roll revolute joints; 100 kg, no
geometry) is driven to the target by SAP's PD-controlled actuators, stiff and implicit. Seven
springs (distance constraints of rest length REST, 0.1 mm) join corresponding points of carrier
and brick: the centre of mass (carrying the weight: its carrier end raised by m g / k0) and the
centre of mass ± 5 cm along each body axis, their stiffnesses and dampings chosen so the seven
sum to the paper's k = m ωn², γ = 2 ζ m ωn in translation and to I ωr², 2 ζ I ωr about each
axis. Distance constraints are compliant and solved implicitly by SAP, and their bodies, points,
stiffness and damping live in the context (``SetDistanceConstraintParams``), so a grasp can
retarget them to any body without changing the plant. The force cap is the target held to within
CAP (5 cm) of the brick's centre of mass at each device sample (60 Hz): Python runs at the device
rate only.

Measured with Drake 1.51.1 on the shipped brick path (8.5 s, whole path, release included):
deepest penetration 0.13 mm at h = 1 ms, 0.27 mm at 2 ms, 1.00 mm at 5 ms and 8.3 mm at 10 ms
(stable); the explicit coupling gives 0.54, 1.29 and 5.28 mm at 1, 2 and 5 ms. The brick climbs
the wall pitched at most 31° (the explicit coupling stands it on end, 90°) and is laid across
brick_1 within 2 mm. Long springs (10 m, nearly parallel) were tried first: their restoring
torque goes as sin 2θ, so the brick flipped over at the wall; zero-length springs restore as
sin θ. At h = 4 ms: 0.78 mm, 0.22-0.28 CPU s per simulated s (``--time``, 2 cores, AMD EPYC,
beside another developer's tests) against 0.50-0.55 s per simulated s for the explicit coupling
at 1 ms (0.54 mm) in the same runs: about 2x faster within a 1 mm budget, and this probe keeps
every brick awake where the library's scene sleeps them.
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

REST = float(sys.argv[3]) if len(sys.argv) > 3 else 1e-4  # the springs' rest length (m)
CARRIER_W = 500.0  # the carrier's PD bandwidth (rad/s), implicit
CARRIER_R = 1.0  # its radius (m): heavy in rotation, so the springs' reaction barely turns it


def build(h, duration, omega_n=40.0, zeta=1.0, omega_r=120.0, a_min=0.05, carrier_mass=100.0):
    s = sc.shipped_scenario("lego")
    s.plant.time_step = h
    builder = DiagramBuilder()
    parts = {}

    def before(plant, sg):
        hand = plant.AddModelInstance("carrier")
        eps = SpatialInertia.SolidSphereWithMass(1e-6, 1e-3)
        links = [plant.AddRigidBody(f"L{i}", hand, eps) for i in range(5)]
        C = plant.AddRigidBody("C", hand, SpatialInertia.SolidSphereWithMass(carrier_mass, CARRIER_R))
        links.append(C)
        axes = np.eye(3)
        parent, joints = plant.world_body(), []
        for i in range(3):
            joints.append(
                plant.AddJoint(PrismaticJoint(f"p{i}", parent.body_frame(), links[i].body_frame(), axes[i]))
            )
            parent = links[i]
        for i, ax in enumerate((2, 1, 0)):  # yaw, pitch, roll: R = Rz Ry Rx, Drake's RollPitchYaw
            joints.append(
                plant.AddJoint(
                    RevoluteJoint(f"r{i}", parent.body_frame(), links[3 + i].body_frame(), axes[ax])
                )
            )
            parent = links[3 + i]
        Ic = 0.4 * carrier_mass * CARRIER_R**2
        for i, j in enumerate(joints):
            mm = carrier_mass if i < 3 else Ic
            a = plant.AddJointActuator(f"a{i}", j)
            a.set_controller_gains(PdControllerGains(p=mm * CARRIER_W**2, d=2 * mm * CARRIER_W))
        brick = plant.GetBodyByName("brick", plant.GetModelInstanceByName("brick_0"))
        Mb = brick.default_spatial_inertia()
        m, p_cm = Mb.get_mass(), Mb.get_com()
        I_cm = Mb.CalcRotationalInertia().ShiftToCenterOfMass(m, p_cm).CopyToFullMatrix3()
        k, g = m * omega_n**2, 2 * zeta * m * omega_n
        ids = []
        e = np.eye(3)
        EPS = REST
        # zero-length springs (rest EPS) between corresponding points: the COM and COM ± a e_j
        Iw = np.diag(I_cm) * omega_r**2  # rotational stiffness wanted about each axis
        Ig = np.diag(I_cm) * 2 * zeta * omega_r
        a = 0.05
        kj = np.array([(Iw[1] + Iw[2] - Iw[0]), (Iw[0] + Iw[2] - Iw[1]), (Iw[0] + Iw[1] - Iw[2])]) / (
            4 * a * a
        )
        gj = np.array([(Ig[1] + Ig[2] - Ig[0]), (Ig[0] + Ig[2] - Ig[1]), (Ig[0] + Ig[1] - Ig[2])]) / (
            4 * a * a
        )
        k0, g0 = k - 2 * kj.sum(), g - 2 * gj.sum()
        assert k0 > 0 and g0 > 0, (k0, g0)
        grav = m * 9.81
        # the COM spring: its carrier end EPS below... along -x, and raised by m g / k0 (gravity)
        ids.append(plant.AddDistanceConstraint(C, np.array([EPS, 0, grav / k0]), brick, p_cm, EPS, k0, g0))
        for j in range(3):
            for sgn in (1, -1):
                off = sgn * a * e[j]
                ids.append(
                    plant.AddDistanceConstraint(
                        C, off + EPS * e[(j + 1) % 3], brick, p_cm + off, EPS, kj[j], gj[j]
                    )
                )
        parts.update(hand=hand, joints=joints, brick=brick, ids=ids, m=m, p_cm=p_cm)

    scene = add_plant(builder, s, before)
    plant = scene.plant
    dev = builder.AddSystem(s.device.make(duration_s=duration))
    X_WB0 = plant.EvalBodyPoseInWorld(plant.CreateDefaultContext(), parts["brick"])
    p_cm = parts["p_cm"]

    CAP = float(sys.argv[2]) if len(sys.argv) > 2 else 0.05
    brick_index = int(parts["brick"].index())
    period = 1.0 / 60.0

    class Desired(LeafSystem):
        """The carrier's desired state: the target (device x grasp offset), held to within CAP of
        the brick's COM as it stood at the last device sample (the force cap, at the device rate)."""

        def __init__(self):
            super().__init__()
            self.X = self.DeclareAbstractInputPort("X_WD", AbstractValue.Make(RigidTransform()))
            self.V = self.DeclareVectorInputPort("V_WD", 6)
            self.poses = self.DeclareAbstractInputPort("body_poses", AbstractValue.Make([RigidTransform()]))
            self.X_DG, self.calls = None, 0
            self.g = self.DeclareDiscreteState(X_WB0 @ p_cm)
            self.DeclarePeriodicDiscreteUpdateEvent(period, 0.0, self.sample)
            self.DeclareVectorOutputPort(
                "xd", 12, self.calc, {self.X.ticket(), self.V.ticket(), self.xd_ticket()}
            )

        def sample(self, c, ds):
            ds.set_value(self.g, self.poses.Eval(c)[brick_index] @ p_cm)

        def calc(self, c, out):
            self.calls += 1
            X_WD = self.X.Eval(c)
            if self.X_DG is None:
                self.X_DG = X_WD.inverse() @ X_WB0
            X_WT = X_WD @ self.X_DG
            p = X_WT @ p_cm
            g = c.get_discrete_state(self.g).get_value()
            s = np.linalg.norm(p - g)
            if s > CAP:
                p = g + (p - g) * (CAP / s)
            V = self.V.Eval(c)
            v = V[3:] + np.cross(V[:3], p - X_WD.translation())
            out.SetFromVector(
                np.concatenate([p, RollPitchYaw(X_WT.rotation()).vector()[::-1], v, np.zeros(3)])
            )

    des = builder.AddSystem(Desired())
    builder.Connect(dev.GetOutputPort("X_WD"), des.X)
    builder.Connect(dev.GetOutputPort("V_WD"), des.V)
    builder.Connect(plant.get_body_poses_output_port(), des.poses)
    builder.Connect(des.get_output_port(), plant.get_desired_state_input_port(parts["hand"]))
    ff = np.zeros(6)
    ff[2] = (carrier_mass + 3e-6) * 9.81
    builder.Connect(
        builder.AddSystem(ConstantVectorSource(ff)).get_output_port(),
        plant.get_actuation_input_port(parts["hand"]),
    )
    return builder.Build(), plant, parts, des, X_WB0


def place_carrier(plant, pc, parts, X_WB):
    X_WC = RigidTransform(X_WB.rotation(), X_WB @ parts["p_cm"])
    q = np.concatenate([X_WC.translation(), RollPitchYaw(X_WC.rotation()).vector()[::-1]])
    for j, qi in zip(parts["joints"], q, strict=True):
        j.set_translation(pc, qi) if isinstance(j, PrismaticJoint) else j.set_angle(pc, qi)


def penetration(plant, pc, parts):
    q = plant.get_geometry_query_input_port().Eval(pc)
    ids = set(plant.GetCollisionGeometriesForBody(parts["brick"]))
    return max(
        [p.depth for p in q.ComputePointPairPenetration() if p.id_A in ids or p.id_B in ids], default=0.0
    )


def run(h, duration=8.5, measure=True):
    diagram, plant, parts, des, X_WB0 = build(h, duration)
    sim = Simulator(diagram)
    pc = plant.GetMyMutableContextFromRoot(sim.get_mutable_context())
    place_carrier(plant, pc, parts, X_WB0)
    sim.Initialize()
    n, release = round(duration / h), round(7.5 / h)
    maxpen, pen_at, wall, traj, k = 0.0, 0.0, 0.0, [], 0
    while k < n:
        step = 1 if measure else ((release if k < release else n) - k)
        t0 = time.process_time()
        sim.AdvanceTo((k + step) * h)
        wall += time.process_time() - t0
        k += step
        if k == release:
            for cid in parts["ids"]:
                plant.SetConstraintActiveStatus(pc, cid, False)
        if measure:
            d = penetration(plant, pc, parts)
            if d > maxpen:
                maxpen, pen_at = d, k * h
            X = plant.EvalBodyPoseInWorld(pc, parts["brick"])
            traj.append(np.concatenate([X.translation(), np.degrees(RollPitchYaw(X.rotation()).vector())]))
    if traj:
        for tt in (0.5, 1.0, 2.0, 2.5, 3.0, 3.1, 3.2, 3.3, 3.5, 4.0, 5.0, 6.0, 7.0, 7.4, 8.4):
            print(f"  t={tt}: {np.round(traj[min(len(traj) - 1, round(tt / h) - 1)], 4)}")
    return dict(
        h=h,
        finite=bool(np.all(np.isfinite(plant.GetPositions(pc)))),
        max_penetration_m=maxpen,
        at=pen_at,
        us_per_step=wall / n * 1e6,
        desired_calls=des.calls,
    )


if __name__ == "__main__":
    measure = "--time" not in sys.argv
    for h in [float(x) for x in sys.argv[1].split(",")]:
        print("h", h, "cap", sys.argv[2] if len(sys.argv) > 2 else 0.05)
        print(run(h, measure=measure), flush=True)
