"""The command line: ``python -m godobject_drake run SCENARIO.yaml [flags]``, ``python -m
godobject_drake analyze SCENARIO.yaml [--out DIR] [flags]``, and the scene scripts.

Every named flag is an alias of one scenario field, ``--set FIELD=VALUE`` (``--help`` names the
field; the few that set a second field declare it: :mod:`godobject_drake.config.flags`); a flag
left out keeps the scenario's value. The scene scripts (``diagrams/*.py``) are ``run`` on their own
scenario file (:func:`scene_main`): one build path for every entry point.
"""

import argparse
import copy
import dataclasses
import logging
import math
import re
import signal
import sys
import threading
import warnings
from pathlib import Path

from godobject_drake import __version__
from godobject_drake.config import scenario as sc
from godobject_drake.config.device_files import INTERPOLATIONS
from godobject_drake.config.devices import DEVICE_KINDS, kinds_in
from godobject_drake.config.flags import Flag, on_off
from godobject_drake.config.gains import CouplingGainError
from godobject_drake.config.tools import TOOL_CONFIGS, ShellSpecError
from godobject_drake.link.logs import StderrHandler
from godobject_drake.metrics import PenetrationBudgetWarning, format_table, write_metrics
from godobject_drake.outputs import OutputError, OutputLock, SignalsHeld, check_output, is_stream
from godobject_drake.safeguards import WiringError
from godobject_drake.simulation import DeviceNotHeardError, RunInterrupted, simulate
from godobject_drake.station.build import build_station

logger = logging.getLogger("godobject_drake")

DESCRIPTION = """Run a god-object scene, or analyse its stability.

  godobject run lego --record lego.html --metrics metrics.json
  godobject run my_scene.yaml --set simulation.duration_s=2
  godobject analyze lego --quick        # the report in analysis_lego/

A scenario is a YAML file or a shipped scene's name ('godobject run --help'
lists them). Every flag overrides one scenario field (its help names the
field); --set KEY=VALUE overrides any field. Exit status: 0 done, 1 a
diverged run or a failed check, 2 bad input. 'godobject run --help' lists
the flags."""


def device_names() -> tuple[str, ...]:
    """Every registered device kind's name, pose and joint alike (``--device NAME``), read when a
    parser is made, so a kind registered after this module was imported is offered too."""
    return tuple(dict.fromkeys(k.name for k in DEVICE_KINDS.values()))


def device_help() -> str:
    """``--device``'s help: each registered kind's name and summary (pose and joint kinds alike)."""
    summaries: dict[str, list[str]] = {}
    for k in DEVICE_KINDS.values():
        if k.summary not in summaries.setdefault(k.name, []):
            summaries[k.name].append(k.summary)
    kinds = "; ".join(f"{name}: {' / '.join(texts)}" for name, texts in summaries.items())
    return plain(f"{kinds}; a new kind keeps the old one's rate, latency and guard")


def _keep_rotation_ratio(given: float, s: sc.Scenario, flags: set) -> dict:
    """``--omega-n`` without ``--omega-n-rot`` keeps the scenario's rotation-to-translation ratio."""
    gains = s.god_object.gains
    if gains.omega_n_rot is None or "--omega-n-rot" in flags:
        return {}
    return {"god_object.gains.omega_n_rot": gains.omega_r / gains.omega_n * given}


def _contact_model(given: str, s: sc.Scenario, flags: set) -> dict:
    """``--contact`` picks the plant's contact model with the geometry that touches."""
    return {"plant.contact_model": "point" if given == "proxies" else "hydroelastic_with_fallback"}


def _as_str(given, s) -> str:
    return str(given)


