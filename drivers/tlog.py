"""MAVLink telemetry logs (.tlog): the file's own records, each packet through the live decoder.

A .tlog (as MAVProxy, QGroundControl and Mission Planner write it, and pymavlink's ``mavlogfile``
reads it) is a sequence of records: an 8-byte big-endian Unix time in microseconds, the ground
station's receive time, then one raw MAVLink packet. Nothing but the packet's own header marks a
record's length. Real logs hold more than clean records: packets the radio damaged (bad CRC, a
wrong length byte), garbage the ground station logged, a record cut short at the end, a receive
time that is nonsense.

:class:`TlogReader` keeps the record framing itself (pymavlink's reader shares its parser with the
file position, and a decoder that re-reads refused bytes desynchronises it): a record is taken
where the packet at ``pos + 8`` passes its CRC, or, where the CRC cannot tell (a damaged packet,
an id outside the dialect), where the next record visibly starts right after it. Elsewhere the
reader searches forward for the next record (a magic byte whose 8-byte time lies within
``RESYNC_WINDOW_US`` of the last trusted one and whose packet passes its CRC) and hands the bytes
in between to the decoder as they are, counted once as ``unframed``: whatever valid packet they
hold is still decoded, as the live decoder would decode it.

Record times. Each must lie in [0, MAX_TIME_NS) and within -RECORD_BACK_US / +RECORD_FORWARD_US of
the last trusted one; one that does not is ``record_time_absurd`` and the record takes the last
trusted time instead, unless the next record confirms the new time (a ground-station clock
step): ``record_clock_step``, and the new time is trusted. Receive times never go backwards.
"""

from __future__ import annotations

import mmap
from pathlib import Path
from typing import Any, Iterator

from pymavlink.generator.mavcrc import x25crc

from .base import SampleSource, SourceError
from .link import LinkSettings
from .mavlink_decode import MavlinkDecoder, dialect_module
from .samples import Sample
from .timebase import MAX_TIME_NS, NS_PER_US

__all__ = ["TlogReader", "TlogSource"]

RECORD_BACK_US = 1_000_000
"""A record time may be this far behind the last trusted one (several links, thread jitter)."""
RECORD_FORWARD_US = 3_600_000_000
"""A record time may be this far ahead of the last trusted one (a link silent for up to an hour)."""
RESYNC_WINDOW_US = 86_400_000_000
"""While searching for the next record after damage, a candidate's time must lie within a day of the last trusted one."""
_TIME_BYTES = 8
_V1, _V2 = 0xFE, 0xFD


