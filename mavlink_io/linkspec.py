"""Link addresses in the form MAVProxy and mavutil users already know.

    serial:/dev/ttyAMA0:921600     a serial port (pyserial) at a baud rate
    /dev/ttyACM0:115200            the same, without the prefix
    udpin:0.0.0.0:14550            listen on a UDP port; reply to whoever spoke last
    udpout:192.168.1.10:14550      send to a UDP address (and receive its replies)
    tcp:127.0.0.1:5760             a TCP client
    tcpin:0.0.0.0:5760             a TCP server for one peer at a time

Parsed once, at configuration time, into a frozen LinkSpec.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from mavlink_io.errors import LinkSpecError

LinkKind = Literal["serial", "udpin", "udpout", "tcp", "tcpin"]
_KINDS: tuple[LinkKind, ...] = ("serial", "udpin", "udpout", "tcp", "tcpin")
_DEFAULT_BAUD = 115200


@dataclass(frozen=True)
class LinkSpec:
    kind: LinkKind
    host: str = ""
    port: int = 0
    device: str = ""
    baud: int = 0

    def __str__(self) -> str:
        if self.kind == "serial":
            return f"serial:{self.device}:{self.baud}"
        return f"{self.kind}:{self.host}:{self.port}"

    def describe(self) -> str:
        """What the link does, for a person: "listening on UDP 127.0.0.1:14550"."""
        return {
            "serial": f"serial port {self.device} at {self.baud} baud",
            "udpin": f"listening on UDP {self.host}:{self.port}",
            "udpout": f"sending to UDP {self.host}:{self.port}",
            "tcp": f"connecting to TCP {self.host}:{self.port}",
            "tcpin": f"accepting TCP on {self.host}:{self.port}",
        }[self.kind]


def _port(text: str, url: str) -> int:
    try:
        port = int(text)
    except ValueError:
        raise LinkSpecError(f"link {url!r}: port {text!r} is not a number") from None
    if not 0 <= port <= 65535:
        raise LinkSpecError(f"link {url!r}: port {port} is outside 0..65535")
    return port


def parse_link(url: str) -> LinkSpec:
    """Parse a link address; raises LinkSpecError naming what is wrong."""
    text = url.strip()
    if not text:
        raise LinkSpecError("link address is empty")
    if text.startswith("/") or text.startswith("serial:"):
        rest = text.removeprefix("serial:")
        device, _, baud_text = rest.partition(":")
        if not device.startswith("/"):
            raise LinkSpecError(
                f"link {url!r}: serial device must be an absolute path like /dev/ttyAMA0"
            )
        try:
            baud = int(baud_text) if baud_text else _DEFAULT_BAUD
        except ValueError:
            raise LinkSpecError(f"link {url!r}: baud {baud_text!r} is not a number") from None
        if baud <= 0:
            raise LinkSpecError(f"link {url!r}: baud must be positive")
        return LinkSpec("serial", device=device, baud=baud)
    kind, sep, rest = text.partition(":")
    if not sep or kind not in _KINDS:
        raise LinkSpecError(
            f"link {url!r}: expected one of serial:DEVICE:BAUD, udpin:HOST:PORT, "
            "udpout:HOST:PORT, tcp:HOST:PORT, tcpin:HOST:PORT"
        )
    host, sep, port_text = rest.rpartition(":")
    if not sep or not host:
        raise LinkSpecError(f"link {url!r}: expected {kind}:HOST:PORT")
    port = _port(port_text, url)
    if port == 0 and kind in ("udpout", "tcp"):
        raise LinkSpecError(f"link {url!r}: {kind} needs a port other than 0")
    return LinkSpec(kind, host=host, port=port)
