"""The link's logger, and the handler both of its ends (the scene's command line, a driver's
process) write their lines through."""

from __future__ import annotations

import logging
import sys

log = logging.getLogger("godobject_drake.link")


class StderrHandler(logging.StreamHandler):
    """A handler that writes to ``sys.stderr`` as it is when a line is written, not as it was when
    the handler was made: a handler kept past a replaced stderr (the driver's ``main`` run in a
    process that swaps it, as a test's capture does) wrote to a closed stream ("Logging error")."""

    def emit(self, record: logging.LogRecord) -> None:
        self.stream = sys.stderr
        super().emit(record)
