"""A disk that fills up while a log is written: one clear line naming the file and what it holds, never a bare
"No space left on device".

Tried on a 512 KiB tmpfs: `replay LOG -o full/r.mcap` went on replaying into a full disk (each chunk counted as a
rejected record) and ended with "bingham-fuser: No space left on device", naming no file; `import` left a truncated
MCAP behind; `sim -o full/s.mcap` said the same and nothing about what its recording holds. The disk here is a file
object that refuses every byte past a budget with ENOSPC, as a full file system does.
"""

from __future__ import annotations

import errno
import io
import re
from pathlib import Path

import pytest

import fuser.record as record
from fuser.config import FuserConfig
from fuser.record import McapRecorder, RecordWriteError, read_log
from fuser.replay import ReplayError, replay

ROOT = Path(__file__).resolve().parent.parent
LOG = ROOT / "logs" / "sim_hover.mcap"
BUDGET = 200_000
"""Bytes the disk takes before it is full: a few chunks of the recording."""


class _FullDisk(io.FileIO):
    """A file on a disk with :data:`BUDGET` bytes free."""

    def write(self, data) -> int:  # type: ignore[override]
        if self.tell() + len(data) > BUDGET:
            raise OSError(errno.ENOSPC, "No space left on device")
        return super().write(data)


@pytest.fixture
def full_disk(monkeypatch):
    """The recorder's files open on the full disk (buffered as ``open`` buffers them)."""
    monkeypatch.setattr(record, "open", lambda path, mode: io.BufferedWriter(_FullDisk(path, "w")), raising=False)


def test_a_replay_onto_a_full_disk_stops_naming_its_output_and_leaves_nothing(full_disk, tmp_path):
    with pytest.raises(ReplayError) as failed:
        replay(LOG, tmp_path / "r.mcap", FuserConfig(), progress=None)
    assert str(failed.value) == f"cannot write {tmp_path / 'r.mcap'}: No space left on device; nothing was kept"
    assert list(tmp_path.iterdir()) == []


def test_a_recording_that_goes_on_says_what_the_full_disk_holds(full_disk, tmp_path):
    """A live recording is not the command's whole product: the loop goes on, records are counted as not written, and
    finishing the file names it and the records safe on it, at least as many as a reader recovers."""
    path = tmp_path / "s.mcap"
    rec = McapRecorder(path, chunk_size=16 * 1024)
    inputs = read_log(LOG).inputs()
    for sample, receive_ns in inputs:
        rec.write_sample(sample, receive_ns)
    assert rec.rejected["write_failed"] > 0
    with pytest.raises(RecordWriteError, match=rf"^cannot write {path}: No space left on device; it holds at least the ([\d,]+) ") as failed:
        rec.close()
    kept = int(re.search(r"at least the ([\d,]+) ", str(failed.value)).group(1).replace(",", ""))
    recovered = read_log(path)
    assert not recovered.complete and kept > 0 and recovered.records >= kept
    assert [s for s, _ in recovered.inputs()] == [s for s, _ in inputs[:recovered.records]]


def test_an_import_onto_a_full_disk_leaves_no_truncated_mcap(full_disk, tmp_path):
    from test_import_dataflash import write_new_log

    from fuser.errors import FuserError
    from fuser.importers import import_log

    log = write_new_log(tmp_path / "flight.BIN")
    with pytest.raises(FuserError, match=rf"^cannot write {tmp_path / 'flight.mcap'}: No space left on device; nothing was kept$"):
        import_log(log.path, tmp_path / "flight.mcap")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["flight.BIN"]


@pytest.mark.skipif(not Path("/dev/full").exists(), reason="/dev/full (every write: ENOSPC) is Linux's")
def test_a_recorder_process_on_a_full_disk_says_so_not_that_it_died(tmp_path):
    """The live recorder (a child process) ended with a traceback and the run said "the recorder process died"; now
    it logs one line and its exit code tells the run why (``write_failed``)."""
    from fuser.record import RecorderProcess

    rec = RecorderProcess("/dev/full")
    for sample, receive_ns in read_log(LOG).inputs()[:100]:
        rec.write_sample(sample, receive_ns)
    assert rec.close() is False and rec.write_failed


def test_a_report_onto_a_full_disk_names_the_file_and_leaves_no_truncated_plot(tmp_path, monkeypatch):
    """It said only "No space left on device" and left a truncated attitude.png."""
    pytest.importorskip("matplotlib")
    from matplotlib.figure import Figure

    from fuser.errors import FuserError
    from fuser.report import write_report

    def fills_the_disk(self, file, **kwargs) -> None:
        Path(file).write_bytes(b"\x89PNG" + bytes(1000))
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(Figure, "savefig", fills_the_disk)
    out = tmp_path / "rep"
    with pytest.raises(FuserError, match=rf"^report: cannot write {out / 'attitude.png'}: No space left on device$"):
        write_report(LOG, out)
    assert list(out.iterdir()) == []


def test_an_import_whose_settings_file_cannot_be_written_says_what_was(tmp_path, monkeypatch):
    from test_import_dataflash import write_new_log

    from fuser.errors import FuserError
    from fuser.importers import import_log

    log = write_new_log(tmp_path / "flight.BIN")

    def fills_the_disk(self, text, *args, **kwargs) -> None:
        self.write_bytes(text.encode()[:10])
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(Path, "write_text", fills_the_disk)
    with pytest.raises(FuserError, match=rf"^cannot write {tmp_path / 'flight.toml'}: No space left on device; "
                                         rf"{tmp_path / 'flight.mcap'} was written, its reference field is \["):
        import_log(log.path, tmp_path / "flight.mcap", config_path=tmp_path / "flight.toml")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["flight.BIN", "flight.mcap"]
    assert read_log(tmp_path / "flight.mcap").complete
