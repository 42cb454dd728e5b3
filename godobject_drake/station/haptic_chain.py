"""The haptic chain between a pose device and the coupling: none, impedance or admittance.

A chain is a part composed into the loop (:mod:`godobject_drake.station.loop`), not a branch of
the coupling's builder. Each kind of chain adds its systems, says which system the coupling reads
its target from (:attr:`HapticChain.target`: ``X_WD``, ``V_WD``, ``grasp``), takes the feedback
wrench where its device renders it, and answers for its own device at run time: whether it
diverged (:meth:`HapticChain.diverged_part`) and its energies (:meth:`HapticChain.metrics`).

- ``none`` (:class:`NoHaptics`): the device's pose is the target; the feedback goes to the device
  itself if it renders it (a real device over LCM) and nowhere otherwise.
- ``impedance`` (:class:`ImpedanceChain`): a simulated hand pushes a 3-axis
  :class:`~godobject_drake.systems.haptic.HapticDevice` along the device's path; its pose is the
  target and the feedback force (optionally through a
  :class:`~godobject_drake.systems.haptic.PassivityController`) acts on its handle.
- ``admittance`` (:class:`AdmittanceChain`): the hand pulls an
  :class:`~godobject_drake.systems.haptic.AdmittanceDevice`'s handle with the coupling's own
  stiffness and damping; the sensed wrench drives the god-object, the handle follows it.

:func:`check_haptic_gains` refuses a feedback stiffness the simulated impedance device cannot
render stably, as the coupling refuses a bandwidth past its explicit limit (docs/theory.md §2).
"""

import math
import warnings

import numpy as np
from pydrake.common.eigen_geometry import Quaternion
from pydrake.math import RigidTransform
from pydrake.systems.framework import DiagramBuilder, OutputPort, System

from godobject_drake.config.gains import FeedbackGains
from godobject_drake.config.scene import Haptic
from godobject_drake.limits import device_wall_limit
from godobject_drake.systems.haptic import (
    AdmittanceDevice,
    HandImpedance,
    HapticDevice,
    PassivityController,
    SimulatedHand,
)

WARN_FRACTION = 0.8  # a feedback stiffness past 80 % of the device's limit warns (as analyze does)


class HapticGainError(ValueError):
    """A feedback stiffness past the simulated haptic device's stability limit."""


class HapticGainWarning(UserWarning):
    """A feedback stiffness the device holds only while the simulated hand holds its handle."""


def hand_on_handle(haptic: Haptic) -> HandImpedance:
    """The simulated user: critically damped at ``hand_frequency_hz`` on the handle's mass."""
    w = 2 * math.pi * haptic.hand_frequency_hz
    return HandImpedance(k=haptic.device_mass_kg * w**2, b=2 * haptic.device_mass_kg * w)


