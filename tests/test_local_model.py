"""The local model (issue 44; docs/local_model.md): the payload and its checks, the driver's
proxy on the planes, its energy budget and passivity controller, the model's expiry, and a
closed loop of the emulated device against a wall a slow scene re-anchors.

Everything here is arithmetic on positions, forces and times handed in (no socket, no wall
clock: the emulated device runs on a clock the test advances), so every figure is exact and
holds on a loaded machine; the timing figures are analysis/local_model_bench.py's."""

import itertools
import math
import struct

import numpy as np
import pytest
from conftest import REPO
from test_link import DRIVER_AT, SCENE_AT, ends, handshake

from godobject_drake.driver.families import EmulatedDevice, HandPath
from godobject_drake.driver.local_model import (
    ACTIVE_M,
    ALLOWANCE_J,
    BANK_J,
    END_EXTRA_S,
    HOLD_EXTRA_S,
    MAX_DAMPING,
    MAX_GAP_S,
    SWEEPS,
    LocalRenderer,
    project,
)
from godobject_drake.link.messages import (
    ALIVE_CHANNEL,
    LOCAL_MODEL_CHANNEL,
    MAX_PLANES,
    LocalModel,
    LocalModelError,
    alive_message,
    parse_alive,
    parse_local_model,
)

INF = math.inf
T = 1e-3  # the device's period (s)
WALL = ((0.0, 0.0, 0.0), (1.0, 0.0, 0.0), INF)  # x ≥ 0 is free, a rigid wall below


def model(p_G=(0, 0, 0), p_T=None, planes=(), kd=200.0, gamma_d=0.0, period_s=0.01, utime=1, lag=(0, 0, 0)):
    return LocalModel(
        scene_utime=utime, pose_utime=0, period_s=period_s, kd=kd, gamma_d=gamma_d, kd_rot=0.0,
        gamma_d_rot=0.0, p_G=tuple(p_G), v_G=(0.0, 0.0, 0.0), q_G=(1.0, 0.0, 0.0, 0.0),
        w_G=(0.0, 0.0, 0.0), p_T=tuple(p_G if p_T is None else p_T), lag=tuple(map(float, lag)),
        planes=tuple(planes),
    )  # fmt: skip


def take_at(renderer, h, arrived, **fields):
    """``renderer`` takes a model whose target is the handle ``h`` the scene used (no grasp offset)."""
    renderer.take(model(p_T=h, **fields), arrived=arrived, h_used=h)


# -- the payload ------------------------------------------------------------------------------------------


def test_a_local_model_is_read_back_as_written():
    m = model(p_G=(0.01, -0.02, 0.03), p_T=(0.0, -0.02, 0.03), planes=[WALL, ((0, 0, 0), (0, 0, 1), 5e4)])
    assert parse_local_model(m.encode()) == m
    assert len(m.encode()) == 213 + 2 * 56  # the head (4 + 3 × 8 + 23 × 8 + 1 bytes), and 7 doubles a plane


def _bad(m: LocalModel, **changes) -> bytes:
    import dataclasses

    return dataclasses.replace(m, **changes).encode()


@pytest.mark.parametrize(
    ("change", "named"),
    [
        (dict(kd=-1.0), "gains"),
        (dict(gamma_d=math.nan), "gains"),
        (dict(p_G=(0.0, math.inf, 0.0)), "p_G"),
        (dict(v_G=(math.nan, 0.0, 0.0)), "v_G"),
        (dict(p_T=(0.0, 0.0, -math.inf)), "p_T"),
        (dict(q_G=(1.0, 0.1, 0.0, 0.0)), "unit quaternion"),
        (dict(period_s=0.0), "period_s"),
        (dict(period_s=math.inf), "period_s"),
        (dict(scene_utime=-1), "times"),
        (dict(planes=[((0, 0, 0), (1.0, 0.01, 0.0), INF)]), "unit length"),
        (dict(planes=[((0, 0, 0), (1.0, 0.0, 0.0), 0.0)]), "stiffness"),
        (dict(planes=[((0, 0, 0), (1.0, 0.0, 0.0), math.nan)]), "stiffness"),
        (dict(planes=[((0, math.nan, 0), (1.0, 0.0, 0.0), INF)]), "plane 0"),
    ],
)
def test_a_local_model_out_of_its_limits_is_refused_naming_the_field(change, named):
    with pytest.raises(LocalModelError, match=named):
        parse_local_model(_bad(model(planes=[WALL]), **change))


def test_a_truncated_padded_or_foreign_payload_is_refused_naming_the_length_or_magic():
    raw = model(planes=[WALL]).encode()
    for cut in (0, 1, 100, len(raw) - 1):
        with pytest.raises(LocalModelError, match="bytes"):
            parse_local_model(raw[:cut])
    with pytest.raises(LocalModelError, match="bytes"):
        parse_local_model(raw + b"\0")
    with pytest.raises(LocalModelError, match="magic"):
        parse_local_model(b"XLM1" + raw[4:])
    too_many = bytearray(raw)
    too_many[212] = MAX_PLANES + 1  # the plane count, the head's last byte
    with pytest.raises(LocalModelError, match=f"at most {MAX_PLANES}"):
        parse_local_model(bytes(too_many))
    with pytest.raises(LocalModelError, match="planes"):
        model(planes=[WALL] * (MAX_PLANES + 1)).encode()
    assert struct.unpack_from(">d", raw, 213 + 48)[0] == INF  # the wall's stiffness, where the format says


@pytest.mark.parametrize("name", ["p_G", "v_G", "q_G", "w_G", "p_T", "lag"])
def test_a_vector_that_is_not_finite_is_refused_by_its_exact_name_and_values(name):
    """The message names the field as the format does, with the values read: ``lag`` [0.0, nan, 0.0]."""
    base = model(planes=[WALL])
    values = [float(v) for v in getattr(base, name)]
    values[1] = math.nan
    with pytest.raises(LocalModelError) as refused:
        parse_local_model(_bad(base, **{name: tuple(values)}))
    assert str(refused.value) == f"local model: {name} {values} is not finite"


def test_a_period_or_gain_that_is_not_finite_is_refused_by_its_exact_name():
    with pytest.raises(LocalModelError) as refused:
        parse_local_model(_bad(model(), period_s=math.nan))
    assert str(refused.value) == "local model: period_s [nan] is not finite"
    with pytest.raises(LocalModelError) as refused:
        parse_local_model(_bad(model(), gamma_d=math.inf))
    assert str(refused.value) == "local model: gains [200.0, inf, 0.0, 0.0] is not finite"


def test_a_local_model_at_its_limits_is_read():
    """Each limit's edge is inside it: no plane (the head alone, 213 bytes), the most planes, a
    scene time of 0 µs, a stiffness just above 0 (a very soft plane)."""
    bare = model()
    assert len(bare.encode()) == 213 and parse_local_model(bare.encode()) == bare
    most = model(planes=[WALL] * MAX_PLANES)
    assert parse_local_model(most.encode()) == most
    first = model(utime=0)
    assert parse_local_model(first.encode()) == first
    soft = model(planes=[((0.0, 0.0, 0.0), (1.0, 0.0, 0.0), 0.5)])
    assert parse_local_model(soft.encode()).planes[0][2] == 0.5


def test_the_length_and_magic_refusals_say_what_was_read_and_expected():
    raw = model(planes=[WALL]).encode()
    with pytest.raises(LocalModelError) as refused:
        parse_local_model(raw + b"\0")
    assert str(refused.value) == "local model: 270 bytes for 1 planes; expected 269"  # 213 + 56
    with pytest.raises(LocalModelError) as refused:
        parse_local_model(b"XLM1" + raw[4:])
    assert str(refused.value) == "local model: magic b'XLM1', not b'GLM2'"


@pytest.mark.parametrize("byte", [0, 50, 100, -1])
def test_a_local_model_changed_on_the_link_is_unauthenticated_and_never_parsed(byte):
    """The local model rides the paired link like the wrench: a changed datagram is dropped
    before any handler, counted; the intact one passes."""
    scene, driver = ends()
    handshake(scene, driver)
    sealed = scene.seal(LOCAL_MODEL_CHANNEL, model(planes=[WALL]).encode())
    changed = bytearray(sealed)
    changed[byte] ^= 0x01
    assert driver.receive(bytes(changed), SCENE_AT, 0.0) == (None, None)
    assert driver.counts["udp_malformed"] + driver.counts["udp_unauthenticated"] == 1
    message, _ = driver.receive(sealed, SCENE_AT, 0.0)
    assert message[0] == LOCAL_MODEL_CHANNEL and parse_local_model(message[1]) == model(planes=[WALL])
    assert driver.receive(sealed, SCENE_AT, 0.0) == (None, None) and driver.counts["udp_replayed"] == 1
    assert scene.receive(sealed, DRIVER_AT) == (None, None)  # the scene's own kind: not taken


# -- the proxy ---------------------------------------------------------------------------------------------


def test_the_proxy_never_enters_a_rigid_plane_and_a_soft_one_by_kd_over_kd_plus_s():
    rng = np.random.default_rng(4)
    floor = ((0.0, 0.0, 0.01), (0.0, 0.0, 1.0), INF)
    for y in rng.uniform(-0.05, 0.05, (500, 3)):
        x = project(y, [WALL, floor], 200.0)
        assert x[0] >= -1e-15 and x[2] >= 0.01 - 1e-15  # a corner of two rigid planes
        assert np.allclose(x, [max(y[0], 0.0), y[1], max(y[2], 0.01)])  # the nearest point of it
    soft = ((0.0, 0.0, 0.0), (1.0, 0.0, 0.0), 600.0)
    assert project(np.array([-0.02, 0.0, 0.0]), [soft], 200.0)[0] == pytest.approx(-0.02 * 200 / 800)


