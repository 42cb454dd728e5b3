"""The god-object kinds, one class each, registered for their scenario config type.

=================  =====================================  ===============================
scenario config    kind class                             builder
=================  =====================================  ===============================
``!Rigid``         :class:`~.rigid.RigidGodObject`         :func:`~.rigid.add_god_object`
``!Articulated``   :class:`~.articulated.ArticulatedGodObject`  :func:`~.articulated.add_articulated`
``!Deformable``    :class:`~.deformable.DeformableGodObject`    :func:`~.deformable.add_deformable`
=================  =====================================  ===============================

:func:`kind_for` is the one dispatch on a scenario's ``god_object`` config; everything after it
asks the built :class:`~.base.GodObject` (docs/design.md "Adding a god-object kind").
"""

from godobject_drake.config import scenario as sc
from godobject_drake.god_objects.articulated import ArticulatedGodObject
from godobject_drake.god_objects.base import GodObject
from godobject_drake.god_objects.deformable import DeformableGodObject
from godobject_drake.god_objects.rigid import RigidGodObject

KINDS: dict[type, type[GodObject]] = {
    sc.Rigid: RigidGodObject,
    sc.Articulated: ArticulatedGodObject,
    sc.Deformable: DeformableGodObject,
}


def kind_for(config) -> type[GodObject]:
    """The kind class of a scenario's ``god_object`` config; an unknown one is refused, naming the known."""
    try:
        return KINDS[type(config)]
    except KeyError:
        known = ", ".join(f"!{c.__name__}" for c in KINDS)
        raise ValueError(
            f"god_object: {type(config).__name__} is not a god-object kind; the kinds are {known}"
        ) from None


__all__ = ["KINDS", "ArticulatedGodObject", "DeformableGodObject", "GodObject", "RigidGodObject", "kind_for"]
