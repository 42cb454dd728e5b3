"""Stand-in for ``pyOpenHaptics.hd`` (README.md here): ``get_transform()`` (4 × 4, translation in
its last row, mm), ``get_buttons()`` (a bit mask), ``set_force([fx, fy, fz])`` (N), valid inside
the servo callback, as OpenHaptics' ``hdGetDoublev``/``hdSetDoublev`` are."""

HAND = None
forces: list[list[float]] = []
frame = {"device": None, "p_mm": [0.0, 0.0, 0.0], "buttons": 0}


def get_transform():
    m = [[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]]
    m[3][0], m[3][1], m[3][2] = frame["p_mm"]
    return m


def get_buttons() -> int:
    return frame["buttons"]


def set_force(feedback) -> None:
    forces.append([float(v) for v in feedback])
    frame["device"].render(feedback)
