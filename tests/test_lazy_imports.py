"""What a command that reads no CAN bus imports: not ``dronecan``, whose import parses its DSDL definitions (about
a third of a second of every command's start, measured with ``python -X importtime -c "import fuser.cli"``:
0.68 s before, 0.22 s after). And ``drivers``' names, loaded on first use, are all there."""

from __future__ import annotations

import importlib
import subprocess
import sys

import pytest

import drivers


def test_the_command_line_and_replay_do_not_import_dronecan():
    code = "import sys, fuser.cli, fuser.replay, fuser.live; print('dronecan' in sys.modules, 'can' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], check=True, capture_output=True, text=True).stdout.split()
    assert out == ["False", "False"]


@pytest.mark.parametrize("name", drivers.__all__)
def test_every_public_name_of_drivers_loads(name):
    value = getattr(drivers, name)
    assert value is getattr(importlib.import_module(f"drivers.{drivers._WHERE[name]}"), name)
    assert name in dir(drivers)


def test_an_unknown_name_is_an_attribute_error():
    with pytest.raises(AttributeError, match="no attribute 'Nothing'"):
        drivers.Nothing  # noqa: B018
