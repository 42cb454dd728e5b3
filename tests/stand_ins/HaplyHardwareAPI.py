"""Stand-in for Haply's ``HaplyHardwareAPI`` (README.md here): ``detect_inverse3s()``,
``SerialStream(port)``, ``Inverse3(stream)`` with ``device_wakeup_dict()`` and
``end_effector_force(forces) -> (position, velocity)`` (Haply's published examples)."""

from godobject_drake.driver.families import EmulatedDevice

HAND = None
forces: list[list[float]] = []


def detect_inverse3s():
    return ["/dev/ttyEMULATED0"]


class SerialStream:
    def __init__(self, port: str):
        self.port = port


class Inverse3:
    def __init__(self, com_stream: SerialStream):
        self.stream = com_stream
        self.device = EmulatedDevice(HAND, start_on_scene=False)

    def device_wakeup_dict(self) -> dict:
        return {"device_id": 1, "port": self.stream.port}

    def end_effector_force(self, forces_n):
        forces.append([float(v) for v in forces_n])
        self.device.render(forces_n)
        p, _, _ = self.device.read()
        return list(p), list(self.device.v)
