"""A small PX4 ULog writer for the tests, written from the format's definition (PX4 "ULog File Format").

A ULog file is a 16-byte header ("ULog", 0x01 0x12 0x35, version 1, start timestamp uint64 in us)
followed by messages, each ``uint16 size, uint8 type`` and ``size`` bytes: 'B' flag bits (8 compat,
8 incompat bytes, 3 appended-data offsets), 'F' formats ("name:type field;type field;..."), then
'A' subscriptions (multi id uint8, msg id uint16, topic name) and 'D' data (msg id uint16, the
fields packed little-endian in the format's order).
"""

from __future__ import annotations

import struct

_TYPES = {"uint64_t": "Q", "int64_t": "q", "uint32_t": "I", "int32_t": "i", "uint16_t": "H", "int16_t": "h",
          "uint8_t": "B", "int8_t": "b", "bool": "?", "float": "f", "double": "d"}


class ULogWriter:
    """Declare every topic with its fields, then append data; ``data`` is the file's content."""

    def __init__(self, start_us: int = 0) -> None:
        self.data = bytearray(b"ULog\x01\x12\x35" + bytes([1]) + struct.pack("<Q", start_us))
        self._message(b"B", bytes(16) + struct.pack("<3Q", 0, 0, 0))
        self._topics: dict[str, tuple[int, list[tuple[str, int, str]]]] = {}
        self._subscribed = False
        self.last_message_at = 0
        """Where the last data message written by :meth:`write` starts (to cut a log inside it)."""

    def _message(self, kind: bytes, payload: bytes) -> None:
        self.data += struct.pack("<H", len(payload)) + kind + payload

    def topic(self, name: str, fields: list[tuple[str, str]]) -> None:
        """A topic (multi id 0) with fields ``(type, name)``, arrays as ``("float[3]", "gyro_rad")``."""
        parsed = []
        for ftype, fname in fields:
            base, _, count = ftype.partition("[")
            parsed.append((base, int(count.rstrip("]")) if count else 0, fname))
        self._message(b"F", f"{name}:".encode() + b"".join(f"{t};".encode() for t in (f"{ft} {fn}" for ft, fn in fields)))
        self._topics[name] = (len(self._topics), parsed)

    def subscribe(self) -> None:
        """The data section begins: one subscription per declared topic (the formats all came before); again for
        an appended-data part."""
        for name, (msg_id, _) in self._topics.items():
            self._message(b"A", struct.pack("<BH", 0, msg_id) + name.encode())
        self._subscribed = True

    def write(self, name: str, **values) -> None:
        """One sample of a topic; every field must be given (arrays as sequences). Declare every topic first."""
        if not self._subscribed:
            self.subscribe()
        msg_id, fields = self._topics[name]
        payload = bytearray(struct.pack("<H", msg_id))
        for base, count, fname in fields:
            value = values[fname]
            code = _TYPES[base]
            payload += struct.pack(f"<{count}{code}", *value) if count else struct.pack("<" + code, value)
        self.last_message_at = len(self.data)
        self._message(b"D", bytes(payload))
