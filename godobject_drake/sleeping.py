"""Sleeping bodies: cost that follows what moves (README "Sleeping bodies").

Drake has no automatic sleeping, but SAP drops the contact pairs of a *locked* tree against
anchored geometry or other locked trees (Drake PR 19349), so a free body that rests is cheap
once its floating joint is locked (``Joint.Lock``). Measured on the brick scene's plant at
h = 1 ms, every brick but the held one resting: 8 bricks 157 → 77 µs per step, 32 bricks
770 → 231 µs, 64 bricks 2 704 → 403 µs.

:class:`SleepManager` decides, every ``check_period_s`` of simulated time (10 ms), at a step
boundary and never per step:

- **asleep**: a free body that is not held, whose centre of mass has moved slower than
  ``speed_m_s`` and turned slower than ``spin_rad_s`` for ``hold_s``, and that no *active*
  body can reach, is locked. Active bodies are the held one and every awake body that is not
  calm. Calm neighbours fall asleep together, so a resting stack sleeps as one.
- **reach**: an active body's bounding sphere grown by how far it can go before the next
  check: its speed × the check period, plus, for the held body, the coupling's capped
  acceleration × period² / 2, plus ``margin_m``. A sleeping body whose bounding sphere meets an
  active body's reach, or the device point's (so a body about to be grasped), is unlocked: it
  wakes before anything can touch it. A grasped sleeping body wakes at the next check.
- **filters**: pairs between two sleeping bodies, or between a sleeping body and welded
  geometry, are excluded in the SceneGraph context (a transient collision filter), so the
  geometry query skips them too.

It runs as part of the safeguards' monitor (:func:`~godobject_drake.safeguards.install_safeguards`),
the one place that may change the plant's context between steps. Locking sets the body's
velocities to zero; unlocking leaves them at zero, which is what a resting body had.
"""

import dataclasses
import math

import numpy as np
from pydrake.geometry import (
    Box,
    Capsule,
    CollisionFilterDeclaration,
    Cylinder,
    Ellipsoid,
    GeometrySet,
    Role,
    Sphere,
)
from pydrake.math import RigidTransform
from pydrake.multibody.plant import MultibodyPlant
from pydrake.multibody.tree import BodyIndex, JointIndex

from godobject_drake.spatial import quats_to_rotations

SLEEP_RGBA = (0.25, 0.45, 0.95, 0.9)


@dataclasses.dataclass
class Sleep:
    """When free bodies sleep (module docstring); ``enabled: false`` keeps every body awake.

    Attributes
    ----------
    enabled : bool
        Lock resting bodies (``--sleep on|off``).
    check_period_s : float
        Simulated time between checks (s), rounded to whole plant steps.
    speed_m_s, spin_rad_s : float
        A body slower than both, for ``hold_s``, is calm.
    hold_s : float
        How long a body must stay calm before it may sleep (s).
    margin_m : float
        Added to every reach (m).
    """

    enabled: bool = True
    check_period_s: float = 0.01
    speed_m_s: float = 0.002
    spin_rad_s: float = 0.05
    hold_s: float = 0.1
    margin_m: float = 0.005

    def check(self) -> None:
        """Raise ``ValueError`` naming a setting out of range."""
        for name, unit in (("check_period_s", "s"), ("speed_m_s", "m/s"), ("spin_rad_s", "rad/s")):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0.0):
                raise ValueError(f"sleep.{name}={value!r} {unit} must be > 0")
        for name in ("hold_s", "margin_m"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0.0):
                raise ValueError(f"sleep.{name}={value!r} must be ≥ 0")


def shape_radius(shape) -> float | None:
    """The radius of a sphere about the shape's origin that holds it; None for a mesh."""
    if isinstance(shape, Sphere):
        return shape.radius()
    if isinstance(shape, Box):
        return 0.5 * math.sqrt(shape.width() ** 2 + shape.depth() ** 2 + shape.height() ** 2)
    if isinstance(shape, Cylinder):
        return math.hypot(shape.radius(), 0.5 * shape.length())
    if isinstance(shape, Capsule):
        return shape.radius() + 0.5 * shape.length()
    if isinstance(shape, Ellipsoid):
        return max(shape.a(), shape.b(), shape.c())
    return None


@dataclasses.dataclass
class _Body:
    name: str
    index: int
    joint: object
    q_start: int
    v_start: int  # in [q; v]
    center_B: np.ndarray  # the bounding sphere's centre in B (m)
    radius: float
    frame: object  # its SceneGraph FrameId


