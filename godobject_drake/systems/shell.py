"""Deformable god-objects (paper section "Deformable body", Fig. 4): a rigid core
that is itself a god-object, carrying a deformable shell.

The core C is a free rigid body: coupled to the device like any rigid
god-object, simulated, neither drawn nor colliding. The shell is drawn and
collides; it is held to the core, so the device controls the rigid motion
and the simulation the deformation. Two shell models share one interface
(:class:`Shell`), picked by name in :data:`SHELL_MODELS`:

``fem``
    Drake's FEM ``DeformableModel``: a tetrahedral ball of radius R (Drake
    meshes the sphere; ``fem_resolution_m`` picks 25, 129 or 833 vertices),
    whose vertices inside the core (radius rc) are fixed to C by
    ``AddFixedConstraint``. Linear tetrahedra, corotated material, implicit
    in SAP.
``mass_spring``
    The paper's own model (Meseure & Chaillou 2000): ``nodes`` point masses
    on the surface, each tied to its rest position on C by a zero-length
    spring and to its neighbours by edge springs. Each node is a small
    sphere (the paper's sphere-based contact) on three prismatic joints
    whose parent is C; the zero-length springs are PD-controlled actuators
    on those joints and the edge springs compliant distance constraints, so
    SAP integrates every spring implicitly (the paper used implicit Euler)
    and the springs' reaction on C is exact.

Both models get their stiffness from one Young's modulus E, shell density
ρ and thickness t = R − rc. The shell's through-thickness mode has
ω_s = √(E/ρ)/t; a mass–spring node of area A = 4πR²/N gets the
zero-length spring k = E A / t (a column of shell under the node), and
edges a quarter of that. Damping: Rayleigh stiffness damping 2ζ/ω_s (FEM),
the same ζ on every spring (mass–spring).

Which to pick (measured, docs/guide/deformable.md): the mass–spring shell
with 42 nodes is the cheaper interactive shell; the FEM shell is the
realistic one (a continuum, any mesh) at 129 vertices. Mass–spring cost
grows as the cube of its node count (the nodes are one kinematic tree with
the core, and SAP factors each tree densely).
"""

import math

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.geometry import (
    AddContactMaterial,
    CollisionFilterDeclaration,
    GeometryConfigurationVector,
    GeometryInstance,
    GeometrySet,
    ProximityProperties,
    Role,
    SceneGraph,
    Sphere,
)
from pydrake.math import RigidTransform
from pydrake.multibody.fem import DeformableBodyConfig
from pydrake.multibody.plant import CoulombFriction, MultibodyPlant
from pydrake.multibody.tree import (
    FixedOffsetFrame,
    PdControllerGains,
    PrismaticJoint,
    SpatialInertia,
    UnitInertia,
)
from pydrake.systems.framework import DiagramBuilder, LeafSystem
from pydrake.systems.primitives import ConstantVectorSource
from scipy.spatial import ConvexHull

from godobject_drake.config.tools import SHELL_MODELS, ShellSpec, ShellSpecError


