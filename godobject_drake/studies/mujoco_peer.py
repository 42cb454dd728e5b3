"""The brick scene rebuilt in MuJoCo, dragged the two ways MuJoCo users drag objects.

    python -m godobject_drake.studies.mujoco_peer [--mode weld|perturb] [--time-step 0.001] [--duration 8.5]

A peer of the brick scene (``diagrams/lego.yaml``) for a speed-versus-error benchmark: the same
8 free 2x4 bricks on the same baseplate and wall (``models/lego/``), the same
device path (``models/lego/default_path.yaml``) sampled at ``device_rate_hz``
with a zero-order hold, and the same bandwidth of the grasp as Drake's
god-object coupling (ωn = 40 rad/s translation, ζ = 1). Units are SI
throughout: m, kg, s, rad; quaternions are ``[w, x, y, z]``.

Scene (what matches Drake, what does not):

- Bricks: boxes 31.8 x 15.8 x 9.6 mm, 2.3 g, the SDF's diagonal inertia,
  centre of mass at the box centre, free joints, resting at z = 4.8 mm.
  Drake's default ``--contact proxies`` touches through 12 inset 1 mm spheres
  per brick; MuJoCo collides the true boxes (box-box, up to 8 points).
- Baseplate (top face z = 0) and wall (8 x 200 x 48 mm at x = y = 0): boxes
  on the world body.
- Friction 0.5 on every geom (MuJoCo uses the larger of a pair's values);
  ``condim`` 3, so only sliding friction, as in Drake's point contact.
- Gravity 9.81 m/s² down; ``timestep`` = ``time_step_s``.
- Solver: MuJoCo's defaults (Newton, Euler integrator, contact
  ``solref = (0.02, 1)``, ``solimp = (0.9, 0.95, 0.001, 0.5, 2)``) except
  ``cone="elliptic"``: Drake's friction cone is the exact circular (Coulomb)
  cone, MuJoCo's default is a pyramid. On this path the elliptic cone is
  also the closer one: with ``"perturb"`` the brick stays pinned by friction
  against the wall's face while the device rises, as in Drake; with the
  pyramid it slides up and over the wall. (The pyramid sinks resting bricks
  less: 0.03 mm against 0.2 mm.) No ``noslip``: the held brick is pulled, not
  gripped by friction, so slip is not what is measured.

Modes (:data:`MODES`):

``"weld"``
    A mocap body is put at the device pose ``X_WD`` at each device sample.
    One weld equality constraint per brick (body1 = mocap, body2 = brick,
    all inactive at the start). When the device grasps a brick, the weld's
    ``relpose`` (``model.eq_data[i, 3:10]``: the brick's pose in the mocap
    frame, ``X_DB``) is set from the current state and ``data.eq_active[i]``
    is set, so grasping does not jump (as Drake stores ``X_DG``); ``""``
    clears it. Bandwidth mapping: a MuJoCo soft constraint with
    ``solref = (τ, ζ)`` and impedance ``d`` follows, with no other forces,
    ``ë = −d b ė − d k e`` with ``b = 2 / (dmax τ)`` and
    ``k = d / (dmax² τ² ζ²)``. At the default ``solimp`` (``d = dmax = 0.95``
    once the error passes its 1 mm width) that is ``ë = −(2/τ) ė − e/(τ ζ)²``:
    natural frequency ``1/(τ ζ)``, damping ratio ``ζ``. So
    ``solref = (1/ωn, 1) = (0.025 s, 1)`` is Drake's ``ωn = 40 rad/s``,
    ``ζ = 1`` (within 5 % for errors under 1 mm, where ``d`` falls to 0.9).
    What the weld cannot match: one ``solref`` serves all six rows, so the
    rotation has 40 rad/s, not Drake's ωr = 120 rad/s (``torquescale``
    rescales residual and Jacobian together and leaves this bandwidth as is);
    a mocap body has no velocity, so the damping pulls toward rest, not
    toward the target's velocity (a lag of ``2ζ v/ωn``, 6.7 mm at the path's
    0.13 m/s, where Drake lags by the zero-order hold only); there is no
    gravity compensation, but ``1 − d`` lets through only 5 % of gravity
    (a sag of 0.3 mm, not ``g/ωn²`` = 6 mm). ``timeconst`` must exceed
    ``2 h`` (MuJoCo's ``refsafe`` clamps it), i.e. ``h < 12.5 ms``.

``"perturb"``
    What ``simulate`` does on a Ctrl+right-drag, driven by the device instead
    of the mouse: ``mjvPerturb`` with ``select`` = the held brick,
    ``mjv_initPerturb`` at grasp time (it sets ``localmass`` from the inverse
    inertia at the selection point, here the brick's mass, and takes the
    reference pose from the body, so grasping does not jump), the reference
    moved with the device as ``refselpos``/``refpos`` = ``p_WT`` and
    ``refquat`` = ``q_WT`` (``T = X_WD X_DG``, ``X_DG`` stored at grasp,
    as Drake), ``active = mjPERT_TRANSLATE | mjPERT_ROTATE``, and before every
    ``mj_step``: clear ``data.xfrc_applied``, ``mjv_applyPerturbForce``.
    (``simulate`` also calls ``mjv_applyPerturbPose(..., 0)``, which only
    moves mocap bodies; with a free brick it does nothing, so it is left out.)
    ``localpos`` is the brick's centre of mass, so the force acts at G as in
    Drake. ``mjv_applyPerturbForce`` applies
    ``f = −m (ks e + √ks v_G)`` and ``τ = I (kr α u − √kr w_G)``, with
    ``ks = vis.map.stiffness``, ``kr = vis.map.stiffnessrot`` and ``I`` one
    scalar inertia (``1 / body_invweight0[:, 1]``: the inverse of the mean
    inverse principal inertia). The model sets ``ks = ωn² = 1600`` and
    ``kr = ωr² = 14400`` (``simulate``'s defaults are 100 and 500), so the
    bandwidths match Drake's; what cannot: the translational damping ratio
    is fixed at 0.5 (``√k`` where critical is ``2√k``), the damping pulls
    toward rest (a lag of ``v/ωn``), there is no gravity compensation (the
    held brick sags ``g/ωn²`` = 6.1 mm), and the scalar inertia gives each
    body axis its own rotational bandwidth ``ωr √(I/Ii)`` and damping ratio
    ``0.5 √(I/Ii)`` (1.38 ωr and 0.69 about the brick's long axis, 0.72 ωr
    and 0.36 about the vertical). Like ``simulate``, the wrench is computed
    from ``data.xpos``/``cvel`` as the last ``mj_step`` left them, i.e. the
    state one step old: an explicit, delayed spring, unstable from about
    h = 5 ms at these gains (the run then stops with ``diverged``).

What to expect at h = 1 ms: with the contacts' default ``solref`` (0.02 s),
a contact is about as soft as the weld, so the two split the error and the
weld pulls brick_0 through the 8 mm wall (by t ≈ 1.7 s); the perturbation
spring leaves it 2 mm into the wall. A contact ``solref`` of ``(2 h, 1)``
holds both at the wall (0.6 mm). Read the wall crossing from ``p_WB``:
MuJoCo's box-box depth never exceeds about the wall's thickness, so
``max_penetration_m`` understates a brick that went through.

Penetration is ``−min(contact.dist)`` over every contact of every step
(MuJoCo's box-box depth). ``wall_s_per_sim_s`` times the stepping loop only
(device sampling, the grasp, ``mj_step`` and recording), not compiling the
model. MuJoCo resets an unstable state to ``qpos0`` with a warning instead
of producing NaN, so a ``BADQACC``/``BADQPOS``/``BADQVEL`` warning counts as
divergence too.

Needs the optional ``mujoco`` package (``pip install -e .[bench]``): only this
module imports it, and only the speed report's MuJoCo rows import this module.
"""