def test_the_force_is_kd_times_the_stretch_to_the_proxy_by_hand():
    """A god-object held by the wall at x = 0 whose target the scene had at x = −1 cm, with a
    free lag of 2 mm on y: the free part ``o`` is (0, 2 mm, 0) and the wall explains the rest.
    With the hand at x = −1.5 cm the force is kd (0 − (−1.5 cm), 2 mm, 0); with the hand out at
    x = +0.3 cm it is kd o only."""
    r = LocalRenderer()
    r.energy_in = r.energy_v = 1.0  # a budget that pays: the force is the model's
    take_at(r, (-0.01, 0.0, 0.0), 0.0, p_G=(0.0, 0.002, 0.0), planes=[WALL], kd=200.0)
    assert np.allclose(r.offset, [0.0, 0.002, 0.0])
    f = r.request((-0.015, 0.0, 0.0), now=0.001, period_s=T)
    assert np.allclose(f, [200 * 0.015, 200 * 0.002, 0.0], rtol=1e-12)
    assert r.spring == pytest.approx(0.5 * 200 * 0.015**2)  # the planes' spring only
    r.rendered(f)
    r.energy_in = r.energy_v = 1.0  # again: the 1.8 cm jump out is no motion a hand makes in 1 ms
    f = r.request((0.003, 0.0, 0.0), now=0.002, period_s=T)
    assert np.allclose(f, [0.0, 200 * 0.002, 0.0], rtol=1e-12)


def test_in_free_space_the_proxy_moves_with_the_hand_between_scene_messages():
    """No plane: the scene's lag ``p_G − h_used`` (1 mm behind a hand moving at 6 cm/s) is
    held, the handle's own motion is not a stretch (a heavy free space is a slow scene's, not
    the hand's): kd × 1 mm against the motion, and the hand pays for it. The same lag ahead of
    the hand would pull it along: rendered only while paid for, then the controller's damper."""
    r = LocalRenderer()
    take_at(r, (0.0, 0.0, 0.0), 0.0, p_G=(-0.001, 0.0, 0.0), kd=50.0)
    for k, x in enumerate(np.linspace(0.0, 0.0058, 30)):  # 6 cm/s for 30 ms
        f = r.request((x, 0.0, 0.0), now=k * T, period_s=T)
        r.rendered(f)
        assert np.allclose(f, [-50 * 0.001, 0.0, 0.0])
    # what the drag took from the hand (0.29 mJ), kept up to the bank: the rest the scene dissipated
    assert 0.05 * 0.0058 > BANK_J and r.energy_in == pytest.approx(BANK_J)
    ahead = LocalRenderer()
    take_at(ahead, (0.0, 0.0, 0.0), 0.0, p_G=(0.001, 0.0, 0.0), kd=50.0)
    f0 = ahead.request((0.0, 0.0, 0.0), now=0.0, period_s=T)
    ahead.rendered(f0)
    f1 = ahead.request((2e-4, 0.0, 0.0), now=T, period_s=T)  # f0 pulled the hand 0.2 mm along
    ahead.rendered(f1)
    assert f0[0] == pytest.approx(0.05) and ahead.energy_in == pytest.approx(-0.05 * 2e-4)
    # in deficit: no lag force, the controller's damper 1e-5 J / ((0.2 m/s)² 1 ms) = 0.25 N·s/m
    assert ahead.damping == pytest.approx(0.25) and f1[0] == pytest.approx(-0.25 * 0.2)
    ahead.request((4e-4, 0.0, 0.0), now=2 * T, period_s=T)
    assert ahead.energy_in == pytest.approx(0.0, abs=1e-18)  # paid back over the next 0.2 mm


def test_a_grasp_offset_is_no_force_and_the_planes_stop_the_grasped_point():
    """The hand grasped the body 1 cm beside its centre: the scene's target sits ``c`` = (0, 1 cm,
    0) from the handle it used, and the god-object is on it (no stretch). Wherever the hand goes
    in free space the force is zero (kd c = 2 N was rendered before: a pull toward the body's
    centre that the scene's own feedback, kd (p_G − p_T), never gives). A wall at y = 0 of the
    god-object's point stops the grasped point, not the handle: with the handle at y = −1.5 cm
    the point is 0.5 cm in, and the force is kd × 0.5 cm."""
    r = LocalRenderer()
    r.energy_in = r.energy_v = 1.0  # a budget that pays: the force is the model's
    wall_y = ((0.0, 0.0, 0.0), (0.0, 1.0, 0.0), INF)
    on_target = model(p_G=(0.0, 0.03, 0.0), p_T=(0.0, 0.03, 0.0), planes=[wall_y])
    r.take(on_target, arrived=0.0, h_used=(0.0, 0.02, 0.0))
    assert np.allclose(r.grasp, [0.0, 0.01, 0.0]) and np.allclose(r.offset, 0.0)
    for k, h in enumerate([(0.0, 0.02, 0.0), (0.01, 0.015, -0.003), (0.0, -0.01, 0.0)]):
        f = r.request(h, now=k * T, period_s=T)  # the grasped point at y ≥ 0: zero (to rounding)
        assert np.allclose(f, 0.0, rtol=0.0, atol=1e-12), (h, f)
        r.energy_in = r.energy_v = 1.0
    f = r.request((0.0, -0.015, 0.0), now=3 * T, period_s=T)
    assert np.allclose(f, [0.0, 200 * 0.005, 0.0], rtol=1e-12)
    assert np.allclose(r.proxy((0.0, -0.015, 0.0)), [0.0, 0.0, 0.0])  # the grasped point on the wall
    assert np.allclose(r.proxy((0.01, 0.02, 0.0)), [0.01, 0.03, 0.0], rtol=0, atol=1e-15)  # h + c


def test_the_couplings_free_lag_is_not_rendered_and_a_contacts_part_is():
    """A slow scene saw the hand at 60 cm/s and its god-object lags 6 mm behind the target on y,
    exactly as a free one would (``lag``): in free space, no force. Where something held it back
    2 mm more than the free one, kd × 2 mm is rendered. Near a contact (a plane published) the
    whole stretch is (module docstring: the approach the budget's bank draws on)."""
    r = LocalRenderer()
    r.energy_in = r.energy_v = 1.0
    take_at(r, (0.0, 0.0, 0.0), 0.0, p_G=(0.0, -0.006, 0.0), lag=(0.0, -0.006, 0.0), kd=200.0)
    assert np.all(r.request((0.0, 0.001, 0.0), now=0.0, period_s=T) == 0.0)
    take_at(r, (0.0, 0.0, 0.0), T, p_G=(0.0, -0.008, 0.0), lag=(0.0, -0.006, 0.0), kd=200.0)
    assert np.allclose(r.request((0.0, 0.001, 0.0), now=T, period_s=T), [0.0, -200 * 0.002, 0.0])
    # near a contact (a plane published, here a wall at x = -1 cm the hand has not reached) the
    # whole stretch is rendered, lag included: kd × 8 mm
    far_wall = ((-0.01, 0.0, 0.0), (1.0, 0.0, 0.0), INF)
    planes = dict(p_G=(0.0, -0.008, 0.0), lag=(0.0, -0.006, 0.0), kd=200.0, planes=[far_wall])
    take_at(r, (0.0, 0.0, 0.0), 2 * T, **planes)
    assert np.allclose(r.request((0.0, 0.001, 0.0), now=2 * T, period_s=T), [0.0, -200 * 0.008, 0.0])


def test_a_soft_plane_lets_the_proxy_in_by_kd_over_kd_plus_s_at_any_kd():
    """kd 1 N/m against a plane of 3 N/m: in by a quarter of the 2 cm (0.5 cm); kd 0 (no spring
    to share the depth with): not at all."""
    soft = ((0.0, 0.0, 0.0), (1.0, 0.0, 0.0), 3.0)
    assert project(np.array([-0.02, 0.0, 0.0]), [soft], 1.0) == pytest.approx([-0.005, 0.0, 0.0], rel=1e-12)
    assert project(np.array([-0.02, 0.0, 0.0]), [soft], 0.0).tolist() == [0.0, 0.0, 0.0]


def test_the_proxy_is_a_new_float_array_whatever_it_is_given():
    """Integer coordinates in, no plane or none reached: the same point back as floats, in a new
    array (the caller's is never changed)."""
    y = np.array([1, 2, 3])
    for planes in ([], [WALL]):  # no plane published (free space), or one not entered
        x = project(y, planes, 200.0)
        assert x.dtype == np.float64 and x.tolist() == [1.0, 2.0, 3.0] and x is not y
        x[0] = 5.0
        assert y.tolist() == [1, 2, 3]


def test_a_soft_plane_lets_the_proxy_in_as_far_with_a_plane_it_never_reaches():
    """A plane the proxy never enters changes nothing: with a rigid floor 0.5 m away, a 600 N/m
    plane still lets it in by kd/(kd + s) = 1/4 of the 2 cm (before: the passes for several
    planes let it in by a quarter of a quarter ..., 8 times: the force 4.0 N, not 3.0 N)."""
    soft = ((0.0, 0.0, 0.0), (1.0, 0.0, 0.0), 600.0)
    floor = ((0.0, 0.0, -0.5), (0.0, 0.0, 1.0), INF)
    y = np.array([-0.02, 0.0, 0.0])
    alone, beside = project(y, [soft], 200.0), project(y, [soft, floor], 200.0)
    assert alone[0] == pytest.approx(-0.005, rel=1e-12) and beside.tolist() == pytest.approx(alone, rel=1e-12)
    assert 200.0 * (alone - y)[0] == pytest.approx(3.0, rel=1e-12)  # kd × 1.5 cm, s × 0.5 cm


