"""Reading the records of an MCAP file whole, cut short or damaged, without its index.

MCAP (https://mcap.dev/spec) is a sequence of records after an 8-byte magic,
each an opcode byte and a little-endian uint64 length followed by that many
bytes. A recorder that was killed leaves no summary, and a flipped bit
anywhere breaks readers that trust the index, so this reads the data section
in file order, record by record, and keeps whatever is sound:

* a chunk whose CRC fails, whose compressed data does not decompress or
  whose records do not parse is skipped whole; reading resumes at the next
  record, which its (intact) length points to. The message-index records
  that follow a skipped chunk say how many messages it held.
* a record whose length or opcode is damaged (it would run past the end of
  the file, is not a known opcode, or does not fit its own fields) is
  resynchronised: the bytes are searched for the next chunk or message index
  whose header is consistent with its length, and reading resumes there. If
  none is found the file is taken as cut short at that record.

Everything skipped is counted (:class:`Skipped`). A file that does not start
with the MCAP magic is not a log at all: :class:`NotAnMcapError`.
"""

from __future__ import annotations

import mmap
import re
import struct
import zlib
from dataclasses import dataclass, field, replace
from io import BytesIO
from pathlib import Path
from typing import Iterator, NamedTuple

import zstandard
from mcap.data_stream import ReadDataStream
from mcap.exceptions import McapError
from mcap.opcode import Opcode
from mcap.records import Channel, Metadata

from .errors import NotALogError

__all__ = ["MAGIC", "McapStream", "NotAnMcapError", "RawMessage", "Scan", "Skipped", "scan_mcap"]

MAGIC = b"\x89MCAP0\r\n"

_RECORD = struct.Struct("<BQ")
"""Opcode and length of every record."""
_MESSAGE = struct.Struct("<HIQQ")
"""Channel id, sequence, log time and publish time: the fixed part of a Message record."""
_CHUNK = struct.Struct("<QQQI")
"""Message start and end time, uncompressed size and CRC: the fixed part of a Chunk record."""
_U32 = struct.Struct("<I")
_U64 = struct.Struct("<Q")
_MESSAGE_INDEX = struct.Struct("<HI")
"""Channel id and the byte length of its (log time, offset) pairs, 16 bytes each."""

MAX_CHUNK_BYTES = 1 << 30
"""A chunk claiming more than this uncompressed is taken as damaged (the recorder writes 64 KiB)."""

_KNOWN_OPCODES = frozenset(int(op) for op in Opcode)
_COMPRESSIONS = ("", "lz4", "zstd")
MAX_REASONS = 10
"""Damages described in :attr:`Skipped.reasons`; further ones are only counted."""


class NotAnMcapError(NotALogError):
    """The file is not an MCAP log (empty, or it does not start with the MCAP magic)."""


class RawMessage(NamedTuple):
    """One message as stored: its topic, times and bytes, not decoded."""

    topic: str
    log_time: int
    publish_time: int
    data: bytes


@dataclass
class Skipped:
    """What could not be read in a damaged file."""

    chunks: int = 0
    """Chunks skipped (bad CRC, undecodable data, damaged records inside)."""
    bytes: int = 0
    """Bytes skipped: the damaged records, and what a resynchronisation jumped over."""
    messages: int = 0
    """Messages of the skipped chunks, as counted by the message indexes that follow them."""
    messages_known: bool = True
    """False when some skipped chunk had no readable message index (``messages`` is then a lower bound)."""
    resyncs: int = 0
    """Times a damaged record length or opcode was resynchronised on the next chunk."""
    unknown_channel: int = 0
    """Messages on a channel whose definition was lost with a damaged chunk."""
    reasons: list[str] = field(default_factory=list)
    """One line per damage, in file order (the first ``MAX_REASONS``)."""

    def __bool__(self) -> bool:
        return bool(self.chunks or self.bytes or self.unknown_channel)

    def note(self, offset: int, what: str) -> None:
        if len(self.reasons) < MAX_REASONS:
            self.reasons.append(f"at byte {offset:,}: {what}")

    def describe(self) -> str:
        """One line: what was skipped, e.g. '1 chunk (7,310 bytes, 150 messages)'."""
        parts = [f"{self.chunks} chunk{'s' * (self.chunks != 1)}", f"{self.bytes:,} bytes"]
        if self.chunks:
            parts.append(f"{'at least ' * (not self.messages_known)}{self.messages:,} messages")
        if self.resyncs:
            parts.append(f"{self.resyncs} resynchronisation{'s' * (self.resyncs != 1)}")
        if self.unknown_channel:
            parts.append(f"{self.unknown_channel:,} messages of lost channels")
        return f"{parts[0]} ({', '.join(parts[1:])})"


