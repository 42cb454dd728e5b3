"""Stand-in for ``pyOpenHaptics.hd_device.HapticDevice`` (README.md here):
``HapticDevice(callback, device_name="Default Device", scheduler_type="async")`` starts the servo
loop, calling ``callback`` every millisecond in its own thread with the frame's state set;
``close()`` stops it."""

import threading
import time

from godobject_drake.driver.families import EmulatedDevice

from . import hd


class HapticDevice:
    def __init__(self, callback, device_name: str = "Default Device", scheduler_type: str = "async"):
        hd.frame["device"] = EmulatedDevice(hd.HAND, start_on_scene=False)
        self._stop = threading.Event()
        self._callback = callback
        self._thread = threading.Thread(target=self._servo, daemon=True)
        self._thread.start()

    def _servo(self):
        while not self._stop.is_set():
            device = hd.frame["device"]
            p, _, _ = device.read()
            _, grasp, clutch = device.hand.at(device.hand_time())
            hd.frame["p_mm"] = [float(v) * 1000.0 for v in p]
            hd.frame["buttons"] = int(grasp) | int(clutch) << 1
            self._callback()
            time.sleep(0.001)

    def close(self):
        self._stop.set()
        self._thread.join()