def test_two_soft_planes_balance_the_spring_as_the_linear_system_of_their_pushes():
    """Two soft planes at 120° (600 and 300 N/m, kd 200) and a point deep in both: the proxy is
    where ``kd (x − y) = Σ s n (depth of x)``, solved here as the 3×3 linear system of both planes
    active (a second method); projected Gauss–Seidel's 8 passes reach it within 0.8 nm (measured),
    asserted to 10 nm. At right angles one pass is exact: each plane's own kd/(kd + s)."""
    n2 = (-0.5, math.sqrt(3) / 2, 0.0)
    planes = [((0.0, 0.0, 0.0), (1.0, 0.0, 0.0), 600.0), ((0.0, 0.0, 0.0), n2, 300.0)]
    y = np.array([-0.004, -0.02, 0.003])
    a, rhs = 200.0 * np.eye(3), 200.0 * y
    for point, normal, s in planes:
        a += s * np.outer(normal, normal)
        rhs += s * np.asarray(normal) * float(np.dot(normal, point))
    exact = np.linalg.solve(a, rhs)
    assert all(-float(np.dot(n, exact)) > 0.002 for _, n, _ in planes)  # both active: the system holds
    assert np.abs(project(y, planes, 200.0) - exact).max() < 1e-8
    square = [planes[0], ((0.0, 0.0, 0.0), (0.0, 1.0, 0.0), 200.0)]
    assert project(y, square, 200.0).tolist() == pytest.approx([-0.001, -0.01, 0.003], rel=1e-12)


def test_a_plane_that_pushed_too_far_gives_back_what_another_took_over():
    """Gauss–Seidel's pushes never pull, but a push a later plane made too large is taken back:
    a rigid floor z ≥ 0 and the rigid plane z ≥ y (normal at 45°), and the point (y, z) =
    (1 cm, −2 mm) below both. The floor alone takes it to (1 cm, 0); the 45° plane then to
    (5 mm, 5 mm), above the floor, which gives its 2 mm back; the 45° plane ends it at (4 mm, 4 mm),
    the nearest point of the wedge by hand (the foot of (1 cm, −2 mm) on z = y). Plain passes of
    projections stop at (5 mm, 5 mm)."""
    n45 = (0.0, -math.sqrt(0.5), math.sqrt(0.5))
    wedge = [((0.0, 0.0, 0.0), (0.0, 0.0, 1.0), INF), ((0.0, 0.0, 0.0), n45, INF)]
    x = project(np.array([0.0, 0.01, -0.002]), wedge, 200.0)
    assert x.tolist() == pytest.approx([0.0, 0.004, 0.004], abs=1e-12)


def test_the_proxy_in_an_acute_corner_comes_to_its_edge_pass_by_pass():
    """A 60° groove of two rigid planes (x ≥ 0 and the plane whose normal is at 120° to it): a
    point 1 cm below the edge on the first plane is projected onto the other plane, then back,
    each projection onto a line 60° away, halving its distance to the edge (cos 60°). The first
    pass projects once (the point is on the first plane), each later pass twice: after
    SWEEPS = 8 passes the proxy is 1 cm × 2⁻¹⁵ = 0.31 µm from the edge, on the second plane."""
    groove = [WALL, ((0.0, 0.0, 0.0), (-0.5, math.sqrt(3) / 2, 0.0), INF)]
    x = project(np.array([0.0, -0.01, 0.0]), groove, 200.0)
    assert SWEEPS == 8 and np.linalg.norm(x) == pytest.approx(0.01 * 0.5 ** (2 * SWEEPS - 1), rel=1e-9)
    assert x @ groove[1][1] == pytest.approx(0.0, abs=1e-20) and x[0] < 0.0  # on the second plane


def test_the_renderers_proxy_is_the_handle_plus_the_free_lag_out_of_the_planes():
    """The model of the by-hand test above (the wall, a 2 mm lag on y): the hand 1.5 cm into the
    wall has its proxy on the wall, 2 mm along y; out of the wall, the hand plus the lag."""
    r = LocalRenderer()
    take_at(r, (-0.01, 0.0, 0.0), 0.0, p_G=(0.0, 0.002, 0.0), planes=[WALL], kd=200.0)
    assert np.allclose(r.proxy((-0.015, 0.0, 0.0)), [0.0, 0.002, 0.0], rtol=0, atol=1e-18)
    assert np.allclose(r.proxy((0.003, 0.001, 0.0)), [0.003, 0.003, 0.0], rtol=0, atol=1e-18)
    soft = LocalRenderer()  # a plane of 600 N/m at kd 200: the proxy in by a quarter of the depth
    soft.take(model(planes=[((0.0, 0.0, 0.0), (1.0, 0.0, 0.0), 600.0)], kd=200.0), arrived=0.0)
    assert soft.proxy((-0.02, 0.0, 0.0)) == pytest.approx([-0.005, 0.0, 0.0], rel=1e-12)


def test_a_model_with_no_h_used_is_taken_against_its_own_target():
    """No handle position given: the stretch is the model's ``p_G − p_T`` (2 mm on y, no plane)."""
    r = LocalRenderer()
    r.take(model(p_G=(0.0, 0.002, 0.0), p_T=(0.0, 0.0, 0.0)), arrived=0.0)
    assert r.offset.tolist() == [0.0, 0.002, 0.0]


def test_a_plane_holds_the_god_object_up_to_active_m_away():
    """The scene's stretch (the target 1 cm into the wall, G on it) is explained by a plane whose
    distance to G is at most ACTIVE_M (0.1 mm) inclusive: no free lag is left; a plane twice as
    far does not hold G, and the whole stretch is the lag."""
    for gap_m, lag in ((0.0, 0.0), (ACTIVE_M, 0.0), (2 * ACTIVE_M, 0.01 + 2 * ACTIVE_M)):
        r = LocalRenderer()
        take_at(r, (-0.01, 0.0, 0.0), 0.0, p_G=(gap_m, 0.0, 0.0), planes=[WALL], kd=100.0)
        assert r.offset == pytest.approx([lag, 0.0, 0.0], abs=1e-18)


def test_a_god_object_sunk_into_a_soft_plane_is_softened_once():
    """A 600 N/m plane at its undeformed surface x = 0, kd 200: the scene's target 2 cm in, G sunk
    to the balance 600 × 5 mm = 200 × 15 mm = 3 N. The plane holds G (G is in it), so at the
    handle the scene used the force is the scene's kd (p_G − p_T) = 3 N; 1 cm deeper it is the
    spring and the plane in series, 150 N/m × 3 cm = 4.5 N. (Before, a plane holding G had to be
    within 0.1 mm of it either side: G 5 mm in was not held, its stretch became a free offset and
    the force 3.75 N, and the scene put the plane through the sunk G: softened twice.)"""
    soft = ((0.0, 0.0, 0.0), (1.0, 0.0, 0.0), 600.0)
    r = LocalRenderer()
    take_at(r, (-0.02, 0.0, 0.0), 0.0, p_G=(-0.005, 0.0, 0.0), planes=[soft], kd=200.0)
    assert r.offset.tolist() == [0.0, 0.0, 0.0]
    for h, force in ((-0.02, 3.0), (-0.03, 4.5)):  # the spring to the proxy, before any budget
        assert 200.0 * (r.proxy((h, 0.0, 0.0))[0] - h) == pytest.approx(force, rel=1e-12)


def test_the_scene_puts_a_soft_plane_at_the_undeformed_surface_and_a_rigid_one_through_g():
    """``plane_point`` by hand, normal +z out of the obstacle, G at z = 1 cm: apart by 2 mm, either
    plane is 2 mm below G; G 0.3 mm into a rigid pair (the solver's penetration), the plane
    through G; G sunk 5 mm into a soft pair, the plane 5 mm above G (where the surface was)."""
    from godobject_drake.link.scene_model import plane_point

    g, n = np.array([0.0, 0.0, 0.01]), np.array([0.0, 0.0, 1.0])
    assert plane_point(g, 0.002, n, INF).tolist() == pytest.approx([0.0, 0.0, 0.008], abs=1e-15)
    assert plane_point(g, 0.002, n, 1e5).tolist() == pytest.approx([0.0, 0.0, 0.008], abs=1e-15)
    assert plane_point(g, -0.0003, n, INF).tolist() == [0.0, 0.0, 0.01]
    assert plane_point(g, -0.005, n, 1e5).tolist() == pytest.approx([0.0, 0.0, 0.015], abs=1e-15)


def test_the_free_lag_is_kept_at_any_kd_above_zero_and_none_at_kd_zero():
    """kd 0 (no spring): the scene's stretch means nothing, o = 0; kd 0.5 N/m keeps it."""
    for kd, lag in ((0.0, 0.0), (0.5, 0.002), (200.0, 0.002)):
        r = LocalRenderer()
        take_at(r, (0.0, 0.0, 0.0), 0.0, p_G=(0.002, 0.0, 0.0), kd=kd)
        assert r.offset.tolist() == [lag, 0.0, 0.0]


