"""Sleeping bodies: cost that follows what moves (docs/guide/sleeping.md).

Drake has no automatic sleeping, but SAP drops the contact pairs of a *locked* tree against
anchored geometry or other locked trees (Drake PR 19349), so a free body that rests is cheap
once its floating joint is locked (``Joint.Lock``). Measured on the brick scene's plant at
h = 1 ms, every brick but the held one resting: 8 bricks 157 → 77 µs per step, 32 bricks
770 → 231 µs, 64 bricks 2 704 → 403 µs.

:class:`SleepManager` decides, every ``check_period_s`` of simulated time (10 ms), at a step
boundary and never per step:

- **asleep**: a free body that is not held, whose origin has moved slower than
  ``speed_m_s`` and turned slower than ``spin_rad_s`` for ``hold_s``, and that no *active*
  body can reach, is locked. Active bodies are the held one and every awake body that is not
  calm. Calm neighbours fall asleep together, so a resting stack sleeps as one.
- **reach**: an active body's bounding sphere grown by how far it can go before the next
  check: its speed × the check period, plus, for the held body, the coupling's capped
  acceleration × period² / 2, plus ``margin_m``. A sleeping body whose bounding sphere meets an
  active body's reach, or the device point's (so a body about to be grasped), is unlocked: it
  wakes before anything can touch it. A grasped sleeping body wakes at the next check.
- **out of the geometry query** (Drake 1.58 on, ``sleep.deactivate``): a sleeping body that no
  awake body can reach before the next check is deactivated in the SceneGraph context
  (``CollisionFilterManager.Deactivate``): no pair of the geometry query has it, so the query
  costs what the awake bodies cost. The reach here is every awake body's, calm ones too (a calm
  brick resting on a sleeping one touches it, and SAP keeps a pair with an unlocked side), grown
  by the largest acceleration the coupling can give a body (as if anything awake could be pushed
  as hard as the held body is pulled) or gravity's; a body is activated again when that reach
  meets it, and when it wakes, both at the check, before the next step. So the only pairs it
  leaves are pairs with both sides locked or anchored, which SAP drops anyway: the trajectory is
  the locked-only one bit for bit (Drake's proximity engine sorts the point pairs it returns, so
  the rest come in the same order; measured on every shipped variant and at 64 bricks).
  A call costs 4 µs for one brick and 0.75 ms for 63 at once (Drake 1.58, measured alone);
  with the reach test at each check it is about 2 % of the brick scene's CPU time at 8 bricks
  and 1 % at 64, where a transient filter declaration cost 20–370 ms a change (its table holds
  every geometry pair, ~700 000 at 64 bricks: docs/results.md, "The cost of a step and of
  changing its context").
  Older Drake has no ``Deactivate``: the query still finds a sleeping body's contacts and SAP
  drops them. The run's log says once which it is.

It runs with the safeguards' checks (:func:`~godobject_drake.safeguards.install_safeguards`: their
per-step monitor, or ``Safeguards.poll`` from ``simulate``'s loop at the same steps), the one place
that may change the plant's context between steps. Locking sets the body's
velocities to zero; unlocking leaves them at zero, which is what a resting body had.
"""

import dataclasses
import importlib.metadata
import logging
import math

import numpy as np
from pydrake.geometry import (
    Box,
    Capsule,
    CollisionFilterManager,
    Cylinder,
    Ellipsoid,
    GeometrySet,
    Role,
    Sphere,
)
from pydrake.math import RigidTransform
from pydrake.multibody.plant import MultibodyPlant
from pydrake.multibody.tree import JointIndex

from godobject_drake.config.scene import Sleep
from godobject_drake.systems.page import page_of, swatch

SLEEP_RGBA = (0.25, 0.45, 0.95, 0.9)
# Drake 1.58 added geometry (de)activation; 1.51 has neither method.
CAN_DEACTIVATE = hasattr(CollisionFilterManager, "Deactivate") and hasattr(CollisionFilterManager, "Activate")

logger = logging.getLogger("godobject_drake")


def drake_version() -> str:
    """The installed Drake's version (its distribution's metadata), or ``unknown``."""
    try:
        return importlib.metadata.version("drake")
    except importlib.metadata.PackageNotFoundError:
        return "unknown"


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
    radius: float  # of a sphere about Bo that holds its proximity geometry (m)
    geometries: tuple  # its proximity GeometryIds


