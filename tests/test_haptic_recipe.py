"""The haptic recipe (``diagrams/lego_haptic.yaml``, docs/guide/haptic_recipe.md): the brick scene
at h = 5 ms with the implicit coupling, for a driver over LCM. What load cannot change is tested
here (it is stable and within its depth budget on the brick path); whether it holds real time is
measured by ``analysis/driver_lag.py --scenario diagrams/lego_haptic.yaml``, never asserted."""

from conftest import REPO

from godobject_drake.config import devices as dk
from godobject_drake.config.scenario import load_scenario
from godobject_drake.simulation import simulate
from godobject_drake.station.build import build_station


def test_the_recipe_carries_the_brick_path_stably_within_its_budget():
    s = load_scenario(REPO / "diagrams" / "lego_haptic.yaml")
    assert s.plant.time_step == 0.005 and s.god_object.coupling == "implicit"
    assert isinstance(s.device, dk.Lcm) and s.device.url.startswith("udp://127.0.0.1:")
    assert s.device.rate_hz * s.plant.time_step == 1.0  # one device sample and feedback a step
    lego = load_scenario(REPO / "diagrams" / "lego.yaml")
    s.device = lego.device  # the brick scene's scripted path in place of the driver (no socket)
    s.simulation.duration_s = lego.simulation.duration_s
    m = simulate(build_station(s), progress=False, keep_logs=False).metrics
    assert not m["diverged"]
    assert m["max_penetration_m"] < s.metrics.penetration_budget_m  # 4 mm: the price of h = 5 ms
    assert m["rms_tracking_error_m"] < 0.01
