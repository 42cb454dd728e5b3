"""The safeguards under a plain ``Simulator``, and the wiring mistakes caught at build time.

A user who composes a diagram by hand (docs/guide/own_scene.md#compose-your-own-diagram) and runs it with
``Simulator`` plus ``install_safeguards`` gets: the wiring checked before the first step,
divergence stopped with the body named, free bodies' quaternions kept on unit norm, and an
action before every plant step (the position baseline).
"""

import math

import numpy as np
import pytest
from conftest import add_free_boxes, run_guarded
from pydrake.multibody.math import SpatialVelocity
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder

from godobject_drake import simulation
from godobject_drake.config.device_files import Waypoint
from godobject_drake.config.gains import CouplingGains
from godobject_drake.config.scenario import shipped_scenario
from godobject_drake.devices.sources import ScriptedDevice
from godobject_drake.safeguards import DivergenceError, WiringError, install_safeguards
from godobject_drake.station.build import build_station
from godobject_drake.station.plant import add_plant
from godobject_drake.station.rigid_tool import add_god_object
from godobject_drake.systems.coupling import GodObjectCoupling

LIFT = [Waypoint(t=0.0, xyz=[-0.10, 0.0, 0.0048], grasp="brick_0"),
        Waypoint(t=1.0, xyz=[-0.10, 0.0, 0.04], grasp="brick_0")]  # fmt: skip


def brick_scene(path=LIFT):
    """The brick scene's plant and a scripted device, added to a builder; nothing wired yet."""
    builder = DiagramBuilder()
    plant = add_plant(builder, shipped_scenario("lego")).plant
    device = builder.AddNamedSystem("device", ScriptedDevice(path))
    return builder, plant, device


def coupled_by_hand(forces=("generalized_force",)):
    """The README's hand wiring, with the coupling's force outputs in ``forces`` sent to the plant."""
    builder, plant, device = brick_scene()
    coupling = builder.AddNamedSystem("coupling", GodObjectCoupling(plant, CouplingGains(40.0, 1.0, 120.0)))
    builder.Connect(plant.get_state_output_port(), coupling.GetInputPort("plant_state"))
    for name in ("X_WD", "V_WD", "grasp"):
        builder.Connect(device.GetOutputPort(name), coupling.GetInputPort(name))
    ports = {
        "generalized_force": plant.get_applied_generalized_force_input_port(),
        "spatial_forces": plant.get_applied_spatial_force_input_port(),
    }
    for name in forces:
        builder.Connect(coupling.GetOutputPort(name), ports[name])
    return builder.Build(), plant


def test_forgetting_the_force_path_is_caught_before_the_first_step():
    diagram, _ = coupled_by_hand(forces=())
    with pytest.raises(
        WiringError, match=r"drives no force into the plant: .*Connect it: .*generalized_force"
    ):
        install_safeguards(Simulator(diagram))


def test_both_force_paths_are_caught():
    diagram, _ = coupled_by_hand(forces=("generalized_force", "spatial_forces"))
    with pytest.raises(WiringError, match=r"both 'generalized_force' and 'spatial_forces'.*twice"):
        install_safeguards(Simulator(diagram))


def test_the_position_baseline_must_leave_the_forces_unconnected():
    diagram, _ = coupled_by_hand()
    with pytest.raises(WiringError, match=r"mode=position imposes .*leave its force outputs unconnected"):
        install_safeguards(Simulator(diagram), mode="position")


def test_one_force_path_lifts_the_brick():
    """The correct hand wiring, under a plain Simulator with the safeguards: the brick is lifted to
    the device's 4 cm; 0.5 s after the device stops (20 time constants 1/ωn) it has settled."""
    diagram, plant = coupled_by_hand()
    run = run_guarded(diagram, 1.5)
    assert run.diagnosis is None and run.safeguards.checks == 30  # every 50 ms
    z = plant.GetPositions(plant.GetMyContextFromRoot(run.context))[6]
    assert abs(z - 0.04) < 0.002


def test_an_unknown_grasp_name_is_refused_when_the_diagram_is_built():
    builder, plant, _ = brick_scene()
    device = builder.AddNamedSystem(
        "hammer_device", ScriptedDevice([*LIFT[:1], Waypoint(t=2.0, grasp="hammer")])
    )
    with pytest.raises(ValueError, match=r"unknown body 'hammer'; graspable bodies are \['brick_0', .*"):
        add_god_object(builder, plant, device, CouplingGains(40.0))


