"""The OpenIGTLink tracker mock's frames: per frame, what the tracker reports for each tool
(a noisy observation of its rig body with status ``OK``, or no pose with PlusLib's status
``MISSING`` / ``OUT_OF_VOLUME``), and the messages that go on the wire for a client of a given
header version."""

from __future__ import annotations

import random
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from ...drivers.igtl import wire
from ...sim.rig import SimRig
from ..bodies import BodyObserver, Visibility, Volume
from .model import IGTLFaults

__all__ = ["Entry", "Frame", "FrameSource", "STATUS_OK"]

_IDENTITY = np.eye(4)
#: PlusServer's keep-alive: STATUS code 1 (OK), subcode 0, no error name, empty text
STATUS_OK = (1).to_bytes(2, "big") + bytes(8) + bytes(20) + b"\0"
#: a STRING message body: US-ASCII (IANA 3), length, text
_STRING = (3).to_bytes(2, "big") + (4).to_bytes(2, "big") + b"mock"


@dataclass(frozen=True)
class Entry:
    """One tool in one frame: its ``device`` name, raw timestamp ``stamp``, ``pose``
    (tracker_from_body 4×4 mm; None when not seen) and PlusLib ``status`` text."""

    device: str
    stamp: int
    pose: np.ndarray | None
    status: str


@dataclass
class Frame:
    """One frame: its ``index``, raw ``stamp`` and ``entries``; ``wire(version)`` are its
    messages for a client of that header version (packed once per version)."""

    index: int
    stamp: int
    entries: list[Entry]
    send_invalid: bool
    faults: IGTLFaults
    rng: random.Random
    _packed: dict[int, bytes] | None = None

    def wire(self, version: int) -> bytes:
        """The frame's messages for a client of header ``version``: every seen tool's
        TRANSFORM (status ``TransformStatus`` in version-2 metadata); an unseen tool's as the
        identity with its status only when invalid transforms are sent (PlusServer's
        ``SendValidTransformsOnly`` FALSE); then the extra messages of the faults."""
        if self._packed is None:
            self._packed = {}
        if version not in self._packed:
            out = bytearray()
            for e in self.entries:
                if e.pose is None and not self.send_invalid:
                    continue
                m = _IDENTITY if e.pose is None else e.pose
                out += self._maybe_corrupt(wire.encode_transform(
                    e.device, m, stamp=e.stamp, version=version,
                    metadata={"TransformStatus": e.status}))
            if self.faults.extra_messages:
                out += wire.encode("STATUS", "", STATUS_OK, stamp=self.stamp, version=version)
                out += wire.encode("STRING", "CommandReply", _STRING, stamp=self.stamp,
                                   version=version)
            self._packed[version] = bytes(out)
        return self._packed[version]

    def _maybe_corrupt(self, msg: bytes) -> bytes:
        p = self.faults.crc_error_prob
        if p > 0 and self.rng.random() < p:
            return msg[:50] + bytes(b ^ 0xFF for b in msg[50:58]) + msg[58:]
        return msg


class FrameSource:
    """Frames of the rig's bodies as the tracker reports them.

    ``tools``: body → device name (the bodies sent, in this order); ``volume`` (None:
    unlimited) makes a body with no sphere inside ``OUT_OF_VOLUME`` (some inside: still
    ``OK``, PlusLib has no partial status); ``faults`` draw from ``rng``."""

    def __init__(self, rig: SimRig, tools: Mapping[str, str], volume: Volume | None,
                 faults: IGTLFaults, rng: np.random.Generator, send_invalid: bool) -> None:
        self.tools = dict(tools)
        self.faults = faults
        self.send_invalid = send_invalid
        self._bodies = BodyObserver(rig, volume)
        self._rng = rng
        self._wire_rng = random.Random(int(rng.integers(2**63)))
        self._stale: dict[str, Entry] = {}

    def frame(self, index: int, stamp: int) -> Frame:
        """Frame ``index`` stamped ``stamp`` (raw OpenIGTLink timestamp)."""
        entries = [self._entry(body, dev, stamp) for body, dev in self.tools.items()
                   if body not in self.faults.drop_tools]
        return Frame(index, stamp, entries, self.send_invalid, self.faults, self._wire_rng)

    def _entry(self, body: str, device: str, stamp: int) -> Entry:
        if body in self._stale:
            return self._stale[body]
        f = self.faults
        if f.missing_fraction > 0 and self._rng.random() < f.missing_fraction:
            e = Entry(device, stamp, None, "MISSING")
        else:
            pose = self._bodies.observe(body)
            if self._bodies.visibility(body, pose) == Visibility.OUTSIDE:
                e = Entry(device, stamp, None, "OUT_OF_VOLUME")
            else:
                e = Entry(device, stamp, pose, "OK")
        if body in f.stale_tools:
            self._stale[body] = e
        return e
