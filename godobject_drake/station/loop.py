"""The god-object loop, in the order a sample travels: device → coupling → plant → feedback → device.

Each step is one function, and a tool kind's builder (:mod:`~godobject_drake.station.rigid_tool`,
:mod:`~godobject_drake.station.articulated_tool`, :mod:`~godobject_drake.station.deformable_tool`)
is these steps in this order; a diagram of one's own calls the same ones
(``examples/compose_diagram.py``)::

    device = add_device(builder, record, meshcat)                 # the user's device (its target)
    coupling = add_coupling(builder, plant, device, gains, ...)   # paper Eq. 2: spring to the target
    chain = add_haptic_chain(builder, scenario.haptic, device, coupling)   # none/impedance/admittance
    feedback = add_feedback(builder, chain, coupling, gains)      # paper Eq. 8: the device's wrench
    connect_target(builder, chain, coupling)                      # the chain's pose is the target
    connect_forces(builder, plant, coupling)                      # the coupling's wrench into the plant
    render_feedback(builder, device, chain, feedback, coupling)   # the wrench back to the device

The articulated tool's loop has the same steps with joint-space parts (:func:`add_joint_coupling`,
:func:`add_joint_feedback`).
"""

import math

from pydrake.multibody.plant import ExternallyAppliedSpatialForceMultiplexer, MultibodyPlant
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import Adder

from godobject_drake.config import scenario as sc
from godobject_drake.config.gains import CouplingGains, FeedbackGains
from godobject_drake.devices import factory
from godobject_drake.devices.sources import DeviceSource, JointDevice
from godobject_drake.station.haptic_chain import HapticChain
from godobject_drake.systems.articulated import ArticulatedCoupling, ArticulatedFeedback, ArticulatedTool
from godobject_drake.systems.coupling import GodObjectCoupling, GraspLedger
from godobject_drake.systems.feedback import FeedbackPort
from godobject_drake.systems.implicit import ImplicitCoupling, ImplicitCouplingError

# -- device ------------------------------------------------------------------------------------------------


def make_device(
    config, *, seed: int = 0, meshcat=None, workspace=None, duration_s: float = math.inf, tool: str = ""
) -> DeviceSource | JointDevice:
    """The device a scenario's ``device`` field describes (not yet added to a builder): its
    registered kind's factory (:func:`godobject_drake.devices.factory.make_device`), its errors
    as a :class:`~godobject_drake.config.scenario.ScenarioError` naming the field.

    ``seed`` seeds the pose devices' noise; a live device (``MeshcatSliders``,
    ``MeshcatJointSliders``) needs the ``meshcat`` whose page drives it, and a pose one the
    ``workspace`` its sliders span. ``duration_s``: the run's length, so a log is read only as far
    as the run reaches (a log of any length costs what the run uses). ``tool``: the tool it drives
    in a scene of several (a live device's sliders and buttons are named by it).
    """
    return _scenario_errors(
        factory.make_device, config, seed=seed, meshcat=meshcat, workspace=workspace, duration_s=duration_s,
        tool=tool,
    )  # fmt: skip


def _scenario_errors(make, *args, **kwargs):
    """``make(*args, **kwargs)``, its errors about the device (an unregistered kind, a field its check
    refuses, what the kind needs from the scene: a Meshcat, a workspace) as ``ScenarioError``."""
    try:
        return make(*args, **kwargs)
    except ValueError as e:
        if str(e).startswith("device"):
            raise sc.ScenarioError(str(e)) from None
        raise


def add_device(builder: DiagramBuilder, record: sc.ToolRecord, meshcat=None):
    """A tool's device (:func:`make_device` of ``record.view.device``), added to ``builder`` as
    ``device`` (``NAME/device`` in a scene of several, its live controls carrying the name)."""
    view = record.view
    device = _scenario_errors(
        factory.make_device_of, record.device, view.device, seed=view.random_seed, meshcat=meshcat,
        workspace=view.workspace, duration_s=view.simulation.duration_s, tool=record.name,
    )  # fmt: skip
    return builder.AddNamedSystem(record.named("device"), device)


# -- the plant's force inputs, shared by every tool -------------------------------------------------------


