"""Both hands from two drivers (issue 53 item 4): the bimanual laparoscopy scene
(``laparoscopy_bimanual_drivers``) with each grasper's device on a driver link of its own, and two
``godobject-driver run emulated`` processes, one per hand, on loopback.

What a person can check: the left hand's path (models/haptic/bimanual_left.json) takes the left
grasper's jaws to the grasp site on the uterus's edge, closes them there and lifts, so the left
tool takes ``edge::site`` and the held edge pulls its jaws down: the left driver renders a force
with a downward z (the device's frame has the world's axes). The right hand's path
(bimanual_right.json) presses the right grasper's closed jaws 8 mm past the uterus's top, so the
tissue pushes back: the right driver renders a force with an upward z. Swap the two links (each
tool driven by the other's hand) and neither holds: the left jaws close far from the site, the
right ones come down beside the organ (its y radius is 30 mm, the left hand takes them to
y = −45 mm).
"""

import json
import threading

import numpy as np
import pytest
from test_driver import free_port, start_driver

from godobject_drake.config.scenario import MODELS_DIR, ScenarioError, shipped_scenario
from godobject_drake.driver import process as drv
from godobject_drake.simulation import simulate
from godobject_drake.station.build import build_station

HANDS = ("left", "right")


def hand(name: str) -> dict:
    return json.loads((MODELS_DIR / "haptic" / f"bimanual_{name}.json").read_text())


def rendered(log) -> np.ndarray:
    return np.c_[log["fx"], log["fy"], log["fz"]]


def test_two_tools_on_one_driver_link_are_refused_naming_both_and_the_fix():
    """A udp:// link pairs with one driver, which drives one tool: two tools on one address are
    refused before the run, whatever their channels (they used to pass the check, then fail to
    listen, blaming "another scene or driver"); two on one channel of one link, as before."""
    one_port = "tools: {right: {device: !Lcm {url: 'udp://127.0.0.1:7668', channel: RIGHT_POSE}}}"
    with pytest.raises(
        ScenarioError,
        match=r"tools\.right\.device\.url: 'udp://127\.0\.0\.1:7668' is tools\.left's driver link too: a "
        r"udp:// link pairs with one driver, which drives one tool; give each tool a port of its own "
        r"\(e\.g\. udp://127\.0\.0\.1:7669\) and start one driver for each",
    ):
        shipped_scenario("laparoscopy_bimanual_drivers", one_port)
    in_process = "tools: {left: {device: !Lcm {url: 'memq://'}}, right: {device: !Lcm {url: 'memq://'}}}"
    with pytest.raises(
        ScenarioError, match=r"tools\.right\.device\.channel: 'GODOBJECT_DEVICE_POSE' on memq"
    ):
        shipped_scenario("laparoscopy_bimanual_drivers", in_process)
    ports = shipped_scenario("laparoscopy_bimanual_drivers").tools  # as shipped: a port each
    assert [ports[name].device.url for name in HANDS] == ["udp://127.0.0.1:7668", "udp://127.0.0.1:7669"]


