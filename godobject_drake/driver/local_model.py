"""The driver's side of the local model (docs/local_model.md): each device period the
force is computed from the scene's newest :class:`~godobject_drake.link.messages.LocalModel` with the
handle's *current* position, a proxy kept out of the model's planes, and an energy budget that
pays for every change of model: what it cannot pay for is not rendered.

Plain arithmetic on the positions, forces and times handed to it (no clock, no socket), so each
rule is checked exactly by the fast tests (``tests/test_local_model.py``) and mutation-tested
(docs/mutation.md). Positions are the device's frame as the scene sees it (the pose the driver
sends, clutch offset included), forces the device's frame (N).

**The proxy** (a god-object at the device's rate, Zilles & Salisbury's, on Adachi's and Mark et
al.'s local planes). When a model arrives, ``c = p_T − h_used`` (``h_used``: the pose the scene
had taken) is where the target sits from the handle (the grasp offset), and the scene's stretch
``p_G − p_T`` — in free space (no plane published) less the coupling's free lag ``lag`` (the
stretch a god-object free of every contact would have, driven by the same targets: what slow
motion makes of a moving hand) — is split into what the model's *active* planes explain (the
god-object rests on them: its component along their normals, pushing out) and the rest ``o``
(friction, a held body pressed where no plane is published). Each period the free proxy is
``y = h + c + o``, with ``h`` the handle now; the proxy ``x`` is ``y`` moved out of every plane
it entered (a plane of stiffness ``s`` lets it in by ``kd/(kd + s)`` of the way: rigid planes
not at all), and the force is ``kd (x − h − c) + γd`` times the stretch's rate: in free space
``kd o``, no drag from the coupling's lag. Near a contact (a plane within reach) the whole
stretch is rendered: the hand pays for the approach as the scene computes it, which is what
the budget's bank draws on when a slow scene's contact arrives late (the budget scales a late
spring down, and pressing on keeps that scale).

**The energy budget** (Hannaford & Ryu's passivity observer and controller). Two accounts of
the work the hand has done on the device since the first model:

- ``E_v``, the *virtual* environment's, by the trapezoid: ``E_v −= ½ (f_prev + f_env(h)) · Δh``,
  ``f_env(h)`` the force the environment last rendered (its model, its scaling) gives at the
  handle's new position. For a fixed spring it equals the spring's energy exactly, so pressing
  into a plane pays for the stretch as it grows; a *new* model (a re-anchoring) is not in it;
- ``E_in``, the *device's*, by the held force: ``E_in −= f_prev · Δh`` (a device holds each force
  over the next period: this is what the hand received).

Neither account keeps more than :data:`BANK_J` (0.2 mJ) beyond what the spring holds: the
work the hand does against the free part (the coupling's lag) is dissipated in the scene, and
banked it would pay for a later push (the passivity observer's known blind spot), so it leaks.
The planes' spring holds ``S = ½ kd |x − y|²`` (the free part ``kd o`` stores nothing: its work
goes through the accounts as it is done). Each period the stretch is scaled by
``β = min(1, √(E_v / S))``, 0 when ``E_v ≤ 0``: a re-anchoring (a new model that moves the
proxy), a fade, a free force that pulls the hand along, anything that would give back more than
was put in, is rendered only as far as it is paid for (the budget lends :data:`ALLOWANCE_J`,
1 µJ, so accounts standing at zero by rounding still render). The controller: while the spring
holds more than the device's account (``S > E_in``: the hold of each force gives the hand up to
``½ kd |Δh|²`` a period more than the virtual spring), or the environment's account is below
zero (``E_v < −1 µJ``: nothing would be rendered until it is repaid), a damper
``α = deficit/(|v|² T)`` (at most :data:`MAX_DAMPING`) against the handle's velocity ``v`` asks
it back over the next period: at a steady press it is Colgate's ``kd T / 2``.

**Validity**: a model holds fully for ``2 gap + 25 ms`` after the scene's last word about it
(``gap``: the scene's period, its stated one or the median of the last 16 intervals between
models when longer, at most :data:`MAX_GAP_S`), then fades linearly to zero at ``3 gap + 50
ms``: a scene killed between two messages leaves no force after that. The scene's last word is
the model's arrival, or a later heartbeat naming that model's time (:meth:`alive`: the scene's
loop is held up, by a fold of its logs or a long step, and the model stands; the scene stops
vouching for a model :data:`~godobject_drake.link.scene_model.STALL_LIMIT_S` after sending it). Each
fade to zero is a watchdog trip.
"""