@dataclass
class Scan:
    """What :func:`scan_mcap` recovered: messages in file order (any outside chunks last)."""

    messages: list[RawMessage]
    complete: bool
    """True when the file ended with its footer and closing magic and nothing was skipped."""
    error: str | None
    """Why reading stopped before the footer (cut short), or what was damaged; None for a sound file."""
    metadata: dict[str, dict[str, str]]
    skipped: Skipped


class _Damaged(Exception):
    """A record that cannot be used; the reader skips it and goes on."""


def _chunk_records(body: bytes) -> bytes:
    """A chunk record's decompressed records (CRC checked)."""
    if len(body) < _CHUNK.size + 4:
        raise _Damaged("chunk header too short")
    _, _, size, crc = _CHUNK.unpack_from(body, 0)
    if size > MAX_CHUNK_BYTES:
        raise _Damaged(f"chunk claims {size:,} bytes uncompressed")
    pos = _CHUNK.size
    (n,) = _U32.unpack_from(body, pos)
    compression = bytes(body[pos + 4 : pos + 4 + n]).decode("utf-8", "replace")
    pos += 4 + n
    if compression not in _COMPRESSIONS or pos + 8 > len(body):
        raise _Damaged(f"chunk with unknown compression {compression!r}")
    (n,) = _U64.unpack_from(body, pos)
    pos += 8
    if pos + n != len(body):
        raise _Damaged("chunk length does not match its data")
    data = body[pos:]
    try:
        if compression == "zstd":
            data = zstandard.decompress(data, max_output_size=size)
        elif compression == "lz4":
            import lz4.frame  # noqa: PLC0415 - only logs of other writers use it

            data = lz4.frame.decompress(data)
    except Exception as e:  # noqa: BLE001 - every decompressor error means the same: damaged data
        raise _Damaged(f"chunk data does not decompress ({type(e).__name__})") from e
    if len(data) != size:
        raise _Damaged(f"chunk decompresses to {len(data)} bytes, not {size}")
    if crc != 0 and zlib.crc32(data) != crc:
        raise _Damaged("chunk CRC mismatch")
    return bytes(data)  # a copy only for an uncompressed chunk's slice of the file


