"""The device families a driver process runs (``godobject-driver FAMILY``), each behind one
small interface, with its rated limits (docs/haptic_devices.md).

A family's device is opened, read and commanded from the driver's loop
(:mod:`godobject_drake.driver.process`) through :class:`HapticIO`:

- ``read() -> (p, q, buttons)``: the handle's position (m) and orientation (a W-first unit
  quaternion) in the device's own frame, and the pressed buttons (a tuple of bools; button 0 is
  the grasp, button 1 the clutch by default);
- ``render(f)``: command the force ``f`` (N, the device's frame) until the next call;
- ``close()``: zero the force and release the device;
- ``watchdog``: what guards the device when the driver cannot (SIGKILL, a crash): the device's own
  watchdog, armed where the vendor's SDK has one, or why there is none (said at the start).

The vendor wrappers are imported when their family is opened, never by the library: none is a
dependency. What each call is, and where it was checked, is in docs/haptic_devices.md; the
tests run every family against stand-in modules with the wrappers' call signatures
(``tests/stand_ins/``), backed by the emulated device.

**Rated limits** (:data:`RATED`): the force the driver never exceeds, from the vendors' published
specifications (see docs/haptic_devices.md for what was checked and what could not be, here
without network). The rate-of-change limit is ours, not a vendor's: the rated force reached in no
less than 10 ms, soft enough not to kick a hand, fast enough for a wall (its first 2 N in 2 ms on
an omega.3).
"""

from __future__ import annotations

import dataclasses
import importlib.resources
import json
import math
from pathlib import Path

import numpy as np

IDENTITY_Q = np.array([1.0, 0.0, 0.0, 0.0])
SLEW_TIME_S = 0.010  # the rated force is reached in no less than this: our limit, not a vendor's


@dataclasses.dataclass(frozen=True)
class Rated:
    """A device's rated limits, as its vendor states them."""

    model: str
    max_force_n: float
    rate_hz: float  # the device's servo rate
    source: str  # where the figure comes from
    # The stiffest spring it renders (N/m, in its own frame): past it a wall buzzes or kicks, and a
    # local model asking more is refused (Driver._on_local_model). The default is the omega.3's
    # 14.5 N/mm, the stiffest, which config.gains.MAX_RENDERED_STIFFNESS_N_M repeats for the scene
    # (the driver loads no config; tests/test_small_defects.py checks the two agree).
    max_stiffness_n_m: float = 14_500.0

    @property
    def max_force_rate_n_s(self) -> float:
        return self.max_force_n / SLEW_TIME_S


RATED = {
    # The emulated device is given an omega.3's figure so the tests exercise a real-sized limit.
    "emulated": Rated("emulated handle", 12.0, 1000.0, "chosen equal to the omega.3's rating"),
    "haply": Rated(
        "Haply Inverse3",
        10.0,
        1000.0,
        "Haply's Inverse3 product page (peak force); NOT re-checked here: check your unit's datasheet; "
        "its stiffness: the omega.3's taken, no figure of Haply's checked",
    ),
    "forcedimension": Rated(
        "Force Dimension omega.3",
        12.0,
        1000.0,
        "Force Dimension omega.3 datasheet (continuous translational force); a Novint Falcon is rated "
        "lower (about 9 N): give --max-force 8.9 for one",
    ),
    "openhaptics": Rated(
        "3D Systems Touch",
        3.3,
        1000.0,
        "3D Systems Touch datasheet: maximum exertable force 3.3 N at the nominal position "
        "(continuous 0.88 N); a Touch X is rated 7.9 N; stiffness 1.02 N/mm (its softest axis, z)",
        max_stiffness_n_m=1020.0,
    ),
}


class HapticIO:
    """One opened device (module docstring)."""

    buttons = 2
    watchdog = "no device watchdog"

    def read(self) -> tuple[np.ndarray, np.ndarray, tuple[bool, ...]]:
        raise NotImplementedError

    def render(self, f: np.ndarray) -> None:
        raise NotImplementedError

    def close(self) -> None:
        pass

    def on_scene(self) -> None:
        """The scene was heard for the first time (the emulated hand starts its path then)."""


# -- the emulated device: a handle on springs, moved by a simulated hand ----------------------------------


HANDS = Path(str(importlib.resources.files("godobject_models") / "haptic"))  # the shipped hand paths


def shipped_hands() -> list[str]:
    """The names ``--hand`` takes for the shipped hand paths."""
    return sorted(p.stem for p in HANDS.glob("*.json"))


