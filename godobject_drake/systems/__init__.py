"""Drake systems of the god-object loop, knowing nothing of a scenario.

Each module is one role: the rigid coupling (:mod:`~.coupling`, paper Eq. 2) and its implicit
form (:mod:`~.implicit`), the feedback port (:mod:`~.feedback`, Eq. 8), the simulated haptic
devices and the user's hand (:mod:`~.haptic`), the articulated tool's coupling and feedback
(:mod:`~.articulated`, Eq. 4–9), the deformable shell (:mod:`~.shell`), FEM tissue
(:mod:`~.tissue`) and the Meshcat drawing (:mod:`~.drawing`). They take plain values and config
types (:mod:`godobject_drake.config`); :mod:`godobject_drake.station` wires them from a scenario.
"""
