"""``bingham-fuser import`` draws its progress while it reads a DataFlash log, not only while it writes the MCAP.

Reading with DFReader is most of an import's time (30 of 80 s for a 10-minute log of three IMUs at 400 Hz,
about 3 minutes for an hour's): the bar appeared only afterwards, so a terminal showed nothing for that long.
"""

from __future__ import annotations

import io
from pathlib import Path

from fuser.importers import import_log

from dataflash_writer import DataFlashWriter

RECORDS = 300


class Terminal(io.StringIO):
    """A stream that says it is a terminal (where a bar is drawn)."""

    def isatty(self) -> bool:
        return True


def _log(path: Path) -> int:
    """IMU records at 50 Hz; returns how many records the file holds (its two FMT records included)."""
    w = DataFlashWriter()
    w.declare(76, "IMU", "QBffffffIIfBBHH", "TimeUS,I,GyrX,GyrY,GyrZ,AccX,AccY,AccZ,EG,EA,T,GH,AH,GHz,AHz")
    for k in range(RECORDS):
        w.write("IMU", TimeUS=1_000_000 + 20_000 * k, I=0, GyrX=0.0, GyrY=0.0, GyrZ=0.0, AccX=0.0, AccY=0.0, AccZ=-9.81,
                EG=0, EA=0, T=40.0, GH=1, AH=1, GHz=1000, AHz=1000)
    path.write_bytes(bytes(w.data))
    return RECORDS + 2


def test_reading_a_dataflash_log_draws_a_bar_of_its_records(tmp_path: Path) -> None:
    total = _log(tmp_path / "flight.bin")
    terminal = Terminal()
    import_log(tmp_path / "flight.bin", tmp_path / "flight.mcap", progress=terminal)
    drawn = terminal.getvalue()
    assert "read" in drawn and f"{total}/{total}" in drawn
    assert drawn.index("read") < drawn.index("import")  # reading first, then the MCAP


def test_no_bar_where_the_stream_is_not_a_terminal(tmp_path: Path) -> None:
    _log(tmp_path / "flight.bin")
    pipe = io.StringIO()
    import_log(tmp_path / "flight.bin", tmp_path / "flight.mcap", progress=pipe)
    assert pipe.getvalue() == ""
