"""HapticDevice alone: FixValue the force, step it, compare with the hand-computed ZOH."""

import math

import numpy as np
import pytest
from pydrake.math import RigidTransform
from pydrake.systems.analysis import Simulator

from godobject_drake.limits import zoh_mass_damper
from godobject_drake.systems.haptic import HapticDevice


def test_zoh_closed_form_matches_matrix_exponential():
    from scipy.linalg import expm

    m, b, T = 0.1, 2.0, 1e-3
    M = np.zeros((3, 3))
    M[0, 1], M[1, 1], M[1, 2] = 1.0, -b / m, 1.0 / m
    E = expm(M * T)
    A, B = zoh_mass_damper(m, b, T)
    np.testing.assert_allclose(A, E[:2, :2], rtol=1e-12, atol=1e-16)
    np.testing.assert_allclose(B, E[:2, 2], rtol=1e-10)
    # no damping: free mass, x = f T²/2m
    _, B0 = zoh_mass_damper(m, 0.0, T)
    np.testing.assert_allclose(B0, [T**2 / (2 * m), T / m])


def run_device(device, force, human=None, steps=3):
    sim = Simulator(device)
    ctx = sim.get_mutable_context()
    device.GetInputPort("F_Do_W").FixValue(ctx, np.concatenate([np.zeros(3), force]))
    if human is not None:
        device.GetInputPort("human_force").FixValue(ctx, human)
    sim.AdvanceTo(steps * device.period_s)
    return sim.get_context()


def test_constant_force_moves_the_device_as_the_exact_zoh():
    dev = HapticDevice(
        mass=0.2, damping=1.0, period_s=1e-3, axes="z", X_WD_home=RigidTransform([0.1, 0.0, 0.3])
    )
    f = 0.5
    ctx = run_device(dev, [0.0, 0.0, f], steps=3)
    # AdvanceTo(3T) runs the updates at 0, T and 2T (the mechanics reach 3T) and the
    # sample events just before T, 2T and 3T (the published sample is x(3T)).
    A, B = zoh_mass_damper(0.2, 1.0, 1e-3)
    s = np.zeros(2)
    x_at = [0.0]
    for _ in range(3):
        s = A @ s + B * f
        x_at.append(s[0])
    x, v = dev.GetOutputPort("device_state").Eval(ctx)
    assert (x, v) == (pytest.approx(x_at[3], rel=1e-12), pytest.approx(s[1], rel=1e-12))
    X_WD = dev.GetOutputPort("X_WD").Eval(ctx)
    np.testing.assert_allclose(X_WD.translation(), [0.1, 0.0, 0.3 + x_at[3]], rtol=1e-12)
    V_WD = dev.GetOutputPort("V_WD").Eval(ctx)
    assert V_WD[5] == pytest.approx((x_at[3] - x_at[2]) / 1e-3, rel=1e-12)
    # Work of the held force: f times the displacement.
    w_user, w_fb = dev.GetOutputPort("work").Eval(ctx)
    assert w_user == 0.0
    assert w_fb == pytest.approx(f * x_at[3], rel=1e-12)


def test_delay_holds_the_force_back_by_whole_samples():
    ctx_now = run_device(HapticDevice(delay=0, axes="x"), [1.0, 0.0, 0.0], steps=2)
    ctx_late = run_device(HapticDevice(delay=2, axes="x"), [1.0, 0.0, 0.0], steps=4)
    # With d = 2 the first two updates apply zero force: the motion lags by 2T exactly.
    a = ctx_now.get_discrete_state_vector().value()[2]
    b = ctx_late.get_discrete_state_vector().value()[2]
    assert a > 0 and b == pytest.approx(a, rel=1e-12)


def test_user_force_and_3dof_axes():
    dev = HapticDevice(mass=0.1, damping=0.0, period_s=1e-3, axes="xyz")
    ctx = run_device(dev, [0.0, 0.0, 0.0], human=np.array([0.0, 2.0, 0.0]), steps=0)
    # one update at t = 0 with 2 N along y: x = f T²/(2m)
    x = dev.GetOutputPort("device_state").Eval(ctx)[:3]
    np.testing.assert_allclose(x, [0.0, 2.0 * 1e-6 / 0.2, 0.0], rtol=1e-12)
    assert dev.GetOutputPort("work").Eval(ctx)[0] == pytest.approx(2.0 * x[1], rel=1e-12)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"mass": 0.0}, "mass=0.0 kg must be > 0"),
        ({"damping": -1.0}, "damping=-1.0"),
        ({"period_s": math.nan}, "period_s=nan"),
        ({"delay": 1.5}, "delay=1.5"),
        ({"axes": "w"}, "axes='w'"),
    ],
)
def test_bad_parameters_are_named(kwargs, match):
    with pytest.raises(ValueError, match=match):
        HapticDevice(**kwargs)
