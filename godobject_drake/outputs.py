"""Writing a run's outputs so that a reader never sees half a file and a full disk loses nothing.

Every file a run writes (the metrics JSON, its checkpoints, the recording) goes through
:func:`write_atomically`: the text is written to a temporary file beside the target, flushed to
disk, and renamed over it, so a reader polling the file sees the last complete version or the new
one, never a mix; if the write fails (a full disk, a file-size limit), the temporary file is
removed, the previous file is left as it was, and :class:`OutputError` names the file and the
cause. Metrics are strict JSON (:func:`strict_json`): a non-finite number becomes ``null`` and is
listed, with its value, under ``non_finite``, so any JSON reader (JavaScript's included) reads it.

What the path names is kept (:func:`write_atomically`): a symlink stays a symlink and its target is
rewritten (followed only where the kernel's ``protected_symlinks`` rule would follow it: not a link
another user left in a sticky world-writable folder such as ``/tmp``); a FIFO, a pipe
(``--metrics >(cmd)``) or a device (``/dev/null``, ``/dev/stdout``) is written through, once,
never replaced by a regular file; a rewritten file keeps its mode (and, for root, its owner). Before a
run, :func:`check_output` refuses a folder, a missing folder or a link it would not follow, and
:class:`OutputLock` holds an advisory lock (``fcntl.flock`` on ``.NAME.lock`` beside the file) for the
whole run, so a second run given the same file is refused before it starts instead of overwriting
the first one's finished metrics with its partial checkpoints.

**Signals while writing** (:class:`SignalsHeld`): Ctrl-C, SIGTERM, SIGHUP or SIGQUIT during a write is held
until the file is whole (or the previous one kept), then acted on as its handler would have; a
temporary file is removed whatever ends the write, and a lock file whatever ends the run but
SIGKILL. A run holds them from the end of its loop to its last write, so a signal there cannot lose
the outputs the run already has.
"""

import errno
import fcntl
import json
import math
import os
import signal
import stat
import tempfile
import threading
from pathlib import Path

# The signals that end a run (Ctrl-C, a stop, a closed terminal, Ctrl-\): held while an output is written.
HELD_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP, signal.SIGQUIT)


class SignalsHeld:
    """Signals held while outputs are written: from :meth:`start` each signal of ``signums`` that
    comes is noted (:attr:`caught`) instead of handled; :meth:`end` puts the handlers back and, with
    ``act``, handles each noted signal once as its handler would have (Ctrl-C's KeyboardInterrupt is
    raised then, a default action is taken then). Holds nest: an inner one hands what it caught to
    the outer one. A signal this process ignores (``nohup``'s SIGHUP) stays ignored; outside the
    main thread (where Python handles no signal) it holds nothing."""

    def __init__(self, signums=HELD_SIGNALS):
        self.signums = tuple(signums)
        self.caught: list[int] = []
        self._previous: dict | None = None

    @property
    def holding(self) -> bool:
        return self._previous is not None

    def start(self) -> "SignalsHeld":
        """Hold the signals from now (again: nothing changes)."""
        if self._previous is None and threading.current_thread() is threading.main_thread():
            self._previous = {
                signum: signal.signal(signum, self._note)
                for signum in self.signums
                if signal.getsignal(signum) != signal.SIG_IGN
            }
        return self

    def _note(self, signum, frame) -> None:
        self.caught.append(signum)

    def end(self, act: bool = True) -> None:
        """Put the handlers back; with ``act``, handle each signal caught, once, in order."""
        previous, self._previous = self._previous, None
        if previous is None:
            return
        for signum, handler in previous.items():
            signal.signal(signum, signal.SIG_DFL if handler is None else handler)
        for signum in dict.fromkeys(self.caught) if act else ():
            handler = previous[signum]
            if callable(handler):
                handler(signum, None)
            elif handler != signal.SIG_IGN:  # the default action (None: a handler set outside Python)
                signal.raise_signal(signum)

    def __enter__(self) -> "SignalsHeld":
        return self.start()

    def __exit__(self, *exc) -> None:
        self.end()


class OutputError(OSError):
    """An output file could not be written; the previous version, if any, is untouched."""


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


_UMASK = _umask()  # read once, at import: os.umask can only be read by setting it


class OutputRefused(ValueError):
    """An output path refused before the run (a folder, a link not to follow, a file another run
    holds): the message names the field, the path, why and the fix."""


MAX_SYMLINK_HOPS = 40  # as the kernel's ELOOP


