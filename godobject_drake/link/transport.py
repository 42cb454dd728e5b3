"""The link's transport: the paired, authenticated unicast UDP that carries the messages of
:mod:`godobject_drake.link.messages` between a scene's LCM devices
(:mod:`godobject_drake.devices.lcm`) and a driver process (:mod:`godobject_drake.driver.process`).

**Transport: LCM messages over unicast UDP**, the scene and a device driver in separate processes.

Drake's LCM (``DrakeLcm``) speaks multicast (``udpm://``) between processes, which a lab's
network or a locked-down machine may not carry, and ``memq://`` stays in one process. A driver
and a scene on one machine (or two, over a cable) need only a point-to-point link, so this is
one: each datagram carries one LCM message (a channel name and a Drake ``lcmt_*`` message's
``encode()`` bytes), sent to one address.

Why datagrams and not a stream (TCP, a Unix stream socket): a haptic loop wants the newest
sample, never a queue of old ones behind a stalled reader; a datagram is a whole message or
nothing (no framing to resynchronise after a crash); there is no connection to set up or tear
down, so a killed scene leaves the driver nothing to clean up (it simply stops hearing
feedback, which its watchdog turns into zero force). UDP rather than a Unix datagram socket:
the same code reaches another machine when the device hangs off a separate real-time computer,
and no socket file is left behind.

**Pairing: only the owner's scene and driver talk**. Any process on the machine can
send a datagram to any UDP port (and read the ports from ``/proc/net/udp``), so every datagram
is authenticated with a key only the user's own files hold:

- the **key**: 32 random bytes, as 64 hex digits in a file only its owner may read (mode 0600,
  in a folder only its owner may write), created on first use by whichever end starts first:
  ``key_file`` (scene) / ``--key-file`` (driver), else ``$GODOBJECT_LINK_KEY``, else
  ``~/.config/godobject/link.key`` (:mod:`godobject_drake.link.keys`). Two computers: copy
  the file to the other one;
- the **handshake**: the driver sends ``HELLO`` (its random session nonce and a fresh
  challenge), the scene answers ``WELCOME`` (its own session nonce, the driver's, the
  challenge), both tagged with a key derived from the shared one; a ``WELCOME`` that does not
  answer the driver's current challenge (an old scene's, replayed) is refused;
- every **message** is then ``DATA``: both session nonces, a counter that only grows, the
  channel and the LCM message, tagged HMAC-SHA256 with a key derived from the shared key and
  both nonces, one key per direction. A message of another session (an earlier scene, a
  replay across runs), an old counter (a replay within the run, from any address), or a tag
  that does not verify is dropped and counted, before any handler sees it. A scene's paired
  driver is where its newest message came from: a newer one from another address moves the
  scene's answers there (only the driver makes new ones), so a replay that arrived first cannot
  hold the scene; the driver hears its scene's address alone;
- a scene **takes one driver at a time**: the first whose ``DATA`` verifies (a driver sends an
  empty one on ``GODOBJECT_LINK`` as soon as it is welcomed). While that driver is heard,
  another with the key is refused (its ``HELLO`` answered ``REFUSED``, its messages dropped);
  once the paired one has been silent :data:`DRIVER_SILENT_S` (crashed, killed, restarted: a new
  process is a new session), the next driver's ``HELLO`` is welcomed and its first ``DATA``
  pairs the scene again (a new driver renders from zero, its rated-rate ramp from there). The
  same ``HELLO`` is answered at most every :data:`HELLO_ANSWER_S` (a replayed flood gets few
  answers, the rest counted ``udp_replayed``), and a second driver is counted in
  ``udp_refused_drivers`` and logged only once it is shown to run: its ``DATA`` of this scene,
  or a ``HELLO`` with a new challenge after its ``REFUSED`` (one replayed ``HELLO`` can do
  neither). Each end says once why it drops what it does (another key, another session, an old
  message from elsewhere, a second driver), with the fix. A driver sends nothing but ``HELLO``
  until it is paired, so nothing reaches its device before.

Wire format (big-endian), each datagram at most :data:`MAX_DATAGRAM` bytes::

    "GOD1" | kind (1 byte) | body | tag: HMAC-SHA256 over everything before it (32 bytes)
    HELLO    H: driver nonce (16) | challenge (16)                       tag key: K_hello
    WELCOME  W: scene nonce (16) | driver nonce (16) | challenge (16)    tag key: K_hello
    REFUSED  R: scene nonce (16) | driver nonce (16) | challenge (16)    tag key: K_hello
    DATA  D, S: scene nonce (16) | driver nonce (16) | counter (8) | channel | NUL | payload
                D from the driver, S from the scene; tag key: K_data(kind, scene nonce, driver nonce)

    K_hello = HMAC-SHA256(K, "godobject link hello")
    K_data  = HMAC-SHA256(K, "godobject link data" | kind | scene nonce | driver nonce)

What it does not do: it does not encrypt (whoever can capture the packets, root on either
machine or on the wire between them, can read the poses and forces, though never forge or
replay them). **A flood**: the driver's socket is connected to the scene's address, so the
kernel drops every other sender's datagram before it is queued, and a flood from another
process (which cannot send from the scene's port while the scene holds it) neither costs the
driver's loop nor crowds the scene's messages out of its buffer. Whatever does reach a socket
(the scene's listening one takes any sender, as a driver must be able to find it) is read at
most :data:`MAX_PER_POLL` datagrams and :data:`MAX_POLL_S` a poll, the rest left for the next
(counted ``udp_flooded``), so neither end's loop is held; such a flood can still starve the
scene's end of its driver's messages, which the driver's watchdog turns into zero force.

URLs (``--lcm-url`` / ``device.url`` on the scene; ``--scene`` on the driver):

- ``udp://HOST:PORT`` on the scene: listen on HOST:PORT; the feedback goes to the paired driver;
- the driver binds an ephemeral port on its own address towards the scene (127.0.0.1 on one
  machine), connected to the scene's address: it sends there, and the kernel gives it datagrams
  from that address only.

Use ``127.0.0.1`` on one machine: nothing leaves the host (tests use nothing else).
:class:`UdpLcm` has the part of ``DrakeLcm``'s interface the devices use (``Subscribe``,
``HandleSubscriptions``, ``Publish``, ``get_lcm_url``); Drake's ``LcmPublisherSystem`` needs a
C++ ``DrakeLcmInterface``, which Python cannot subclass in pydrake 1.51, so the feedback on
this transport is published by :class:`~godobject_drake.devices.lcm.ForceTorquePublisher`.
"""