def test_the_feedback_at_each_device_is_3_kd_along_the_tube_and_far_stiffer_across_it():
    """The left device at its grasper's starting tip (45 mm below the pivot), the feedback's
    stiffness per N/m of kd (Eq. 8's spring on each coupled body's centre of mass, through the
    trocar's ``Jᵀ f = τ``), by two methods: Jacobians (``J⁻ᵀ (Σ Jᵢᵀ Jᵢ) J⁻¹``, as
    analysis/bimanual_drivers.py --stiffness gives it) and Drake's forward kinematics (the device
    moved 10 µm, each body's centre of mass moved, the spring's forces mapped to the device as the
    scene maps them). Along the tube 3 kd (the tube and the two jaws slide 1:1 with the insertion:
    by hand); across it 25.4 kd, the centres of mass being above the pivot. The shipped kd keeps
    that under 600 N/m (kd 60, 1,530 N/m, oscillated the emulated handle to its 12 N clamp)."""
    from pydrake.multibody.tree import BodyIndex

    from godobject_drake.config.scenario import replace
    from godobject_drake.devices.trocar import TrocarKinematics
    from godobject_drake.systems.articulated import generalized_forces

    s = replace(shipped_scenario("laparoscopy_bimanual"), **{"organs.model": "rigid"})
    station = build_station(s)
    plant, tool = station.plant, station.tools["left"].coupling.tool
    model = plant.GetModelInstanceByName("grasper_left")
    kin = TrocarKinematics.from_plant(plant, model, "port", "tube", ("yaw", "pitch", "insertion", "roll"))
    drivers = shipped_scenario("laparoscopy_bimanual_drivers").tools["left"]
    q0 = kin.inverse(drivers.device.device_to_world.xyz, np.eye(3))
    assert q0[2] == pytest.approx(0.0451, abs=1e-4)  # 45 mm deep
    v = [plant.GetJointByName(j, model).velocity_start() for j in ("yaw", "pitch", "insertion")]
    K = sum(J[3:, v].T @ J[3:, v] for J in tool.com_jacobians(np.r_[q0, 0.0, 0.0]))
    J_inv = np.linalg.inv(kin.jacobian(q0))
    K_device = J_inv.T @ K @ J_inv  # method 1, per N/m of kd
    u = kin.forward(q0)[1][:, 2]  # the tube's axis
    across = np.cross(u, [1.0, 0.0, 0.0])
    across /= np.linalg.norm(across)

    context = plant.CreateDefaultContext()

    def centres(q4):
        positions = plant.GetPositions(context).copy()
        for name, value in zip(("yaw", "pitch", "insertion", "roll"), q4, strict=True):
            positions[plant.GetJointByName(name, model).position_start()] = value
        plant.SetPositions(context, positions)
        return [plant.EvalBodyPoseInWorld(context, plant.get_body(BodyIndex(b.index))).multiply(b.p_BoBcm_B)
                for b in tool.bodies]  # fmt: skip

    def stiffness(direction):  # method 2: the device moved 10 µm, kd = 1 (Eq. 8: f = kd (x − x_device))
        p0, R0 = kin.forward(q0)
        q1 = kin.inverse(p0 + 1e-5 * direction, R0)
        f = [x - x_device for x, x_device in zip(centres(q0), centres(q1), strict=True)]
        tau = generalized_forces(tool, np.array([np.r_[np.zeros(3), fi] for fi in f]), np.r_[q0, 0.0, 0.0])
        return -float(kin.device_wrench(q0, tau[:4])[3:] @ direction) / 1e-5  # it pulls the device back

    assert u @ K_device @ u == pytest.approx(3.0, rel=1e-6)
    assert stiffness(-u) == pytest.approx(3.0, rel=1e-3)
    assert across @ K_device @ across == pytest.approx(25.44, abs=0.01)
    assert stiffness(across) == pytest.approx(across @ K_device @ across, rel=1e-3)
    kd = drivers.feedback.kd
    assert kd * across @ K_device @ across < 600.0, (
        f"kd {kd}: {kd * across @ K_device @ across:.0f} N/m across"
    )


