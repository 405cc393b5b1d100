"""Shared fixtures: real pty pairs and the shared recorded logs."""

from __future__ import annotations

import pytest

from serialport.ptys import open_pty
from service.datasets import data_dir


@pytest.fixture
def pty_pair():
    """A raw pty pair: ``.master`` fd for an emulator, ``.path`` for a driver to open."""
    with open_pty() as pair:
        yield pair


@pytest.fixture(scope="session")
def shared_data():
    """The folder of the shared real logs (../shared/data)."""
    return data_dir()
