"""The link's checks (godobject_drake.link, issue 45): the key file, the datagrams, each end's
rules (pairing, replays, other sessions, other addresses, a second driver, floods), exactly.

Two layers: the ends (:class:`SceneEnd`, :class:`DriverEnd`) with datagrams handed between them
by the test, so every count is exact, and :class:`UdpLcm` over real sockets on 127.0.0.1. Fast,
and the mutation goal's tests for the link (pyproject ``[tool.mutmut]``)."""

import hashlib
import hmac
import logging
import math
import os
import socket
import stat
import struct
import threading
import time
from pathlib import Path

import pytest
from drake import lcmt_force_torque, lcmt_robot_state

from godobject_drake.driver.process import main as process_main
from godobject_drake.link import keys as key_files
from godobject_drake.link import messages, transport
from godobject_drake.link.keys import KeyFileError
from godobject_drake.link.transport import (
    DRIVER_DATA,
    HELLO,
    LINK_CHANNEL,
    MAX_DATAGRAM,
    TAG_BYTES,
    DriverEnd,
    SceneEnd,
    UdpLcm,
)

KEY = bytes(range(32))
OTHER_KEY = bytes(range(1, 33))
SCENE_AT = ("127.0.0.1", 7667)
DRIVER_AT = ("127.0.0.1", 40000)


# -- helpers, also used by test_driver, test_pairing and test_fuzz -----------------------------------------


@pytest.fixture(autouse=True)
def the_package_logger_as_a_fresh_process_has_it():
    """Each test here hears the link's log as a process of its own would: a scene or a driver run
    earlier in the same process (a command line's handler, its info level) is set aside and put
    back after."""
    logger = logging.getLogger("godobject_drake")
    before = (logger.level, logger.propagate, list(logger.handlers))
    logger.setLevel(logging.NOTSET)
    logger.propagate = True
    for handler in before[2]:
        logger.removeHandler(handler)
    yield
    logger.setLevel(before[0])
    logger.propagate = before[1]
    for handler in before[2]:
        logger.addHandler(handler)


def pump(*links, until, timeout_s: float = 5.0, what: str = "") -> None:
    """Poll ``links`` (waiting 1 ms each for a datagram) until ``until()``; fail after ``timeout_s``
    (generous: only a stalled machine comes near it)."""
    deadline = time.monotonic() + timeout_s
    while not until():
        if time.monotonic() > deadline:
            raise AssertionError(
                f"not within {timeout_s} s: {what}; counts {[dict(x.counts) for x in links]}"
            )
        for link in links:
            link.HandleSubscriptions(1)


def scene_link(**options) -> UdpLcm:
    """A scene's end on a free port of 127.0.0.1 (the kernel's pick, bound at once: no race)."""
    return UdpLcm.listen("udp://127.0.0.1:0", **options)


def driver_link(scene: UdpLcm, **options) -> UdpLcm:
    return UdpLcm.connect(f"udp://127.0.0.1:{scene.port}", **options)


def pair(scene: UdpLcm, driver: UdpLcm) -> None:
    pump(scene, driver, until=lambda: scene.paired and driver.paired, what="pairing")


def received(link: UdpLcm, n: int) -> None:
    """Wait until ``link`` has read ``n`` datagrams in all (handling them)."""
    pump(link, until=lambda: link.counts["udp_received"] >= n, what=f"{n} datagrams")


def accounted(counts: dict) -> bool:
    """Each datagram an end read is counted once: taken, a handshake, refused, or dropped."""
    outcomes = counts["udp_taken"] + counts["udp_handshakes"] + counts["udp_refused"]
    return counts["udp_received"] == outcomes + sum(counts[k] for k in transport.LINK_REJECTED)


def nonzero(counts: dict) -> dict:
    return {k: v for k, v in counts.items() if v}


def handshake(scene: SceneEnd, driver: DriverEnd, now: float = 0.0):
    """HELLO, WELCOME, the driver's first DATA: both paired. Returns what the scene took last."""
    _, welcome = scene.receive(driver.hello(now), DRIVER_AT)
    message, first = driver.receive(welcome, SCENE_AT, now)
    assert message is None
    taken, reply = scene.receive(first, DRIVER_AT)
    assert reply is None
    return taken


def ends(scene_nonce=b"s" * 16, driver_nonce=b"d" * 16):
    return SceneEnd(KEY, scene_nonce), DriverEnd(KEY, SCENE_AT, driver_nonce)


# -- the key file ------------------------------------------------------------------------------------------


def test_the_key_is_created_on_first_use_user_only_and_read_back(tmp_path):
    path = tmp_path / "cfg" / "godobject" / "link.key"
    key, where = key_files.load_key(path, create=True)  # as the default file is
    assert where == path and len(key) == 32
    assert stat.S_IMODE(path.stat().st_mode) == 0o600 and stat.S_IMODE(path.parent.stat().st_mode) == 0o700
    assert path.read_text() == key.hex() + "\n"
    assert key_files.load_key(path) == (key, path)  # read back, not made again
    assert sorted(p.name for p in path.parent.iterdir()) == ["link.key"]  # no temporary file left
    assert key_files.load_key(tmp_path / "another.key", create=True)[0] != key  # each new key is random


def test_the_key_path_is_the_given_file_else_the_environment_else_the_config_folder(tmp_path, monkeypatch):
    monkeypatch.setenv(key_files.KEY_ENV, str(tmp_path / "env.key"))
    monkeypatch.setenv("XDG_CONFIG_HOME", str(tmp_path / "xdg"))
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    assert key_files.key_path(tmp_path / "given.key") == tmp_path / "given.key"
    assert key_files.key_path("~/k") == tmp_path / "home" / "k"
    assert key_files.key_path() == tmp_path / "env.key"
    monkeypatch.delenv(key_files.KEY_ENV)
    assert key_files.key_path() == tmp_path / "xdg" / "godobject" / "link.key"
    monkeypatch.delenv("XDG_CONFIG_HOME")
    assert key_files.key_path() == tmp_path / "home" / ".config" / "godobject" / "link.key"


