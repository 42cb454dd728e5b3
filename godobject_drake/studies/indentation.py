"""FEM tissue against contact mechanics: a rigid sphere pressed into a FEM block, against Hertz.

    python -m godobject_drake.studies.indentation --fine 0.5e-3 --depths 0.5e-3 1e-3

A rigid sphere of the grasper tube's tip radius (R = 5 mm) on a prismatic joint
is driven down into a block of FEM tissue (the scene's material: E = 50 kPa,
ν = 0.45, unless given) by a stiff PD actuator that SAP integrates implicitly,
slowly enough to be quasi-static. At each prescribed depth it is held until the
tissue settles; the force is read twice, from Drake's contact results (the
deformable contacts' net force) and from the actuator's reaction
(``kp (q_d − q) − kd v``: the sphere is massless to gravity here, so at rest the
actuator holds exactly the contact). The depth is the sphere's actual
indentation below the block's undeformed top. Hertz's closed form for a rigid
sphere on an elastic half-space::

    F = (4/3) E* √R d^(3/2),   E* = E / (1 − ν²),   contact radius a = √(R d)

The block is a graded grid (:func:`graded_axis`): cells of ``fine`` near the
axis out to ``fine_extent`` (a few contact radii), then growing by ``growth``
to the block's half width ``half_width`` and depth ``depth``; its bottom is
held (Drake's wall boundary condition), its sides free. A finite block is a
half-space only while a ≪ its size, and the cells must resolve a; the held
bottom stiffens it, by the factor :func:`layer_correction` (12.8 % at a = 2.2 mm
over 15 mm), so the forces are compared with both.

Press in steps of 0.5 mm or less at 10 ms: Drake 1.51 loses the contact when
the sphere comes in 0.05 mm a step (a ramp straight to 1 mm in 0.2 s, or the
same ramp at 20 ms): the sphere ends inside the block with no contact force.
"""

import argparse
import dataclasses
import json
import math
import tempfile
import time
from pathlib import Path

import numpy as np
from pydrake.geometry import (
    AddContactMaterial,
    AddRigidHydroelasticProperties,
    GeometryInstance,
    Mesh,
    ProximityProperties,
    Sphere,
)
from pydrake.math import RigidTransform
from pydrake.multibody.plant import (
    AddMultibodyPlant,
    CoulombFriction,
    MultibodyPlantConfig,
)
from pydrake.multibody.tree import PdControllerGains, PrismaticJoint, SpatialInertia, UnitInertia
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import ConstantVectorSource

from godobject_drake.systems.tissue import grid_tet_mesh, write_vtk


def hertz_force(E: float, nu: float, R: float, d) -> np.ndarray:
    """Hertz: a rigid sphere of radius R pressed d into an elastic half-space (N)."""
    return 4.0 / 3.0 * E / (1.0 - nu * nu) * math.sqrt(R) * np.asarray(d, float) ** 1.5


def layer_correction(nu: float, R: float, d, thickness: float) -> np.ndarray:
    """Hertz's force times this for a layer of ``thickness`` bonded to a rigid base (Dimitriadis
    et al. 2002, Biophys. J. 82, Eq. 12): χ = √(R d)/h, the contact radius over the thickness."""
    chi = np.sqrt(R * np.asarray(d, float)) / thickness
    a0 = -(1.2876 - 1.4678 * nu + 1.3442 * nu**2) / (1.0 - nu)
    b0 = (0.6387 - 1.0277 * nu + 1.5164 * nu**2) / (1.0 - nu)
    pi = math.pi
    return (1.0 - 2.0 * a0 * chi / pi + 4.0 * a0**2 * chi**2 / pi**2
            - 8.0 / pi**3 * (a0**3 + 4.0 * pi**2 * b0 / 15.0) * chi**3)  # fmt: skip


def graded_axis(fine: float, fine_extent: float, extent: float, growth: float) -> np.ndarray:
    """Coordinates 0, fine, 2 fine, ... up to fine_extent, then cells growing by ``growth`` to
    ``extent`` (the last cell ends exactly there)."""
    xs = list(np.arange(0.0, fine_extent + 0.5 * fine, fine))
    h = fine
    while xs[-1] < extent - 1e-12:
        h *= growth
        xs.append(min(xs[-1] + h, extent))
    if extent - xs[-2] < 0.5 * (xs[-2] - xs[-3]):  # no sliver at the end
        xs.pop(-2)
    return np.array(xs)


