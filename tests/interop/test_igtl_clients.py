"""OpenIGTLink interop, both ways, with pyigtl's UNMODIFIED client and server:

* pyigtl's ``OpenIGTLinkClient`` reads our OpenIGTLink tracker mock (as it would read a
  PlusServer): the TRANSFORMs it gets are the sim rig's poses;
* our driver reads pyigtl's ``OpenIGTLinkServer`` streaming TRANSFORMs (a third-party
  source that is not a PlusServer: version-1 messages, no status, its own timestamps).

pyigtl's server installs SIGINT/SIGTERM handlers and threads that outlive it, so it runs in a
forked child process. Poses are 4×4 mm.
"""

from __future__ import annotations

import multiprocessing as mp
import time

import numpy as np
import pytest
from pyigtl import OpenIGTLinkClient, OpenIGTLinkServer, TransformMessage

from tmscal.drivers.igtl.tracker import IGTLTracker
from tmscal.geometry import make_pose, rotation_angle
from tmscal.mocks.clock import FAST
from tmscal.mocks.igtl import IGTLTrackerMock
from tmscal.sim.rig import TMS_RIG_P0, Noise, SimRig, tms_rig_truth

pytestmark = pytest.mark.interop

POS_TOL_MM = 0.5
ROT_TOL_RAD = np.radians(0.5)


def test_pyigtl_client_reads_the_mock() -> None:
    rig = SimRig(tms_rig_truth(), noise=Noise(fiducial_sigma_mm=0.05),
                 rng=np.random.default_rng(2), start=TMS_RIG_P0)
    # pyigtl's client checks its stop flag only between bursts of messages, and the mock on
    # the fast clock never pauses: the mock closes first, then the client stops
    client = None
    try:
        with IGTLTrackerMock(rig, port=0, clock=FAST) as m:
            client = OpenIGTLinkClient(host="127.0.0.1", port=m.port)
            got = {dev: client.wait_for_message(dev, timeout=10)
                   for dev in ("MarkerToTracker", "ProbeToTracker")}
    finally:
        if client is not None:
            client.stop()
    for dev, body in (("MarkerToTracker", "marker"), ("ProbeToTracker", "probe")):
        msg = got[dev]
        assert msg is not None, f"pyigtl got no {dev}"
        assert msg.message_type == "TRANSFORM" and msg.device_name == dev
        true = rig.true_body(body)
        assert np.linalg.norm(msg.matrix[:3, 3] - true[:3, 3]) < POS_TOL_MM
        assert rotation_angle(true[:3, :3].T @ np.asarray(msg.matrix)[:3, :3]) < ROT_TOL_RAD


#: what the pyigtl server streams: device name → pose (tracker_from_tool, mm)
POSES = {"MarkerToTracker": make_pose(np.eye(3), [9.0, 50.0, -1513.0]),
         "ProbeToTracker": make_pose([[0, -1, 0], [1, 0, 0], [0, 0, 1]], [0.0, 0.0, -1500.0])}


def _pyigtl_source(conn, stop) -> None:  # runs in the child process
    server = OpenIGTLinkServer(port=0, local_server=True)
    conn.send(server.server_address[1])
    deadline = time.monotonic() + 60
    while not stop.is_set() and time.monotonic() < deadline:   # bounded
        if server.is_connected():
            stamp = time.time()   # one timestamp per frame, as PlusServer does
            for dev, pose in POSES.items():
                server.send_message(TransformMessage(pose, timestamp=stamp, device_name=dev),
                                    wait=False)
        time.sleep(1 / 60)
    server.stop()


def test_the_driver_reads_pyigtls_server() -> None:
    ctx = mp.get_context("fork")
    conn, child = ctx.Pipe()
    stop = ctx.Event()
    proc = ctx.Process(target=_pyigtl_source, args=(child, stop), daemon=True)
    proc.start()
    try:
        assert conn.poll(20), "the pyigtl server did not start"
        port = conn.recv()
        tools = {"marker": "MarkerToTracker", "probe": "ProbeToTracker"}
        with IGTLTracker("127.0.0.1", tools, port=port, timeout_s=5.0) as t:
            frames = list(t.distinct_frames(10, timeout_s=30))
            ident = t.identity()
    finally:
        stop.set()
        proc.join(10)
        if proc.is_alive():  # pragma: no cover
            proc.kill()
    assert ident["header_version"] == 1 and not ident["transform_status"]
    numbers = [f.frame for f in frames]
    assert all(b > a for a, b in zip(numbers, numbers[1:]))
    complete = [f for f in frames if all(s.usable for s in f.tools.values())]
    assert len(complete) >= 8   # a frame may be cut by the client connecting mid-frame
    for fr in complete:
        for tool, dev in tools.items():
            np.testing.assert_allclose(fr.pose(tool), POSES[dev], atol=1e-3)
