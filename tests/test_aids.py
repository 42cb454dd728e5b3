"""The pseudo-haptic aids on their own (docs/guide/visual.md): the tether, the control/display
ratio and the device code that applies them, fast enough for the mutation run.

Each test drives a :class:`RelativeDevice` alone in a ``Simulator``: the coupling's target T and
god-object G it reads (``pose_WT``, ``pose_WG``) are fixed on its input ports before each sample,
as the coupling would report them, so every number below follows from the increments by hand.
``tests/test_pseudo_haptics.py`` runs the aids in the brick scene.
"""

import math

import numpy as np
import pytest
from conftest import add_free_boxes, assert_refused
from pydrake.common.eigen_geometry import AngleAxis
from pydrake.math import RigidTransform, RotationMatrix
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder

from godobject_drake.config.device_files import IncrementLog, RelativeAids, SampleGuard
from godobject_drake.config.gains import CouplingGains
from godobject_drake.devices.sources import DeviceSource, RelativeDevice
from godobject_drake.spatial import rotation_error
from godobject_drake.station.rigid_tool import add_god_object

T = 0.01  # device period (s)
R, ONSET, CAP = 10.0, 0.005, 0.2  # the ratio, its onset and the force-cap stretch (m)


def rz(angle: float) -> RotationMatrix:
    return RotationMatrix(AngleAxis(angle, [0.0, 0.0, 1.0]))


def pose_array(X: RigidTransform) -> np.ndarray:
    """``[qw qx qy qz x y z]``, the layout of the coupling's ``pose_WT`` and ``pose_WG``."""
    return np.concatenate([X.rotation().ToQuaternion().wxyz(), X.translation()])


def angle_between(R_a: RotationMatrix, R_b: RotationMatrix) -> float:
    return float(np.linalg.norm(rotation_error(R_a.ToQuaternion().wxyz(), R_b.ToQuaternion().wxyz())))


def relative(dps, drots=None, X_WD0=None, aids=None, guard=None, grasp="") -> RelativeDevice:
    """A relative device at 100 Hz whose sample k (k ≥ 1) reports the increments ``dps[k − 1]``
    (m) and ``drots[k − 1]`` (rad, rotation vector), clutch released, holding ``grasp``."""
    n = len(dps)
    log = IncrementLog(
        T * np.arange(1, n + 1),
        np.array(dps, float).reshape(n, 3),
        np.zeros((n, 3)) if drots is None else np.array(drots, float).reshape(n, 3),
        np.zeros(n, bool),
        [grasp] * n,
    )
    return RelativeDevice(log, X_WD0, period_s=T, aids=aids, guard=guard)


class Rig:
    """A device alone, sampled one sample at a time, with the coupling's T and G fixed on its
    inputs before each sample: T = X_WD X_DT (the target where the device put it) and a
    god-object held at ``X_WG`` (an obstacle stops it)."""

    def __init__(self, device: RelativeDevice, X_WG=None, X_DT=None):
        self.device, self.X_WG, self.X_DT = device, X_WG or RigidTransform(), X_DT or RigidTransform()
        self.simulator = Simulator(device)
        self.context = self.simulator.get_mutable_context()
        self.k = -1

    @property
    def X_WD(self) -> RigidTransform:
        return self.device.GetOutputPort("X_WD").Eval(self.context)

    @property
    def X_WT(self) -> RigidTransform:
        return self.X_WD @ self.X_DT

    @property
    def status(self) -> dict:
        return DeviceSource.status_dict(self.device.GetOutputPort("device_status").Eval(self.context))

    def sample(self, n: int = 1) -> RigidTransform:
        """Take the next ``n`` samples; the device pose after them."""
        for _ in range(n):
            self.device.GetInputPort("pose_WT").FixValue(self.context, pose_array(self.X_WT))
            self.device.GetInputPort("pose_WG").FixValue(self.context, pose_array(self.X_WG))
            self.k += 1
            self.simulator.AdvanceTo(self.k * T + 1e-6)
        return self.X_WD


# -- the tether ------------------------------------------------------------------------------------


