"""The link between a scene and a device's driver: channels, messages, and the transport.

What the scene's LCM devices (:mod:`godobject_drake.devices.lcm`) and a driver process
(:mod:`godobject_drake.driver.process`) share, and nothing else: the channel names, the packing of a pose
sample, a driver's counts and the parsing of a pose message (Drake's ``lcmt_*`` types, which the
drake wheel ships without ``pydrake.systems``), and the unicast UDP transport below. The message
formats are in :mod:`godobject_drake.devices.lcm`'s docstring and docs/haptic_devices.md.

**Transport: LCM messages over unicast UDP**, the scene and a device driver in separate processes.

Drake's LCM (``DrakeLcm``) speaks multicast (``udpm://``) between processes, which a lab's
network or a locked-down machine may not carry, and ``memq://`` stays in one process. A driver
and a scene on one machine (or two, over a cable) need only a point-to-point link, so this is
one: each datagram is one LCM message in LCM's own small-message packet format (the
``LC02`` magic, a sequence number, the channel name NUL-terminated, then the message's
``encode()`` bytes), sent to one address. The message types are Drake's (``lcmt_robot_state``
for poses, ``lcmt_force_torque`` for the wrench), so nothing about the messages changes, only
how they travel.

Why datagrams and not a stream (TCP, a Unix stream socket): a haptic loop wants the newest
sample, never a queue of old ones behind a stalled reader; a datagram is a whole message or
nothing (no framing to resynchronise after a crash); there is no connection to set up or tear
down, so a killed scene leaves the driver nothing to clean up (it simply stops hearing
feedback, which its watchdog turns into zero force), and a restarted scene is heard at once.
UDP rather than a Unix datagram socket: the same code reaches another machine when the device
hangs off a separate real-time computer, and no socket file is left behind.

URLs (``--lcm-url`` / ``device.url`` on the scene; ``--scene`` on the driver):

- ``udp://HOST:PORT`` on the scene: listen on HOST:PORT; the feedback goes back to whoever sent
  the newest datagram (the driver), so one address configures both directions.
- the driver binds an ephemeral port on the same host and sends to the scene's address.

Use ``127.0.0.1`` on one machine: nothing leaves the host (tests use nothing else).
:class:`UdpLcm` has the part of ``DrakeLcm``'s interface the devices use (``Subscribe``,
``HandleSubscriptions``, ``Publish``, ``get_lcm_url``); Drake's ``LcmPublisherSystem`` needs a
C++ ``DrakeLcmInterface``, which Python cannot subclass in pydrake 1.51, so the feedback on
this transport is published by :class:`~godobject_drake.devices.lcm.ForceTorquePublisher`.
"""

from __future__ import annotations

import errno
import socket
import struct
import urllib.parse
from collections.abc import Callable

from drake import lcmt_robot_state
from pydrake.lcm import DrakeLcm

POSE_CHANNEL = "GODOBJECT_DEVICE_POSE"


JOINT_CHANNEL = "GODOBJECT_DEVICE_JOINTS"


FEEDBACK_CHANNEL = "GODOBJECT_FEEDBACK"


DRIVER_STATUS_CHANNEL = "GODOBJECT_DRIVER_STATUS"


STOP_SUFFIX = "_STOP"


POSE_NAMES = ("x", "y", "z", "qw", "qx", "qy", "qz")


# What a driver counts (godobject_drake.driver.process), in the metrics as driver_<key>.
DRIVER_STATUS_KEYS = (
    "loops",  # device periods run
    "overruns",  # periods that started more than one period late
    "watchdog_trips",  # feedback went silent for the watchdog time: force zeroed
    "scene_stops",  # the scene said it stopped: force zeroed
    "force_clamps",  # device periods with the force cut to the device's rated maximum
    "rate_clamps",  # device periods with the force's change cut to the rated rate
    "buzz_events",  # feedback oscillating near the device's Nyquist rate: damped
    "bad_feedback",  # feedback messages that did not decode or were not finite
)


GRASP_PREFIX = "grasp="


LCM_STATUS_KEYS = (
    "lcm_messages",
    "lcm_bad_messages",
    "lcm_stale_messages",
    "lcm_bursts",
    "lcm_silent_samples",
)


def make_lcm(url: str = ""):
    """Drake's LCM on ``url`` (empty: Drake's default, ``udpm://`` multicast); ``udp://HOST:PORT``:
    a point-to-point link to a driver process, listened on (:class:`UdpLcm`): the scene's side."""
    if is_udp_url(url):
        return UdpLcm.listen(url)
    return DrakeLcm(url) if url else DrakeLcm()


def driver_lcm(url: str = ""):
    """The driver's side of :func:`make_lcm`: ``udp://HOST:PORT`` is the scene's address, sent to
    from an ephemeral port of the same host (:meth:`UdpLcm.connect`); any other URL is Drake's LCM."""
    if is_udp_url(url):
        return UdpLcm.connect(url)
    return DrakeLcm(url) if url else DrakeLcm()


def parse_robot_state(raw: bytes, names) -> tuple[int, list[str], list[float], str | None] | None:
    """An ``lcmt_robot_state`` pose or joint sample: ``(utime, names, values, grasp)`` with the
    ``grasp=`` entry taken out (``grasp`` None when the message has none), or None when ``raw`` is
    not one (another type, a truncated message, lengths that disagree)."""
    try:
        msg = lcmt_robot_state.decode(raw)
    except ValueError:  # another type, or a truncated message
        return None
    names, values = list(msg.joint_name), list(msg.joint_position)
    if len(names) != msg.num_joints or len(values) != msg.num_joints:
        return None
    grasp = None
    for i, name in enumerate(names):
        if name.startswith(GRASP_PREFIX):
            grasp = name[len(GRASP_PREFIX) :]
            del names[i], values[i]
            break
    return int(msg.utime), names, values, grasp


