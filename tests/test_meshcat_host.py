"""Meshcat listens on this machine only unless asked otherwise.

The bound address is tested by connecting: on 127.0.0.1 the server must answer, on
this machine's non-loopback addresses it must refuse; a server opened with host "*"
is the positive control (it answers there), so the check can tell the two apart.
"""

import socket
import warnings

import pytest

from drake_estop.cli import main
from drake_estop.systems.visualization import is_loopback_host, make_meshcat


def _non_loopback_ipv4():
    """This machine's IPv4 addresses other than 127.0.0.0/8 (a UDP socket sends nothing)."""
    found = set()
    try:
        found.update(info[4][0] for info in socket.getaddrinfo(socket.gethostname(), None, socket.AF_INET))
    except socket.gaierror:
        pass
    for target in ("10.255.255.255", "192.0.2.1", "198.51.100.1"):  # private / documentation nets
        probe = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            probe.connect((target, 9))  # picks the outgoing interface; a UDP connect sends nothing
            found.add(probe.getsockname()[0])
        except OSError:
            pass
        finally:
            probe.close()
    return sorted(a for a in found if not a.startswith("127.") and a != "0.0.0.0")


ADDRESSES = _non_loopback_ipv4()


def _answers(address, port):
    connection = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    connection.settimeout(2.0)
    try:
        connection.connect((address, port))
        return True
    except OSError:
        return False
    finally:
        connection.close()


def test_default_listens_on_loopback_only():
    if not ADDRESSES:
        pytest.skip("this machine has no non-loopback IPv4 address to probe")
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # the default must not warn
        meshcat = make_meshcat()
    assert meshcat.web_url().startswith("http://localhost:")
    assert _answers("127.0.0.1", meshcat.port())
    for address in ADDRESSES:
        assert not _answers(address, meshcat.port()), f"Meshcat answers on {address}"


def test_all_interfaces_on_request_with_a_warning():
    if not ADDRESSES:
        pytest.skip("this machine has no non-loopback IPv4 address to probe")
    with pytest.warns(UserWarning, match="press its emergency-stop button"):
        meshcat = make_meshcat(host="*")
    assert _answers(ADDRESSES[0], meshcat.port())  # the control: this check sees an exposed server


@pytest.mark.parametrize("host, loopback", [("localhost", True), ("127.0.0.1", True), ("::1", True),
                                            ("*", False), ("0.0.0.0", False), ("192.0.2.2", False)])
def test_loopback_hosts(host, loopback):
    assert is_loopback_host(host) is loopback


def test_bad_host_is_named():
    with pytest.raises(ValueError, match="host must be"):
        make_meshcat(host="")


def test_meshcat_host_option_needs_meshcat(capsys):
    assert main(["simulate", "--kinematic", "--meshcat-host", "*"]) == 2
    assert "meshcat_host needs --meshcat" in capsys.readouterr().err
