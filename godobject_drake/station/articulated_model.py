"""The local model of an articulated tool driven by a pose device through a trocar, on a driver
link (docs/local_model.md "An articulated tool"; issue 53).

The device's point is the instrument's tip (:mod:`godobject_drake.devices.trocar`): the target
``p_T`` is the tip of the device's joints, the god-object's point ``p_G`` the tip of the tool's
own. The feedback (paper Eq. 8) pulls each coupled body's centre of mass toward its target,
``fᵢ = kd (xᵢ − x_Tᵢ)`` (and ``kd_rot`` on its rotation), and the device gets the force that
does the joints' work, ``Jᵀ f = τ`` with ``J = ∂p_tip/∂(yaw, pitch, insertion)``. For a small
stretch ``e = p_G − p_T`` of the tip the joints move ``J⁻¹ e`` and the body ``i`` by
``Jᵢ J⁻¹ e``, so the device's force is ``K e`` with

    K = J⁻ᵀ (Σᵢ Jᵢᵀ diag(kd_rot, kd) Jᵢ) J⁻¹

(:func:`lever_matrices`): the trocar's lever. Along the tube every body moves with the tip
(the insertion); across it a body at ``rᵢ`` from the pivot moves ``rᵢ/d`` of the tip's motion
(reversed above the pivot), so ``K`` is stiffer along the tube than across it: a matrix, sent
as the ``GLM3`` payload, and the damping ``D`` the same with ``γd``, ``γd_rot``.

The planes: the FEM organ (``organs.model: fem``) under the tool's tip, where the tube's axis
meets its rest surface (:func:`~godobject_drake.systems.tissue_stiffness.ray_surface_hit`), a
plane through it for the tool's furthest point along the axis, published while that point is
within :data:`TISSUE_MARGIN_M` of it (the rest surface does not move: the plane is true before
the scene's tip gets there, so the driver's proxy meets the tissue as the hand does, however
far the slow scene's tip lags); its stiffness the tissue's there from the FEM model
(``analyze``'s :func:`~godobject_drake.systems.tissue_stiffness.contact_stiffness`, its
matrix factorised once), so the
driver's proxy sinks into it as the tool's tip sinks into the tissue.

The lag: while the tip is clear of that plane (more than
:data:`~godobject_drake.driver.local_model.ACTIVE_M` above it) and the jaws hold nothing, the
tool touches nothing the model states, so its whole stretch is the coupling's free lag
(published as ``lag``: no force); on or in it, none; while the jaws hold a site, none either:
the stretch is the held tissue's pull (the driver renders it as the free part, a constant
force the energy budget pays for, as the rigid tool's held body's weight). Rigid organs
publish no plane and no lag (not built: the stretch is then rendered as the free part,
re-anchored each model and paid for by the driver's energy budget, as the held wrench renders
it).
"""

from __future__ import annotations

import math
import time

import numpy as np
from pydrake.math import RigidTransform, RotationMatrix
from pydrake.multibody.tree import BodyIndex
from pydrake.systems.framework import LeafSystem

from godobject_drake.link.messages import ALIVE_CHANNEL, LOCAL_MODEL_CHANNEL, LocalModel
from godobject_drake.link.scene_model import LOCAL_MODEL_MIN_PERIOD_S, SceneHeartbeat
from godobject_drake.systems.tissue import tool_capsules
from godobject_drake.systems.tissue_stiffness import OrganCompliance, ray_surface_hit

TISSUE_MARGIN_M = 0.05  # the organ's plane is published this far ahead of the tool (its size)
CLEAR_M = 1e-4  # the tip farther than this above the organ's plane touches nothing (the driver's ACTIVE_M)


def lever_matrices(tool, trocar, q_device, q4, v_trocar, gains) -> tuple[np.ndarray, np.ndarray]:
    """The feedback's stiffness and damping at the tip, in W (module docstring): ``K = J⁻ᵀ Kq J⁻¹``
    with ``Kq = Σ Jᵢᵀ diag(kd_rot I, kd I) Jᵢ`` over the trocar's velocities ``v_trocar`` (yaw,
    pitch, insertion), the centre-of-mass Jacobians of the device's configuration ``q_device``
    (as the feedback takes them), ``J`` the trocar's at ``q4``; ``D`` the same with the dampings.
    Symmetrised (rounding). Zero closer to the pivot than the trocar's ``min_insertion_m``, as the
    wrench the trocar maps there (``J`` is singular at the pivot: ``K`` grows as ``1/d²``)."""
    if not float(q4[2]) >= trocar.min_insertion_m:
        return np.zeros((3, 3)), np.zeros((3, 3))
    Js = [J[:, v_trocar] for J in tool.com_jacobians(np.asarray(q_device, float))]
    J_inv = np.linalg.inv(trocar.jacobian(q4))
    out = []
    for rot, lin in ((gains.kd_rot, gains.kd), (gains.gamma_d_rot, gains.gamma_d)):
        weights = np.array([rot] * 3 + [lin] * 3)
        Kq = sum(J.T @ (weights[:, None] * J) for J in Js)
        K = J_inv.T @ Kq @ J_inv
        out.append(0.5 * (K + K.T))
    return out[0], out[1]