class SleepManager:
    """Locks resting free bodies and wakes them before anything reaches them (module docstring).

    Parameters
    ----------
    plant, scene_graph :
        The finalized discrete plant and its SceneGraph.
    config : Sleep
        Checked (``check_scenario`` checks a scenario's; ``config.check()`` one made by hand).
    coupling : GodObjectCoupling | sequence of them | None
        Each tool's rigid coupling: its ``held_body`` and ``pose_WT`` say what it holds and where
        its device is; its force cap bounds how fast a held body can be pulled. None: no device.
    meshcat : Meshcat | None
        Draws a blue marker over each sleeping body (and into a recording).
    """

    def __init__(self, plant: MultibodyPlant, scene_graph, config: Sleep, coupling=None, meshcat=None):
        h = plant.time_step()
        if not h > 0.0:
            raise ValueError(f"sleeping bodies need a discrete plant (time_step={h!r} s)")
        self.plant, self.config = plant, config
        if coupling is None:
            self.couplings = ()
        elif isinstance(coupling, list | tuple):
            self.couplings = tuple(coupling)
        else:
            self.couplings = (coupling,)
        self.scene_graph = scene_graph
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
            radius = max(float(np.linalg.norm(c)) + r for c, r in spheres)  # about Bo
            self.bodies.append(
                _Body(
                    name=body.scoped_name().get_full(),
                    index=int(i),
                    joint=joints[int(i)],
                    q_start=body.floating_positions_start(),
                    v_start=nq + body.floating_velocities_start_in_v(),
                    radius=radius,
                    geometries=tuple(geometries),
                )
            )
        self._radius = np.array([b.radius for b in self.bodies])
        starts = np.array([[b.q_start, b.v_start] for b in self.bodies], int).reshape(-1, 2)
        self._p_index = starts[:, :1] + np.arange(4, 7)  # (n, 3) indices of each p_WBo in [q; v]
        self._w_index = starts[:, 1:] + np.arange(3)  # (n, 3) of its w_WB
        self._v_index = starts[:, 1:] + np.arange(3, 6)  # (n, 3) of its v_WBo
        self.reset()
        self._meshcat = meshcat
        self.held_accel = self._held_accel()
        self._index = np.array([b.index for b in self.bodies], int)
        self._pull = np.array([0.5 * self.held_accel.get(b.index, 0.0) for b in self.bodies])  # a/2
        g = float(np.linalg.norm(plant.gravity_field().gravity_vector()))
        # what an awake body's reach adds for the query: the margin and the largest pull (or g)
        # anything awake may get, as if it were pushed as hard as the held body is pulled
        self._reach_more = config.margin_m + 0.5 * max([g, *self.held_accel.values()]) * self.period_s**2
        self.deactivates = config.deactivate and CAN_DEACTIVATE
        if self.deactivates:
            logger.info(
                "sleeping bodies: locked, and out of the geometry query while nothing awake can reach "
                "them (Drake %s: CollisionFilterManager.Deactivate)",
                drake_version(),
            )
        elif config.deactivate:
            logger.info(
                "sleeping bodies: locked only, still in the geometry query (Drake %s has no "
                "CollisionFilterManager.Deactivate; Drake 1.58 has)",
                drake_version(),
            )
        else:
            logger.info("sleeping bodies: locked only, still in the geometry query (sleep.deactivate: false)")
        if meshcat is not None:
            if self.bodies:
                why = "blue ball: a body asleep (at rest, out of the simulation until touched)"
                page_of(meshcat).add("sleep", swatch(SLEEP_RGBA, "dot"), why)
            for b in self.bodies:
                meshcat.SetObject(f"/godobject/sleep/{b.name}", Sphere(0.0025), _rgba(SLEEP_RGBA))
                meshcat.SetProperty(f"/godobject/sleep/{b.name}", "visible", False)

    def reset(self) -> None:
        """Forget what slept: for a new context, where every body starts awake and unfiltered."""
        n = len(self.bodies)
        self.asleep = np.zeros(n, bool)
        self.inactive = np.zeros(n, bool)  # out of the geometry query (a subset of asleep)
        self.calm_s = np.zeros(n)
        self.checks = self.wakeups = self.sleeps = 0
        self.deactivations = self.activations = 0
        self._asleep_sum = 0

    def _held_accel(self) -> dict[int, float]:
        """The largest acceleration (m/s²) a coupling can give each body it may hold (with two
        tools that may hold one body, the larger)."""
        g = float(np.linalg.norm(self.plant.gravity_field().gravity_vector()))
        out = {}
        for coupling in self.couplings:
            for index, body in coupling._by_index.items():
                force_cap, _ = coupling.force_caps(body)
                out[int(index)] = max(out.get(int(index), 0.0), force_cap / body.mass + g)
        return out

    # -- the check ------------------------------------------------------------------------------
    def check(self, plant_context, root_context) -> None:
        """Put calm bodies to sleep and wake the ones something can reach (module docstring)."""
        cfg, P = self.config, self.period_s
        x = self.plant.GetPositionsAndVelocities(plant_context)
        centers = x[self._p_index]  # (n, 3): each body's sphere is about Bo
        v, w = x[self._v_index], x[self._w_index]
        speed, spin = np.sqrt(np.sum(v * v, axis=1)), np.sqrt(np.sum(w * w, axis=1))
        is_held = np.zeros(len(self.bodies), bool)
        points, reaches = [], []
        for coupling in self.couplings:
            # read off the coupling's state and the device's outputs: nothing here recomputes the
            # coupling's terms (a Lock or Unlock changes the plant's parameters: they would be stale)
            held, p_WD, v_WD = coupling.device_and_grasp(coupling.GetMyContextFromRoot(root_context))
            is_held |= self._index == held
            # the device point: where a grasp would take a body (within grasp_reach_m) if nothing is held
            points.append(p_WD)
            reaches.append(v_WD * P + cfg.margin_m + (coupling.grasp_reach_m if held < 0 else 0.0))
        calm = (speed < cfg.speed_m_s) & (spin < cfg.spin_rad_s) & ~is_held
        self.calm_s = np.where(calm | self.asleep, self.calm_s + P, 0.0)
        active = ~self.asleep & (~calm | is_held)
        # how far each active body's fastest point can go before the next check
        reach = self._radius + (speed + spin * self._radius) * P + cfg.margin_m + is_held * self._pull * P * P
        c, r = centers[active], reach[active]
        if points:
            c, r = np.vstack([c, *points]), np.append(r, reaches)
        d2 = np.sum((centers[:, None, :] - c[None, :, :]) ** 2, axis=2)  # (n, m)
        near = np.any(d2 < (self._radius[:, None] + r[None, :]) ** 2, axis=1) | is_held
        wake = self.asleep & near
        sleep = ~self.asleep & calm & (self.calm_s >= cfg.hold_s - 1e-9) & ~near
        t = plant_context.get_time()
        for k in np.flatnonzero(wake):
            self.bodies[k].joint.Unlock(plant_context)
            self.calm_s[k] = 0.0
            self._mark(k, False, t)
        for k in np.flatnonzero(sleep):
            self.bodies[k].joint.Lock(plant_context)
            self._mark(k, True, t, centers[k])
        self.asleep = (self.asleep & ~wake) | sleep
        if self.deactivates:
            self._leave_query(root_context, centers, speed, spin)
        self.wakeups += int(wake.sum())
        self.sleeps += int(sleep.sum())
        self.checks += 1
        self._asleep_sum += int(self.asleep.sum())

    def _leave_query(self, root_context, centers, speed, spin) -> None:
        """Deactivate the sleeping bodies no awake body can reach before the next check, and
        activate every other one that was deactivated (module docstring)."""
        asleep, awake = self.asleep, ~self.asleep
        out = asleep.copy()  # nothing awake: every sleeping body out
        if asleep.any() and awake.any():
            r, P = self._radius, self.period_s
            reach = r[awake] + (speed[awake] + spin[awake] * r[awake]) * P + self._reach_more
            rows = np.flatnonzero(asleep)
            d2 = np.sum((centers[rows, None, :] - centers[None, awake, :]) ** 2, axis=2)
            out[rows[np.any(d2 < (r[rows, None] + reach[None, :]) ** 2, axis=1)]] = False
        back, leave = self.inactive & ~out, out & ~self.inactive
        if not (back.any() or leave.any()):
            return
        sg = self.scene_graph
        manager = sg.collision_filter_manager(sg.GetMyMutableContextFromRoot(root_context))
        if back.any():
            manager.Activate(self._geometry_set(back))
            self.activations += int(back.sum())
        if leave.any():
            manager.Deactivate(self._geometry_set(leave))
            self.deactivations += int(leave.sum())
        self.inactive = out

    def _geometry_set(self, which: np.ndarray) -> GeometrySet:
        return GeometrySet([g for k in np.flatnonzero(which) for g in self.bodies[k].geometries])

    def draw_marks(self, t: float) -> None:
        """Each marker as its body is now, at time ``t`` of a recording just started: its first
        keyframe (else the viewer holds a marker's first sleep back to the recording's start)."""
        for k in range(len(self.bodies)):
            self._mark(k, bool(self.asleep[k]), t)

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
