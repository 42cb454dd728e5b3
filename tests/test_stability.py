"""The analysis against closed forms and second methods (no Drake simulation here)."""

import math

import control as ct
import numpy as np
import pytest
import theory

from godobject_drake.limits import zoh_mass_damper
from godobject_drake.studies import stability as st

# -- the simulated body ----------------------------------------------------------------------------------


@pytest.mark.parametrize("scheme", sorted(st.SCHEMES))
def test_roots_agree_with_jury_conditions(scheme):
    # Grid offset so no point sits exactly on a boundary.
    K, B = np.meshgrid(np.linspace(-0.4913, 6.1, 157), np.linspace(-0.4877, 4.2, 113))
    by_roots = st.spectral_radius(K, B, scheme) < 1.0
    assert np.array_equal(by_roots, theory.stable_by_table(K, B, scheme))


def test_symplectic_euler_needs_positive_damping():
    # β > 0 is needed too (docs/theory.md §1): with β = −0.1 the root product 1 − β exceeds 1.
    assert st.spectral_radius(1.0, -0.1, "symplectic_euler") > 1.0


@pytest.mark.parametrize("scheme", ["symplectic_euler", "symplectic_implicit_damping", "implicit_euler"])
def test_state_space_model_has_the_tables_polynomial(scheme):
    m, h, k, g = 0.7, 1e-2, 900.0, 12.0
    loop = st.BodyLoop(m, k, g, h, scheme=scheme)
    kappa, beta = k * h * h / m, g * h / m
    expected = st.characteristic_polynomial(kappa, beta, scheme)
    A, _ = st.coupled_body_matrices(loop)
    np.testing.assert_allclose(np.poly(A), expected / expected[0], rtol=1e-12)


def test_drake_scheme_is_symplectic_in_free_space_and_implicit_in_the_wall():
    m, h = 1.0, 1e-3
    free = st.BodyLoop(m, 1600.0, 80.0, h)
    np.testing.assert_allclose(
        st.coupled_body_matrices(free)[0],
        st.coupled_body_matrices(st.BodyLoop(m, 1600.0, 80.0, h, scheme="symplectic_euler"))[0],
    )
    # A wall of 1e9 N/m cannot destabilise the SAP (implicit) contact, it would the explicit one.
    assert st.body_spectral_radius(st.BodyLoop(m, 1600.0, 80.0, h, k_w=1e9, b_w=1e6)) < 1.0
    assert st.body_spectral_radius(st.BodyLoop(m, 1600.0, 80.0, h, k_w=1e9, scheme="symplectic_euler")) > 1.0


@pytest.mark.parametrize("zeta", [0.7, 1.0])
@pytest.mark.parametrize("h", [1e-3, 1e-2])
@pytest.mark.parametrize("mass", [1.0, 0.0023])
def test_k_crit_closed_form_matches_pole_bisection(mass, zeta, h):
    assert theory.k_crit_from_poles(mass, zeta, h) == pytest.approx(
        theory.explicit_k_crit(mass, zeta, h), rel=1e-5
    )


def test_explicit_limit_by_hand():
    # ζ = 1: 2(√2 − 1) = 0.828427... (the coupling module's limit, reused here)
    assert st.explicit_limit_omega_h(1.0) == pytest.approx(0.8284271247, rel=1e-9)
    # 1 kg, ζ = 1, h = 1 ms: k_crit = (828.43 rad/s)² kg = 686 291 N/m.
    assert theory.explicit_k_crit(1.0, 1.0, 1e-3) == pytest.approx(686291.5, rel=1e-6)


def test_h_max_and_min_mass_are_the_boundary():
    m, K, B = 0.3, 5000.0, 7.0
    h = st.explicit_h_max(m, K, B)
    # at h_max: κ + 2β = 4 exactly
    assert K * h * h / m + 2 * B * h / m == pytest.approx(4.0, rel=1e-12)
    assert st.explicit_min_mass(K, B, h) == pytest.approx(m, rel=1e-12)


def test_first_order_coupling_breaks_on_stiff_walls_first():
    # 1 kg, ωn = 40, ζ = 1, h = 1 ms: first order needs k + k_w < 2γ/h = 160 000 N/m;
    # symplectic Euler survives k + k_w < (4 − 2γh/m) m/h² = 3.84e6 N/m.
    k, g, h = 1600.0, 80.0, 1e-3
    assert theory.max_explicit_wall_stiffness("first_order", 1.0, k, g, h) == pytest.approx(
        160000 - k, rel=1e-5
    )
    assert theory.max_explicit_wall_stiffness("symplectic_euler", 1.0, k, g, h) == pytest.approx(
        3.84e6 - k, rel=1e-5
    )
    assert theory.max_explicit_wall_stiffness("implicit_euler", 1.0, k, g, h) == math.inf


def test_recommended_gains_respect_their_rule():
    r = st.recommend_gains("brick", 0.0023, (1e-7, 2e-7, 2.5e-7), 1e-3, device_rate_hz=60.0)
    assert r.omega_n_rot == pytest.approx(0.5 * r.omega_n_max)  # rotation at half the limit
    assert r.omega_n == pytest.approx(r.omega_n_rot / 3)
    assert r.k == pytest.approx(0.0023 * r.omega_n**2)
    slow = st.recommend_gains("brick", 0.0023, (1e-7, 2e-7, 2.5e-7), 1e-4, device_rate_hz=60.0)
    assert slow.omega_n == pytest.approx(math.pi * 60.0)  # capped by the device's Nyquist rate