@dataclasses.dataclass
class HandPath:
    """Where a simulated hand takes the handle: waypoints ``t`` (s), ``xyz`` (m, the device's
    frame), ``grasp`` and ``clutch`` (buttons held from that waypoint on); linear in between."""

    t: np.ndarray
    xyz: np.ndarray
    grasp: np.ndarray
    clutch: np.ndarray

    @classmethod
    def load(cls, path: str | Path) -> HandPath:
        """A hand path from a JSON file, or a shipped one by name (:func:`shipped_hands`,
        ``models/haptic/NAME.json``) where no such file exists."""
        if not Path(path).exists() and str(path) in shipped_hands():
            path = HANDS / f"{path}.json"
        try:
            data = json.loads(Path(path).read_text())
            rows = data["waypoints"]
            t = np.array([float(r["t"]) for r in rows])
            xyz = np.array([[float(v) for v in r["xyz"]] for r in rows])
        except (OSError, ValueError, KeyError, TypeError) as e:
            raise ValueError(
                f"--hand {path}: {e}; give JSON {{'waypoints': [{{'t': 0, 'xyz': [x, y, z], 'grasp': false, "
                f"'clutch': false}}, ...]}} (s, m), or a shipped hand: {', '.join(shipped_hands())}"
            ) from None
        if len(t) == 0 or xyz.shape != (len(t), 3) or np.any(np.diff(t) <= 0) or not np.all(np.isfinite(xyz)):
            raise ValueError(f"--hand {path}: waypoints need increasing t and 3 finite xyz each")
        return cls(
            t,
            xyz,
            np.array([bool(r.get("grasp")) for r in rows]),
            np.array([bool(r.get("clutch")) for r in rows]),
        )

    @classmethod
    def still(cls) -> HandPath:
        return cls(np.zeros(1), np.zeros((1, 3)), np.zeros(1, bool), np.zeros(1, bool))

    def at(self, t: float) -> tuple[np.ndarray, bool, bool]:
        k = int(np.searchsorted(self.t, t, side="right")) - 1
        p = np.array([np.interp(t, self.t, self.xyz[:, i]) for i in range(3)])
        k = max(k, 0)
        return p, bool(self.grasp[k]), bool(self.clutch[k])


class EmulatedDevice(HapticIO):
    """A handle of mass ``mass_kg`` held by a simulated hand: a spring ``hand_stiffness`` (N/m) and
    damper ``hand_damping`` (N·s/m) to the hand's path; the rendered force pushes the handle, and
    mechanical stops bound it to ``reach_m`` (the box :mod:`godobject_drake.driver.process`'s ``calibrate``
    finds). Time is the wall clock (``clock``), starting when the scene is first heard, so the hand
    moves as a person's would, whatever the scene's speed."""

    REACH_M = ((-0.08, -0.08, -0.06), (0.08, 0.08, 0.06))

    def __init__(
        self,
        hand: HandPath | None = None,
        clock=None,
        mass_kg: float = 0.1,
        hand_stiffness: float = 400.0,
        hand_damping: float = 8.0,
        reach_m=REACH_M,
        start_on_scene: bool = True,
    ):
        import time

        self.hand = hand or HandPath.still()
        self.clock = clock or time.monotonic
        self.m, self.k, self.b = mass_kg, hand_stiffness, hand_damping
        self.lower, self.upper = (np.asarray(v, float) for v in reach_m)
        self.p = np.clip(self.hand.at(0.0)[0], self.lower, self.upper)
        self.v = np.zeros(3)
        self.f = np.zeros(3)
        self.t0 = None if start_on_scene else self.clock()
        self._last = self.clock()
        self.rendered: list[np.ndarray] = []  # the last force, for a stand-in's checks

    def on_scene(self) -> None:
        if self.t0 is None:
            self.t0 = self.clock()

    def hand_time(self) -> float:
        return 0.0 if self.t0 is None else self.clock() - self.t0

    def _advance(self) -> None:
        now = self.clock()
        dt_total, self._last = min(now - self._last, 0.05), now
        target, _, _ = self.hand.at(self.hand_time())
        steps = max(1, math.ceil(dt_total / 5e-4))
        dt = dt_total / steps
        for _ in range(steps):  # semi-implicit Euler, 0.5 ms steps: ω dt = 0.03
            a = (self.k * (target - self.p) - self.b * self.v + self.f) / self.m
            self.v = self.v + dt * a
            self.p = self.p + dt * self.v
            hit = (self.p < self.lower) | (self.p > self.upper)
            self.p = np.clip(self.p, self.lower, self.upper)  # the mechanical stops
            self.v[hit] = 0.0

    def read(self):
        self._advance()
        _, grasp, clutch = self.hand.at(self.hand_time())
        return self.p.copy(), IDENTITY_Q.copy(), (grasp, clutch)

    def render(self, f) -> None:
        self.f = np.asarray(f, float).copy()

    def close(self) -> None:
        self.f = np.zeros(3)


