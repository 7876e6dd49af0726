"""The batch summary names its columns for what they count.

The column that sums the loop's ``late`` samples and the model's gated measurements (``REJECTION_COUNTERS``) was
headed "rejected", which read as "samples refused" beside "accepted" ("accepted 903, rejected 527"), although the
samples a single ``replay LOG`` reports as refused are the decoder's ("not used: ..."), and gated measurements come
from accepted samples."""

from fuser import batch


def test_the_late_and_gated_column_is_not_called_rejected():
    result = batch.LogResult("a.tlog", "out/a.mcap", True, samples=1430, estimates=500, seconds=1.0, accepted=903, rejected=527)
    head, row, _total = batch.format_summary([result])
    columns = head.split()
    assert "rejected" not in columns
    assert "late+gated" in columns
    # the count sits under its name (numeric columns are right-aligned)
    assert row[:head.index("late+gated") + len("late+gated")].endswith("527")


def test_the_rates_leave_out_the_compiling_and_the_notes_say_so():
    """A worker's first log after installing compiles the filter (about 30 s): its rate is the replay's without it."""
    first = batch.LogResult("a.mcap", "out/a.mcap", True, samples=3000, estimates=1500, seconds=31.0, compile_seconds=30.0)
    second = batch.LogResult("b.mcap", "out/b.mcap", True, samples=3000, estimates=1500, seconds=1.0)
    lines = batch.format_summary([first, second])
    assert [row.split()[5] for row in lines[1:3]] == ["3,000", "3,000"]
    assert "samples/s leave out the 30.0 s spent compiling the filter (the first logs after installing)" in lines
    assert not any("compiling" in line for line in batch.format_summary([second]))


def test_the_90_percent_region_column_shows_the_share_of_estimates_it_held_the_reference():
    scored = batch.LogResult("a.mcap", "out/a.mcap", True, samples=10, estimates=5, seconds=1.0, error_deg=1.5,
                             reference="simulator truth", inside_90=0.874)
    unscored = batch.LogResult("b.mcap", "out/b.mcap", True, samples=10, estimates=5, seconds=1.0)
    head, row, other, _total = batch.format_summary([scored, unscored])
    end = head.index("in 90 % region") + len("in 90 % region")
    assert row[:end].endswith("87 %") and other[:end].endswith("-")
    assert row.endswith("1.50 vs simulator truth")


def test_a_replayed_log_scores_its_90_percent_region(tmp_path):
    """Through a real replay and its streamed score: the hover flight's share, as ``replay`` prints it."""
    from pathlib import Path

    from fuser.config import FuserConfig
    from fuser.report import stream_score

    log = Path(__file__).resolve().parent.parent / "logs" / "sim_hover.mcap"
    result = batch.run_task(batch.LogTask(str(log), str(tmp_path / "h.mcap"), FuserConfig()))
    assert result.ok and result.inside_90 is not None
    assert result.inside_90 == stream_score(tmp_path / "h.mcap", batch.SCORE_SINCE_S).coverage[0.9]
