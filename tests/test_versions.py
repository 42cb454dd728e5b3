"""The Drake each Python gets, and the guard against the next Drake's deprecations."""

import sys
import warnings
from importlib.metadata import version

import pytest
from conftest import DRAKE_DEPRECATIONS
from pydrake.common.deprecation import DrakeDeprecationWarning


def test_each_python_gets_its_pinned_drake():
    # pyproject.toml: 1.51.1 is the last Drake with Python 3.11 wheels; 3.12 and later get 1.58.0.
    expected = "1.51.1" if sys.version_info < (3, 12) else "1.58.0"
    assert version("drake") == expected


def test_a_drake_deprecation_warning_is_an_error():
    with pytest.raises(DrakeDeprecationWarning, match="was deprecated"):
        warnings.warn("a pydrake API was deprecated", DrakeDeprecationWarning, stacklevel=1)


def test_a_deprecation_in_drakes_log_is_caught():
    import logging

    seen = len(DRAKE_DEPRECATIONS.messages)
    logging.getLogger("drake").warning("Foo() is deprecated and will be removed from Drake on or after 2027")
    assert DRAKE_DEPRECATIONS.messages[seen:] == [
        "Foo() is deprecated and will be removed from Drake on or after 2027"
    ]
    DRAKE_DEPRECATIONS.messages.pop()  # this test's own message: not a failure of the suite