# Each flag is an alias of one scenario field (config.flags.Flag): --omega-n 30 is
# --set god_object.gains.omega_n=30. The tool kinds add their own (config.tools: FLAGS).
COMMON_FLAGS = (
    Flag("--mode", "simulation.mode",
         "god_object: the PD coupling; position: impose the device pose (the baseline, the paper's Fig. 5)",
         choices=sc.SIMULATION_MODES),
    Flag("--duration", "simulation.duration_s", "simulated time (s)", type=float),
    Flag("--time-step", "plant.time_step", "plant step h (s)", type=float),
    Flag("--device", "device", device_help, choices=device_names),
    Flag("--lcm-url", "device.url",
         "a device read over LCM: Drake's LCM URL (default Drake's: UDP multicast; memq:// stays in the "
         "process)"),
    Flag("--lcm-wait", "device.wait_s",
         "LCM devices: seconds to wait for the driver's first sample before the run's clock starts "
         "(default 30 on udp://, 0 on memq://; 0: do not wait)", type=float),
    Flag("--device-log", "device.log",
         "the CSV for --device replay (t,x,y,z,qw,qx,qy,qz,grasp; a joint device's t,<channels>) or "
         "relative (t,dx,dy,dz,drx,dry,drz,clutch,grasp)", type=Path,
         value=lambda given, s: str(sc.absolute(given))),
    Flag("--device-rate", "device.rate_hz", "device rate (Hz), independent of --time-step", type=float),
    Flag("--device-latency", "device.latency_s", "device latency (s)", type=float),
    Flag("--device-interpolation", "device.interpolation",
         "between device samples: hold, or linear (smooth, one period late)", choices=INTERPOLATIONS),
    Flag("--max-device-speed", "device.guard.max_speed_m_s",
         "a sample farther than this speed (m/s) could go is held back as a glitch; inf: off", type=float),
    Flag("--device-noise", "device.noise_m",
         "std. dev. of Gaussian noise on each device position sample (m), seeded by --seed (sample k draws "
         "from (seed, k))", type=float),
    Flag("--seed", "random_seed", "seed of every random draw", type=int),
    Flag("--omega-n", "god_object.gains.omega_n", "coupling bandwidth ωn (rad/s); without --omega-n-rot "
         "the rotation keeps the scenario's ratio to it", type=float, also=_keep_rotation_ratio),
    Flag("--zeta", "god_object.gains.zeta", "coupling damping ratio ζ", type=float),
    Flag("--omega-n-rot", "god_object.gains.omega_n_rot", "rotational bandwidth (rad/s)", type=float),
    Flag("--contact", "contact.geometry", "collision geometry: proxies (point contact) or hydroelastic "
         "(sets plant.contact_model too)", choices=sc.CONTACT_GEOMETRIES, also=_contact_model),
    Flag("--contact-approximation", "plant.discrete_contact_approximation",
         "Drake's discrete contact approximation", choices=("sap", "lagged", "similar")),
    Flag("--haptic", "haptic.mode", "none: the device's pose is the target; impedance: a simulated 3-axis "
         "haptic device held by a simulated hand; admittance: a simulated admittance device",
         choices=sc.HAPTIC_MODES),
    Flag("--haptic-rate", "haptic.rate_hz", "haptic servo rate (Hz)", type=float),
    Flag("--kd", "feedback.kd", "feedback stiffness kd (N/m); the feedback port is wired with any gains, a "
         "haptic device or not", type=float),
    Flag("--gamma-d", "feedback.gamma_d", "feedback damping γd (N·s/m)", type=float),
    Flag("--passivity-damping", "haptic.passivity_damping",
         "a passivity observer/controller on the impedance device's feedback, its damping capped at this "
         "(N·s/m); 0: off", type=float),
    Flag("--record", "recording.file", "write a self-contained Meshcat HTML recording", type=Path,
         value=_as_str),
    Flag("--record-devices", "recording.device_log",
         "write each tool's device, as it was sampled tick by tick, to this CSV (several tools: one file "
         "each, the tool's name before the suffix), for --replay-devices", type=Path, value=_as_str),
    Flag("--replay-devices", None,
         "replay each tool's device from the logs --record-devices wrote (this file, or its stem and each "
         "tool's name): the same samples at the same ticks, so the same run", type=Path),
    Flag("--meshcat", "visualization.serve", "serve the run live in Meshcat, at real-time rate",
         action="store_true"),
    Flag("--meshcat-host", "visualization.host",
         "the interface Meshcat listens on; default localhost (this machine only). Another host lets "
         "anyone who reaches it drive the device: it is announced loudly; prefer an SSH tunnel"),
    Flag("--trust-local-pages", "visualization.trust_local_pages",
         "serve the live page with a haptic device (--haptic impedance|admittance, --device lcm) although "
         "any web page open on this machine can drive it (Drake's Meshcat checks no Origin): refused "
         "without this", action="store_true"),
    Flag("--force-cue", "visualization.force_cue",
         "rigid: the ghost and spring turn from faint to solid magenta as the stretch reaches the force cap",
         choices=("on", "off"), value=on_off),
    Flag("--tether", "device.tether_m", "relative and live devices: re-index the target after each sample "
         "to stay within this distance (m) of the god-object; inf: off", type=float),
    Flag("--tether-angle", "device.tether_angle_rad",
         "relative and live devices: ... and within this angle (rad); inf: off", type=float),
    Flag("--cd-ratio", "device.cd_ratio", "relative and live devices: the control/display ratio at the "
         "force cap; an increment pushing the target away from a blocked god-object is divided by a ratio "
         "growing from 1 to this; 1: off", type=float),
    Flag("--cd-onset", "device.cd_onset_m",
         "relative and live devices: the stretch (m) where the control/display ratio starts to grow",
         type=float),
    Flag("--sleep", "sleep.enabled",
         "lock free bodies that rest and that nothing can reach, so they cost nothing; off: all awake",
         choices=("on", "off"), value=on_off),
    Flag("--bricks", "bricks", "the brick scene's brick count: 8, and more on a grid in layers", type=int),
    Flag("--metrics", "metrics.file", "write the metrics JSON here", type=Path, value=_as_str),
    Flag("--no-progress", None, "no progress bar", action="store_true"),
)  # fmt: skip