def _symlink_followable(link: str) -> str | None:
    """Why ``link`` (a symlink) must not be followed, or None. The kernel's ``protected_symlinks``
    rule: in a sticky world-writable folder (``/tmp``), a link is followed only if its owner is the
    one who follows it or the folder's owner; elsewhere always."""
    folder = os.stat(os.path.dirname(os.path.abspath(link)) or ".")
    sticky_shared = folder.st_mode & stat.S_ISVTX and folder.st_mode & stat.S_IWOTH
    owner = os.lstat(link).st_uid
    if sticky_shared and owner not in (os.geteuid(), folder.st_uid):
        return (
            f"it is a symlink owned by uid {owner} in a folder anyone can write to "
            f"({os.path.dirname(link)}); following it would write where another user chose. Give a path "
            "of your own"
        )
    return None


def _follow(path: Path) -> Path:
    """``path`` with its symlinks (the last component's chain) followed under the
    :func:`_symlink_followable` rule; raises :class:`OutputRefused` for a loop or a link not to follow."""
    p = str(path)
    for _ in range(MAX_SYMLINK_HOPS):
        if not os.path.islink(p):
            return Path(p)
        why = _symlink_followable(p)
        if why:
            raise OutputRefused(f"{path}: {why}")
        link = os.readlink(p)
        p = link if os.path.isabs(link) else os.path.join(os.path.dirname(p), link)
    raise OutputRefused(f"{path}: a symlink loop (more than {MAX_SYMLINK_HOPS} links); point it at a file")


def _stat(path: Path) -> os.stat_result | None:
    """``os.stat`` following links (the kernel's own, so ``/dev/fd/N`` works), None if nothing is there."""
    try:
        return os.stat(path)
    except FileNotFoundError:
        return None
    except OSError as e:
        if e.errno == errno.ELOOP:
            raise OutputRefused(f"{path}: a symlink loop; point it at a file") from None
        raise


def is_stream(path: str | Path) -> bool:
    """Whether ``path`` names something written through rather than replaced: a FIFO, a pipe, a
    device or a socket (:func:`write_atomically`). A checkpoint is not sent there: a reader of a pipe
    would get one JSON document after another."""
    st = _stat(Path(path))
    return st is not None and not stat.S_ISREG(st.st_mode) and not stat.S_ISDIR(st.st_mode)


def check_output(path: str | Path, field: str, example: str = "") -> None:
    """Refuse, before a run, an output ``path`` it could only fail to write at its end: a folder,
    a missing folder, a symlink loop or a link not to follow, something not writable (raises
    :class:`OutputRefused` naming ``field``, the path and the fix; ``example``: a file name the fix
    gives for a folder)."""
    path = Path(path)
    try:
        st = _stat(path)
        if st is not None and stat.S_ISDIR(st.st_mode):
            example = example or ("metrics.json" if field.startswith("metrics") else "recording.html")
            raise OutputRefused(f"{path} is a folder; give a file name, e.g. {path / example}")
        if st is not None and not stat.S_ISREG(st.st_mode):
            if not os.access(path, os.W_OK):
                raise OutputRefused(f"{path} is not writable by this user; give another path")
            return  # a FIFO, a pipe or a device: written through at the end
        target = _follow(path)
        folder = target.resolve().parent
        if not folder.is_dir():
            raise OutputRefused(f"{path}: the folder {folder} does not exist; create it or write elsewhere")
        if not os.access(folder, os.W_OK | os.X_OK):
            raise OutputRefused(f"{path}: the folder {folder} is not writable by this user; write elsewhere")
    except OutputRefused as e:
        raise OutputRefused(f"{field}: {e}") from None


def _write_through(path: Path, data: bytes) -> None:
    """Write ``data`` into a FIFO, pipe or device as it is. A FIFO nobody reads is refused at once
    (``O_NONBLOCK``: ENXIO) instead of blocking the end of the run; then the writes block as usual."""
    try:
        fd = os.open(path, os.O_WRONLY | os.O_NONBLOCK | os.O_NOCTTY)
    except OSError as e:
        if e.errno == errno.ENXIO:
            raise OSError(
                e.errno, "no process has the FIFO open for reading; start its reader first"
            ) from None
        raise
    try:
        flags = fcntl.fcntl(fd, fcntl.F_GETFL)
        fcntl.fcntl(fd, fcntl.F_SETFL, flags & ~os.O_NONBLOCK)
        view = memoryview(data)
        while view:
            view = view[os.write(fd, view) :]
    finally:
        os.close(fd)


def write_atomically(path: str | Path, text: str) -> int:
    """Write ``text`` to ``path`` all at once (module docstring); return the bytes written.

    A regular file (or a new one) is written to a temporary file beside it and renamed over it,
    keeping its mode (and owner, for root); through a symlink, the link's target is. A FIFO, a pipe
    or a device is written through as it is. A signal that comes meanwhile is handled once the
    file is whole (:class:`SignalsHeld`)."""
    with SignalsHeld():
        return _write_atomically(Path(path), text)


def _remove(tmp: str | None) -> None:
    if tmp is not None:
        try:
            os.unlink(tmp)
        except OSError:
            pass


