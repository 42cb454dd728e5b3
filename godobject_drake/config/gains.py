"""The coupling's and the feedback's gains, and the grasp-name convention: plain config types.

:class:`CouplingGains` (paper Eq. 2–3) gives the spring by bandwidth and damping ratio, scaled by
each held body's own mass and inertia; :class:`FeedbackGains` (Eq. 8) are absolute, chosen for the
device. Both load from a scenario file field by field and check themselves where they are used.
"""

import dataclasses
import math
import warnings

from godobject_drake.limits import explicit_limit_omega_h

PAPER_DAMPING_RATIO_RANGE = (0.7, 1.0)  # paper: 1.4 ≤ γ/√(mk) ≤ 2, i.e. 2ζ.


GRASP_NEAREST = "*"  # grasp name: the nearest free body within reach (a live device's button)


class CouplingGainError(ValueError):
    """Gains that the explicit (symplectic Euler) coupling cannot integrate stably."""


class CouplingGainWarning(UserWarning):
    """Gains outside the paper's recommended damping range."""


@dataclasses.dataclass
class CouplingGains:
    """Coupling gains by bandwidth, scaled per body by its mass and inertia.

    A plain, mutable config (a scenario file fills it field by field); :meth:`check`
    validates it where it is used.

    Attributes
    ----------
    omega_n : float
        Translational natural frequency ωn (rad/s): ``k = m ωn²``.
    zeta : float
        Translational damping ratio ζ: ``γ = 2 ζ m ωn``.
    omega_n_rot : float | None
        Rotational natural frequency (rad/s), ``kr = I ωr²``; None = omega_n (the same
        bandwidth). The brick scene sets 3 × omega_n: a hand holds a tool's orientation
        firmer than its position.
    zeta_rot : float | None
        Rotational damping ratio; None = zeta.
    """

    omega_n: float = 40.0
    zeta: float = 1.0
    omega_n_rot: float | None = None
    zeta_rot: float | None = None

    @property
    def omega_r(self) -> float:
        return self.omega_n if self.omega_n_rot is None else self.omega_n_rot

    @property
    def zeta_r(self) -> float:
        return self.zeta if self.zeta_rot is None else self.zeta_rot

    def translational(self, mass: float) -> tuple[float, float]:
        """``(k, γ)`` in N/m and N·s/m for a body of ``mass`` kg."""
        return mass * self.omega_n**2, 2.0 * self.zeta * mass * self.omega_n

    def check(self, time_step: float) -> None:
        """Raise :class:`CouplingGainError` past the explicit stability limit, naming every gain
        past it (the translation's and the rotation's) and the step that would take them all.

        Also warns (:class:`CouplingGainWarning`) when a damping ratio is
        outside the paper's ``[0.7, 1]``. ``time_step = 0`` (continuous plant)
        skips the step-size check.
        """
        past = []
        for label, w, z in (
            ("omega_n", self.omega_n, self.zeta),
            ("omega_n_rot", self.omega_r, self.zeta_r),
        ):
            if not (math.isfinite(w) and w > 0.0):
                raise CouplingGainError(f"{label}={w!r} rad/s must be a positive number")
            if not (math.isfinite(z) and z >= 0.0):
                raise CouplingGainError(f"damping ratio {z!r} for {label} must be ≥ 0")
            lo, hi = PAPER_DAMPING_RATIO_RANGE
            if not lo <= z <= hi:
                warnings.warn(
                    f"damping ratio ζ={z:g} for {label} is outside the paper's "
                    f"[{lo}, {hi}] (1.4 ≤ γ/√(mk) ≤ 2); the god-object will "
                    f"{'overshoot and ring' if z < lo else 'lag'}",
                    CouplingGainWarning,
                    stacklevel=3,
                )
            follows = label == "omega_n_rot" and self.omega_n_rot is None and z == self.zeta
            if time_step > 0.0 and not follows:  # a rotation that follows omega_n is fixed with it
                limit = explicit_limit_omega_h(z)
                if w * time_step >= limit:
                    past.append((label, w, z, limit))
        if not past:
            return
        said = []
        for i, (label, w, z, limit) in enumerate(past):
            at = f" at time_step={time_step:g} s" if i == 0 else ""
            said.append(
                f"{label}={w:g} rad/s{at} gives ωn·h={w * time_step:.4g}, past the explicit (symplectic "
                f"Euler) stability limit 2(√(1+ζ²)−ζ)={limit:.4g} for ζ={z:g}"
            )
        gains = " and ".join(f"{label} < {limit / time_step:.4g} rad/s" for label, _, _, limit in past)
        h_max = min(limit / w for _, w, _, limit in past)
        sep = ", or" if len(past) > 1 else " or"
        raise CouplingGainError(f"{'; '.join(said)}. Use {gains}{sep} time_step < {h_max:.4g} s.")


DEFAULT_MAX_STRETCH_M = 0.2

# The stiffest spring a supported haptic device renders (N/m, the device's frame: ``scale² kd``):
# the omega.3's closed-loop stiffness, 14.5 N/mm (Force Dimension's datasheet, as cited in
# docs/haptic_devices.md; not re-read here), the stiffest of driver.families.RATED (a Touch's is
# 1.02 N/mm). A scene asking more of a device (``feedback.kd``) is refused at its start, and a driver
# refuses a local model asking more than its own family's figure.
MAX_RENDERED_STIFFNESS_N_M = 14_500.0


DEFAULT_MAX_TWIST_RAD = math.pi  # the largest possible error: only a velocity spike is cut


@dataclasses.dataclass
class FeedbackGains:
    """Feedback (virtual coupling) gains, absolute: they suit the device, not the body.

    Attributes
    ----------
    kd : float
        Translational stiffness (N/m). With a device that renders the feedback (``!Lcm``), at
        most 14,500 N/m on the device (``scale² kd``), the stiffest a supported device renders.
    gamma_d : float
        Translational damping (N·s/m).
    kd_rot : float
        Rotational stiffness (N·m/rad).
    gamma_d_rot : float
        Rotational damping (N·m·s/rad).
    """

    kd: float = 0.0
    gamma_d: float = 0.0
    kd_rot: float = 0.0
    gamma_d_rot: float = 0.0

    def __post_init__(self):
        self.check()

    def check(self) -> None:
        """Raise ``ValueError`` naming a gain that is negative or not finite."""
        for f in dataclasses.fields(self):
            v = getattr(self, f.name)
            if not (math.isfinite(v) and v >= 0.0):
                raise ValueError(f"feedback gain {f.name}={v!r} must be a finite number ≥ 0")