class TissuePlane:
    """The FEM organ's plane under the tool's tip (module docstring), with the tissue's stiffness
    there from the FEM model (:class:`~godobject_drake.systems.tissue_stiffness.OrganCompliance`)."""

    def __init__(self, organ, plant, scene_graph, model):
        self.organ, self.plant = organ, plant
        self.capsules = tool_capsules(plant, scene_graph, model)
        # the organ's stiffness matrix assembled and factorised now, not at the first contact:
        # contact_stiffness's sparse solve costs 4 (4 cells) to 25 ms (8 cells) a point, 20 to
        # 150 ms the first (measured), each a hold-up of the scene's loop
        self.compliance = OrganCompliance(organ)

    def reach(self, context, p_W: np.ndarray, d: np.ndarray) -> float:
        """How far past the tip's origin ``p_W`` the tool reaches along the axis ``d`` (its
        capsules' ends and radii) in the plant ``context``."""
        reach = -math.inf
        for index, X_BG, r, half in self.capsules:
            X_WG = self.plant.EvalBodyPoseInWorld(context, self.plant.get_body(BodyIndex(index))) @ X_BG
            for end in (-half, half):
                reach = max(
                    reach, float((X_WG.translation() + end * X_WG.rotation().matrix()[:, 2] - p_W) @ d) + r
                )
        return reach

    def plane(self, context, p_W: np.ndarray, d: np.ndarray):
        """``(point, normal, stiffness)`` in W for the tip's origin, or None: the axis misses the
        organ, or the tool's furthest point is farther than the margin from its rest surface."""
        organ = self.organ
        back = float(np.max(np.linalg.norm(organ.rest_W - p_W, axis=1))) + 0.01
        hit = ray_surface_hit(organ.rest_W, organ.triangles, p_W - back * d, d)
        if hit is None:
            return None
        t, tri, w, normal = hit
        surface = p_W + (t - back) * d
        point = surface - self.reach(context, p_W, d) * d  # the tip's origin when the tool touches
        if float(normal @ (p_W - point)) > TISSUE_MARGIN_M:
            return None
        return point, normal, self.compliance.stiffness(tri, w, d)