def _chunk_messages(data: bytes, channels: dict[int, str], orphans: list[tuple[int, int, int, bytes]]) -> list[RawMessage]:
    """The messages of a chunk's records, registering the channels it declares.

    Messages on a channel not (yet) declared go to ``orphans`` as ``(channel id,
    log time, publish time, data)``, for the summary's channels to name later.
    Parsing the message headers with one ``unpack_from`` each is several times
    faster than building mcap's record objects. Nothing is returned, registered
    or appended unless the whole chunk parses.
    """
    found: list[RawMessage] = []
    lost: list[tuple[int, int, int, bytes]] = []
    known = dict(channels)
    pos, size = 0, len(data)
    unpack_record, unpack_message, header = _RECORD.unpack_from, _MESSAGE.unpack_from, _RECORD.size + _MESSAGE.size
    try:
        while pos < size:
            opcode, length = unpack_record(data, pos)
            end = pos + _RECORD.size + length
            if end > size:
                raise _Damaged(f"record of {length} bytes overruns its chunk")
            if opcode == Opcode.MESSAGE:
                channel_id, _, log_time, publish_time = unpack_message(data, pos + _RECORD.size)
                topic = known.get(channel_id)
                if topic is None:
                    lost.append((channel_id, log_time, publish_time, data[pos + header : end]))
                else:
                    found.append(RawMessage(topic, log_time, publish_time, data[pos + header : end]))
            elif opcode == Opcode.CHANNEL:
                channel = Channel.read(ReadDataStream(BytesIO(data[pos + _RECORD.size : end])))
                known[channel.id] = channel.topic
            pos = end
    except (McapError, struct.error, UnicodeDecodeError, ValueError) as e:
        raise _Damaged(f"chunk records do not parse ({e})") from e
    channels.update(known)
    orphans += lost
    return found


def _consistent_chunk(buf: mmap.mmap, pos: int, size: int) -> bool:
    """Whether a chunk record at ``pos`` has a length that fits its own fields and the file."""
    if pos + _RECORD.size + _CHUNK.size + 4 > size:
        return False
    _, length = _RECORD.unpack_from(buf, pos)
    body = pos + _RECORD.size
    (n,) = _U32.unpack_from(buf, body + _CHUNK.size)
    data_len_at = body + _CHUNK.size + 4 + n
    if data_len_at + 8 > size:
        return False
    (data_len,) = _U64.unpack_from(buf, data_len_at)
    return _CHUNK.size + 4 + n + 8 + data_len == length and body + length <= size


def _consistent_index(buf: mmap.mmap, pos: int, size: int) -> bool:
    """Whether a message-index record at ``pos`` has a length that fits its entries and the file."""
    if pos + _RECORD.size + _MESSAGE_INDEX.size > size:
        return False
    _, length = _RECORD.unpack_from(buf, pos)
    _, n = _MESSAGE_INDEX.unpack_from(buf, pos + _RECORD.size)
    return n % 16 == 0 and _MESSAGE_INDEX.size + n == length and pos + _RECORD.size + length <= size


_CANDIDATE = re.compile(
    rb"(?=\x06.{36}(?:\x00\x00\x00\x00|\x03\x00\x00\x00lz4|\x04\x00\x00\x00zstd)|\x07.{4}\x00\x00\x00\x00)", re.DOTALL
)
"""Where a chunk record may start (opcode, length, fixed fields, a known compression), or a message
index (opcode, a length under 4 GiB); a lookahead, so that a false match never hides a true one inside it."""


def _resync(buf: mmap.mmap, start: int, size: int) -> int | None:
    """Offset of the next consistent chunk or message-index record at or after ``start``, or None."""
    for m in _CANDIDATE.finditer(buf, start):
        pos = m.start()
        if (_consistent_chunk if buf[pos] == Opcode.CHUNK else _consistent_index)(buf, pos, size):
            return pos
    return None


def _plausible_record(buf: mmap.mmap, pos: int, size: int) -> bool:
    """Whether a record header at ``pos`` has a known opcode and fits the file (the file may end there)."""
    if pos == size:
        return True
    if pos + _RECORD.size > size:
        return False
    opcode, length = _RECORD.unpack_from(buf, pos)
    return opcode in _KNOWN_OPCODES and pos + _RECORD.size + length <= size


def scan_mcap(path: str | Path) -> Scan:
    """Every message that can be read from the MCAP file ``path``, in file order (see the module doc)."""
    stream = McapStream(path)
    messages = [m for group in stream for m in group]
    return replace(stream.result, messages=messages)