def test_the_damper_acts_on_the_stretchs_rate_through_a_soft_plane_not_on_the_hand_in_free_space():
    """γd 0.5 N·s/m, kd 200 N/m on a plane of 600 N/m: the proxy is in by a quarter of the depth,
    so the force is the series spring's 150 N/m × depth and the stretch grows at ¾ of the hand's
    speed. Pressing in at 0.1 m/s from 1 mm deep adds 0.5 × 0.075 = 0.0375 N (not at the first
    request: no earlier handle), holding adds nothing, withdrawing at 0.1 m/s takes 0.0375 N off.
    In free space the lag (1 mm) moves with the hand: no rate, kd × o alone, and a new model (a
    new lag) is no rate either. The budget is in credit, so β = 1 and no controller damper."""
    soft = ((0.0, 0.0, 0.0), (1.0, 0.0, 0.0), 600.0)
    r = LocalRenderer()
    take_at(r, (0.0, 0.0, 0.0), 0.0, planes=[soft], kd=200.0, gamma_d=0.5)
    r.energy_in = r.energy_v = 1.0
    depths = [0.001, 0.0011, 0.0012, 0.0012, 0.0011]
    pushes = [0.0, 0.0375, 0.0375, 0.0, -0.0375]
    for k, (d, push) in enumerate(zip(depths, pushes, strict=True)):
        f = r.request((-d, 0.0, 0.0), now=k * T, period_s=T)
        r.rendered(f)
        assert r.beta == 1.0 and r.damping == 0.0
        assert f[0] == pytest.approx(150.0 * d + push, rel=1e-9) and f[1] == f[2] == 0.0
    free = LocalRenderer()
    take_at(free, (0.0, 0.0, 0.0), 0.0, p_G=(-0.001, 0.0, 0.0), kd=50.0, gamma_d=0.5)
    for k in range(5):  # 6 cm/s
        f = free.request((k * 6e-5, 0.0, 0.0), now=k * T, period_s=T)
        free.rendered(f)
        assert f == pytest.approx([-0.05, 0.0, 0.0], rel=1e-9)
    h = (4 * 6e-5, 0.0, 0.0)  # the hand still; the scene's new lag is 2 mm
    take_at(free, h, 5 * T, p_G=(h[0] - 0.002, 0.0, 0.0), kd=50.0, gamma_d=0.5)
    assert free.request(h, now=5 * T, period_s=T) == pytest.approx([-0.1, 0.0, 0.0], rel=1e-9)


def test_a_request_with_no_time_since_the_last_has_no_rate_and_no_damper():
    """period_s 0 (two reads at once): the stretch's rate and the controller's damper need a
    time; with none the force is the spring's alone (no division by zero), even in deficit and
    with the hand moved 0.1 mm along each axis."""
    r = LocalRenderer()
    take_at(r, (0.0, 0.0, 0.0), 0.0, p_G=(-0.001, 0.0, 0.0), kd=50.0, gamma_d=0.5)
    r.rendered(r.request((0.0, 0.0, 0.0), now=0.0, period_s=T))
    r.energy_in = -2e-3
    f = r.request((1e-4, 1e-4, 1e-4), now=T, period_s=0.0)
    assert f == pytest.approx([-0.05, 0.0, 0.0], rel=1e-9) and r.damping == 0.0


# -- the energy budget -------------------------------------------------------------------------------------


def _press(r: LocalRenderer, depths, t0=0.0):
    """Move the handle through ``depths`` (m into the wall, one a period), rendering as asked."""
    f = np.zeros(3)
    for k, d in enumerate(depths):
        f = r.request((-d, 0.0, 0.0), now=t0 + k * T, period_s=T)
        r.rendered(f)
    return f


def test_pressing_renders_the_spring_and_the_controller_pays_for_the_held_force():
    """The hand presses 1 cm into the wall at kd 100 in 10 steps of 1 mm. The virtual account
    (trapezoid) of a linear spring is exact, ``E_v = ½ kd d²``: the spring is rendered whole
    (β = 1) at every step. The device holds each force over the next step, so the hand puts in
    less than the spring holds: the first step puts in nothing, and the controller's damper
    asks the missing ½ kd Δ² over the next step at the step's speed Δ/T: α = kd T / 2, against
    the motion, so the force rendered is ``kd Δ + (kd T/2)(Δ/T) = 1.5 kd Δ``. At the end the hand
    has put in at least what the spring holds, less one step's ½ kd Δ²."""
    r = LocalRenderer()
    take_at(r, (0.0, 0.0, 0.0), 0.0, planes=[WALL], kd=100.0)
    f = _press(r, [0.0, 0.001])
    assert r.beta == 1.0 and r.energy_in == 0.0
    assert r.energy_v == pytest.approx(0.5 * 100 * 0.001**2, rel=1e-12)
    assert r.damping == pytest.approx(100 * T / 2, rel=1e-12) and f[0] == pytest.approx(1.5 * 100 * 0.001)
    _press(r, np.arange(2, 11) * 1e-3, t0=2 * T)
    assert r.beta == 1.0 and r.spring == pytest.approx(0.5 * 100 * 0.01**2) and r.energy_v >= r.spring
    assert r.energy_in >= r.spring - 0.5 * 100 * 0.001**2 - 1e-15


def test_a_re_anchoring_is_rendered_only_as_far_as_the_budget_pays():
    """Held 1 cm into the wall with a budget of exactly what the spring holds (5 mJ at kd 100),
    the scene moves the wall 5 mm out (towards the hand's free side): the model asks
    ½ kd (1.5 cm)² = 11.25 mJ; the device renders β = √(5/11.25) of its force, and the spring
    it renders holds exactly the 5 mJ paid for."""
    r = LocalRenderer()
    take_at(r, (0.0, 0.0, 0.0), 0.0, planes=[WALL], kd=100.0)
    r.energy_in = r.energy_v = 0.5 * 100 * 0.01**2
    f = r.request((-0.01, 0.0, 0.0), now=0.001, period_s=T)
    r.rendered(f)
    assert f[0] == pytest.approx(1.0) and r.beta == 1.0
    moved = ((0.005, 0.0, 0.0), (1.0, 0.0, 0.0), INF)
    take_at(r, (-0.01, 0.0, 0.0), 0.002, p_G=(0.005, 0, 0), planes=[moved], kd=100.0)
    f = r.request((-0.01, 0.0, 0.0), now=0.002, period_s=T)
    paid = 5e-3 + ALLOWANCE_J  # what the hand put in, and the 1 µJ the budget lends
    beta = math.sqrt(paid / 11.25e-3)
    assert r.beta == pytest.approx(beta, rel=1e-12) and f[0] == pytest.approx(100 * 0.015 * beta, rel=1e-12)
    assert r.spring == pytest.approx(paid, rel=1e-12) and r.unpaid == pytest.approx(11.25e-3 - paid)


def test_accounts_standing_at_zero_by_rounding_still_render_the_model():
    """The controller repays a deficit exactly, so the accounts can stay a rounding error below
    zero: the budget's 1 µJ allowance renders the model (no deadlock at zero force)."""
    r = LocalRenderer()
    take_at(r, (0.0, 0.0, 0.0), 0.0, p_G=(-0.001, 0.0, 0.0), kd=50.0)
    r.energy_in = r.energy_v = -1e-12
    assert np.allclose(r.request((0.0, 0.0, 0.0), now=T, period_s=T), [-0.05, 0.0, 0.0])
    r.energy_v = -2 * ALLOWANCE_J
    assert np.allclose(r.request((0.0, 0.0, 0.0), now=2 * T, period_s=T), 0.0)


def test_an_environment_account_below_zero_is_repaid_by_the_damper_then_renders_again():
    """The device's account in credit, the environment's 3 µJ short (the hand was pulled along
    by a free force): nothing of the model is rendered, and the damper asks for the 2 µJ past
    the allowance at the hand's 0.1 m/s (α = 2e-6 / (0.01 × 1e-3) = 0.2 N·s/m); once the hand
    has paid it, the model renders again."""
    r = LocalRenderer()
    take_at(r, (0.0, 0.0, 0.0), 0.0, p_G=(-0.001, 0.0, 0.0), kd=50.0)
    r.request((0.0, 0.0, 0.0), now=0.0, period_s=T)
    r.rendered(np.zeros(3))
    r._env = None  # nothing rendered before: the trapezoid counts only the held force
    r.energy_in, r.energy_v = 1e-3, -3e-6
    f = r.request((1e-4, 0.0, 0.0), now=T, period_s=T)
    assert r.beta == 0.0 and r.damping == pytest.approx(0.2) and np.allclose(f, [-0.02, 0.0, 0.0])
    r.rendered(f)
    f = r.request((2e-4, 0.0, 0.0), now=2 * T, period_s=T)  # the hand paid 0.02 N × 0.1 mm = 2 µJ
    assert r.energy_v == pytest.approx(-1e-6) and r.beta == 1.0 and f[0] == pytest.approx(-0.05)