def fibonacci_sphere(n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``n`` nearly even unit vectors, their triangles (outward) and edges.

    Points of a Fibonacci lattice; scipy's convex hull triangulates them.
    Returns ``(V (n,3), F (2n−4,3), E (3n−6,2))``.
    """
    i = np.arange(n) + 0.5
    z = 1.0 - 2.0 * i / n
    r = np.sqrt(1.0 - z * z)
    phi = math.pi * (1.0 + math.sqrt(5.0)) * i
    V = np.column_stack([r * np.cos(phi), r * np.sin(phi), z])
    F = ConvexHull(V).simplices.copy()
    normals = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    inward = np.einsum("ij,ij->i", normals, V[F].mean(axis=1)) < 0
    F[inward] = F[inward][:, ::-1]
    E = np.unique(np.sort(np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]]), axis=1), axis=0)
    return V, F, E


def _contact_properties(friction: float, stiffness: float | None = None) -> ProximityProperties:
    props = ProximityProperties()
    AddContactMaterial(
        dissipation=None, point_stiffness=stiffness, friction=CoulombFriction(friction, friction),
        properties=props,
    )  # fmt: skip
    return props


class Shell:
    """A rigid core C (a god-object body) carrying a deformable shell.

    Built by :func:`add_deformable_god_object` before ``Finalize()``;
    :meth:`connect` wires what needs the finalized plant and returns a
    :class:`ShellObserver`. Grasp the core by :attr:`grasp_name` with a
    :class:`~godobject_drake.systems.coupling.GodObjectCoupling` given
    ``carried={grasp_name: shell_inertia}``.

    Attributes
    ----------
    core : RigidBody
        The core C; no geometry.
    rest_C : (V, 3)
        Rest positions of the shell's tracked points in C (vertices, nodes).
    contact_radius_m : float
        Radius of the contact sphere around each tracked point (0 for FEM
        vertices; the node sphere's radius for mass–spring).
    surface : np.ndarray
        Indices of the tracked points on the outer surface (drawn).
    """

    model: str

    def __init__(self, plant: MultibodyPlant, spec: ShellSpec, X_WC: RigidTransform, name: str):
        spec.check()
        if plant.is_finalized():
            raise RuntimeError(
                "add_deformable_god_object() adds bodies: call it before plant.Finalize() "
                "(add_scene_from_directives(..., before_finalize=...))"
            )
        if plant.time_step() <= 0:
            raise ShellSpecError("a deformable god-object needs a discrete SAP plant (time_step > 0)")
        self.spec, self.name = spec, name
        self.instance = plant.AddModelInstance(name)
        rc = spec.core_radius_m
        self.core = plant.AddRigidBody(
            "core", self.instance, SpatialInertia(spec.core_mass_kg, np.zeros(3), UnitInertia.SolidSphere(rc))
        )
        plant.SetDefaultFloatingBaseBodyPose(self.core, X_WC)
        self.grasp_name = name

    # -- what subclasses fill in -------------------------------------------------
    rest_C: np.ndarray
    surface: np.ndarray
    contact_radius_m: float
    shell_mass_kg: float

    @property
    def vertex_count(self) -> int:
        """Points whose motion the shell model computes (FEM vertices, nodes)."""
        return len(self.rest_C)

    def shell_inertia(self) -> SpatialInertia:
        """The shell's spatial inertia about Co in C, at rest (for the coupling)."""
        # A uniform spherical shell: I = (2/5) m (R⁵ − a⁵)/(R³ − a³), a its inner radius.
        R, a = self.spec.radius_m, self._inertia_inner_radius()
        g = 0.4 * (R**5 - a**5) / (R**3 - a**3)
        return SpatialInertia(self.shell_mass_kg, np.zeros(3), UnitInertia(g, g, g))

    def _inertia_inner_radius(self) -> float:
        return self.spec.core_radius_m

    def connect(self, builder: DiagramBuilder, plant: MultibodyPlant) -> "ShellObserver":
        raise NotImplementedError

    def impose_core(self, plant: MultibodyPlant, plant_context, set_core) -> None:
        """Position baseline: ``set_core()`` sets the core's state; the shell keeps its own.

        The paper's first idea, which it rejects: the rigid component is
        driven directly and the shell follows only through its springs.
        """
        set_core()


class FemShell(Shell):
    """The shell as a Drake FEM deformable body fixed to the core inside rc."""

    model = "fem"

    def __init__(self, plant, scene_graph, spec, X_WC, name):
        super().__init__(plant, spec, X_WC, name)
        R, rc = spec.radius_m, spec.core_radius_m
        config = DeformableBodyConfig()
        config.set_youngs_modulus(spec.youngs_modulus_pa)
        config.set_poissons_ratio(spec.poissons_ratio)
        config.set_mass_density(spec.density_kg_m3)
        config.set_stiffness_damping_coefficient(2.0 * spec.damping_ratio / spec.shell_omega)
        instance = GeometryInstance(X_WC, Sphere(R), f"{name}_shell")
        props = _contact_properties(spec.friction)
        props.AddProperty("material", "relaxation_time", spec.fem_contact_relaxation_s)
        instance.set_proximity_properties(props)
        model = plant.mutable_deformable_model()
        self.body_id = model.RegisterDeformableBody(instance, self.instance, config, spec.fem_resolution_m)
        model.AddFixedConstraint(self.body_id, self.core, RigidTransform(), Sphere(rc), RigidTransform())
        # Reference positions are in W at X_WC; the constraint reads them in C.
        p_W = np.asarray(model.GetReferencePositions(self.body_id)).reshape(-1, 3)
        self.rest_C = X_WC.inverse().multiply(p_W.T).T
        radii = np.linalg.norm(self.rest_C, axis=1)
        self.surface = np.flatnonzero(radii > R * (1 - 1e-6))
        self.contact_radius_m = 0.0
        self.geometry_id = model.GetGeometryId(self.body_id)
        # Drake's sphere mesh is inscribed in R (its vertices are on the sphere, so
        # the mesh is their convex hull): ρ times the hull's volume is its mass,
        # 9 % less than the ball's at 129 vertices, which would lift the probe
        # by 0.5 mm through overcompensated gravity.
        self.shell_mass_kg = spec.density_kg_m3 * ConvexHull(self.rest_C).volume

    def _inertia_inner_radius(self) -> float:
        return 0.0  # a solid ball: its part inside the core moves with the core

    def connect(self, builder, plant):
        observer = builder.AddNamedSystem(f"{self.name}_shell_observer", ShellObserver(self, plant))
        builder.Connect(
            plant.get_deformable_body_configuration_output_port(),
            observer.GetInputPort("deformable_configuration"),
        )
        builder.Connect(plant.get_body_poses_output_port(), observer.GetInputPort("body_poses"))
        return observer


class MassSpringShell(Shell):
    """The paper's shell: surface nodes on zero-length springs to the core, edge springs between."""

    model = "mass_spring"

    def __init__(self, plant, scene_graph, spec, X_WC, name):
        super().__init__(plant, spec, X_WC, name)
        R, rc, N = spec.radius_m, spec.core_radius_m, spec.nodes
        V, self.faces, self.edges = fibonacci_sphere(N)
        edge = float(np.mean(np.linalg.norm(V[self.edges[:, 0]] - V[self.edges[:, 1]], axis=1))) * R
        rn = min(0.5 * edge, 0.5 * spec.thickness_m)
        self.contact_radius_m = rn
        self.rest_C = (R - rn) * V  # node spheres reach R
        self.surface = np.arange(N)
        self.shell_mass_kg = spec.density_kg_m3 * 4.0 / 3.0 * math.pi * (R**3 - rc**3)
        m = self.shell_mass_kg / N
        self.node_mass_kg = m
        self.anchor_stiffness = spec.youngs_modulus_pa * (4.0 * math.pi * R**2 / N) / spec.thickness_m
        self.edge_stiffness = 0.25 * self.anchor_stiffness
        zeta = spec.damping_ratio
        self.anchor_gains = PdControllerGains(
            p=self.anchor_stiffness, d=2.0 * zeta * math.sqrt(self.anchor_stiffness * m)
        )
        shell = plant.AddModelInstance(f"{name}_shell")
        self.shell_instance = shell
        massless = SpatialInertia(0.0, np.zeros(3), UnitInertia(0.0, 0.0, 0.0))
        node_inertia = SpatialInertia(m, np.zeros(3), UnitInertia.SolidSphere(rn))
        props = _contact_properties(spec.friction, spec.node_contact_stiffness)
        self.nodes, self.joints, ids = [], [], []
        for i, p_C in enumerate(self.rest_C):
            # C → x → y → node, prismatic along C's axes; all joints read 0 at rest.
            bx = plant.AddRigidBody(f"node{i}_x", shell, massless)
            by = plant.AddRigidBody(f"node{i}_y", shell, massless)
            node = plant.AddRigidBody(f"node{i}", shell, node_inertia)
            rest = plant.AddFrame(FixedOffsetFrame(f"node{i}_rest", by.body_frame(), RigidTransform(p_C)))
            joints = (
                PrismaticJoint(f"node{i}_x", self.core.body_frame(), bx.body_frame(), [1, 0, 0]),
                PrismaticJoint(f"node{i}_y", bx.body_frame(), by.body_frame(), [0, 1, 0]),
                PrismaticJoint(f"node{i}_z", rest, node.body_frame(), [0, 0, 1]),
            )
            added = [plant.AddJoint(joint) for joint in joints]  # the plant's copies carry the index
            for joint in added:
                plant.AddJointActuator(joint.name(), joint)  # PD gains: in connect()
            self.joints.append(tuple(added))
            ids.append(plant.RegisterCollisionGeometry(node, RigidTransform(), Sphere(rn), f"node{i}", props))
            self.nodes.append(node)
        d_edge = 2.0 * zeta * math.sqrt(self.edge_stiffness * m)
        for a, b in self.edges:
            length = float(np.linalg.norm(self.rest_C[a] - self.rest_C[b]))
            plant.AddDistanceConstraint(
                self.nodes[a], np.zeros(3), self.nodes[b], np.zeros(3), length, self.edge_stiffness, d_edge
            )
        self.geometry_ids = ids
        scene_graph.collision_filter_manager().Apply(
            CollisionFilterDeclaration().ExcludeWithin(GeometrySet(ids))
        )

    def connect(self, builder, plant):
        for index in plant.GetJointActuatorIndices(self.shell_instance):
            plant.get_joint_actuator(index).set_controller_gains(self.anchor_gains)
        n = plant.num_actuated_dofs(self.shell_instance)
        rest = builder.AddNamedSystem(f"{self.name}_shell_rest", ConstantVectorSource(np.zeros(2 * n)))
        builder.Connect(rest.get_output_port(), plant.get_desired_state_input_port(self.shell_instance))
        observer = builder.AddNamedSystem(f"{self.name}_shell_observer", ShellObserver(self, plant))
        builder.Connect(plant.get_body_poses_output_port(), observer.GetInputPort("body_poses"))
        return observer

    def impose_core(self, plant, plant_context, set_core):
        # Node coordinates are relative to the core: re-express each node's world position
        # and velocity after the core moves, so the nodes stay where they were in W.
        ctx = plant_context
        p_WN = [plant.EvalBodyPoseInWorld(ctx, n).translation() for n in self.nodes]
        v_WN = [plant.EvalBodySpatialVelocityInWorld(ctx, n).translational() for n in self.nodes]
        set_core()
        X_WC = plant.EvalBodyPoseInWorld(ctx, self.core)
        V_WC = plant.EvalBodySpatialVelocityInWorld(ctx, self.core)
        R_CW = X_WC.rotation().inverse().matrix()
        p_WC, w, v_WC = X_WC.translation(), V_WC.rotational(), V_WC.translational()
        for (jx, jy, jz), rest, p, v in zip(self.joints, self.rest_C, p_WN, v_WN, strict=True):
            q = R_CW @ (p - p_WC) - rest
            qdot = R_CW @ (v - v_WC - np.cross(w, p - p_WC))
            for joint, value, rate in ((jx, q[0], qdot[0]), (jy, q[1], qdot[1]), (jz, q[2], qdot[2])):
                joint.set_translation(ctx, value)
                joint.set_translation_rate(ctx, rate)


def add_deformable_god_object(
    plant: MultibodyPlant,
    scene_graph: SceneGraph,
    shell: str = "fem",
    spec: ShellSpec | None = None,
    X_WC: RigidTransform | None = None,
    name: str = "probe",
) -> Shell:
    """Add a core and its shell (``shell`` ∈ :data:`SHELL_MODELS`) before ``Finalize()``.

    ``X_WC`` is the core's initial pose (the shell starts at rest around it).
    """
    if shell not in SHELL_MODELS:
        raise ShellSpecError(f"shell={shell!r}; choose one of {SHELL_MODELS}")
    cls = FemShell if shell == "fem" else MassSpringShell
    return cls(plant, scene_graph, spec or ShellSpec(), X_WC or RigidTransform(), name)


class ShellObserver(LeafSystem):
    """Where the shell is and where it would be at rest on the core.

    .. pydrake_system::

        name: ShellObserver
        input_ports:
        - body_poses
        - deformable_configuration (FEM only)
        output_ports:
        - vertex_positions
        - rest_positions
        - pose_WC

    ``vertex_positions`` and ``rest_positions`` are the tracked points in W,
    ``[x0 y0 z0 x1 ...]``; ``pose_WC`` the core pose ``[qw qx qy qz x y z]``.
    """

    def __init__(self, shell: Shell, plant: MultibodyPlant):
        super().__init__()
        self._shell = shell
        self._core = int(shell.core.index())
        self._poses = self.DeclareAbstractInputPort("body_poses", AbstractValue.Make([RigidTransform()]))
        n = 3 * shell.vertex_count
        if isinstance(shell, FemShell):
            self._config = self.DeclareAbstractInputPort(
                "deformable_configuration", AbstractValue.Make(GeometryConfigurationVector())
            )
            self._gid = shell.geometry_id
            positions = self._fem_positions
        else:
            self._nodes = [int(b.index()) for b in shell.nodes]
            positions = self._node_positions
        self.DeclareVectorOutputPort("vertex_positions", n, positions)
        self.DeclareVectorOutputPort("rest_positions", n, self._rest_positions)
        self.DeclareVectorOutputPort("pose_WC", 7, self._core_pose)

    def _fem_positions(self, context, output):
        output.SetFromVector(np.asarray(self._config.Eval(context).value(self._gid)).ravel())

    def _node_positions(self, context, output):
        poses = self._poses.Eval(context)
        output.SetFromVector(np.concatenate([poses[i].translation() for i in self._nodes]))

    def _rest_positions(self, context, output):
        X_WC = self._poses.Eval(context)[self._core]
        output.SetFromVector(X_WC.multiply(self._shell.rest_C.T).T.ravel())

    def _core_pose(self, context, output):
        X_WC = self._poses.Eval(context)[self._core]
        q = X_WC.rotation().ToQuaternion()
        output.SetFromVector(np.concatenate([q.wxyz(), X_WC.translation()]))


def obstacle_geometries(scene_graph: SceneGraph, shell: Shell, plant: MultibodyPlant):
    """Rigid proximity geometries that are not part of the deformable god-object."""
    inspector = scene_graph.model_inspector()
    own = {plant.GetBodyFrameIdOrThrow(b) for b in plant.GetBodyIndices(shell.instance)}
    if isinstance(shell, MassSpringShell):
        own |= {plant.GetBodyFrameIdOrThrow(b) for b in plant.GetBodyIndices(shell.shell_instance)}
    return {
        g
        for g in inspector.GetAllGeometryIds(Role.kProximity)
        if not inspector.IsDeformableGeometry(g) and inspector.GetFrameId(g) not in own
    }
