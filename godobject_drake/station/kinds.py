"""What every tool (god-object) kind has: the parts it added, and the questions the library asks of it.

A kind is one subclass of :class:`GodObject` (rigid, articulated, deformable), named once by its
scenario config's registration (:func:`godobject_drake.config.tools.tool_kind`); :func:`kind_for` is
the one dispatch on a scenario's ``god_object``. Everything kind-specific is a method or class
attribute of the subclass:
what it adds to the plant before ``Finalize`` and how it builds its loop, its loggers, metrics and
drawing, the penetration it can cause and what runs before each plant step. The builder, the
simulation, the metrics, the CLI and the studies call these and never ask which kind they have
(docs/design.md "Adding a tool kind"); what only the studies ask of a kind is theirs, keyed by its
``kind`` (:mod:`godobject_drake.studies.kinds`). The haptic chain is a part of its own
(:mod:`~godobject_drake.station.haptic_chain`), composed into the loop.
"""

import dataclasses
import functools
import importlib
from typing import TYPE_CHECKING, ClassVar

from pydrake.multibody.plant import MultibodyPlant
from pydrake.systems.framework import DiagramBuilder, System

from godobject_drake.config.tools import TOOL_BUILDERS
from godobject_drake.station.haptic_chain import HapticChain
from godobject_drake.systems.contacts import ToolParts
from godobject_drake.systems.drawing import ONE_TOOL, Drawing

if TYPE_CHECKING:
    from godobject_drake.devices.sources import DeviceSource, JointDevice
    from godobject_drake.systems.articulated import ArticulatedCoupling, ArticulatedFeedback
    from godobject_drake.systems.coupling import GodObjectCoupling
    from godobject_drake.systems.feedback import FeedbackPort


def builder_of(config_type: type) -> type["GodObject"]:
    """The :class:`GodObject` subclass that builds the tool kind ``config_type`` (its registration,
    :func:`~godobject_drake.config.tools.tool_kind`; a ``"module:Class"`` is imported once)."""
    builder = TOOL_BUILDERS.get(config_type)
    if builder is None:
        known = ", ".join(f"!{c.__name__}" for c in TOOL_BUILDERS)
        raise ValueError(
            f"god_object: {config_type.__name__} is not a god-object kind; the kinds are {known} (register "
            "one with godobject_drake.config.tools.tool_kind)"
        )
    return builder if isinstance(builder, type) else _imported(builder)


@functools.cache
def _imported(path: str) -> type["GodObject"]:
    module, _, name = path.partition(":")
    try:
        cls = getattr(importlib.import_module(module), name)
    except (ImportError, AttributeError) as e:
        raise ValueError(
            f"god_object: the builder {path!r} cannot be imported ({e}): fix its tool_kind"
        ) from None
    if not (isinstance(cls, type) and issubclass(cls, GodObject)):
        raise ValueError(f"god_object: the builder {path!r} is not a GodObject subclass: fix its tool_kind")
    return cls


def kind_for(config) -> type["GodObject"]:
    """The kind class of a scenario's ``god_object`` config; an unknown one is refused, naming the known."""
    return builder_of(type(config))