def test_work_done_on_a_free_force_is_not_banked_to_pay_a_later_push():
    """The hand drags against a 0.5 N lag for 2 cm (10 mJ put in); then a new model puts a plane
    5 mm inside the hand (a contact the scene saw late) asking ½ kd (5 mm)² = 1.25 mJ at kd 100:
    only the 0.2 mJ bank (and the 1 µJ allowance) pays, β = √(0.201 / 1.25), not the 10 mJ."""
    r = LocalRenderer()
    take_at(r, (0.0, 0.0, 0.0), 0.0, p_G=(-0.005, 0.0, 0.0), kd=100.0, period_s=0.1)
    for k, x in enumerate(np.linspace(0.0, 0.02, 201)):  # 10 cm/s for 0.2 s: a 10 Hz scene, fresh
        r.rendered(r.request((x, 0.0, 0.0), now=k * T, period_s=T))
    assert r.energy_in == pytest.approx(BANK_J) and r.energy_v == pytest.approx(BANK_J)
    wall = ((0.025, 0.0, 0.0), (1.0, 0.0, 0.0), INF)
    take_at(r, (0.02, 0.0, 0.0), 0.2, p_G=(0.025, 0.0, 0.0), planes=[wall], kd=100.0)
    f = r.request((0.02, 0.0, 0.0), now=0.2, period_s=T)
    beta = math.sqrt((BANK_J + ALLOWANCE_J) / (0.5 * 100 * 0.005**2))
    assert r.beta == pytest.approx(beta, rel=1e-9) and f[0] == pytest.approx(100 * 0.005 * beta, rel=1e-9)


def test_a_deficit_is_paid_back_by_the_controllers_damper():
    """The hand was given 2 mJ more than it put in and moves at 0.1 m/s: the controller's
    damper is 2 mJ / (v² T) = 200 N·s/m, cut to MAX_DAMPING, opposing the motion; no deficit,
    no damper."""
    r = LocalRenderer()
    take_at(r, (0.0, 0.0, 0.0), 0.0, kd=100.0)
    r.request((0.0, 0.0, 0.0), now=0.0, period_s=T)
    r.rendered(np.zeros(3))
    r.energy_in = -2e-3
    f = r.request((1e-4, 0.0, 0.0), now=T, period_s=T)
    assert r.damping == MAX_DAMPING and np.allclose(f, [-MAX_DAMPING * 0.1, 0.0, 0.0])
    r.energy_in = -2e-7
    r.rendered(np.zeros(3))
    f = r.request((2e-4, 0.0, 0.0), now=2 * T, period_s=T)
    assert r.damping == pytest.approx(2e-7 / (0.01 * T)) and f[0] == pytest.approx(-2e-7 / (0.01 * T) * 0.1)
    r.energy_in = 0.0
    r.request((3e-4, 0.0, 0.0), now=3 * T, period_s=T)
    assert r.damping == 0.0


def test_a_hand_settling_by_steps_whose_square_underflows_gets_no_damper_and_no_error():
    """A handle settling under a steady force (the emulated hand's spring, a few seconds) moves by
    steps of 1e-164 m: its speed² is 1e-322 (subnormal), its speed² × T 0.0. The controller's
    damper divided by that and the driver died of a ZeroDivisionError in its loop (exit 1); the
    damper is now none, and a step whose product is above zero still gets the capped damper."""
    r = LocalRenderer()
    take_at(r, (0.0, 0.0, 0.0), 0.0, kd=100.0)
    r.request((0.0, 0.0, 0.0), now=0.0, period_s=T)
    r.rendered(np.zeros(3))
    r.energy_in = -2e-3  # a deficit: the controller would act
    f = r.request((1e-164, 0.0, 0.0), now=T, period_s=T)
    assert r.damping == 0.0 and np.all(np.isfinite(f))
    r.rendered(np.zeros(3))
    r.request((1e-150, 0.0, 0.0), now=2 * T, period_s=T)
    assert r.damping == MAX_DAMPING


def test_a_renderer_that_has_heard_nothing_renders_nothing_and_reports_its_idle_state():
    """Before any model the driver logs weight 0, β 1 (nothing scaled), no damper, no spring, no
    energy, no trip, no model; the scene's period is taken as the longest held (MAX_GAP_S), so a
    model would fade by 3 × 0.1 + 0.05 = 0.35 s; and a request is three zeros."""
    r = LocalRenderer()
    assert not r.heard and r.models == 0 and r.trips == 0
    assert (r.weight, r.beta, r.damping, r.spring, r.unpaid) == (0.0, 1.0, 0.0, 0.0, 0.0)
    assert (r.energy_in, r.energy_v, r.reserve) == (0.0, 0.0, 0.0)
    assert r.gap() == MAX_GAP_S and r.fade_end() == pytest.approx(0.35)
    assert r.validity(0.0) == 0.0 and r.request((0.01, 0.0, 0.0), now=0.0, period_s=T).tolist() == [0.0] * 3
    assert r.weight == 0.0 and r.beta == 0.0 and r.trips == 0


def test_every_model_taken_is_counted():
    r = LocalRenderer()
    for k in range(3):
        r.take(model(), arrived=k * 0.01)
    assert r.heard and r.models == 3


def test_credit_beyond_the_spring_leaks_down_to_the_bank():
    """Held 1 cm into the wall at kd 100 (the spring holds 5 mJ) with 1 J in both accounts: after
    one request each keeps the spring's 5 mJ plus BANK_J (0.2 mJ), and the reserve E_in − S is
    the bank."""
    r = LocalRenderer()
    take_at(r, (0.0, 0.0, 0.0), 0.0, planes=[WALL], kd=100.0)
    r.energy_in = r.energy_v = 1.0
    f = r.request((-0.01, 0.0, 0.0), now=0.0, period_s=T)
    assert f[0] == pytest.approx(1.0) and r.beta == 1.0 and r.spring == pytest.approx(5e-3, rel=1e-12)
    assert r.energy_in == pytest.approx(5e-3 + BANK_J, rel=1e-12) and r.energy_v == r.energy_in
    assert r.reserve == pytest.approx(BANK_J, rel=1e-9)


def test_a_re_anchoring_held_spends_nothing_and_its_shortfall_is_summed_each_period():
    """The re-anchoring above (5 mJ paid, 11.25 mJ asked) held for two periods, the hand still:
    the spring rendered holds exactly what was paid, so the accounts keep their 5 mJ, and the
    unpaid 11.25 − 5.001 mJ is counted in each period (twice)."""
    r = LocalRenderer()
    moved = ((0.005, 0.0, 0.0), (1.0, 0.0, 0.0), INF)
    take_at(r, (-0.01, 0.0, 0.0), 0.0, p_G=(0.005, 0, 0), planes=[moved], kd=100.0)
    r.energy_in = r.energy_v = 5e-3
    for k in range(2):
        r.rendered(r.request((-0.01, 0.0, 0.0), now=k * T, period_s=T))
        assert r.energy_v == 5e-3 and r.energy_in == 5e-3
    assert r.unpaid == pytest.approx(2 * (11.25e-3 - 5e-3 - ALLOWANCE_J), rel=1e-9)


def test_a_stop_or_the_clutch_renders_nothing_and_the_push_meanwhile_pays_nothing():
    """Not ``live`` (the scene's stop, the clutch) with a fresh model and the hand 1 cm into the
    wall: zero force, no spring held, β 0, the accounts untouched (1 mJ). The hand goes 1 mm
    deeper while the device holds zero: the next live request has the 1 mJ alone to pay the
    ½ kd (1.1 cm)² = 6.05 mJ the wall now asks (the environment rendered nothing over the step)."""
    r = LocalRenderer()
    take_at(r, (0.0, 0.0, 0.0), 0.0, planes=[WALL], kd=100.0)
    r.energy_in = r.energy_v = 1e-3
    f = r.request((-0.01, 0.0, 0.0), now=0.0, period_s=T, live=False)
    assert f.tolist() == [0.0, 0.0, 0.0] and (r.spring, r.beta, r.damping, r.weight) == (0.0, 0.0, 0.0, 1.0)
    assert r.energy_v == 1e-3 and r.energy_in == 1e-3
    r.rendered(f)
    r.request((-0.011, 0.0, 0.0), now=T, period_s=T)
    assert r.energy_v == 1e-3 and r.beta == pytest.approx(math.sqrt((1e-3 + ALLOWANCE_J) / 6.05e-3), rel=1e-9)


def test_an_expired_model_renders_no_force_not_even_the_controllers_damper():
    """A model of a 100 Hz scene ends 3 × 10 + 50 = 80 ms after it arrived: a request after that
    is zero, though the device's account is 1 mJ short and the hand moves at 0.1 m/s (no
    damper), and the accounts are left as they were for the model that follows; one trip."""
    r = LocalRenderer()
    take_at(r, (0.0, 0.0, 0.0), 0.0, p_G=(-0.001, 0.0, 0.0), kd=50.0, period_s=0.01)
    r.rendered(r.request((0.0, 0.0, 0.0), now=0.079, period_s=T, live=False))  # the clutch: nothing held
    assert 0.0 < r.weight < 0.05
    r.energy_in, r.energy_v = -1e-3, 3e-4
    f = r.request((1e-4, 0.0, 0.0), now=0.081, period_s=T)
    assert f.tolist() == [0.0, 0.0, 0.0] and (r.weight, r.beta, r.damping) == (0.0, 0.0, 0.0)
    assert r.energy_in == -1e-3 and r.energy_v == 3e-4 and r.trips == 1


# -- validity ----------------------------------------------------------------------------------------------


def test_a_model_holds_then_fades_to_zero_within_three_gaps_and_50_ms_and_counts_one_trip():
    r = LocalRenderer()
    for k in range(5):  # a scene at 64 Hz (times exact in binary)
        r.take(model(period_s=0.01), arrived=k / 64)
    last, gap = 4 / 64, 1 / 64
    assert r.gap() == pytest.approx(gap)
    hold, end = 2 * gap + HOLD_EXTRA_S, 3 * gap + END_EXTRA_S
    assert r.validity(last + hold) == 1.0
    assert r.validity(last + (hold + end) / 2) == pytest.approx(0.5)
    assert r.validity(last + end + 1e-12) == 0.0 and r.trips == 1
    assert r.validity(last + end + 1.0) == 0.0 and r.trips == 1
    r.take(model(period_s=0.01), arrived=last + 1.2)  # the scene back: valid, a new trip later
    assert r.validity(last + 1.2) == 1.0
    assert LocalRenderer().validity(0.0) == 0.0  # no model: nothing