from __future__ import annotations

import math
from collections import deque

import numpy as np

from godobject_drake.link.messages import LocalModel

MAX_GAP_S = 0.1  # a scene slower than 10 Hz is held no longer than a 10 Hz one
HOLD_GAPS, HOLD_EXTRA_S = 2.0, 0.025
END_GAPS, END_EXTRA_S = 3.0, 0.05
ACTIVE_M = 1e-4  # a plane the god-object is in, or within this of, holds it (explains its stretch)
SWEEPS = 8  # passes over the planes when projecting the proxy
BANK_J = 2e-4  # J: what the accounts keep beyond the spring's energy (the rest the scene dissipated)
ALLOWANCE_J = 1e-6  # J: the budget lends this much, so accounts standing at zero (rounding) still render
MAX_DAMPING = 10.0  # N·s/m: the passivity controller's damper at most (a hand's own is ~8)


def project(y: np.ndarray, planes, kd) -> np.ndarray:
    """``y`` moved out of every plane it entered (module docstring): the proxy ``x`` that balances
    the coupling's spring ``kd (y − x)`` against the planes' pushes, a plane of stiffness ``s``
    pushing ``s`` times the depth of ``x`` in it (``s`` inf: rigid, ``x`` not in it at all). One
    plane: ``x`` stays in by ``kd/(kd + s)`` of the depth of ``y``. Several: projected
    Gauss–Seidel on each plane's push (its share of ``x − y``, never pulling), :data:`SWEEPS`
    passes; exact in one pass for planes at right angles, and a plane ``y`` never reached moves
    nothing. ``kd`` a 3×3 matrix (an articulated tool's coupling, ``GLM3``): the same balance in
    its metric (:func:`project_matrix`)."""
    if isinstance(kd, np.ndarray):
        return project_matrix(y, planes, kd)
    x = np.array(y, float)
    pushed = [0.0] * len(planes)  # each plane's push so far, as a displacement along its normal (m)
    for _ in range(SWEEPS if len(planes) > 1 else 1):
        for i, (point, normal, stiffness) in enumerate(planes):
            depth = -float(np.dot(normal, x - point))
            ratio = kd / stiffness  # a rigid plane (inf) or no spring (kd 0): 0
            # the change of push u − pushed with depth − (u − pushed) = ratio · u (balanced against
            # this plane alone; a rigid plane: the depth), never below a push of zero
            change = max(-pushed[i], (depth - ratio * pushed[i]) / (1.0 + ratio))
            x = x + change * np.asarray(normal)
            pushed[i] += change
    return x


def project_matrix(y: np.ndarray, planes, K: np.ndarray) -> np.ndarray:
    """:func:`project` for a coupling whose stiffness is the symmetric positive definite matrix
    ``K`` (docs/local_model.md "An articulated tool"): ``x`` minimises
    ``½ (x − y)ᵀ K (x − y) + Σ ½ sᵢ depthᵢ(x)²`` (a rigid plane: ``x`` not in it), so
    ``K (x − y) = Σ λᵢ nᵢ`` with each push ``λᵢ = sᵢ depthᵢ(x) ≥ 0``. A push ``λ`` on plane ``i``
    moves ``x`` by ``λ K⁻¹ nᵢ``, and its own depth by ``−λ mᵢ`` (``mᵢ = nᵢᵀ K⁻¹ nᵢ``), so alone
    it balances at ``Δλ = (depth − λᵢ/sᵢ) / (mᵢ + 1/sᵢ)``, never below a push of zero; the
    same projected Gauss–Seidel passes. ``K = kd I``: :func:`project`'s steps. All zero (no
    spring): ``x`` is ``y`` moved out of each plane along its normal, as ``kd`` 0 does."""
    x = np.array(y, float)
    if not np.any(K):
        return project(x, planes, 0.0)
    K_inv = np.linalg.inv(K)
    pushed = [0.0] * len(planes)  # each plane's push so far (N)
    for _ in range(SWEEPS if len(planes) > 1 else 1):
        for i, (point, normal, stiffness) in enumerate(planes):
            n = np.asarray(normal, float)
            w = K_inv @ n
            depth = -float(np.dot(n, x - point))
            change = max(-pushed[i], (depth - pushed[i] / stiffness) / (float(n @ w) + 1.0 / stiffness))
            x = x + change * w
            pushed[i] += change
    return x