def all_flags() -> tuple[Flag, ...]:
    """The common flags, then each registered tool kind's own (a flag two kinds share, once)."""
    seen, out = set(), []
    for flag in (*COMMON_FLAGS, *(f for config in TOOL_CONFIGS for f in getattr(config, "FLAGS", ()))):
        if flag.name not in seen:
            seen.add(flag.name)
            out.append(flag)
    return tuple(out)


# Flags of a run that ``analyze`` has no use for: it writes no recording or metrics file, serves
# no page, and stands a scripted device in for the scenario's (studies.analyze.analysis_scenario).
RUN_ONLY_FLAGS = frozenset({
    "--record", "--meshcat", "--meshcat-host", "--trust-local-pages", "--force-cue", "--metrics",
    "--no-progress", "--device", "--lcm-wait",
    "--device-log", "--lcm-url", "--device-interpolation", "--max-device-speed", "--device-noise", "--seed",
    "--tether", "--tether-angle", "--cd-ratio", "--cd-onset", "--record-devices",
})  # fmt: skip


def add_arguments(parser: argparse.ArgumentParser, exclude=frozenset()) -> None:
    """The flags (:func:`all_flags`) but those in ``exclude``, each help naming its field; then
    ``--set``, ``-v`` and ``-q``."""
    for flag in all_flags():
        if flag.name in exclude:
            continue
        options = {"dest": flag.dest}
        if flag.action:
            options["action"] = flag.action
        if flag.type:
            options["type"] = flag.type
        if flag.choices:
            options["choices"] = flag.choices() if callable(flag.choices) else flag.choices
        text = flag.help() if callable(flag.help) else flag.help
        parser.add_argument(flag.name, help=f"{text} [{flag.field}]" if flag.field else text, **options)
    parser.add_argument(
        "--set", action="append", default=[], metavar="KEY=VALUE", dest="set_fields",
        help="set any scenario field, e.g. --set simulation.duration_s=2 or --set 'feedback={kd: 50}' "
        "(the value is YAML; applied before the named flags; repeatable)",
    )  # fmt: skip
    parser.add_argument("-v", "--verbose", action="count", default=0, help="say more (debug messages)")
    parser.add_argument("-q", "--quiet", action="count", default=0, help="say only warnings and errors")


_KEY = re.compile(r"[A-Za-z_][A-Za-z0-9_]*(\.[A-Za-z_][A-Za-z0-9_]*)*")


def set_overrides(items: list[str]) -> str | None:
    """``--set a.b=v`` items as one YAML override text (``a:\n  b: v``); raises ``ScenarioError``
    naming an item that is not ``KEY=VALUE``."""
    tree: dict = {}
    for item in items:
        key, eq, value = item.partition("=")
        key = key.strip()
        if not eq or not _KEY.fullmatch(key):
            raise sc.ScenarioError(
                f"--set {item}: give KEY=VALUE with KEY a scenario field's dotted path, e.g. "
                "--set simulation.duration_s=2"
            )
        *parents, leaf = key.split(".")
        node = tree
        for part in parents:
            node = node.setdefault(part, {})
            if not isinstance(node, dict):
                raise sc.ScenarioError(f"--set {item}: {key} is inside a field set whole by another --set")
        node[leaf] = value.strip() or '""'

    def emit(node: dict, indent: int) -> list[str]:
        lines = []
        for k, v in node.items():
            if isinstance(v, dict):
                lines += [" " * indent + f"{k}:", *emit(v, indent + 2)]
            else:
                lines.append(" " * indent + f"{k}: {v}")
        return lines

    return "\n".join(emit(tree, 0)) + "\n" if tree else None


# ``--set`` fields that name an input file: a relative one is the user's, from where they run the
# command, not from the scenario file's folder (a shipped scene's is inside the installed package).
_PATH_KEYS = ("device.path", "device.log")


