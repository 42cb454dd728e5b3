"""A pose device driving an articulated tool through a trocar (docs/guide/laparoscopy.md "From a
pose device").

A commodity haptic device reports a Cartesian pose; a laparoscopic instrument has joints: two
rotations of the trocar about the insertion point P (``yaw`` about P's x, then ``pitch`` about
the rotated y), the instrument's ``roll`` about its own axis and its ``insertion`` (the tip's
depth below P along the axis), then the jaws. :class:`TrocarKinematics` maps the device's pose,
taken as the instrument's tip (its position, and its twist about the instrument's axis as the
handle's roll), to those joints, and the joints' feedback forces back to a force and a torque at
the device (``Jᵀ f = τ``: the force does on the device's motion the work the joint forces do on
the joints'). :class:`PoseJointDevice` is the device adapter: a
:class:`~godobject_drake.devices.sources.JointDevice` whose samples are a pose device's, mapped;
the jaws open or close with the device's button (its grasp).

With the tip at ``p`` and the instrument's unit axis ``u`` (from the tip toward the handle), in P's
frame: ``p = −d u``, ``u = Rx(yaw) Ry(pitch) e_z = (sin pitch, −sin yaw cos pitch, cos yaw cos
pitch)``, so ``d = |p|``, ``pitch = asin(u_x)``, ``yaw = atan2(−u_y, u_z)``; the roll is the
twist about ``e_z`` of ``(R_WP Rx Ry)ᵀ R_device`` (its swing is the trocar's to decide).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from pydrake.math import RigidTransform
from pydrake.systems.framework import LeafSystem

from godobject_drake.devices.sources import DeviceSource, JointDevice
from godobject_drake.spatial import quat_to_rotation

TROCAR_JOINTS = ("yaw", "pitch", "insertion", "roll")


def _rx(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def _ry(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def _rz(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


class TrocarKinematics:
    """The trocar's kinematics about its pivot frame ``X_WP`` (module docstring); ``q`` is
    ``(yaw, pitch, insertion, roll)`` (rad, rad, m, rad)."""

    def __init__(self, X_WP: RigidTransform, min_insertion_m: float = 0.01):
        self.R_WP = X_WP.rotation().matrix()
        self.p_WP = X_WP.translation().copy()
        self.min_insertion_m = float(min_insertion_m)

    def forward(self, q) -> tuple[np.ndarray, np.ndarray]:
        """The tip's position and orientation in W at ``q``."""
        yaw, pitch, d, roll = (float(v) for v in q)
        R = self.R_WP @ _rx(yaw) @ _ry(pitch) @ _rz(roll)
        return self.p_WP + R @ np.array([0.0, 0.0, -d]), R

    def inverse(self, p_W, R_W, roll_near: float | None = None) -> np.ndarray:
        """``q`` putting the tip at ``p_W`` with the roll of ``R_W`` about the axis (the
        continuous choice nearest ``roll_near``: no 2π jump as the handle turns past ±π)."""
        v = self.R_WP.T @ (np.asarray(p_W, float) - self.p_WP)
        d = float(np.linalg.norm(v))
        if d == 0.0:
            raise ValueError("the tip is at the pivot: the instrument's direction is undefined")
        u = -v / d
        pitch = math.asin(min(max(u[0], -1.0), 1.0))
        yaw = math.atan2(-u[1], u[2])
        M = (self.R_WP @ _rx(yaw) @ _ry(pitch)).T @ np.asarray(R_W, float)
        roll = math.atan2(M[1, 0] - M[0, 1], M[0, 0] + M[1, 1])
        if roll_near is not None:
            roll = roll_near + math.remainder(roll - roll_near, 2.0 * math.pi)
        return np.array([yaw, pitch, d, roll])

    def jacobian(self, q) -> np.ndarray:
        """``∂p_tip/∂(yaw, pitch, insertion)`` in W (3×3); the roll does not move the tip."""
        yaw, pitch, d, _ = (float(v) for v in q)
        sy, cy, sp, cp = math.sin(yaw), math.cos(yaw), math.sin(pitch), math.cos(pitch)
        J = np.array([
            [0.0, -d * cp, -sp],
            [d * cy * cp, -d * sy * sp, sy * cp],
            [d * sy * cp, d * cy * sp, -cy * cp],
        ])  # fmt: skip
        return self.R_WP @ J

    def device_wrench(self, q, tau) -> np.ndarray:
        """``[τ_W; f_W]`` at the device from the joint forces ``tau`` on ``(yaw, pitch,
        insertion, roll)``: ``Jᵀ f = τ[:3]`` and the roll's torque about the axis. Zero closer to
        the pivot than ``min_insertion_m`` (J is singular at the pivot: ``τ/d`` grows without bound)."""
        q, tau = np.asarray(q, float), np.asarray(tau, float)
        if not (q[2] >= self.min_insertion_m and np.all(np.isfinite(tau)) and np.all(np.isfinite(q))):
            return np.zeros(6)
        f = np.linalg.solve(self.jacobian(q).T, tau[:3])
        axis = self.forward(q)[1][:, 2]
        return np.concatenate([tau[3] * axis, f])

    @classmethod
    def from_plant(cls, plant, model, pivot_body: str, tip_body: str, joints: Sequence[str],
                   min_insertion_m: float = 0.01) -> TrocarKinematics:  # fmt: skip
        """The pivot from the plant's ``pivot_body`` (its default pose), checked: Drake's forward
        kinematics of the tip body must equal :meth:`forward` at three configurations, else the
        model is not a trocar of this form and a ``ValueError`` says so."""
        context = plant.CreateDefaultContext()
        instance = plant.GetModelInstanceByName(model) if isinstance(model, str) else model
        model = plant.GetModelInstanceName(instance)
        pivot = plant.GetBodyByName(pivot_body, instance)
        tip = plant.GetBodyByName(tip_body, instance)
        kin = cls(plant.EvalBodyPoseInWorld(context, pivot), min_insertion_m)
        named = [plant.GetJointByName(name, instance) for name in joints]
        for q in ([0.3, -0.2, 0.08, 0.7], [-0.5, 0.4, 0.12, -2.0], [0.0, 0.0, 0.05, 0.0]):
            positions = plant.GetPositions(context).copy()
            for joint, value in zip(named, q, strict=True):
                positions[joint.position_start()] = value
            plant.SetPositions(context, positions)
            X = plant.EvalBodyPoseInWorld(context, tip)
            p, R = kin.forward(q)
            if np.linalg.norm(X.translation() - p) > 1e-9 or np.linalg.norm(X.rotation().matrix() - R) > 1e-9:
                raise ValueError(
                    f"god_object.pose_to_joints.joints: {list(joints)} of {model} do not move {tip_body} as "
                    f"a trocar about {pivot_body} (yaw about x, pitch about y, roll about z, insertion along "
                    f"−z: docs/guide/laparoscopy.md); at q = {q} Drake puts the tip at "
                    f"{X.translation().round(6).tolist()}, the trocar at {p.round(6).tolist()}: drive this "
                    "tool from a joint-space device instead"
                )
        return kin