class TlogReader:
    """Records of a .tlog as ``(receive_ns, bytes)``: one packet, or a run of unframed bytes between records.

    ``stats`` (shared with the decoder when given) counts ``unframed``, ``record_time_absurd`` and
    ``record_clock_step``. ``dialect`` gives the CRC extras the framing checks packets with.
    """

    def __init__(self, data: bytes | mmap.mmap, dialect: str, stats: Any) -> None:
        self._data = data
        self._map = dialect_module(dialect).mavlink_map
        self.stats = stats
        self._trusted_us: int | None = None
        self._used_ns = 0
        self._suspect_us: int | None = None

    def __iter__(self) -> Iterator[tuple[int | None, bytes]]:
        """``(receive_ns, bytes)`` in file order; unframed bytes take the last trusted time (None before the first)."""
        data, n, pos = self._data, len(self._data), 0
        while pos < n:
            size = self._framed_size(pos)
            if size is None:
                start, pos = pos, self._resync(pos + 1)
                self.stats["unframed"] += 1
                yield (None if self._trusted_us is None else self._used_ns), bytes(data[start:pos])
                continue
            yield self._receive_ns(int.from_bytes(data[pos : pos + _TIME_BYTES], "big")), bytes(data[pos + _TIME_BYTES : pos + size])
            pos += size

    def _packet_size(self, at: int) -> int | None:
        """Length of the packet whose magic byte is at ``at`` (None: no magic, or its header is cut off)."""
        data = self._data
        if at + 3 > len(data) or data[at] not in (_V1, _V2):
            return None
        if data[at] == _V1:
            return 8 + data[at + 1]
        return 12 + data[at + 1] + (13 if data[at + 2] & 0x01 else 0)

    def _crc_ok(self, at: int, size: int) -> bool | None:
        """Whether the packet at ``at`` passes its CRC (None: its id is not in the dialect, so it cannot tell)."""
        data = self._data
        v2 = data[at] == _V2
        header = 10 if v2 else 6
        payload = data[at + 1]
        if size < header + 2:
            return False
        msgid = (data[at + 7] | data[at + 8] << 8 | data[at + 9] << 16) if v2 else data[at + 5]
        kind = self._map.get(msgid)
        if kind is None:
            return None
        crc = x25crc(bytes(data[at + 1 : at + header + payload]))
        crc.accumulate(bytes((kind.crc_extra,)))
        return crc.crc == int.from_bytes(data[at + header + payload : at + header + payload + 2], "little")

    def _record_starts(self, pos: int) -> bool:
        """Whether a record visibly starts at ``pos``: the end of the file, or a time near the trusted one and a magic byte."""
        data = self._data
        if pos == len(data):
            return True
        if pos + _TIME_BYTES >= len(data) or data[pos + _TIME_BYTES] not in (_V1, _V2):
            return False
        return self._near_trusted(int.from_bytes(data[pos : pos + _TIME_BYTES], "big"), RESYNC_WINDOW_US)

    def _near_trusted(self, t_us: int, window_us: int) -> bool:
        return self._trusted_us is None or abs(t_us - self._trusted_us) <= window_us

    def _framed_size(self, pos: int) -> int | None:
        """Size of the record at ``pos`` (time and packet), or None where no record starts."""
        size = self._packet_size(pos + _TIME_BYTES)
        end = pos + _TIME_BYTES + (size or 0)
        if size is None or end > len(self._data):
            return None
        return end - pos if self._crc_ok(pos + _TIME_BYTES, size) or self._record_starts(end) else None

    def _resync(self, pos: int) -> int:
        """Start of the next record at or after ``pos`` that passes its CRC, with a time near the trusted one (or the end)."""
        data, n = self._data, len(self._data)
        at = pos + _TIME_BYTES
        while True:
            v1, v2 = data.find(bytes((_V1,)), at), data.find(bytes((_V2,)), at)
            hits = [h for h in (v1, v2) if h >= 0]
            if not hits:
                return n
            at = min(hits)
            start = at - _TIME_BYTES
            size = self._packet_size(at)
            if (
                size is not None
                and at + size <= n
                and self._near_trusted(int.from_bytes(data[start:at], "big"), RESYNC_WINDOW_US)
                and self._crc_ok(at, size)
            ):
                return start
            at += 1

    def _receive_ns(self, t_us: int) -> int:
        """Receive time of a record stamped ``t_us`` (see the module docstring), in ns, never decreasing."""
        trusted = self._trusted_us
        plausible = t_us * NS_PER_US < MAX_TIME_NS and (trusted is None or -RECORD_BACK_US <= t_us - trusted <= RECORD_FORWARD_US)
        if plausible:
            self._suspect_us = None
        elif self._suspect_us is not None and 0 <= t_us - self._suspect_us <= RECORD_FORWARD_US and t_us * NS_PER_US < MAX_TIME_NS:
            self.stats["record_clock_step"] += 1
            self._suspect_us = None
            plausible = True
        else:
            self.stats["record_time_absurd"] += 1
            self._suspect_us = t_us
        if plausible:
            self._trusted_us = t_us
            self._used_ns = max(self._used_ns, t_us * NS_PER_US)
        return self._used_ns


class TlogSource(SampleSource):
    """Samples of a .tlog with their receive times, through the live decoder (``link`` as for a live link).

    ``samples()`` yields ``(sample, receive_ns)`` in file order; ``poll`` returns the next samples
    and sets ``exhausted`` at the end. ``stats`` counts everything the live decoder counts, and the
    reader's record faults. Signatures are checked from a signing clock of zero (the log is older than
    now); every sender's messages are decoded, so ``decoder.received`` counts them all.
    """

    def __init__(self, path: str | Path, link: LinkSettings | None = None) -> None:
        self.decoder = MavlinkDecoder(LinkSettings() if link is None else link, signing_timestamp=0, screen=False)
        self.stats = self.decoder.stats
        try:
            with open(path, "rb") as f:
                self._data: bytes | mmap.mmap = mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ) if f.seek(0, 2) else b""
        except OSError as exc:
            raise SourceError(f"cannot read the telemetry log {path}: {exc.strerror or exc}") from exc
        self._records = iter(TlogReader(self._data, self.decoder.link.dialect, self.stats))
        self.exhausted = False

    def samples(self) -> Iterator[tuple[Sample, int]]:
        """Every sample of the log with the receive time of its record."""
        while not self.exhausted:
            yield from self._next()

    def poll(self, timeout: float) -> list[Sample]:  # noqa: ARG002 - a file never waits
        return [sample for sample, _ in self._next()]

    def _next(self) -> list[tuple[Sample, int]]:
        """The samples of the next records that give any (empty, and ``exhausted``, at the end)."""
        for receive_ns, packet in self._records:
            samples = self.decoder.feed_datagram(packet, receive_ns)
            if samples and receive_ns is None:  # unframed bytes before the first record: no time to give them
                self.stats["no_receive_time"] += len(samples)
            elif samples:
                return [(sample, receive_ns) for sample in samples]
        self.exhausted = True
        return []

    def close(self) -> None:
        if isinstance(self._data, mmap.mmap):
            self._data.close()