@dataclasses.dataclass
class IndentationSetup:
    """The check's geometry, material and loading (SI units)."""

    sphere_radius_m: float = 0.005
    youngs_modulus_pa: float = 5.0e4
    poissons_ratio: float = 0.45
    density_kg_m3: float = 1000.0
    fine_m: float = 0.5e-3
    fine_extent_m: float = 3.0e-3
    half_width_m: float = 0.02
    depth_m: float = 0.02
    growth: float = 1.6
    time_step_s: float = 0.01
    ramp_s: float = 0.2
    hold_s: float = 0.2
    kp: float = 1.0e5
    sphere_resolution_m: float = 0.25e-3  # Drake's mesh of the rigid sphere for deformable contact

    def block(self):
        side = graded_axis(self.fine_m, self.fine_extent_m, self.half_width_m, self.growth)
        xs = np.concatenate([-side[:0:-1], side])
        zs = -graded_axis(self.fine_m, self.fine_extent_m, self.depth_m, self.growth)[::-1]
        return grid_tet_mesh(xs, xs, zs)


def indent(setup: IndentationSetup, depths, vtk_dir: str | Path | None = None) -> dict:
    """Press the sphere to each of ``depths`` (m, increasing) in turn; the measured forces."""
    V, T = setup.block()
    vtk_dir = Path(vtk_dir or tempfile.mkdtemp(prefix="godobject_indent_"))
    path = write_vtk(vtk_dir / "block.vtk", V, T)
    builder = DiagramBuilder()
    plant, _ = AddMultibodyPlant(
        MultibodyPlantConfig(time_step=setup.time_step_s, discrete_contact_approximation="sap"), builder
    )
    plant.mutable_gravity_field().set_gravity_vector([0.0, 0.0, 0.0])
    from pydrake.multibody.fem import DeformableBodyConfig

    config = DeformableBodyConfig()
    config.set_youngs_modulus(setup.youngs_modulus_pa)
    config.set_poissons_ratio(setup.poissons_ratio)
    config.set_mass_density(setup.density_kg_m3)
    config.set_stiffness_damping_coefficient(0.05)
    props = ProximityProperties()
    AddContactMaterial(dissipation=None, point_stiffness=None, friction=CoulombFriction(0.0, 0.0),
                       properties=props)  # fmt: skip
    props.AddProperty("material", "relaxation_time", setup.time_step_s)
    block = GeometryInstance(RigidTransform(), Mesh(str(path)), "block")
    block.set_proximity_properties(props)
    model = plant.mutable_deformable_model()
    body_id = model.RegisterDeformableBody(block, config, 1.0)
    model.SetWallBoundaryCondition(body_id, [0.0, 0.0, -setup.depth_m + 1e-9], [0.0, 0.0, 1.0])
    R = setup.sphere_radius_m
    sphere = plant.AddRigidBody("sphere", SpatialInertia(0.01, np.zeros(3), UnitInertia.SolidSphere(R)))
    joint = plant.AddJoint(PrismaticJoint("z", plant.world_frame(), sphere.body_frame(), [0.0, 0.0, 1.0]))
    plant.AddJointActuator("z", joint).set_controller_gains(
        PdControllerGains(p=setup.kp, d=2.0 * math.sqrt(setup.kp * 0.01) * 20.0)
    )
    sphere_props = ProximityProperties()
    AddContactMaterial(dissipation=None, point_stiffness=None, friction=CoulombFriction(0.0, 0.0),
                       properties=sphere_props)  # fmt: skip
    AddRigidHydroelasticProperties(setup.sphere_resolution_m, sphere_props)
    plant.RegisterCollisionGeometry(sphere, RigidTransform(), Sphere(R), "sphere", sphere_props)
    plant.Finalize()
    target = builder.AddSystem(ConstantVectorSource(np.zeros(2)))
    builder.Connect(
        target.get_output_port(),
        plant.get_desired_state_input_port(plant.GetModelInstanceByName("DefaultModelInstance")),
    )
    diagram = builder.Build()
    simulator = Simulator(diagram)
    root = simulator.get_mutable_context()
    ctx = plant.GetMyMutableContextFromRoot(root)
    tctx = target.GetMyContextFromRoot(root)
    joint.set_translation(ctx, R)  # touching the top (z = 0)
    simulator.Initialize()
    out = {"depth_cmd_m": [], "depth_m": [], "force_contact_N": [], "force_actuator_N": [],
           "hertz_N": [], "layer_N": [], "contact_radius_m": []}  # fmt: skip
    start = time.perf_counter()
    t, previous = 0.0, 0.0
    for d_cmd in depths:
        steps = max(1, round(setup.ramp_s / setup.time_step_s))
        for k in range(1, steps + 1):  # ramp, then hold
            z = R - (previous + (d_cmd - previous) * k / steps)
            target.get_mutable_source_value(tctx).set_value([z, 0.0])
            t += setup.time_step_s
            simulator.AdvanceTo(t)
        t += setup.hold_s
        simulator.AdvanceTo(t)
        previous = d_cmd
        q, v = joint.get_translation(ctx), joint.get_translation_rate(ctx)
        results = plant.get_contact_results_output_port().Eval(ctx)
        f = sum(
            (
                results.deformable_contact_info(i).F_Ac_W().translational()
                for i in range(results.num_deformable_contacts())
            ),
            np.zeros(3),
        )
        depth = R - q
        out["depth_cmd_m"].append(d_cmd)
        out["depth_m"].append(depth)
        out["force_contact_N"].append(float(abs(f[2])))
        out["force_actuator_N"].append(
            float(setup.kp * (z - q) - 2.0 * math.sqrt(setup.kp * 0.01) * 20.0 * v)
        )
        out["hertz_N"].append(float(hertz_force(setup.youngs_modulus_pa, setup.poissons_ratio, R, depth)))
        out["layer_N"].append(
            out["hertz_N"][-1] * float(layer_correction(setup.poissons_ratio, R, depth, setup.depth_m))
        )
        out["contact_radius_m"].append(math.sqrt(R * depth))
    out["wall_s"] = time.perf_counter() - start
    out["vertices"], out["tetrahedra"] = len(V), len(T)
    out["setup"] = dataclasses.asdict(setup)
    out["error"] = [c / h - 1.0 for c, h in zip(out["force_contact_N"], out["hertz_N"], strict=True)]
    out["layer_error"] = [c / h - 1.0 for c, h in zip(out["force_contact_N"], out["layer_N"], strict=True)]
    return out


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--fine", type=float, default=0.5e-3, help="cell size near the axis (m)")
    parser.add_argument("--extent", type=float, default=3e-3, help="fine cells out to this radius (m)")
    parser.add_argument("--nu", type=float, default=0.45, help="Poisson's ratio")
    parser.add_argument("--depths", type=float, nargs="+", default=[0.25e-3, 0.5e-3, 1e-3])
    parser.add_argument("--size", type=float, default=0.02, help="block half width and depth (m)")
    parser.add_argument("--growth", type=float, default=1.6, help="cell growth past the fine region")
    parser.add_argument("--step", type=float, default=0.01, help="time step (s)")
    parser.add_argument("--sphere-resolution", type=float, default=0.25e-3, help="the sphere's mesh hint (m)")
    parser.add_argument("--json", type=Path, help="write the results here")
    args = parser.parse_args(argv)
    setup = IndentationSetup(fine_m=args.fine, fine_extent_m=args.extent, poissons_ratio=args.nu,
                             half_width_m=args.size, depth_m=args.size, growth=args.growth,
                             time_step_s=args.step, sphere_resolution_m=args.sphere_resolution)  # fmt: skip
    out = indent(setup, args.depths)
    rows = zip(out["depth_m"], out["force_contact_N"], out["force_actuator_N"], out["hertz_N"], out["error"],
               out["layer_N"], out["layer_error"], strict=True)  # fmt: skip
    for d, fc, fa, fh, e, fl, el in rows:
        print(
            f"d = {d * 1e3:.3f} mm: contact {fc * 1e3:.2f} mN, actuator {fa * 1e3:.2f} mN, "
            f"Hertz {fh * 1e3:.2f} mN ({e * 100:+.1f} %), bonded layer {fl * 1e3:.2f} mN ({el * 100:+.1f} %)"
        )
    print(f"{out['vertices']} vertices, {out['tetrahedra']} tetrahedra, {out['wall_s']:.1f} s")
    if args.json:
        args.json.write_text(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