from __future__ import annotations

import argparse
import math
import statistics
import sys
import time

import numpy as np

from godobject_drake.station.plant import brick_grid_positions

try:
    import mujoco
except ImportError as e:  # an optional extra, never a runtime dependency of godobject_drake
    raise ImportError(
        "godobject_drake.studies.mujoco_peer needs MuJoCo, which godobject_drake does not install. "
        "Install the benchmark extra: pip install -e .[bench]  (mujoco, mujoco-core and mujoco-studio 4.0.0)"
    ) from e

from godobject_drake.config.device_files import load_device_path
from godobject_drake.config.scenario import MODELS_DIR
from godobject_drake.devices.sources import ScriptedDevice
from godobject_drake.spatial import quat_conjugate, quat_multiply, quat_to_rotation

MODES = ("weld", "perturb")

DEVICE_PATH = MODELS_DIR / "lego" / "default_path.yaml"
BODY_NAMES = [f"brick_{i}" for i in range(8)]
CONES = ("elliptic", "pyramidal")

# Rest positions of the brick centres (m), as models/lego/lego.dmd.yaml (all unrotated).
BRICK_XYZ = [  # (list: brick_positions extends it)
    (-0.10, 0.0, 0.0048),
    (-0.06, 0.05, 0.0048),
    (-0.06, -0.05, 0.0048),
    (-0.10, 0.05, 0.0048),
    (-0.10, -0.05, 0.0048),
    (-0.14, 0.05, 0.0048),
    (-0.14, -0.05, 0.0048),
    (-0.14, 0.0, 0.0048),
]
BRICK_HALF_SIZE = (0.0159, 0.0079, 0.0048)  # m (31.8 x 15.8 x 9.6 mm)
BRICK_MASS = 0.0023  # kg
BRICK_INERTIA = (6.551167e-08, 2.114850e-07, 2.416687e-07)  # kg·m², principal, about the centre
FRICTION = 0.5
OMEGA_N = 40.0  # rad/s, Drake's translational coupling bandwidth (ζ = 1)
OMEGA_R = 120.0  # rad/s, Drake's rotational coupling bandwidth
DIVERGED_SPEED = 1000.0  # m/s or rad/s, as godobject_drake.safeguards
BAD_STATE_WARNINGS = ("mjWARN_BADQACC", "mjWARN_BADQPOS", "mjWARN_BADQVEL")


