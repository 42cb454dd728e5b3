"""Live devices: drive a scene's target from the browser (Meshcat).

``--device meshcat`` on every scene uses these (docs/guide/live.md).
They are ordinary device sources, sampled at the device rate through the
same :class:`~godobject_drake.devices.sources.SampleGuard`, so a live run is the loop
of a scripted one with a human in it:

- :class:`MeshcatDevice` (pose devices: bricks, deformable probe): Drake's
  ``MeshcatPoseSliders`` (roll, pitch, yaw, x, y, z sliders, with its keyboard
  bindings Q/E, S/W, A/D for roll/pitch/yaw and J/L, K/I, U/O for x/y/z), a
  gamepad if the browser sees one (left stick x/y, right stick z, button 0
  = grasp), and a **Grasp / release** button (Space). Grasp takes the free
  body nearest the device point (``"*"``, within the coupling's reach).
- :class:`MeshcatJointDevice` (joint-space interfaces: the laparoscope):
  one slider per channel, each with a key pair.

Both add a **Stop** button (Escape) that ends the run.

In a scene of several tools each live device names its controls by its tool (``tool``): the
sliders ``left_x``, ``left_yaw``, ..., the button ``left: Grasp / release``, so each tool is
driven on its own. The keys and the gamepad drive the first live device added to the page; the
others are driven by their sliders and buttons (one key pressed must not move two tools).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from pydrake.geometry import Meshcat
from pydrake.math import RigidTransform
from pydrake.visualization import MeshcatPoseSliders

from godobject_drake.config.device_files import DEFAULT_DEVICE_RATE_HZ, RelativeAids, SampleGuard
from godobject_drake.config.gains import GRASP_NEAREST
from godobject_drake.devices.sources import DeviceSource, JointDevice
from godobject_drake.spatial import pose_arrays

STOP_BUTTON = "Stop"
GRASP_BUTTON = "Grasp / release"
GAMEPAD_SPEED_M_S = 0.1  # full stick deflection
GAMEPAD_DEADZONE = 0.15


def stop_requested(meshcat: Meshcat) -> bool:
    """True once the Stop button (or Escape) has been pressed."""
    return meshcat.GetButtonClicks(STOP_BUTTON) > 0


def add_stop_button(meshcat: Meshcat) -> None:
    if STOP_BUTTON not in meshcat.GetButtonNames():
        meshcat.AddButton(STOP_BUTTON, "Escape")


def keys_are_free(meshcat: Meshcat) -> bool:
    """No live device is on the page yet (each adds Stop): this one takes the keys and the gamepad."""
    return STOP_BUTTON not in meshcat.GetButtonNames()


def grasp_button(tool: str = "") -> str:
    """The grasp button's name: ``Grasp / release``, ``left: Grasp / release`` for the tool left."""
    return f"{tool}: {GRASP_BUTTON}" if tool else GRASP_BUTTON


