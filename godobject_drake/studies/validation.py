"""Drake simulations that check :mod:`godobject_drake.studies.stability`'s predictions.

Each function runs the real loop — ``GodObjectCoupling`` on a SAP
MultibodyPlant, ``FeedbackPort``, ``HapticDevice`` — in the configuration a
prediction is about, and measures the quantity predicted:

* :func:`drake_k_crit` — the explicit stiffness limit of the coupling, by
  bisection on growth of a free held body's oscillation.
* :func:`simulate_haptic` / :func:`drake_device_k_max` — the simulated device
  holding the probe on the tissue (``models/haptic``): its trajectory, the
  exact work of the user's and the feedback's forces, and the largest stable
  feedback stiffness by bisection.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
from pydrake.math import RigidTransform
from pydrake.multibody.math import SpatialVelocity
from pydrake.multibody.plant import AddMultibodyPlant, MultibodyPlantConfig
from pydrake.multibody.tree import SpatialInertia
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import LogVectorOutput, Sine

from godobject_drake.config.device_files import Waypoint
from godobject_drake.config.gains import CouplingGains, FeedbackGains
from godobject_drake.devices.sources import ScriptedDevice
from godobject_drake.station.plant import SceneParts, add_scene_from_directives, set_contact_material
from godobject_drake.studies.stability import (
    BodyLoop,
    DeviceParams,
    Pipeline,
    bisect,
)
from godobject_drake.systems.coupling import GodObjectCoupling
from godobject_drake.systems.feedback import FeedbackPort
from godobject_drake.systems.haptic import HapticDevice, PassivityController

HAPTIC_SCENE = "package://godobject_models/haptic/probe_on_tissue.dmd.yaml"


def is_growing(signal: np.ndarray, floor: float = 1e-9) -> bool:
    """True if ``|signal|`` peaks higher in its last quarter than in the quarter before.

    Once the faster modes have died out the ratio of the two peaks is the
    dominant pole's modulus to the power of a quarter of the samples, so the
    test reads the sign of ``ρ − 1`` without fitting. A signal that has
    decayed below ``floor`` times its first peak counts as decaying (the
    solver's noise would otherwise decide).
    """
    a = np.abs(np.asarray(signal, float))
    if not np.all(np.isfinite(a)):
        return True
    n = len(a) // 4
    first, third, last = a[:n].max(), a[2 * n : 3 * n].max(), a[-n:].max()
    if last < floor * first:
        return False
    return bool(last > third)


# -- the explicit limit of the coupling ------------------------------------------------------------------


def free_body_error(
    mass: float, zeta: float, omega_n: float, time_step: float, steps: int = 400
) -> np.ndarray:
    """Position error ``x_G − x_T`` (m) of a free body held by the coupling, after a 1 cm/s kick.

    The body (a 32 × 16 × 10 mm box of ``mass`` kg, the brick's shape) is
    grasped half a step after t = 0 by a device that does not move; the kick
    along x is its initial velocity. The rotational bandwidth is ``ωn/4`` so
    that only translation is near its limit. Gains past the limit are allowed
    (``check_gains=False``): that is what is measured.
    """
    builder = DiagramBuilder()
    plant, _ = AddMultibodyPlant(
        MultibodyPlantConfig(time_step=time_step, discrete_contact_approximation="sap"), builder
    )
    body = plant.AddRigidBody("body", SpatialInertia.SolidBoxWithMass(mass, 0.0318, 0.0158, 0.0096))
    plant.Finalize()
    device = builder.AddNamedSystem(
        "device", ScriptedDevice([Waypoint(t=0.0, grasp="body"), Waypoint(t=1e6, grasp="body")])
    )
    coupling = builder.AddNamedSystem(
        "coupling",
        GodObjectCoupling(
            plant,
            CouplingGains(omega_n=omega_n, zeta=zeta, omega_n_rot=omega_n / 4),
            device_period_s=device.period_s,
            check_gains=False,
            max_stretch_m=math.inf,  # the linear law docs/theory.md §1 analyses: no force cap
        ),
    )
    builder.Connect(plant.get_state_output_port(), coupling.GetInputPort("plant_state"))
    for name in ("X_WD", "V_WD", "grasp"):
        builder.Connect(device.GetOutputPort(name), coupling.GetInputPort(name))
    builder.Connect(coupling.GetOutputPort("spatial_forces"), plant.get_applied_spatial_force_input_port())
    log_G = LogVectorOutput(coupling.GetOutputPort("pose_WG"), builder, time_step)
    log_T = LogVectorOutput(coupling.GetOutputPort("pose_WT"), builder, time_step)
    diagram = builder.Build()
    sim = Simulator(diagram)
    ctx = plant.GetMyMutableContextFromRoot(sim.get_mutable_context())
    plant.SetFreeBodySpatialVelocity(ctx, body, SpatialVelocity(np.zeros(3), np.array([0.01, 0.0, 0.0])))
    sim.AdvanceTo(steps * time_step)
    c = sim.get_context()
    e = log_G.FindLog(c).data()[4] - log_T.FindLog(c).data()[4]
    return e[2:]  # from the first logged sample after the grasp


def drake_k_crit(mass: float, zeta: float, time_step: float, guess: float, rel_tol: float = 1e-3) -> float:
    """Coupling stiffness (N/m) where the Drake run turns from decaying to growing (bisection).

    ``guess`` brackets the search (``[0.8, 1.25] × guess``); the bracket
    itself is checked, so a wrong guess raises instead of returning it.
    """

    def stable(k: float) -> bool:
        return not is_growing(free_body_error(mass, zeta, math.sqrt(k / mass), time_step))

    return bisect(stable, 0.8 * guess, 1.25 * guess, rel_tol)


# -- the haptic device on the probe ----------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class HapticScenario:
    """The simulated device holding the probe on the tissue (``models/haptic``), vertical axis.

    Attributes
    ----------
    device : DeviceParams
        The device (mass, damping, period, delay).
    time_step : float
        Plant step h (s); ``device.period_s`` must be a whole multiple.
    omega_n, zeta : float
        Coupling bandwidth (rad/s) and damping ratio (probe: ``k = m ωn²``).
    k_w, tau_w : float
        Tissue contact stiffness (N/m) and SAP relaxation time (s): ``b_w = k_w τ``.
    kd, gamma_d : float
        Feedback gains (N/m, N·s/m).
    force_amplitude, force_frequency : float
        User's force ``F sin(ω t)`` (N, rad/s), sampled by the device.
    passivity_max_damping : float
        > 0 puts a :class:`~godobject_drake.systems.haptic.PassivityController` with
        this damping cap (N·s/m) on the feedback path; 0 = none.
    """

    device: DeviceParams
    time_step: float = 1e-3
    omega_n: float = 40.0
    zeta: float = 1.0
    k_w: float = 2000.0
    tau_w: float = 1e-3
    kd: float = 0.0
    gamma_d: float = 0.0
    force_amplitude: float = 0.0
    force_frequency: float = 10.0
    passivity_max_damping: float = 0.0

    def pipeline(self, mass: float) -> Pipeline:
        """The analysis model of this scenario
        (:func:`~godobject_drake.studies.stability.pipeline_impedance`)."""
        body = BodyLoop.by_bandwidth(
            mass, self.omega_n, self.zeta, self.time_step, k_w=self.k_w, b_w=self.k_w * self.tau_w
        )
        return Pipeline(body, self.kd, self.gamma_d, self.device.period_s, self.device.delay)


def set_point_contact(scene: SceneParts, stiffness: float, relaxation_time: float) -> None:
    """Give every proximity geometry ``2·stiffness`` and ``relaxation_time/2``.

    Drake combines a contact pair's point stiffnesses harmonically and sums
    their relaxation times (measured), so a pair of such geometries contacts
    with ``stiffness`` and ``relaxation_time``.
    """
    set_contact_material(
        scene.plant,
        scene.scene_graph,
        point_contact_stiffness=2.0 * stiffness,
        relaxation_time=0.5 * relaxation_time,
    )


@dataclasses.dataclass
class HapticRun:
    """Samples at the device period (logged after that instant's update).

    Times (s), device displacement (m) and velocity (m/s), work of the user's and the feedback's
    forces (J), probe height (m), feedback force along the device axis (N).
    """

    times: np.ndarray
    x_device: np.ndarray
    v_device: np.ndarray
    work_user: np.ndarray
    work_feedback: np.ndarray
    z_probe: np.ndarray
    f_feedback: np.ndarray
    probe_mass: float
    passivity_energy: np.ndarray | None = None  # [E_t, E_r, dissipated_t, dissipated_r] per sample (J)

    @property
    def energy_to_user(self) -> np.ndarray:
        """Energy the device has given the user (J): ``−work_user``; ≤ 0 for a passive loop."""
        return -self.work_user


def simulate_haptic(sc: HapticScenario, duration: float, v0_device: float = 0.0) -> HapticRun:
    """Run :class:`HapticScenario` from static equilibrium for ``duration`` s.

    The probe starts resting on the tissue at its static penetration
    ``m g/k_w`` (no gravity compensation: the tissue carries the weight, so
    the probe stays in contact while the perturbation is small); the device
    starts at the probe's centre with velocity ``v0_device`` (m/s) along z.
    """
    builder = DiagramBuilder()
    scene = add_scene_from_directives(builder, HAPTIC_SCENE, time_step=sc.time_step)
    set_point_contact(scene, sc.k_w, sc.tau_w)
    plant = scene.plant
    probe = plant.GetBodyByName("probe")
    radius = 0.02
    g = -plant.gravity_field().gravity_vector()[2]
    z0 = radius - probe.default_mass() * g / sc.k_w
    d = sc.device
    device = builder.AddNamedSystem(
        "haptic_device",
        HapticDevice(
            d.mass,
            d.damping,
            d.period_s,
            d.delay,
            axes="z",
            X_WD_home=RigidTransform([0, 0, z0]),
            grasp="probe",
        ),
    )
    coupling = builder.AddNamedSystem(
        "coupling",
        GodObjectCoupling(
            plant,
            CouplingGains(omega_n=sc.omega_n, zeta=sc.zeta),
            device_period_s=d.period_s,
            gravity_compensation=False,
            check_gains=False,
            max_stretch_m=math.inf,  # the linear loop the report analyses: no force cap
        ),
    )
    feedback = builder.AddNamedSystem("feedback", FeedbackPort(FeedbackGains(kd=sc.kd, gamma_d=sc.gamma_d)))
    builder.Connect(plant.get_state_output_port(), coupling.GetInputPort("plant_state"))
    for name in ("X_WD", "V_WD", "grasp"):
        builder.Connect(device.GetOutputPort(name), coupling.GetInputPort(name))
    builder.Connect(coupling.GetOutputPort("spatial_forces"), plant.get_applied_spatial_force_input_port())
    builder.Connect(device.GetOutputPort("X_WD"), feedback.GetInputPort("X_WD"))
    for name in ("pose_WT", "V_WT", "pose_WG", "V_WG"):
        builder.Connect(coupling.GetOutputPort(name), feedback.GetInputPort(name))
    log_pc = None
    if sc.passivity_max_damping > 0.0:
        pc = builder.AddNamedSystem("passivity", PassivityController(d.period_s, sc.passivity_max_damping))
        builder.Connect(feedback.GetOutputPort("F_Do_W"), pc.GetInputPort("F_in"))
        builder.Connect(device.GetOutputPort("X_WD"), pc.GetInputPort("X_WD"))
        builder.Connect(pc.GetOutputPort("F_out"), device.GetInputPort("F_Do_W"))
        log_pc = LogVectorOutput(pc.GetOutputPort("energy"), builder, d.period_s)
    else:
        builder.Connect(feedback.GetOutputPort("F_Do_W"), device.GetInputPort("F_Do_W"))
    if sc.force_amplitude:
        user = builder.AddNamedSystem("user", Sine(sc.force_amplitude, sc.force_frequency, 0.0, 1))
        builder.Connect(user.get_output_port(0), device.GetInputPort("human_force"))
    log_dev = LogVectorOutput(device.GetOutputPort("device_state"), builder, d.period_s)
    log_work = LogVectorOutput(device.GetOutputPort("work"), builder, d.period_s)
    log_G = LogVectorOutput(coupling.GetOutputPort("pose_WG"), builder, d.period_s)
    log_F = LogVectorOutput(feedback.GetOutputPort("F_Do_W"), builder, d.period_s)
    diagram = builder.Build()
    sim = Simulator(diagram)
    root = sim.get_mutable_context()
    plant.SetFreeBodyPose(plant.GetMyMutableContextFromRoot(root), probe, RigidTransform([0, 0, z0]))
    device.set_initial_state(device.GetMyMutableContextFromRoot(root), x=[0.0], v=[v0_device])
    sim.AdvanceTo(duration)
    c = sim.get_context()
    dev, work, G, F = (log.FindLog(c) for log in (log_dev, log_work, log_G, log_F))
    return HapticRun(
        times=dev.sample_times(),
        x_device=dev.data()[0],
        v_device=dev.data()[1],
        work_user=work.data()[0],
        work_feedback=work.data()[1],
        z_probe=G.data()[6],
        f_feedback=F.data()[5],
        probe_mass=probe.default_mass(),
        passivity_energy=log_pc.FindLog(c).data().T if log_pc else None,
    )


def drake_device_k_max(
    sc: HapticScenario, guess: float, duration: float = 0.4, kick: float = 1e-3, rel_tol: float = 2e-3
) -> float:
    """Largest feedback stiffness ``kd`` (N/m) for which the simulated device stays stable (bisection).

    The device starts with a ``kick`` (m/s) small enough that the probe stays
    in contact; a run is unstable when its displacement grows
    (:func:`is_growing`). ``duration`` (s) must cover a few periods of the
    mode that goes unstable (0.4 s for the stiff obstacle's near-Nyquist
    mode; a few seconds for soft tissue's low-frequency one). ``guess``
    brackets the search (``[0.7, 1.4] × guess``), and the bracket is checked.
    """

    def stable(kd: float) -> bool:
        return not is_growing(
            simulate_haptic(dataclasses.replace(sc, kd=kd), duration, v0_device=kick).x_device
        )

    return bisect(stable, 0.7 * guess, 1.4 * guess, rel_tol)
