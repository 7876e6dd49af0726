"""Which vehicle a MAVLink link is read from, and how its frames are authenticated: ``LinkSettings``.

Vehicle selection. A link carries more than the vehicle: a ground station's HEARTBEATs, a
companion computer, a gimbal, a second vehicle, or anyone who can reach the port. By default
the decoder waits for the first HEARTBEAT of an autopilot (a vehicle ``MAV_TYPE``, ``autopilot``
not ``MAV_AUTOPILOT_INVALID``, not from a gimbal component: pymavlink's own
``probably_vehicle_heartbeat`` rule, with every peripheral type excluded) and takes data from
that (system, component) only; everyone else's data is counted as ``other_sender``, and data
that arrives before any autopilot is heard as ``no_vehicle_yet``.

Signing (MAVLink 2 message signing, MAVLink developer guide "Message Signing"). With a key,
only frames whose signature verifies are used; pymavlink's ``MAVLink.signing`` does the
cryptography (SHA-256 over key, header, payload, CRC, link id and timestamp, first 48 bits).
The key file holds either the raw secret key, exactly 32 bytes, or a passphrase (UTF-8 text,
surrounding whitespace and the final newline removed) whose SHA-256 digest is the key, as
MAVProxy's ``signing setup PASSPHRASE`` and Mission Planner derive it. A file of 32 bytes is the
raw key unless it is one line of text: UTF-8 that ends in a newline and holds no other control
character than tabs and a carriage return. So a 31-character passphrase written by ``echo`` or an
editor (32 bytes with its newline) is a passphrase, and a random key is taken as text only if it
ends in 0x0a and its other bytes make printable UTF-8 (fewer than one key in 10^12). A passphrase of
exactly 32 characters must end in a newline, or it is read as the raw key.
"""

from __future__ import annotations

import hashlib
import importlib.util
import ipaddress
import math
import os
import re
from dataclasses import dataclass, fields
from typing import Any, Mapping

from .base import SourceError

__all__ = ["LinkSettings", "SIGNING_KEY_BYTES", "check_connection"]

SIGNING_KEY_BYTES = 32
"""Length of a MAVLink 2 secret key (the SETUP_SIGNING message's ``secret_key``)."""
MAX_KEY_FILE_BYTES = 4096
"""The largest signing key file: a 32-byte key or a passphrase of a line or a few."""
MAX_REQUEST_RATE_HZ = 1000.0
"""The fastest rate ``request_rate_hz`` may ask for (an IMU's; a MAVLink message interval is in whole microseconds)."""
MIN_REQUEST_RATE_HZ = 0.1
"""The slowest: an IMU every ten seconds carries no attitude (and the interval, a float32 of microseconds, stays finite:
1e-300 Hz asked the vehicle for an infinite one)."""
_DIALECT_NAME = re.compile(r"[A-Za-z0-9_]+")
_CONTROL = re.compile(rb"[\x00-\x08\x0b\x0c\x0e-\x1f\x7f]")
"""Control characters other than a tab, a newline and a carriage return: not in a line of text."""


_NETWORK_PREFIXES = ("tcp", "tcpin", "udpin", "udpout", "udpbcast", "udp")


def check_connection(text: str) -> str:
    """``text`` if it has the form of a connection string pymavlink opens (a link in, or ``--mavlink-out``), else
    ``ValueError`` saying what is expected; whether it opens is not tried."""
    prefix, _, rest = text.partition(":")
    if prefix in _NETWORK_PREFIXES or re.fullmatch(r"[\w.-]+:\d+", text):
        host, _, port = (rest if prefix in _NETWORK_PREFIXES else text).rpartition(":")
        if not host or not port.isdigit() or int(port) > 65535:
            raise ValueError(f"{text!r} is not a network connection: expected {prefix}:HOST:PORT with a port 0-65535, "
                             "e.g. udpin:0.0.0.0:14550")
        if re.fullmatch(r"[\d.]+", host):
            try:
                ipaddress.IPv4Address(host)
            except ValueError:
                raise ValueError(f"{text!r}: {host} is not an IPv4 address") from None
        return text
    if text.startswith(("mcast:", "uds:", "unix:", "ws:", "wss:", "wsserver:", "/dev/")) or re.fullmatch(r"COM\d+", text, re.I):
        return text
    if os.path.exists(text):  # a serial device elsewhere, or a .tlog to read
        return text
    raise ValueError(f"{text!r} is not a MAVLink connection: give udpin:HOST:PORT (listen), udpout:HOST:PORT, tcp:HOST:PORT, "
                     "tcpin:HOST:PORT, or a serial device such as /dev/ttyUSB0 or COM3")


def _is_text_line(data: bytes) -> bool:
    """Whether ``data`` is one line of text: UTF-8 ending in a newline, without other control characters."""
    if not data.endswith(b"\n") or _CONTROL.search(data) or b"\n" in data[:-1]:
        return False
    try:
        data.decode("utf-8")
    except UnicodeDecodeError:
        return False
    return True