def test_a_target_5_cm_away_is_reindexed_to_the_2_mm_tether_and_turns_back_at_once():
    # G held at the origin; the device (= T) pushed 5 cm along (3, 4, 0)/5 in one increment
    rig = Rig(relative([[0.03, 0.04, 0.0], [-0.0006, -0.0008, 0.0]], aids=RelativeAids(tether_m=0.002)))
    assert rig.sample().translation() == pytest.approx([0, 0, 0], abs=0)  # t = 0: no increment yet
    assert rig.status["device_tethered_samples"] == 0
    # re-indexed onto the tether, along the same direction: 2 mm × (3, 4, 0)/5
    np.testing.assert_allclose(rig.sample().translation(), [0.0012, 0.0016, 0.0], rtol=0, atol=1e-15)
    assert rig.status["device_tethered_samples"] == 1
    # turning back 1 mm moves the target back 1 mm at once (not 5 cm later): 1 mm from G
    np.testing.assert_allclose(rig.sample().translation(), [0.0006, 0.0008, 0.0], rtol=0, atol=1e-15)
    assert rig.status["device_tethered_samples"] == 1  # within the tether: not re-indexed
    assert rig.status["device_samples"] == 3 and rig.status["device_rejected_jumps"] == 0


def test_the_tether_binds_the_target_not_the_device_point():
    # the target 1 cm below the device point (a grasp offset X_DT), the device turned a quarter
    # turn about z; G at (0.1, 0, 0). Re-indexing moves the device and keeps its turn.
    X_WG = RigidTransform([0.1, 0.0, 0.0])
    X_DT = RigidTransform([0.0, 0.0, -0.01])
    X_WD0 = RigidTransform(rz(math.pi / 2), [0.1, 0.0, 0.01])
    rig = Rig(relative([[0.05, 0.0, 0.0]], X_WD0=X_WD0, aids=RelativeAids(0.002)), X_WG, X_DT)
    rig.sample(2)
    np.testing.assert_allclose(rig.X_WT.translation(), [0.102, 0.0, 0.0], rtol=0, atol=1e-15)
    np.testing.assert_allclose(rig.X_WD.translation(), [0.102, 0.0, 0.01], rtol=0, atol=1e-15)
    np.testing.assert_allclose(rig.X_WD.rotation().matrix(), rz(math.pi / 2).matrix(), rtol=0, atol=1e-15)
    assert rig.status["device_tethered_samples"] == 1


def test_every_sample_the_tether_moves_is_counted():
    # 1 mm per sample, tether 2.5 mm: samples 3, 4 and 5 are re-indexed, the step back is not
    rig = Rig(relative([[1e-3, 0, 0]] * 5 + [[-1e-3, 0, 0]], aids=RelativeAids(tether_m=0.0025)))
    xs, counts = [], []
    for _ in range(7):
        xs.append(rig.sample().translation()[0])
        counts.append(rig.status["device_tethered_samples"])
    np.testing.assert_allclose(xs, [0, 1e-3, 2e-3, 2.5e-3, 2.5e-3, 2.5e-3, 1.5e-3], rtol=0, atol=1e-15)
    assert counts == [0, 0, 0, 1, 2, 3, 3]


def test_the_angle_tether_turns_the_target_back_about_its_own_origin():
    # the target 1 cm ahead of the device point along x; a 0.5 rad turn about z at D's origin
    # swings T to 1 cm × (cos 0.5, sin 0.5, 0); the 0.1 rad tether turns it back to 0.1 rad there
    X_DT = RigidTransform([0.01, 0.0, 0.0])
    rig = Rig(relative([[0, 0, 0]], [[0, 0, 0.5]], aids=RelativeAids(tether_angle_rad=0.1)), X_DT=X_DT)
    rig.sample(2)
    assert angle_between(rig.X_WT.rotation(), RotationMatrix()) == pytest.approx(0.1, rel=1e-12)
    assert np.allclose(rig.X_WT.rotation().matrix(), rz(0.1).matrix(), rtol=0, atol=1e-15)
    np.testing.assert_allclose(
        rig.X_WT.translation(), [0.01 * math.cos(0.5), 0.01 * math.sin(0.5), 0], atol=1e-15
    )
    # D is 1 cm behind T along T's x axis
    np.testing.assert_allclose(
        rig.X_WD.translation(), rig.X_WT.translation() - 0.01 * np.array([math.cos(0.1), math.sin(0.1), 0]),
        atol=1e-15,
    )  # fmt: skip
    assert rig.status["device_tethered_samples"] == 1