# -- the device ------------------------------------------------------------------------------------------


def test_device_model_is_the_exact_zoh_of_the_haptic_device():
    dev = st.DeviceParams(0.1, 2.0, 1e-3)
    G = st.device_model(dev)
    A, B = zoh_mass_damper(0.1, 2.0, 1e-3)
    np.testing.assert_allclose(np.asarray(G.A), A, rtol=1e-10, atol=1e-15)
    np.testing.assert_allclose(np.asarray(G.B)[:, 0], B, rtol=1e-10)


@pytest.mark.parametrize(
    ("K", "B", "T"), [(1000.0, 0.0, 1e-3), (1000.0, 2.0, 1e-3), (1000.0, -1.0, 1e-3), (200.0, 3.0, 1e-2)]
)
def test_colgate_wall_closed_form(K, B, T):
    r = st.colgate_required_damping(st.wall_impedance(K, B, T), T)
    assert r.required_b == pytest.approx(K * T / 2 + abs(B), rel=1e-6)


@pytest.mark.parametrize(
    ("B", "expected"), [(0.0, 1.5), (0.5, 1.25), (1.0, 1.625), (2.0, 2.5625), (-0.5, 2.0)]
)
def test_colgate_one_sample_delay(B, expected):
    # K = 1000 N/m, T = 1 ms, d = 1: KT/2 + B + (KT)²/(8B) if KT < 4B, else 3KT/2 − B (B < 0: 3KT/2 + |B|).
    r = st.colgate_required_damping(st.wall_impedance(1000.0, B, 1e-3, delay=1), 1e-3)
    assert r.required_b == pytest.approx(expected, rel=1e-6)


@pytest.mark.parametrize("delay", [0, 1])
@pytest.mark.parametrize("damping", [0.5, 2.0])
def test_stiffness_limit_near_theory_approximation(damping, delay):
    # docs/theory.md's 2b/T and b/(T(d+½)) hold to ~1 % while bT/m is small (here 0.005–0.02).
    dev = st.DeviceParams(0.1, damping, 1e-3, delay)
    k_max = st.device_stiffness_limit(dev, lambda K: st.wall_impedance(K, 0.0, 1e-3, delay))
    assert k_max == pytest.approx(theory.stiffness_limit_approx(dev, 0.0), rel=0.01)


def test_gain_margin_equals_stiffness_limit():
    dev = st.DeviceParams(0.1, 2.0, 1e-3, 1)
    k_max = st.device_stiffness_limit(dev, lambda K: st.wall_impedance(K, 0.0, 1e-3, 1))
    gm = ct.stability_margins(st.device_model(dev) * st.wall_impedance(1.0, 0.0, 1e-3, 1), method="frd")[0]
    assert gm == pytest.approx(k_max, rel=1e-4)


def test_human_port_admittance_passivity_follows_the_damping():
    # A 500 N/m wall on a device with b_d = 2 is passive; virtual damping of −3 (beyond b_d) is not.
    dev = st.DeviceParams(0.1, 2.0, 1e-3)
    assert st.passivity_check(st.human_port_admittance(dev, st.wall_impedance(500.0, 0.0, 1e-3))).passive
    assert not st.passivity_check(st.human_port_admittance(dev, st.wall_impedance(500.0, -3.0, 1e-3))).passive


# -- the two-port ----------------------------------------------------------------------------------------


def test_llewellyn_eta_is_one_for_proportional_gains():
    res = st.llewellyn_eta(st.TwoPort(1.0, 1600.0, 80.0, 1600.0 / 80, 80.0 / 80))
    np.testing.assert_allclose(res.eta, 1.0, atol=1e-9)
    assert res.absolutely_stable


def test_llewellyn_eta_min_off_proportional():
    # η(ω) = cos(∠Zd − ∠Zc), minimum 2√r/(1+r) with r = γd k/(γ kd), at ω = √(k kd/(γ γd)).
    k, g, kd, gd = 1600.0, 80.0, 100.0, 20.0
    r = gd * k / (g * kd)
    w = np.geomspace(1e-2, 1e4, 20001)
    res = st.llewellyn_eta(st.TwoPort(1.0, k, g, kd, gd), w)
    assert res.eta_min == pytest.approx(2 * math.sqrt(r) / (1 + r), rel=1e-6)
    assert res.omega_at_min == pytest.approx(math.sqrt(k * kd / (g * gd)), rel=1e-3)
    assert not res.absolutely_stable


def test_rendered_impedance_is_active_below_the_tissue_frequency_with_gamma_d_zero():
    m, k, g, kw, kd = 1.0, 1600.0, 80.0, 2000.0, 100.0
    w = np.geomspace(1.0, 1e3, 50)
    Z = theory.rendered_impedance(m, k, g, kw, 0.0, kd, 0.0)
    np.testing.assert_allclose(
        Z(1j * w).real, theory.re_rendered_impedance_gamma_d0(m, k, g, kw, kd, w), rtol=1e-9, atol=1e-12
    )
    assert np.all(Z(1j * w[w < math.sqrt(kw / m)]).real < 0)
    assert np.all(Z(1j * w[w > math.sqrt(kw / m)]).real > 0)
