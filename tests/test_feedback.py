"""The feedback port alone: fixed inputs, hand-computed wrench."""

import numpy as np
import pytest
from pydrake.math import RigidTransform

from godobject_drake.config.gains import FeedbackGains
from godobject_drake.systems.feedback import FeedbackPort

IDENTITY_Q = [1.0, 0, 0, 0]


def wrench(gains, p_WD, pose_WT, V_WT, pose_WG, V_WG):
    port = FeedbackPort(gains)
    context = port.CreateDefaultContext()
    port.GetInputPort("X_WD").FixValue(context, RigidTransform(p_WD))
    for name, value in (("pose_WT", pose_WT), ("V_WT", V_WT), ("pose_WG", pose_WG), ("V_WG", V_WG)):
        port.GetInputPort(name).FixValue(context, np.asarray(value, float))
    return port.GetOutputPort("F_Do_W").Eval(context)


def test_stiffness_pulls_device_toward_god_object_and_moves_to_device_point():
    # G is 1 cm along +x of its target T; T is 0.1 m along +y of the device point Do.
    F = wrench(
        FeedbackGains(kd=100.0),
        p_WD=[0, 0, 0],
        pose_WT=[*IDENTITY_Q, 0, 0.1, 0],
        V_WT=np.zeros(6),
        pose_WG=[*IDENTITY_Q, 0.01, 0.1, 0],
        V_WG=np.zeros(6),
    )
    # f = kd (p_G − p_T) = 100 · 0.01 x̂ = 1 N x̂; τ_Do = p_DoT × f = 0.1 ŷ × 1 x̂ = −0.1 ẑ N·m.
    np.testing.assert_allclose(F, [0, 0, -0.1, 1.0, 0, 0], atol=1e-12)


def test_damping_and_rotation():
    a = np.radians(30)
    F = wrench(
        FeedbackGains(gamma_d=2.0, kd_rot=0.5, gamma_d_rot=0.1),
        p_WD=[0, 0, 0],
        pose_WT=[*IDENTITY_Q, 0, 0, 0],
        V_WT=[0, 0, 1.0, 0, 0, 0.5],
        pose_WG=[np.cos(a / 2), 0, 0, np.sin(a / 2), 0, 0, 0],
        V_WG=np.zeros(6),
    )
    # f = γd (v_G − v_T) = 2 · (−0.5 ẑ); τ = kd_r · 30° ẑ + γd_r (w_G − w_T) = 0.5 a − 0.1.
    np.testing.assert_allclose(F, [0, 0, 0.5 * a - 0.1, 0, 0, -1.0], atol=1e-12)


def test_zero_gains_is_a_non_haptic_device():
    F = wrench(
        FeedbackGains(), [0, 0, 0], [*IDENTITY_Q, 0, 0, 0], np.ones(6), [*IDENTITY_Q, 1, 2, 3], np.zeros(6)
    )
    assert np.all(F == 0.0)


def test_negative_gain_is_refused():
    with pytest.raises(ValueError, match="kd=-1"):
        FeedbackGains(kd=-1.0)


def test_the_moment_is_taken_about_the_device_point_wherever_it_is():
    """Do at (1, 2, 0), T at (1, 2.1, 0): the arm p_DoT is 0.1 ŷ (not p_WT + p_WD), so with
    f = 1 N x̂ the moment is −0.1 ẑ N·m as in the first test, moved by (1, 2, 0)."""
    F = wrench(
        FeedbackGains(kd=100.0),
        p_WD=[1.0, 2.0, 0.0],
        pose_WT=[*IDENTITY_Q, 1.0, 2.1, 0],
        V_WT=np.zeros(6),
        pose_WG=[*IDENTITY_Q, 1.01, 2.1, 0],
        V_WG=np.zeros(6),
    )
    np.testing.assert_allclose(F, [0, 0, -0.1, 1.0, 0, 0], atol=1e-12)