def check_haptic_gains(haptic: Haptic, feedback_gains: FeedbackGains) -> None:
    """Refuse a feedback stiffness the impedance device cannot render stably.

    The model (:func:`godobject_drake.limits.device_wall_limit`) is the device's worst case:
    the god-object held still by a rigid obstacle, the handle's exact sampled mechanics, the
    feedback port's ``kd`` and ``γd`` on its sampled position, the simulated hand on the
    handle. Past that limit the device diverges at the first rigid contact: refused. Within
    20 % of it, or past the limit of the same device without a hand (stable only while the hand
    holds it), a warning. Drake's boundary on a scene, bisected by ``analyze --verify``, depends
    on its contact: 6 % below this limit on the brick scene, 33 % above it on the README's cube
    (docs/theory.md §2). A passivity controller (``passivity_damping > 0``) is meant to hold a
    stiffer wall, so it gets the warning only.
    """
    if haptic.mode != "impedance" or feedback_gains.kd <= 0.0:
        return
    hand = hand_on_handle(haptic)
    period = 1.0 / haptic.rate_hz
    m, b, gd, kd = haptic.device_mass_kg, haptic.device_damping, feedback_gains.gamma_d, feedback_gains.kd
    held = device_wall_limit(m, b, period, gd, hand.k, hand.b)
    alone = device_wall_limit(m, b, period, gd)
    where = (
        f"the simulated haptic device (mass {m:g} kg, damping {b:g} N·s/m, {haptic.rate_hz:g} Hz) "
        f"pressing a rigid obstacle with feedback.gamma_d {gd:g} N·s/m"
    )
    if kd >= held and haptic.passivity_damping <= 0.0:
        raise HapticGainError(
            f"feedback.kd: {kd:g} N/m is past the stability limit {held:.4g} N/m of {where} and "
            f"the simulated hand on its handle: the device would diverge at the first contact. Use "
            f"feedback.kd < {held:.4g} N/m (--kd), or raise haptic.device_damping or haptic.rate_hz "
            f"(the limit grows as (damping + gamma_d) x rate), or set haptic.passivity_damping > 0"
        )
    near = []
    if kd >= alone:
        near.append(f"past the limit {alone:.4g} N/m of the same device with no hand on its handle")
    if kd >= WARN_FRACTION * held:
        near.append(
            f"within {1 - WARN_FRACTION:.0%} of the limit {held:.4g} N/m with the hand against a rigid "
            "obstacle (a scene's own boundary depends on its contact: `analyze --verify` measures it)"
        )
    if near:
        warnings.warn(
            f"feedback.kd {kd:g} N/m for {where} is " + "; and ".join(near),
            HapticGainWarning,
            stacklevel=4,
        )


class HapticChain:
    """No simulated haptic device (``haptic.mode: none``): the device is the target.

    Attributes
    ----------
    mode : str
        ``none``, ``impedance`` or ``admittance``.
    target : System
        What the coupling reads ``X_WD``, ``V_WD`` and ``grasp`` from.
    """

    mode = "none"

    def __init__(self, device: System):
        self.target = device

    def connect_feedback(self, builder: DiagramBuilder, force: OutputPort) -> None:
        """Route the feedback wrench ``F_Do_W`` to the chain's device (nowhere here)."""

    def diverged_part(self, root_context, max_speed: float, feedback_gains: FeedbackGains):
        """``(part, what and likely cause)`` if the chain's device diverged, else None."""
        return None

    def metrics(self, root_context) -> dict:
        """The chain's energies at the end of a run (J); none here."""
        return {}


NoHaptics = HapticChain