def test_rotations_follow_the_raw_increments_each_sample():
    # three 0.1 rad turns about z, then one back: with a loose tether (active, never binding)
    rig = Rig(relative([[0, 0, 0]] * 4, [[0, 0, 0.1]] * 3 + [[0, 0, -0.1]], aids=RelativeAids(tether_m=1.0)))
    for k, angle in enumerate([0.0, 0.1, 0.2, 0.3, 0.2]):
        assert np.allclose(rig.sample().rotation().matrix(), rz(angle).matrix(), rtol=0, atol=1e-14), k
        assert np.linalg.norm(rig.X_WD.rotation().ToQuaternion().wxyz()) == pytest.approx(1.0, abs=1e-15)
    assert rig.status["device_tethered_samples"] == 0


def test_samples_off_unit_within_the_tolerance_turn_nothing():
    # A device's quaternions may be off unit by up to the guard's tolerance (1e-3: accepted, then
    # normalised). An increment device that holds one orientation (0.4 rad about z, |q| = 1.0005)
    # and moves 1 mm a sample must report no rotation increment, from its first sample on.
    class Increments(DeviceSource):
        reports_increments = True

    q = 1.0005 * np.array([math.cos(0.2), 0.0, 0.0, math.sin(0.2)])
    device = Increments(lambda t: ([1e-3 * round(t / T), 0, 0], q, ""), period_s=T, aids=RelativeAids(1.0))
    X = Rig(device).sample(3)
    np.testing.assert_allclose(X.rotation().matrix(), rz(0.4).matrix(), rtol=0, atol=1e-15)
    np.testing.assert_allclose(X.translation(), [2e-3, 0, 0], rtol=0, atol=1e-15)


def test_exactly_at_the_tether_is_not_reindexed():
    # a target exactly at the bound (the same floating-point distance and angle) is left alone
    dp, dR = np.array([0.002, 0.0, 0.0]), rz(0.25).matrix()
    angle = angle_between(RotationMatrix(dR), RotationMatrix())
    aids = RelativeAids(tether_m=0.002, tether_angle_rad=angle)
    X, moved = aids.apply(RigidTransform(), dp, dR, RigidTransform(), RigidTransform())
    assert not moved
    assert X.IsExactlyEqualTo(RigidTransform(RotationMatrix(dR), dp))
    X, moved = aids.apply(RigidTransform(), 1.5 * dp, dR, RigidTransform(), RigidTransform())
    assert moved and X.translation() == pytest.approx([0.002, 0, 0], abs=1e-18)


def test_the_jump_check_compares_raw_samples_not_the_tethered_target():
    # 8 mm per sample under a 1 m/s guard at 100 Hz (≤ 10 mm a sample): the device moves no faster
    # than the guard allows, although it runs 6 to 30 mm ahead of the target held at the tether
    guard = SampleGuard(max_speed_m_s=1.0)
    rig = Rig(relative([[0.008, 0, 0]] * 4, aids=RelativeAids(tether_m=0.002), guard=guard))
    rig.sample(5)
    assert rig.status["device_rejected_jumps"] == 0 and rig.status["device_tethered_samples"] == 4
    assert rig.X_WD.translation() == pytest.approx([0.002, 0, 0], abs=1e-15)
    # a real jump of the device (5 cm in one sample) is still held back
    rig = Rig(relative([[0.05, 0, 0]], aids=RelativeAids(tether_m=0.002), guard=guard))
    rig.sample(2)
    assert rig.status["device_rejected_jumps"] == 1 and rig.X_WD.translation() == pytest.approx([0, 0, 0])


# -- the control/display ratio ---------------------------------------------------------------------


def test_the_ratio_is_1_at_the_onset_and_r_at_the_cap():
    aids = RelativeAids(cd_ratio=R, cd_onset_m=ONSET, cap_stretch_m=CAP)
    assert aids.cd(0.0) == aids.cd(0.004) == aids.cd(ONSET) == 1.0
    assert aids.cd(CAP) == pytest.approx(R, rel=1e-15)
    # linear between: halfway (0.1025 m) 1 + 9/2; past the cap it goes on growing
    assert aids.cd(0.1025) == pytest.approx(5.5, rel=1e-15)
    assert aids.cd(0.395) == pytest.approx(19.0, rel=1e-14)
    assert RelativeAids(cd_ratio=4.0, cd_onset_m=0.0, cap_stretch_m=0.1).cd(0.05) == pytest.approx(2.5)
    assert RelativeAids(cd_ratio=2.0, cd_onset_m=0.0, cap_stretch_m=0.1).cd(0.05) == pytest.approx(1.5)
    assert RelativeAids(cap_stretch_m=CAP).cd(CAP) == 1.0  # R = 1: off


