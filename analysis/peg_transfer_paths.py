"""The peg transfer scene's scripted sessions: each grasper's joint path, worked out from the board.

``python analysis/peg_transfer_paths.py [--out models/peg_transfer] [--session expert|clumsy|both]``
writes ``SESSION_left_path.yaml`` and ``SESSION_right_path.yaml`` (``channels: [yaw, pitch,
insertion, roll, jaw]``, ``waypoints``), the ScriptedJoints paths of diagrams/peg_transfer.yaml
(expert) and of its clumsy session (``--set`` the two paths: docs/guide/peg_transfer.md).

Each transfer: the left grasper comes down on the side of ring k nearest its trocar, closes its
jaws (they take the ring as it is: ``grasp.hold: pose``), lifts it clear of its peg and carries it
to a hand-off point in mid-air between the sides; the right grasper closes on the ring's side
nearest its own trocar, the left opens; the right carries the ring over its peg, lowers it onto
the peg and opens. While a grasper holds a ring its roll keeps the ring level: a held ring turns
with the tool (the trocar's pivot tilts it as the tip moves), and turning the tool about its axis
takes back what it can (least squares on the ring's centre and its axis).

The kinematics are the grasper's (models/laparoscopy/grasper.sdf): the tool's axis from the trocar
point P is ``Rx(yaw) Ry(pitch) (0, 0, -1)``, the jaws' hinge ``insertion`` along it and the grasp
point ``GRASP_POINT_M`` past the hinge; the tube's frame turns by ``roll`` about the axis.

The clumsy session: the same transfers with a longer, wandering path (a detour up and out on each
carry), slower, pressing each ring down onto the board past its rest with the right grasper
(deeper, a harder press), and one ring let go in mid-air away from every peg (a drop).
"""

import argparse
import math
from pathlib import Path

import numpy as np
from scipy.optimize import least_squares

PORTS = {"left": np.array([0.04, 0.11, 0.20]), "right": np.array([-0.04, 0.11, 0.20])}
LEFT_PEGS = [
    (0.026, -0.012),
    (0.044, -0.012),
    (0.062, -0.012),
    (0.035, 0.008),
    (0.053, 0.008),
    (0.044, 0.027),
]  # models/peg_transfer/pegboard.sdf: peg_l1 .. peg_l6
PEGS = {"left": LEFT_PEGS, "right": [(-x, y) for x, y in LEFT_PEGS]}
ORDER = (5, 4, 3, 2, 1, 0)  # the rings nearest the trocars first: the tools pass over the pegs behind
GRASP_POINT_M = 0.014  # the grasp point past the jaws' hinge along the tool (god_object.grasp.point_m)
RING_APOTHEM_M = 0.0056  # a bead on the ring's side (every 30°) from its centre
RING_REST_Z = 0.0013  # the ring's centre lying on the board
PICK_Z = 0.004  # the grasp point's height closing on a ring that lies on the board
LIFT_Z = 0.032  # the ring's centre carried clear of the pegs (their tops at 0.022)
HANDOFF = np.array([0.0, 0.02, 0.03])  # the ring's centre at the hand-off
PLACE_Z = 0.008  # the ring's centre let go over its peg (it drops to the board)
OPEN, SHUT = 0.6, 0.0


def at(p, x: float, y: float, z: float) -> np.ndarray:
    """The point ``p`` moved by (x, y, z) m."""
    return np.asarray(p, float) + np.array([x, y, z])


