"""A protocol-level OpenIGTLink tracker mock (a PlusServer streaming TRANSFORMs) serving a
:class:`~tmscal.sim.rig.SimRig`.

It speaks OpenIGTLink over TCP on loopback (:meth:`IGTLTrackerMock.start` returns
``host:port``), through the codec the driver uses (:mod:`tmscal.drivers.igtl.wire`, which
packs with pyigtl), and behaves as PlusServer does towards a client (PlusLib,
``vtkPlusOpenIGTLinkServer``): it streams without being asked, to every connected client, one
TRANSFORM per tool per frame, all of a frame with the frame's timestamp (UTC); clients get
header version 1 (``header_version``) until they send a version-2 message, then version 2
with the metadata ``TransformStatus``; ``GET_STATUS`` is answered with ``STATUS`` OK; other
messages are skipped; a client that does not take a frame within 0.5 s is dropped.

What it models (modules of this package):

* :mod:`.frames`: per frame and tool, a noisy observation of the rig body
  (``mocks.bodies``, as the Polaris mock), ``OK``; a body with no marker sphere inside the
  measurement volume is ``OUT_OF_VOLUME`` (some inside: ``OK``; PLUS has no partial status);
  an unseen tool is not sent (PlusServer's default ``SendValidTransformsOnly``) or, with
  ``send_invalid``, sent as the identity with its status;
* :mod:`.model`: faults (:class:`IGTLFaults`): tools missing in a fraction of frames, tools
  never sent, stale tools (re-sent with an old timestamp), corrupted CRCs, extra message
  types, disconnects and garbage bytes after a number of frames; one seeded RNG;
* :mod:`.mock`: the server, one thread that generates and broadcasts frames (PlusServer's
  data sender) and one per connection for what the client sends.

Clocks. On the real-time clock frames go out at ``rate_hz`` (60 Hz), stamped with the wall
time. A streaming protocol cannot offer the Polaris mock's fast clock (a new frame per request)
because nothing in OpenIGTLink tells the server that a client has used a frame, and a driver
must read the stream continuously whatever it does with the frames. So on the fast clock frames
go out at a fixed accelerated rate, ``fast_rate_hz`` (1000 Hz: 100 samples per pose in 0.1 s
at a few percent of one core), stamped ``1/rate_hz`` apart as if at the nominal rate, and
only while a client is connected; :meth:`IGTLTrackerMock.tracker_time_s` (frames generated /
``rate_hz``) is the tracker's virtual time, which the mock rig makes the sim rig's time base
(settling decays as frames go out, not as wall time passes).
"""

from __future__ import annotations

from ..polaris.model import MeasurementVolume
from .mock import IGTLTrackerMock
from .model import IGTLFaults, default_device_name

__all__ = ["IGTLTrackerMock", "IGTLFaults", "MeasurementVolume", "default_device_name"]