class ForceBus:
    """The forces of every tool of a scene into the plant's two force inputs: one source is
    connected straight, several through an ``Adder`` (generalized forces) or an
    ``ExternallyAppliedSpatialForceMultiplexer`` (spatial forces), when the station is finished."""

    def __init__(self, plant: MultibodyPlant):
        self.plant = plant
        self.generalized, self.spatial = [], []

    def connect(self, builder: DiagramBuilder) -> None:
        plant = self.plant
        for ports, into, join in (
            (self.generalized, plant.get_applied_generalized_force_input_port(),
             lambda n: Adder(n, plant.num_velocities())),
            (self.spatial, plant.get_applied_spatial_force_input_port(),
             ExternallyAppliedSpatialForceMultiplexer),
        ):  # fmt: skip
            if len(ports) == 1:
                builder.Connect(ports[0], into)
            elif ports:
                name = "generalized_forces" if ports is self.generalized else "spatial_forces"
                sum_ = builder.AddNamedSystem(name, join(len(ports)))
                for i, port in enumerate(ports):
                    builder.Connect(port, sum_.get_input_port(i))
                builder.Connect(sum_.get_output_port(0), into)


def _drive(builder: DiagramBuilder, plant: MultibodyPlant, port, bus: ForceBus | None, spatial: bool) -> None:
    """``port`` into the plant's spatial or generalized force input: now, or through ``bus``."""
    if bus is not None:
        (bus.spatial if spatial else bus.generalized).append(port)
    elif spatial:
        builder.Connect(port, plant.get_applied_spatial_force_input_port())
    else:
        builder.Connect(port, plant.get_applied_generalized_force_input_port())


# -- coupling ----------------------------------------------------------------------------------------------


def add_coupling(
    builder: DiagramBuilder,
    plant: MultibodyPlant,
    device: DeviceSource,
    gains: CouplingGains,
    *,
    period_s: float | None = None,
    springs=None,
    check_gains: bool = True,
    name: str = "coupling",
    **options,
):
    """The rigid coupling (paper Eq. 2) on the plant's free bodies, reading the plant's state.

    Explicit (:class:`~godobject_drake.systems.coupling.GodObjectCoupling`: its wrench is applied
    each plant step, :func:`connect_forces`), or implicit when ``springs``
    (:func:`~godobject_drake.systems.implicit.add_springs`, added before ``Finalize``) are given
    (:class:`~godobject_drake.systems.implicit.ImplicitCoupling`: SAP integrates the spring, the
    Python runs every ``period_s``, the device's period by default). Every grasp name the device
    can report is checked; pseudo-haptic aids of the device read the coupling's T and G.
    ``options``: ``graspable``, ``gravity_compensation``, ``max_stretch_m``, ``max_twist_rad``,
    ``grasp_reach_m``, ``carried``.
    """
    if springs is not None:
        if options.get("carried"):
            raise ImplicitCouplingError(
                "the implicit coupling drives a rigid body with springs: not a carried shell"
            )
        system = ImplicitCoupling(plant, gains, springs, period_s or device.period_s, **options)
    else:
        system = GodObjectCoupling(plant, gains, device_period_s=device.period_s, check_gains=check_gains,
                                   **options)  # fmt: skip
    coupling = builder.AddNamedSystem(name, system)
    coupling.validate_grasp_names(device.grasp_names())
    builder.Connect(plant.get_state_output_port(), coupling.GetInputPort("plant_state"))
    device.follow(builder, coupling)  # pseudo-haptic aids read T and G
    return coupling


def add_joint_coupling(
    builder: DiagramBuilder,
    plant: MultibodyPlant,
    model,
    device_joints,
    *,
    coupling: str = "cartesian",
    gains: CouplingGains,
    device_period_s: float,
    q_reference,
    imposed_joints=(),
    q_check=None,
    connect_forces: bool = True,
    check_gains: bool = True,
    name: str = "coupling",
    bus: ForceBus | None = None,
) -> ArticulatedCoupling:
    """Make a tree model a god-object (paper Eq. 4–7): one call, after ``plant.Finalize()``.

    Adds an :class:`~godobject_drake.systems.articulated.ArticulatedCoupling` named ``name`` and
    connects it to the plant (state, body poses and velocities in; forces, generalized forces or
    desired state out, as the coupling mode needs). Connect a
    :class:`~godobject_drake.devices.sources.JointDevice`'s ``q_device`` and ``v_device`` to it.
    ``connect_forces=False`` leaves the plant's inputs alone (the position baseline). ``q_check``
    lists device configurations at which the explicit modes' stability is checked (default
    ``q_reference``); ``check_gains=False`` skips it (stability analysis only). A tool's own parts
    usually overlap at their joints (the grasper's jaws at the hinge): filter them with
    :func:`godobject_drake.station.plant.exclude_self_collisions`.
    """
    tool = ArticulatedTool(plant, model, device_joints, imposed_joints)
    system = builder.AddNamedSystem(
        name,
        ArticulatedCoupling(
            tool, coupling, gains, device_period_s, q_reference, q_check, check_gains=check_gains
        ),
    )
    builder.Connect(plant.get_state_output_port(), system.GetInputPort("plant_state"))
    builder.Connect(plant.get_body_poses_output_port(), system.GetInputPort("body_poses"))
    builder.Connect(
        plant.get_body_spatial_velocities_output_port(), system.GetInputPort("body_spatial_velocities")
    )
    if connect_forces:
        _drive(builder, plant, system.GetOutputPort("spatial_forces"), bus, spatial=True)
        if coupling == "joint_pd":
            _drive(builder, plant, system.GetOutputPort("generalized_force"), bus, spatial=False)
        if coupling == "joint_pd_sap":
            builder.Connect(
                system.GetOutputPort("desired_state"), plant.get_desired_state_input_port(tool.model)
            )
    return system


