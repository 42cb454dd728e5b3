"""Command-line flags as aliases of scenario fields: ``--omega-n 30`` is
``--set god_object.gains.omega_n=30``.

A :class:`Flag` names the one field it sets (a dotted path from the scenario's top), its help and
the type argparse parses its value with. The few real special cases are declared on the flag
itself, once: :attr:`Flag.value` turns the command line's word into the field's value (``--sleep
off`` is ``sleep.enabled: false``) and :attr:`Flag.also` names the other fields a flag sets with it
(``--contact hydroelastic`` sets the plant's contact model too). The common flags are in
:mod:`godobject_drake.cli`; a tool kind's own flags are its config's ``FLAGS``
(:mod:`godobject_drake.config.tools`), registered with the kind.
"""

import dataclasses
from collections.abc import Callable
from typing import Any


@dataclasses.dataclass(frozen=True)
class Flag:
    """One command-line flag: an alias of one scenario field.

    Attributes
    ----------
    name : str
        ``--omega-n``.
    field : str | None
        The dotted field it sets (``god_object.gains.omega_n``); None: an option of the run, not
        of the scenario (``--no-progress``).
    help : str
        What the field means, with its unit.
    type : callable | None
        How argparse reads the value (``float``, ``int``, ``Path``); None: a string.
    choices : tuple | callable | None
        The allowed values, or a function giving them when the parser is made (a registry's names).
    action : str | None
        argparse's action (``store_true`` for a switch).
    value : callable | None
        ``value(given, scenario) -> field value`` where the word given is not the value itself.
    also : callable | None
        ``also(given, scenario, flags_given) -> {field: value}``: the other fields it sets.
    """

    name: str
    field: str | None
    help: str
    type: Callable | None = None
    choices: tuple | Callable | None = None
    action: str | None = None
    value: Callable[[Any, Any], Any] | None = None
    also: Callable[[Any, Any, set], dict] | None = None

    @property
    def dest(self) -> str:
        """The argparse attribute: ``--omega-n`` → ``omega_n``."""
        return self.name[2:].replace("-", "_")


def on_off(given: str, scenario) -> bool:
    """``on``/``off`` → True/False."""
    return given == "on"
