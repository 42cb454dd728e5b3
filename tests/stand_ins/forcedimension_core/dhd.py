"""Stand-in for ``forcedimension_core.dhd`` (README.md here), the signatures of the wrapper's
``forcedimension_core/dhd/__init__.py``: ``open() -> ID`` (−1: none), ``enableForce(enable, ID=-1)``,
``getPosition(out, ID=-1)``, ``getButton(index, ID=-1)``, ``setForce(f, ID=-1)``, ``stop(ID=-1)``,
``close(ID=-1)``, ``errorGetLastStr()``; 0 on success, −1 on error. ``expert``: the wrapper's
``forcedimension_core/dhd/expert/__init__.py`` (a subpackage there), its ``enableExpertMode()``,
``disableExpertMode()`` and ``setWatchdog(duration, ID=-1)`` (units of 125 µs; 0 disables)."""

from godobject_drake.driver.families import EmulatedDevice

HAND = None
forces: list[list[float]] = []
state = {"device": None, "force_enabled": False, "stopped": False, "closed": False, "expert": False,
         "watchdog": 0, "has_watchdog": True}  # fmt: skip


def errorGetLastStr() -> str:
    return "no error (stand-in)"


def open() -> int:
    state.update(device=EmulatedDevice(HAND, start_on_scene=False), closed=False, stopped=False)
    return 0


def enableForce(enable: bool, ID: int = -1) -> int:
    state["force_enabled"] = bool(enable)
    return 0


def getPosition(out, ID: int = -1) -> int:
    p, _, _ = state["device"].read()
    out[0], out[1], out[2] = (float(v) for v in p)
    return 0


def getButton(index: int, ID: int = -1) -> int:
    device = state["device"]
    _, grasp, clutch = device.hand.at(device.hand_time())
    return int((grasp, clutch)[index]) if index < 2 else 0


def setForce(f, ID: int = -1) -> int:
    if not state["force_enabled"]:
        return -1
    forces.append([float(v) for v in f])
    state["device"].render(f)
    return 0


def stop(ID: int = -1) -> int:
    state["stopped"] = True
    state["force_enabled"] = False
    return 0


def close(ID: int = -1) -> int:
    state["closed"] = True
    return 0


class expert:  # the wrapper's subpackage, as a namespace
    @staticmethod
    def enableExpertMode() -> int:
        state["expert"] = True
        return 0

    @staticmethod
    def disableExpertMode() -> int:
        state["expert"] = False
        return 0

    @staticmethod
    def setWatchdog(duration: int, ID: int = -1) -> int:
        if not state["expert"] or not state["has_watchdog"]:
            return -1
        state["watchdog"] = int(duration)
        return 0
