"""``python -m godobject_drake run SCENARIO.yaml [flags]``: run a scenario (``--help`` for the flags)."""

import sys

from godobject_drake.cli import main

if __name__ == "__main__":
    sys.exit(main())