from __future__ import annotations

import errno
import hashlib
import hmac
import math
import secrets
import socket
import struct
import threading
import time
import urllib.parse
from collections.abc import Callable
from pathlib import Path

from pydrake.lcm import DrakeLcm

from godobject_drake.link.keys import KEY_BYTES, key_fingerprint, load_key
from godobject_drake.link.logs import log


def make_lcm(url: str = "", key_file: str | Path = ""):
    """Drake's LCM on ``url`` (empty: Drake's default, ``udpm://`` multicast); ``udp://HOST:PORT``:
    a paired point-to-point link to a driver process, listened on (:class:`UdpLcm`, its key from
    ``key_file``: :func:`~godobject_drake.link.keys.key_path`): the scene's side."""
    if is_udp_url(url):
        return UdpLcm.listen(url, key_file)
    return DrakeLcm(url) if url else DrakeLcm()


def driver_lcm(url: str = "", key_file: str | Path = ""):
    """The driver's side of :func:`make_lcm`: ``udp://HOST:PORT`` is the scene's address, sent to
    from an ephemeral port of the same host (:meth:`UdpLcm.connect`); any other URL is Drake's LCM."""
    if is_udp_url(url):
        return UdpLcm.connect(url, key_file)
    return DrakeLcm(url) if url else DrakeLcm()


SCHEME = "udp"


def parse_url(url: str) -> tuple[str, int]:
    """``udp://HOST:PORT`` → ``(HOST, PORT)``; anything else refused naming the form."""
    parts = urllib.parse.urlsplit(url)
    try:
        port = parts.port
    except ValueError:
        port = None
    if parts.scheme != SCHEME or not parts.hostname or port is None:
        raise ValueError(
            f"LCM URL {url!r}: a driver link is udp://HOST:PORT, e.g. udp://127.0.0.1:7667 "
            "(127.0.0.1 keeps every datagram on this machine)"
        )
    return parts.hostname, port


def is_udp_url(url: str) -> bool:
    return url.startswith(SCHEME + "://")


# -- the datagrams ---------------------------------------------------------------------------------------

