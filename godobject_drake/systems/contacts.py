"""What each tool touches, per plant step, from Drake's contact results: the force it applies to
everything else and whether two tools touch (:mod:`godobject_drake.task_metrics` folds them).

A tool is a set of bodies (an articulated tool's model; a rigid god-object's held body, which
changes as it grasps and lets go, read from its coupling's ``held_body``) and of deformable
geometries (a soft shell). Point contacts (``contact_force``: on body B), hydroelastic contacts
(``F_Ac_W``: on the body of the surface's geometry M) and deformable contacts (``F_Ac_W``: on the
deformable geometry A) all count: the force a tool applies to a body that is not its own is the
opposite of what that body applies to it.

A step where only rigid tools' held bodies are the tools (no fixed bodies, no shells) and at most
one tool holds a body (no two tools can touch) takes a shortcut: the held body's net contact force
is the force part of its model instance's generalized contact forces (the plant's
``generalized_contact_forces`` port, computed by Drake's contact solver), with no walk over the
contact list in Python (~35 µs a step for the brick scene's 33 point contacts).
``tests/test_task_metrics.py`` checks the two ways give the same rows.
"""

from __future__ import annotations

import dataclasses
import itertools

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.geometry import Role
from pydrake.multibody.plant import ContactResults, MultibodyPlant
from pydrake.systems.framework import BasicVector, LeafSystem

PER_TOOL = 4  # [fx, fy, fz, touching]: the net force (N, W) on the other bodies; 1 if a force is nonzero


@dataclasses.dataclass(frozen=True)
class ToolParts:
    """What a tool is made of, for :class:`ContactMeter`: its fixed bodies (BodyIndex values), its
    deformable geometries (GeometryId), and whether a held body joins them (a ``held_body`` input)."""

    bodies: frozenset = frozenset()
    deformable_geometries: frozenset = frozenset()
    holds: bool = False