def _sets_from_here(items: list[str]) -> list[str]:
    """``items`` with a relative file of :data:`_PATH_KEYS` made absolute against the working folder."""
    out = []
    for item in items:
        key, eq, value = item.partition("=")
        v = value.strip()
        field = re.sub(r"^tools\.[^.]+\.", "", key.strip())  # a tool's own: tools.NAME.device.path
        if eq and field in _PATH_KEYS and v and "://" not in v and not Path(v).is_absolute():
            item = f"{key.strip()}={sc.absolute(v)}"
        out.append(item)
    return out


def load_with_sets(path: str | Path, items: list[str], *, check: bool = True) -> sc.Scenario:
    """The scenario file with the ``--set`` items applied (before its checks); an error names the
    item that caused it. A relative file path set on the device is taken from the working folder;
    a field of the device or the god-object set alone keeps the kind the file gives
    (:func:`~godobject_drake.config.scenario.load_scenario`; ``check=False``: not checked yet)."""
    items = _sets_from_here(items)
    text = set_overrides(items)
    try:
        return sc.load_scenario(path, text, check=check)
    except sc.ScenarioError as e:
        if not text:
            raise
        sc.load_scenario(path, check=False)  # the file's own error (a key twice, say) is the file's
        for item in items:  # which item: the first that fails alone
            try:
                sc.load_scenario(path, set_overrides([item]), check=check)
            except sc.ScenarioError as alone:
                raise sc.ScenarioError(f"--set {item}: {alone}") from None
        raise sc.ScenarioError(f"--set {' '.join(items)}: {e}") from None


class _Handler(StderrHandler):
    """The command line's handler of the ``godobject_drake`` logger (one at a time), to the
    ``sys.stderr`` of the moment."""


def configure_logging(verbose: int = 0, quiet: int = 0) -> None:
    """The ``godobject_drake`` logger to stderr as plain lines: info by default, debug with
    ``-v``, warnings and errors only with ``-q``."""
    handler = _Handler()
    handler.setFormatter(logging.Formatter("%(message)s"))
    for old in [h for h in logger.handlers if isinstance(h, _Handler)]:
        logger.removeHandler(old)
    logger.addHandler(handler)
    logger.setLevel(
        logging.DEBUG if verbose > quiet else logging.WARNING if quiet > verbose else logging.INFO
    )
    logger.propagate = False


def plain(text: str | None) -> str | None:
    """A docstring as plain help text: no reStructuredText markup (````x````, ``:func:`~a.b```)."""
    if text is None:
        return None
    text = re.sub(r":[a-z]+:`~?(?:[\w.]*\.)?([\w]+)`", r"\1", text)
    return text.replace("``", "")


def flags_given(args: argparse.Namespace) -> list[Flag]:
    """The flags given on the command line, in the table's order (a switch only when set)."""
    return [
        f
        for f in all_flags()
        if getattr(args, f.dest, None) is not None and getattr(args, f.dest) is not False
    ]


def apply_arguments(scenario: sc.Scenario, args: argparse.Namespace) -> sc.Scenario:
    """A copy of ``scenario`` with every given flag applied: each sets its field (``--set FIELD=VALUE``),
    ``--device`` first (it changes the device's kind, keeping its sampling). A flag whose field the
    scenario's kinds do not have is refused naming the kinds that have it; a value the scenario's
    checks refuse names the flag (raises ``ScenarioError``)."""
    s, fields = _applied(scenario, args)
    try:
        sc.check_scenario(s, where="flags")
    except sc.ScenarioError as e:
        raise _blamed(e, "flags", fields, []) from None
    return s


def scenario_of(path: str | Path, args: argparse.Namespace) -> tuple[sc.Scenario, dict]:
    """The command line's scenario: the file, its ``--set`` items (:func:`load_with_sets`) and the
    flags (:func:`apply_arguments`), checked once (:func:`~godobject_drake.config.scenario.check_scenario`),
    an error naming the flag or the ``--set`` item that set the field it is about. Returns the
    scenario and its tools' records, for :func:`~godobject_drake.station.build.build_station`."""
    s, fields = _applied(load_with_sets(path, args.set_fields, check=False), args)
    try:
        return s, sc.check_scenario(s, where=str(path))
    except sc.ScenarioError as e:
        raise _blamed(e, str(path), fields, _sets_from_here(args.set_fields)) from None