def brick_names(bricks: int = 8) -> list[str]:
    return [f"brick_{i}" for i in range(bricks)]


def brick_positions(bricks: int = 8) -> list[tuple[float, float, float]]:
    """The scene's 8 bricks, and more where Drake's ``--bricks`` puts them (a grid, in layers)."""

    if not (isinstance(bricks, int) and bricks >= 8):
        raise ValueError(f"bricks={bricks!r}: the brick scene has 8; give an integer ≥ 8")
    return BRICK_XYZ + brick_grid_positions(bricks - 8)


def scene_xml(
    time_step_s: float,
    mode: str,
    bricks: int = 8,
    contact_timeconst_s: float | None = None,
    cone: str = "elliptic",
    sleep: bool = False,
) -> str:
    """MJCF of the brick scene for ``mode``; see the module docstring for each setting.

    ``bricks``: 8, or more on Drake's grid. ``contact_timeconst_s``: every geom's contact
    ``solref`` time constant (s); None keeps MuJoCo's 0.02 s; MuJoCo's floor is 2 h (``refsafe``),
    the stiffest contact it allows. ``cone``: ``elliptic`` (Drake's circular cone) or ``pyramidal``.
    ``sleep``: MuJoCo's sleeping islands (``<flag sleep="enable"/>``, MuJoCo ≥ 3.4).
    """
    if cone not in CONES:
        raise ValueError(f"cone={cone!r}; choose one of {CONES}")
    if contact_timeconst_s is not None and not (
        math.isfinite(contact_timeconst_s) and contact_timeconst_s > 0
    ):
        raise ValueError(f"contact_timeconst_s={contact_timeconst_s!r} s must be > 0 (None: MuJoCo's 0.02 s)")
    names = brick_names(bricks)
    bricks_xml = []
    for name, (x, y, z) in zip(names, brick_positions(bricks), strict=True):
        bricks_xml.append(
            f'<body name="{name}" pos="{x} {y} {z}"><freejoint name="{name}"/>'
            f'<inertial pos="0 0 0" mass="{BRICK_MASS}" diaginertia="{" ".join(map(str, BRICK_INERTIA))}"/>'
            f'<geom name="{name}" type="box" size="{" ".join(map(str, BRICK_HALF_SIZE))}" '
            'rgba="0.85 0.1 0.1 1"/></body>'
        )
    mocap, welds = "", ""
    if mode == "weld":
        mocap = '<body name="device" mocap="true" pos="-0.1 0 0.0048"/>'
        solref = f"{1.0 / OMEGA_N} 1"
        rows = [
            f'<weld name="grasp_{n}" body1="device" body2="{n}" active="false" solref="{solref}"/>'
            for n in names
        ]
        welds = f"<equality>{''.join(rows)}</equality>"
    solref = "" if contact_timeconst_s is None else f' solref="{contact_timeconst_s!r} 1"'
    flag = '<flag sleep="enable"/>' if sleep else ""
    return f"""
<mujoco model="lego_bricks">
  <option timestep="{time_step_s!r}" gravity="0 0 -9.81" cone="{cone}">{flag}</option>
  <visual><map stiffness="{OMEGA_N**2}" stiffnessrot="{OMEGA_R**2}"/></visual>
  <default><geom friction="{FRICTION} 0.005 0.0001" condim="3"{solref}/></default>
  <worldbody>
    <geom name="baseplate" type="box" pos="0 0 -0.005" size="0.2 0.2 0.005" rgba="0.2 0.55 0.25 1"/>
    <geom name="wall" type="box" pos="0 0 0.024" size="0.004 0.1 0.024" rgba="0.6 0.6 0.65 1"/>
    {"".join(bricks_xml)}
    {mocap}
  </worldbody>
  {welds}
</mujoco>"""