# -- vendor families ---------------------------------------------------------------------------------------


def _missing(family: str, package: str, fix: str) -> ValueError:
    return ValueError(
        f"{family}: the vendor wrapper {package!r} is not installed; {fix} (docs/haptic_devices.md)"
    )


class HaplyInverse3(HapticIO):
    """A Haply Inverse3 through ``HaplyHardwareAPI`` (PyPI ``haplyhardwareapi``), over its serial port.

    Calls (Haply's published Python examples): ``detect_inverse3s()`` lists the ports,
    ``SerialStream(port)``, ``Inverse3(stream)``, ``device_wakeup_dict()``, and once per period
    ``end_effector_force([fx, fy, fz]) -> (position, velocity)``: the force is sent and the position
    read in one call, so :meth:`render` makes the call and :meth:`read` returns its position. The
    Inverse3 has no buttons of its own (the VerseGrip handle's are not read here): the grasp is
    the driver's ``--grasp always``.
    """

    buttons = 0
    watchdog = "no device watchdog: HaplyHardwareAPI's calls (as read here) offer none"

    def __init__(self, port: str = ""):
        try:
            import HaplyHardwareAPI as api
        except ImportError:
            raise _missing("haply", "HaplyHardwareAPI", "pip install HaplyHardwareAPI") from None
        ports = list(api.detect_inverse3s())
        if not port:
            if not ports:
                raise ValueError("haply: no Inverse3 found on a serial port; plug it in, or give --port")
            port = ports[0]
        self.device = api.Inverse3(api.SerialStream(port))
        self.info = self.device.device_wakeup_dict()
        self.p = np.zeros(3)
        self._send(np.zeros(3))

    def _send(self, f) -> None:
        position, _velocity = self.device.end_effector_force([float(v) for v in f])
        self.p = np.asarray(position, float)

    def read(self):
        return self.p.copy(), IDENTITY_Q.copy(), ()

    def render(self, f) -> None:
        self._send(f)

    def close(self) -> None:
        self._send(np.zeros(3))


class ForceDimension(HapticIO):
    """A Force Dimension device (omega, sigma, delta; a Novint Falcon) through ``forcedimension_core``
    (PyPI ``forcedimension-core``, over Force Dimension's SDK, which must be installed).

    Calls (the wrapper's documented ``dhd`` module): ``dhd.open() -> ID`` (−1: none),
    ``dhd.enableForce(True, ID)``, each period ``dhd.getPosition(out=[3], ID=ID)``,
    ``dhd.getButton(index, ID=ID)`` and ``dhd.setForce([fx, fy, fz], ID=ID)`` (0 on success, −1
    on error), and at the end ``dhd.setForce([0, 0, 0])``, ``dhd.stop(ID)`` (forces off, brakes
    on) and ``dhd.close(ID)``.
    """

    def __init__(self):
        try:
            from forcedimension_core import dhd
        except ImportError:
            raise _missing(
                "forcedimension",
                "forcedimension_core",
                "pip install forcedimension-core and install Force Dimension's SDK",
            ) from None
        except OSError as e:  # the wrapper loads the SDK's shared library at import
            raise ValueError(f"forcedimension: Force Dimension's SDK library did not load ({e})") from None
        self.dhd = dhd
        self.id = dhd.open()
        if self.id < 0:
            raise ValueError(f"forcedimension: no device opened ({dhd.errorGetLastStr()}); plug it in")
        self._check(dhd.enableForce(True, ID=self.id), "enableForce")
        self._pos = [0.0, 0.0, 0.0]
        self.watchdog = self._arm_watchdog()

    WATCHDOG_S = 0.025  # the firmware's watchdog: 200 × 125 µs (at most 255 × 125 µs = 31.9 ms)

    def _arm_watchdog(self) -> str:
        """Arm the device's own watchdog (the SDK's expert ``dhdSetWatchdog``, in units of 125 µs):
        when no force command reaches the device for :attr:`WATCHDOG_S` (the driver killed, crashed or
        hung), its firmware turns the forces off. The driver commands every period (1 ms), so only a
        loop held up that long trips it. Said at the start; a model without one runs on, said so."""
        try:
            from forcedimension_core.dhd import expert
        except ImportError as e:
            return f"device watchdog NOT armed (the wrapper has no dhd.expert: {e})"
        units = round(self.WATCHDOG_S / 125e-6)
        armed = expert.enableExpertMode() == 0 and expert.setWatchdog(units, ID=self.id) == 0
        why = "" if armed else self.dhd.errorGetLastStr()
        expert.disableExpertMode()  # the watchdog is the firmware's; the SDK back to its normal mode
        if not armed:
            return f"device watchdog NOT armed ({why}): this model may have none"
        return f"device watchdog armed: forces off {self.WATCHDOG_S * 1e3:g} ms after the last command"

    def _check(self, code: int, call: str) -> None:
        if code == -1:
            raise RuntimeError(f"forcedimension: dhd.{call} failed: {self.dhd.errorGetLastStr()}")

    def read(self):
        self._check(self.dhd.getPosition(out=self._pos, ID=self.id), "getPosition")
        buttons = tuple(self.dhd.getButton(index=i, ID=self.id) == 1 for i in range(self.buttons))
        return np.array(self._pos, float), IDENTITY_Q.copy(), buttons

    def render(self, f) -> None:
        self._check(self.dhd.setForce([float(v) for v in f], ID=self.id), "setForce")

    def close(self) -> None:
        try:
            self.dhd.setForce([0.0, 0.0, 0.0], ID=self.id)
            self.dhd.stop(self.id)
        finally:
            self.dhd.close(self.id)


