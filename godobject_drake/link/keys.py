"""The link's key (the pairing: :mod:`godobject_drake.link.transport`): 32 random bytes,
as 64 hex digits in a file only its owner may read (mode 0600, in a folder only its owner may
write), created on first use by whichever end starts first: ``key_file`` (scene) /
``--key-file`` (driver), else ``$GODOBJECT_LINK_KEY``, else ``~/.config/godobject/link.key``
(:func:`key_path`, :func:`load_key`)."""

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
    """A key file that cannot pair a link: the message names the file, what is wrong and the fix."""


def key_path(key_file: str | Path = "") -> Path:
    """The link's key file: ``key_file`` if given, else ``$GODOBJECT_LINK_KEY``, else
    ``$XDG_CONFIG_HOME/godobject/link.key`` (``~/.config/godobject/link.key``)."""
    if key_file:
        return Path(key_file).expanduser()
    if os.environ.get(KEY_ENV):
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


def load_key(key_file: str | Path = "") -> tuple[bytes, Path]:
    """The link's key and its file (:func:`key_path`), created there on first use (and its
    folder, mode 0700). Refused (:class:`KeyFileError`, naming the file and the fix) when the
    file is not a regular file of yours that only you can read or change, or not 64 hex digits."""
    path = key_path(key_file)
    folder = path.parent
    if not folder.exists():
        folder.mkdir(mode=0o700, parents=True)
    _check_folder(folder, path)
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK)
    except FileNotFoundError:
        _create_key(path)
        return load_key(path)
    except OSError as e:  # ELOOP: a symbolic link
        raise KeyFileError(
            f"key file {path}: {e.strerror}; give the path of a regular file (not a link), or a new "
            "path where the key will be created"
        ) from None
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode):
            raise KeyFileError(
                f"key file {path}: not a regular file; give the path of the key file (64 hex "
                "digits), or a new path where the key will be created"
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
    return binascii.unhexlify(text[:KEY_HEX]), path


def key_fingerprint(key: bytes) -> str:
    """8 hex digits that name a key without revealing it: compare the two ends' to see they pair."""
    return hmac.digest(key, b"godobject link fingerprint", hashlib.sha256)[:4].hex()