class McapStream:
    """The messages of an MCAP file, one group at a time, in file order: what :func:`scan_mcap` returns, without
    holding it. Iterating yields each sound chunk's messages, then those outside chunks (or whose channel only the
    summary declares); the memory held is one chunk's, whatever the file's length. After the iteration,
    :attr:`result` tells what was read (``complete``, ``error``, ``metadata``, ``skipped``; no ``messages``).

    Raises :class:`NotAnMcapError` at once (not on iteration) if the file is not an MCAP. Each iteration reads the
    file again, with the same result.
    """

    PAGES_KEPT = 16 << 20
    """Bytes of the file read behind the current record that stay mapped in memory (see :meth:`__iter__`)."""

    def __init__(self, path: str | Path) -> None:
        self.path = path
        with open(path, "rb") as f:
            size = f.seek(0, 2)
            if size == 0:
                raise NotAnMcapError(f"{path} is empty")
            f.seek(0)
            if f.read(len(MAGIC)) != MAGIC:
                raise NotAnMcapError(f"{path} is not an MCAP file (it does not start with the MCAP magic)")
        self.result: Scan | None = None
        """What the last complete iteration read (its ``messages`` empty); None before one has ended."""

    def __iter__(self) -> Iterator[list[RawMessage]]:
        """Each group of messages in file order. The pages of the file already read are released as reading goes
        on (``MADV_DONTNEED``): a mapped file's pages count in the process's resident memory until then."""
        with open(self.path, "rb") as f, mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ) as buf:
            scanner = _Scanner(buf, len(buf))
            released = 0
            for group in scanner.groups():
                released = _release(buf, released, scanner.pos - self.PAGES_KEPT)
                yield group
            self.result = scanner.result


def _release(buf: mmap.mmap, start: int, end: int) -> int:
    """Drop the pages of ``buf`` from ``start`` up to ``end`` (rounded down to a page) from memory; the new start."""
    end -= end % mmap.PAGESIZE
    if end <= start or not hasattr(mmap, "MADV_DONTNEED"):
        return start
    buf.madvise(mmap.MADV_DONTNEED, start, end - start)
    return end


