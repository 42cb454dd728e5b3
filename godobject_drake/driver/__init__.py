"""A haptic device's driver process (``godobject-driver``): reads the device, renders the scene's
feedback, guards the force. It shares only :mod:`godobject_drake.link` with the scene (and
loads no ``pydrake.systems``)."""