def _blamed(e: sc.ScenarioError, where: str, fields: dict, items: list[str]) -> sc.ScenarioError:
    """The check's error ``where: FIELD...`` named by the flag that set FIELD (``--flag: FIELD...``),
    else by the ``--set`` item that did (``--set ITEM: where: FIELD...``), else as it is."""
    said = str(e).removeprefix(f"{where}: ")

    def about(field: str) -> bool:
        return said.startswith(field) and said[len(field) : len(field) + 1] in ("", ".", ":", " ", "=")

    flag = next((name for field, (name, _) in fields.items() if about(field)), None)
    if flag is not None:
        return sc.ScenarioError(f"{flag}: {said}")
    item = next((i for i in items if about(i.split("=", 1)[0].strip())), None)
    return sc.ScenarioError(f"--set {item}: {e}" if item is not None else str(e))


def _applied(scenario: sc.Scenario, args: argparse.Namespace) -> tuple[sc.Scenario, dict]:
    """:func:`apply_arguments` before the check: the scenario, and each field set with its flag's
    name and value."""
    given = flags_given(args)
    names = {f.name for f in given}
    s = copy.deepcopy(scenario)
    if "--replay-devices" in names:
        if "--device" in names:
            raise sc.ScenarioError("--replay-devices sets every tool's device: leave out --device")
        s = sc.replaying_devices(s, args.replay_devices)
    if "--device" in names:
        s.device = switch_device(s, args.device, getattr(args, "device_log", None))
    elif "--device-log" in names:
        raise sc.ScenarioError("--device-log: give --device replay or --device relative with it")
    fields: dict[str, tuple[str, object]] = {}
    for flag in given:
        if flag.field is None or flag.name in ("--device", "--device-log"):
            continue
        _check_field(s, flag)
        raw = getattr(args, flag.dest)
        fields[flag.field] = (flag.name, flag.value(raw, s) if flag.value else raw)
        for field, value in (flag.also(raw, s, names) if flag.also else {}).items():
            fields[field] = (flag.name, value)
    return sc.replace(s, **{field: value for field, (_, value) in fields.items()}), fields


def _check_field(s: sc.Scenario, flag: Flag) -> None:
    """Refuse ``flag`` when the scenario's tool or device has no such field, naming the kinds that do."""
    *parents, last = flag.field.split(".")
    target = s
    for name in parents:
        target = getattr(target, name, None)
    if target is not None and hasattr(target, last):
        return
    part = parents[0] if parents else last
    kinds = TOOL_CONFIGS if part == "god_object" else list(DEVICE_KINDS) if part == "device" else []
    having = [k for k in kinds if _has_field(k, flag.field.split(".", 1)[1])]
    owner = getattr(s, part)
    raise sc.ScenarioError(
        f"{flag.name}: sets {flag.field}, which the scenario's !{type(owner).__name__} {part} has not; "
        + (f"it is for {', '.join('!' + k.__name__ for k in having)}" if having else "no kind has it")
    )


def _has_field(config_type: type, path: str) -> bool:
    """Whether a config type has the dotted field ``path`` (its defaults walked)."""
    try:
        target = config_type()
    except TypeError:  # a kind of one's own without defaults
        return False
    for name in path.split("."):
        if not hasattr(target, name):
            return False
        target = getattr(target, name)
    return True


def switch_device(s: sc.Scenario, name: str, log: Path | None) -> object:
    """The scenario's device as the ``--device`` kind ``name`` of the same space (pose or joint): a new
    kind keeps the old one's sampling settings and starts where the old one starts."""
    old = s.device
    if s.tools:
        raise sc.ScenarioError(
            f"--device {name}: this scene has tools ({', '.join(s.tools)}), each with its own device: set "
            "one with --set 'tools.NAME.device=!KIND {...}'"
        )
    space = sc.tool_records(s)[""].device.space
    kinds = kinds_in(space)
    if name not in kinds:
        raise sc.ScenarioError(
            f"--device {name}: the scenario's device is a {sc.SPACE_NAMES[space]} device; use one of "
            f"{sorted(kinds)}"
        )
    cls = kinds[name]
    if isinstance(old, cls):
        if log is not None:
            old.log = str(sc.absolute(log))
        return old
    if DEVICE_KINDS[cls].needs_log and log is None:
        raise sc.ScenarioError(
            f"--device {name} needs --device-log FILE.csv (docs/guide/devices.md: the log formats)"
        )
    common = {f.name: getattr(old, f.name) for f in dataclasses.fields(cls) if hasattr(old, f.name)}
    for field in ("path", "waypoints", "log"):
        common.pop(field, None)
    new = cls(**common)
    if hasattr(new, "log"):
        new.log = str(sc.absolute(log))
    if hasattr(new, "start_xyz"):
        X0 = old.start_pose()
        new.start_xyz = X0.translation().tolist()
        new.start_rpy_deg = [math.degrees(a) for a in _rpy(X0)]
    if hasattr(new, "grasp"):  # a device that holds a body keeps a deformable tool's core
        new.grasp = getattr(s.god_object, "name", "")  # a deformable tool's core is always held
    if DEVICE_KINDS[cls].live or DEVICE_KINDS[cls].real_time:
        if hasattr(new, "noise_m"):
            new.noise_m = 0.0  # the samples are the user's or the device's own
    if hasattr(new, "start") and space == "joint":
        new.start = old.start_values()
    return new


