"""A live command whose recorder process dies fails: ``run`` and a paced ``sim`` record in a child process, and a
recording that stopped partway has lost the estimates after it, so the command ends with one line saying so and
exit code 1 (it had gone on and exited 0, with only the recorder's log line to tell)."""

from __future__ import annotations

import os
import signal
import socket
import threading
from pathlib import Path

import pytest

import fuser.cli as cli
import fuser.record as record
from local_net import free_port


class DyingRecorder(record.RecorderProcess):
    """The recorder process, killed 0.3 s after it starts (as by the OOM killer, or a crash in the child)."""

    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.killer = threading.Timer(0.3, os.kill, (self.pid, signal.SIGKILL))
        self.killer.start()


COMMANDS = {
    "run": lambda: ["run", "--mavlink", f"udpin:127.0.0.1:{free_port(socket.SOCK_DGRAM)}", "--no-zenoh", "--duration", "1.5"],
    "sim": lambda: ["sim", "--scenario", "hover", "--speed", "20", "--no-zenoh"],
}


@pytest.mark.parametrize("command", list(COMMANDS))
def test_a_recorder_that_dies_during_the_run_fails_the_command(command: str, tmp_path: Path, monkeypatch, capsys) -> None:
    monkeypatch.setattr(record, "RecorderProcess", DyingRecorder)
    monkeypatch.chdir(tmp_path)
    code = cli.main([*COMMANDS[command](), "-o", "rec.mcap"])
    err = capsys.readouterr().err.splitlines()
    assert code == 1, err
    assert err[-1].startswith("bingham-fuser: the recorder process died during the run: rec.mcap "), err
    assert "Traceback" not in "\n".join(err)
