"""Stand-in for ``pyOpenHaptics.hd_callback.hd_callback`` (README.md here): the decorator that
makes a function the servo callback (the real one wraps it in begin/end frame for ctypes)."""


def hd_callback(input_function):
    return input_function