def test_a_welded_body_is_named_as_welded():
    builder, plant, _ = brick_scene()
    wall = ScriptedDevice([Waypoint(t=0.0, grasp="wall"), Waypoint(t=1.0, grasp="wall")])
    device = builder.AddNamedSystem("wall_device", wall)
    with pytest.raises(
        ValueError, match=r"'wall' names lego_table::wall .*welded to the world.*only a free body"
    ):
        add_god_object(builder, plant, device, CouplingGains(40.0))
    with pytest.raises(ValueError, match=r"'baseplate' names .* welded"):
        GodObjectCoupling(plant, CouplingGains(40.0), graspable=["brick_0", "baseplate"])


def test_a_hand_wired_unknown_grasp_is_caught_by_the_check():
    """Wired by hand (not through add_god_object), the name is checked when the safeguards go on."""
    builder, plant, device = brick_scene([Waypoint(t=0.0, grasp="brick_9"), Waypoint(t=1.0, grasp="brick_9")])
    coupling = builder.AddNamedSystem("coupling", GodObjectCoupling(plant, CouplingGains(40.0, 1.0, 120.0)))
    builder.Connect(plant.get_state_output_port(), coupling.GetInputPort("plant_state"))
    for name in ("X_WD", "V_WD", "grasp"):
        builder.Connect(device.GetOutputPort(name), coupling.GetInputPort(name))
    builder.Connect(
        coupling.GetOutputPort("generalized_force"), plant.get_applied_generalized_force_input_port()
    )
    with pytest.raises(ValueError, match=r"unknown body 'brick_9'"):
        install_safeguards(Simulator(builder.Build()))


def test_divergence_names_the_body_and_stops_before_nans():
    """Gains 1.5 × past the explicit limit (the check turned off): the error grows by |z| > 1 per
    step; the 50 ms check stops it at the first speed past 1000 m/s, naming body_0."""
    builder = DiagramBuilder()
    plant, _ = add_free_boxes(builder, 1e-2, (1.0,), gravity=False)
    path = [Waypoint(t=0.0, grasp="body_0"), Waypoint(t=1.0, xyz=[0.01, 0, 0], grasp="body_0")]
    device = builder.AddSystem(ScriptedDevice(path))
    add_god_object(builder, plant, device, CouplingGains(omega_n=1.5 * 0.8284 / 1e-2), check_gains=False,
                   max_stretch_m=math.inf)  # fmt: skip
    simulator = Simulator(builder.Build())
    install_safeguards(simulator)
    with pytest.raises(
        DivergenceError, match=r"::body_0 diverged: its velocity \S*body_0_v[xyz] reached"
    ) as e:
        simulator.AdvanceTo(20.0)
    assert e.value.body.endswith("::body_0") and e.value.time_s < 20.0
    assert round(e.value.time_s / 0.05, 6).is_integer()  # at a check time
    assert np.all(
        np.isfinite(plant.GetPositionsAndVelocities(plant.GetMyContextFromRoot(simulator.get_context())))
    )


def spinning_body(simulator_wrapper):
    """A free body spinning at 10 rad/s about a tilted axis, no gravity, h = 1 ms, for 5 s."""
    builder = DiagramBuilder()
    plant, (body,) = add_free_boxes(builder, 1e-3, (1.0,), inertia_diag=(1e-3, 1e-3, 1e-3), gravity=False)
    simulator = Simulator(builder.Build())
    context = plant.GetMyMutableContextFromRoot(simulator.get_mutable_context())
    w = 10.0 * np.array([1.0, 2.0, 2.0]) / 3.0
    plant.SetFreeBodySpatialVelocity(context, body, SpatialVelocity(w, np.zeros(3)))
    guard = simulator_wrapper(simulator)
    norms = []
    for k in range(1, 101):
        simulator.AdvanceTo(0.05 * k)
        norms.append(np.linalg.norm(plant.GetPositions(context)[:4]))
    return np.array(norms), guard


