"""The motion, force and safety scores surgical-skill user studies report, for any tool's tip.

Per tool, from its tip's trajectory sampled at every plant step (docs/task_metrics.md):

- **path length** ``tip_path_m``: the sum of the distances between consecutive samples (a
  polyline through the logged positions; J Laparoendosc Adv Surg Tech 2014, doi
  10.1089/lap.2014.0015, reports it per instrument tip);
- **economy of motion** ``tip_economy_of_motion``: the straight-line distance from the first
  sample to the last over the path length (1 for a straight line, 2/π for a semicircle; the ratio
  of the shortest path between the two ends to the path taken);
- **smoothness** ``tip_log_dimensionless_jerk``: the log dimensionless jerk of Balasubramanian et
  al. 2012 (IEEE Trans Biomed Eng 59(8), "A robust and sensitive metric for quantifying movement
  smoothness"), ``LDLJ = −ln( T³ / v_peak² · ∫ |d³p/dt³|² dt )``, with ``T`` the task time below and
  ``v_peak`` the largest tip speed; closer to zero is smoother (a minimum-jerk reach: −ln 204.8);
- **idle time** ``tip_idle_time_s``: the time the tip's speed is under :data:`IDLE_SPEED_MPS`;
- **task time** ``task_time_s``: from the first sample the tip moves faster than that to the last;
- **out of view** ``tip_out_of_view_s``: the time the tip is outside the scene camera's view cone
  (:class:`CameraView`).

Derivatives come from a Savitzky–Golay filter (``scipy.signal.savgol_coeffs``: a polynomial of
degree :data:`SMOOTHING_ORDER` fitted by least squares over :data:`SMOOTHING_WINDOW_S` of samples,
differentiated at its centre): a jerk from raw 1 ms differences would be the differences' noise
amplified by h⁻³. The filter needs a full window, so the first and last half window of a run have
no speed or jerk (they count for the path length). Every fold takes its rows a chunk at a time and
any split gives the same numbers (the last window carried over).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
from scipy.signal import savgol_coeffs

IDLE_SPEED_MPS = 0.005  # a tip slower than this (5 mm/s) is idle
SMOOTHING_WINDOW_S = 0.1  # the Savitzky–Golay window (s), rounded to an odd count of samples
SMOOTHING_ORDER = 5  # its polynomial's degree: exact on a quintic (a minimum-jerk reach)
MESHCAT_FOV_DEG = 75.0  # Meshcat's default camera: three.js PerspectiveCamera(75, ...), vertical
MESHCAT_NEAR_M = 0.01  # ... and its near plane


def path_length(p: np.ndarray) -> float:
    """Length of the polyline through the positions ``p`` (N, 3) (m)."""
    p = np.asarray(p, float)
    return float(np.sum(np.linalg.norm(np.diff(p, axis=0), axis=1))) if len(p) > 1 else 0.0


def economy_of_motion(p: np.ndarray) -> float | None:
    """Straight-line distance from the first to the last of the positions ``p`` over their path
    length (1: a straight line); None for a path of zero length."""
    length = path_length(p)
    if length <= 0.0:
        return None
    return float(np.linalg.norm(np.asarray(p[-1], float) - np.asarray(p[0], float)) / length)


def log_dimensionless_jerk(jerk_sq_integral: float, duration_s: float, peak_speed: float) -> float | None:
    """Balasubramanian et al. 2012's ``LDLJ = −ln( T³ / v_peak² · ∫ |jerk|² dt )`` from its three
    parts; None where it is undefined (a tip that never moved, no jerk at all)."""
    if duration_s <= 0.0 or peak_speed <= 0.0 or jerk_sq_integral <= 0.0:
        return None
    return -math.log(duration_s**3 / peak_speed**2 * jerk_sq_integral)


def window_samples(h: float, window_s: float = SMOOTHING_WINDOW_S, order: int = SMOOTHING_ORDER) -> int:
    """The Savitzky–Golay window in samples: ``window_s / h`` rounded to the nearest odd count, at
    least ``order + 2`` (a fit needs more samples than coefficients). Refuses a bad step or window."""
    if not (h > 0.0 and math.isfinite(h)):
        raise ValueError(f"time step h = {h!r} s must be finite and > 0: give the plant's time step")
    if not (window_s > 0.0 and math.isfinite(window_s)):
        raise ValueError(f"smoothing window {window_s!r} s must be finite and > 0: give e.g. 0.1 s")
    n = 2 * round(window_s / (2.0 * h)) + 1
    least = order + 2 - (order % 2 == 0)  # the smallest odd count above the order
    return max(n, least)


@dataclasses.dataclass(frozen=True)
class CameraView:
    """A camera's view as a cone: the tip is in view when the angle between the camera's axis (from
    ``position_m`` to ``target_m``) and the ray to it is at most half of ``fov_deg``, and it is at
    least ``near_m`` in front. Meshcat's camera (what the scene's ``visualization.camera`` places)
    has a vertical field of view of 75° (:data:`MESHCAT_FOV_DEG`); a landscape window shows more
    across, so the cone is the view any window shows."""

    position_m: tuple
    target_m: tuple
    fov_deg: float = MESHCAT_FOV_DEG
    near_m: float = MESHCAT_NEAR_M

    def __post_init__(self):
        axis = np.asarray(self.target_m, float) - np.asarray(self.position_m, float)
        if not np.all(np.isfinite(axis)) or np.linalg.norm(axis) == 0.0:
            raise ValueError(
                f"camera position {list(self.position_m)} and target {list(self.target_m)}: the target must "
                "differ from the position (the camera looks from one to the other); move one of them"
            )
        if not 0.0 < self.fov_deg < 180.0:
            raise ValueError(f"camera field of view {self.fov_deg!r}° must be in (0, 180): give e.g. 75")

    def in_view(self, p: np.ndarray) -> np.ndarray:
        """Whether each position of ``p`` (N, 3) is in view."""
        c = np.asarray(self.position_m, float)
        axis = np.asarray(self.target_m, float) - c
        axis = axis / np.linalg.norm(axis)
        r = np.asarray(p, float) - c
        depth = r @ axis
        distance = np.linalg.norm(r, axis=1)
        cos_half = math.cos(math.radians(0.5 * self.fov_deg))
        return (depth >= self.near_m) & (depth >= cos_half * distance)


class TipMotion:
    """A tip's motion scores, folded a chunk of rows at a time (module docstring).

    :meth:`update` takes the tip's positions (N, 3) at consecutive plant steps of ``h`` and, for a
    tip whose reference point switches (a rigid god-object: the device's point while nothing is
    held, the held body's centre of mass while one is), a flag per row saying the reference switched
    at that row: that row's step is a change of point, not a motion, and is left out of the path
    (the positions after it are shifted by the jump, so derivatives see no step either).
    """

    def __init__(self, h: float, camera: CameraView | None = None, idle_speed_mps: float = IDLE_SPEED_MPS,
                 window_s: float = SMOOTHING_WINDOW_S, order: int = SMOOTHING_ORDER):  # fmt: skip
        if not (idle_speed_mps >= 0.0 and math.isfinite(idle_speed_mps)):
            raise ValueError(f"idle speed {idle_speed_mps!r} m/s must be finite and ≥ 0: give e.g. 0.005")
        self.h, self.camera, self.idle_speed = h, camera, idle_speed_mps
        self.window = window_samples(h, window_s, order)
        self._c1 = savgol_coeffs(self.window, order, deriv=1, delta=h, use="dot")
        self._c3 = savgol_coeffs(self.window, order, deriv=3, delta=h, use="dot")
        self._tail = np.zeros((0, 3))  # the last window − 1 shifted positions
        self._offset = np.zeros(3)  # the jumps of the reference point so far
        self._last = None  # the last shifted position
        self.first = None  # the first position
        self.path = 0.0
        self.rows = 0  # rows folded
        self.estimated = 0  # rows with a speed and jerk (the window's centre)
        self.idle_rows = 0
        self.first_active = self.last_active = None  # estimated rows' indexes, from the run's first row
        self.jerk_sq = 0.0  # ∫ |jerk|² dt
        self.peak_speed = 0.0
        self.out_of_view_rows = 0

    def update(self, p: np.ndarray, switched: np.ndarray | None = None) -> None:
        p = np.array(p, float).reshape(-1, 3)
        n = len(p)
        if n == 0:
            return
        if self.camera is not None:
            self.out_of_view_rows += int(np.count_nonzero(~self.camera.in_view(p)))
        if self.first is None:
            self.first = p[0].copy()
        previous = self._last + self._offset if self._last is not None else p[0]
        steps = np.diff(np.vstack([previous, p]), axis=0)  # each row's step from the row before
        if switched is not None:
            jumps = np.where(np.asarray(switched, bool)[:, None], steps, 0.0)
            steps = steps - jumps
            shift = self._offset + np.cumsum(jumps, axis=0)
            self._offset = shift[-1].copy()
        else:
            shift = np.broadcast_to(self._offset, p.shape)
        shifted = p - shift
        self.path += float(np.sum(np.linalg.norm(steps, axis=1)))
        self._last = shifted[-1].copy()
        self._derivatives(shifted)
        self.rows += n

    def _derivatives(self, shifted: np.ndarray) -> None:
        x = np.vstack([self._tail, shifted])
        w = self.window
        self._tail = x[-(w - 1) :] if w > 1 else x[:0]
        if len(x) < w:
            return
        windows = np.lib.stride_tricks.sliding_window_view(x, w, axis=0)  # (M, 3, w)
        speed = np.linalg.norm(windows @ self._c1, axis=1)
        jerk = windows @ self._c3
        first_row = self.estimated  # estimated row k is the run's row k + w // 2
        self.estimated += len(speed)
        self.jerk_sq += float(np.sum(jerk * jerk)) * self.h
        self.peak_speed = max(self.peak_speed, float(speed.max()))
        idle = speed < self.idle_speed
        self.idle_rows += int(np.count_nonzero(idle))
        active = np.flatnonzero(~idle)
        if len(active):
            if self.first_active is None:
                self.first_active = first_row + int(active[0])
            self.last_active = first_row + int(active[-1])

    @property
    def task_time_s(self) -> float:
        """From the first row the tip moves faster than the idle speed to the last (s); 0 if never."""
        if self.first_active is None:
            return 0.0
        return (self.last_active - self.first_active + 1) * self.h

    def result(self) -> dict:
        straight = None
        if self._last is not None and self.path > 0.0:  # the ends of the path taken: the jumps left out
            straight = float(np.linalg.norm(self._last - self.first)) / self.path
        return {
            "tip_path_m": self.path,
            "tip_economy_of_motion": straight,
            "tip_log_dimensionless_jerk": log_dimensionless_jerk(
                self.jerk_sq, self.task_time_s, self.peak_speed
            ),
            "tip_peak_speed_mps": self.peak_speed if self.estimated else None,
            "tip_idle_time_s": self.idle_rows * self.h,
            "task_time_s": self.task_time_s,
            "tip_out_of_view_s": self.out_of_view_rows * self.h if self.camera is not None else None,
        }


class ForceFold:
    """The contact force a tool applies to everything but itself, per row: the largest, and the mean
    over the rows it is in contact (Horeman et al., Surg Endosc 2010, report both)."""

    def __init__(self, h: float):
        self.h = h
        self.max_force, self.sum_force, self.contact_rows = 0.0, 0.0, 0

    def update(self, force_W: np.ndarray, contacts: np.ndarray) -> None:
        """``force_W`` (N, 3) the net force (N) on the other bodies, ``contacts`` (N,) how many
        contacts the tool has with them at each row."""
        magnitude = np.linalg.norm(np.asarray(force_W, float).reshape(-1, 3), axis=1)
        touching = np.asarray(contacts, float) > 0.5
        if len(magnitude):
            self.max_force = max(self.max_force, float(magnitude.max()))
        self.sum_force += float(np.sum(magnitude[touching]))
        self.contact_rows += int(np.count_nonzero(touching))

    def result(self) -> dict:
        return {
            "tool_max_force_N": self.max_force,
            "tool_mean_force_N": self.sum_force / self.contact_rows if self.contact_rows else None,
            "tool_contact_time_s": self.contact_rows * self.h,
        }


COLLISION_GAP_S = 0.1  # contacts apart by less than this are one collision (a chattering contact)


class CollisionFold:
    """Contacts between two tools: the events and the total time in contact, over rows of 0/1 flags
    folded a chunk at a time. An event is a row in contact after at least ``gap_s`` of rows apart
    (or the first contact): a contact that chatters, apart for a step or two, is one collision."""

    def __init__(self, h: float, gap_s: float = COLLISION_GAP_S):
        if not (gap_s >= 0.0 and math.isfinite(gap_s)):
            raise ValueError(f"collision gap {gap_s!r} s must be finite and ≥ 0: give e.g. 0.1")
        self.h, self.events, self.rows = h, 0, 0
        self._gap = max(1, round(gap_s / h))  # rows apart that end an event
        self._apart = self._gap  # rows apart since the last contact (a run starts apart)

    def update(self, touching: np.ndarray) -> None:
        for run_touching, length in _runs(np.asarray(touching, float).reshape(-1) > 0.5):
            if run_touching:
                if self._apart >= self._gap:
                    self.events += 1
                self.rows += length
                self._apart = 0
            else:
                self._apart += length

    def result(self, prefix: str = "instrument_") -> dict:
        return {f"{prefix}collisions": self.events, f"{prefix}collision_time_s": self.rows * self.h}


def _runs(flags: np.ndarray):
    """``(value, length)`` of each run of equal values of ``flags``, in order."""
    if not len(flags):
        return []
    edges = np.flatnonzero(flags[1:] != flags[:-1]) + 1
    starts = np.concatenate([[0], edges])
    ends = np.concatenate([edges, [len(flags)]])
    return [(bool(flags[a]), int(b - a)) for a, b in zip(starts, ends, strict=True)]