def status_message(utime: int, counts: dict) -> lcmt_robot_state:
    """A driver's counts as an ``lcmt_robot_state`` (names :data:`DRIVER_STATUS_KEYS`)."""
    msg = lcmt_robot_state()
    msg.utime = int(utime)
    msg.num_joints = len(DRIVER_STATUS_KEYS)
    msg.joint_name = list(DRIVER_STATUS_KEYS)
    msg.joint_position = [float(counts.get(k, 0)) for k in DRIVER_STATUS_KEYS]
    return msg


def pose_message(utime: int, p, q, grasp: str | None = None) -> lcmt_robot_state:
    """An ``lcmt_robot_state`` pose sample, as a driver publishes it."""
    msg = lcmt_robot_state()
    msg.utime = int(utime)
    names, values = list(POSE_NAMES), [*map(float, p), *map(float, q)]
    if grasp is not None:
        names.append(GRASP_PREFIX + grasp)
        values.append(0.0)
    msg.num_joints, msg.joint_name, msg.joint_position = len(names), names, values
    return msg


SCHEME = "udp"
MAGIC = 0x4C433032  # "LC02": LCM's short-message packet
HEADER = struct.Struct(">II")
MAX_DATAGRAM = 65507


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


def pack(channel: str, payload: bytes, seqno: int) -> bytes:
    """One LCM short-message packet."""
    return HEADER.pack(MAGIC, seqno & 0xFFFFFFFF) + channel.encode() + b"\0" + payload


def unpack(datagram: bytes) -> tuple[str, bytes] | None:
    """``(channel, payload)`` of a packet, or None if it is not one."""
    if len(datagram) < HEADER.size + 1:
        return None
    magic, _ = HEADER.unpack_from(datagram)
    end = datagram.find(b"\0", HEADER.size)
    if magic != MAGIC or end < 0:
        return None
    try:
        channel = datagram[HEADER.size : end].decode()
    except UnicodeDecodeError:
        return None
    return channel, datagram[end + 1 :]


class UdpLcm:
    """LCM packets over one UDP socket (module docstring).

    Parameters
    ----------
    bind : (host, port)
        Where to listen; port 0 picks a free one (a driver).
    peer : (host, port) or None
        Where :meth:`Publish` sends; None: back to the sender of the newest datagram (a scene).
    """

    def __init__(self, bind: tuple[str, int], peer: tuple[str, int] | None = None, url: str = ""):
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
        self.sock.setblocking(False)
        self.peer, self._fixed_peer = peer, peer is not None
        self.url = url or f"{SCHEME}://{bind[0]}:{self.sock.getsockname()[1]}"
        self._handlers: dict[str, list[Callable[[bytes], None]]] = {}
        self._seqno = 0
        self.counts = {"udp_received": 0, "udp_malformed": 0, "udp_sent": 0, "udp_send_errors": 0}

    @classmethod
    def listen(cls, url: str) -> UdpLcm:
        """The scene's end: listen on the URL's address, answer whoever sent last."""
        return cls(parse_url(url), None, url)

    @classmethod
    def connect(cls, url: str) -> UdpLcm:
        """The driver's end: a free port on the scene's host, sending to the URL's address."""
        host, port = parse_url(url)
        return cls((host, 0), (host, port))

    @property
    def port(self) -> int:
        return self.sock.getsockname()[1]

    def get_lcm_url(self) -> str:
        return self.url

    def Subscribe(self, channel: str, handler: Callable[[bytes], None]) -> None:
        self._handlers.setdefault(channel, []).append(handler)

    def Publish(self, channel: str, buffer: bytes, time_sec=None) -> None:
        if self.peer is None:
            return  # nobody has spoken yet: nobody to answer
        self._seqno += 1
        try:
            self.sock.sendto(pack(channel, bytes(buffer), self._seqno), self.peer)
            self.counts["udp_sent"] += 1
        except OSError as e:  # no listener (ECONNREFUSED), a full buffer: the message is lost
            if e.errno not in (errno.ECONNREFUSED, errno.EAGAIN, errno.ENOBUFS, errno.EHOSTUNREACH):
                raise
            self.counts["udp_send_errors"] += 1

    def HandleSubscriptions(self, timeout_millis: int = 0) -> int:
        """Hand every datagram waiting to its channel's handlers; waits up to ``timeout_millis``
        for the first only if none is waiting. Returns how many messages were handled."""
        handled = 0
        if timeout_millis > 0:
            self.sock.settimeout(timeout_millis / 1000.0)
        try:
            while True:
                try:
                    datagram, sender = self.sock.recvfrom(MAX_DATAGRAM)
                except (BlockingIOError, TimeoutError, ConnectionRefusedError):
                    break
                finally:
                    self.sock.setblocking(False)
                self.counts["udp_received"] += 1
                message = unpack(datagram)
                if message is None:
                    self.counts["udp_malformed"] += 1
                    continue
                if not self._fixed_peer:
                    self.peer = sender
                for handler in self._handlers.get(message[0], ()):
                    handler(message[1])
                    handled += 1
        finally:
            self.sock.setblocking(False)
        return handled

    def close(self) -> None:
        self.sock.close()