class MeshcatDevice(DeviceSource):
    """A pose device driven from the browser: sliders and keys, gamepad, grasp button.

    The user moves the target by steps (keys, a slider, the stick), so it is an increment
    device: a tether and a control/display ratio (``aids``, :class:`RelativeAids`) act on the
    steps; the sliders then show the device, not the target.

    Parameters
    ----------
    meshcat : Meshcat
        The scene's Meshcat (the page the user has open).
    X_WD0 : RigidTransform
        Where the device starts.
    workspace : tuple of two 3-vectors
        Lower and upper corners (m) of the sliders' x, y, z range.
    grasp : str | None
        None: the grasp button toggles between ``""`` and ``"*"`` (nearest
        body). A name: the device always holds that body (the deformable
        probe's core) and no button is added.
    period_s, latency_s, guard, interpolation :
        As for :class:`~godobject_drake.devices.sources.DeviceSource`.
    step_m : float
        Slider and key step (m); rotation steps are 0.05 rad.
    tool : str
        The tool it drives in a scene of several: its sliders are ``{tool}_roll``, ...,
        ``{tool}_z`` and its button ``{tool}: Grasp / release`` (module docstring).
    """

    reports_increments = True

    def __init__(
        self,
        meshcat: Meshcat,
        X_WD0: RigidTransform,
        workspace: tuple[Sequence[float], Sequence[float]],
        grasp: str | None = None,
        period_s: float = 1.0 / DEFAULT_DEVICE_RATE_HZ,
        latency_s: float = 0.0,
        guard: SampleGuard | None = None,
        step_m: float = 0.002,
        interpolation: str = "hold",
        aids: RelativeAids | None = None,
        tool: str = "",
    ):
        lo, hi = (np.asarray(v, float).reshape(3) for v in workspace)
        p0 = X_WD0.translation()
        if not (np.all(lo < hi) and np.all(lo <= p0) and np.all(p0 <= hi)):
            raise ValueError(
                f"live device workspace {lo.tolist()}..{hi.tolist()} (m) must be a box containing the "
                f"start point {p0.tolist()}"
            )
        self.meshcat = meshcat
        self._lo, self._hi = lo, hi
        self.keys = keys_are_free(meshcat)
        keys = {} if self.keys else {"decrement_keycodes": [""] * 6, "increment_keycodes": [""] * 6}
        self.sliders = MeshcatPoseSliders(
            meshcat,
            initial_pose=X_WD0,
            lower_limit=np.concatenate([[-math.pi] * 3, lo]),
            upper_limit=np.concatenate([[math.pi] * 3, hi]),
            step=np.array([0.05, 0.05, 0.05, step_m, step_m, step_m]),
            prefix=tool,
            **keys,
        )
        self.grasp_button = grasp_button(tool)
        self._sliders_context = self.sliders.CreateDefaultContext()
        self._fixed_grasp = grasp
        self._grasping = False
        self._clicks = 0
        self._pad_pressed = False
        self._last_t = 0.0
        self._commanded = self._shown = None
        self.clamped = 0  # slider poses held back to the workspace
        if grasp is None:
            meshcat.AddButton(self.grasp_button, "Space" if self.keys else "")
        add_stop_button(meshcat)
        super().__init__(self._read, period_s, latency_s, interpolation=interpolation, guard=guard, aids=aids)

    def _read(self, t: float):
        X = self._pose(t)
        q, p, _ = pose_arrays(X)
        if self._fixed_grasp is not None:
            return p, q, self._fixed_grasp
        clicks = self.meshcat.GetButtonClicks(self.grasp_button)
        if clicks != self._clicks:
            self._grasping ^= (clicks - self._clicks) % 2 == 1
            self._clicks = clicks
        return p, q, GRASP_NEAREST if self._grasping else ""

    def _pose(self, t: float) -> RigidTransform:
        """The sliders' pose, moved by the gamepad's sticks (velocity control).

        The stick's motion is integrated in full precision (a slider rounds to its step, which
        would swallow motions under half a step per sample); the sliders are set to follow it,
        and a slider the user moves takes over.
        """
        dt, self._last_t = max(t - self._last_t, 0.0), t
        sliders = self._held_to_workspace(self.sliders.get_output_port().Eval(self._sliders_context))
        if self._commanded is None or self._shown is None or not sliders.IsNearlyEqualTo(self._shown, 1e-12):
            self._commanded = sliders  # the user moved a slider or pressed a key
        pad = self.meshcat.GetGamepad()
        if not self.keys or pad.index is None or len(pad.axes) < 4:
            return self._commanded
        axes = np.array(pad.axes[:4], float)
        axes[np.abs(axes) < GAMEPAD_DEADZONE] = 0.0
        if pad.button_values:
            pressed = pad.button_values[0] > 0.5
            if pressed and not self._pad_pressed and self._fixed_grasp is None:
                self._grasping = not self._grasping
            self._pad_pressed = pressed
        if dt > 0.0 and np.any(axes):
            # stick up is negative in the browser's Gamepad API
            v = GAMEPAD_SPEED_M_S * np.array([axes[0], -axes[1], -axes[3]])
            p = np.clip(self._commanded.translation() + v * dt, self._lo, self._hi)
            self._commanded = RigidTransform(self._commanded.rotation(), p)
            self.sliders.SetPose(self._commanded)
            self._shown = self.sliders.get_output_port().Eval(self._sliders_context)
        else:
            self._shown = sliders
        return self._commanded

    def _held_to_workspace(self, X: RigidTransform) -> RigidTransform:
        """The sliders' pose held to the workspace on the server: any page on this machine can send
        a slider value, and Meshcat does not bound it. A pose outside (or not finite) is moved to
        the nearest point inside, counted (``device_clamped_samples``), and shown on the sliders."""
        p = X.translation()
        held = np.clip(np.nan_to_num(p, nan=0.0), self._lo, self._hi)
        if np.array_equal(held, p):
            return X
        self.clamped += 1
        finite = np.all(np.isfinite(X.rotation().matrix()))
        R = X.rotation() if finite or self._commanded is None else self._commanded.rotation()
        X = RigidTransform(R, held)
        self.sliders.SetPose(X)
        return X

    def status(self, context) -> dict:
        return {**super().status(context), "device_clamped_samples": self.clamped}

    def grasp_names(self, duration_s: float | None = None) -> set[str]:
        """A live device names no body in advance (``"*"`` picks the nearest)."""
        return {self._fixed_grasp} if self._fixed_grasp else set()