def _rpy(X):
    from pydrake.math import RollPitchYaw

    return RollPitchYaw(X.rotation()).vector()


def run_scenario(
    scenario: sc.Scenario, progress: bool = True, records: dict | None = None, hold: SignalsHeld | None = None
):
    """Build (:func:`~godobject_drake.station.build.build_station`; ``records``: the scenario's,
    checked by :func:`scenario_of`) and simulate in bounded memory (no logs kept); with a metrics
    file, the metrics so far are written to it every ``metrics.checkpoint_period_s`` of wall time,
    marked ``partial``, so a killed run leaves its last ones. ``hold``: :func:`simulate`'s (the
    signals held from the loop's end, left on for the caller)."""

    for field, output in outputs(scenario):
        check_output(output, field)  # a folder, a missing folder: refused now, not after the run
    path = scenario.metrics.file
    if path and is_stream(path):  # a pipe or a device gets the final metrics once, no checkpoints
        logger.info(
            "metrics.file %s is not a regular file: no checkpoints, the metrics once at the end", path
        )
        path = None
    station = build_station(scenario, records=records)  # with the Meshcat it asks for
    failed = []

    def checkpoint(metrics):
        try:
            write_metrics(path, metrics)
        except OutputError as e:  # the run goes on; the last complete file stays, said once
            if not failed:
                logger.warning("checkpoint not written: %s", e)
            failed.append(e)

    return simulate(
        station, progress=progress, keep_logs=False, checkpoint=checkpoint if path else None,
        checkpoint_period_s=scenario.metrics.checkpoint_period_s, hold=hold,
    )  # fmt: skip


def outputs(scenario: sc.Scenario) -> list[tuple[str, str]]:
    """The run's output files, ``(field, path)``: the metrics and the recording, those given."""
    given = (("metrics.file", scenario.metrics.file), ("recording.file", scenario.recording.file))
    return [(field, path) for field, path in given if path]


def claim_outputs(scenario: sc.Scenario, locks: OutputLock) -> None:
    """Check the run's output files (:func:`~godobject_drake.outputs.check_output`) and lock each
    for the run: another run writing one of them is refused now, before this one starts."""
    for field, path in outputs(scenario):
        check_output(path, field)
        locks.acquire(path, field)


def report(results: list[dict], metrics_path: str | Path | None) -> bool:
    """Print the metrics table; write the JSON (one run: an object; several: a list). Returns
    False, saying why on stderr, if the file could not be written (the last complete one stays)."""
    print(format_table(results))
    if metrics_path:
        try:
            write_metrics(metrics_path, results[0] if len(results) == 1 else results)
        except OutputError as e:
            logger.error("metrics not written: %s", e)
            return False
        logger.info("metrics written to %s", metrics_path)
    return True


def refuse_input(parser: argparse.ArgumentParser, error: Exception):
    """Bad input: the message alone (no usage block: the flags were parsed), exit status 2; a
    control character a name or path brought into it is escaped, not sent to the terminal."""
    said = "\n".join(sc.shown(line) for line in str(error).split("\n"))
    parser.exit(2, f"{parser.prog}: error: {said}\n")


class Terminated(KeyboardInterrupt):
    """SIGTERM, SIGHUP (a closed terminal, a dropped SSH session) or SIGQUIT (Ctrl-\\): the command
    line ends the run as Ctrl-C does (partial metrics, a whole recording, the device's STOP)."""

    def __init__(self, signum: int = signal.SIGTERM):
        super().__init__(signal.Signals(signum).name)
        self.signum = signum


# The signals the command line ends a run with, as Ctrl-C: a stop, a closed terminal, Ctrl-\ (whose
# default, a core dump, would leave the device's driver without its STOP and lose the metrics).
ENDING = (signal.SIGTERM, signal.SIGHUP, signal.SIGQUIT)


class _Ending:
    """The handler of :data:`ENDING`'s signals for one run: the first raises :class:`Terminated` (the loop
    ends as with Ctrl-C); a later one, before ``hold`` takes over at the loop's end, is noted in
    it instead of raised again into the loop's own ending."""

    def __init__(self, hold: SignalsHeld):
        self.hold, self.raised = hold, False

    def __call__(self, signum, frame):
        if self.raised:
            self.hold.caught.append(signum)
            return
        self.raised = True
        raise Terminated(signum)


