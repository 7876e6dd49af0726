"""The recorder's MCAP files carry the data-section CRC (issue 12 item 9), checked against zlib directly."""

from __future__ import annotations

import struct
import zlib

from drivers.samples import ImuSample, SourceId
from fuser.record import McapRecorder

DATA_END_OPCODE = 0x0F
FOOTER_BYTES = 1 + 8 + 8 + 8 + 4  # opcode, length, summary_start, summary_offset_start, summary_crc


def test_the_data_end_record_holds_the_crc32_of_every_byte_before_it(tmp_path):
    path = tmp_path / "r.mcap"
    with McapRecorder(path) as rec:
        for i in range(2_000):
            rec.write_sample(ImuSample(10**9 + 2_500_000 * i, (0.01, 0.0, 0.0), (0.0, 0.0, -9.8), None, SourceId("mavlink", 1, 1, 0)), 10**9 + 2_500_000 * i)
    data = path.read_bytes()
    footer = data[-8 - FOOTER_BYTES : -8]
    (summary_start,) = struct.unpack_from("<Q", footer, 9)
    data_end = summary_start - 13  # opcode, uint64 length, uint32 data_section_crc
    assert data[data_end] == DATA_END_OPCODE
    (crc,) = struct.unpack_from("<I", data, data_end + 9)
    assert crc != 0 and crc == zlib.crc32(data[:data_end])