def _write_atomically(path: Path, text: str) -> int:
    data = text.encode()
    tmp = None
    try:
        st = _stat(path)
        if st is not None and stat.S_ISDIR(st.st_mode):
            raise IsADirectoryError(errno.EISDIR, "it is a folder")
        if st is not None and not stat.S_ISREG(st.st_mode):
            _write_through(path, data)
            return len(data)
        target = _follow(path)
        fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".tmp", dir=target.parent)
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        if st is not None:  # the file's own mode, owner and group: a private file stays private
            os.chmod(tmp, stat.S_IMODE(st.st_mode))
            if (st.st_uid, st.st_gid) != (os.geteuid(), os.getegid()):
                try:
                    os.chown(tmp, st.st_uid, st.st_gid)
                except PermissionError:  # not root: the file becomes this user's, its mode kept
                    pass
        else:
            os.chmod(tmp, 0o666 & ~_UMASK)  # as open() would make it: mkstemp's file is private (0600)
        os.replace(tmp, target)
    except OutputRefused as e:
        raise OutputError(errno.EINVAL, f"could not write {path}: {e}") from None
    except OSError as e:
        _remove(tmp)
        kept = "the previous version is kept" if os.path.lexists(path) else "nothing was written"
        space = e.errno in (errno.ENOSPC, errno.EFBIG, errno.EDQUOT)
        fix = "Free space on that disk or write elsewhere" if space else "Write elsewhere"
        raise OutputError(
            e.errno, f"could not write {path} ({len(data)} bytes): {e.strerror or e}; {kept}. {fix}"
        ) from None
    except BaseException:  # whatever else ends the write (a MemoryError): no temporary file left
        _remove(tmp)
        raise
    return len(data)


class OutputLock:
    """An advisory lock (``fcntl.flock``) on ``.NAME.lock`` beside each output file, held for a run:
    a second run given the same file is refused at :meth:`acquire`, before it starts, naming the
    process that holds it. The lock file is removed on :meth:`release`; a run killed with it held
    leaves it, unlocked, and the next run takes it. FIFOs, pipes and devices are not locked."""

    def __init__(self):
        self._held: list[tuple[int, Path]] = []

    def acquire(self, path: str | Path, field: str) -> None:
        path = Path(path)
        if is_stream(path):
            return
        target = _follow(path).resolve()
        lock = target.parent / f".{target.name}.lock"
        if any(held == lock for _, held in self._held):
            raise OutputRefused(
                f"{field}: {path} is already another output of this run; give each its own file"
            )
        while True:
            fd = os.open(lock, os.O_RDWR | os.O_CREAT | os.O_NOFOLLOW | os.O_CLOEXEC, 0o600)
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                holder = os.read(fd, 64).decode(errors="replace").strip() or "another process"
                os.close(fd)
                raise OutputRefused(
                    f"{field}: {path} is being written by another run (pid {holder}, holding {lock}); "
                    "wait for it to finish or give this run another file"
                ) from None
            # the file may have been removed by the holder between our open and our lock: retry
            try:
                same = os.fstat(fd).st_ino == os.stat(lock).st_ino
            except FileNotFoundError:
                same = False
            if same:
                break
            os.close(fd)
        os.ftruncate(fd, 0)
        os.write(fd, f"{os.getpid()}\n".encode())
        self._held.append((fd, lock))

    def release(self) -> None:
        with SignalsHeld():  # each lock file removed, whatever signal comes
            self._release()

    def _release(self) -> None:
        for fd, lock in reversed(self._held):
            try:
                os.unlink(lock)  # while still locked: a waiter that opened it retries on the new one
            except OSError:
                pass
            os.close(fd)
        self._held.clear()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.release()


def strict_json(value):
    """``value`` with every non-finite float replaced by None; returns ``(clean, non_finite)``
    where ``non_finite`` maps each replaced key path (``a.b[2]``) to the value's text."""
    found: dict[str, str] = {}

    def clean(v, where: str):
        if isinstance(v, float) and not math.isfinite(v):
            found[where or "value"] = repr(v)
            return None
        if isinstance(v, dict):
            return {k: clean(x, f"{where}.{k}" if where else str(k)) for k, x in v.items()}
        if isinstance(v, list | tuple):
            return [clean(x, f"{where}[{i}]") for i, x in enumerate(v)]
        return v

    return clean(value, ""), found


def dumps_metrics(metrics) -> str:
    """Metrics (one run's dict, or a list of them) as strict JSON text (module docstring)."""
    runs = metrics if isinstance(metrics, list) else [metrics]
    out = []
    for run in runs:
        clean, found = strict_json(run)
        if found:
            clean["non_finite"] = found  # what was not a number, and where
        out.append(clean)
    return json.dumps(out if isinstance(metrics, list) else out[0], indent=2, allow_nan=False) + "\n"
