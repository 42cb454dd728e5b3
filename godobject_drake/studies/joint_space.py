"""The articulated tool's loop, linearized: its response to a device's path, step by step.

What ``tests/test_laparoscopy.py`` holds Drake's articulated coupling against: the joint targets as
the coupling holds them (:func:`device_targets`) and the linear model's joint positions under them
(:func:`linear_response`), for the explicit and the implicit (SAP) joint-space couplings. The loop
itself (:func:`~godobject_drake.systems.articulated.joint_space_loop`) stays with the coupling,
which refuses gains whose loop is unstable.
"""

import math

import numpy as np

from godobject_drake.systems.articulated import JointSpaceLoop


def device_targets(device, time_step: float, n_steps: int, coupling_offset: float = 0.5):
    """The joint targets ``(q_T, qdot_T)`` in effect during each plant step, as the coupling holds them.

    The device samples at ``kT``; the coupling copies the sample at
    ``kT + ½h``, so plant step n (from ``nh``) uses sample
    ``k = ⌊(n − ½) h / T⌋`` (the reference before the first), with the
    backward-difference rate ``(q_k − q_{k−1}) / T``.
    """
    T = device.period_s
    q_T, v_T = [], []
    for n in range(n_steps):
        k = max(math.floor(((n - coupling_offset) * time_step) / T + 1e-9), 0)
        q_k = device.sample(k * T)
        q_T.append(q_k)
        v_T.append((q_k - device.sample((k - 1) * T)) / T if k > 0 else np.zeros_like(q_k))
    return np.array(q_T), np.array(v_T)


def linear_response(loop: JointSpaceLoop, q0, q_T, v_T, implicit: bool) -> np.ndarray:
    """Joint positions of the linearized coupled tool, step by step (no contact, gravity compensated).

    Explicit (Drake's applied forces): ``v⁺ = v + h M⁻¹(K (q_T − q) + D (v_T − v))``;
    implicit (SAP's PD actuators): the same with ``q + h v⁺`` and ``v⁺`` in
    the force. ``q_T``, ``v_T``: (N, n) targets per step, on the coupled
    joints. Returns (N + 1, n) positions, ``q0`` first.
    """
    M, K, D, h = loop.M, loop.K, loop.D, loop.time_step
    q = np.array(q0, dtype=float)
    v = np.zeros_like(q)
    A = M + h * D + h * h * K
    out = [q.copy()]
    for qt, vt in zip(q_T, v_T, strict=True):
        if implicit:
            v = np.linalg.solve(A, M @ v + h * (K @ (qt - q) + D @ vt))
        else:
            v = v + h * np.linalg.solve(M, K @ (qt - q) + D @ (vt - v))
        q = q + h * v
        out.append(q.copy())
    return np.array(out)
