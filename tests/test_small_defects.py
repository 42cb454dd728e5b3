"""The hostile round's smaller defects, each reproduced: a feedback stiffness no device renders,
and a hint naming a driver flag that does not exist. (The key's defects are tested with the key
file, in tests/test_link.py, where mutation testing runs them.)"""

import logging
import shlex

import numpy as np
import pytest
from conftest import REPO

from godobject_drake.config.gains import MAX_RENDERED_STIFFNESS_N_M
from godobject_drake.config.scenario import ScenarioError, load_scenario
from godobject_drake.driver import process as drv
from godobject_drake.driver.families import FAMILIES, RATED, HandPath
from godobject_drake.link.messages import LocalModel
from godobject_drake.simulation import DRIVER_FAMILIES, driver_command

LEGO_DRIVER = REPO / "diagrams" / "lego_driver.yaml"

# -- the feedback stiffness -------------------------------------------------------------------------------


def test_a_scene_asking_a_device_a_stiffness_past_what_it_renders_is_refused_naming_the_limit():
    """Before: ``--kd 1e300`` was accepted without a word (the hand got 212 periods of force steps
    over 1 N)."""
    with pytest.raises(
        ScenarioError, match=r"feedback\.kd: 1e\+300 N/m is past .* 14,500 N/m.*--kd ≤ 1\.45e\+04"
    ):
        load_scenario(LEGO_DRIVER, "feedback: {kd: 1e300}")
    scaled = "feedback: {kd: 5000}\ndevice: !Lcm {device_to_world: {scale: 2.0}}"
    with pytest.raises(ScenarioError, match=r"× scale² = 4: 2e\+04 N/m on the device.*--kd ≤ 3625"):
        load_scenario(LEGO_DRIVER, scaled)
    load_scenario(LEGO_DRIVER, f"feedback: {{kd: {MAX_RENDERED_STIFFNESS_N_M}}}")  # at the limit: taken


def _model(kd: float) -> bytes:
    p = (0.0, 0.0, 0.0)
    return LocalModel(1, 2, 0.001, kd, 0.0, 0.0, 0.0, p, p, (1.0, 0.0, 0.0, 0.0), p, p).encode()


class _Quiet:
    def Subscribe(self, channel, handler):
        pass

    def HandleSubscriptions(self, timeout_millis=0):
        return 0

    def Publish(self, channel, data):
        pass


@pytest.mark.parametrize("family", ["emulated", "openhaptics"])
def test_a_driver_refuses_a_local_model_stiffer_than_its_device_renders_and_says_so_once(family, caplog):
    """Before: the driver took it and rendered kd · stretch, clamped only by the rated force."""
    hand = HandPath(np.array([0.0, 1.0]), np.zeros((2, 3)), np.zeros(2, bool), np.zeros(2, bool))
    device = drv.EmulatedDevice(hand, start_on_scene=False)
    driver = drv.Driver(device, _Quiet(), RATED[family], rate_hz=1000.0, watchdog_periods=10, max_force_n=3.0)
    limit = RATED[family].max_stiffness_n_m
    with caplog.at_level(logging.WARNING, logger="godobject_drake"):
        driver._on_local_model(_model(1e300))
        driver._on_local_model(_model(limit * 1.01))
    assert not driver.local.heard and driver.counts["bad_feedback"] == 2
    assert driver.summary()["local_model"]["too_stiff"] == 2
    said = [r.getMessage() for r in caplog.records if "renders: refused" in r.getMessage()]
    assert len(said) == 1 and "kd = 1e+300 N/m" in said[0] and f"{limit:,.0f} N/m" in said[0]
    driver._on_local_model(_model(limit))
    assert driver.local.heard


def test_each_family_states_its_stiffness_and_the_scene_bound_is_the_stiffest():
    assert max(r.max_stiffness_n_m for r in RATED.values()) == MAX_RENDERED_STIFFNESS_N_M
    assert RATED["openhaptics"].max_stiffness_n_m == 1020.0


# -- the hint ------------------------------------------------------------------------------------------


def test_the_scenes_hint_to_start_the_driver_parses_with_the_drivers_own_parser(tmp_path):
    """Before: the hint said ``--lcm-url``, a flag the driver does not have (it takes --scene)."""
    assert DRIVER_FAMILIES == tuple(sorted(FAMILIES))
    key = tmp_path / "my keys" / "link.key"
    hint = driver_command("udp://127.0.0.1:7667", key)
    command = shlex.split(hint.split(" (FAMILY:")[0])
    assert command[:3] == ["godobject-driver", "run", "FAMILY"]
    for family in DRIVER_FAMILIES:
        args = drv.parser().parse_args([command[1], family, *command[3:]])
        assert (args.family, args.scene, args.key_file) == (family, "udp://127.0.0.1:7667", str(key))
    for url, unpaired in (("udp://h:1", False), ("memq://", True)):
        words = shlex.split(driver_command(url).split(" (FAMILY:")[0])[3:]
        args = drv.parser().parse_args(["run", "emulated", *words])
        assert (args.scene, args.key_file, args.allow_unauthenticated) == (url, "", unpaired)