def _signal_name(e: BaseException) -> str:
    return signal.Signals(e.signum).name if isinstance(e, Terminated) else "Ctrl-C"


def _exit_code(signum: int) -> int:
    return 128 + signum  # as a shell reports a signal: 130 Ctrl-C, 143 SIGTERM, 129 SIGHUP, 131 SIGQUIT


USER_ERRORS = (
    sc.ScenarioError,
    CouplingGainError,
    ShellSpecError,
    WiringError,
    ValueError,
    FileNotFoundError,
    DeviceNotHeardError,
)


SCENARIO_HELP = f"a scenario YAML file, or a shipped scene by name ({', '.join(sc.SHIPPED)})"


def scenario_path(text: str) -> Path:
    """The command line's scenario: a file, or a shipped scene's name (``lego``) when no such file
    is here."""
    path = Path(text)
    if text in sc.SHIPPED and not path.exists():
        return sc.shipped_scenario_file(text)
    return path


def version_text() -> str:
    """``--version``: this package's version and the Drake it runs on."""
    import importlib.metadata

    try:
        drake = importlib.metadata.version("drake")
    except importlib.metadata.PackageNotFoundError:
        drake = "unknown"
    return f"godobject_drake {__version__} (drake {drake}, Python {sys.version.split()[0]})"


def console_main() -> int:
    """The ``godobject`` console script (``godobject run lego``)."""
    return main(prog="godobject")


def main(argv=None, *, prog: str = "python -m godobject_drake") -> int:
    """The command line: ``run SCENARIO`` or ``analyze SCENARIO``, the scenario's fields overridden by
    the flags; the exit status is 1 for a diverged run or a failed metric, 2 for bad input. The
    scene scripts (``diagrams/*.py``) call it with ``run`` and their own scenario file."""
    argv = list(sys.argv[1:] if argv is None else argv)
    parser = argparse.ArgumentParser(prog=prog, description=DESCRIPTION,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)  # fmt: skip
    parser.add_argument("--version", action="version", version=version_text())
    commands = parser.add_subparsers(dest="command", required=True)
    run = commands.add_parser("run", help="run a scenario: the metrics table, and a recording with --record")
    run.add_argument("scenario", type=scenario_path, help=SCENARIO_HELP)
    add_arguments(run)
    analyze = commands.add_parser(
        "analyze", help="the scenario's stability and passivity report, each verdict checked in Drake"
    )
    analyze.add_argument("scenario", type=scenario_path, help=SCENARIO_HELP)
    analyze.add_argument(
        "--out", type=Path,
        help="the folder for report.md, summary.json and margins.png (drawn when a row has a value and an "
        "upper limit; default: analysis_SCENE in the current folder)",
    )  # fmt: skip
    analyze.add_argument("--quick", action="store_true", help="coarser bisections (seconds, not minutes)")
    analyze.add_argument(
        "--verify", action=argparse.BooleanOptionalAction, default=None,
        help="simulate each prediction in Drake on this scene (default: on, off with --quick)",
    )  # fmt: skip
    add_arguments(analyze, exclude=RUN_ONLY_FLAGS)
    args = parser.parse_args(argv)
    configure_logging(args.verbose, args.quiet)
    if args.command == "analyze":
        return _analyze(args, analyze)
    return _run(args, run)


def scene_main(scenario: str | Path, argv=None, *, prog: str, description: str | None = None) -> int:
    """A scene script's command line (``python diagrams/lego.py [flags]``): ``run`` on its own
    ``scenario`` file, the script's docstring as the help's description. The same path as
    ``godobject run SCENARIO [flags]`` (:func:`_run`)."""
    argv = list(sys.argv[1:] if argv is None else argv)
    parser = argparse.ArgumentParser(prog=prog, description=plain(description),
                                     formatter_class=argparse.RawDescriptionHelpFormatter)  # fmt: skip
    add_arguments(parser)
    args = parser.parse_args(argv)
    args.scenario = Path(scenario)
    configure_logging(args.verbose, args.quiet)
    return _run(args, parser)


