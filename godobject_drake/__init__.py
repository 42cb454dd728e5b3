"""Generalized god-objects (Meseure et al., CASA 2004) as Drake systems.

Describe a scene once in a scenario file, build it with one call, run it::

    from godobject_drake import build_station, load_scenario, shipped_scenario, simulate

    station = build_station(shipped_scenario("lego"))  # or load_scenario("my_scene.yaml")
    result = simulate(station)
    print(result.metrics["max_penetration_m"])

or compose a diagram of one's own from the same parts (docs/guide/own_scene.md, "Compose your own
diagram"). The layers, each importing only those below it (docs/design.md):

- :mod:`~godobject_drake.spatial`, :mod:`~godobject_drake.limits`: quaternion math, the explicit
  stability limits;
- :mod:`~godobject_drake.config`: the scenario and every part of it, plain types (tool and device
  kinds registered once);
- :mod:`~godobject_drake.systems`: the Drake systems of the loop (coupling, feedback, haptic
  devices, articulated tool, shell, tissue, drawing); :mod:`~godobject_drake.devices`: the device
  sources; :mod:`~godobject_drake.link`: the LCM link to a driver process;
  :mod:`~godobject_drake.metrics`, :mod:`~godobject_drake.safeguards`,
  :mod:`~godobject_drake.sleeping`, :mod:`~godobject_drake.outputs`;
- :mod:`~godobject_drake.station`: a scenario into a diagram, in one straight line;
- :mod:`~godobject_drake.simulation`: running and measuring;
- :mod:`~godobject_drake.cli` and :mod:`~godobject_drake.studies` (stability and passivity,
  ``analyze``, the speed-against-error runs) on top;
- :mod:`~godobject_drake.driver`: a haptic device's driver process, beside them, sharing only
  :mod:`~godobject_drake.link`.

The names above are imported lazily, so ``import godobject_drake`` stays cheap.
"""

__version__ = "0.1.0"

_EXPORTS = {
    "Scenario": "config.scenario",
    "load_scenario": "config.scenario",
    "shipped_scenario": "config.scenario",
    "build_station": "station.build",
    "add_god_object": "station.rigid_tool",
    "simulate": "simulation",
    "install_safeguards": "safeguards",
    "add_joint_coupling": "station.loop",
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