@dataclasses.dataclass
class GodObject:
    """What a kind's builder (``add_god_object``, ``add_articulated``, ``add_deformable``) added.

    Attributes
    ----------
    coupling : GodObjectCoupling | ArticulatedCoupling
        The coupling (paper Eq. 2 or 6).
    feedback : FeedbackPort | ArticulatedFeedback
        The feedback port (paper Eq. 8): ``F_Do_W`` (or the articulated wrenches), wired
        whatever its gains, so a logger or a device of one's own can read it.
    source : DeviceSource | JointDevice
        The user's device.
    chain : HapticChain
        The haptic chain between the device and the coupling (none, impedance, admittance).
    publisher : System | None
        What renders the feedback wrench on a real device (its kind's ``connect_feedback``).
    mode : str
        ``god_object`` or ``position`` (the coupling's forces are not connected).
    """

    coupling: "GodObjectCoupling | ArticulatedCoupling"
    feedback: "FeedbackPort | ArticulatedFeedback"
    source: "DeviceSource | JointDevice"
    chain: HapticChain = None
    publisher: System | None = None
    mode: str = "god_object"

    def __post_init__(self):
        if self.chain is None:
            self.chain = HapticChain(self.source)

    @property
    def device(self) -> System:
        """What the coupling reads its target from: the device, or the simulated one in between."""
        return self.chain.target

    @property
    def haptic(self):
        """The simulated haptic device (impedance or admittance), or None."""
        return getattr(self.chain, "handle", None) or getattr(self.chain, "admittance", None)

    @property
    def hand(self):
        """The simulated user on an impedance device's handle, or None."""
        return getattr(self.chain, "hand", None)

    @property
    def passivity(self):
        """The passivity controller on an impedance device's feedback, or None."""
        return getattr(self.chain, "passivity", None)

    # -- what a kind says of itself (class attributes) -----------------------------------------------
    kind: ClassVar[str] = ""  # its name in reports: "rigid", "articulated", "deformable"
    device_space: ClassVar[str] = "pose"  # the device kinds it takes (device_kinds.SPACES)
    sleeps_others: ClassVar[bool] = True  # free bodies it can reach may be put to sleep around it
    predicts_penetration: ClassVar[bool] = False  # a force cap, so a worst-case static penetration
    no_prediction_reason: ClassVar[str] = ""  # why not, for analyze's contact row
    tissue = None  # the FEM organ the tool presses (an articulated tool on organs.model fem)

    @classmethod
    def add_to_plant(
        cls, plant: MultibodyPlant, scene_graph, scenario, device, *, check_gains=True, name=""
    ) -> dict:
        """What the kind adds to the plant before ``Finalize`` (nothing by default); the returned
        dict is handed to :meth:`build`. ``name``: the tool's, in a scene of several (for the names
        of what it adds to the plant)."""
        return {}

    @classmethod
    def build(cls, builder: DiagramBuilder, scene, scenario, device, added: dict, *, check_gains=True):
        """The tool's loop on the finalized plant of ``scene`` (:mod:`~godobject_drake.station.loop`),
        from the scenario's ``god_object`` and the device already in ``builder``; the tool."""
        raise NotImplementedError(f"{cls.__name__}.build")

    def logged_ports(self, plant: MultibodyPlant) -> dict:
        """The output ports the metrics fold, by logger name (the plant's state always)."""
        return {"state": plant.get_state_output_port()}

    def complete_logs(self, rows: dict) -> dict:
        """A drained chunk of the logs (one row per plant step), with what the kind computes from
        them after the run rather than per step (nothing by default)."""
        return rows

    def add_drawing(
        self, builder: DiagramBuilder, meshcat, scene, scenario, drawing: Drawing = ONE_TOOL
    ) -> None:
        """The kind's own drawing beside Drake's MeshcatVisualizer (nothing by default), under
        ``drawing.prefix`` in ``drawing``'s colours (a tool of a scene of several)."""

    def new_metrics(self, station):
        """The kind's metrics accumulator: ``fold(rows, data, finite) -> (p_WT, p_WG)`` and ``result()``."""
        raise NotImplementedError(f"{type(self).__name__}.new_metrics")

    def predict_penetration(self, scene, penetration_allowance: float = 1e-3, duration_s=None):
        """The deepest static penetration its capped pull can cause on the bodies its device grasps
        over ``duration_s``, or None (no force cap)."""
        return None

    def configuration(self, scenario, station) -> dict:
        """The metrics' configuration keys this kind adds."""
        return {}

    def held_bodies(self, root_context) -> set[int]:
        """The BodyIndex values the coupling holds now (none by default)."""
        return set()

    def contact_parts(self, plant: MultibodyPlant, scene_graph) -> ToolParts:
        """What the tool touches with, for its contact forces and collisions
        (:class:`~godobject_drake.systems.contacts.ContactMeter`): nothing by default."""
        return ToolParts()

    def held_body_port(self):
        """The output port of the BodyIndex it holds (−1: none), for a tool whose parts include
        the body it holds (:attr:`ToolParts.holds`); None by default."""
        return None

    def tip_reference(self, data: dict):
        """Per logged row of ``data`` (the tool's logs), which point its tip metrics follow, when
        that point can switch (a rigid god-object: −1 the device's point, else the held body's
        BodyIndex, its centre of mass); None: one point throughout."""
        return None

    holds_free_bodies: ClassVar[bool] = False  # its coupling grasps the scene's free bodies by name

    def grasp_spans(self) -> dict[str, tuple[float, float]]:
        """The free bodies its device's path or log grasps by name, each with the first and last
        time (s) it does: two tools may not hold one body at once (``station.build.check_grasps``).
        None by default; a grasp decided at run time (``*``) is the couplings' to share."""
        return {}

    def prepare(self, plant_context) -> None:
        """Before the simulator initializes (nothing by default)."""

    def before_step(self, plant: MultibodyPlant):
        """What must happen before every plant step, or None."""
        return None

    def diverged_part(self, root_context, max_speed: float) -> tuple[str, str] | None:
        """``(part, what and likely cause)`` if a part outside the plant diverged (the haptic chain's
        simulated device). The safeguards ask at every check; a run Drake stopped asks it for the
        likely cause."""
        return self.chain.diverged_part(root_context, max_speed, self.feedback.gains)

    def device_metrics(self, root_context) -> dict:
        """The device's counts and the haptic chain's energies (J) at the end of a run."""
        out = dict(self.source.status(self.source.GetMyContextFromRoot(root_context)))
        out.update(self.chain.metrics(root_context))
        return out