class _Scanner:
    """One pass over the records of a file; the state is what a damaged record leaves to count."""

    def __init__(self, buf: mmap.mmap, size: int) -> None:
        self.buf, self.size = buf, size
        self.channels: dict[int, str] = {}
        self.pos = len(MAGIC)
        """Offset of the record being read."""
        self.result: Scan | None = None
        """Set when :meth:`groups` has ended."""
        self.orphans: list[tuple[int, int, int, bytes]] = []
        """Messages whose channel was not declared before them (it may be in the summary)."""
        self.metadata: dict[str, dict[str, str]] = {}
        self.skipped = Skipped()
        self.counting = False
        """True after a skipped chunk: the message indexes that follow it count its messages."""
        self.counted = False
        self.last_sound: int | None = None
        """Opcode of the last record whose header was sound."""

    def _was_chunk(self, pos: int, opcode: int, length: int, resumed_at: int) -> bool:
        """Whether the damaged record at ``pos``, skipped up to ``resumed_at``, was a chunk (its messages are lost)."""
        if opcode in (Opcode.CHUNK, Opcode.MESSAGE_INDEX):
            return opcode == Opcode.CHUNK
        if pos + _RECORD.size + length == resumed_at:  # only the opcode byte is damaged: the fields tell
            return _consistent_chunk(self.buf, pos, self.size)
        # message indexes follow their chunk: resuming on one that no chunk read just now precedes means a chunk was lost
        return self.buf[resumed_at] == Opcode.MESSAGE_INDEX and self.last_sound not in (Opcode.CHUNK, Opcode.MESSAGE_INDEX)

    def _lost_chunk(self) -> None:
        self._end_count()
        self.skipped.chunks += 1
        self.counting, self.counted = True, False

    def _end_count(self) -> None:
        if self.counting and not self.counted:
            self.skipped.messages_known = False
        self.counting = False

    def groups(self) -> Iterator[list[RawMessage]]:
        """The messages of each sound chunk, then those outside chunks; :attr:`result` set at the end."""
        buf, size, skipped = self.buf, self.size, self.skipped
        complete, error = False, None
        pos = len(MAGIC)
        while True:
            self.pos = pos
            if pos + _RECORD.size > size:
                error = "cut short: no footer" if pos == size else f"cut short inside a record header at byte {pos:,}"
                break
            opcode, length = _RECORD.unpack_from(buf, pos)
            body_at, end = pos + _RECORD.size, pos + _RECORD.size + length
            sound = opcode in _KNOWN_OPCODES and end <= size
            if sound and opcode == Opcode.CHUNK and not _consistent_chunk(buf, pos, size):
                # fields damaged: skip it by its length if a record follows there, else resynchronise
                sound = _plausible_record(buf, end, size)
            if not sound:
                nxt = _resync(buf, pos + 1, size)
                if nxt is None:
                    if opcode in _KNOWN_OPCODES and end > size:
                        error = f"cut short inside a record at byte {pos:,} ({length:,} bytes declared, {size - body_at:,} left)"
                    else:
                        error = f"damaged record at byte {pos:,}, and no chunk after it"
                        skipped.bytes += size - pos
                        skipped.note(pos, "damaged record, nothing readable after it")
                    break
                if self._was_chunk(pos, opcode, length, nxt):
                    self._lost_chunk()
                skipped.resyncs += 1
                skipped.bytes += nxt - pos
                skipped.note(pos, f"damaged record length or opcode; resumed at byte {nxt:,}")
                pos = nxt
                continue
            if opcode != Opcode.MESSAGE_INDEX:
                self._end_count()
            self.last_sound = opcode
            try:
                if opcode == Opcode.FOOTER:
                    if buf[end : end + len(MAGIC)] == MAGIC:
                        complete = True
                    else:
                        error = "no closing magic after the footer"
                    break
                found = self._record(opcode, buf[body_at:end])
            except (_Damaged, McapError, struct.error, UnicodeDecodeError, ValueError) as e:
                found = None
                skipped.bytes += end - pos
                if opcode == Opcode.CHUNK:
                    self._lost_chunk()
                skipped.note(pos, f"{Opcode(opcode).name.lower()} skipped: {e}")
            pos = end
            if found:
                yield found
        self._end_count()
        messages = []
        for channel_id, log_time, publish_time, data in self.orphans:
            topic = self.channels.get(channel_id)
            if topic is None:
                skipped.unknown_channel += 1
            else:
                messages.append(RawMessage(topic, log_time, publish_time, data))
        if skipped and error is None:
            error = "damaged: " + "; ".join(skipped.reasons[:3])
        if messages:
            yield messages
        self.result = Scan([], complete and not skipped, error, self.metadata, skipped)

    def _record(self, opcode: int, body: bytes) -> list[RawMessage] | None:
        """Read one sound record: a chunk's messages, or None."""
        if opcode == Opcode.CHUNK:
            return _chunk_messages(_chunk_records(body), self.channels, self.orphans)
        elif opcode == Opcode.MESSAGE_INDEX:
            _, n = _MESSAGE_INDEX.unpack_from(body, 0)
            if n % 16 or _MESSAGE_INDEX.size + n != len(body):
                raise _Damaged("message index length does not match its entries")
            if self.counting:
                self.skipped.messages += n // 16
                self.counted = True
        elif opcode == Opcode.CHANNEL:
            channel = Channel.read(ReadDataStream(BytesIO(body)))
            self.channels[channel.id] = channel.topic
        elif opcode == Opcode.MESSAGE:
            channel_id, _, log_time, publish_time = _MESSAGE.unpack_from(body, 0)
            self.orphans.append((channel_id, log_time, publish_time, body[_MESSAGE.size :]))  # named at the end
        elif opcode == Opcode.METADATA:
            record = Metadata.read(ReadDataStream(BytesIO(body)))
            self.metadata[record.name] = dict(record.metadata)
        return None