MAGIC = b"GOD1"
HELLO, WELCOME, REFUSED, DRIVER_DATA, SCENE_DATA = b"H", b"W", b"R", b"D", b"S"
NONCE_BYTES = 16
TAG_BYTES = 32
COUNTER = struct.Struct(">Q")
HEAD = len(MAGIC) + 1
DATA_HEAD = HEAD + 2 * NONCE_BYTES + COUNTER.size
MAX_DATAGRAM = 8192  # bytes: a driver's messages take ~300; a longer datagram is dropped unread
RECV_BYTES = MAX_DATAGRAM + 1  # read one byte more: a longer datagram shows as too long
MAX_PER_POLL = 256  # datagrams handled per poll: a flood cannot hold either end in one poll
# a poll's reading stops after this long too (s): a quarter of a 1 kHz period, whatever a datagram costs
MAX_POLL_S = 0.25e-3
HELLO_INTERVAL_S = 0.1  # a driver without a scene says HELLO this often
SILENT_S = 0.5  # a paired driver that heard nothing this long says HELLO again (a scene restarted)
MAX_REFUSED = 64  # second drivers (a scene) or scenes (a driver) remembered and logged
# a scene takes a new driver (a restarted one: the same key, a new session) once its paired driver has
# been silent this long (s): twice the driver's SILENT_S, after which a live driver says HELLO again,
# and a thousand of its periods, so a driver that still runs is never replaced
DRIVER_SILENT_S = 1.0
# a scene answers one HELLO (the same nonce and challenge) at most once this often (s): a driver repeats
# its HELLO every HELLO_INTERVAL_S, so each live one is answered; a replayed flood gets 20 answers a second
HELLO_ANSWER_S = HELLO_INTERVAL_S / 2
LINK_CHANNEL = "GODOBJECT_LINK"  # a driver's first DATA (empty): the scene pairs with its sender

# What each end of a link counts (UdpLcm.counts; a scene's metrics have them as lcm_<key>).
LINK_COUNT_KEYS = (
    "udp_received",  # datagrams read: each is counted once more below, as taken, a handshake, or dropped
    "udp_taken",  # messages handed on (DATA, authentic, of this session, newer than the last)
    "udp_handshakes",  # HELLO answered WELCOME (a scene), WELCOME taken (a driver)
    "udp_malformed",  # not a datagram of this link, or of a kind this end does not take
    "udp_unauthenticated",  # the tag did not verify: another key, altered, forged
    "udp_stale",  # authentic but of another session: an earlier scene's, an answer to an old HELLO
    "udp_replayed",  # authentic, this session, its counter not above the last; a HELLO answered just before
    "udp_foreign",  # a driver: from another address than the scene's; a scene: an old message from elsewhere
    "udp_refused",  # a scene: messages of a second driver; a driver: REFUSED answers
    "udp_refused_drivers",  # a scene: second drivers refused
    "udp_pairings",  # sessions paired
    "udp_unpaired",  # messages not sent: no end paired yet
    "udp_flooded",  # polls that stopped at MAX_PER_POLL datagrams or after MAX_POLL_S, the rest left waiting
    "udp_sent",
    "udp_send_errors",
)
# The counts of datagrams dropped by an end's checks (a driver reports their sum as link_rejected).
LINK_REJECTED = ("udp_malformed", "udp_unauthenticated", "udp_stale", "udp_replayed", "udp_foreign")


def _derive(key: bytes, label: bytes) -> bytes:
    return hmac.digest(key, b"godobject link " + label, hashlib.sha256)


class _Tagger:
    """HMAC-SHA256 with one key, keyed once (a copy per message saves two compressions)."""

    def __init__(self, key: bytes):
        self._mac = hmac.new(key, digestmod=hashlib.sha256)

    def seal(self, data: bytes) -> bytes:
        mac = self._mac.copy()
        mac.update(data)
        return data + mac.digest()

    def verify(self, datagram: bytes) -> bool:
        mac = self._mac.copy()
        mac.update(datagram[:-TAG_BYTES])
        return hmac.compare_digest(mac.digest(), datagram[-TAG_BYTES:])


BODY_BYTES = {HELLO: 2 * NONCE_BYTES, WELCOME: 3 * NONCE_BYTES, REFUSED: 3 * NONCE_BYTES}


def split(datagram: bytes, kinds: tuple[bytes, ...]) -> bytes | None:
    """The kind of a datagram of this link if it is one of ``kinds`` (and, for a handshake, of
    its length), its tag not yet checked; None if not: too long, another magic or kind."""
    kind = datagram[4:HEAD]
    if len(datagram) > MAX_DATAGRAM or datagram[:4] != MAGIC or kind not in kinds:
        return None
    if kind in BODY_BYTES and len(datagram) != HEAD + BODY_BYTES[kind] + TAG_BYTES:
        return None
    return kind