def test_the_outward_part_of_an_increment_is_divided_by_the_ratio_the_tangential_part_kept():
    # T 0.1025 m from G along x, where CD = 5.5: 11 mm out becomes 2 mm, 3 mm across stays 3 mm
    aids = RelativeAids(cd_ratio=R, cd_onset_m=ONSET, cap_stretch_m=CAP)
    X_WD0 = RigidTransform([0.1025, 0.0, 0.0])
    rig = Rig(relative([[0.011, 0.003, 0.0]], X_WD0=X_WD0, aids=aids))
    np.testing.assert_allclose(rig.sample(2).translation(), [0.1045, 0.003, 0.0], rtol=0, atol=1e-15)
    # the same increment pointing back toward G is not scaled
    rig = Rig(relative([[-0.011, 0.003, 0.0]], X_WD0=X_WD0, aids=aids))
    np.testing.assert_allclose(rig.sample(2).translation(), [0.0915, 0.003, 0.0], rtol=0, atol=1e-15)
    # R = 2, halfway from the onset (0) to the cap (0.1 m): CD = 1.5, so 3 mm out becomes 2 mm
    aids2 = RelativeAids(cd_ratio=2.0, cd_onset_m=0.0, cap_stretch_m=0.1)
    rig = Rig(relative([[0.003, 0.0, 0.0]], X_WD0=RigidTransform([0.05, 0, 0]), aids=aids2))
    np.testing.assert_allclose(rig.sample(2).translation(), [0.052, 0.0, 0.0], rtol=0, atol=1e-15)
    # below the onset the device moves one to one
    rig = Rig(relative([[0.001, 0.0, 0.0]], X_WD0=RigidTransform([0.003, 0, 0]), aids=aids))
    np.testing.assert_allclose(rig.sample(2).translation(), [0.004, 0.0, 0.0], rtol=0, atol=1e-15)
    assert rig.status["device_tethered_samples"] == 0  # the ratio re-indexes nothing


def test_the_ratio_scales_along_the_separation_from_g_not_the_device_axes():
    # G at (0, 0, 0.1), T 0.1025 m from it along (0, 0.6, 0.8): 5.5 mm out along that line is 1 mm
    u = np.array([0.0, 0.6, 0.8])
    X_WG = RigidTransform([0.0, 0.0, 0.1])
    aids = RelativeAids(cd_ratio=R, cd_onset_m=ONSET, cap_stretch_m=CAP)
    rig = Rig(relative([0.0055 * u + [0.002, 0, 0]], X_WD0=RigidTransform(X_WG.translation() + 0.1025 * u),
                       aids=aids), X_WG)  # fmt: skip
    expected = X_WG.translation() + 0.1035 * u + [0.002, 0, 0]
    np.testing.assert_allclose(rig.sample(2).translation(), expected, rtol=0, atol=1e-15)


def test_the_ratio_never_scales_a_rotation():
    aids = RelativeAids(cd_ratio=R, cd_onset_m=ONSET, cap_stretch_m=CAP)
    rig = Rig(relative([[0.011, 0, 0]], [[0, 0, 0.2]], X_WD0=RigidTransform([0.1025, 0, 0]), aids=aids))
    X = rig.sample(2)
    assert np.allclose(X.rotation().matrix(), rz(0.2).matrix(), rtol=0, atol=1e-15)
    np.testing.assert_allclose(X.translation(), [0.1045, 0, 0], rtol=0, atol=1e-15)


def test_at_the_god_object_itself_the_increment_passes_whole():
    # s = 0: no direction to scale along, and CD(0) = 1 anyway; no 0/0 on the way
    aids = RelativeAids(cd_ratio=R, cd_onset_m=0.0, cap_stretch_m=CAP)
    with np.errstate(all="raise"):
        X, moved = aids.apply(
            RigidTransform(), np.array([0.01, 0, 0]), np.eye(3), RigidTransform(), RigidTransform()
        )
    assert X.translation() == pytest.approx([0.01, 0, 0], abs=0) and not moved