def test_two_ends_creating_the_key_at_once_get_the_same_one(tmp_path):
    path = tmp_path / "k" / "link.key"
    path.parent.mkdir(mode=0o700)
    keys, start = [], threading.Barrier(8)

    def load():
        start.wait()
        keys.append(key_files.load_key(path, create=True)[0])

    threads = [threading.Thread(target=load) for _ in range(8)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert len(keys) == 8 and len(set(keys)) == 1
    assert sorted(p.name for p in path.parent.iterdir()) == ["link.key"]


KEY_HEX = hashlib.sha256(b"a test key").hexdigest()  # 32 bytes that look random (not all equal)


def _key_file(tmp_path, text=KEY_HEX + "\n", mode=0o600) -> Path:
    folder = tmp_path / "private"
    folder.mkdir(mode=0o700, exist_ok=True)
    path = folder / "link.key"
    path.write_text(text)
    path.chmod(mode)
    return path


@pytest.mark.parametrize("mode", [0o640, 0o604, 0o610, 0o660, 0o602, 0o601])
def test_a_key_others_may_read_or_change_is_refused_naming_its_mode_and_the_fix(tmp_path, mode):
    path = _key_file(tmp_path, mode=mode)
    with pytest.raises(KeyFileError) as refused:
        key_files.load_key(path)
    message = str(refused.value)
    assert message.startswith(f"key file {path}: mode {mode:04o}") and "at most 0600" in message
    assert f"chmod 600 {path}" in message


def test_the_key_mode_0400_is_accepted(tmp_path):
    assert key_files.load_key(_key_file(tmp_path, mode=0o400))[0] == bytes.fromhex(KEY_HEX)


@pytest.mark.parametrize("mode", [0o777, 0o775, 0o757, 0o1777])
def test_a_key_in_a_folder_others_can_write_is_refused(tmp_path, mode):
    folder = tmp_path / "shared"
    folder.mkdir()
    folder.chmod(mode)
    with pytest.raises(KeyFileError) as refused:
        key_files.load_key(folder / "link.key", create=True)
    message = str(refused.value)
    assert f"its folder {folder} (mode {mode:04o}" in message and f"chmod 700 {folder}" in message
    assert not (folder / "link.key").exists()  # nothing created there


def test_a_key_folder_readable_by_others_is_accepted(tmp_path):
    folder = tmp_path / "readable"
    folder.mkdir()
    folder.chmod(0o755)
    assert len(key_files.load_key(folder / "link.key", create=True)[0]) == 32


@pytest.mark.skipif(os.getuid() != 0, reason="changing a file's owner needs root")
def test_a_key_file_or_folder_of_another_user_is_refused(tmp_path):
    path = _key_file(tmp_path)
    os.chown(path, 65534, 65534)
    with pytest.raises(KeyFileError, match=r"owned by uid 65534, not by you \(uid 0\)"):
        key_files.load_key(path)
    with pytest.raises(KeyFileError) as refused:
        key_files.load_key(path)
    assert str(refused.value) == (
        f"key file {path}: owned by uid 65534, not by you (uid 0); only your own key can pair your scene "
        "and driver: copy it to a file of yours (mode 0600)"
    )
    for uid in (65534, 1):
        folder = tmp_path / f"theirs_{uid}"
        folder.mkdir(mode=0o700)
        os.chown(folder, uid, uid)
        with pytest.raises(KeyFileError, match=rf"its folder .*owner uid {uid}\)"):
            key_files.load_key(folder / "link.key", create=True)
    root_folder = tmp_path / "root_owned"  # root's own folders are accepted (the user's is too)
    root_folder.mkdir(mode=0o755)
    assert len(key_files.load_key(root_folder / "link.key", create=True)[0]) == 32


@pytest.mark.skipif(os.getuid() != 0, reason="running a process as another user needs root")
def test_another_user_cannot_read_the_key(tmp_path):
    import subprocess

    path = tmp_path / "k" / "link.key"
    key_files.load_key(path, create=True)
    os.chmod(tmp_path, 0o755)  # pytest's own folder is user-only: let the other user try the file itself
    done = subprocess.run(["cat", str(path)], user=65534, capture_output=True, text=True)
    assert done.returncode == 1 and "Permission denied" in done.stderr and done.stdout == ""


def test_a_symlink_a_folder_or_a_fifo_as_the_key_is_refused_naming_the_fix(tmp_path):
    real = _key_file(tmp_path)
    link = real.parent / "link.key.symlink"
    link.symlink_to(real)
    with pytest.raises(KeyFileError) as refused:
        key_files.load_key(link)
    assert str(refused.value) == (
        f"key file {link}: Too many levels of symbolic links; give the path of a regular file (not a "
        "link), or leave the key file out to use the default, made on first use"
    )
    folder, fifo = real.parent / "a_folder", real.parent / "fifo"
    folder.mkdir()
    os.mkfifo(fifo, 0o600)
    for path in (folder, fifo):  # a FIFO: refused, and no hang on opening it
        with pytest.raises(KeyFileError) as refused:
            key_files.load_key(path)
        assert str(refused.value) == (
            f"key file {path}: not a regular file; give the path of the key file (64 hex digits), or "
            "leave the key file out to use the default, made on first use"
        )


@pytest.mark.parametrize(
    "text",
    ["ab" * 31, "zz" * 32, "ab" * 33, "", "é" * 32, "ab" * 32 + "\n\n", " " + "ab" * 32, "ab" * 32 + "\n\r"],
)
def test_anything_but_64_hex_digits_and_a_line_end_is_refused_naming_its_size(tmp_path, text):
    path = _key_file(tmp_path, text)
    with pytest.raises(KeyFileError) as refused:
        key_files.load_key(path)
    assert str(refused.value) == (
        f"key file {path}: not a key of 64 hex digits ({len(text.encode())} bytes); delete it so a new "
        "key is made, or copy the other end's key file here"
    )


@pytest.mark.parametrize("end", ["", "\n", "\r\n", "\r"])
def test_64_hex_digits_of_either_case_and_a_line_end_are_a_key(tmp_path, end):
    key = bytes(range(0x90, 0xB0))
    assert key_files.load_key(_key_file(tmp_path, key.hex().upper() + end)) == (
        key,
        tmp_path / "private" / "link.key",
    )
    assert key_files.load_key(_key_file(tmp_path, key.hex() + end))[0] == key


def test_the_key_file_messages_name_the_file_and_the_fix(tmp_path, caplog):
    path = _key_file(tmp_path, mode=0o644)
    with pytest.raises(KeyFileError) as refused:
        key_files.load_key(path)
    assert str(refused.value) == (
        f"key file {path}: mode 0644 lets others read or change it (at most 0600): chmod 600 {path}, and "
        "if others may have read it, delete it so a new key is made (then copy the new one to the other end)"
    )
    folder = tmp_path / "open"
    folder.mkdir()
    folder.chmod(0o777)
    with pytest.raises(KeyFileError) as refused:
        key_files.load_key(folder / "k")
    assert str(refused.value) == (
        f"key file {folder / 'k'}: its folder {folder} (mode 0777, owner uid {os.getuid()}) can be "
        "written by others, who could replace the key; keep the key in a folder only you can write "
        f"(chmod 700 {folder}, or the default ~/.config/godobject/)"
    )
    with caplog.at_level(logging.WARNING, logger="godobject_drake.link"):
        new = tmp_path / "new" / "link.key"
        key_files.load_key(new, create=True)  # as the default file is
        key_files.load_key(new)
    assert [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING] == [
        f"created the link key {new} (mode 0600): a scene and a driver pair with the same file; copy it "
        "to the other computer if the driver runs there"
    ]


def test_the_key_is_the_environments_when_none_is_given(link_key):
    assert key_files.load_key()[1] == link_key == Path(os.environ[key_files.KEY_ENV])


def test_the_fingerprint_names_a_key_in_8_hex_digits():
    """The first 4 bytes of HMAC-SHA256(K, "godobject link fingerprint"), as docs/haptic_devices.md says."""
    expected = hmac.new(KEY, b"godobject link fingerprint", hashlib.sha256).hexdigest()[:8]
    assert key_files.key_fingerprint(KEY) == expected and len(expected) == 8
    assert key_files.key_fingerprint(KEY) != key_files.key_fingerprint(OTHER_KEY)
    with pytest.raises(ValueError, match="a link key is 32 bytes, not 31"):
        SceneEnd(KEY[:31])


# -- the datagrams -----------------------------------------------------------------------------------------


def test_a_datagram_is_split_only_if_of_this_link_and_of_a_kind_taken():
    hello = ends()[1].hello(0.0)
    assert len(hello) == 4 + 1 + 32 + TAG_BYTES and hello[:5] == b"GOD1H"
    assert transport.split(hello, (HELLO,)) == HELLO
    assert transport.split(hello, (DRIVER_DATA,)) is None
    assert transport.split(b"LC02" + hello[4:], (HELLO,)) is None
    assert transport.split(hello[:-1], (HELLO,)) is None and transport.split(hello + b"x", (HELLO,)) is None
    assert transport.split(b"", (HELLO,)) is None and transport.split(b"GOD1", (HELLO,)) is None
    data = b"GOD1D" + bytes(MAX_DATAGRAM - 5)
    assert transport.split(data, (DRIVER_DATA,)) == DRIVER_DATA
    assert transport.split(data + b"\0", (DRIVER_DATA,)) is None  # one byte over the limit


def test_data_fields_need_a_named_nul_terminated_channel():
    head = b"GOD1D" + b"s" * 16 + b"d" * 16 + struct.pack(">Q", 7)
    tag = b"t" * TAG_BYTES
    assert transport.data_fields(head + b"CH\0payload" + tag) == (
        (b"s" * 16, b"d" * 16),
        7,
        ("CH", b"payload"),
    )
    assert transport.data_fields(head + b"C\0" + tag) == ((b"s" * 16, b"d" * 16), 7, ("C", b""))
    assert transport.data_fields(head + b"\0payload" + tag) is None  # no channel name
    assert transport.data_fields(head + b"CH" + tag) is None  # no NUL
    assert transport.data_fields(head + b"CH" + tag[:-1] + b"\0") is None  # a NUL in the tag is not one
    assert transport.data_fields(head + b"\xff\0" + tag) is None  # not UTF-8
    assert transport.data_fields(head[:-3]) is None


def test_decode_refuses_a_truncated_or_foreign_message_without_raising():
    state = messages.pose_message(5, [0.1, 0.2, 0.3], [1, 0, 0, 0], "*").encode()
    assert messages.decode(lcmt_robot_state, state).utime == 5
    for cut in range(len(state)):
        assert messages.decode(lcmt_robot_state, state[:cut]) is None
        assert messages.parse_robot_state(state[:cut], messages.POSE_NAMES) is None
    assert messages.decode(lcmt_force_torque, state) is None  # another type
    negative = bytearray(state)
    negative[16:18] = struct.pack(">h", -3)  # num_joints −3
    assert messages.decode(lcmt_robot_state, bytes(negative)) is None


# -- the ends, datagram by datagram ------------------------------------------------------------------------


def test_a_handshake_pairs_both_ends_and_messages_pass_both_ways():
    scene, driver = ends()
    assert handshake(scene, driver) == (LINK_CHANNEL, b"")
    assert scene.session == driver.session == (b"s" * 16, b"d" * 16) and scene.peer == DRIVER_AT
    assert scene.counts["udp_pairings"] == driver.counts["udp_pairings"] == 1
    assert scene.receive(driver.seal("POSE", b"p1"), DRIVER_AT) == (("POSE", b"p1"), None)
    assert driver.receive(scene.seal("FEEDBACK", b"f1"), SCENE_AT, 1.0) == (("FEEDBACK", b"f1"), None)
    assert driver.heard == 1.0
    assert nonzero(scene.counts) == {"udp_pairings": 1, "udp_handshakes": 1, "udp_taken": 2}
    assert nonzero(driver.counts) == {"udp_pairings": 1, "udp_handshakes": 1, "udp_taken": 1}


def test_nothing_is_sealed_before_pairing():
    scene, driver = ends()
    assert scene.seal("FEEDBACK", b"f") is None and driver.seal("POSE", b"p") is None
    assert scene.counts["udp_unpaired"] == 1 and driver.counts["udp_unpaired"] == 1


def test_the_directions_have_their_own_keys_and_counters():
    scene, driver = ends()
    handshake(scene, driver)
    a, b = driver.seal("C", b"x"), driver.seal("C", b"x")
    assert (
        struct.unpack(">Q", a[37:45])[0] == 2 and struct.unpack(">Q", b[37:45])[0] == 3
    )  # 1: the first DATA
    reflected = bytearray(scene.seal("C", b"x"))
    reflected[4:5] = DRIVER_DATA  # a scene's message sent back to it as the driver's: its tag fails
    assert scene.receive(bytes(reflected), DRIVER_AT) == (None, None)
    assert scene.counts["udp_unauthenticated"] == 1
    assert driver.receive(a, SCENE_AT, 0.0) == (None, None) and driver.counts["udp_malformed"] == 1


def test_a_replayed_or_older_message_is_dropped_and_counted():
    scene, driver = ends()
    handshake(scene, driver)
    first, second = driver.seal("C", b"1"), driver.seal("C", b"2")
    assert scene.receive(second, DRIVER_AT)[0] == ("C", b"2")
    assert scene.receive(second, DRIVER_AT)[0] is None  # replayed
    assert scene.receive(first, DRIVER_AT)[0] is None  # older (reordered, or replayed)
    assert scene.receive(driver.seal("C", b"3"), DRIVER_AT)[0] == ("C", b"3")
    assert scene.counts["udp_replayed"] == 2
    back = scene.seal("F", b"f")
    assert driver.receive(back, SCENE_AT, 0.0)[0] == ("F", b"f")
    assert driver.receive(back, SCENE_AT, 0.0)[0] is None and driver.counts["udp_replayed"] == 1


@pytest.mark.parametrize("byte", [0, 4, 5, 30, 40, 50, -1, -32])
def test_a_message_changed_anywhere_is_unauthenticated(byte):
    scene, driver = ends()
    handshake(scene, driver)
    changed = bytearray(driver.seal("CHANNEL", b"payload"))
    changed[byte] ^= 0x01
    before = dict(scene.counts)
    assert scene.receive(bytes(changed), DRIVER_AT) == (None, None)
    changed_counts = {k: v - before[k] for k, v in scene.counts.items() if v != before[k]}
    assert changed_counts in ({"udp_malformed": 1}, {"udp_unauthenticated": 1})


def test_another_key_pairs_nothing_and_moves_nothing():
    scene, driver = ends()
    stranger = DriverEnd(OTHER_KEY, SCENE_AT, b"x" * 16)
    assert scene.receive(stranger.hello(0.0), DRIVER_AT) == (None, None)
    assert scene.counts["udp_unauthenticated"] == 1
    handshake(scene, driver)
    forged = SceneEnd(OTHER_KEY, b"s" * 16)  # another key, the same nonces
    forged._pair((b"s" * 16, b"d" * 16))
    assert driver.receive(forged.seal("FEEDBACK", b"12 N"), SCENE_AT, 0.0) == (None, None)
    assert driver.counts["udp_unauthenticated"] == 1
    welcome = SceneEnd(OTHER_KEY).receive(DriverEnd(OTHER_KEY, SCENE_AT).hello(0.0), DRIVER_AT)[1]
    assert (
        driver.receive(welcome, SCENE_AT, 0.0) == (None, None) and driver.counts["udp_unauthenticated"] == 2
    )
    stranger._pair((b"s" * 16, b"x" * 16))
    assert scene.receive(stranger.seal("POSE", b"10 m"), DRIVER_AT) == (None, None)
    assert scene.counts["udp_unauthenticated"] == 2 and scene.session == (b"s" * 16, b"d" * 16)


def test_a_message_of_an_earlier_scene_is_stale_for_the_next_and_the_driver_pairs_again(caplog):
    """Scene A pairs with the driver, then a scene B (same key, a new nonce) starts on its
    address: the driver's messages of A's session are dropped as stale by B; the driver, not
    hearing A for SILENT_S, says HELLO with a new challenge and pairs with B; A's messages are
    then stale for the driver, and an answer to its first challenge (replayed) pairs nothing."""
    a, driver = ends(b"a" * 16)
    handshake(a, driver, now=0.0)
    old_welcome = a.receive(DriverEnd(KEY, SCENE_AT, b"d" * 16).hello(0.0), DRIVER_AT)[1]
    b = SceneEnd(KEY, b"b" * 16)
    assert b.receive(driver.seal("POSE", b"p"), DRIVER_AT) == (None, None)
    assert b.counts["udp_stale"] == 1 and b.session is None
    assert driver.hello(0.4) is None  # heard at 0: not yet silent
    hello = driver.hello(0.6)
    assert hello is not None and hello[-2 * TAG_BYTES + 16 : -TAG_BYTES] != old_welcome[-2 * TAG_BYTES :]
    _, welcome = b.receive(hello, DRIVER_AT)
    _, first = driver.receive(welcome, SCENE_AT, 0.6)
    assert b.receive(first, DRIVER_AT)[0] == (LINK_CHANNEL, b"")
    assert driver.session == (b"b" * 16, b"d" * 16) and driver.counts["udp_pairings"] == 2
    with caplog.at_level(logging.WARNING, logger="godobject_drake.link"):
        assert driver.receive(a.seal("FEEDBACK", b"old"), SCENE_AT, 0.7) == (None, None)
        assert driver.receive(a.seal("FEEDBACK", b"old"), SCENE_AT, 0.7) == (None, None)
    assert driver.receive(old_welcome, SCENE_AT, 0.7) == (None, None)
    assert driver.counts["udp_stale"] == 3 and driver.session[0] == b"b" * 16
    said = [
        r.getMessage()
        for r in caplog.records
        if r.name == "godobject_drake.link" and r.levelno >= logging.WARNING
    ]
    assert said == [
        "a message of another session arrived from 127.0.0.1:40000: a driver still paired with an earlier "
        "scene; it finds this one by itself (it says HELLO after 0.5 s without its scene), or restart it "
        "(counted in udp_stale, said once)",
        "a message of another session arrived from the scene at 127.0.0.1:7667: an earlier scene's (it "
        "restarted), or one that has not paired this driver; dropped, nothing rendered from it; this "
        "driver pairs with the scene that answers its HELLO (counted in udp_stale, said once)",
    ]
    assert driver.receive(b.seal("FEEDBACK", b"new"), SCENE_AT, 0.8)[0] == ("FEEDBACK", b"new")


def test_the_driver_says_hello_every_interval_until_paired_then_only_after_a_silence():
    scene, driver = ends()
    first = driver.hello(0.0)
    assert driver.hello(transport.HELLO_INTERVAL_S * 0.99) is None
    again = driver.hello(transport.HELLO_INTERVAL_S)
    assert again == first  # the same challenge while the search goes on
    _, welcome = scene.receive(again, DRIVER_AT)
    scene.receive(driver.receive(welcome, SCENE_AT, 0.25)[1], DRIVER_AT)
    assert driver.heard == 0.25
    assert driver.hello(0.25 + transport.SILENT_S) is None
    later = driver.hello(0.25 + transport.SILENT_S + 0.01)
    assert later is not None and later != first  # a new search, a new challenge
    assert driver.hello(0.25 + transport.SILENT_S + 0.02) is None
    driver.receive(scene.seal("FEEDBACK", b"f"), SCENE_AT, 11.0)  # heard: no HELLO needed
    assert driver.hello(11.0 + transport.SILENT_S) is None


def test_a_driver_hears_nothing_from_another_address():
    scene, driver = ends()
    _, welcome = scene.receive(driver.hello(0.0), DRIVER_AT)
    assert driver.receive(welcome, ("127.0.0.1", 7668), 0.0) == (None, None)
    assert driver.receive(welcome, ("127.0.0.2", 7667), 0.0) == (None, None)
    assert driver.counts["udp_foreign"] == 2 and driver.session is None
    assert (
        driver.receive(b"junk", ("127.0.0.1", 1), 0.0) == (None, None) and driver.counts["udp_foreign"] == 3
    )


def test_only_a_newer_message_of_the_paired_driver_moves_it_to_another_address(caplog):
    """A message of the session from another address is a replay (foreign, said once) unless it
    is newer than every one taken: then it is the driver's own, and the scene answers it there."""
    scene, driver = ends()
    handshake(scene, driver)
    old = driver.seal("POSE", b"p")
    assert scene.receive(old, DRIVER_AT)[0] == ("POSE", b"p")
    with caplog.at_level(logging.WARNING, logger="godobject_drake.link"):
        assert scene.receive(old, ("127.0.0.1", 40001)) == (None, None)
        assert scene.receive(old, ("127.0.0.1", 40001)) == (None, None)
    assert scene.counts["udp_foreign"] == 2 and scene.peer == DRIVER_AT
    assert [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING] == [
        "an old message of the paired driver arrived from 127.0.0.1:40001, not 127.0.0.1:40000: a "
        "replay, dropped (counted in udp_foreign, said once)"
    ]
    with caplog.at_level(logging.INFO, logger="godobject_drake.link"):
        assert scene.receive(driver.seal("POSE", b"q"), ("127.0.0.1", 40001))[0] == ("POSE", b"q")
    assert caplog.records[-1].getMessage() == "the paired driver moved to 127.0.0.1:40001"
    assert scene.peer == ("127.0.0.1", 40001) and scene.counts["udp_foreign"] == 2
    assert scene.counts["udp_taken"] == 3 and scene.counts["udp_pairings"] == 1


def test_a_new_session_is_taken_only_after_the_paired_driver_has_been_silent(caplog):
    """Driver A pairs at 0 s and is last heard at 0.5 s; B (the same key, a new session: A
    restarted) is REFUSED until A has been silent over DRIVER_SILENT_S, then welcomed, and its
    first message pairs the scene; A's messages are then a second driver's."""
    scene, a = ends()
    b = DriverEnd(KEY, SCENE_AT, b"b" * 16)
    b_at = ("127.0.0.1", 40007)
    _, first = a.receive(scene.receive(a.hello(0.0), DRIVER_AT, 0.0)[1], SCENE_AT, 0.0)
    scene.receive(first, DRIVER_AT, 0.0)
    assert scene.session == (b"s" * 16, b"d" * 16)
    assert scene.receive(a.seal("POSE", b"a"), DRIVER_AT, 0.5)[0] == ("POSE", b"a") and scene.heard == 0.5
    silent = 0.5 + transport.DRIVER_SILENT_S
    refused = scene.receive(b.hello(silent), b_at, silent)[1]
    assert refused[4:5] == transport.REFUSED  # silent exactly DRIVER_SILENT_S: not yet
    assert b.receive(refused, SCENE_AT, silent) == (None, None) and b.session is None
    with caplog.at_level(logging.WARNING, logger="godobject_drake.link"):
        welcome = scene.receive(b.hello(silent + 0.1), b_at, silent + 0.01)[1]
        assert welcome[4:5] == transport.WELCOME
        _, first = b.receive(welcome, SCENE_AT, 0.0)
        assert scene.receive(first, b_at, silent + 0.02)[0] == (LINK_CHANNEL, b"")
        assert scene.session == (b"s" * 16, b"b" * 16) and scene.peer == b_at and scene.heard == silent + 0.02
        assert scene.receive(a.seal("POSE", b"late"), DRIVER_AT, silent + 0.03) == (None, None)
    assert scene.counts["udp_pairings"] == 2 and scene.counts["udp_refused_drivers"] == 1
    assert scene.counts["udp_refused"] == 2 and scene.counts["udp_handshakes"] == 2
    assert [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING] == [
        "the scene at 127.0.0.1:7667 refused this driver: it is paired with another driver, which "
        "still sends; nothing is rendered (stop the other driver: this one is taken once that one "
        "has been silent 1.0 s)",
        "paired with a new driver at 127.0.0.1:40007: the driver at 127.0.0.1:40000 had been silent over "
        "1.0 s (a driver restarted)",
        "refused a second driver (at 127.0.0.1:40000): this scene is paired with the driver at "
        "127.0.0.1:40007, which still sends; stop one of them (a new driver is taken once the paired "
        "one has been silent 1.0 s) (lcm_udp_refused_drivers in the metrics)",
    ]
    assert driver_sees(scene, b) == [("FEEDBACK", b"f")]


def driver_sees(scene: SceneEnd, driver: DriverEnd) -> list:
    message, _ = driver.receive(scene.seal("FEEDBACK", b"f"), SCENE_AT, 0.0)
    return [message] if message is not None else []


def test_the_same_hello_is_answered_at_most_every_HELLO_ANSWER_S_and_a_replay_is_no_second_driver(caplog):
    """A HELLO replayed (the scene paired with another driver): answered REFUSED once per
    HELLO_ANSWER_S, the rest counted replayed, and no "second driver" said or counted; a driver
    that asks again with a new challenge after its REFUSED is one, said once."""
    scene, first = ends()
    _, welcome = first.receive(scene.receive(first.hello(0.0), DRIVER_AT, 0.0)[1], SCENE_AT, 0.0)
    scene.receive(welcome, DRIVER_AT, 0.0)  # paired, heard at 0 s
    other = DriverEnd(KEY, SCENE_AT, b"o" * 16)
    hello = other.hello(0.0)
    step = transport.HELLO_ANSWER_S
    with caplog.at_level(logging.WARNING, logger="godobject_drake.link"):
        answers = [scene.receive(hello, ("127.0.0.1", 50000), t * step / 4)[1] for t in range(9)]
        assert [t for t, answer in enumerate(answers) if answer is not None] == [0, 4, 8]
        assert scene.counts["udp_replayed"] == 6 and scene.counts["udp_refused"] == 3
        assert scene.counts["udp_refused_drivers"] == 0 and caplog.records == []
        assert other.receive(answers[0], SCENE_AT, 0.0) == (None, None)  # REFUSED: it asks anew
        assert scene.receive(other.hello(1.0), ("127.0.0.1", 50000), 0.5)[1][4:5] == transport.REFUSED
    assert scene.counts["udp_refused_drivers"] == 1
    assert [r.getMessage()[:40] for r in caplog.records if r.levelno >= logging.WARNING] == [
        "the scene at 127.0.0.1:7667 refused this",
        "refused a second driver (at 127.0.0.1:50",
    ]


def test_a_scene_remembers_at_most_MAX_REFUSED_hellos_it_answered(monkeypatch):
    """The HELLOs answered are remembered up to MAX_REFUSED (then those older than HELLO_ANSWER_S
    are forgotten); one not remembered is answered each time."""
    monkeypatch.setattr(transport, "MAX_REFUSED", 4)
    scene = SceneEnd(KEY, b"s" * 16)
    hellos = [DriverEnd(KEY, SCENE_AT, bytes([i]) * 16).hello(0.0) for i in range(5)]
    assert all(scene.receive(h, DRIVER_AT, 0.0)[1] is not None for h in hellos)
    assert scene.receive(hellos[0], DRIVER_AT, 0.01)[1] is None  # remembered: too soon
    assert scene.receive(hellos[4], DRIVER_AT, 0.01)[1] is not None  # the fifth: not remembered
    assert scene.receive(hellos[4], DRIVER_AT, 1.0)[1] is not None  # the others forgotten, it kept
    assert scene.receive(hellos[4], DRIVER_AT, 1.01)[1] is None
    assert scene.receive(hellos[0], DRIVER_AT, 1.01)[1] is not None
    assert scene.counts["udp_handshakes"] == 8 and scene.counts["udp_replayed"] == 2


def test_a_restarted_driver_pairs_again_with_the_running_scene(monkeypatch):
    """Before: a driver killed and started again was refused until the scene ended (its tool frozen);
    now it is taken once the first has been silent DRIVER_SILENT_S (over sockets, the real clock;
    0.3 s here to keep the test, run per mutant, quick)."""
    monkeypatch.setattr(transport, "DRIVER_SILENT_S", 0.3, raising=False)  # main's code had none
    scene, a, b = scene_link(), None, None
    try:
        a = driver_link(scene)
        started = time.monotonic()  # before A is last heard: the silence is measured from later
        pair(scene, a)
        a.close()  # the driver crashed
        b = driver_link(scene)
        pump(scene, b, until=lambda: b.paired and scene.end.session[1] == b.end.nonce, what="B paired")
        assert time.monotonic() - started > transport.DRIVER_SILENT_S  # not before A was silent
        b.Publish("POSE", b"b")
        scene.Publish("FEEDBACK", b"to b")
        got = []
        b.Subscribe("FEEDBACK", got.append)
        pump(scene, b, until=lambda: got, what="feedback to the new driver")
        assert got == [b"to b"] and scene.counts["udp_pairings"] == 2
    finally:
        for link in (scene, a, b):
            if link is not None:
                link.close()


def test_a_first_message_replayed_from_elsewhere_cannot_hold_the_scene():
    """Before: a thief that sent the driver's first message before it arrived paired the scene
    with itself for its whole life, the real driver's messages dropped as foreign; now the
    driver's next (newer) message moves the scene back to it, and its feedback goes there."""
    scene = scene_link()
    real, thief = (socket.socket(socket.AF_INET, socket.SOCK_DGRAM) for _ in range(2))
    try:
        for s in (real, thief):
            s.bind(("127.0.0.1", 0))
            s.settimeout(5.0)
        at = ("127.0.0.1", scene.port)
        end = DriverEnd(scene.end.key, at)
        real.sendto(end.hello(0.0), at)
        received(scene, 1)
        _, first = end.receive(real.recv(65535), at, 0.0)
        thief.sendto(first, at)  # the replay wins the race
        received(scene, 2)
        assert scene.paired and scene.end.peer == thief.getsockname()
        real.sendto(first, at)
        real.sendto(end.seal("POSE", b"p"), at)
        received(scene, 4)
        scene.Publish("FEEDBACK", b"f")
        message, _ = end.receive(real.recv(65535), at, 0.0)
        assert message == ("FEEDBACK", b"f") and scene.end.peer == real.getsockname()
        assert scene.counts["udp_foreign"] == 1 and scene.counts["udp_taken"] == 2
    finally:
        for s in (scene, real, thief):
            s.close()


def test_a_flood_of_replayed_hellos_gets_few_answers_and_no_false_second_driver(caplog):
    """Before: each of 1000 replayed HELLOs of an earlier driver was answered and the scene logged
    "refused a second driver"; now the same HELLO is answered once per HELLO_ANSWER_S at most."""
    scene, driver, thief = scene_link(), None, socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        driver = driver_link(scene)
        pair(scene, driver)
        thief.bind(("127.0.0.1", 0))
        hello = DriverEnd(scene.end.key, ("127.0.0.1", scene.port)).hello(0.0)  # an earlier driver's
        n = scene.counts["udp_received"]
        started = time.monotonic()
        with caplog.at_level(logging.WARNING, logger="godobject_drake.link"):
            for _ in range(1000):
                thief.sendto(hello, ("127.0.0.1", scene.port))
            received(scene, n + 1000)
        elapsed = time.monotonic() - started
        answers = drain_socket(thief)
        assert scene.counts["udp_refused_drivers"] == 0
        assert not [r for r in caplog.records if "second driver" in r.getMessage()]
        assert 1 <= len(answers) <= 1 + elapsed / transport.HELLO_ANSWER_S, (len(answers), elapsed)
    finally:
        for s in (scene, driver, thief):
            if s is not None:
                s.close()


def drain_socket(s: socket.socket) -> list[bytes]:
    s.settimeout(0.05)
    out = []
    try:
        while True:
            out.append(s.recv(65535))
    except TimeoutError:
        return out


def test_a_scene_takes_one_driver_and_refuses_a_second_saying_so(caplog):
    """Both drivers are welcomed before either pairs; the first DATA pairs its driver, the other's
    is refused, and so is its next HELLO (REFUSED, which it takes as such): counted once per
    driver in udp_refused_drivers, every message in udp_refused, and logged once each side."""
    scene, first = ends()
    second = DriverEnd(KEY, SCENE_AT, b"e" * 16)
    second_at = ("127.0.0.1", 40002)
    _, w1 = scene.receive(first.hello(0.0), DRIVER_AT)
    _, w2 = scene.receive(second.hello(0.0), second_at)
    _, d1 = first.receive(w1, SCENE_AT, 0.0)
    _, d2 = second.receive(w2, SCENE_AT, 0.0)
    with caplog.at_level(logging.INFO, logger="godobject_drake.link"):
        assert scene.receive(d1, DRIVER_AT)[0] == (LINK_CHANNEL, b"")
        assert scene.receive(d2, second_at) == (None, None)
        assert scene.receive(second.seal("POSE", b"10 m"), second_at) == (None, None)
        _, refused = scene.receive(second.hello(1.0), second_at)
        assert refused[4:5] == transport.REFUSED
        assert second.receive(refused, SCENE_AT, 1.0) == (None, None)
        assert second.receive(refused, SCENE_AT, 1.0) == (None, None)
    assert scene.session == (b"s" * 16, b"d" * 16) and scene.peer == DRIVER_AT
    assert scene.counts["udp_refused"] == 3 and scene.counts["udp_refused_drivers"] == 1
    assert second.counts["udp_refused"] == 2 and second.seal("POSE", b"x") is not None  # its own, for nobody
    warnings = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    assert warnings == [
        "refused a second driver (at 127.0.0.1:40002): this scene is paired with the driver at "
        "127.0.0.1:40000, which still sends; stop one of them (a new driver is taken once the paired "
        "one has been silent 1.0 s) (lcm_udp_refused_drivers in the metrics)",
        "the scene at 127.0.0.1:7667 refused this driver: it is paired with another driver, which "
        "still sends; nothing is rendered (stop the other driver: this one is taken once that one "
        "has been silent 1.0 s)",
    ]
    _, welcome = scene.receive(first.hello(2.0), DRIVER_AT)  # the paired driver is welcomed again
    assert welcome[4:5] == transport.WELCOME and first.receive(welcome, SCENE_AT, 2.0) == (None, None)
    assert first.counts["udp_pairings"] == 1


def test_a_scene_remembers_at_most_MAX_REFUSED_second_drivers(monkeypatch):
    monkeypatch.setattr(transport, "MAX_REFUSED", 4)  # 64 by default; 4 keeps the test (run per mutant) quick
    scene, first = ends()
    handshake(scene, first)
    for i in range(transport.MAX_REFUSED + 3):
        other = DriverEnd(KEY, SCENE_AT, i.to_bytes(16, "big"))
        other.receive(scene.receive(other.hello(0.0), ("127.0.0.1", 50000 + i))[1], SCENE_AT, 0.0)
        scene.receive(other.hello(1.0), ("127.0.0.1", 50000 + i))  # asked again: a driver, not a replay
    assert scene.counts["udp_refused_drivers"] == transport.MAX_REFUSED
    assert len(scene.refused) == transport.MAX_REFUSED and scene.counts["udp_refused"] == 2 * (
        transport.MAX_REFUSED + 3
    )


def test_a_driver_remembers_at_most_MAX_REFUSED_scenes(caplog, monkeypatch):
    monkeypatch.setattr(transport, "MAX_REFUSED", 4)
    driver = DriverEnd(KEY, SCENE_AT, b"d" * 16)
    with caplog.at_level(logging.WARNING, logger="godobject_drake.link"):
        for i in range(transport.MAX_REFUSED + 2):
            scene = SceneEnd(KEY, i.to_bytes(16, "big"))
            handshake(scene, DriverEnd(KEY, SCENE_AT, b"o" * 16))
            refused = scene.receive(driver.hello(float(i)), DRIVER_AT)[1]
            driver.receive(refused, SCENE_AT, float(i))
    assert (
        driver.counts["udp_refused"] == transport.MAX_REFUSED + 2
        and len(driver.refused_by) == transport.MAX_REFUSED
    )
    logged = [r for r in caplog.records if r.getMessage().startswith("the scene at 127.0.0.1:7667 refused")]
    assert len(logged) == transport.MAX_REFUSED


def test_welcome_and_refused_answer_only_the_current_challenge():
    scene, driver = ends()
    assert driver.receive(scene.receive(ends()[1].hello(0.0), DRIVER_AT)[1], SCENE_AT, 0.0) == (None, None)
    assert driver.counts["udp_stale"] == 1  # answers a HELLO this driver never sent (no challenge yet)
    hello = driver.hello(0.0)
    other = DriverEnd(KEY, SCENE_AT, b"d" * 16)  # the same nonce, another challenge
    welcome_to_other = scene.receive(other.hello(0.0), DRIVER_AT)[1]
    assert driver.receive(welcome_to_other, SCENE_AT, 0.0) == (None, None)
    assert driver.counts["udp_stale"] == 2 and driver.session is None
    welcome = scene.receive(hello, DRIVER_AT)[1]
    assert driver.receive(welcome, SCENE_AT, 0.0)[1] is not None and driver.session is not None
    assert driver.receive(welcome, SCENE_AT, 0.0) == (None, None)  # again: already paired, nothing sent
    assert driver.counts["udp_pairings"] == 1


def test_kinds_an_end_does_not_take_are_malformed():
    scene, driver = ends()
    hello = driver.hello(0.0)
    _, welcome = scene.receive(hello, DRIVER_AT)
    assert scene.receive(welcome, DRIVER_AT) == (None, None)  # a WELCOME sent to the scene
    assert driver.receive(hello, SCENE_AT, 0.0) == (None, None)  # a HELLO sent to the driver
    assert scene.counts["udp_malformed"] == 1 and driver.counts["udp_malformed"] == 1


def test_a_message_too_long_for_a_datagram_is_refused_when_sealed():
    scene, driver = ends()
    handshake(scene, driver)
    room = MAX_DATAGRAM - (transport.DATA_HEAD + 2 + TAG_BYTES)  # a one-letter channel and its NUL
    assert len(driver.seal("C", bytes(room))) == MAX_DATAGRAM
    with pytest.raises(ValueError, match=r"of 8114 bytes is over the link's 8192-byte datagram"):
        driver.seal("C", bytes(room + 1))


def _tag(key: bytes, label: bytes, data: bytes) -> bytes:
    """The wire format's tag, computed here from its description (docs/haptic_devices.md)."""
    derived = hmac.new(key, b"godobject link " + label, hashlib.sha256).digest()
    return hmac.new(derived, data, hashlib.sha256).digest()


def test_the_datagrams_are_as_the_wire_format_says():
    """Known answers, from the format's description alone: HELLO, WELCOME and DATA (both ways)."""
    scene, driver = ends()
    driver_nonce, scene_nonce = b"d" * 16, b"s" * 16
    hello = driver.hello(0.0)
    challenge = hello[5 + 16 : 5 + 32]
    head = b"GOD1H" + driver_nonce + challenge
    assert hello == head + _tag(KEY, b"hello", head)
    _, welcome = scene.receive(hello, DRIVER_AT)
    head = b"GOD1W" + scene_nonce + driver_nonce + challenge
    assert welcome == head + _tag(KEY, b"hello", head)
    _, first = driver.receive(welcome, SCENE_AT, 0.0)
    head = b"GOD1D" + scene_nonce + driver_nonce + struct.pack(">Q", 1) + LINK_CHANNEL.encode() + b"\0"
    assert first == head + _tag(KEY, b"dataD" + scene_nonce + driver_nonce, head)
    scene.receive(first, DRIVER_AT)
    back = scene.seal("FEEDBACK", b"f")
    head = b"GOD1S" + scene_nonce + driver_nonce + struct.pack(">Q", 1) + b"FEEDBACK\0f"
    assert back == head + _tag(KEY, b"dataS" + scene_nonce + driver_nonce, head)


def test_the_robot_state_of_a_pose_is_parsed_with_its_grasp_taken_out():
    names = list(messages.POSE_NAMES)
    q = [1.0, 0.0, 0.0, 0.0]
    for grasp, expected in (("*", "*"), ("", ""), ("brick_0", "brick_0"), (None, None)):
        raw = messages.pose_message(2**40, [0.5, -0.25, 1.0], q, grasp).encode()
        assert messages.parse_robot_state(raw, names) == (2**40, names, [0.5, -0.25, 1.0, *q], expected)
    two = lcmt_robot_state()
    two.utime, two.num_joints, two.joint_name, two.joint_position = 1, 2, ["x", "y"], [0.0, 1.0]
    assert messages.parse_robot_state(two.encode(), names) == (1, ["x", "y"], [0.0, 1.0], None)
    assert messages.parse_robot_state(two.encode()[:-4], names) is None  # one value short
    first = lcmt_robot_state()
    first.utime, first.num_joints = 3, 3
    first.joint_name, first.joint_position = ["grasp=*", "x", "grasp=y"], [0.0, 0.5, 0.0]
    assert messages.parse_robot_state(first.encode(), names) == (
        3,
        ["x", "grasp=y"],
        [0.5, 0.0],
        "*",
    )  # the first


def test_each_rejection_is_counted_each_time():
    """Every count goes up by one per datagram (two of each here), not to one."""
    scene, driver = ends()
    forged_hello = DriverEnd(OTHER_KEY, SCENE_AT, b"x" * 16).hello(0.0)
    driver.seal("P", b"")
    driver.seal("P", b"")
    hello = driver.hello(0.0)
    for _ in range(2):
        scene.receive(b"junk", DRIVER_AT)
        scene.receive(forged_hello, DRIVER_AT)
        driver.receive(b"junk", SCENE_AT, 0.0)
        driver.receive(b"junk", ("127.0.0.1", 1), 0.0)
        scene.seal("F", b"")
        _, welcome = scene.receive(hello, DRIVER_AT)
        driver.receive(welcome, SCENE_AT, 0.0)
    keys = ("udp_malformed", "udp_unauthenticated", "udp_unpaired", "udp_handshakes")
    assert [scene.counts[k] for k in keys] == [2, 2, 2, 2]
    for _ in range(2):  # the head of a DATA, and no channel after it
        assert scene.receive(b"GOD1D" + bytes(40) + b"\0" + bytes(32), DRIVER_AT) == (None, None)
    assert scene.counts["udp_malformed"] == 4
    keys = ("udp_malformed", "udp_foreign", "udp_unpaired", "udp_handshakes")
    assert [driver.counts[k] for k in keys] == [2, 2, 2, 2]
    scene.receive(driver.seal("P", b"1"), DRIVER_AT)  # the first DATA pairs the scene
    older = SceneEnd(KEY, b"o" * 16)
    older._pair((b"o" * 16, b"d" * 16))
    stale = DriverEnd(KEY, SCENE_AT, b"d" * 16)
    stale._pair((b"q" * 16, b"d" * 16))
    taken = driver.seal("P", b"p")
    scene.receive(taken, DRIVER_AT)
    for _ in range(2):
        scene.receive(taken, ("127.0.0.1", 40009))  # not newer, from elsewhere: a replay
        scene.receive(stale.seal("P", b"p"), DRIVER_AT)
        driver.receive(older.seal("F", b"f"), SCENE_AT, 0.0)
        driver.receive(b"GOD1S" + bytes(40) + b"F\0" + bytes(32), SCENE_AT, 0.0)
    assert (scene.counts["udp_foreign"], scene.counts["udp_stale"]) == (2, 2)
    assert (driver.counts["udp_stale"], driver.counts["udp_unauthenticated"]) == (2, 2)


def test_a_search_after_a_silence_asks_a_new_challenge_even_when_answered_at_once():
    scene, driver = ends()
    hello = driver.hello(1.0)
    scene.receive(driver.receive(scene.receive(hello, DRIVER_AT)[1], SCENE_AT, 1.0)[1], DRIVER_AT)
    assert driver.challenge == hello[21:37] and driver.answered
    again = driver.hello(1.0 + transport.SILENT_S + 0.001)
    assert again[21:37] == driver.challenge != hello[21:37] and not driver.answered
    old_welcome = scene.receive(hello, DRIVER_AT)[1]  # an answer to the first challenge, replayed
    assert driver.receive(old_welcome, SCENE_AT, 2.0) == (None, None) and driver.counts["udp_stale"] == 1


# -- the transport, over sockets on 127.0.0.1 --------------------------------------------------------------


def test_udp_links_pair_and_carry_messages_both_ways():
    scene, driver = scene_link(), None
    try:
        driver = driver_link(scene)
        poses, feedback = [], []
        scene.Subscribe("POSE", poses.append)
        driver.Subscribe("FEEDBACK", feedback.append)
        driver.Publish("POSE", b"before")  # not paired: not sent
        scene.Publish("FEEDBACK", b"before")
        assert driver.counts["udp_unpaired"] == 1 and scene.counts["udp_unpaired"] == 1
        pair(scene, driver)
        assert scene.end.peer == ("127.0.0.1", driver.port)
        driver.Publish("POSE", b"p")
        scene.Publish("FEEDBACK", b"f")
        pump(scene, driver, until=lambda: poses and feedback, what="both messages")
        assert poses == [b"p"] and feedback == [b"f"]
        assert driver.counts["udp_sent"] == 3 and scene.counts["udp_sent"] == 2  # HELLO, first DATA; WELCOME
        assert accounted(scene.counts) and accounted(driver.counts)
        assert scene.counts["udp_taken"] == 2 and driver.counts["udp_handshakes"] == 1
    finally:
        scene.close()
        if driver is not None:
            driver.close()


def test_the_driver_sends_its_hello_from_the_poll_at_the_interval():
    now = [0.0]
    ticks = iter(range(10))
    scene = scene_link(clock=lambda: float(next(ticks)))  # each datagram a second later: each HELLO answered
    driver = driver_link(scene, clock=lambda: now[0])
    try:
        driver.HandleSubscriptions(0)
        driver.HandleSubscriptions(0)
        assert driver.counts["udp_sent"] == 1  # one HELLO: the next is due at 0.1 s
        now[0] = transport.HELLO_INTERVAL_S
        driver.HandleSubscriptions(0)
        assert driver.counts["udp_sent"] == 2
        received(scene, 2)
        assert scene.counts["udp_sent"] == 2  # two WELCOMEs
    finally:
        scene.close(), driver.close()


def test_a_flood_is_read_at_most_MAX_PER_POLL_datagrams_a_poll():
    scene = scene_link()
    scene.poll_budget_s = math.inf  # the count's bound alone (the time's: the test below)
    junk = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        n = transport.MAX_PER_POLL + 40
        for i in range(n):
            junk.sendto(b"junk %d" % i, ("127.0.0.1", scene.port))
        time.sleep(0.05)
        assert scene.HandleSubscriptions(0) == 0
        assert scene.counts["udp_received"] == transport.MAX_PER_POLL and scene.counts["udp_flooded"] == 1
        received(scene, n)
        assert scene.counts["udp_malformed"] == n and scene.counts["udp_flooded"] == 1
        assert accounted(scene.counts)
    finally:
        scene.close(), junk.close()


def test_a_polls_reading_is_bounded_in_time_and_the_rest_read_by_the_next():
    """At 2 to 4 µs a datagram in Python, 256 cost most of a 1 kHz period: a poll also stops
    reading :data:`MAX_POLL_S` after its first datagram (here 0: one datagram a poll), the poll
    counted ``udp_flooded``, what is left read by the next polls."""
    assert transport.MAX_POLL_S <= 0.25e-3
    scene = scene_link()
    assert scene.poll_budget_s == transport.MAX_POLL_S
    scene.poll_budget_s = 0.0
    junk = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        for i in range(3):
            junk.sendto(b"junk %d" % i, ("127.0.0.1", scene.port))
        time.sleep(0.05)
        for polls in (1, 2):
            scene.HandleSubscriptions(0)
            assert scene.counts["udp_received"] == polls and scene.counts["udp_flooded"] == polls
        scene.HandleSubscriptions(0)
        scene.HandleSubscriptions(0)  # nothing left: not a flooded poll
        assert scene.counts["udp_received"] == 3 and scene.counts["udp_flooded"] == 2
        assert scene.counts["udp_malformed"] == 3 and accounted(scene.counts)
    finally:
        scene.close(), junk.close()


def test_a_drivers_socket_takes_datagrams_from_its_scene_only():
    """The driver's socket is connected to the scene's address: a stranger's datagrams (from its
    own port, to the driver's port read from /proc/net/udp) are dropped by the kernel before they
    are queued, so they cost the driver's loop nothing (not even a read, ``udp_foreign``), and
    the scene's messages behind them arrive."""
    scene = scene_link()
    driver = driver_link(scene)
    got = []
    driver.Subscribe("FEEDBACK", got.append)
    stranger = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        pair(scene, driver)
        before = driver.counts["udp_received"]
        for i in range(1000):
            stranger.sendto(b"junk %d" % i, ("127.0.0.1", driver.port))
        scene.Publish("FEEDBACK", b"f")
        pump(driver, until=lambda: got, what="the scene's message")
        time.sleep(0.05)
        driver.HandleSubscriptions(0)
        assert got == [b"f"] and driver.counts["udp_received"] == before + 1
        assert driver.counts["udp_foreign"] == driver.counts["udp_flooded"] == 0
    finally:
        scene.close(), driver.close(), stranger.close()


def test_an_oversized_datagram_is_malformed_and_one_at_the_limit_is_read():
    scene = scene_link()
    driver = driver_link(scene)
    got = []
    scene.Subscribe("C", got.append)
    try:
        pair(scene, driver)
        room = MAX_DATAGRAM - (transport.DATA_HEAD + 2 + TAG_BYTES)
        driver.Publish("C", bytes(room))
        driver.sock.sendto(b"GOD1D" + bytes(60000), ("127.0.0.1", scene.port))
        pump(scene, until=lambda: scene.counts["udp_malformed"] == 1 and got, what="both")
        assert len(got[0]) == room
    finally:
        scene.close(), driver.close()


def test_a_port_in_use_or_a_host_without_address_is_refused_naming_the_fix():
    scene = scene_link()
    try:
        with pytest.raises(ValueError) as refused:
            UdpLcm.listen(f"udp://127.0.0.1:{scene.port}")
        assert str(refused.value) == (
            f"LCM URL udp://127.0.0.1:{scene.port}: cannot listen on 127.0.0.1:{scene.port} (Address "
            "already in use); another scene or driver may hold the port: choose another PORT"
        )
        with pytest.raises(ValueError, match=r"no address for 'no-such-host.invalid'.*give an IP address"):
            UdpLcm.connect("udp://no-such-host.invalid:7667")
    finally:
        scene.close()
    assert UdpLcm._address("udp://localhost:5") == ("127.0.0.1", 5)
    # the driver binds its own address towards the scene: 127.0.0.1 here, an interface's on a
    # second computer (before, it bound the scene's address, which a second computer does not have)
    assert UdpLcm._local_address_towards(("127.0.0.1", 5)) == "127.0.0.1"


def test_a_url_that_is_not_udp_host_port_is_refused_naming_the_form():
    for bad in ("udp://127.0.0.1", "udpm://239.255.76.67:7667", "udp://:80", "udp://127.0.0.1:x", "memq://"):
        with pytest.raises(ValueError) as refused:
            transport.parse_url(bad)
        assert str(refused.value) == (
            f"LCM URL {bad!r}: a driver link is udp://HOST:PORT, e.g. udp://127.0.0.1:7667 (127.0.0.1 "
            "keeps every datagram on this machine)"
        )
    assert transport.parse_url("udp://127.0.0.1:7667") == ("127.0.0.1", 7667)
    assert (
        transport.is_udp_url("udp://h:1")
        and not transport.is_udp_url("udpm://h:1")
        and not transport.is_udp_url("memq://")
    )


def test_a_listening_link_names_its_own_address_key_and_buffer(tmp_path, caplog):
    key_file = tmp_path / "k" / "link.key"
    key_files.load_key(key_file, create=True)
    with caplog.at_level(logging.INFO, logger="godobject_drake.link"):
        scene = UdpLcm.listen("udp://localhost:0", key_file)
        driver = driver_link(scene, key_file=key_file)
        pair(scene, driver)
    try:
        key = key_files.load_key(key_file)[0]
        assert scene.get_lcm_url() == f"udp://127.0.0.1:{scene.port}" and scene.key_file == key_file
        assert driver.get_lcm_url() == f"udp://127.0.0.1:{driver.port}" and driver.key_file == key_file
        low = int(Path("/proc/sys/net/ipv4/ip_local_port_range").read_text().split()[0])
        assert driver.port >= low  # a port the kernel picked
        rmem_max = int(Path("/proc/sys/net/core/rmem_max").read_text())
        buffer = scene.sock.getsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF)
        assert buffer == 2 * min(1 << 20, rmem_max)  # Linux reports twice what was set
        messages = [r.getMessage() for r in caplog.records if r.name == "godobject_drake.link"]
        assert messages[-3:] == [
            f"udp://127.0.0.1:{scene.port}: waiting for a driver with the key {key_file} (fingerprint "
            f"{key_files.key_fingerprint(key)})",
            f"paired with the scene at 127.0.0.1:{scene.port}",
            f"paired with the driver at 127.0.0.1:{driver.port}",
        ]
    finally:
        scene.close(), driver.close()


