"""Progress bars: percentage, count, rate and time left on a terminal; nothing at all elsewhere."""

from __future__ import annotations

import io
import re
from pathlib import Path

import numpy as np
from mcap.reader import make_reader

from fuser.config import FuserConfig
from fuser.importers import ImuStream, SensorData, write_mcap
from fuser.progress import progress_bar
from fuser.record import INPUT_TOPICS
from fuser.replay import replay

LOGS = Path(__file__).resolve().parent.parent / "logs"


class Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def final_state(text: str) -> str:
    """The bar as last drawn (tqdm redraws the line after carriage returns)."""
    return text.replace("\r", "\n").strip().splitlines()[-1]


def test_no_terminal_no_bar_and_the_items_untouched() -> None:
    items = [3, 1, 2]
    pipe = io.StringIO()
    assert progress_bar(items, 3, "x", " items", pipe) is items
    assert progress_bar(items, 3, "x", " items", None) is items
    assert pipe.getvalue() == ""


def test_a_terminal_sees_percentage_count_rate_and_time_left() -> None:
    term = Terminal()
    assert list(progress_bar(iter(range(500)), 500, "replay", " samples", term)) == list(range(500))
    last = final_state(term.getvalue())
    assert last.startswith("replay: 100%") and "500/500" in last
    assert re.search(r"\[\d\d:\d\d<\d\d:\d\d, +[\d.]+ samples/s\]", last), last  # elapsed < left, rate


def test_unknown_total_shows_count_and_rate() -> None:
    term = Terminal()
    list(progress_bar(iter(range(70)), None, "replay", " samples", term))
    last = final_state(term.getvalue())
    assert "70 samples" in last and "%" not in last and "samples/s" in last


def test_replay_draws_the_bar_over_every_input(tmp_path: Path) -> None:
    log = LOGS / "sim_hover.mcap"
    with open(log, "rb") as f:
        inputs = sum(1 for _, c, _ in make_reader(f).iter_messages() if c.topic in INPUT_TOPICS)
    term = Terminal()
    summary = replay(log, tmp_path / "out.mcap", FuserConfig(), progress=term)
    last = final_state(term.getvalue())
    assert summary.samples == inputs
    assert last.startswith("replay: 100%") and f"{inputs}/{inputs}" in last


def test_import_draws_the_bar_over_every_message(tmp_path: Path) -> None:
    n, m = 300, 40
    t = np.arange(n, dtype=np.int64) * 5_000_000 + 1_000_000_000
    data = SensorData(
        imus=[ImuStream(0, t, np.zeros((n, 3)), np.tile([0.0, 0.0, -9.81], (n, 1)), None)],
        ref_t_ns=t[:: n // m][:m], ref_q=np.tile([1.0, 0.0, 0.0, 0.0], (m, 1)), reference="EKF2 (test)", attribution="test",
        source="test", mag_field_ned_gauss=(0.21, 0.0, 0.43), attitude_stream=True,
    )
    term = Terminal()
    summary = write_mcap(data, tmp_path / "out.mcap", progress=term)
    assert (summary.imu, summary.attitude) == (n, m)
    last = final_state(term.getvalue())
    assert last.startswith("import: 100%") and f"{n + m}/{n + m}" in last