def data_fields(datagram: bytes) -> tuple[tuple[bytes, bytes], int, tuple[str, bytes]] | None:
    """``((scene nonce, driver nonce), counter, (channel, payload))`` of a DATA datagram, or None
    if it has no NUL-terminated, non-empty UTF-8 channel name after its head."""
    end = datagram.find(b"\0", DATA_HEAD, len(datagram) - TAG_BYTES)
    if end <= DATA_HEAD:
        return None
    try:
        channel = datagram[DATA_HEAD:end].decode()
    except UnicodeDecodeError:
        return None
    nonces = datagram[HEAD : HEAD + NONCE_BYTES], datagram[HEAD + NONCE_BYTES : HEAD + 2 * NONCE_BYTES]
    (counter,) = COUNTER.unpack_from(datagram, HEAD + 2 * NONCE_BYTES)
    return nonces, counter, (channel, datagram[end + 1 : -TAG_BYTES])


class _End:
    """What both ends of a link keep: the key, this end's nonce, the session's keys, the
    counters (sent and last taken) and the counts."""

    SEND: bytes  # the kind of DATA this end sends
    TAKE: bytes  # the kind of DATA it takes
    _rx: _Tagger  # the session's key for what this end takes (set when paired)
    _taken: int  # the counter of the last DATA taken in this session (0 when paired)

    def __init__(self, key: bytes, nonce: bytes | None = None):
        if len(key) != KEY_BYTES:
            raise ValueError(f"a link key is {KEY_BYTES} bytes, not {len(key)}")
        self.key, self.nonce = key, nonce or secrets.token_bytes(NONCE_BYTES)
        self._hello = _Tagger(_derive(key, b"hello"))
        self.counts = dict.fromkeys(LINK_COUNT_KEYS, 0)
        self.session: tuple[bytes, bytes] | None = None  # (scene nonce, driver nonce) once paired
        self._tx: _Tagger | None = None
        self._sent = 0  # the counter of the last DATA sent: it only grows
        self._said_wrong_key = False

    def _unauthenticated(self, sender) -> None:
        """Count a datagram of this link's form whose tag does not verify; say why, once."""
        self.counts["udp_unauthenticated"] += 1
        if not self._said_wrong_key and sender is not None:
            self._said_wrong_key = True
            log.warning(
                f"a datagram with a wrong key arrived from port {sender[1]} ({sender[0]}): the two processes "
                "use different key files (give both the same --key-file / device.key_file; each names its "
                "key's fingerprint when it starts), or another process sent it (counted in "
                "udp_unauthenticated, said once)"
            )

    def data_key(self, kind: bytes, session: tuple[bytes, bytes]) -> _Tagger:
        return _Tagger(_derive(self.key, b"data" + kind + session[0] + session[1]))

    def _pair(self, session: tuple[bytes, bytes]) -> None:
        self.session, self._taken = session, 0
        self._tx, self._rx = self.data_key(self.SEND, session), self.data_key(self.TAKE, session)
        self.counts["udp_pairings"] += 1

    def seal(self, channel: str, payload: bytes) -> bytes | None:
        """A DATA datagram of this session, or None before pairing (counted ``udp_unpaired``)."""
        if self._tx is None:
            self.counts["udp_unpaired"] += 1
            return None
        self._sent += 1
        head = MAGIC + self.SEND + self.session[0] + self.session[1] + COUNTER.pack(self._sent)
        datagram = self._tx.seal(head + channel.encode() + b"\0" + payload)
        if len(datagram) > MAX_DATAGRAM:
            raise ValueError(
                f"an LCM message on {channel} of {len(payload)} bytes is over the link's "
                f"{MAX_DATAGRAM}-byte datagram: send fewer values per message"
            )
        return datagram

    def _verified(self, datagram: bytes, sender=None):
        """:func:`data_fields` of a DATA datagram whose tag verifies (for its session's key),
        or None (counted)."""
        fields = data_fields(datagram)
        if fields is None:
            self.counts["udp_malformed"] += 1
            return None
        session = fields[0]
        tagger = self._rx if session == self.session else self.data_key(self.TAKE, session)
        if not tagger.verify(datagram):
            self._unauthenticated(sender)
            return None
        return fields

    def _newer(self, counter: int, message: tuple[str, bytes]) -> tuple[str, bytes] | None:
        """The message of this session's DATA if its counter is above the last taken."""
        if counter <= self._taken:
            self.counts["udp_replayed"] += 1
            return None
        self._taken = counter
        self.counts["udp_taken"] += 1
        return message