def test_a_poll_hands_on_each_message_to_each_handler_and_says_how_many():
    scene = scene_link()
    driver = driver_link(scene)
    got = []
    scene.Subscribe("A", got.append)
    scene.Subscribe("A", got.append)
    scene.Subscribe("B", got.append)
    try:
        pair(scene, driver)
        driver.Publish("A", b"a")
        driver.Publish("B", b"b")
        time.sleep(0.05)
        handled = scene.HandleSubscriptions(0)
        if handled < 3:  # a loaded machine delivered one late
            handled += scene.HandleSubscriptions(1000)
        assert handled == 3 and got == [b"a", b"a", b"b"]
        assert scene.HandleSubscriptions(0) == 0
    finally:
        scene.close(), driver.close()


def test_a_poll_waits_for_the_first_datagram_only_as_long_as_asked():
    scene = scene_link()
    try:
        start = time.monotonic()
        assert scene.HandleSubscriptions(0) == 0
        assert scene.HandleSubscriptions(-5) == 0
        quick = time.monotonic() - start
        start = time.monotonic()
        assert scene.HandleSubscriptions(40) == 0
        waited = time.monotonic() - start
        assert waited >= 0.04 and waited < 5.0 and quick < 1.0  # upper bounds: only a stalled machine
        assert scene.sock.gettimeout() == 0.0  # non-blocking again after the wait
    finally:
        scene.close()