def _check_args(duration_s, time_step_s, mode, device_rate_hz, sample_dt_s, repeats):
    if mode not in MODES:
        raise ValueError(f"mode={mode!r} is not a MuJoCo drag mode; choose one of {MODES}.")
    for label, value, unit in (
        ("duration_s", duration_s, "s"),
        ("time_step_s", time_step_s, "s"),
        ("device_rate_hz", device_rate_hz, "Hz"),
        ("sample_dt_s", sample_dt_s, "s"),
    ):
        try:
            ok = math.isfinite(float(value)) and float(value) > 0.0
        except (TypeError, ValueError):
            ok = False
        if not ok:
            raise ValueError(f"{label}={value!r} {unit} must be a finite number > 0; pass a positive value.")
    if time_step_s > duration_s:
        raise ValueError(
            f"time_step_s={time_step_s!r} s is longer than duration_s={duration_s!r} s, so no step "
            "would run; pass a time step ≤ the duration (e.g. 1e-3)."
        )
    if not (isinstance(repeats, int) and repeats >= 1):
        raise ValueError(f"repeats={repeats!r} must be an integer ≥ 1; pass e.g. repeats=3.")


def _world_angular_velocity(qpos: np.ndarray, qvel: np.ndarray) -> np.ndarray:
    """``w_WB`` (n, 3) from free-joint ``qvel``, whose angular part is in the body frame."""
    w, x, y, z = qpos[:, 3], qpos[:, 4], qpos[:, 5], qpos[:, 6]
    R = np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
            np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
            np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
        ],
        -2,
    )
    return np.einsum("nij,nj->ni", R, qvel[:, 3:])


