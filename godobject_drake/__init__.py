"""Generalized god-objects (Meseure et al., CASA 2004) as Drake systems.

Describe a scene once in a scenario file, build it with one call, run it::

    from godobject_drake import build_station, load_scenario, shipped_scenario, simulate

    station = build_station(shipped_scenario("lego"))  # or load_scenario("my_scene.yaml")
    result = simulate(station)
    print(result.metrics["max_penetration_m"])

or compose a diagram of one's own from the parts (docs/guide/own_scene.md, "Compose your own
diagram"). The runtime, what runs in a scene, is one module per role:

- :mod:`~godobject_drake.config.devices`: the device kinds, each a scenario config registered once;
- :mod:`~godobject_drake.devices`, :mod:`~godobject_drake.live`, :mod:`~godobject_drake.lcm_device`:
  device sources (scripted, replayed, relative, from the browser, over LCM) and their sample guard;
- :mod:`~godobject_drake.god_objects`: the god-object kinds (rigid, articulated, deformable), one
  class each with its builder;
- :mod:`~godobject_drake.coupling`: the PD coupling (paper Eq. 2) and its gains;
- :mod:`~godobject_drake.feedback`: the feedback port (Eq. 8);
- :mod:`~godobject_drake.haptic`: simulated haptic devices, the user's hand, the passivity controller;
- :mod:`~godobject_drake.articulated`, :mod:`~godobject_drake.deformable`: the articulated
  coupling and tool, the deformable shell;
- :mod:`~godobject_drake.config.scenario`: the typed scenario a YAML file loads into;
- :mod:`~godobject_drake.scenes`: model loading and contact settings;
- :mod:`~godobject_drake.building`: a scenario into a diagram, and the one-call helpers;
- :mod:`~godobject_drake.safeguards`: divergence, quaternion drift, Stop, wiring checks;
- :mod:`~godobject_drake.simulation`: running and measuring (one result type);
- :mod:`~godobject_drake.metrics`, :mod:`~godobject_drake.recording`: true-shape metrics,
  Meshcat drawing and recordings;
- :mod:`~godobject_drake.cli`: ``python -m godobject_drake run SCENARIO.yaml``;
- :mod:`~godobject_drake.spatial`, :mod:`~godobject_drake.limits`: quaternion math, the
  explicit stability limits.

The studies of a scene are apart, in :mod:`godobject_drake.studies`: python-control analysis
(``stability``) and its Drake checks (``validation``), ``analyze``, and the speed-against-error
report's runs (``benchmark``, ``sweep``, ``mujoco_peer``).

The names above are imported lazily, so ``import godobject_drake`` stays cheap.
"""

__version__ = "0.1.0"

_EXPORTS = {
    "Scenario": "config.scenario",
    "load_scenario": "config.scenario",
    "shipped_scenario": "config.scenario",
    "build_station": "building",
    "add_god_object": "building",
    "simulate": "simulation",
    "install_safeguards": "safeguards",
    "add_articulated_god_object": "articulated",
}


def __getattr__(name: str):
    if name in _EXPORTS:
        import importlib

        return getattr(importlib.import_module(f"godobject_drake.{_EXPORTS[name]}"), name)
    raise AttributeError(f"module 'godobject_drake' has no attribute {name!r}")


def __dir__() -> list[str]:
    """The module's names and the lazily imported public ones (tab completion, ``help()``)."""
    return sorted({*globals(), *_EXPORTS})


__all__ = sorted(_EXPORTS)
