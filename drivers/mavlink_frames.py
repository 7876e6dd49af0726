"""MAVLink bytes to authenticated pymavlink messages: framing, CRC, signing, every fault counted.

pymavlink's ``MAVLink`` object frames and checks the bytes (robust parsing: a bad frame comes
back as ``MAVLink_bad_data``); this module decides what each refusal is and what to do next:

* a frame refused for its CRC, its header or an unknown id is handed back to the parser minus
  its first byte, so a valid packet swallowed by a false header found in garbage is still found
  (pymavlink alone loses it). The bytes are re-read in place (the buffer index moves back), so a
  flood of refused frames costs no copying;
* every message in the bytes is returned, not one per read, and the parser's buffer is compacted
  after each call, so it never holds more than one incomplete frame;
* garbage is skipped to the next magic byte with ``bytearray.find`` (pymavlink steps through it
  byte by byte in Python: 0.3 us a byte, the bulk of a random-bytes flood's cost);
* once the vehicle is known (``screen``), a header that does not claim the vehicle is never
  decoded: another sender's frame that the next frame's start follows (or the end of the bytes)
  is counted as ``other_sender``, and any other such header is a stray magic byte in garbage,
  stepped over one byte at a time, so it can swallow nothing. A flood from other senders, or of
  random bytes, costs a header read per frame or false header. Other senders' HEARTBEATs (one a
  second each) are decoded, so that another vehicle on the link can be named;
* a datagram or a log record is complete in itself: what is left at its end is a frame cut
  short (``truncated``), and the bytes after its first are searched for frames too.

Signing (MAVLink 2 message signing, MAVLink developer guide "Message Signing"): with a key,
pymavlink's ``MAVLink.signing`` verifies each signature (SHA-256 of key + frame, 48 bits) and its
timestamp (newer than the last of the same (link id, system, component) stream, and for a new
stream at most one minute older than the newest seen). Refusals are counted as ``unsigned`` (no
signature, or a MAVLink 1 frame), ``bad_signature`` (a signature that does not verify, whatever
its timestamp: the signature is judged first) or ``replayed`` (a signature that verifies, with a
timestamp not newer than its stream's, or a new stream's over a minute old). pymavlink records
a frame's timestamp before checking its signature, so one forged frame with a far-future
timestamp would make every genuine frame after it look replayed, and forged frames from new
(link, system, component) triples would each add a stream entry; the stream's previous timestamp
is restored after every refusal, so only verified frames change the signing state.
"""

from __future__ import annotations

import hashlib
import time
from typing import Any, Callable

from .base import ReasonLog

SIGNING_EPOCH_S = 1_420_070_400
"""2015-01-01T00:00:00Z, the origin of MAVLink 2 signing timestamps (10 us units)."""
_SIGNING_UNITS_PER_S = 100_000
_SIGNATURE_BYTES = 6
_MAGIC = (0xFE, 0xFD)
_V2 = 0xFD
_HEARTBEAT_ID = 0


def signing_timestamp_now() -> int:
    """The current time in MAVLink signing units, as pymavlink's ``setup_signing`` starts from."""
    return int((max(time.time(), SIGNING_EPOCH_S) - SIGNING_EPOCH_S) * _SIGNING_UNITS_PER_S)


def _signature_verifies(key: bytes, msgbuf: bytes | bytearray) -> bool:
    """Whether a signed MAVLink 2 frame's signature is the one ``key`` gives (its timestamp not judged)."""
    digest = hashlib.sha256(key + bytes(msgbuf[:-_SIGNATURE_BYTES])).digest()
    return digest[:_SIGNATURE_BYTES] == bytes(msgbuf[-_SIGNATURE_BYTES:])


def _frame_reason(text: str) -> str:
    if text.startswith("invalid MAVLink CRC"):
        return "bad_crc"
    return "bad_frame"