@pytest.mark.slow(seconds=90)
def test_two_driver_processes_each_drive_their_own_grasper_and_feel_its_tissue(tmp_path):
    """The scene waits for both drivers, then runs its 8 s at real time (slower on a loaded
    machine: each hand moves on the wall clock, so it runs ahead of the scene, and the checks
    below hold for that). Checked: each link paired once with its own driver, whose counts the
    tool's metrics carry; a second driver for the left tool, started 1 s into the run, is refused
    (the left link counts it, the right does not) and renders nothing; the left grasper takes the
    site and lifts it while the right one presses the tissue; each driver renders a non-zero force
    of the direction its tool's contact gives (left: down, the held edge; right: up, the tissue)."""
    s = shipped_scenario("laparoscopy_bimanual_drivers")
    urls = {name: f"udp://127.0.0.1:{free_port()}" for name in HANDS}
    for name in HANDS:
        s.tools[name].device.url = urls[name]
    folders = {name: tmp_path / name for name in (*HANDS, "second")}
    for folder in folders.values():
        folder.mkdir()
    drivers = {
        name: start_driver(folders[name], urls[name], "--exit-on-stop", "--duration", "600", hand=hand(name))
        for name in HANDS
    }
    started = threading.Event()
    second = []

    def start_second(plant_context, root_context):  # once both drivers are paired and the run is on
        if not started.is_set() and plant_context.get_time() >= 1.0:
            started.set()
            second.append(start_driver(folders["second"], urls["left"], "--duration", "2", hand=hand("left")))

    try:
        result = simulate(build_station(s), progress=False, observe=start_second)
        for name, driver in drivers.items():
            assert driver.wait(timeout=60) == 0, (name, driver.stderr.read())
        assert second and second[0].wait(timeout=60) == 0, second and second[0].stderr.read()
    finally:
        for driver in [*drivers.values(), *second]:
            driver.kill()
    m = result.metrics
    assert not m["diverged"]
    tools = m["tools"]
    for name in HANDS:  # each link: one pairing, its own driver's counts
        assert tools[name]["lcm_udp_pairings"] == 1, name
        assert tools[name]["driver_loops"] > 1000 and tools[name]["driver_status_messages"] > 0, name
    assert tools["left"]["lcm_udp_refused_drivers"] == 1 and tools["right"]["lcm_udp_refused_drivers"] == 0
    refused = json.loads((folders["second"] / "driver.json").read_text())
    assert refused["link"]["udp_refused"] > 0 and refused["link"]["udp_pairings"] == 0
    assert not np.any(rendered(drv.read_log(folders["second"] / "driver.csv")))

    # each tool went where its own hand took it
    events = tools["left"].get("grasp_events", [])
    assert events and events[0].endswith("took edge::site"), events
    assert "grasp_events" not in tools["right"]
    assert tools["left"]["grasped_max_rise_m"] > 0.002
    assert tools["right"]["max_tissue_contact_force_N"] > 1.0
    assert tools["left"]["max_tissue_contact_force_N"] < 0.5 * tools["right"]["max_tissue_contact_force_N"]

    took, let_go = (float(e.split()[0]) for e in events)
    logs = {name: drv.read_log(folders[name] / "driver.csv") for name in HANDS}
    left, right = logs["left"], logs["right"]
    # left: held, the hand lifted (its handle above -15 mm on its way up from -30 mm)
    ok = left["state"] == "ok"
    held = ok & (left["t_scene"] > took) & (left["t_scene"] < let_go) & (left["z"] > -0.015)
    # right: the handle within 5 mm of the press's depth (-34.8 mm)
    pressed = (right["state"] == "ok") & (right["z"] < -0.030)
    f_left, f_right = rendered(left)[held], rendered(right)[pressed]
    print(
        f"left: {held.sum()} periods held, |f| peak {np.linalg.norm(f_left, axis=1).max():.3g} N, "
        f"mean f {np.round(f_left.mean(axis=0), 3)}; right: {pressed.sum()} periods pressed, |f| peak "
        f"{np.linalg.norm(f_right, axis=1).max():.3g} N, mean f {np.round(f_right.mean(axis=0), 3)}; "
        f"real time {m['real_time_factor']:.3g}, trips {[tools[n]['driver_watchdog_trips'] for n in HANDS]}"
    )
    assert held.sum() > 20 and pressed.sum() > 20  # 20 ms each (loaded, 0.25 of real time: 150, 195)
    assert f_left[:, 2].mean() < -0.1 and np.linalg.norm(f_left, axis=1).max() > 0.3
    assert f_right[:, 2].mean() > 0.1 and np.linalg.norm(f_right, axis=1).max() > 0.3
