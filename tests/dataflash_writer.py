"""A small ArduPilot DataFlash (.bin) writer for the tests, written from the format's definition.

A DataFlash log is a sequence of records, each ``0xA3 0x95 <type id>`` followed by the packed
little-endian fields of that type. Types are declared in-band by FMT records (type 128, itself
"BBnNZ": type id, record length including the 3 header bytes, name char[4], format char[16],
column names char[64]). Format characters as ArduPilot's AP_Logger documents them (LogStructure.h):
b/B int8/uint8, h/H int16/uint16, i/I int32/uint32, q/Q int64/uint64, f float, d double,
n/N/Z char[4]/[16]/[64], M uint8 flight mode, c/C int16/uint16 * 100, e/E int32/uint32 * 100,
L int32 latitude/longitude * 1e7. Values are given here in their physical units (degrees, metres,
m/s) and scaled on the way in, as the autopilot does.
"""

from __future__ import annotations

import struct

HEADER = b"\xa3\x95"
FMT_TYPE = 128
_CODES = {
    "b": ("b", 1), "B": ("B", 1), "h": ("h", 1), "H": ("H", 1), "i": ("i", 1), "I": ("I", 1), "q": ("q", 1),
    "Q": ("Q", 1), "f": ("f", 1), "d": ("d", 1), "M": ("B", 1), "n": ("4s", None), "N": ("16s", None),
    "Z": ("64s", None), "c": ("h", 100), "C": ("H", 100), "e": ("i", 100), "E": ("I", 100), "L": ("i", 10_000_000),
}


class DataFlashWriter:
    """Append FMT declarations, records and raw bytes; ``data`` is the file's content."""

    def __init__(self) -> None:
        self.data = bytearray()
        self._types: dict[str, tuple[int, str, list[str]]] = {}
        self.last_record_at = 0
        """Where the last record written by :meth:`write` starts (to cut a log inside it)."""
        self.declare(FMT_TYPE, "FMT", "BBnNZ", "Type,Length,Name,Format,Columns")  # a log begins by describing FMT

    def declare(self, type_id: int, name: str, fmt: str, columns: str) -> None:
        names = columns.split(",")
        if len(names) != len(fmt):
            raise ValueError(f"{name}: {len(fmt)} format characters for {len(names)} columns")
        length = 3 + struct.calcsize("<" + "".join(_CODES[c][0] for c in fmt))
        self._types[name] = (type_id, fmt, names)
        self.data += HEADER + bytes([FMT_TYPE]) + struct.pack(
            "<BB4s16s64s", type_id, length, name.encode(), fmt.encode(), columns.encode()
        )

    def write(self, name: str, **values: float | int | str) -> None:
        """One record of a declared type; every column must be given."""
        type_id, fmt, names = self._types[name]
        packed = bytearray(HEADER + bytes([type_id]))
        for column, c in zip(names, fmt):
            code, scale = _CODES[c]
            value = values[column]
            if scale is None:
                packed += struct.pack("<" + code, str(value).encode())
            elif code in "fd":
                packed += struct.pack("<" + code, float(value))
            else:
                packed += struct.pack("<" + code, int(round(float(value) * scale)))
        if set(values) - set(names):
            raise ValueError(f"{name} has no column(s) {sorted(set(values) - set(names))}")
        self.last_record_at = len(self.data)
        self.data += packed

    def raw(self, data: bytes) -> None:
        """Bytes that are not a record (a corrupted stretch of an SD card)."""
        self.data += data
