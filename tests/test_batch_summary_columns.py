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