class SleepManager:
    """Locks resting free bodies and wakes them before anything reaches them (module docstring).

    Parameters
    ----------
    plant, scene_graph :
        The finalized discrete plant and its SceneGraph.
    config : Sleep
    coupling : GodObjectCoupling | None
        The rigid coupling: its ``held_body`` and ``pose_WT`` say what is held and where the
        device is; its force cap bounds how fast the held body can be pulled. None: no device.
    meshcat : Meshcat | None
        Draws a blue marker over each sleeping body (and into a recording).
    """

    def __init__(self, plant: MultibodyPlant, scene_graph, config: Sleep, coupling=None, meshcat=None):
        config.check()
        h = plant.time_step()
        if not h > 0.0:
            raise ValueError(f"sleeping bodies need a discrete plant (time_step={h!r} s)")
        self.plant, self.scene_graph, self.config, self.coupling = plant, scene_graph, config, coupling
        self.every = max(1, round(config.check_period_s / h))
        self.period_s = self.every * h
        inspector = scene_graph.model_inspector()
        joints = {}
        for j in range(plant.num_joints()):
            joint = plant.get_joint(JointIndex(j))
            joints[int(joint.child_body().index())] = joint
        nq = plant.num_positions()
        self.bodies: list[_Body] = []
        for i in plant.GetFloatingBaseBodies():
            body = plant.get_body(i)
            if not body.has_quaternion_dofs():
                continue
            frame = plant.GetBodyFrameIdIfExists(i)
            geometries = inspector.GetGeometries(frame, Role.kProximity) if frame is not None else []
            if not geometries:
                continue  # nothing can touch it: sleeping would save nothing
            spheres = []
            for g in geometries:
                r = shape_radius(inspector.GetShape(g))
                if r is None:
                    spheres = []
                    break
                spheres.append((inspector.GetPoseInFrame(g).translation(), r))
            if not spheres:
                continue  # a mesh: no bounding sphere here, so it stays awake
            center = np.mean([c for c, _ in spheres], axis=0)
            radius = max(float(np.linalg.norm(c - center)) + r for c, r in spheres)
            self.bodies.append(
                _Body(
                    name=body.scoped_name().get_full(),
                    index=int(i),
                    joint=joints[int(i)],
                    q_start=body.floating_positions_start(),
                    v_start=nq + body.floating_velocities_start_in_v(),
                    center_B=center,
                    radius=radius,
                    frame=frame,
                )
            )
        self._radius = np.array([b.radius for b in self.bodies])
        self._center_B = np.array([b.center_B for b in self.bodies]).reshape(-1, 3)
        starts = np.array([[b.q_start, b.v_start] for b in self.bodies], int).reshape(-1, 2)
        self._q_index = starts[:, :1] + np.arange(7)  # (n, 7) indices of each body's q in [q; v]
        self._v_index = starts[:, 1:] + np.arange(6)  # (n, 6) of its v
        self._anchored = [plant.GetBodyFrameIdIfExists(BodyIndex(k)) for k in range(plant.num_bodies())
                          if plant.IsAnchored(plant.get_body(BodyIndex(k)))]  # fmt: skip
        self._anchored = [f for f in self._anchored if f is not None]
        self.reset()
        self._meshcat = meshcat
        self.held_accel = self._held_accel()
        if meshcat is not None:
            for b in self.bodies:
                meshcat.SetObject(f"/godobject/sleep/{b.name}", Sphere(0.0025), _rgba(SLEEP_RGBA))
                meshcat.SetProperty(f"/godobject/sleep/{b.name}", "visible", False)

    def reset(self) -> None:
        """Forget what slept: for a new context, where every body starts awake and unfiltered."""
        n = len(self.bodies)
        self.asleep = np.zeros(n, bool)
        self.calm_s = np.zeros(n)
        self.checks = self.wakeups = self.sleeps = 0
        self._asleep_sum = 0
        self._filter_id = None

    def _held_accel(self) -> dict[int, float]:
        """The largest acceleration (m/s²) the coupling can give each body it may hold."""
        if self.coupling is None:
            return {}
        g = float(np.linalg.norm(self.plant.gravity_field().gravity_vector()))
        out = {}
        for index, body in self.coupling._by_index.items():
            force_cap, _ = self.coupling.force_caps(body)
            out[int(index)] = force_cap / body.mass + g
        return out

    # -- the check ------------------------------------------------------------------------------
    def check(self, plant_context, root_context) -> None:
        """Put calm bodies to sleep and wake the ones something can reach (module docstring)."""
        cfg, P = self.config, self.period_s
        x = self.plant.GetPositionsAndVelocities(plant_context)
        n = len(self.bodies)
        q = x[self._q_index]  # (n, 7): [qw qx qy qz x y z] per body
        v = x[self._v_index]  # (n, 6): [w; v_Bo]
        R = quats_to_rotations(q[:, :4] / np.linalg.norm(q[:, :4], axis=1, keepdims=True))
        r = np.einsum("kij,kj->ki", R, self._center_B)  # the sphere's centre from Bo, in W
        centers = q[:, 4:] + r
        speed = np.linalg.norm(v[:, 3:] + np.cross(v[:, :3], r), axis=1)
        spin = np.linalg.norm(v[:, :3], axis=1)
        held, device = -1, None
        if self.coupling is not None:
            cc = self.coupling.GetMyContextFromRoot(root_context)
            held = int(self.coupling.GetOutputPort("held_body").Eval(cc)[0])
            p_T = self.coupling.GetOutputPort("pose_WT").Eval(cc)[4:]
            v_T = float(np.linalg.norm(self.coupling.GetOutputPort("V_WT").Eval(cc)[3:]))
            # the target: where a grasp would take a body (within grasp_reach_m) if nothing is held
            device = (p_T, v_T * P + cfg.margin_m + (self.coupling.grasp_reach_m if held < 0 else 0.0))
        is_held = np.array([b.index == held for b in self.bodies], bool)
        calm = (speed < cfg.speed_m_s) & (spin < cfg.spin_rad_s) & ~is_held
        self.calm_s = np.where(calm | self.asleep, self.calm_s + P, 0.0)
        active = ~self.asleep & (~calm | is_held)
        reach = self._radius + speed * P + cfg.margin_m
        for k in np.flatnonzero(is_held):
            reach[k] += 0.5 * self.held_accel.get(self.bodies[k].index, 0.0) * P * P
        reachers = [(centers[k], reach[k]) for k in np.flatnonzero(active)]
        if device is not None:
            reachers.append(device)
        near = np.zeros(n, bool)
        if reachers:
            c = np.array([c for c, _ in reachers])  # (m, 3)
            reach_r = np.array([r for _, r in reachers])  # (m,)
            d = np.linalg.norm(centers[:, None, :] - c[None, :, :], axis=2)  # (n, m)
            near = np.any(d < self._radius[:, None] + reach_r[None, :], axis=1)
        near |= is_held
        wake = self.asleep & near
        sleep = ~self.asleep & calm & (self.calm_s >= cfg.hold_s - 1e-9) & ~near
        changed = bool(wake.any() or sleep.any())
        t = plant_context.get_time()
        for k in np.flatnonzero(wake):
            self.bodies[k].joint.Unlock(plant_context)
            self.calm_s[k] = 0.0
            self._mark(k, False, t)
        for k in np.flatnonzero(sleep):
            self.bodies[k].joint.Lock(plant_context)
            self._mark(k, True, t, centers[k])
        self.asleep = (self.asleep & ~wake) | sleep
        self.wakeups += int(wake.sum())
        self.sleeps += int(sleep.sum())
        self.checks += 1
        self._asleep_sum += int(self.asleep.sum())
        if changed:
            self._filter(root_context)

    def _filter(self, root_context) -> None:
        """Exclude pairs among the sleeping bodies and the anchored geometry, in the SceneGraph context."""
        manager = self.scene_graph.collision_filter_manager(
            self.scene_graph.GetMyMutableContextFromRoot(root_context)
        )
        if self._filter_id is not None:
            manager.RemoveDeclaration(self._filter_id)
            self._filter_id = None
        frames = [b.frame for b, a in zip(self.bodies, self.asleep, strict=True) if a]
        if frames:
            group = GeometrySet(frames + self._anchored)
            self._filter_id = manager.ApplyTransient(CollisionFilterDeclaration().ExcludeWithin(group))

    def _mark(self, k: int, asleep: bool, t: float, center=None) -> None:
        if self._meshcat is None:
            return
        path = f"/godobject/sleep/{self.bodies[k].name}"
        if center is not None:
            above = center + np.array([0.0, 0.0, self._radius[k] + 0.004])
            self._meshcat.SetTransform(path, RigidTransform(above), t)
        self._meshcat.SetProperty(path, "visible", asleep, t)

    def result(self) -> dict:
        """``sleep_mean_bodies`` (over the checks), ``sleep_wakeups``, ``sleep_falls``, ``sleep_bodies``."""
        return {
            "sleep_bodies": len(self.bodies),
            "sleep_mean_bodies": self._asleep_sum / self.checks if self.checks else 0.0,
            "sleep_falls": self.sleeps,
            "sleep_wakeups": self.wakeups,
        }


def _rgba(values):
    from pydrake.geometry import Rgba

    return Rgba(*values)
