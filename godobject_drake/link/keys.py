"""The link's key (the pairing: :mod:`godobject_drake.link.transport`): 32 random bytes,
as 64 hex digits in a file only its owner may read (mode 0600, in a folder only its owner may
write): ``key_file`` (scene) / ``--key-file`` (driver), else ``$GODOBJECT_LINK_KEY``, else
``~/.config/godobject/link.key`` (:func:`key_path`, :func:`load_key`). The default file (the
environment's, else the config folder's) is created on first use by whichever end starts first;
a file named by ``key_file`` / ``--key-file`` must exist (a mistyped name made a new key, which
paired with nothing). A value that is a key itself rather than a path, and a key of few distinct
bytes (all zero, all equal), are refused."""

from __future__ import annotations

import binascii
import hashlib
import hmac
import os
import re
import stat
import tempfile
from pathlib import Path

from godobject_drake.link.logs import log

KEY_ENV = "GODOBJECT_LINK_KEY"
KEY_BYTES = 32
KEY_HEX = 2 * KEY_BYTES


class KeyFileError(ValueError):
    """A key file that cannot pair a link: the message names the file, what is wrong and the fix
    (a control character in the file's name escaped: it is printed to a terminal)."""

    def __str__(self) -> str:
        text = super().__str__()
        return text if text.isprintable() else "".join(c if c.isprintable() else repr(c)[1:-1] for c in text)


# A random 32-byte key has about 30 distinct bytes; fewer than 16 has a chance under 1e-14.
MIN_DISTINCT_BYTES = 16
# A value given as a key file's path that is a key itself: hex digits (and a line end), 32 or more.
LOOKS_LIKE_A_KEY = re.compile(r"\s*[0-9a-fA-F]{32,}\s*")


def _not_a_key(value: str, given: str) -> None:
    if LOOKS_LIKE_A_KEY.fullmatch(value):
        raise KeyFileError(
            f"{given} holds {len(value.strip())} hex digits, a key itself rather than the path of a key "
            "file (it would be taken as a file name, and a new key made there): put the key in a file "
            "(mode 0600) and give that file's path"
        )


def key_path(key_file: str | Path = "") -> Path:
    """The link's key file: ``key_file`` if given, else ``$GODOBJECT_LINK_KEY``, else
    ``$XDG_CONFIG_HOME/godobject/link.key`` (``~/.config/godobject/link.key``). Refuses a value
    that is a key itself (:class:`KeyFileError`)."""
    if key_file:
        _not_a_key(str(key_file), "the key file")
        return Path(key_file).expanduser()
    if os.environ.get(KEY_ENV):
        _not_a_key(os.environ[KEY_ENV], f"${KEY_ENV}")
        return Path(os.environ[KEY_ENV]).expanduser()
    config = os.environ.get("XDG_CONFIG_HOME") or Path.home() / ".config"
    return Path(config) / "godobject" / "link.key"


def _check_folder(folder: Path, path: Path) -> None:
    st = folder.stat()
    if st.st_uid not in (os.getuid(), 0) or st.st_mode & 0o022:
        raise KeyFileError(
            f"key file {path}: its folder {folder} (mode {stat.S_IMODE(st.st_mode):04o}, owner uid "
            f"{st.st_uid}) can be written by others, who could replace the key; keep the key in a "
            f"folder only you can write (chmod 700 {folder}, or the default ~/.config/godobject/)"
        )


def _create_key(path: Path) -> None:
    """A new random key at ``path``, atomically: written whole in a private temporary file
    (mode 0600) and linked to ``path`` only if nothing is there yet (another end may have
    made one at the same moment: then theirs is used)."""
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=".link.key.")
    try:
        os.write(fd, os.urandom(KEY_BYTES).hex().encode() + b"\n")
        os.fsync(fd)
        os.close(fd)
        try:
            os.link(tmp, path)
            log.warning(
                f"created the link key {path} (mode 0600): a scene and a driver pair with the same "
                "file; copy it to the other computer if the driver runs there"
            )
        except FileExistsError:
            pass
    finally:
        os.unlink(tmp)


def load_key(key_file: str | Path = "", *, create: bool | None = None) -> tuple[bytes, Path]:
    """The link's key and its file (:func:`key_path`). The default file is created on first use
    (and its folder, mode 0700); a named ``key_file`` must exist unless ``create``. Refused
    (:class:`KeyFileError`, naming the file and the fix) when the file is not a regular file of
    yours that only you can read or change, not 64 hex digits, or a key of few distinct bytes."""
    path = key_path(key_file)
    create = not key_file if create is None else create
    folder = path.parent
    if not folder.exists():
        if not create:
            _missing(path)
        folder.mkdir(mode=0o700, parents=True)
    _check_folder(folder, path)
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK)
    except FileNotFoundError:
        if not create:
            _missing(path)
        _create_key(path)
        return load_key(path)
    except OSError as e:  # ELOOP: a symbolic link
        raise KeyFileError(
            f"key file {path}: {e.strerror}; give the path of a regular file (not a link), or leave "
            "the key file out to use the default, made on first use"
        ) from None
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode):
            raise KeyFileError(
                f"key file {path}: not a regular file; give the path of the key file (64 hex "
                "digits), or leave the key file out to use the default, made on first use"
            )
        if st.st_uid != os.getuid():
            raise KeyFileError(
                f"key file {path}: owned by uid {st.st_uid}, not by you (uid {os.getuid()}); only "
                "your own key can pair your scene and driver: copy it to a file of yours (mode 0600)"
            )
        if st.st_mode & 0o077:
            raise KeyFileError(
                f"key file {path}: mode {stat.S_IMODE(st.st_mode):04o} lets others read or change it "
                f"(at most 0600): chmod 600 {path}, and if others may have read it, delete it so a "
                "new key is made (then copy the new one to the other end)"
            )
        text = os.read(fd, KEY_HEX + 3)  # 64 digits and a line end ("\n" or "\r\n"); one more: too long
    finally:
        os.close(fd)
    if re.fullmatch(rb"[0-9a-fA-F]{%d}\r?\n?" % KEY_HEX, text) is None:
        raise KeyFileError(
            f"key file {path}: not a key of {KEY_HEX} hex digits ({st.st_size} bytes); delete it so a "
            "new key is made, or copy the other end's key file here"
        )
    key = binascii.unhexlify(text[:KEY_HEX])
    if len(set(key)) < MIN_DISTINCT_BYTES:
        raise KeyFileError(
            f"key file {path}: a key of {len(set(key))} distinct bytes (all zero, a repeated pattern), "
            "not a random one: anyone could guess it. Delete it so a new key is made (then copy it to "
            "the other end)"
        )
    return key, path


def _missing(path: Path):
    try:
        default = key_path()
    except KeyFileError:
        default = f"${KEY_ENV}, else ~/.config/godobject/link.key"
    raise KeyFileError(
        f"key file {path} does not exist: give the key file the other end uses (each end names its "
        f"key file and fingerprint when it starts), or leave the key file out to use the default "
        f"({default}), made on first use; copy it here if this path is wanted"
    )


def key_fingerprint(key: bytes) -> str:
    """8 hex digits that name a key without revealing it: compare the two ends' to see they pair."""
    return hmac.digest(key, b"godobject link fingerprint", hashlib.sha256)[:4].hex()