class ImpedanceChain(HapticChain):
    """A simulated hand on a 3-axis impedance device (``haptic.mode: impedance``).

    Attributes
    ----------
    handle : HapticDevice
    hand : SimulatedHand
    passivity : PassivityController | None
    """

    mode = "impedance"

    def __init__(self, builder: DiagramBuilder, device: System, haptic: Haptic, p0: np.ndarray):
        self.haptic = haptic
        period = 1.0 / haptic.rate_hz
        self.handle = builder.AddNamedSystem(
            "haptic_device",
            HapticDevice(haptic.device_mass_kg, haptic.device_damping, period, axes="xyz",
                         X_WD_home=RigidTransform(p0)),
        )  # fmt: skip
        self.hand = builder.AddNamedSystem("hand", SimulatedHand(hand_on_handle(haptic), p0))
        builder.Connect(device.GetOutputPort("X_WD"), self.hand.GetInputPort("X_WH"))
        builder.Connect(device.GetOutputPort("V_WD"), self.hand.GetInputPort("V_WH"))
        builder.Connect(self.handle.GetOutputPort("device_state"), self.hand.GetInputPort("device_state"))
        builder.Connect(self.hand.GetOutputPort("human_force"), self.handle.GetInputPort("human_force"))
        builder.Connect(self.hand.GetOutputPort("q_WD"), self.handle.GetInputPort("q_WD"))
        builder.Connect(device.GetOutputPort("grasp"), self.handle.GetInputPort("grasp_in"))
        self.passivity = None
        self.target = self.handle

    def connect_feedback(self, builder: DiagramBuilder, force: OutputPort) -> None:
        """The feedback acts on the handle, through the passivity controller when there is one."""
        if self.haptic.passivity_damping > 0.0:
            pc = builder.AddNamedSystem(
                "passivity", PassivityController(1.0 / self.haptic.rate_hz, self.haptic.passivity_damping)
            )
            builder.Connect(force, pc.GetInputPort("F_in"))
            builder.Connect(self.handle.GetOutputPort("X_WD"), pc.GetInputPort("X_WD"))
            force = pc.GetOutputPort("F_out")
            self.passivity = pc
        builder.Connect(force, self.handle.GetInputPort("F_Do_W"))

    def diverged_part(self, root_context, max_speed: float, feedback_gains: FeedbackGains):
        """The handle's state non-finite or faster than ``max_speed`` (m/s), with the likely cause:
        ``kd`` past the device's limit against a rigid obstacle, or the loop on this contact."""
        dev = self.handle
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
        kd, gd = feedback_gains.kd, feedback_gains.gamma_d
        hand = self.hand.hand
        limit = device_wall_limit(dev.mass, dev.damping, dev.period_s, gd, hand.k, hand.b)
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

    def metrics(self, root_context) -> dict:
        """The energy the device gave the user and the work of the feedback on it; the passivity
        controller's observed and dissipated energies (J)."""
        work = self.handle.GetOutputPort("work").Eval(self.handle.GetMyContextFromRoot(root_context))
        out = {"haptic_energy_to_user_j": float(-work[0]), "haptic_feedback_work_j": float(work[1])}
        if self.passivity is not None:
            e = self.passivity.GetOutputPort("energy").Eval(self.passivity.GetMyContextFromRoot(root_context))
            out["passivity_observed_energy_j"] = float(e[0] + e[1])
            out["passivity_dissipated_j"] = float(e[2] + e[3])
        return out


class AdmittanceChain(HapticChain):
    """A simulated admittance device (``haptic.mode: admittance``), sized on the first body the
    device grasps: its sensed wrench drives the god-object (the coupling's ``F_device_W``)."""

    mode = "admittance"

    def __init__(self, builder: DiagramBuilder, device, coupling, haptic: Haptic, p0, q0):
        names = sorted(device.grasp_names())
        if not names:
            raise ValueError(
                "haptic mode admittance sizes the hand on the first body the device grasps; it grasps none"
            )
        body = coupling.body_for_grasp(names[0])
        hand = HandImpedance.matching(coupling.gains, body.mass, float(np.trace(body.I_Bcm_B)) / 3.0)
        adm = builder.AddNamedSystem(
            "admittance_device",
            AdmittanceDevice(hand, 1.0 / haptic.rate_hz, RigidTransform(Quaternion(q0), p0)),
        )
        builder.Connect(device.GetOutputPort("X_WD"), adm.GetInputPort("X_WH"))
        builder.Connect(device.GetOutputPort("V_WD"), adm.GetInputPort("V_WH"))
        builder.Connect(device.GetOutputPort("grasp"), adm.GetInputPort("grasp_in"))
        for port in ("pose_WG", "V_WG"):
            builder.Connect(coupling.GetOutputPort(port), adm.GetInputPort(port))
        builder.Connect(adm.GetOutputPort("F_device_W"), coupling.GetInputPort("F_device_W"))
        self.admittance = self.target = adm


def add_haptic_chain(builder: DiagramBuilder, haptic: Haptic, device, coupling) -> HapticChain:
    """The chain ``haptic.mode`` names, between ``device`` and ``coupling`` (module docstring)."""
    p0, q0, _ = device.samples(0.0)[0][1]
    if haptic.mode == "impedance":
        return ImpedanceChain(builder, device, haptic, p0)
    if haptic.mode == "admittance":
        return AdmittanceChain(builder, device, coupling, haptic, p0, q0)
    return HapticChain(device)