def test_the_scene_period_is_its_stated_one_or_the_median_interval_when_longer():
    """One stall among 16 intervals does not stretch the fade (the median, not the longest); a
    scene publishing faster than it says is held for the period it says."""
    r = LocalRenderer()
    times = [k / 256 for k in range(16)] + [15 / 256 + 0.5]  # 4 ms intervals, then a 0.5 s stall
    for t in times:
        r.take(model(period_s=1 / 1024), arrived=t)
    assert r.gap() == 1 / 256
    fast = LocalRenderer()
    for k in range(5):
        fast.take(model(period_s=1 / 64), arrived=k / 1024)
    assert fast.gap() == 1 / 64


def test_a_scene_slower_than_10_hz_is_held_as_a_10_hz_one():
    r = LocalRenderer()
    r.take(model(period_s=1.0), arrived=0.0)
    assert r.gap() == 0.1 and r.validity(0.35 - 1e-6) > 0.0 and r.validity(0.35 + 1e-12) == 0.0


def test_a_fade_keeps_what_the_spring_held_for_the_model_that_follows():
    """Held 1 cm into the wall with the spring paid (5 mJ at kd 100), the model fades half way:
    half the force, and the accounts keep the 5 mJ; the next model renders the whole spring."""
    r = LocalRenderer()
    take_at(r, (-0.01, 0.0, 0.0), 0.0, planes=[WALL], kd=100.0, period_s=0.01)
    r.energy_in = r.energy_v = 0.5 * 100 * 0.01**2
    f = r.request((-0.01, 0.0, 0.0), now=(0.045 + 0.08) / 2, period_s=T)
    r.rendered(f)
    assert f[0] == pytest.approx(0.5) and r.energy_v == pytest.approx(5e-3)
    take_at(r, (-0.01, 0.0, 0.0), 0.07, planes=[WALL], kd=100.0, period_s=0.01)
    assert r.request((-0.01, 0.0, 0.0), now=0.07, period_s=T)[0] == pytest.approx(1.0)


def test_a_fading_model_renders_its_weight_of_the_force():
    r = LocalRenderer()
    take_at(r, (0.0, 0.0, 0.0), 0.0, p_G=(0.01, 0.0, 0.0), kd=100.0, period_s=0.01)
    f = r.request((0.0, 0.0, 0.0), now=(0.045 + 0.08) / 2, period_s=T)  # half way down
    assert np.allclose(f, [0.5, 0.0, 0.0])


def test_the_fade_ends_three_gaps_and_50_ms_after_the_model():
    r = LocalRenderer()
    for k in range(3):  # 64 Hz
        r.take(model(period_s=0.01), arrived=k / 64)
    assert r.gap() == 1 / 64 and r.fade_end() == pytest.approx(3 / 64 + END_EXTRA_S, rel=1e-15)


def test_two_models_at_the_same_time_are_no_interval():
    """A model taken at the same instant as the one before (two in one poll) is no 0 s interval:
    the scene's period stays the 1/64 s between the others (a 0 would halve the median)."""
    r = LocalRenderer()
    for t in (0.0, 1 / 64, 1 / 64):
        r.take(model(period_s=1 / 1024), arrived=t)
    assert r.gap() == 1 / 64


def test_the_scene_period_is_the_median_of_the_last_16_intervals_only():
    """Intervals of 1/64 s, then 8 of 1/256 s and 8 of 1/128 s: the last 16 are the 8 and 8, their
    median (1/256 + 1/128)/2 = 3/512 s; the 1/64 before them is forgotten (with it, 17 intervals
    would have the median 1/128)."""
    r = LocalRenderer()
    t = 0.0
    r.take(model(period_s=1 / 1024), arrived=t)
    for dt in [1 / 64] + [1 / 256] * 8 + [1 / 128] * 8:
        t += dt
        r.take(model(period_s=1 / 1024), arrived=t)
    assert r.gap() == 3 / 512


def test_a_trip_is_counted_at_each_fall_to_zero_and_only_then():
    """A 100 Hz scene's model (hold 45 ms, end 80 ms): valid at every millisecond of its life, no
    trip; the fall after 80 ms is one; the scene back after 1 s (its period now taken as the
    longest held, 0.1 s: the end 0.35 s after) and gone again: the second trip; a model first
    looked at after its end never fell: no trip."""
    r = LocalRenderer()
    r.take(model(period_s=0.01), arrived=0.0)
    assert all(r.validity(k * 1e-3) > 0.0 for k in range(80)) and r.trips == 0
    assert r.validity(0.081) == 0.0 and r.trips == 1
    r.take(model(period_s=0.01), arrived=1.0)
    assert r.gap() == MAX_GAP_S and r.validity(1.0 + 0.34) > 0.0 and r.trips == 1
    assert r.validity(1.0 + 0.351) == 0.0 and r.trips == 2
    late = LocalRenderer()
    late.take(model(period_s=0.01), arrived=0.0)
    assert late.validity(0.5) == 0.0 and late.trips == 0


# -- the scene's heartbeat ---------------------------------------------------------------------------------


def test_a_heartbeat_is_read_back_as_written_and_a_wrong_one_is_refused_by_length_magic_or_time():
    raw = alive_message(1_234_567)
    assert len(raw) == 12 and raw[:4] == b"GLA1" and parse_alive(raw) == 1_234_567
    assert parse_alive(alive_message(0)) == 0
    with pytest.raises(LocalModelError, match=r"^scene heartbeat: 11 bytes; expected 12$"):
        parse_alive(raw[:-1])
    with pytest.raises(LocalModelError, match=r"^scene heartbeat: 13 bytes; expected 12$"):
        parse_alive(raw + b"\0")
    with pytest.raises(LocalModelError, match=r"^scene heartbeat: magic b'GLM2', not b'GLA1'$"):
        parse_alive(b"GLM2" + raw[4:])
    with pytest.raises(LocalModelError, match=r"^scene heartbeat: time -1 µs must be ≥ 0$"):
        parse_alive(struct.pack(">4sq", b"GLA1", -1))
    assert ALIVE_CHANNEL != LOCAL_MODEL_CHANNEL


def test_a_heartbeat_naming_the_model_holds_it_as_its_arrival_would():
    """A 64 Hz scene's model (hold 2/64 s + 25 ms, end 3/64 s + 50 ms, times exact in binary)
    taken at 1 s, faded (a trip) at 1.25 s when a heartbeat naming it arrives: the model is whole
    again, until hold after the beat,
    fades to half half way, and is zero (one trip) just past end after it."""
    r = LocalRenderer()
    for k in range(5):
        r.take(model(period_s=0.01, utime=7), arrived=1.0 - (4 - k) / 64)
    gap = 1 / 64
    hold, end = 2 * gap + HOLD_EXTRA_S, 3 * gap + END_EXTRA_S
    assert r.validity(1.0 + hold) == 1.0
    assert r.validity(1.25) == 0.0 and r.trips == 1  # past its own end: faded
    r.alive(7, arrived=1.25)
    assert (r.alive_at, r.beats) == (1.25, 1)
    assert r.validity(1.25) == 1.0 and r.validity(1.25 + hold) == 1.0
    assert r.validity(1.25 + (hold + end) / 2) == pytest.approx(0.5)
    assert r.validity(1.25 + end + 1e-12) == 0.0 and r.trips == 2
    assert r.gap() == gap  # a heartbeat is no model: the scene's period is the models'


def test_a_heartbeat_for_another_model_or_before_any_holds_nothing():
    """A beat naming an older model, a newer one (lost, or not here yet), or any before the
    first model changes nothing; an older beat arriving after a newer one does not move the
    scene's last word back."""
    r = LocalRenderer()
    r.alive(5, arrived=0.0)
    assert (r.alive_at, r.beats, r.heard) == (-INF, 0, False)
    r.take(model(period_s=0.01, utime=5), arrived=0.0)  # hold 45 ms, end 80 ms
    r.alive(4, arrived=0.07)
    r.alive(6, arrived=0.07)
    assert (r.alive_at, r.beats) == (-INF, 0) and r.validity(0.081) == 0.0
    r.alive(5, arrived=0.2)
    r.alive(5, arrived=0.1)
    assert (r.alive_at, r.beats) == (0.2, 2) and r.validity(0.2 + 0.045) == 1.0


def test_the_scene_beats_while_its_loop_is_held_up_and_only_then():
    """The scene's side (link/scene_model.py SceneHeartbeat, beat 5 ms, limit 0.5 s, decided on the
    times given): no beat before a model; none while the model is younger than a beat; one at
    each tick from 5 ms to 0.5 s after it, naming its time; none past the limit (a loop that
    hangs is vouched for no longer); none once stopped."""
    from godobject_drake.link.scene_model import BEAT_S, STALL_LIMIT_S, SceneHeartbeat

    sent = []
    beat = SceneHeartbeat(sent.append, clock=lambda: 0.0)
    beat._thread = "not started"  # the decisions alone: no thread
    assert not beat.tick(1.0) and sent == []
    beat.model_sent(42_000, now=10.0)
    assert not beat.tick(10.0 + BEAT_S / 2)
    assert beat.tick(10.0 + BEAT_S) and beat.tick(10.0 + STALL_LIMIT_S)
    assert not beat.tick(10.0 + STALL_LIMIT_S + 1e-9)
    assert [parse_alive(raw) for raw in sent] == [42_000, 42_000] and beat.beats == 2
    beat.model_sent(43_000, now=11.0)  # the loop goes on: a newer model, beats again
    assert beat.tick(11.0 + BEAT_S) and parse_alive(sent[-1]) == 43_000
    beat.stop()
    assert not beat.tick(11.0 + 2 * BEAT_S) and beat.beats == 3
    beat.model_sent(44_000, now=20.0)  # the same scene run again: it vouches again
    assert beat.tick(20.0 + 2 * BEAT_S) and parse_alive(sent[-1]) == 44_000
    beat.stop()


