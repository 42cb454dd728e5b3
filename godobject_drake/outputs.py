"""Writing a run's outputs so that a reader never sees half a file and a full disk loses nothing.

Every file a run writes (the metrics JSON, its checkpoints, the recording) goes through
:func:`write_atomically`: the text is written to a temporary file beside the target, flushed to
disk, and renamed over it, so a reader polling the file sees the last complete version or the new
one, never a mix; if the write fails (a full disk, a file-size limit), the temporary file is
removed, the previous file is left as it was, and :class:`OutputError` names the file and the
cause. Metrics are strict JSON (:func:`strict_json`): a non-finite number becomes ``null`` and is
listed, with its value, under ``non_finite``, so any JSON reader (JavaScript's included) reads it.
"""

import json
import math
import os
import tempfile
from pathlib import Path


class OutputError(OSError):
    """An output file could not be written; the previous version, if any, is untouched."""


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


_UMASK = _umask()  # read once, at import: os.umask can only be read by setting it


def write_atomically(path: str | Path, text: str) -> int:
    """Write ``text`` to ``path`` all at once (module docstring); return the bytes written."""
    path = Path(path)
    data = text.encode()
    tmp = None
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.chmod(tmp, 0o666 & ~_UMASK)  # as open() would make it: mkstemp's file is private (0600)
        os.replace(tmp, path)
    except OSError as e:
        if tmp is not None:
            try:
                os.unlink(tmp)
            except OSError:
                pass
        kept = "the previous version is kept" if path.exists() else "nothing was written"
        raise OutputError(
            e.errno, f"could not write {path} ({len(data)} bytes): {e.strerror or e}; {kept}. "
            "Free space on that disk or write elsewhere"
        ) from None  # fmt: skip
    return len(data)


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
