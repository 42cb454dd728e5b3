"""Stand-in for ``pyOpenHaptics`` (README.md here): ``hd``, ``hd_callback``, ``hd_device``."""