def test_floods_are_counted_each_time_a_poll_stops_at_its_limit():
    scene = scene_link()
    scene.poll_budget_s = math.inf
    junk = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        for _ in range(2):
            for i in range(transport.MAX_PER_POLL + 1):
                junk.sendto(b"junk %d" % i, ("127.0.0.1", scene.port))
            time.sleep(0.05)
            received(scene, scene.counts["udp_received"] + transport.MAX_PER_POLL + 1)
        assert scene.counts["udp_flooded"] == 2
    finally:
        scene.close(), junk.close()


class _RefusingSocket:
    """The OS refusing to send (a full buffer, no route): ``sendto`` raises ``errno``."""

    def __init__(self, sock, code):
        self.sock, self.code = sock, code

    def sendto(self, data, address):
        raise OSError(self.code, os.strerror(self.code))

    def __getattr__(self, name):
        return getattr(self.sock, name)


def test_a_datagram_the_os_cannot_send_is_counted_and_any_other_error_raised():
    import errno

    scene, driver = scene_link(), None
    try:
        driver = driver_link(scene)
        pair(scene, driver)
        real = driver.sock
        for code in (errno.ECONNREFUSED, errno.EAGAIN, errno.ENOBUFS, errno.EHOSTUNREACH):
            driver.sock = _RefusingSocket(real, code)
            driver.Publish("P", b"p")
        assert driver.counts["udp_send_errors"] == 4
        driver.sock = _RefusingSocket(real, errno.EPERM)
        with pytest.raises(PermissionError):
            driver.Publish("P", b"p")
        driver.sock = real
    finally:
        scene.close()
        if driver is not None:
            driver.close()


