"""Shared fixtures: real pty pairs, the shared recorded logs, and the mapper's kernels compiled.

Property tests (hypothesis) draw the same examples on every run (profile ``repeatable``), so a
new draw cannot fail CI at random; ``pytest --hypothesis-profile=explore`` draws new ones (then
``--hypothesis-seed=N`` repeats a draw)."""

from __future__ import annotations

import pytest
from hypothesis import settings

from serialport.ptys import open_pty
from service.datasets import data_dir

settings.register_profile("repeatable", derandomize=True)
settings.register_profile("explore", derandomize=False)
settings.load_profile("repeatable")


@pytest.fixture
def pty_pair():
    """A raw pty pair: ``.master`` fd for an emulator, ``.path`` for a driver to open."""
    with open_pty() as pair:
        yield pair


@pytest.fixture(scope="session")
def shared_data():
    """The folder of the shared real logs (../shared/data)."""
    return data_dir()



@pytest.fixture(scope="session", autouse=True)
def _kernels_compiled():
    """The mapper's kernels compiled into the disk cache before any test runs. A child service
    (``asrmap run`` on ptys) compiles them in its warm-up before its first status and READY=1; on
    a cold cache (a fresh machine, or the first run after any mapper source changed, see
    ``mapper.jit``) that is 13-18 s, past the waits of the tests that start one. Warm, this costs
    about a second."""
    from mapper.mapper import Mapper

    Mapper()  # the first Mapper of a process runs the warm-up (mapper.warmup)