class SceneEnd(_End):
    """The scene's checks (module docstring): answers HELLO, pairs with the first driver whose
    DATA verifies, refuses any other while that one is heard, moves to the address its newest
    DATA comes from. :meth:`receive` returns ``(message, reply)``: the ``(channel, payload)`` to
    hand to the subscribers and a datagram to send back to the sender."""

    SEND, TAKE = SCENE_DATA, DRIVER_DATA

    def __init__(self, key: bytes, nonce: bytes | None = None):
        super().__init__(key, nonce)
        self.peer: tuple | None = None  # the paired driver's address
        self.heard = -math.inf  # when the paired driver's newest DATA was taken
        self.refused: set[bytes] = set()
        self._asked: dict[bytes, bytes] = {}  # a refused HELLO's driver nonce: its challenge
        self._answered: dict[bytes, float] = {}  # a HELLO's nonce and challenge: when last answered
        self._said: set[str] = set()

    def _say_once(self, what: str, text: str) -> None:
        if what not in self._said:
            self._said.add(what)
            log.warning(text)

    def silent(self, now: float | None) -> bool:
        """Has the paired driver been silent :data:`DRIVER_SILENT_S` (never without a clock)?"""
        return self.session is not None and now is not None and now - self.heard > DRIVER_SILENT_S

    def receive(
        self, datagram: bytes, sender, now: float | None = None
    ) -> tuple[tuple[str, bytes] | None, bytes | None]:
        """``now``: the scene's clock (s); None: no clock (the paired driver is never silent and
        every HELLO is answered)."""
        kind = split(datagram, (HELLO, DRIVER_DATA))
        if kind is None:
            self.counts["udp_malformed"] += 1
            return None, None
        if kind == HELLO:
            return None, self._answer(datagram, sender, now)
        fields = self._verified(datagram, sender)
        if fields is None:
            return None, None
        session, counter, message = fields
        if session[0] != self.nonce:
            self.counts["udp_stale"] += 1
            self._say_once(
                "stale",
                f"a message of another session arrived from {sender[0]}:{sender[1]}: a driver still "
                "paired with an earlier scene; it finds this one by itself (it says HELLO after "
                f"{SILENT_S} s without its scene), or restart it (counted in udp_stale, said once)",
            )
            return None, None
        if self.session is None or (session != self.session and self.silent(now)):
            was = self.peer
            self._pair(session)
            self.peer, self.heard = sender, now if now is not None else -math.inf
            if was is None:
                log.info(f"paired with the driver at {sender[0]}:{sender[1]}")
            else:
                log.warning(
                    f"paired with a new driver at {sender[0]}:{sender[1]}: the driver at {was[0]}:{was[1]} "
                    f"had been silent over {DRIVER_SILENT_S} s (a driver restarted)"
                )
        elif session != self.session:
            self._refuse(session[1], sender)
            return None, None
        if counter <= self._taken and sender != self.peer:
            self.counts["udp_foreign"] += 1  # an old message from elsewhere: a replay
            self._say_once(
                "foreign",
                f"an old message of the paired driver arrived from {sender[0]}:{sender[1]}, not "
                f"{self.peer[0]}:{self.peer[1]}: a replay, dropped (counted in udp_foreign, said once)",
            )
            return None, None
        taken = self._newer(counter, message)
        if taken is not None:
            if sender != self.peer:  # newer than any taken: the driver's own, from where it is now
                log.info(f"the paired driver moved to {sender[0]}:{sender[1]}")
                self.peer = sender
            if now is not None:
                self.heard = now
        return taken, None

    def _refuse(self, driver_nonce: bytes, sender) -> None:
        """Count a second driver's message; log the driver once."""
        self.counts["udp_refused"] += 1
        self._refused_driver(driver_nonce, sender)

    def _refused_driver(self, driver_nonce: bytes, sender) -> None:
        if driver_nonce in self.refused or len(self.refused) >= MAX_REFUSED:
            return
        self.refused.add(driver_nonce)
        self.counts["udp_refused_drivers"] += 1
        log.warning(
            f"refused a second driver (at {sender[0]}:{sender[1]}): this scene is paired with the "
            f"driver at {self.peer[0]}:{self.peer[1]}, which still sends; stop one of them (a new "
            f"driver is taken once the paired one has been silent {DRIVER_SILENT_S} s) "
            "(lcm_udp_refused_drivers in the metrics)"
        )

    def _answer(self, datagram: bytes, sender, now: float | None) -> bytes | None:
        """WELCOME to a HELLO when no driver, this one, or any after a silence of the paired one;
        REFUSED to another driver. The same HELLO is answered at most every
        :data:`HELLO_ANSWER_S` (a replayed flood); a second driver is said to be there once it
        asks again with a new challenge (a replay of one HELLO cannot)."""
        if not self._hello.verify(datagram):
            self._unauthenticated(sender)
            return None
        asked = datagram[HEAD:-TAG_BYTES]  # the driver's nonce and challenge
        if now is not None:
            if now - self._answered.get(asked, -math.inf) < HELLO_ANSWER_S:
                self.counts["udp_replayed"] += 1
                return None
            if len(self._answered) >= MAX_REFUSED:
                self._answered = {a: t for a, t in self._answered.items() if now - t < HELLO_ANSWER_S}
            if len(self._answered) < MAX_REFUSED:
                self._answered[asked] = now
        nonce, challenge = asked[:NONCE_BYTES], asked[NONCE_BYTES:]
        if self.session is not None and nonce != self.session[1] and not self.silent(now):
            self.counts["udp_refused"] += 1
            first = self._asked.get(nonce)
            if first is None and len(self._asked) < MAX_REFUSED:
                self._asked[nonce] = challenge
            elif first is not None and first != challenge:  # asked again after a REFUSED: it runs
                self._refused_driver(nonce, sender)
            return self._hello.seal(MAGIC + REFUSED + self.nonce + asked)
        self.counts["udp_handshakes"] += 1
        return self._hello.seal(MAGIC + WELCOME + self.nonce + asked)