def _check_id(key: str, value: Any) -> None:
    if value is not None and (type(value) is not int or not 1 <= value <= 255):
        raise ValueError(f"link.{key}: a MAVLink id from 1 to 255 (or unset), got {value!r}")


@dataclass(frozen=True)
class LinkSettings:
    """The vehicle a MAVLink link is read from, its signing key and its dialect (validated here)."""

    system: int | None = None
    """System id (1-255) of the vehicle to fuse. Unset: the first autopilot heard, if
    ``lock_first_autopilot``, else every sender."""
    component: int | None = None
    """Component id (1-255). Unset: the locked autopilot's own component, or, with ``system``
    given, any component of that system."""
    lock_first_autopilot: bool = True
    """With ``system`` unset, use only the (system, component) of the first autopilot HEARTBEAT.
    False: use every sender (a bench with one known sender)."""
    signing_key_file: str | None = None
    """File with the MAVLink 2 signing key (32 raw bytes, or a passphrase: see the module docstring).
    Set: unsigned and wrongly signed frames are refused."""
    dialect: str = "ardupilotmega"
    """pymavlink dialect of the link (``ardupilotmega`` is a superset of ``common``)."""
    request_rate_hz: float | None = None
    """Ask the vehicle to stream the messages the fuser reads at this rate (Hz), as a ground station does
    (:mod:`drivers.stream_request`; live links only). Unset: only listen, never write to the vehicle's link."""

    def __post_init__(self) -> None:
        _check_id("system", self.system)
        _check_id("component", self.component)
        if type(self.lock_first_autopilot) is not bool:
            raise ValueError(f"link.lock_first_autopilot: true or false, got {self.lock_first_autopilot!r}")
        if isinstance(self.signing_key_file, os.PathLike):
            object.__setattr__(self, "signing_key_file", os.fspath(self.signing_key_file))
        if self.signing_key_file is not None and (not isinstance(self.signing_key_file, str) or not self.signing_key_file):
            raise ValueError(f"link.signing_key_file: a file name (or unset), got {self.signing_key_file!r}")
        rate = self.request_rate_hz
        if rate is not None and not (type(rate) in (int, float) and MIN_REQUEST_RATE_HZ <= rate <= MAX_REQUEST_RATE_HZ):  # nan fails
            raise ValueError(f"link.request_rate_hz: a number of Hz from {MIN_REQUEST_RATE_HZ:g} to {MAX_REQUEST_RATE_HZ:g} (or unset), "
                             f"got {rate!r}")
        if not isinstance(self.dialect, str) or not _DIALECT_NAME.fullmatch(self.dialect) or (
            importlib.util.find_spec(f"pymavlink.dialects.v20.{self.dialect}") is None
        ):
            raise ValueError(f"link.dialect: the name of a pymavlink dialect (e.g. ardupilotmega, common), got {self.dialect!r}")

    @classmethod
    def from_table(cls, table: Mapping[str, Any]) -> LinkSettings:
        """Settings from a TOML table (``[fuser.link]``); an unknown key is an error naming it."""
        if not isinstance(table, Mapping):
            raise ValueError(f"link: a table of settings ([fuser.link]), got {table!r}")
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(table) - known)
        if unknown:
            raise ValueError(f"unknown setting(s): {', '.join('link.' + k for k in unknown)}")
        return cls(**table)

    def signing_key(self) -> bytes | None:
        """The 32-byte secret key read from ``signing_key_file`` (None without one): the file's bytes if it holds 32 that
        are not a line of text, else the SHA-256 of the passphrase it holds (module docstring); ``SourceError`` if unreadable."""
        if self.signing_key_file is None:
            return None
        try:
            with open(self.signing_key_file, "rb") as f:
                data = f.read(MAX_KEY_FILE_BYTES + 1)
        except OSError as exc:
            raise SourceError(f"link.signing_key_file: cannot read {self.signing_key_file}: {exc.strerror}") from exc
        if len(data) == SIGNING_KEY_BYTES and not _is_text_line(data):
            return data
        try:
            passphrase = data.decode("utf-8").strip()
        except UnicodeDecodeError:
            passphrase = "\0"
        if len(data) > MAX_KEY_FILE_BYTES or "\0" in passphrase:  # /dev/zero was a passphrase of 4,096 NULs, a long file cut
            raise SourceError(f"link.signing_key_file: {self.signing_key_file} is neither a 32-byte key nor a UTF-8 passphrase "
                              f"(of at most {MAX_KEY_FILE_BYTES} bytes, without NUL)")
        if not passphrase:
            raise SourceError(f"link.signing_key_file: {self.signing_key_file} is empty")
        return hashlib.sha256(passphrase.encode("utf-8")).digest()
