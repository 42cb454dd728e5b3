"""What every god-object kind has: the parts it added, and the questions the library asks of it.

A kind is one subclass of :class:`GodObject` (rigid, articulated, deformable), registered for its
scenario config type in :data:`godobject_drake.station.build.KINDS`. Everything kind-specific is
a method or class attribute of the subclass; the builder, the simulation, the metrics and the
studies call these and never compare a kind's name (docs/design.md "Adding a god-object kind").
"""

import dataclasses
from typing import TYPE_CHECKING, ClassVar

import numpy as np
from pydrake.multibody.plant import MultibodyPlant
from pydrake.systems.framework import DiagramBuilder, System
from pydrake.systems.primitives import LogVectorOutput, VectorLogSink

if TYPE_CHECKING:
    from godobject_drake.devices.sources import DeviceSource, JointDevice
    from godobject_drake.systems.articulated import ArticulatedCoupling, ArticulatedFeedback
    from godobject_drake.systems.coupling import GodObjectCoupling
    from godobject_drake.systems.feedback import FeedbackPort
    from godobject_drake.systems.haptic import (
        AdmittanceDevice,
        HapticDevice,
        PassivityController,
        SimulatedHand,
    )


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
    device : System
        What the coupling reads its target from: ``source``, or the haptic device in between.
    haptic : HapticDevice | AdmittanceDevice | None
    hand : SimulatedHand | None
        The simulated user on an impedance device's handle.
    passivity : PassivityController | None
    publisher : System | None
        What renders the feedback wrench on a real device (its kind's ``connect_feedback``).
    mode : str
        ``god_object`` or ``position`` (the coupling's forces are not connected).
    """

    coupling: "GodObjectCoupling | ArticulatedCoupling"
    feedback: "FeedbackPort | ArticulatedFeedback"
    source: "DeviceSource | JointDevice"
    device: System
    haptic: "HapticDevice | AdmittanceDevice | None" = None
    hand: "SimulatedHand | None" = None
    passivity: "PassivityController | None" = None
    publisher: System | None = None
    mode: str = "god_object"

    # -- what a kind says of itself (class attributes) -----------------------------------------------
    kind: ClassVar[str] = ""  # its name in reports: "rigid", "articulated", "deformable"
    device_space: ClassVar[str] = "pose"  # the device kinds it takes (device_kinds.SPACES)
    sleeps_others: ClassVar[bool] = True  # free bodies it can reach may be put to sleep around it
    predicts_penetration: ClassVar[bool] = False  # a force cap, so a worst-case static penetration
    no_prediction_reason: ClassVar[str] = ""  # why not, for analyze's contact row

    @classmethod
    def build(cls, builder: DiagramBuilder, scenario, device, *, check_gains: bool = True):
        """Add the scenario's plant and this god-object to ``builder``; ``(SceneParts, god)``."""
        raise NotImplementedError(f"{cls.__name__}.build")

    def logged_ports(self, plant: MultibodyPlant) -> dict:
        """The output ports the metrics fold, by logger name (the plant's state always)."""
        return {"state": plant.get_state_output_port()}

    def add_loggers(self, builder: DiagramBuilder, plant: MultibodyPlant) -> dict[str, VectorLogSink]:
        """Per-step logs of :meth:`logged_ports` (each logged port costs a call per step)."""
        loggers = {}
        for name, port in self.logged_ports(plant).items():
            loggers[name] = LogVectorOutput(port, builder, plant.time_step())
            loggers[name].set_name(f"{name}_log")  # named, so GetGraphvizString reads well
        return loggers

    def complete_logs(self, rows: dict) -> dict:
        """A drained chunk of the logs (one row per plant step), with what the kind computes from
        them after the run rather than per step (nothing by default)."""
        return rows

    def add_drawing(self, builder: DiagramBuilder, meshcat, scene, scenario) -> None:
        """The kind's own drawing beside Drake's MeshcatVisualizer (nothing by default)."""

    def new_metrics(self, station):
        """The kind's metrics accumulator: ``fold(rows, data, finite) -> (p_WT, p_WG)`` and ``result()``."""
        raise NotImplementedError(f"{type(self).__name__}.new_metrics")

    def predict_penetration(self, scene, penetration_allowance: float = 1e-3):
        """The deepest static penetration its capped pull can cause, or None (no force cap)."""
        return None

    def configuration(self, scenario, station) -> dict:
        """The metrics' configuration keys this kind adds."""
        return {}

    def held_bodies(self, root_context) -> set[int]:
        """The BodyIndex values the coupling holds now (none by default)."""
        return set()

    def prepare(self, plant_context) -> None:
        """Before the simulator initializes (nothing by default)."""

    def before_step(self, plant: MultibodyPlant):
        """What must happen before every plant step, or None."""
        return None

    def diverged_part(self, root_context, max_speed: float) -> tuple[str, str] | None:
        """``(part, what and likely cause)`` if a part outside the plant diverged: a simulated
        impedance device whose handle's state is non-finite or faster than ``max_speed`` (m/s).
        The safeguards ask at every check; a run Drake stopped asks it for the likely cause."""
        from godobject_drake.limits import device_wall_limit
        from godobject_drake.systems.haptic import HapticDevice

        dev = self.haptic
        if not isinstance(dev, HapticDevice):
            return None
        state = dev.GetOutputPort("device_state").Eval(dev.GetMyContextFromRoot(root_context))
        n = dev.num_axes
        x, v = state[:n], state[n:]
        if np.all(np.isfinite(state)) and float(np.max(np.abs(v))) <= max_speed:
            return None
        what = (
            f"its handle's state is not finite (x = {x}, v = {v})"
            if not np.all(np.isfinite(state))
            else f"its handle's speed reached {float(np.max(np.abs(v))):.3g} m/s (> {max_speed:g})"
        )
        kd, gd = self.feedback.gains.kd, self.feedback.gains.gamma_d
        hand = self.hand.hand if self.hand is not None else None
        on_handle = (hand.k, hand.b) if hand else ()
        limit = device_wall_limit(dev.mass, dev.damping, dev.period_s, gd, *on_handle)
        if kd >= limit:
            cause = (
                f"the likely cause: feedback.kd {kd:g} N/m is past the device's stability limit "
                f"{limit:.4g} N/m against a rigid obstacle; use feedback.kd < {limit:.4g} N/m, or raise "
                "haptic.device_damping or haptic.rate_hz"
            )
        else:
            cause = (
                f"the likely cause: the haptic loop (feedback.kd {kd:g} N/m, gamma_d {gd:g} N·s/m) on this "
                "scene's contact; `python -m godobject_drake analyze SCENARIO` gives the device's limit"
            )
        return "the simulated haptic device", f"{what}; {cause}"

    def device_metrics(self, root_context) -> dict:
        """The device's counts and the haptic loop's energies (J) at the end of a run."""
        from godobject_drake.systems.haptic import HapticDevice

        out = dict(self.source.status(self.source.GetMyContextFromRoot(root_context)))
        if isinstance(self.haptic, HapticDevice):
            work = self.haptic.GetOutputPort("work").Eval(self.haptic.GetMyContextFromRoot(root_context))
            out["haptic_energy_to_user_j"] = float(-work[0])
            out["haptic_feedback_work_j"] = float(work[1])
        if self.passivity is not None:
            e = self.passivity.GetOutputPort("energy").Eval(self.passivity.GetMyContextFromRoot(root_context))
            out["passivity_observed_energy_j"] = float(e[0] + e[1])
            out["passivity_dissipated_j"] = float(e[2] + e[3])
        return out
