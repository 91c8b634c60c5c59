"""m6p: talk to the M6P digital twin (m6p-twin) from Python.

- :mod:`m6p.csp`: CSP 1.4 on the wire (header, CRC-32C, KISS, the ZMQ hub's messages);
- :mod:`m6p.links`: KISS over TCP and libcsp 1.4's ZMQ hub;
- :mod:`m6p.node`: a CSP node: requests, ICD commands by name, servers on ports;
- :mod:`m6p.icd`: the ICD as data (``m6p-twin icd --json``): typed encoding and decoding;
- :mod:`m6p.session`: the PC's payload data sessions, from the payload and the ground;
- :mod:`m6p.twin`: start and stop a twin;
- :mod:`m6p.pytest_plugin`: the fixtures ``twin``, ``ground`` and ``payload``.
"""

from .csp import Header, Packet, crc32c
from .icd import Icd, IcdError, Reply
from .links import KissTcp, LinkClosed, ZmqHub
from .node import CspNode, CspTimeout
from .session import Payload, Session, counter_frames
from .twin import Twin, TwinError, find_binary

__version__ = "0.1.0"

__all__ = [
    "CspNode",
    "CspTimeout",
    "Header",
    "Icd",
    "IcdError",
    "KissTcp",
    "LinkClosed",
    "Packet",
    "Payload",
    "Reply",
    "Session",
    "Twin",
    "TwinError",
    "ZmqHub",
    "counter_frames",
    "crc32c",
    "find_binary",
]
