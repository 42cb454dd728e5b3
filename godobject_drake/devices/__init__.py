"""The device sources: the target a user's device gives, as Drake systems.

:mod:`~.sources` (scripted paths, logs, increments, joint-space paths and logs), :mod:`~.live`
(the browser's sliders, keys and gamepad) and :mod:`~.lcm` (a real device's driver over LCM).
"""