def _run(args: argparse.Namespace, parser: argparse.ArgumentParser) -> int:
    """``run``: build, simulate, print the metrics table, write what was asked; the output files
    locked from before the build to after the last write (:class:`~godobject_drake.outputs.OutputLock`).
    SIGTERM, SIGHUP and SIGQUIT end the run as Ctrl-C does; from the end of its loop to the lock files
    removed, a signal is held (:class:`~godobject_drake.outputs.SignalsHeld`): the outputs are
    written whole, then the exit says so."""
    main_thread = threading.current_thread() is threading.main_thread()
    hold = SignalsHeld()
    ending = _Ending(hold)
    previous = (  # a signal ignored when the run began (nohup's SIGHUP) stays ignored
        {
            signum: signal.signal(signum, ending)
            for signum in ENDING
            if signal.getsignal(signum) != signal.SIG_IGN
        }
        if main_thread
        else {}
    )
    try:
        with OutputLock() as locks:
            return _run_locked(args, parser, locks, hold)
    finally:
        hold.end(act=False)  # what it caught is said by _run_locked; the locks are gone
        for signum, handler in previous.items():
            signal.signal(signum, handler)


def _run_locked(
    args: argparse.Namespace, parser: argparse.ArgumentParser, locks: OutputLock, hold: SignalsHeld
) -> int:
    interrupted = None
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("always", PenetrationBudgetWarning)
            s, records = scenario_of(args.scenario, args)
            claim_outputs(s, locks)
            result = run_scenario(s, progress=not args.no_progress, records=records, hold=hold)
    except USER_ERRORS as e:
        refuse_input(parser, e)
    except RunInterrupted as e:  # Ctrl-C, SIGTERM, SIGHUP, SIGQUIT: what the run produced, written, partial
        result, interrupted = e.result, e.__cause__ or e
    except KeyboardInterrupt as e:  # before the run's loop ended (simulate holds signals from there)
        logger.warning("interrupted (%s) before the run started", _signal_name(e))
        return _exit_code(e.signum) if isinstance(e, Terminated) else 130
    hold.start()  # (simulate started it at the loop's end): the outputs written whole
    return _outputs(s, result, interrupted, hold)


def _outputs(s: sc.Scenario, result, interrupted, hold: SignalsHeld) -> int:
    """Write and say what the run produced; the exit code (a signal's 128 + N when one ended the
    run or came while its outputs were written, which it then says)."""
    metrics = result.metrics
    written = report([metrics], s.metrics.file or None)
    if s.recording.file and "recording_error" not in metrics:
        logger.info("recording written to %s", s.recording.file)
    elif "recording_error" in metrics:  # on stderr too, not only a row of the table
        logger.error("recording not written: %s", metrics["recording_error"])
    if "meshcat_error" in metrics:
        logger.error("%s", metrics["meshcat_error"])
    late = [signal.Signals(n).name for n in dict.fromkeys(hold.caught)]
    if late:
        logger.warning(
            "%s came while the run ended and its outputs were written: held until they were whole",
            ", ".join(late),
        )
    if interrupted is not None:
        by = _signal_name(interrupted)
        logger.warning(
            "interrupted (%s) at t = %.3f s: the metrics above are partial", by, metrics["sim_time_s"]
        )
        return _exit_code(interrupted.signum) if isinstance(interrupted, Terminated) else 130
    if late:
        return 128 + hold.caught[0]
    if not written or "recording_error" in metrics or "meshcat_error" in metrics:
        return 1
    if (s.visualization.serve or result.station.live) and sys.stdin.isatty():
        hold.end(act=False)  # the outputs are written: Ctrl-C ends the wait as Enter does
        try:
            input("Meshcat is still serving the scene; press Enter (or Ctrl-C) to exit.")
        except (KeyboardInterrupt, EOFError):
            pass
    return 1 if metrics["diverged"] or "metrics_error" in metrics else 0


def default_report_folder(path: Path) -> Path:
    """``analyze``'s folder without ``--out``: ``analysis_SCENE`` in the current folder, SCENE the
    scenario file's name without ``.yaml`` (a shipped scene's name)."""
    return Path(f"analysis_{Path(path).stem}")


def _analyze(args: argparse.Namespace, parser: argparse.ArgumentParser) -> int:
    """``analyze``: write the report; exit 1 if a check fails, 2 for bad input."""
    # The studies (python-control, matplotlib) load for ``analyze`` only: ``run`` starts without them.
    from godobject_drake.studies.analyze import analyze, verdict_table, write_report

    try:
        s, _ = scenario_of(args.scenario, args)
        summary = analyze(s, quick=args.quick, verify=args.verify)
    except USER_ERRORS as e:
        refuse_input(parser, e)
    path = write_report(summary, args.out or default_report_folder(args.scenario))
    print(verdict_table(summary))
    print(f"verdict: {summary['verdict']}")  # the product, with the table: stdout
    logger.info("report written to %s", path)
    return 1 if summary["verdict"] == "fail" else 0