class MeshcatJointDevice(JointDevice):
    """A joint-space device driven from the browser: one slider and key pair per channel.

    Parameters
    ----------
    meshcat : Meshcat
        The scene's Meshcat.
    channels : sequence of str
        Channel names (e.g. ``yaw, pitch, insertion, roll, jaw``).
    limits : sequence of (lower, upper)
        Range of each channel (rad or m).
    initial : sequence of float
        Start values.
    keys : sequence of (decrement, increment) key codes, optional
        Default: Q/E, S/W, A/D, J/L, K/I, U/O for the first six channels.
    mix, period_s, latency_s :
        As for :class:`~godobject_drake.devices.sources.JointDevice`.
    tool : str
        The tool it drives in a scene of several: its sliders are ``{tool}_{channel}`` (else
        ``device {channel}``), and only the first live device on the page has keys.
    """

    DEFAULT_KEYS = (("KeyQ", "KeyE"), ("KeyS", "KeyW"), ("KeyA", "KeyD"),
                    ("KeyJ", "KeyL"), ("KeyK", "KeyI"), ("KeyU", "KeyO"))  # fmt: skip

    def __init__(
        self,
        meshcat: Meshcat,
        channels: Sequence[str],
        limits: Sequence[tuple[float, float]],
        initial: Sequence[float],
        keys: Sequence[tuple[str, str]] | None = None,
        mix=None,
        period_s: float = 1.0 / DEFAULT_DEVICE_RATE_HZ,
        latency_s: float = 0.0,
        steps: Sequence[float] | None = None,
        tool: str = "",
    ):
        channels = tuple(channels)
        keys = keys or self.DEFAULT_KEYS
        if not (len(limits) == len(initial) == len(channels) <= len(keys)):
            raise ValueError(
                f"{len(channels)} channels need as many limits ({len(limits)}), initial values "
                f"({len(initial)}) and key pairs ({len(keys)})"
            )
        self.meshcat = meshcat
        self._names = [f"{tool}_{c}" if tool else f"device {c}" for c in channels]
        self.keys = keys_are_free(meshcat)
        for i, (name, (lo, hi), x0) in enumerate(zip(self._names, limits, initial, strict=True)):
            if not lo <= x0 <= hi:
                raise ValueError(f"channel {channels[i]} starts at {x0}, outside its range [{lo}, {hi}]")
            step = steps[i] if steps else (hi - lo) / 200.0
            down, up = keys[i] if self.keys else ("", "")
            meshcat.AddSlider(name, lo, hi, step, x0, down, up)
        add_stop_button(meshcat)
        self._limits = np.array(limits, float).reshape(-1, 2)
        self.clamped = 0  # channel values held back to their range
        super().__init__(self._read, channels, mix, period_s, latency_s)

    def _read(self, t: float) -> np.ndarray:
        """The sliders' values, each held to its range on the server (any page on this machine can
        send a value, and Meshcat does not bound it): counted, and shown back on the slider."""
        values = np.array([self.meshcat.GetSliderValue(name) for name in self._names])
        lo, hi = self._limits[:, 0], self._limits[:, 1]
        held = np.clip(np.where(np.isnan(values), lo, values), lo, hi)
        for i in np.nonzero(held != values)[0]:
            self.clamped += 1
            self.meshcat.SetSliderValue(self._names[i], float(held[i]))
        return held

    def status(self, context) -> dict:
        return {"device_clamped_samples": self.clamped}