def connect_target(builder: DiagramBuilder, chain: HapticChain, coupling) -> None:
    """The coupling's target is the haptic chain's pose: the device's, or its simulated handle's."""
    for port in ("X_WD", "V_WD", "grasp"):
        builder.Connect(chain.target.GetOutputPort(port), coupling.GetInputPort(port))


def connect_forces(
    builder: DiagramBuilder, plant: MultibodyPlant, coupling, bus: ForceBus | None = None
) -> None:
    """The explicit coupling's wrench into the plant (an implicit coupling's springs are the
    plant's own: nothing to connect); through the station's ``bus`` when several tools share the
    plant's input."""
    if not isinstance(coupling, ImplicitCoupling):
        _drive(builder, plant, coupling.GetOutputPort("generalized_force"), bus, spatial=False)


def share_grasps(builder: DiagramBuilder, couplings: list) -> None:
    """A scene of several rigid tools: each coupling learns what the others hold (a
    :class:`~godobject_drake.systems.coupling.GraspLedger`), so no two hold one body."""
    if len(couplings) < 2:
        return
    ledger = builder.AddNamedSystem("grasp_ledger", GraspLedger(len(couplings)))
    for i, coupling in enumerate(couplings):
        builder.Connect(coupling.GetOutputPort("held_body"), ledger.GetInputPort(f"held_body_{i}"))
        builder.Connect(ledger.GetOutputPort(f"held_elsewhere_{i}"), coupling.GetInputPort("held_elsewhere"))


# -- feedback ----------------------------------------------------------------------------------------------


def add_feedback(
    builder: DiagramBuilder, chain: HapticChain, coupling, gains: FeedbackGains | None = None
) -> FeedbackPort:
    """The feedback port (paper Eq. 8), a second coupling between the god-object G and the
    target T, named ``feedback``; wired whatever its gains (zero: a non-haptic device), so a logger
    or a device of one's own can read ``F_Do_W``."""
    feedback = builder.AddNamedSystem("feedback", FeedbackPort(gains))
    builder.Connect(chain.target.GetOutputPort("X_WD"), feedback.GetInputPort("X_WD"))
    for port in ("pose_WT", "V_WT", "pose_WG", "V_WG"):
        builder.Connect(coupling.GetOutputPort(port), feedback.GetInputPort(port))
    return feedback


def add_joint_feedback(
    builder: DiagramBuilder, plant: MultibodyPlant, device: JointDevice, coupling, gains=None
) -> ArticulatedFeedback:
    """The articulated tool's feedback (paper Eq. 8–9: per-body wrenches, moved to the parents, the
    device joints' forces), named ``feedback``, reading the device and the plant's bodies."""
    feedback = builder.AddNamedSystem("feedback", ArticulatedFeedback(coupling.tool, gains))
    builder.Connect(device.GetOutputPort("q_device"), feedback.GetInputPort("q_device"))
    builder.Connect(coupling.GetOutputPort("targets"), feedback.GetInputPort("targets"))
    builder.Connect(plant.get_body_poses_output_port(), feedback.GetInputPort("body_poses"))
    builder.Connect(
        plant.get_body_spatial_velocities_output_port(), feedback.GetInputPort("body_spatial_velocities")
    )
    return feedback


def render_feedback(builder: DiagramBuilder, device, chain: HapticChain, feedback, coupling):
    """Close the loop: the feedback wrench to the chain's simulated device, and to the user's device
    when it renders it itself (a real haptic device over LCM); returns the latter's publisher or
    None."""
    force = feedback.GetOutputPort("F_Do_W")
    chain.connect_feedback(builder, force)
    publisher = device.connect_feedback(builder, force, coupling.bodies)
    if hasattr(device, "connect_local_model"):  # a driver process: the local model too
        device.connect_local_model(builder, coupling, feedback.gains)
    return publisher