class _Grasp:
    """The grasp of one mode: what changes when the device's grasp name or pose changes."""

    def __init__(self, model, data, mode: str, body_ids: dict[str, int]):
        self.model, self.data, self.mode, self.body_ids = model, data, mode, body_ids
        self.held = ""
        if mode == "weld":
            self.mocap = int(model.body_mocapid[model.body("device").id])
            self.eq_ids = {name: model.equality(f"grasp_{name}").id for name in body_ids}
        else:
            self.pert = mujoco.MjvPerturb()
            self.scene = mujoco.MjvScene(model, maxgeom=1)  # mjv_initPerturb reads its camera
            self.camera = mujoco.MjvCamera()
            mujoco.mjv_defaultFreeCamera(model, self.camera)
            mujoco.mjv_updateCamera(model, data, self.camera, self.scene)
            self.q_DG = np.array([1.0, 0.0, 0.0, 0.0])
            self.p_DG = np.zeros(3)

    def device(self, p_WD: np.ndarray, q_WD: np.ndarray, name: str) -> None:
        """A new device sample: move the target, grasp or release if ``name`` changed."""
        m, d = self.model, self.data
        if name and name not in self.body_ids:
            raise ValueError(
                f"the device grasps {name!r}; the bricks are {sorted(self.body_ids)}. Fix the path."
            )
        if self.mode == "weld":
            d.mocap_pos[self.mocap] = p_WD
            d.mocap_quat[self.mocap] = q_WD
            if name != self.held:
                if self.held:
                    d.eq_active[self.eq_ids[self.held]] = 0
                if name:
                    qpos = d.joint(name).qpos  # [x y z qw qx qy qz] of the brick frame B
                    eq = self.eq_ids[name]
                    m.eq_data[eq, 0:3] = 0.0  # anchor: the brick's origin
                    m.eq_data[eq, 3:6] = quat_to_rotation(q_WD).T @ (qpos[:3] - p_WD)  # p_DB
                    m.eq_data[eq, 6:10] = quat_multiply(quat_conjugate(q_WD), qpos[3:])  # q_DB
                    d.eq_active[eq] = 1
            self.held = name
            return
        pert = self.pert
        if name != self.held:
            pert.active = 0
            pert.select = -1
            if name:
                body = self.body_ids[name]
                pert.select = body
                pert.localpos = m.body_ipos[body]  # select the centre of mass G
                mujoco.mjv_initPerturb(m, d, self.scene, pert)
                q_WG = np.array(pert.refquat)
                self.q_DG = quat_multiply(quat_conjugate(q_WD), q_WG)
                self.p_DG = quat_to_rotation(q_WD).T @ (np.array(pert.refselpos) - p_WD)
                pert.active = int(mujoco.mjtPertBit.mjPERT_TRANSLATE | mujoco.mjtPertBit.mjPERT_ROTATE)
            self.held = name
        if self.held:
            p_WT = p_WD + quat_to_rotation(q_WD) @ self.p_DG
            pert.refselpos = p_WT  # what the spring pulls G to
            pert.refpos = p_WT  # moved with it, as mjv_movePerturb does (drawn by mjv_updateScene)
            pert.refquat = quat_multiply(q_WD, self.q_DG)

    def apply(self) -> None:
        """Before each step: the perturbation wrench, as ``simulate`` (weld: nothing to do)."""
        if self.mode == "perturb":
            self.data.xfrc_applied[:] = 0.0
            mujoco.mjv_applyPerturbForce(self.model, self.data, self.pert)