def test_pushed_in_small_steps_the_target_ends_where_the_curves_integral_says():
    # u + a u²/2 = X − s₀ with a = (R − 1)/(s_cap − s₀): to reach the cap (u = 0.195 m) the device
    # must be pushed X = s₀ + u (R + 1)/2 = 1.0775 m; halfway (u = 0.0975 m), X = 0.321875 m
    aids = RelativeAids(cd_ratio=R, cd_onset_m=ONSET, cap_stretch_m=CAP)
    assert aids.predicted_stretch(1.0775) == pytest.approx(CAP, rel=1e-12)
    assert aids.predicted_stretch(0.321875) == pytest.approx(0.1025, rel=1e-12)
    assert aids.predicted_stretch(0.004) == 0.004 and aids.predicted_stretch(ONSET) == ONSET
    assert RelativeAids(cap_stretch_m=CAP).predicted_stretch(0.3) == 0.3  # R = 1: one to one
    # The device pushed 322 mm in 1 mm increments from G: each increment is scaled by the ratio
    # where it starts, forward Euler on ds/dX = 1/CD(s), whose error is (h/2)(1/CD) ln(CD/CD₀) at
    # the end (CD₀ = 1, CD ≈ 5.5, h = 1 mm): 0.155 mm past the integral's 102.5 mm.
    rig = Rig(relative([[0.001, 0, 0]] * 322, aids=aids))
    x = rig.sample(323).translation()[0]
    exact = aids.predicted_stretch(0.322)
    cd = aids.cd(exact)
    assert x - exact == pytest.approx(0.0005 / cd * math.log(cd), rel=0.05)


# -- what a device accepts --------------------------------------------------------------------------


def test_aids_add_the_coupling_inputs_only_when_active():
    active = relative([[0, 0, 0]], aids=RelativeAids(tether_m=0.01))
    assert [active.get_input_port(i).get_name() for i in range(active.num_input_ports())] == [
        "pose_WT",
        "pose_WG",
    ]
    assert all(active.get_input_port(i).size() == 7 for i in range(2))
    # inactive aids (no tether, ratio 1) are no aids: no inputs, and the device runs on its own
    for device in (relative([[0.05, 0, 0]], aids=RelativeAids()), relative([[0.05, 0, 0]])):
        assert device.num_input_ports() == 0 and device.aids is None
        simulator = Simulator(device)
        simulator.AdvanceTo(T + 1e-6)
        assert device.GetOutputPort("X_WD").Eval(simulator.get_context()).translation()[0] == 0.05
    # an absolute device takes inactive aids, and refuses active ones
    absolute = DeviceSource(lambda t: ([0.0, 0.0, 0.0], [1.0, 0.0, 0.0, 0.0], ""), aids=RelativeAids())
    assert absolute.num_input_ports() == 0
    assert_refused(
        lambda: DeviceSource(lambda t: ([0.0, 0.0, 0.0], [1.0, 0.0, 0.0, 0.0], ""), aids=RelativeAids(0.01)),
        ValueError,
        value=r"^a tether or control/display ratio re-indexes a device's increments; a DeviceSource reports",
        limit=r"absolute poses, which cannot be re-indexed \(the target would no longer be where the device",
        fix=r"Use a relative or live device, or leave the aids off$",
    )


def test_wired_to_a_coupling_the_aids_close_the_loop_without_an_algebraic_cycle():
    # add_god_object wires the coupling's pose_WT and pose_WG, which follow the device's X_WD and
    # V_WD at once, back into the device: the loop builds only because the device's X_WD and V_WD
    # depend on its state alone. One free box, held from t = 0, no gravity: at rest where the
    # device starts, so the 5 cm increment of sample 1 is re-indexed to the 2 mm tether.
    builder = DiagramBuilder()
    plant, _ = add_free_boxes(builder, 1e-3, gravity=False)
    device = relative([[0.05, 0, 0]], aids=RelativeAids(tether_m=0.002), grasp="body_0")
    builder.AddNamedSystem("device", device)
    add_god_object(builder, plant, device, CouplingGains(40.0))
    simulator = Simulator(builder.Build())
    simulator.AdvanceTo(T + 1e-6)
    context = device.GetMyContextFromRoot(simulator.get_context())
    assert device.GetOutputPort("X_WD").Eval(context).translation() == pytest.approx([0.002, 0, 0], abs=1e-15)
    assert (
        DeviceSource.status_dict(device.GetOutputPort("device_status").Eval(context))[
            "device_tethered_samples"
        ]
        == 1
    )


