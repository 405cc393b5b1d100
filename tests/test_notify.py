"""sd_notify: one datagram per call to a real AF_UNIX socket, path or abstract."""

from __future__ import annotations

import os
import socket
import time
import uuid

import pytest

from service.notify import Notifier, watchdog_interval


@pytest.fixture
def listener(tmp_path):
    s = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    path = str(tmp_path / "notify")
    s.bind(path)
    s.settimeout(1.0)
    yield s, path
    s.close()


def test_ready_with_status_is_one_datagram(listener):
    sock, path = listener
    n = Notifier(environ={"NOTIFY_SOCKET": path})
    assert n.ready("mapping")
    assert sock.recv(4096) == b"READY=1\nSTATUS=mapping"
    n.close()


def test_watchdog_and_stopping(listener):
    sock, path = listener
    n = Notifier(environ={"NOTIFY_SOCKET": path})
    n.watchdog()
    n.stopping()
    assert [sock.recv(4096), sock.recv(4096)] == [b"WATCHDOG=1", b"STOPPING=1"]


def test_abstract_namespace_socket():
    name = f"asrmap-test-{uuid.uuid4().hex}"
    s = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    s.bind("\0" + name)
    s.settimeout(1.0)
    try:
        assert Notifier(environ={"NOTIFY_SOCKET": "@" + name}).status("line1\nline2")
        assert s.recv(4096) == b"STATUS=line1 line2"
    finally:
        s.close()


def test_without_notify_socket_nothing_is_sent():
    n = Notifier(environ={})
    assert not n.enabled and not n.ready() and not n.watchdog()


def test_a_vanished_socket_is_logged_not_raised(tmp_path, caplog):
    assert not Notifier(environ={"NOTIFY_SOCKET": str(tmp_path / "gone")}).ready()
    assert "sd_notify" in caplog.text


def test_watchdog_interval_from_environment():
    assert watchdog_interval({"WATCHDOG_USEC": "10000000"}) == 10.0
    assert watchdog_interval({"WATCHDOG_USEC": "10000000", "WATCHDOG_PID": str(os.getpid())}) == 10.0
    assert watchdog_interval({"WATCHDOG_USEC": "10000000", "WATCHDOG_PID": "1"}) is None
    assert watchdog_interval({}) is None and watchdog_interval({"WATCHDOG_USEC": "x"}) is None


def test_a_receiver_that_does_not_read_never_blocks_the_sender(listener):
    _, path = listener
    n = Notifier(environ={"NOTIFY_SOCKET": path})
    t = time.monotonic()
    sent = [n.status("x" * 1000) for _ in range(5000)]
    assert time.monotonic() - t < 2.0 and not all(sent) and n.dropped == sent.count(False)