class FrameParser:
    """Frames and authenticates MAVLink bytes with one pymavlink ``MAVLink`` object of ``dialect_module``.

    ``parse`` returns the valid messages in the bytes; every refusal is counted through ``note``
    by reason. ``signing_key`` (32 bytes) turns signature checking on; ``signing_timestamp`` is the
    signing clock to start from (MAVLink units; None: now, as pymavlink's ``setup_signing``; 0 for
    a log recorded in the past).
    """

    def __init__(
        self,
        dialect_module: Any,
        note: ReasonLog,
        signing_key: bytes | None = None,
        signing_timestamp: int | None = None,
    ) -> None:
        mav = self.mav = dialect_module.MAVLink(None)
        mav.robust_parsing = True
        self._note = note
        self._bad_data = dialect_module.MAVLink_bad_data
        self._unknown = dialect_module.MAVLink_unknown
        self._signature_fault: str | None = None
        self.screen: Callable[[int, int], bool] | None = None
        """Whether a (system, component) is wanted; frames of the others are counted, not decoded (None: decode all)."""

        if signing_key is not None:
            signing = mav.signing
            signing.secret_key = signing_key
            signing.sign_outgoing = False
            signing.allow_unsigned_callback = None
            signing.timestamp = signing_timestamp_now() if signing_timestamp is None else signing_timestamp
            mav.check_signature = self._checked_signature(mav.check_signature)

    def parse(self, data: bytes, complete: bool = False) -> list[Any]:
        """Valid messages in ``data`` (continuing the bytes fed before).

        ``complete``: ``data`` ends a datagram or log record, so an unfinished frame at its end
        is refused as ``truncated`` instead of waiting for more bytes.
        """
        mav = self.mav
        out: list[Any] = []
        mav.buf.extend(data)
        while True:
            while (msg := self._next()) is not None:
                kind = type(msg)
                if kind is self._bad_data:
                    self._refused(msg)
                elif kind is self._unknown:
                    self._note("unknown_message", msg.get_type())
                    self._rescan(msg.data)
                else:
                    out.append(msg)
            if not complete or mav.buf_len() == 0:
                break
            self._note("truncated", f"{mav.buf_len()} bytes of an unfinished frame")
            mav.buf_index += 1  # look for frames in the rest of it
            mav.expected_length = 8
        if mav.buf_index:
            del mav.buf[: mav.buf_index]
            mav.buf_index = 0
        return out

    def _next(self) -> Any:
        """The parser's next message, after skipping garbage and, once the vehicle is known, what
        cannot be the vehicle's: another sender's frame that a frame start follows is counted as
        ``other_sender``; any other header not claiming the vehicle is a stray magic byte (garbage)."""
        mav = self.mav
        buf, i, n = mav.buf, mav.buf_index, len(mav.buf)
        screen = self.screen
        if screen is None and i < n and buf[i] in _MAGIC:
            return mav.parse_char(b"")
        others = garbage = 0
        while i < n:
            if buf[i] not in _MAGIC:
                hits = [j for j in (buf.find(0xFD, i), buf.find(0xFE, i)) if j >= 0]
                i = min(hits) if hits else n
                garbage += 1
                continue
            if screen is None or i + 10 > n:
                break
            if buf[i] == _V2:
                end, system, component = i + 12 + buf[i + 1] + (13 if buf[i + 2] & 0x01 else 0), buf[i + 5], buf[i + 6]
                valid_flags, msgid = not buf[i + 2] & 0xFE, buf[i + 7] | buf[i + 8] << 8 | buf[i + 9] << 16
            else:
                end, system, component, valid_flags, msgid = i + 8 + buf[i + 1], buf[i + 3], buf[i + 4], True, buf[i + 5]
            if valid_flags and (screen(system, component) or msgid == _HEARTBEAT_ID):
                break  # the vehicle's, or claims to be, or anyone's HEARTBEAT: pymavlink checks it
            if valid_flags and end > n:
                break  # another sender's frame, not complete yet
            if valid_flags and (end == n or buf[end] in _MAGIC):
                others += 1
                i = end
            else:  # not a frame that ends where another starts: a magic byte in garbage
                garbage += 1
                i += 1
        if others:
            self._note.stats["other_sender"] += others
        if garbage:
            self._note("garbage", f"{garbage} runs", garbage)
        if i != mav.buf_index:
            mav.buf_index = i
            mav.expected_length = 8
        return mav.parse_char(b"")

    def _refused(self, msg: Any) -> None:
        text = msg.reason
        if text == "Invalid signature":
            reason, self._signature_fault = self._signature_fault or "unsigned", None
            self._note(reason, f"from {msg.data[5] if msg.data[0] == 0xFD else msg.data[3]}")
        else:
            self._note(_frame_reason(text), text)
            self._rescan(msg.data)

    def _rescan(self, frame: bytes | bytearray) -> None:
        """Hand the parser every byte of a refused frame but its first again."""
        mav = self.mav
        n = len(frame)
        if mav.buf_index >= n and mav.buf[mav.buf_index - n : mav.buf_index] == frame:
            mav.buf_index -= n - 1  # still in the buffer, just consumed: read it again in place
        else:  # the parser emptied its buffer after the frame
            mav.buf = bytearray(frame[1:]) + mav.buf[mav.buf_index :]
            mav.buf_index = 0
        mav.expected_length = 8

    def _checked_signature(self, check: Callable[[bytearray, int, int], bool]) -> Callable[[bytearray, int, int], bool]:
        """pymavlink's signature check, undoing its state change when it refuses and naming why: ``bad_signature``
        if the signature does not verify (judged first, whatever the timestamp), else ``replayed`` (the timestamp)."""
        signing = self.mav.signing

        def checked(msgbuf: bytearray, system: int, component: int) -> bool:
            key = (msgbuf[-13], system, component)
            before = signing.stream_timestamps.get(key)
            if check(msgbuf, system, component):
                return True
            if before is None:
                signing.stream_timestamps.pop(key, None)
            else:
                signing.stream_timestamps[key] = before
            self._signature_fault = "replayed" if _signature_verifies(signing.secret_key, msgbuf) else "bad_signature"
            return False

        return checked