class ContactMeter(LeafSystem):
    """Per step, each tool's net contact force on other bodies and whether it touches one (a
    contact with a nonzero force), then one 0/1 per pair of tools (in :meth:`pairs`' order): whether
    they touch. ``shortcut`` (module docstring) may be turned off to walk the contact list always.

    .. pydrake_system::

        name: ContactMeter
        input_ports:
        - contact_results
        - held_body_<tool> (one per tool that holds bodies)
        - generalized_contact_forces_<instance> (one per model instance with a free body, when a
          tool holds bodies)
        output_ports:
        - contacts
    """

    def __init__(self, plant: MultibodyPlant, scene_graph, parts: dict[str, ToolParts]):
        super().__init__()
        self.tools = list(parts)
        self.parts = parts
        self._results = self.DeclareAbstractInputPort("contact_results", AbstractValue.Make(ContactResults()))
        self._held = {
            name: self.DeclareVectorInputPort(f"held_body_{name or 'tool'}", 1)
            for name, p in parts.items()
            if p.holds
        }
        inspector = scene_graph.model_inspector()
        self._body_of = {}  # GeometryId → BodyIndex value, every rigid proximity geometry
        for gid in inspector.GetAllGeometryIds(Role.kProximity):
            if not inspector.IsDeformableGeometry(gid):
                self._body_of[gid] = int(plant.GetBodyFromFrameId(inspector.GetFrameId(gid)).index())
        self._fixed = {b: name for name, p in parts.items() for b in p.bodies}
        self._soft = {g: name for name, p in parts.items() for g in p.deformable_geometries}
        self._index = {name: k for k, name in enumerate(self.tools)}
        self._pairs = list(itertools.combinations(range(len(self.tools)), 2))
        self._free = {}  # a free body's BodyIndex value → (its instance's forces input, force offset)
        self.instance_ports: dict[int, str] = {}  # ModelInstanceIndex value → input port name
        if any(p.holds for p in parts.values()):
            everything = np.arange(plant.num_velocities(), dtype=float)
            for index in plant.GetFloatingBaseBodies():
                body = plant.get_body(index)
                instance = int(body.model_instance())
                name = f"generalized_contact_forces_{instance}"
                if instance not in self.instance_ports:
                    self.instance_ports[instance] = name
                    self.DeclareVectorInputPort(name, plant.num_velocities(body.model_instance()))
                local = list(plant.GetVelocitiesFromArray(body.model_instance(), everything))
                offset = local.index(float(body.floating_velocities_start_in_v() + 3))  # [w; v]: v's
                self._free[int(index)] = (self.GetInputPort(name), offset)
        self.shortcut = not self._fixed and not self._soft
        size = PER_TOOL * len(self.tools) + len(self._pairs)
        self.DeclareVectorOutputPort("contacts", BasicVector(size), self._calc)

    def pairs(self) -> list[tuple[str, str]]:
        """The pairs of tools, in the output's order."""
        return [(self.tools[i], self.tools[j]) for i, j in self._pairs]

    def columns(self, name: str) -> slice:
        """The tool ``name``'s ``[fx, fy, fz, touching]`` columns of the output."""
        k = self._index[name]
        return slice(PER_TOOL * k, PER_TOOL * k + PER_TOOL)

    def pair_columns(self, name: str) -> list[int]:
        """The output's columns of the pairs of tools ``name`` is in."""
        k, base = self._index[name], PER_TOOL * len(self.tools)
        return [base + n for n, (i, j) in enumerate(self._pairs) if k in (i, j)]

    def _owners(self, context) -> dict:
        owners = dict(self._fixed)
        for name, port in self._held.items():
            held = round(port.Eval(context)[0])
            if held >= 0:
                owners[held] = name
        return owners

    def _calc(self, context, output) -> None:
        owners = self._owners(context)
        n = len(self.tools)
        out = np.zeros(PER_TOOL * n + len(self._pairs))
        if not owners and not self._soft:  # rigid tools holding nothing: nothing to look at
            output.SetFromVector(out)
            return
        if self.shortcut and len(set(owners.values())) == 1 and all(b in self._free for b in owners):
            for body, name in owners.items():
                port, offset = self._free[body]
                f = -port.Eval(context)[offset : offset + 3]  # on the body: the tool applies its opposite
                k = PER_TOOL * self._index[name]
                out[k : k + 3] += f
                out[k + 3] = 1.0 if np.any(out[k : k + 3] != 0.0) else 0.0
            output.SetFromVector(out)
            return
        self._walk(self._results.Eval(context), owners, out)
        output.SetFromVector(out)

    def _walk(self, results, owners: dict, out: np.ndarray) -> None:
        """The contact list walked: each contact of a tool's body or shell with another body."""
        n = len(self.tools)
        touching = set()
        index = self._index

        def add(a, b, f_on_b):  # owners a and b (a tool's name or None); f: the force on b's side
            if a == b:
                return
            pushes = 1.0 if np.any(f_on_b != 0.0) else 0.0
            if a is not None:
                k = PER_TOOL * index[a]
                out[k : k + 3] += f_on_b
                out[k + 3] = max(out[k + 3], pushes)
            if b is not None:
                k = PER_TOOL * index[b]
                out[k : k + 3] -= f_on_b
                out[k + 3] = max(out[k + 3], pushes)
            if a is not None and b is not None:
                touching.add((min(index[a], index[b]), max(index[a], index[b])))

        pair_info = results.point_pair_contact_info
        for i in range(results.num_point_pair_contacts()):
            info = pair_info(i)
            a, b = owners.get(int(info.bodyA_index())), owners.get(int(info.bodyB_index()))
            if a is not None or b is not None:
                add(a, b, info.contact_force())
        for i in range(results.num_hydroelastic_contacts()):
            info = results.hydroelastic_contact_info(i)
            surface = info.contact_surface()
            a = owners.get(self._body_of.get(surface.id_M()))
            b = owners.get(self._body_of.get(surface.id_N()))
            if a is not None or b is not None:  # F_Ac_W is on M's body: B gets its opposite
                add(a, b, -info.F_Ac_W().translational())
        for i in range(results.num_deformable_contacts()):
            info = results.deformable_contact_info(i)
            a = self._soft.get(info.id_A())
            gid = info.id_B()
            b = self._soft.get(gid) or owners.get(self._body_of.get(gid))
            if a is not None or b is not None:  # F_Ac_W is on the deformable A
                add(a, b, -info.F_Ac_W().translational())
        base = PER_TOOL * n
        for m, pair in enumerate(self._pairs):
            out[base + m] = 1.0 if pair in touching else 0.0