def rot(axis: int, a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    m = np.eye(3)
    i, j = [(1, 2), (2, 0), (0, 1)][axis]
    m[i, i], m[i, j], m[j, i], m[j, j] = c, -s, s, c
    return m


def tool_pose(side: str, q) -> tuple[np.ndarray, np.ndarray]:
    """The tube's rotation R_WT and the grasp point's position for joints (yaw, pitch, insertion, roll)."""
    yaw, pitch, insertion, roll = q
    R_Wtrocar = rot(0, yaw) @ rot(1, pitch)
    p = PORTS[side] + R_Wtrocar @ np.array([0.0, 0.0, -(insertion + GRASP_POINT_M)])
    return R_Wtrocar @ rot(2, roll), p


def reach(side: str, p: np.ndarray, roll: float = 0.0) -> np.ndarray:
    """The joints that put the grasp point at ``p`` (closed form), with ``roll``."""
    d = p - PORTS[side]
    n = float(np.linalg.norm(d))
    d = d / n
    return np.array([math.atan2(d[1], -d[2]), math.asin(-d[0]), n - GRASP_POINT_M, roll])


def carry(side: str, q0, held: tuple[np.ndarray, np.ndarray], centre: np.ndarray) -> np.ndarray:
    """The joints that carry a held ring (its rotation R_TB and centre p_TB in the tube's frame) to
    ``centre``, as level as the tool's roll makes it."""
    R_TB, p_TB = held

    def residual(q):
        R, g = tool_pose(side, q)
        c = g + R @ p_TB
        axis = R @ R_TB[:, 2]
        return np.concatenate([(c - centre) / 1e-4, np.cross(axis, [0, 0, 1]) / 0.02])

    return least_squares(residual, q0, xtol=1e-12, ftol=1e-12).x


def across(side: str, q, radial: np.ndarray) -> np.ndarray:
    """``q`` rolled so that the jaws open along the ring's side (the tube's y across ``radial``): the
    jaw that would go inside the ring stays clear of its peg."""
    rolls = np.linspace(-math.pi / 2, math.pi / 2, 721) + q[3]
    cost = [abs(float(tool_pose(side, [*q[:3], r])[0][:, 1] @ radial)) for r in rolls]
    return np.array([*q[:3], rolls[int(np.argmin(cost))]])


def take(side: str, q, R_WB: np.ndarray, p_WB: np.ndarray):
    """The ring held as it is (rotation R_WB, centre p_WB) by a tool at ``q``: (R_TB, p_TB)."""
    R, g = tool_pose(side, q)
    return R.T @ R_WB, R.T @ (p_WB - g)


def side_towards(side: str, centre: np.ndarray, R_WB: np.ndarray) -> np.ndarray:
    """The middle of the ring's side that faces ``side``'s trocar (the grasp point there)."""
    toward = PORTS[side][:2] - centre[:2]
    best, best_dot = None, -2.0
    for k in range(6):
        a = math.radians(30 + 60 * k)
        p = centre + R_WB @ np.array([RING_APOTHEM_M * math.cos(a), RING_APOTHEM_M * math.sin(a), 0.0])
        dot = float(np.dot((p - centre)[:2], toward) / (np.linalg.norm(toward) * RING_APOTHEM_M))
        if dot > best_dot:
            best, best_dot = p, dot
    return best


class Path_:
    """One grasper's waypoints, its clock advanced by each move."""

    def __init__(self, side: str, q, t0: float = 0.0):
        self.side, self.t, self.q, self.jaw = side, t0, np.asarray(q, float), OPEN
        self.points = [(t0, self.q.copy(), self.jaw)]

    def go(self, dt: float, q=None, jaw=None):
        self.t += dt
        if q is not None:
            self.q = np.asarray(q, float)
        if jaw is not None:
            self.jaw = jaw
        self.points.append((self.t, self.q.copy(), self.jaw))

    def wait_until(self, t: float):
        if t > self.t + 1e-9:
            self.go(t - self.t)


def session(clumsy: bool) -> dict[str, Path_]:
    """Both graspers' paths for the six transfers."""
    slow = 1.6 if clumsy else 1.0
    home = {s: reach(s, np.array([0.03 * (1 if s == "left" else -1), 0.02, 0.05])) for s in PORTS}
    left, right = Path_("left", home["left"]), Path_("right", home["right"])
    level = np.eye(3)
    for n, k in enumerate(ORDER):
        peg = np.array([*PEGS["left"][k], 0.0])
        centre = at(peg, 0, 0, RING_REST_Z)
        g = side_towards("left", centre, level)
        down = across("left", reach("left", at(g, 0, 0, PICK_Z - RING_REST_Z)), g - centre)
        over = across("left", reach("left", at(g, 0, 0, LIFT_Z), down[3]), g - centre)
        left.go(0.5 * slow, over, OPEN)  # over the ring's side, the open jaws clear of the peg's top
        left.go(0.3 * slow, across("left", reach("left", at(g, 0, 0, 0.012), down[3]), g - centre))
        left.go(0.5 * slow, down)  # down on its side
        left.go(0.25, jaw=SHUT)  # the jaws close: the ring is held
        left.go(0.15)
        held = take("left", left.q, level, centre)
        left.go(0.6 * slow, carry("left", left.q, held, at(peg, 0, 0, LIFT_Z)))  # off its peg
        if clumsy:  # a detour out and up: the longer path
            left.go(0.9, carry("left", left.q, held, at(peg, 0.01, 0.02, LIFT_Z + 0.025)))
        handoff = at(HANDOFF, 0.0, 0.004 * (n % 3 - 1), 0.0)
        left.go(0.9 * slow, carry("left", left.q, held, handoff))
        R_T, g_T = tool_pose("left", left.q)
        R_WB, p_WB = R_T @ held[0], g_T + R_T @ held[1]  # the ring at the hand-off, as held
        right.wait_until(left.t - 0.9 * slow)
        g = side_towards("right", p_WB, R_WB)
        away = (g - p_WB) / np.linalg.norm(g - p_WB)
        on = across("right", reach("right", g), g - p_WB)
        right.go(0.6 * slow, reach("right", at(g + 0.012 * away, 0, 0, 0.006), on[3]), OPEN)
        right.wait_until(left.t)
        right.go(0.4 * slow, on)  # on the ring's far side
        right.go(0.25, jaw=SHUT)
        right.go(0.1)
        left.wait_until(right.t)
        left.go(0.25, jaw=OPEN)  # the left lets go: the hand-off
        held_r = take("right", right.q, R_WB, p_WB)
        left.go(0.5, reach("left", at(tool_pose("left", left.q)[1], 0.012, 0.01, 0.012), left.q[3]))
        right.wait_until(left.t - 0.25)
        target = np.array([*PEGS["right"][k], 0.0])
        if clumsy and n == 2:  # this one is let go in mid-air, off every peg: a drop
            right.go(0.9 * slow, carry("right", right.q, held_r, np.array([-0.02, -0.03, LIFT_Z])))
            right.go(0.25, jaw=OPEN)
            right.go(0.5, reach("right", at(tool_pose("right", right.q)[1], -0.01, 0.01, 0.015), right.q[3]))
            continue
        if clumsy:
            right.go(0.9, carry("right", right.q, held_r, at(target, -0.015, 0.025, LIFT_Z + 0.025)))
        right.go(0.9 * slow, carry("right", right.q, held_r, at(target, 0, 0, LIFT_Z)))  # over its peg
        right.go(0.6 * slow, carry("right", right.q, held_r, at(target, 0, 0, PLACE_Z)))  # down the peg
        if clumsy:  # pressed onto the board, past where it rests: the harder press
            right.go(0.5, carry("right", right.q, held_r, at(target, 0, 0, RING_REST_Z - 0.001)))
            right.go(0.4)
        right.go(0.2, jaw=OPEN)
        right.go(0.5, reach("right", at(tool_pose("right", right.q)[1], -0.008, 0.01, 0.018), right.q[3]))
    end = max(left.t, right.t) + 1.0
    for p in (left, right):
        p.wait_until(end)
    return {"left": left, "right": right}


def write(path: Path_, file: Path, header: str) -> None:
    lines = [f"# {line}".rstrip() for line in header.splitlines()]
    lines += ["channels: [yaw, pitch, insertion, roll, jaw]", "waypoints:"]
    for t, q, jaw in path.points:
        names = ("yaw", "pitch", "insertion", "roll")
        values = ", ".join(f"{c}: {v:.5f}" for c, v in zip(names, q, strict=True))
        lines.append(f"- {{t: {t:.3f}, values: {{{values}, jaw: {jaw:.2f}}}}}")
    file.write_text("\n".join(lines) + "\n")


HEADER = """The peg transfer scene's {session} session, the {side} grasper (diagrams/peg_transfer.yaml;
docs/guide/peg_transfer.md). Written by analysis/peg_transfer_paths.py: edit that, not this."""


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path, default=Path("models/peg_transfer"))
    parser.add_argument("--session", choices=("expert", "clumsy", "both"), default="both")
    args = parser.parse_args(argv)
    for name in ("expert", "clumsy") if args.session == "both" else (args.session,):
        paths = session(name == "clumsy")
        for side, path in paths.items():
            file = args.out / f"{name}_{side}_path.yaml"
            write(path, file, HEADER.format(session=name, side=side))
            print(f"{file}: {len(path.points)} waypoints, {path.points[-1][0]:.2f} s")


if __name__ == "__main__":
    main()