class ArticulatedModelPublisher(LeafSystem):
    """The articulated tool's local model (module docstring) every device period, at most every
    :data:`~godobject_drake.link.scene_model.LOCAL_MODEL_MIN_PERIOD_S` of simulated time, on the
    driver link of ``lcm_device`` (an :class:`~godobject_drake.devices.lcm.LcmDevice`), in its
    frame; its heartbeat as the rigid tool's. Inputs: ``q_device`` (the mapped device's joints:
    the target) and the plant's ``state``."""

    def __init__(self, lcm_device, pose_joints, tool, gains, tissue: TissuePlane | None, grasp=None):
        super().__init__()
        self.device, self.tool, self.gains, self.tissue = lcm_device, tool, gains, tissue
        self.grasp = grasp  # the jaws' JawHold (station.articulated_tool), or None
        self.trocar = pose_joints.trocar
        plant = tool.plant
        self.plant = plant
        self._q_at = list(pose_joints._index)  # (yaw, pitch, insertion, roll) in q_device
        q_device_plant = list(tool.q_device)
        self._q_plant = [q_device_plant[i] for i in self._q_at]  # the same in the plant's q
        v_device = list(tool.v_device)
        self._v_trocar = [v_device[i] for i in self._q_at[:3]]  # yaw, pitch, insertion in the plant's v
        X = lcm_device.X_WDev or RigidTransform()
        self._R_DevW = X.rotation().matrix().T
        self._p_WDev = X.translation().copy()
        self._scale = lcm_device.scale
        self._q_device = self.DeclareVectorInputPort("q_device", tool.nq_device)
        self._state = self.DeclareVectorInputPort("state", plant.num_multibody_states())
        period = pose_joints.period_s
        # at most every 4 ms of simulated time, and no more often than the plant steps (between
        # two steps nothing the model states changes)
        least = max(LOCAL_MODEL_MIN_PERIOD_S, plant.time_step())
        self.every = max(1, math.ceil(least / period - 1e-9))
        self.period_s = self.every * period
        self._ticks = 0
        self.DeclarePeriodicPublishEvent(period, 0.0, self._publish)
        self.published, self.seconds, self.throttle = 0, 0.0, None
        self.heartbeat = SceneHeartbeat(lambda raw: lcm_device.lcm.Publish(ALIVE_CHANNEL, raw))

    def _to_dev(self, p_W) -> tuple:
        return tuple((self._R_DevW @ (np.asarray(p_W, float) - self._p_WDev)) / self._scale)

    def model(self, context) -> LocalModel:
        """The model now (module docstring)."""
        q_device = self._q_device.Eval(context)
        x = self._state.Eval(context)
        nq = self.plant.num_positions()
        q4_T, q4_G = q_device[self._q_at], x[self._q_plant]
        p_T, _ = self.trocar.forward(q4_T)
        p_G, R_G = self.trocar.forward(q4_G)
        v_G = self.trocar.jacobian(q4_G) @ x[nq:][self._v_trocar]
        K_W, D_W = lever_matrices(self.tool, self.trocar, q_device, q4_T, self._v_trocar, self.gains)
        R, s2 = self._R_DevW, self._scale**2
        K, D = s2 * R @ K_W @ R.T, s2 * R @ D_W @ R.T
        planes, lag = (), (0.0, 0.0, 0.0)
        if self.tissue is not None:
            ctx = self.tool.set_device_state(x[:nq][self.tool.q_device], None, x)
            found = self.tissue.plane(ctx, p_G, -R_G[:, 2])
            if found is not None:
                point, normal, k = found
                planes = ((self._to_dev(point), tuple(R @ normal), s2 * k),)
                holding = self.grasp is not None and bool(self.grasp.holding)
                if float(normal @ (p_G - point)) > CLEAR_M and not holding:  # clear: all of it lag
                    lag = tuple(R @ (p_G - p_T) / self._scale)
        q = (RotationMatrix(R) @ RotationMatrix(R_G)).ToQuaternion().wxyz()
        kd, gamma_d = (float(np.linalg.eigvalsh(M)[-1]) for M in (K, D))  # the stiffest direction's
        return LocalModel(
            scene_utime=round(context.get_time() * 1e6), pose_utime=self.device.receiver._last_utime or 0,
            period_s=self.period_s, kd=kd, gamma_d=gamma_d,
            kd_rot=0.0, gamma_d_rot=0.0, p_G=self._to_dev(p_G), v_G=tuple(R @ v_G / self._scale),
            q_G=tuple(q / np.linalg.norm(q)), w_G=(0.0, 0.0, 0.0), p_T=self._to_dev(p_T), lag=lag,
            planes=planes,
            stiffness=tuple(K.ravel().tolist()), damping=tuple(D.ravel().tolist()),
        )  # fmt: skip

    def _publish(self, context):
        self._ticks += 1
        if (self._ticks - 1) % self.every != 0:
            return
        start = time.perf_counter()
        model = self.model(context)
        self.device.lcm.Publish(LOCAL_MODEL_CHANNEL, model.encode())
        self.heartbeat.model_sent(model.scene_utime, time.monotonic())
        self.seconds += time.perf_counter() - start
        self.published += 1


def add_articulated_model(builder, scene, lcm_device, pose_joints, god) -> ArticulatedModelPublisher:
    """The articulated tool's local model for a pose device on a driver link (module docstring):
    the publisher, reading the mapped device's joints and the plant's state; the FEM organ's
    plane when the scene has one. The LCM device reports its cost and stops its heartbeat as it
    does the rigid tool's (``local_publisher``)."""
    tissue = None
    if god.tissue is not None:
        tissue = TissuePlane(god.tissue, scene.plant, scene.scene_graph, god.tool.model)
    publisher = builder.AddNamedSystem(
        "local_model_publisher",
        ArticulatedModelPublisher(lcm_device, pose_joints, god.tool, god.feedback.gains, tissue, god.grasp),
    )
    builder.Connect(pose_joints.GetOutputPort("q_device"), publisher.GetInputPort("q_device"))
    builder.Connect(scene.plant.get_state_output_port(), publisher.GetInputPort("state"))
    lcm_device.local_publisher = publisher
    return publisher


__all__ = ["ArticulatedModelPublisher", "TissuePlane", "add_articulated_model", "lever_matrices"]