def test_a_port_that_cannot_be_bound_is_refused_naming_it():
    scene = scene_link()
    try:
        assert UdpLcm(("127.0.0.1", 0), key=KEY).key_file is None  # made here: no file named
        with pytest.raises(ValueError) as refused:
            UdpLcm(("127.0.0.1", scene.port), key=KEY)
        assert str(refused.value) == (
            f"LCM URL ('127.0.0.1', {scene.port}): cannot listen on 127.0.0.1:{scene.port} (Address "
            "already in use); another scene or driver may hold the port: choose another PORT"
        )
    finally:
        scene.close()


# -- the key: a key for a path, a missing named file, a guessable key, another key ---------------------------


def test_the_key_itself_in_the_environment_or_as_the_key_file_is_refused_and_nothing_made(
    tmp_path, monkeypatch
):
    """Before: $GODOBJECT_LINK_KEY holding the key was taken as a file name, and a new key made in
    the current folder under that name."""
    monkeypatch.chdir(tmp_path)
    key = hashlib.sha256(b"k").hexdigest()
    monkeypatch.setenv(key_files.KEY_ENV, key)
    with pytest.raises(
        KeyFileError, match=r"\$GODOBJECT_LINK_KEY holds 64 hex digits, a key itself .*put the key in a file"
    ):
        key_files.load_key()
    monkeypatch.delenv(key_files.KEY_ENV)
    with pytest.raises(KeyFileError, match="the key file holds 64 hex digits"):
        key_files.load_key(key)
    assert list(tmp_path.iterdir()) == []
    assert process_main(["run", "emulated", "--scene", "udp://127.0.0.1:9", "--key-file", key]) == 2


