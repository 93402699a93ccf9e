"""What ``pcreg view --web`` says of a port it cannot take and of an address it serves on: a privileged port was
said to be "in use" (it was free: only the permission was missing), and ``--bind 127.0.0.2``, an address of this
machine alone, was said to let whoever reaches the machine read "the recording" (a run's review serves no recording)."""

from __future__ import annotations

import errno
import socket

import pytest

from pcreg.errors import InputError
from pcreg.recording.viewer import check_port, loopback, port_free, port_problem


def test_a_privileged_port_is_said_to_be_one_not_in_use(monkeypatch):
    def bind(self, address):
        raise PermissionError(errno.EACCES, "Permission denied")

    monkeypatch.setattr(socket.socket, "bind", bind)  # as for a user without CAP_NET_BIND_SERVICE
    assert not port_free("127.0.0.1", 80)
    with pytest.raises(InputError) as caught:
        check_port("--web-port", 80, "127.0.0.1", "localhost")
    assert str(caught.value).startswith("--web-port 80: a privileged port") and "in use" not in str(caught.value)
    assert "privileged" not in port_problem("127.0.0.1", 50000)  # refused above 1023: not for being privileged


def test_a_port_in_use_is_said_to_be_in_use_under_the_address_given():
    with socket.socket() as held:
        held.bind(("127.0.0.1", 0))
        held.listen()
        port = held.getsockname()[1]
        assert port_problem("127.0.0.1", port, "localhost") == (
            "the port is in use on localhost (choose another, or 0 for any free port)")
    assert port_problem("127.0.0.1", 0) is None


@pytest.mark.parametrize("bind, alone", [("127.0.0.1", True), ("127.0.0.2", True), ("::1", True), ("localhost", True),
                                         ("::ffff:127.0.0.1", True), ("0.0.0.0", False), ("::", False), ("192.168.1.5", False),
                                         ("::ffff:192.168.1.5", False), ("myhost", False)])
def test_only_an_address_of_others_gets_the_note(bind, alone):
    assert loopback(bind) is alone

