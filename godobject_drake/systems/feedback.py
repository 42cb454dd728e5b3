"""The feedback port (paper Eq. 8): the wrench a haptic device renders.

A second, independent coupling between the god-object G and the target T
gives the force fed back to the device::

    f_D = kd (p_WG − p_WT) + γd (v_WG − v_WT)
    τ_T = kd_r α_fb u_fb + γd_r (w_WG − w_WT),   α_fb u_fb = axis-angle of q_WG q_WT⁻¹

Sign convention: ``F_Do_W`` is the wrench the device should apply to the
user's hand, expressed in W and taken about the device point Do
(``τ_Do = τ_T + p_DoTo × f``). It pulls the hand toward the god-object: when
an obstacle stops G short of T, the user feels the obstacle. All gains zero
(the default) is a non-haptic device: zero wrench, same god-object loop.
"""

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.math import RigidTransform
from pydrake.systems.framework import LeafSystem

from godobject_drake.config.gains import FeedbackGains
from godobject_drake.spatial import cross3, pose_arrays, rotation_error


class FeedbackPort(LeafSystem):
    """Computes the device wrench ``F_Do_W`` from the god-object and its target.

    .. pydrake_system::

        name: FeedbackPort
        input_ports:
        - X_WD
        - pose_WT
        - V_WT
        - pose_WG
        - V_WG
        output_ports:
        - F_Do_W

    ``X_WD`` is the device pose (abstract ``RigidTransform``); the others are
    the vector ports of the same names on
    :class:`~godobject_drake.systems.coupling.GodObjectCoupling`. ``F_Do_W`` is
    ``[τ; f]`` (N·m, N).
    """

    def __init__(self, gains: FeedbackGains | None = None):
        super().__init__()
        self.gains = gains or FeedbackGains()
        self.gains.check()
        self._X_WD = self.DeclareAbstractInputPort("X_WD", AbstractValue.Make(RigidTransform()))
        self._pose_WT = self.DeclareVectorInputPort("pose_WT", 7)
        self._V_WT = self.DeclareVectorInputPort("V_WT", 6)
        self._pose_WG = self.DeclareVectorInputPort("pose_WG", 7)
        self._V_WG = self.DeclareVectorInputPort("V_WG", 6)
        self.DeclareVectorOutputPort("F_Do_W", 6, self._calc, {self.all_input_ports_ticket()})

    def _calc(self, context, output):
        g = self.gains
        pose_WT, V_WT = self._pose_WT.Eval(context), self._V_WT.Eval(context)
        pose_WG, V_WG = self._pose_WG.Eval(context), self._V_WG.Eval(context)
        f = g.kd * (pose_WG[4:] - pose_WT[4:]) + g.gamma_d * (V_WG[3:] - V_WT[3:])
        tau_T = g.kd_rot * rotation_error(pose_WG[:4], pose_WT[:4]) + g.gamma_d_rot * (V_WG[:3] - V_WT[:3])
        _, p_WD, _ = pose_arrays(self._X_WD.Eval(context))
        output.SetFromVector(np.concatenate([tau_T + cross3(pose_WT[4:] - p_WD, f), f]))
