"""Plain config types: the scenario and its parts, loaded from YAML, knowing no Drake system.

- :mod:`~godobject_drake.config.scenario`: the :class:`~godobject_drake.config.scenario.Scenario`,
  loading, checking and overriding it;
- :mod:`~godobject_drake.config.scene`: contact, haptic chain, run, drawing, outputs, organs,
  sleeping;
- :mod:`~godobject_drake.config.tools`: the tool (god-object) kinds' configs;
- :mod:`~godobject_drake.config.devices`: the device kinds' configs, each registered once;
- :mod:`~godobject_drake.config.device_files`: scripted paths, logs, the sample guard and aids;
- :mod:`~godobject_drake.config.gains`: coupling and feedback gains.

Nothing here imports a LeafSystem module of the package (``tests/test_structure.py`` checks it).
"""