class PoseJointDevice(JointDevice):
    """A pose device's samples as an articulated tool's joint samples (module docstring).

    Each sample of ``pose_device`` (its sampler, with its latency) is mapped by ``trocar`` to the
    trocar's joints, in ``device_joints`` order; each of ``jaw_joints`` turns by half of
    ``jaw_open_rad`` while the device's button (its grasp) is up, and closes (0) while it is down.
    A sample that is missing, invalid (the pose device's own checks: NaN, a non-unit quaternion),
    at the pivot, outside ``limits`` (the joints' ranges) or an absurd jump (the pose device's
    ``guard``: :meth:`_plausible`) is not used: the tool's target holds its last one, counted in
    ``pose_to_joints_held_samples``.
    """

    def __init__(
        self,
        pose_device: DeviceSource,
        trocar: TrocarKinematics,
        device_joints: Sequence[str],
        trocar_joints: Sequence[str],
        jaw_joints: Sequence[str] = (),
        jaw_open_rad: float = 0.6,
        limits: dict | None = None,
    ):
        self.pose_device, self.trocar = pose_device, trocar
        self.device_joints = tuple(device_joints)
        self._index = [self.device_joints.index(name) for name in trocar_joints]
        self._jaws = [self.device_joints.index(name) for name in jaw_joints]
        self.jaw_open_rad = float(jaw_open_rad)
        self.limits = {i: limits[name] for i, name in enumerate(trocar_joints) if name in (limits or {})}
        self.held = self.rejected_jumps = self.relocations = 0
        self._last: np.ndarray | None = None
        self._p_last: np.ndarray | None = None  # the tip position of the last accepted sample
        self._gap, self._candidates, self._candidate = 0, 0, None
        self._last = self._map(pose_device._sample(0.0), None)
        if self._last is None:
            first = pose_device._sample(0.0)
            at = None if first is None else np.round(first[0], 6).tolist()
            raise ValueError(
                f"the pose device's first sample (t = 0) at {at} m is "
                f"outside the trocar's reach (below the insertion point {self.trocar.p_WP.tolist()} within "
                f"the joints' limits {limits}): start the device (start_xyz, the path's first waypoint) "
                "where the instrument's tip can be"
            )
        super().__init__(self._value, self.device_joints, None, pose_device.period_s, 0.0)

    def _map(self, sample, last: np.ndarray | None) -> np.ndarray | None:
        """The joint values of one pose sample, or None when it cannot be used."""
        if sample is None or self.pose_device._problem(sample) is not None:
            return None
        p, q_wxyz, grasp = sample
        roll_near = None if last is None else float(last[self._index[3]])
        v = np.asarray(p, float) - self.trocar.p_WP
        if np.linalg.norm(v) < 1e-9:
            return None
        q4 = self.trocar.inverse(p, quat_to_rotation(np.asarray(q_wxyz) / np.linalg.norm(q_wxyz)), roll_near)
        for i, (lower, upper) in self.limits.items():
            if not lower <= q4[i] <= upper:
                return None
        out = np.zeros(len(self.device_joints))
        out[self._index] = q4
        out[self._jaws] = 0.0 if grasp else 0.5 * self.jaw_open_rad
        return out

    def _value(self, t: float) -> np.ndarray:
        sample = self.pose_device._sample(t)
        mapped = self._map(sample, self._last)
        if mapped is not None and not self._plausible(np.asarray(sample[0], float)):
            mapped = None
        if mapped is None:
            self.held += 1
            self._gap += 1
            return self._last
        self._last, self._p_last, self._gap = mapped, np.asarray(sample[0], float), 0
        return mapped

    def _plausible(self, p: np.ndarray) -> bool:
        """The pose device's jump guard (:class:`~godobject_drake.config.device_files.SampleGuard`)
        on the tip's position: farther from the last accepted than ``max_speed_m_s`` carries it
        is held back (``pose_to_joints_rejected_jumps``) until ``confirm_samples`` samples agree
        at the new place (``pose_to_joints_relocations``)."""
        guard = self.pose_device.guard
        step = guard.max_speed_m_s * self.period_s
        if self._p_last is None or np.linalg.norm(p - self._p_last) <= step * (self._gap + 1):
            self._candidates = 0
            return True
        agrees = self._candidates > 0 and np.linalg.norm(p - self._candidate) <= step
        self._candidates = self._candidates + 1 if agrees else 1
        self._candidate = p
        if self._candidates >= guard.confirm_samples:
            self.relocations += 1
            self._candidates = 0
            return True
        self.rejected_jumps += 1
        return False

    def samples(self, duration_s: float) -> np.ndarray:
        """The pose device's samples known before the run (a script's, an LCM device's start),
        mapped; one that cannot be used repeats the last."""
        rows, last = [], self._map(self.pose_device._sample(0.0), None)
        for _, sample in self.pose_device.samples(duration_s):
            mapped = self._map(sample, last)
            last = last if mapped is None else mapped
            rows.append(last)
        return np.array(rows)

    def status(self, context) -> dict:
        out = {
            "pose_to_joints_held_samples": self.held,
            "pose_to_joints_rejected_jumps": self.rejected_jumps,
            "pose_to_joints_relocations": self.relocations,
        }
        if hasattr(self.pose_device, "lcm_status"):
            out.update(self.pose_device.lcm_status())
        return out

    def zero_feedback(self, t: float) -> bool:
        """The pose device's: a real device is sent the zero wrench."""
        return self.pose_device.zero_feedback(t)

    def connect_joint_feedback(self, builder, tau_device_port, q_device_port, tau_at: Sequence[int]):
        """The joint forces (``tau_device``; the trocar joints' at ``tau_at`` in it) to the device's
        wrench (:class:`TrocarFeedback`), rendered by the pose device when it renders feedback itself."""
        feedback = builder.AddNamedSystem(
            "trocar_feedback",
            TrocarFeedback(self.trocar, len(self.device_joints), self._index, tau_at, tau_device_port.size()),
        )
        builder.Connect(tau_device_port, feedback.GetInputPort("tau_device"))
        builder.Connect(q_device_port, feedback.GetInputPort("q_device"))
        self.pose_device.connect_feedback(builder, feedback.GetOutputPort("F_Do_W"), set())
        return feedback


class TrocarFeedback(LeafSystem):
    """The articulated feedback's joint forces to a pose device's wrench ``F_Do_W`` (``[τ; f]``
    in W, as the rigid tool's): :meth:`TrocarKinematics.device_wrench`."""

    def __init__(
        self, trocar: TrocarKinematics, n_q: int, q_at: Sequence[int], tau_at: Sequence[int], n_tau: int
    ):
        super().__init__()
        self.trocar = trocar
        self._q_at, self._tau_at = list(q_at), list(tau_at)  # (yaw, pitch, insertion, roll) in each
        self._tau = self.DeclareVectorInputPort("tau_device", n_tau)
        self._q = self.DeclareVectorInputPort("q_device", n_q)
        self.DeclareVectorOutputPort("F_Do_W", 6, self._calc)

    def _calc(self, context, output):
        q = self._q.Eval(context)[self._q_at]
        tau = self._tau.Eval(context)[self._tau_at]
        output.SetFromVector(self.trocar.device_wrench(q, tau))


__all__ = ["TROCAR_JOINTS", "PoseJointDevice", "TrocarFeedback", "TrocarKinematics"]
