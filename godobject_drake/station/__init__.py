"""From a scenario to a diagram: the plant, each tool kind, the haptic loop, the finished station.

:func:`~.build.build_station` builds any scenario in one straight line; the parts it calls are
public, so a diagram of one's own uses the same ones.
"""