def test_the_scenes_heartbeat_thread_speaks_while_the_main_thread_computes():
    """The thread the first model starts beats while this (main) thread runs Python for 0.2 s
    without a pause (50 ms at a time), as a fold of the logs does (the interpreter hands the
    thread its turn);
    stopped, it ends; a model after the stop (the scene run again) starts a new one."""
    import time

    from godobject_drake.link.scene_model import SceneHeartbeat

    sent = []
    beat = SceneHeartbeat(sent.append)
    beat.model_sent(1, now=time.monotonic())
    deadline = time.monotonic() + 10.0
    while len(sent) < 3 and time.monotonic() < deadline:
        end = time.monotonic() + 0.05
        while time.monotonic() < end:
            pass
    assert len(sent) >= 3 and all(parse_alive(raw) == 1 for raw in sent)
    beat.stop()
    first = beat._thread
    first.join(timeout=5.0)
    assert not first.is_alive()
    beat.model_sent(2, now=time.monotonic())  # run again: a new thread, which speaks too
    deadline = time.monotonic() + 10.0
    while parse_alive(sent[-1]) != 2 and time.monotonic() < deadline:
        end = time.monotonic() + 0.05
        while time.monotonic() < end:
            pass
    assert beat._thread is not first and parse_alive(sent[-1]) == 2
    beat.stop()
    beat._thread.join(timeout=5.0)
    assert not beat._thread.is_alive()


# -- a closed loop: the emulated device against a slow scene's wall ---------------------------------------


class _Clock:
    def __init__(self):
        self.t = 0.0

    def __call__(self):
        return self.t


def _wall_loop(scene_hz: float, kd: float, local: bool):
    """The emulated handle (0.1 kg, hand 400 N/m, 8 N·s/m) pressed 2.5 cm past a wall at x = 0
    (from x = +1 cm), held, and brought back; a scene at ``scene_hz`` sees the handle when it
    publishes and answers with a god-object on the wall (its contact one scene period late).
    ``local``: the driver renders the local model; else the scene's wrench, held. Returns the
    work the device did on the hand (J) and the force's ripple during the hold (N)."""
    clock = _Clock()
    xyz = np.array([[0.01, 0, 0], [-0.025, 0, 0], [-0.025, 0, 0], [0.01, 0, 0], [0.01, 0, 0]])
    path = HandPath(np.array([0.0, 0.5, 1.5, 2.0, 3.0]), xyz, np.zeros(5, bool), np.zeros(5, bool))
    device = EmulatedDevice(path, clock=clock, start_on_scene=False)
    r = LocalRenderer()
    work, f, held, peak = 0.0, np.zeros(3), [], 0.0
    every = round(1.0 / scene_hz / T)
    h_prev = None
    for k in range(3000):
        clock.t = k * T
        h, _, _ = device.read()
        if h_prev is not None:
            work += float(f @ (h - h_prev))  # the held force over the period's motion
        h_prev = h
        if k % every == 0:  # the scene's step: the god-object on the wall, the handle as it was then
            p_G = np.array([max(h[0], 0.0), 0.0, 0.0])
            scene_model = model(p_G=p_G, p_T=h, planes=[WALL] if h[0] < 0.005 else [], kd=kd)
            r.take(scene_model, arrived=clock.t, h_used=h)
            wrench = kd * (p_G - h)
        f = r.request(h, clock.t, T) if local else wrench
        r.rendered(f)
        peak = max(peak, abs(f[0]))
        device.render(f)
        if 1.0 <= clock.t <= 1.5:
            held.append(f[0])
    return work, float(np.ptp(held)), peak


@pytest.mark.parametrize("scene_hz", [1000, 100, 30])
@pytest.mark.parametrize("kd", [200.0, 1000.0])
def test_the_local_model_wall_does_no_work_on_the_hand_where_the_held_wrench_does(scene_hz, kd):
    """Press, hold, release against a wall a slow scene publishes: the held wrench puts energy
    into the hand (its contact arrives a scene period late), the local model does not (≤ 0.5 mJ)
    and holds still. The same loop, the same hand, exact arithmetic: the held wrench at 30 Hz
    is the check that this test can fail."""
    work_local, ripple_local, peak = _wall_loop(scene_hz, kd, local=True)
    work_held, _, _ = _wall_loop(scene_hz, kd, local=False)
    print(f"{scene_hz} Hz kd {kd:g}: local model {work_local * 1e3:+.4f} mJ (ripple {ripple_local:.4f} N, "
          f"peak {peak:.3f} N); "
          f"held wrench {work_held * 1e3:+.3f} mJ")  # fmt: skip
    assert work_local <= 0.5e-3 and ripple_local <= 0.05
    if scene_hz <= 100:
        assert work_held > 0.5e-3


# -- the scene's side: the coupling's free lag -------------------------------------------------------------


def _held_samples_exactly(omega, samples, period):
    """The coupling's law for a free god-object, ``p̈ = ω² (p_D − p) + 2ω (v_D − ṗ)``, solved
    exactly over each period with the sample that started it held (the matrix exponential of the
    linear ODE): the lag ``p − p_D`` of the next sample after each period, the second method
    FreeLag is checked against."""
    from scipy.linalg import expm

    k, b = omega**2, 2 * omega
    p, v, lags = samples[0][0].copy(), np.zeros(3), []
    for (p_D, v_D), (p_next, _) in itertools.pairwise(samples):
        for axis in range(3):
            A = np.array([[0.0, 1.0, 0.0], [-k, -b, k * p_D[axis] + b * v_D[axis]], [0.0, 0.0, 0.0]])
            p[axis], v[axis], _ = expm(A * period) @ np.array([p[axis], v[axis], 1.0])
        lags.append(p - p_next)
    return lags


def test_the_free_lag_follows_the_coupling_law_for_a_free_god_object():
    """A hand starts at 6 cm/s from rest, sampled at 1 kHz (held between samples, the backward
    difference as its velocity): the coupling (ω 40 rad/s, critical) lags at most about
    ``V/(e ω)`` = 0.55 mm, then follows the ramp. ``FreeLag`` (symplectic Euler, as Drake steps a
    free body) against the exact solution of the same held samples: within ``3 ω h`` of the peak
    at h = 1 ms, half that at h = 0.5 ms (first order). Its force cap: a 1 m jump of the target
    is met at ``ω² max_stretch`` m/s² (0.2 m/s after the first millisecond at 0.125 m), not 40 m/s."""
    from godobject_drake.link.scene_model import FreeLag

    omega, V, T = 40.0, np.array([0.0, 0.06, 0.0]), 1e-3
    samples = [(V * T * max(n - 1, 0), V if n > 1 else np.zeros(3)) for n in range(400)]  # a start at rest
    exact = _held_samples_exactly(omega, samples, T)
    peak = 0.06 / (math.e * omega)
    assert max(np.linalg.norm(lag) for lag in exact) == pytest.approx(peak, rel=0.1)
    for implicit in (False, True):  # symplectic Euler (the explicit coupling), backward Euler (SAP's)
        worst = {}
        for h in (1e-3, 5e-4):
            free = FreeLag(omega**2, 2 * omega, math.inf, h, implicit)
            free.reset(0.0, 3, samples[0][0], np.zeros(3), np.zeros(3), samples[0][1])
            lags = [np.array(free.advance(n * T, *samples[n])) for n in range(1, len(samples))]
            worst[h] = max(np.linalg.norm(a - b) for a, b in zip(lags, exact, strict=True))
        assert worst[1e-3] <= 3 * omega * 1e-3 * peak and 1.8 <= worst[1e-3] / worst[5e-4] <= 2.2, worst
    capped = FreeLag(omega**2, 2 * omega, 0.125, 1e-3)
    capped.reset(0.0, 3, np.zeros(3), np.zeros(3), np.zeros(3), np.zeros(3))
    capped.advance(1e-3, np.array([1.0, 0.0, 0.0]), np.zeros(3))  # the jump, held from 1 ms on
    assert capped.v == (0.0, 0.0, 0.0)  # the first millisecond held the sample at 0
    capped.advance(2e-3, np.array([1.0, 0.0, 0.0]), np.zeros(3))
    assert capped.v[0] == pytest.approx(1e-3 * omega**2 * 0.125)  # 0.2 m/s
    assert capped.v[1:] == (0.0, 0.0)


def _carry(rate_hz: float) -> str:
    """A brick scene's device, scripted: grasp brick_0 where it rests, lift it 1.5 cm at 5.1 cm/s,
    carry it toward the wall at 35 cm/s, sampled at ``rate_hz``; 0.52 s (before it reaches the wall)."""
    return f"""
device: !Scripted
  path: ""
  rate_hz: {rate_hz}
  waypoints:
  - {{t: 0.0, xyz: [-0.10, 0.0, 0.0048], rpy_deg: [0, 0, 0], grasp: brick_0}}
  - {{t: 0.3, xyz: [-0.10, 0.0, 0.020], rpy_deg: [0, 0, 0], grasp: brick_0}}
  - {{t: 0.7, xyz: [0.04, 0.0, 0.020], rpy_deg: [0, 0, 0], grasp: brick_0}}
simulation: {{duration_s: 0.52}}
"""


