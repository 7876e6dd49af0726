"""``replay LOG.bin`` (and a batch of such logs) says what the import's decoder refused, as ``import`` does.

Every imported sample travels through MAVLink and the project's decoder, which refuses what it cannot use (a
magnetometer reading beyond its range, a NaN velocity, a time that repeats or runs back). ``import`` prints those
refusals ("decoder refused"); ``replay LOG.bin`` and the batch's summary left them out, so samples refused there
were gone without a count: a two-boot log lost half its IMU samples as ``duplicate`` that way, exit 0.
"""

from __future__ import annotations

from pathlib import Path

from fuser.batch import run_batch
from fuser.config import FuserConfig
from fuser.replay import replay

from test_import_damaged import _dataflash

REFUSED = {"mag_out_of_range": 1, "non_finite": 1}
"""What the decoder refuses of ``_dataflash``'s log: its 32.8-gauss reading's IMU sample and its NaN GPS speed
(``test_a_damaged_dataflash_log_imports_the_rest_and_counts_what_it_left_out``)."""


def test_replaying_a_log_through_import_counts_what_the_decoder_refused(tmp_path: Path) -> None:
    _dataflash(tmp_path / "damaged.bin")
    summary = replay(tmp_path / "damaged.bin", tmp_path / "out.mcap", FuserConfig(), progress=None)
    assert summary.imported == {"time_out_of_range_IMU": 1, **REFUSED}


def test_a_batch_counts_what_the_decoder_refused(tmp_path: Path) -> None:
    _dataflash(tmp_path / "damaged.bin")
    (result,) = run_batch([tmp_path / "damaged.bin"], tmp_path / "out", FuserConfig(), jobs=1)
    assert result.ok and result.not_imported == {"time_out_of_range_IMU": 1, **REFUSED}