def _diagnosis(model, data, qvel: np.ndarray) -> str | None:
    """Why the state at ``data.time`` is unusable, or None."""
    t = data.time
    for w in BAD_STATE_WARNINGS:
        if data.warning[int(getattr(mujoco.mjtWarning, w))].number > 0:
            return f"MuJoCo warning {w} by t={t:.4f} s (MuJoCo reset the state)"
    if not (np.all(np.isfinite(data.qpos)) and np.all(np.isfinite(data.qvel))):
        return f"non-finite state at t={t:.4f} s"
    speed = float(np.max(np.abs(qvel)))
    if speed > DIVERGED_SPEED:
        return f"a brick speed reached {speed:.3g} (> {DIVERGED_SPEED:g} m/s or rad/s) at t={t:.4f} s"
    return None


def _run_once(model, path, mode, duration_s, h, device_rate_hz, sample_dt_s, names):
    """One run from rest: the recording, max penetration, loop wall time (s), diagnosis and the
    mean number of awake trees (MuJoCo's sleeping islands; every brick when sleep is off)."""
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    body_ids = {name: model.body(name).id for name in names}
    qadr = np.array([model.jnt_qposadr[model.joint(n).id] for n in names])
    vadr = np.array([model.jnt_dofadr[model.joint(n).id] for n in names])
    qidx, vidx = qadr[:, None] + np.arange(7), vadr[:, None] + np.arange(6)
    grasp = _Grasp(model, data, mode, body_ids)

    n_steps = round(duration_s / h)
    n_samples = math.floor(duration_s / sample_dt_s + 1e-9) + 1
    sample_step = [round(k * sample_dt_s / h) for k in range(n_samples)]
    qpos = np.full((n_samples, len(names), 7), np.nan)
    qvel = np.full((n_samples, len(names), 6), np.nan)
    max_pen, diagnosis, k, next_tick, awake = 0.0, None, 0, 0, 0

    wall0, cpu0 = time.perf_counter(), time.process_time()
    for j in range(n_steps + 1):
        while k < n_samples and sample_step[k] == j:
            qpos[k], qvel[k] = data.qpos[qidx], data.qvel[vidx]
            diagnosis = _diagnosis(model, data, qvel[k])
            k += 1
        if diagnosis or j == n_steps:
            break
        tick = math.floor(j * h * device_rate_hz + 1e-9)  # zero-order hold of the device
        if tick >= next_tick:
            p_WD, q_WD, name = path.path_sample(tick / device_rate_hz)
            grasp.device(p_WD, q_WD, name)
            next_tick = tick + 1
        grasp.apply()
        mujoco.mj_step(model, data)
        awake += data.ntree_awake
        if data.ncon:
            max_pen = max(max_pen, -float(data.contact.dist.min()))
    wall, cpu = time.perf_counter() - wall0, time.process_time() - cpu0
    return qpos[:k], qvel[:k], max_pen, (wall, cpu), data.time, diagnosis, awake / max(j, 1)


