"""The link between a scene and a device's driver process (docs/haptic_devices.md), in one place:

- :mod:`~godobject_drake.link.messages`: the channels, the pose and status messages, the local
  model's and the heartbeat's payloads: what the two ends say;
- :mod:`~godobject_drake.link.keys`: the key file both ends pair with;
- :mod:`~godobject_drake.link.transport`: the paired, authenticated unicast UDP that carries the
  messages (``UdpLcm``, its two ends' checks, ``make_lcm`` / ``driver_lcm``);
- :mod:`~godobject_drake.link.logs`: the link's logger and the stderr handler both ends log with;
- :mod:`~godobject_drake.link.scene_model`: the scene's half of the local model (a Drake system,
  the free lag, the heartbeat); the driver's half is :mod:`godobject_drake.driver.local_model`.

A driver process imports the first four only, and so loads no ``pydrake.systems``
(tests/test_structure.py): this file imports none of them.
"""