class DriverEnd(_End):
    """The driver's checks (module docstring): HELLO until a scene answers this challenge,
    DATA only from that scene's session, nothing from another address."""

    SEND, TAKE = DRIVER_DATA, SCENE_DATA

    def __init__(self, key: bytes, peer, nonce: bytes | None = None):
        super().__init__(key, nonce)
        self.peer = peer  # the scene's address: the only one heard
        self.challenge: bytes | None = None
        self.answered = True  # the current challenge was answered: the next search asks a new one
        self.heard = -math.inf  # when the scene was last heard (authentic, this session)
        self._said_hello = -math.inf
        self._said_stale = False
        self.refused_by: set[bytes] = set()

    def hello(self, now: float) -> bytes | None:
        """A HELLO to send now, or None: paired and heard within :data:`SILENT_S`, or one sent
        less than :data:`HELLO_INTERVAL_S` ago. Each search (the first, or after a silence)
        asks with a new challenge, so no answer to an earlier one can pair the driver."""
        if self.session is not None and now - self.heard <= SILENT_S:
            return None
        if now - self._said_hello < HELLO_INTERVAL_S:
            return None
        if self.answered:
            self.challenge, self.answered = secrets.token_bytes(NONCE_BYTES), False
        self._said_hello = now
        return self._hello.seal(MAGIC + HELLO + self.nonce + self.challenge)

    def receive(self, datagram: bytes, sender, now: float) -> tuple[tuple[str, bytes] | None, bytes | None]:
        """``(message, reply)`` as :meth:`SceneEnd.receive`; the reply to a WELCOME that pairs
        the driver is its first DATA (on :data:`LINK_CHANNEL`), which pairs the scene."""
        if sender != self.peer:
            self.counts["udp_foreign"] += 1
            return None, None
        kind = split(datagram, (WELCOME, REFUSED, SCENE_DATA))
        if kind is None:
            self.counts["udp_malformed"] += 1
            return None, None
        if kind == SCENE_DATA:
            return self._scene_data(datagram, sender, now), None
        if not self._hello.verify(datagram):
            self._unauthenticated(sender)
            return None, None
        scene_nonce = datagram[HEAD : HEAD + NONCE_BYTES]
        if self.challenge is None or datagram[HEAD + NONCE_BYTES : -TAG_BYTES] != self.nonce + self.challenge:
            self.counts["udp_stale"] += 1
            return None, None
        if kind == REFUSED:
            self._refused(scene_nonce)
            return None, None
        self.counts["udp_handshakes"] += 1
        self.heard, self.answered = now, True
        if self.session == (scene_nonce, self.nonce):
            return None, None
        self._pair((scene_nonce, self.nonce))
        log.info(f"paired with the scene at {self.peer[0]}:{self.peer[1]}")
        return None, self.seal(LINK_CHANNEL, b"")

    def _scene_data(self, datagram: bytes, sender, now: float) -> tuple[str, bytes] | None:
        fields = self._verified(datagram, sender)
        if fields is None:
            return None
        session, counter, message = fields
        if session != self.session:
            self.counts["udp_stale"] += 1
            if not self._said_stale:
                self._said_stale = True
                log.warning(
                    f"a message of another session arrived from the scene at {self.peer[0]}:{self.peer[1]}: "
                    "an earlier scene's (it restarted), or one that has not paired this driver; dropped, "
                    "nothing rendered from it; this driver pairs with the scene that answers its HELLO "
                    "(counted in udp_stale, said once)"
                )
            return None
        message = self._newer(counter, message)
        if message is not None:
            self.heard = now
        return message

    def _refused(self, scene_nonce: bytes) -> None:
        self.counts["udp_refused"] += 1
        self.answered = True  # the next HELLO asks a new challenge: the scene sees a live driver
        if scene_nonce in self.refused_by or len(self.refused_by) >= MAX_REFUSED:
            return
        self.refused_by.add(scene_nonce)
        log.warning(
            f"the scene at {self.peer[0]}:{self.peer[1]} refused this driver: it is paired with "
            "another driver, which still sends; nothing is rendered (stop the other driver: this "
            f"one is taken once that one has been silent {DRIVER_SILENT_S} s)"
        )