def run_mujoco(
    duration_s: float = 8.5,
    time_step_s: float = 1e-3,
    mode: str = "weld",
    device_rate_hz: float = 60.0,
    sample_dt_s: float = 0.01,
    repeats: int = 1,
    bricks: int = 8,
    contact_timeconst_s: float | None = None,
    cone: str = "elliptic",
    sleep: bool = False,
) -> dict:
    """Run the brick scene in MuJoCo on the default device path; see the module docstring.

    Parameters
    ----------
    duration_s : float
        Simulated time (s).
    time_step_s : float
        MuJoCo ``timestep`` h (s).
    mode : str
        ``"weld"`` (mocap body + weld constraint) or ``"perturb"`` (``simulate``'s drag spring).
    device_rate_hz : float
        Device sampling rate (Hz); the pose is held between samples.
    sample_dt_s : float
        Recording period (s); each sample is the state at the step nearest ``k * sample_dt_s``.
    repeats : int
        Runs from rest, each timed; the recording is the last run's (runs are deterministic).
    bricks, contact_timeconst_s, cone, sleep :
        The scene's settings (:func:`scene_xml`).

    Returns
    -------
    dict
        ``times`` (N,), ``body_names``, ``p_WB`` (N, 8, 3) m, ``q_WB`` (N, 8, 4) wxyz,
        ``v_WB`` (N, 8, 3) m/s of the centre, ``w_WB`` (N, 8, 3) rad/s in W,
        ``max_penetration_m``, ``wall_s_per_sim_s`` and ``cpu_s_per_sim_s`` (one per repeat: the
        loop's wall and CPU time over the simulated time reached, which is ``duration_s`` unless
        the run diverged),
        ``diverged``, ``diagnosis``, ``mujoco_version``, ``mode``, ``time_step_s``,
        ``mean_awake_trees`` (the last run's, per step).
        A diverged run stops at the first bad sample; the arrays end there.
    """
    _check_args(duration_s, time_step_s, mode, device_rate_hz, sample_dt_s, repeats)
    model = mujoco.MjModel.from_xml_string(
        scene_xml(time_step_s, mode, bricks, contact_timeconst_s, cone, sleep)
    )
    names = brick_names(bricks)
    path = ScriptedDevice(load_device_path(DEVICE_PATH).waypoints, period_s=1.0 / device_rate_hz)
    walls, cpus, max_pen = [], [], 0.0
    for _ in range(int(repeats)):
        qpos, qvel, pen, (wall, cpu), sim_time, diagnosis, awake = _run_once(
            model, path, mode, duration_s, time_step_s, device_rate_hz, sample_dt_s, names
        )
        max_pen = max(max_pen, pen)
        walls.append(wall / sim_time if sim_time > 0 else math.inf)
        cpus.append(cpu / sim_time if sim_time > 0 else math.inf)
        if diagnosis:
            break
    n = len(qpos)
    return {
        "times": np.arange(n) * sample_dt_s,
        "body_names": list(names),
        "p_WB": qpos[:, :, :3].copy(),
        "q_WB": qpos[:, :, 3:].copy(),
        "v_WB": qvel[:, :, :3].copy(),
        "w_WB": _world_angular_velocity(qpos.reshape(-1, 7), qvel.reshape(-1, 6)).reshape(n, len(names), 3),
        "max_penetration_m": max_pen,
        "wall_s_per_sim_s": walls,
        "cpu_s_per_sim_s": cpus,
        "diverged": diagnosis is not None,
        "diagnosis": diagnosis,
        "mujoco_version": mujoco.__version__,
        "mode": mode,
        "time_step_s": time_step_s,
        "mean_awake_trees": awake,
    }


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(
        description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--mode", choices=MODES, default="weld", help="how the device drags the brick")
    parser.add_argument("--time-step", type=float, default=1e-3, help="MuJoCo timestep h (s)")
    parser.add_argument("--duration", type=float, default=8.5, help="simulated time (s)")
    parser.add_argument("--repeats", type=int, default=3, help="timed runs; the median is printed")
    args = parser.parse_args(argv)
    try:
        r = run_mujoco(args.duration, args.time_step, args.mode, repeats=args.repeats)
    except ValueError as e:
        parser.error(str(e))
    p, q = np.round(r["p_WB"][-1, 0], 5).tolist(), np.round(r["q_WB"][-1, 0], 4).tolist()
    walls = r["wall_s_per_sim_s"]
    print(f"MuJoCo {r['mujoco_version']}, mode={r['mode']}, h={r['time_step_s']:g} s")
    print(f"brick_0 at t={r['times'][-1]:.3f} s: p = {p} m, q_wxyz = {q}")
    print(f"max penetration: {r['max_penetration_m'] * 1e3:.3f} mm")
    print(f"wall time per simulated second (median of {len(walls)}): {statistics.median(walls):.4f} s")
    if r["diverged"]:
        print(f"diverged: {r['diagnosis']}")
    return 1 if r["diverged"] else 0


if __name__ == "__main__":
    sys.exit(main())