def test_quaternion_drift_is_projected_away():
    """A free body's quaternion off unit norm (|q| = 1.2, what drift does slowly) is put back on it
    at the next check, the same rotation and the same velocities, and left alone between checks.
    With no spin Drake's update keeps |q| as it is, so what changes it is the safeguards alone."""
    builder = DiagramBuilder()
    plant, _ = add_free_boxes(builder, 1e-3, (1.0,), gravity=False)
    simulator = Simulator(builder.Build())
    guard = install_safeguards(simulator, check_period_s=0.01)  # every 10 plant steps
    context = plant.GetMyMutableContextFromRoot(simulator.get_mutable_context())
    q = plant.GetPositions(context)
    q_unit = np.array([0.5, 0.5, -0.5, 0.5])
    q[:4] = 1.2 * q_unit
    plant.SetPositions(context, q)
    v = np.array([0.0, 0.0, 0.0, 0.1, -0.2, 0.3])  # translating, not turning
    plant.SetVelocities(context, v)
    simulator.AdvanceTo(0.005)  # half a check period: left alone
    assert np.linalg.norm(plant.GetPositions(context)[:4]) == pytest.approx(1.2, abs=1e-12)
    simulator.AdvanceTo(0.0105)  # past the check at 10 ms
    q_after = plant.GetPositions(context)[:4]
    np.testing.assert_allclose(q_after, q_unit, atol=1e-12)  # |q| = 1, the same rotation
    np.testing.assert_allclose(plant.GetVelocities(context), v, atol=1e-12)
    assert guard.projections == 1


def test_a_long_spin_stays_on_unit_norm():
    """Spinning at 10 rad/s for 5 s at h = 1 ms, projected every 50 ms: |q| stays within 1e-3 of 1
    (the drift between checks is at most 50 (h|w|)²/8 = 6.25e-4), at every check."""
    guarded, guard = spinning_body(install_safeguards)
    assert np.max(np.abs(guarded - 1.0)) < 1e-3
    assert guard.projections == 100


def test_before_step_runs_before_every_plant_step():
    builder = DiagramBuilder()
    add_free_boxes(builder, 1e-3, (1.0,))
    simulator = Simulator(builder.Build())
    times = []
    install_safeguards(
        simulator, before_step=lambda plant_context, root: times.append(plant_context.get_time())
    )
    simulator.AdvanceTo(0.1)
    np.testing.assert_allclose(times, np.arange(101) * 1e-3, atol=1e-12)  # t = 0 (at Initialize) to 0.1


def test_a_polled_run_is_the_monitored_run_bit_for_bit(monkeypatch):
    """``simulate`` runs the checks from its loop (no per-step monitor) where nothing must happen
    before each step. The brick scene's first 1.2 s (the grasp, sleep checks every 10 ms and
    safeguard checks every 50 ms) with the checks polled and with the per-step monitor: every
    state bit for bit, the same number of checks and of bodies put to sleep."""
    real = simulation.install_safeguards

    def run(polled: bool):
        def install(*args, **kwargs):
            return real(*args, **{**kwargs, "polled": polled})

        monkeypatch.setattr(simulation, "install_safeguards", install)
        s = shipped_scenario("lego")
        return simulation.simulate(build_station(s), duration_s=1.2, progress=False)

    polled, monitored = run(True), run(False)
    assert polled.safeguards.polled and not monitored.safeguards.polled
    np.testing.assert_array_equal(polled.states.view(np.uint64), monitored.states.view(np.uint64))
    assert polled.safeguards.checks == monitored.safeguards.checks == 24
    assert polled.metrics["sleep_falls"] == monitored.metrics["sleep_falls"] > 0


def test_simulate_observes_every_plant_step_and_runs_the_same():
    """``simulate(..., observe=...)`` calls ``observe`` before every plant step, at t = 0 (at
    Initialize) to the end, after the safeguards' checks, and changes nothing of the run: the
    brick scene's first 0.3 s (sleep checks every 10 ms, safeguard checks every 50 ms) bit for bit
    as without."""
    times = []

    def run(observe):
        return simulation.simulate(
            build_station(shipped_scenario("lego")), duration_s=0.3, progress=False, observe=observe
        )

    plain = run(None)
    observed = run(lambda plant_context, root: times.append(root.get_time()))
    np.testing.assert_allclose(times, np.arange(301) * 1e-3, atol=1e-12)
    assert plain.safeguards.polled and not observed.safeguards.polled
    np.testing.assert_array_equal(plain.states.view(np.uint64), observed.states.view(np.uint64))
    assert plain.safeguards.checks == observed.safeguards.checks == 6