class UdpLcm:
    """LCM messages over one UDP socket, paired and authenticated (module docstring).

    Parameters
    ----------
    bind : (host, port)
        Where to listen; port 0 picks a free one (a driver).
    peer : (host, port) or None
        The scene's address (a driver: the only one heard, where everything is sent); None: a
        scene, answering the paired driver.
    key : bytes
        The shared key (:func:`~godobject_drake.link.keys.load_key`).
    clock : callable
        Seconds (``time.monotonic``): when a driver says HELLO; a scene's silence and HELLO rules.
    """

    def __init__(
        self,
        bind: tuple[str, int],
        peer: tuple[str, int] | None = None,
        url: str = "",
        *,
        key: bytes,
        clock: Callable[[], float] = time.monotonic,
    ):
        self.end = SceneEnd(key) if peer is None else DriverEnd(key, peer)
        self.clock = clock
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 20)
        try:
            self.sock.bind(bind)
        except OSError as e:
            self.sock.close()
            raise ValueError(
                f"LCM URL {url or bind}: cannot listen on {bind[0]}:{bind[1]} ({e.strerror}); "
                "another scene or driver may hold the port: choose another PORT"
            ) from None
        if peer is not None:
            # a driver hears its scene only: connected, the socket takes datagrams from the scene's
            # address and port alone, and the kernel drops any other sender's before they are
            # queued, so a flood from another process costs the driver's loop nothing (a process
            # cannot send from the scene's port while the scene holds it)
            try:
                self.sock.connect(peer)
            except OSError as e:
                self.sock.close()
                raise ValueError(
                    f"LCM URL {url or peer}: cannot reach {peer[0]}:{peer[1]} ({e.strerror}): give the "
                    "scene's address as this machine reaches it"
                ) from None
        self.sock.setblocking(False)
        self.poll_budget_s = MAX_POLL_S  # how long a poll may read (tests that count a whole poll: inf)
        self.url = f"{SCHEME}://{bind[0]}:{self.port}"  # where it listens (the port picked, if 0)
        self._handlers: dict[str, list[Callable[[bytes], None]]] = {}
        self.key_file: Path | None = None
        # a scene's heartbeat thread publishes beside its main loop: sealing (the session's
        # counter) and sending are one step under this lock, so datagrams leave in counter order
        self._lock = threading.Lock()

    @staticmethod
    def _address(url: str) -> tuple[str, int]:
        host, port = parse_url(url)
        try:
            return socket.gethostbyname(host), port
        except OSError as e:
            raise ValueError(f"LCM URL {url!r}: no address for {host!r} ({e}); give an IP address") from None

    @classmethod
    def listen(cls, url: str, key_file: str | Path = "", **options) -> UdpLcm:
        """The scene's end: listen on the URL's address, answer the paired driver."""
        key, path = load_key(key_file)
        link = cls(cls._address(url), None, url, key=key, **options)
        link.key_file = path
        log.info(f"{link.url}: waiting for a driver with the key {path} (fingerprint {key_fingerprint(key)})")
        return link

    @staticmethod
    def _local_address_towards(scene: tuple[str, int]) -> str:
        """This machine's address that reaches ``scene`` (the scene's own on one machine; the
        interface towards it on a second): a UDP socket's connect picks the route, sends nothing."""
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
            try:
                probe.connect(scene)
            except OSError as e:
                raise ValueError(
                    f"no route from this machine to {scene[0]}:{scene[1]} ({e.strerror}): give the "
                    "scene's address as this machine reaches it"
                ) from None
            return probe.getsockname()[0]

    @classmethod
    def connect(cls, url: str, key_file: str | Path = "", **options) -> UdpLcm:
        """The driver's end: a free port on this machine's address towards the scene, sending to
        (and hearing only) the URL's address."""
        key, path = load_key(key_file)
        scene = cls._address(url)
        link = cls((cls._local_address_towards(scene), 0), scene, key=key, **options)
        link.key_file = path
        return link

    @property
    def counts(self) -> dict:
        return self.end.counts

    @property
    def paired(self) -> bool:
        return self.end.session is not None

    @property
    def port(self) -> int:
        return self.sock.getsockname()[1]

    def get_lcm_url(self) -> str:
        return self.url

    def Subscribe(self, channel: str, handler: Callable[[bytes], None]) -> None:
        self._handlers.setdefault(channel, []).append(handler)

    def Publish(self, channel: str, buffer: bytes, time_sec=None) -> None:
        with self._lock:
            datagram = self.end.seal(channel, bytes(buffer))
            if datagram is not None:
                self._send(datagram, self.end.peer)

    def _send(self, datagram: bytes, address) -> None:
        try:
            self.sock.sendto(datagram, address)
            self.counts["udp_sent"] += 1
        except OSError as e:  # no listener (ECONNREFUSED), a full buffer: the message is lost
            if e.errno not in (errno.ECONNREFUSED, errno.EAGAIN, errno.ENOBUFS, errno.EHOSTUNREACH):
                raise
            self.counts["udp_send_errors"] += 1

    def HandleSubscriptions(self, timeout_millis: int) -> int:
        """Hand every authentic message waiting (at most :data:`MAX_PER_POLL` datagrams, read for
        at most :attr:`poll_budget_s` after the first) to its channel's handlers; waits up to
        ``timeout_millis`` for the first only if none is waiting. What is left waits for the next
        poll (the poll is counted ``udp_flooded``). A driver says HELLO first when it has to.
        Returns how many were handled."""
        if isinstance(self.end, DriverEnd):
            with self._lock:
                hello = self.end.hello(self.clock())
                if hello is not None:
                    self._send(hello, self.end.peer)
        handled = 0
        self.sock.settimeout(max(timeout_millis, 0) * 1e-3)  # 0: do not wait
        read_until = math.inf
        try:
            for _ in range(MAX_PER_POLL):
                if time.perf_counter() > read_until:
                    if self._waiting():
                        self.counts["udp_flooded"] += 1
                    break
                try:
                    datagram, sender = self.sock.recvfrom(RECV_BYTES)
                except (BlockingIOError, TimeoutError, ConnectionRefusedError):
                    break
                finally:
                    self.sock.setblocking(False)
                if read_until == math.inf:  # the budget runs from the first datagram, not the wait
                    read_until = time.perf_counter() + self.poll_budget_s
                with self._lock:
                    self.counts["udp_received"] += 1
                    message, reply = self.end.receive(datagram, sender, self.clock())
                    if reply is not None:
                        self._send(reply, sender)
                if message is None:
                    continue
                for handler in self._handlers.get(message[0], ()):
                    handler(message[1])
                    handled += 1
            else:
                self.counts["udp_flooded"] += 1
        finally:
            self.sock.setblocking(False)
        return handled

    def _waiting(self) -> bool:
        """Is a datagram waiting (looked at, not read)?"""
        try:
            self.sock.recv(1, socket.MSG_PEEK | socket.MSG_DONTWAIT)
        except OSError:  # none (EAGAIN), or an ICMP error queued (ECONNREFUSED)
            return False
        return True

    def close(self) -> None:
        self.sock.close()
