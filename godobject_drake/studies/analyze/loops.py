"""What ``analyze`` checks each loop model with (:data:`LOOPS`, keyed by a tool kind's
:func:`~godobject_drake.studies.analyze.common.loop_model`): its own rows, its haptic device's rows
and the prediction it simulates in Drake with ``--verify``."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

from godobject_drake.studies.analyze.articulated import _articulated_checks
from godobject_drake.studies.analyze.common import Check
from godobject_drake.studies.analyze.device import _device_checks
from godobject_drake.studies.analyze.implicit import _implicit_pose_checks
from godobject_drake.studies.analyze.pose_tool import _pose_tool_checks
from godobject_drake.studies.analyze.verify import _verify_explicit_limit, _verify_implicit_rate
from godobject_drake.studies.analyze.verify_joint import _verify_joint_space_limit


def _body_checks(station, out: dict) -> list[Check]:
    """A rigid or deformable tool's per-body explicit limits (symplectic Euler on its spring)."""
    _gains_row(station, out)
    return _pose_tool_checks(station, out)


def _implicit_body_checks(station, out: dict) -> list[Check]:
    """The implicit coupling's per-body decay rate and SAP regime (backward Euler on its spring)."""
    _gains_row(station, out)
    out["coupling"] = "implicit"
    return _implicit_pose_checks(station, out)


def _joint_checks(station, out: dict) -> list[Check]:
    """The articulated tool's joint-space loop at every ``check_every``-th device sample."""
    cfg = station.scenario.god_object
    out["coupling"] = cfg.coupling
    return _articulated_checks(station, out, station.scenario.simulation.duration_s, cfg.check_every)


def _gains_row(station, out: dict) -> None:
    g = station.coupling.gains
    out["gains"] = {"omega_n": g.omega_n, "zeta": g.zeta, "omega_n_rot": g.omega_r, "zeta_rot": g.zeta_r}


def _no_haptic_device(station, scenario, out: dict) -> list[Check]:
    return [Check("device", "haptic loop", "device", "info", None, None, "", "",
                  why="joint-space devices here are not haptic: no device loop to judge")]  # fmt: skip


def _verify_implicit(station, scenario, out: dict, rel_tol: float) -> Check | None:
    return _verify_implicit_rate(station, scenario, out)


@dataclasses.dataclass(frozen=True)
class Loop:
    """How ``analyze`` checks a loop model (:func:`loop_model`): its own rows, its haptic
    device's rows, and the prediction it simulates in Drake with ``--verify``."""

    checks: Callable
    device_checks: Callable
    verify: Callable


LOOPS = {
    "body": Loop(_body_checks, _device_checks, _verify_explicit_limit),
    "implicit_body": Loop(_implicit_body_checks, _device_checks, _verify_implicit),
    "joint": Loop(_joint_checks, _no_haptic_device, _verify_joint_space_limit),
}
