"""From a scenario to a diagram: the plant, each tool kind, the haptic loop, the finished station.

:func:`~.build.build_station` builds any scenario in one straight line; the parts it calls are
public, so a diagram of one's own uses the same ones.
"""

# The built-in tool kinds register themselves (station.kinds.tool_kind) as their modules load:
# importing any part of the station makes every built-in kind known to kind_for.
from godobject_drake.station import articulated_tool, deformable_tool, rigid_tool  # noqa: F401