def test_the_free_lag_is_the_brick_scenes_own_stretch_while_it_touches_nothing():
    """The brick scene in Drake (h = 1 ms, the explicit coupling, ω 40 rad/s): the device grasps
    brick_0, lifts it at 5.1 cm/s and carries it toward the wall at 35 cm/s (what a 6 cm/s hand is
    to a scene at a sixth of real time), sampled at 1 kHz. ``FreeLag`` driven by the samples the
    coupling logged, each given at the step it starts (as the publisher sees them), is the
    scene's own stretch ``p_G − p_T`` within 1 µm while the brick touches nothing (before 0.52 s;
    the stretch reaches 3 mm). Given each sample for the period before it, the twin ran one
    sample ahead: 0.35 mm off at 35 cm/s (measured), the drag of 0.10 N at kd 200 N/m the bench
    measured at a sixth of real time."""
    from pydrake.systems.analysis import Simulator

    from godobject_drake.config import scenario as sc
    from godobject_drake.link.scene_model import FreeLag
    from godobject_drake.station.build import build_station
    from godobject_drake.systems.coupling import TERMS_LAYOUT

    path = _carry(rate_hz=1000.0)
    station = build_station(sc.load_scenario(REPO / "diagrams" / "lego.yaml", path))
    simulator = Simulator(station.diagram)
    simulator.AdvanceTo(0.52)
    log = station.loggers["terms"].FindLog(simulator.get_context())
    t, terms = log.sample_times(), log.data().T
    held = terms[:, TERMS_LAYOUT["held_body"]]
    p_T, V_T = terms[:, TERMS_LAYOUT["pose_WT"]][:, 4:], terms[:, TERMS_LAYOUT["V_WT"]][:, 3:]
    p_G, V_G = terms[:, TERMS_LAYOUT["pose_WG"]][:, 4:], terms[:, TERMS_LAYOUT["V_WG"]][:, 3:]
    coupling = station.god_object.coupling
    assert held[0] >= 0 and np.all(held == held[0])
    free = FreeLag(coupling._wn2, coupling._2zwn, coupling.max_stretch_m, station.plant.time_step())
    free.reset(t[0], int(held[0]), p_T[0], p_G[0] - p_T[0], V_G[0], V_T[0])
    off = [np.linalg.norm(p_G[k] - p_T[k] - free.advance(t[k], p_T[k], V_T[k])) for k in range(1, len(t))]
    assert np.max(np.linalg.norm(p_G - p_T, axis=1)) > 3e-3  # the scene's own stretch: not a trivial check
    assert max(off) < 1e-6, max(off)


def test_the_implicit_free_lag_is_the_haptic_recipes_own_stretch_to_a_fiftieth():
    """The haptic recipe in Drake (diagrams/lego_haptic.yaml: h = 5 ms, the implicit coupling, its
    springs stepped by SAP), the device sampled at 200 Hz on the path of the test above (the
    springs moved between steps as a run moves them, :meth:`before_step`). ``FreeLag`` by backward
    Euler, driven by the targets the coupling logged, each from the step it is in force: within
    0.05 mm of the scene's stretch, whose peak is 4.7 mm (measured: 0.035 mm, all of it vertical,
    from the lift off the table on; the carrying direction to 1e-9 m); symplectic Euler, the
    explicit coupling's twin, is 2.2 mm off (measured: the recipe's 0.06 N of drag at kd 200 N/m
    at real time, before the twin knew its coupling)."""
    from pydrake.systems.analysis import Simulator
    from pydrake.systems.framework import EventStatus

    from godobject_drake.config import scenario as sc
    from godobject_drake.link.scene_model import FreeLag
    from godobject_drake.station.build import build_station
    from godobject_drake.systems.coupling import TERMS_LAYOUT
    from godobject_drake.systems.implicit import STATE_LAYOUT, implicit_terms

    path = _carry(rate_hz=200.0)
    station = build_station(sc.load_scenario(REPO / "diagrams" / "lego_haptic.yaml", path))
    tool, plant = station.god_object, station.plant
    simulator = Simulator(station.diagram)
    tool.prepare(plant.GetMyContextFromRoot(simulator.get_mutable_context()))
    hook = tool.before_step(plant)

    def monitor(root):
        hook(plant.GetMyContextFromRoot(root), root)
        return EventStatus.Succeeded()

    simulator.set_monitor(monitor)
    simulator.Initialize()
    simulator.AdvanceTo(0.52)
    context = simulator.get_context()
    t = station.loggers["state"].FindLog(context).sample_times()
    states = station.loggers["state"].FindLog(context).data().T
    rows = station.loggers["coupling"].FindLog(context).data().T
    coupling = tool.coupling
    assert getattr(coupling, "integrates_implicitly", False)
    p_G = implicit_terms(coupling, states, rows)[:, TERMS_LAYOUT["pose_WG"]][:, 4:]
    p_T, V_T = rows[:, STATE_LAYOUT["pose_WT"]][:, 4:], rows[:, STATE_LAYOUT["V_WT"]][:, 3:]
    off = {}
    for implicit in (True, False):
        free = FreeLag(coupling._wn2, coupling._2zwn, coupling.max_stretch_m, plant.time_step(), implicit)
        free.reset(t[1], 3, p_T[1], p_G[1] - p_T[1], np.zeros(3), V_T[1])
        lags = np.array([free.advance(t[k], p_T[k], V_T[k]) for k in range(2, len(t))])
        off[implicit] = np.abs(p_G[2:] - p_T[2:] - lags)
    assert np.max(np.linalg.norm(p_G - p_T, axis=1)) > 4e-3
    assert off[True].max() < 5e-5 and off[True][:, 0].max() < 1e-8 and off[False].max() > 1e-3, off


def test_the_free_lag_restarts_on_the_god_object_when_the_grasp_changes():
    """A new held body: the free god-object starts where the scene's is (lag = its stretch, no
    force from it), moving with it; nothing held: the coupling's G is the target (lag 0)."""
    from godobject_drake.link.scene_model import FreeLag

    free = FreeLag(1600.0, 80.0, math.inf, 1e-3)
    assert free.advance(0.0, np.ones(3), np.zeros(3)) == (0.0, 0.0, 0.0)  # nothing held yet
    p_D, stretch, v_G = np.array([0.2, 0.1, 0.0]), np.array([0.0, 0.0, -0.003]), np.array([0.0, 0.5, 0.0])
    free.reset(0.004, 5, p_D, stretch, v_G, np.zeros(3))
    assert free.lag == (0.0, 0.0, -0.003) and np.allclose(free.p, [0.2, 0.1, -0.003], rtol=0, atol=1e-15)
    assert free.v == (0.0, 0.5, 0.0)
    free.reset(0.008, -1, np.array([0.3, 0.0, 0.0]), np.array([0.01, 0, 0]), np.zeros(3), np.zeros(3))
    assert free.advance(0.009, np.array([0.3, 0.0, 0.0]), np.ones(3)) == (0.0, 0.0, 0.0)


def test_after_a_stall_the_damper_takes_the_handles_speed_over_the_time_that_passed():
    """The driver's loop is held up 18 ms (a loaded machine) while the hand moves at 0.1 m/s: the
    handle is 1.8 mm on at the next request. Its speed is 1.8 mm / 18 ms = 0.1 m/s, so the
    controller's damper, capped (a 100 mJ deficit: 100 mJ / (0.1² × 1 ms) ≫ 10 N·s/m), pushes
    1 N against it, not the 18 N of the same step read as one period's 1.8 m/s (the spike seen
    after a stall on a loaded machine); the stretch's rate through a soft plane the same:
    γd × 0.1 m/s × kd/(kd + s), not 18 times that."""
    r = LocalRenderer()
    take_at(r, (0.0, 0.0, 0.0), 0.0, kd=100.0)
    r.request((0.0, 0.0, 0.0), now=0.0, period_s=T)
    r.rendered(np.zeros(3))
    r.energy_in = -0.1  # a deficit: the controller acts, at its cap
    f = r.request((1.8e-3, 0.0, 0.0), now=0.018, period_s=T)
    assert r.damping == MAX_DAMPING and np.allclose(f, [-MAX_DAMPING * 0.1, 0.0, 0.0], rtol=1e-12)
    # the stretch's rate: a soft plane (s = kd) the handle presses into by 1.8 mm in 18 ms
    r = LocalRenderer()
    soft = ((0.0, 0.0, 0.0), (0.0, 0.0, 1.0), 100.0)
    take_at(r, (0.0, 0.0, 0.0), 0.0, kd=100.0, gamma_d=2.0, planes=(soft,))
    r.request((0.0, 0.0, 0.0), now=0.0, period_s=T)
    r.rendered(np.zeros(3))
    r.energy_in = r.energy_v = 1.0  # paid for: β = 1, no controller
    f = r.request((0.0, 0.0, -1.8e-3), now=0.018, period_s=T)
    # the proxy sinks by kd/(kd + s) = ½ of the way: its stretch 0.9 mm up, its rate 0.05 m/s
    assert r.damping == 0.0 and f[2] == pytest.approx(100.0 * 0.9e-3 + 2.0 * 0.05, rel=1e-9)
