"""Studies of a scene: what analyses, measures and compares the runtime, never part of a run.

- :mod:`~godobject_drake.studies.stability`: python-control models of the loop (explicit limits,
  the haptic device's passivity) and the bisections that find a limit in Drake;
- :mod:`~godobject_drake.studies.validation`: the models checked against Drake runs;
- :mod:`~godobject_drake.studies.analyze`: ``python -m godobject_drake analyze``, the stability and
  passivity report of any scenario, each verdict checked in Drake;
- :mod:`~godobject_drake.studies.kinds`: what the studies ask of each tool kind (a run's label,
  the report's columns, the god-object's pose body, the loop model ``analyze`` checks), keyed by
  the kind's name;
- :mod:`~godobject_drake.studies.benchmark`, :mod:`~godobject_drake.studies.sweep`,
  :mod:`~godobject_drake.studies.mujoco_peer`: the speed-against-error report's runs, their
  distribution over processes or a Dask cluster, and the MuJoCo peer.

The runtime (``godobject_drake`` itself) never imports these, except the command line's
``analyze`` verb, lazily.
"""
