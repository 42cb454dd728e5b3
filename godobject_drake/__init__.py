"""Generalized god-objects (Meseure et al., CASA 2004) as Drake systems.

One module per role: :mod:`~godobject_drake.devices` (device sources),
:mod:`~godobject_drake.coupling` (PD coupling, Eq. 2),
:mod:`~godobject_drake.feedback` (feedback port, Eq. 8),
:mod:`~godobject_drake.scenes` (models and contact settings),
:mod:`~godobject_drake.metrics` (true-shape metrics),
:mod:`~godobject_drake.recording` (Meshcat ghost and recording),
:mod:`~godobject_drake.runner` (flags, simulation loop, divergence).
"""

__version__ = "0.1.0"