def test_a_named_key_file_that_does_not_exist_is_an_error_naming_it(tmp_path, monkeypatch, capsys):
    """Before: a mistyped --key-file made a new key there, which paired with nothing."""
    missing = tmp_path / "link.kye"
    with pytest.raises(KeyFileError, match=rf"key file {missing} does not exist: give the key file"):
        key_files.load_key(missing)
    assert not missing.exists()
    assert process_main(["run", "emulated", "--scene", "udp://127.0.0.1:9", "--key-file", str(missing)]) == 2
    assert f"key file {missing} does not exist" in capsys.readouterr().err
    monkeypatch.setenv(key_files.KEY_ENV, str(tmp_path / "default" / "link.key"))
    assert len(key_files.load_key()[0]) == 32  # the default file is made on first use, as documented


@pytest.mark.parametrize("text", ["00" * 32, "ff" * 32, "0123456789abcdef" * 4])
def test_a_key_anyone_could_guess_is_refused(tmp_path, text):
    """Before: an all-zero key paired a scene and a driver."""
    path = tmp_path / "k" / "link.key"
    path.parent.mkdir(mode=0o700)
    path.write_text(text + "\n")
    path.chmod(0o600)
    with pytest.raises(KeyFileError, match=r"distinct bytes .*not a random one"):
        key_files.load_key(path)


def test_a_datagram_with_another_key_is_counted_and_named_once_with_the_fix(caplog):
    """Before: counted only; the scene said "start the driver" while one with another key knocked."""
    scene = SceneEnd(hashlib.sha256(b"scene's").digest())
    driver = DriverEnd(hashlib.sha256(b"driver's").digest(), ("127.0.0.1", 7667))
    with caplog.at_level(logging.WARNING, logger="godobject_drake.link"):
        for now in (0.0, 1.0, 2.0):
            message, reply = scene.receive(driver.hello(now), ("127.0.0.1", 40123))
            assert message is None and reply is None
    assert scene.counts["udp_unauthenticated"] == 3
    said = [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING]
    assert len(said) == 1
    assert said[0].startswith(
        "a datagram with a wrong key arrived from port 40123 (127.0.0.1): the two processes use different "
        "key files (give both the same --key-file"
    )


def test_a_control_character_in_a_key_files_name_is_escaped_in_the_message(tmp_path):
    path = tmp_path / "evil\x1b[2J" / "link.key"
    with pytest.raises(KeyFileError) as refused:
        key_files.load_key(path)
    assert "\x1b" not in str(refused.value) and "evil\\x1b[2J" in str(refused.value)