def spring_force(K, e: np.ndarray) -> np.ndarray:
    """The coupling's spring on the stretch ``e``: ``kd e``, or ``K e`` for a matrix."""
    return K @ e if isinstance(K, np.ndarray) else K * e


def spring_energy(K, e: np.ndarray) -> float:
    """What the coupling's spring holds at the stretch ``e``: ``½ kd |e|²`` or ``½ eᵀ K e``."""
    return 0.5 * float(e @ K @ e) if isinstance(K, np.ndarray) else 0.5 * K * float(e @ e)


def explained(stretch: np.ndarray, normal: np.ndarray, K) -> np.ndarray:
    """The stretch less what a plane of ``normal`` pushing on the god-object explains: its push
    ``λ n`` holds the stretch ``λ K⁻¹ n`` (``λ/kd n`` for a scalar); the part along ``n`` is
    taken, so what is left has no component along ``n`` (scalar) or pushes nothing along it
    (``nᵀ K⁻¹ K (rest) = 0``)."""
    along = float(np.dot(normal, stretch))
    if along <= 0.0:
        return stretch
    if not isinstance(K, np.ndarray):
        return stretch - along * normal
    w = np.linalg.solve(K, normal)
    return stretch - along / float(normal @ w) * w


class LocalRenderer:
    """The force from the newest local model (module docstring).

    - :meth:`take` a model (and the handle position the scene had used, or None: its target);
    - :meth:`validity` its weight now (1 fresh, fading to 0);
    - :meth:`request` the force for the handle at ``h`` now;
    - :meth:`rendered` what the device was actually commanded (after :class:`ForceSafety`): the
      energy budget counts that.
    """

    def __init__(self):
        self.model: LocalModel | None = None
        self.arrived = -math.inf
        self.alive_at = -math.inf  # the newest heartbeat naming the model's time
        self.beats = 0  # heartbeats taken
        self.gaps: deque = deque(maxlen=16)
        self.planes: list = []
        self.offset = np.zeros(3)  # o: the stretch no plane explains
        self.grasp = np.zeros(3)  # c: the target from the handle (the grasp offset)
        self.energy_in = 0.0  # E_in (J): the work the hand has done on the device (held forces)
        self.energy_v = 0.0  # E_v (J): the same, on the virtual environment (trapezoid)
        self._env = None  # what the last request rendered: (c + o, c, planes, kd, β)
        self.spring = 0.0  # S (J) as last requested
        self.beta = 1.0
        self.weight = 0.0  # the model's validity at the last request
        self.damping = 0.0  # N·s/m: the passivity controller's at the last request
        self.K = self.D = 0.0  # the coupling's stiffness and damping: kd, γd or 3×3 matrices (GLM3)
        self.unpaid = 0.0  # J: spring energy asked for and not rendered, summed
        self.trips = 0
        self.models = 0
        self._h: np.ndarray | None = None  # the handle at the last render
        self._t: float | None = None  # when the last request was made (the driver's clock, s)
        self._f = np.zeros(3)  # the force last rendered
        self._damper = np.zeros(3)  # the controller's part of the force last requested
        self._was_valid = False

    @property
    def heard(self) -> bool:
        return self.model is not None

    def take(self, model: LocalModel, arrived: float, h_used=None) -> None:
        if self.model is not None and arrived > self.arrived:
            self.gaps.append(arrived - self.arrived)
        self.model, self.arrived = model, float(arrived)
        self.models += 1
        if model.stiffness is None:  # GLM2: the scalar gains, rendered exactly as before GLM3
            self.K, self.D = model.kd, model.gamma_d
        else:  # GLM3: the coupling's matrices at the device
            self.K = np.array(model.stiffness, float).reshape(3, 3)
            self.D = np.array(model.damping, float).reshape(3, 3)
        p_G, p_T = np.array(model.p_G, float), np.array(model.p_T, float)
        h_used = p_T if h_used is None else np.array(h_used, float)
        self.planes = [(np.array(p, float), np.array(n, float), float(s)) for p, n, s in model.planes]
        self.grasp = p_T - h_used
        stretch = p_G - p_T
        # free space: the coupling's free lag is no force (module docstring); a matrix model
        # (GLM3) states its lag whatever its planes: the whole stretch while its tool touches
        # nothing, none while it does (docs/local_model.md "An articulated tool")
        if not self.planes or model.stiffness is not None:
            stretch = stretch - np.array(model.lag, float)
        for point, normal, _ in self.planes:  # what the planes holding G (on or in them) explain
            if float(np.dot(normal, p_G - point)) <= ACTIVE_M:
                stretch = explained(stretch, normal, self.K)
        self.offset = stretch if np.any(self.K) else np.zeros(3)

    def alive(self, scene_utime: int, arrived: float) -> None:
        """The scene's heartbeat of ``arrived``: alive, its newest model of ``scene_utime``
        standing. Holds the model as its arrival would, if it names the model rendered (a
        heartbeat for another model, one lost or not yet here, holds nothing)."""
        if self.model is not None and scene_utime == self.model.scene_utime:
            self.alive_at = max(self.alive_at, float(arrived))
            self.beats += 1

    def gap(self) -> float:
        """The scene's period (s): its stated one, or the median of the last 16 intervals between
        its models when longer (a scene slower than it says), at most :data:`MAX_GAP_S`."""
        if self.model is None:
            return MAX_GAP_S
        seen = float(np.median(self.gaps)) if self.gaps else 0.0
        return min(max(seen, self.model.period_s), MAX_GAP_S)

    def fade_end(self) -> float:
        """How long after the scene's last word the newest model is rendered at all (s):
        ``3 gap + 50 ms``."""
        return END_GAPS * self.gap() + END_EXTRA_S

    def validity(self, now: float) -> float:
        """The model's weight at ``now``: 1 until ``2 gap + 25 ms`` after the scene's last word
        (its arrival or a later heartbeat), then linear to 0 at ``3 gap + 50 ms``; 0 with no
        model. Counts a trip at each fall to 0."""
        if self.model is None:
            return 0.0
        gap, age = self.gap(), now - max(self.arrived, self.alive_at)
        hold, end = HOLD_GAPS * gap + HOLD_EXTRA_S, self.fade_end()
        weight = 1.0 if age <= hold else 0.0 if age >= end else (end - age) / (end - hold)
        valid = weight > 0.0
        if self._was_valid and not valid:
            self.trips += 1
        self._was_valid = valid
        return weight

    def proxy(self, h) -> np.ndarray:
        """The proxy ``x`` for the handle at ``h`` (the god-object's point: ``h + c`` moved by the
        free part and out of the planes)."""
        return project(np.asarray(h, float) + self.grasp + self.offset, self.planes, self.K)

    def request(self, h, now: float, period_s: float, live: bool = True) -> np.ndarray:
        """The force to render for the handle at ``h`` now (module docstring): the free part
        ``kd o`` and the planes' spring ``kd (x − y)`` (and the damper on the stretch's rate),
        scaled by the budget's ``β`` and the model's validity (:attr:`weight`), plus the
        passivity controller's damper while the spring holds more than the hand put in; zero
        when not ``live`` (a stop, the clutch). Called every period: the budget counts every move."""
        h = np.asarray(h, float)
        before = self._h
        # the handle moved from ``before`` over the time since the last request: a period, or
        # more when the driver's loop was held up (a rate over the nominal period would be that
        # many times too fast: the damper's spike after a stall)
        elapsed = period_s if self._t is None else max(period_s, now - self._t)
        self._t = now
        self._account(h)
        weight = self.weight = self.validity(now)
        self.damping, self._damper = 0.0, np.zeros(3)
        if self.model is None or weight == 0.0 or not live:
            self.spring, self.beta, self._env = 0.0, 0.0, None
            return np.zeros(3)
        K, D = self.K, self.D
        hc = h + self.grasp  # the target now
        y = hc + self.offset
        x = project(y, self.planes, K)
        rate = np.zeros(3)
        if before is not None and np.any(D > 0.0) and period_s > 0.0:
            b = before + self.grasp  # the same model: a re-anchoring is no rate
            rate = ((x - hc) - (project(b + self.offset, self.planes, K) - b)) / elapsed
        spring = spring_energy(K, x - y)
        budget = self.energy_v + ALLOWANCE_J
        if spring <= budget:
            beta = 1.0
        else:
            beta = math.sqrt(budget / spring) if budget > 0.0 else 0.0
            self.unpaid += spring - max(budget, 0.0)
        self.beta = min(beta, weight)
        self.spring = self.beta**2 * spring
        # what the hand put in and the spring the budget pays for does not hold went into the
        # scene's damping (the coupling's lag, a body's friction): it is not banked to pay a later
        # push (a leak); a fade keeps what the faded spring held, for the model that follows
        paid = beta**2 * spring + BANK_J
        self.energy_v, self.energy_in = min(self.energy_v, paid), min(self.energy_in, paid)
        self._env = (self.grasp + self.offset, self.grasp, self.planes, K, self.beta)
        f = self.beta * (spring_force(K, x - hc) + spring_force(D, rate))
        # short in either account: the device's (its held forces) or the environment's (a free
        # force that pulled the hand along, a change of model): the damper asks it back
        deficit = max(self.spring - self.energy_in, -self.energy_v - ALLOWANCE_J)
        if deficit > 0.0 and before is not None and period_s > 0.0:  # the controller
            v = (h - before) / elapsed
            speed2 = float(v @ v)
            # > 0 as a product: a hand settling on a steady force moves by steps whose square
            # underflows (its speed² × T is 0.0 while its speed² is not): no damper, no division by 0
            if speed2 * period_s > 0.0:
                self.damping = min(MAX_DAMPING, deficit / (speed2 * period_s))
                self._damper = -self.damping * v
                f = f + self._damper
        return f

    def _environment(self, h: np.ndarray) -> np.ndarray:
        """The force the environment rendered at the last request gives at ``h`` (its model
        and scaling, before any new model): the virtual spring's force, for the trapezoid."""
        if self._env is None:
            return np.zeros(3)
        offset, grasp, planes, kd, beta = self._env
        stretch = project(h + offset, planes, kd) - h - grasp
        return beta * (kd @ stretch) if isinstance(kd, np.ndarray) else beta * kd * stretch

    def _account(self, h: np.ndarray) -> None:
        if self._h is not None:
            step = h - self._h
            self.energy_in -= float(self._f @ step)
            # the environment's part of the held force by the trapezoid, the damper's as held
            self.energy_v -= float((0.5 * (self._f + self._damper + self._environment(h))) @ step)
        self._h = h.copy()

    def rendered(self, f) -> None:
        """The force the device was commanded this period (held until the next)."""
        self._f = np.array(f, float)

    @property
    def reserve(self) -> float:
        """``E_in − S`` (J): the energy the hand put in and the spring does not hold: ≥ 0 while
        the device is passive (module docstring)."""
        return self.energy_in - self.spring
