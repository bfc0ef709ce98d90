"""Vehicle connection strings (fleet.vehicle.urls): parsed, printed back, and in MAVSDK's form."""

from __future__ import annotations

import pytest

from drona_gcs.errors import DronaError
from fleet.vehicle.urls import DEFAULT_BAUD, LinkUrl, LinkUrlError, Scheme, parse_link_url


@pytest.mark.parametrize(("text", "expected"), [
    ("udpin://0.0.0.0:14540", LinkUrl(Scheme.UDPIN, host="0.0.0.0", port=14540)),
    ("udpout://192.168.1.20:14550", LinkUrl(Scheme.UDPOUT, host="192.168.1.20", port=14550)),
    ("tcp://localhost:5760", LinkUrl(Scheme.TCP, host="localhost", port=5760)),
    ("TCP://[::1]:5760", LinkUrl(Scheme.TCP, host="::1", port=5760)),
    ("serial:///dev/ttyUSB0:57600", LinkUrl(Scheme.SERIAL, device="/dev/ttyUSB0", baud=57600)),
    ("serial:///dev/ttyACM0:921600", LinkUrl(Scheme.SERIAL, device="/dev/ttyACM0", baud=921600)),
    ("serial:///dev/serial/by-id/usb-Hex_ProfiCNC_CubeOrange-if00",
     LinkUrl(Scheme.SERIAL, device="/dev/serial/by-id/usb-Hex_ProfiCNC_CubeOrange-if00", baud=DEFAULT_BAUD)),
    ("serial://COM3:115200", LinkUrl(Scheme.SERIAL, device="COM3", baud=115200)),
])
def test_connection_strings_parse(text: str, expected: LinkUrl) -> None:
    assert parse_link_url(text) == expected
    assert parse_link_url(str(expected)) == expected


@pytest.mark.parametrize(("text", "expected"), [
    ("udpin://0.0.0.0:14540", "udpin://0.0.0.0:14540"),
    ("udpout://192.168.1.20:14550", "udpout://192.168.1.20:14550"),
    ("tcp://[::1]:5760", "tcpout://[::1]:5760"),
    ("serial:///dev/ttyUSB0", "serial:///dev/ttyUSB0:57600"),
])
def test_connection_strings_in_mavsdk_form(text: str, expected: str) -> None:
    try:
        from fleet.vehicle.mavsdk_link import mavsdk_url
    except Exception as exc:  # no package, or its native library does not load here
        pytest.skip(f"MAVSDK cannot run here: {type(exc).__name__}: {exc}")
    assert mavsdk_url(parse_link_url(text)) == expected


@pytest.mark.parametrize(("text", "problem"), [
    ("127.0.0.1:14540", "starts with a scheme"),
    ("udp://127.0.0.1:14540", "unknown scheme 'udp'"),
    ("udpin://:14540", "host is missing"),
    ("tcp://127.0.0.1", "port is missing"),
    ("tcp://127.0.0.1:http", "port must be a number"),
    ("tcp://127.0.0.1:70000", "port must be a number"),
    ("tcp://127.0.0.1:0", "port must be a number"),
    ("tcp://127.0.0.1:5760/x", "nothing after the port"),
    ("udpout://0.0.0.0:14550", "listening address"),
    ("tcp://user@host:5760", "user names"),
    ("serial://", "device is missing"),
    ("serial:///dev/ttyUSB0:57601", "unsupported baud rate '57601'"),
    ("serial:///dev/ttyUSB0:fast", "unsupported baud rate 'fast'"),
])
def test_bad_connection_strings_say_what_is_wrong(text: str, problem: str) -> None:
    with pytest.raises(LinkUrlError, match=problem) as error:
        parse_link_url(text)
    assert isinstance(error.value, DronaError) and isinstance(error.value, ValueError)
    assert repr(text) in str(error.value)