def test_wired_to_a_coupling_the_ratio_grows_to_r_at_its_force_cap():
    # add_god_object hands the coupling's force-cap stretch (here 0.1 m) to the ratio: R = 4 there,
    # 2.5 halfway from an onset of 0; an onset past the cap is refused, naming the coupling's cap
    def wire(aids):
        builder = DiagramBuilder()
        plant, _ = add_free_boxes(builder, 1e-3, gravity=False)
        device = builder.AddNamedSystem("device", relative([[0.001, 0, 0]], aids=aids, grasp="body_0"))
        add_god_object(builder, plant, device, CouplingGains(40.0), max_stretch_m=0.1)
        return device

    device = wire(RelativeAids(cd_ratio=4.0, cd_onset_m=0.0))
    assert device.aids.cap_stretch_m == 0.1
    assert device.aids.cd(0.1) == 4.0 and device.aids.cd(0.05) == 2.5
    assert_refused(
        lambda: wire(RelativeAids(cd_ratio=4.0, cd_onset_m=0.3)),
        ValueError,
        value=r"^cd_ratio=4 grows to R at the coupling's force-cap stretch, which is 0\.1 m;",
        limit=r"it must be finite and past cd_onset_m=0\.3 m\.",
        fix=r" Set god_object\.max_stretch_m, or a smaller cd_onset_m$",
    )


def test_aids_without_the_coupling_wired_say_what_to_connect():
    device = relative([[0.001, 0, 0]], aids=RelativeAids(tether_m=0.01))
    device.set_name("mouse")
    assert_refused(
        lambda: Simulator(device).AdvanceTo(T),
        RuntimeError,
        value=r"^mouse: a tether or control/display ratio",
        limit=r"needs the coupling's pose_WT and pose_WG on the device's inputs of the same names",
        fix=r"connect them \(godobject_drake\.add_god_object does\), or build the "
        r"device without",
    )


REFUSED = {  # RelativeAids(**kw): (the value, the limit, the fix), as regular expressions
    "zero tether": ({"tether_m": 0.0}, r"^tether_m=0\.0 m", r"must be > 0", r"\(inf: no tether\)$"),
    "negative tether": ({"tether_m": -0.01}, r"^tether_m=-0\.01 m", r"must be > 0", r"inf: no tether"),
    "NaN tether": ({"tether_m": math.nan}, r"^tether_m=nan m", r"must be > 0", r"inf: no tether"),
    "zero tether angle": (
        {"tether_angle_rad": 0.0}, r"^tether_angle_rad=0\.0 rad", r"must be > 0", r"\(inf: no tether\)$",
    ),
    "ratio below 1": ({"cd_ratio": 0.5}, r"^cd_ratio=0\.5", r"must be ≥ 1", r"\(1: off; e\.g\. 10\)$"),
    "infinite ratio": ({"cd_ratio": math.inf}, r"^cd_ratio=inf", r"must be ≥ 1", r"1: off"),
    "NaN ratio": ({"cd_ratio": math.nan}, r"^cd_ratio=nan", r"must be ≥ 1", r"1: off"),
    "negative onset": ({"cd_onset_m": -0.001}, r"^cd_onset_m=-0\.001 m", r"must be ≥ 0$", r"≥ 0"),
    "infinite onset": ({"cd_onset_m": math.inf}, r"^cd_onset_m=inf m", r"must be ≥ 0$", r"≥ 0"),
}  # fmt: skip


@pytest.mark.parametrize("case", REFUSED)
def test_bad_aid_values_are_refused(case):
    kw, value, limit, fix = REFUSED[case]
    assert_refused(lambda: RelativeAids(**kw), ValueError, value=value, limit=limit, fix=fix)


def test_aid_values_at_their_limits_are_accepted():
    for kw in ({"cd_ratio": 1.0}, {"cd_onset_m": 0.0}, {"tether_m": 1e-9, "tether_angle_rad": 1e-9}):
        RelativeAids(**kw).check()
    assert not RelativeAids().active and RelativeAids(tether_angle_rad=0.1).tethered


@pytest.mark.parametrize("cap", [math.inf, math.nan, ONSET, 0.004])
def test_a_ratio_with_no_force_cap_past_its_onset_is_refused(cap):
    assert_refused(
        lambda: RelativeAids(cd_ratio=4.0, cd_onset_m=ONSET).check_cap(cap),
        ValueError,
        value=rf"^cd_ratio=4 grows to R at the coupling's force-cap stretch, which is {cap!r} m;",
        limit=r"it must be finite and past cd_onset_m=0\.005 m\.",
        fix=r" Set god_object\.max_stretch_m, or a smaller cd_onset_m$",
    )


def test_a_force_cap_past_the_onset_or_no_ratio_is_accepted():
    RelativeAids(cd_ratio=4.0, cd_onset_m=ONSET).check_cap(0.0051)
    RelativeAids(cd_ratio=1.0, cd_onset_m=ONSET).check_cap(math.inf)  # no ratio: no cap needed