class OpenHaptics(HapticIO):
    """A 3D Systems Touch (Phantom Omni, Touch X) through ``pyOpenHaptics`` (PyPI ``pyopenhaptics``,
    over OpenHaptics' HD library, which must be installed).

    OpenHaptics runs its own 1 kHz servo thread and calls a callback in it:
    ``HapticDevice(callback=..., device_name=..., scheduler_type="async")`` with the callback
    decorated by ``hd_callback``; in it ``hd.get_transform()`` (a 4 × 4, translation in its
    last row, in mm), ``hd.get_buttons()`` (a bit mask) and ``hd.set_force([fx, fy, fz])`` (N).
    The driver's loop exchanges the newest pose and force with that callback; ``device.close()``
    stops the scheduler.
    """

    watchdog = (
        "no device watchdog: OpenHaptics' HD calls offer none (its servo thread dies with the driver: "
        "what the Touch then renders is its own driver's, not checked here)"
    )

    def __init__(self, device_name: str = "Default Device"):
        try:
            import pyOpenHaptics.hd as hd
            from pyOpenHaptics.hd_callback import hd_callback
            from pyOpenHaptics.hd_device import HapticDevice
        except ImportError:
            raise _missing(
                "openhaptics", "pyOpenHaptics", "pip install pyopenhaptics and install OpenHaptics (libHD.so)"
            ) from None
        except OSError as e:
            raise ValueError(f"openhaptics: OpenHaptics' libHD did not load ({e})") from None
        self.hd = hd
        self.p, self.mask, self.f = np.zeros(3), 0, [0.0, 0.0, 0.0]

        @hd_callback
        def servo():  # OpenHaptics' servo thread, 1 kHz
            transform = hd.get_transform()
            self.p = np.array([transform[3][0], transform[3][1], transform[3][2]], float) / 1000.0
            self.mask = int(hd.get_buttons())
            hd.set_force(list(self.f))

        self._servo = servo  # kept alive: the scheduler holds only a C pointer
        self.device = HapticDevice(callback=servo, device_name=device_name, scheduler_type="async")

    def read(self):
        return self.p.copy(), IDENTITY_Q.copy(), tuple(bool(self.mask >> i & 1) for i in range(self.buttons))

    def render(self, f) -> None:
        self.f = [float(v) for v in f]

    def close(self) -> None:
        self.f = [0.0, 0.0, 0.0]
        import time

        time.sleep(0.005)  # a few servo ticks send the zero before the scheduler stops
        self.device.close()


FAMILIES = {
    "emulated": EmulatedDevice,
    "haply": HaplyInverse3,
    "forcedimension": ForceDimension,
    "openhaptics": OpenHaptics,
}
