"""``tmscal stream`` end to end: a mock Polaris (in this process, over loopback TCP) serving the
simulated TMS rig, ``tmscal stream`` in a child process, and OpenIGTLink clients receiving its
TRANSFORM messages: ``pyigtl.OpenIGTLinkClient`` (as 3D Slicer connects) and a lossless reader
built on pyigtl's message parser. The messages are checked against the stored calibration (read
here with PyYAML) and against the sim rig's truth.

Tolerances: the mock's fiducial noise is σ = 0.05 mm per coordinate (its config), so a tool's
pose is within 0.5 mm / 0.5° of the truth; the calibration is QR36 on 200 simulated poses of
the same rig (seed 3), whose coil placement error is a few tenths of a mm: 2 mm bounds the coil
centre in the robot base. OpenIGTLink carries float32 (2e-3 mm at 2,000 mm).
"""

from __future__ import annotations

import re
import signal
import socket
import struct
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import yaml

from tests.rigs import write_config
from tmscal.config import load_config
from tmscal.mocks.launch import start_mock_rig
from tmscal.sim import tms_rig_truth
from tmscal.timing import Deadline

pyigtl = pytest.importorskip("pyigtl")

pytestmark = pytest.mark.e2e

#: the device names docs/streaming.md promises (Slicer's "FromToTo" convention)
NAMES = {"CoilToRobotBase", "CoilToTracker", "MarkerToTracker", "TrackerToRobotBase"}

F32_MM = 5e-3  # float32 on the wire, translations up to ~2,000 mm
F32_ROT = 1e-4  # degrees (float32 rotation entries, ~1e-7 rad)


@pytest.fixture(scope="module")
def calib_file(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """``tmscal solve -o`` of 200 simulated poses (Eq. 14 plan, the paper's noise, seed 3) of
    the mock's rig (the built-in TMS rig truth)."""
    from tmscal.session import make_header, records_from_arrays, write_session
    from tmscal.sim import Noise, simulate

    d = tmp_path_factory.mktemp("stream-calib")
    truth, sim = simulate(200, np.random.default_rng(3), noise=Noise(), truth=tms_rig_truth())
    header = make_header(["marker", "probe"], truth=truth.as_dict())
    write_session(d / "s.jsonl", header,
                  records_from_arrays(sim["A"], sim["marker"], sim["probe"], sim["commanded"]))
    out = d / "calib.yaml"
    r = subprocess.run([sys.executable, "-m", "tmscal.cli", "solve", str(d / "s.jsonl"), "-o",
                        str(out)], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    return out


@pytest.fixture
def polaris(tmp_path: Path):
    """(config path, running mock rig) of configs/mock-polaris.yaml on an ephemeral port."""
    def start(**faults: float):
        cfg = write_config(tmp_path, "mock-polaris.yaml",
                           mock={"clock": "real", "seed": 1,
                                 "noise": {"fiducial_sigma_mm": 0.05},
                                 "tracker": {"model": "spectra", "faults": dict(faults)}})
        mr = start_mock_rig(load_config(cfg), tracker_transport="tcp")
        started.append(mr)
        return cfg, mr
    started: list = []
    yield start
    for mr in started:
        mr.close()


def _start_stream(cfg: Path, calib: Path, tracker: str, *extra: str) -> tuple[subprocess.Popen,
                                                                              int]:
    """``tmscal stream`` in a child process on a free port; returns (process, port) once it
    has said where it listens."""
    proc = subprocess.Popen([sys.executable, "-m", "tmscal.cli", "stream", str(cfg), "--calib",
                             str(calib), "--tracker-port", tracker, "--port", "0", *extra],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    line = proc.stdout.readline()  # type: ignore[union-attr]
    m = re.search(r"OpenIGTLink server on 127\.0\.0\.1:(\d+)", line)
    if m is None:
        proc.kill()
        raise AssertionError(f"stream did not start: {line!r} {proc.communicate()[1]!r}")
    return proc, int(m.group(1))


def _stop(proc: subprocess.Popen) -> tuple[int, str, str]:
    """Ctrl-C (SIGINT) the stream; its exit code and output."""
    proc.send_signal(signal.SIGINT)
    out, err = proc.communicate(timeout=30)
    return proc.returncode, out, err


def _stored_Z(calib: Path) -> np.ndarray:
    return np.asarray(yaml.safe_load(calib.read_text())["Z"], dtype=float)


def _angle_deg(Ra: np.ndarray, Rb: np.ndarray) -> float:
    """The angle between two rotations, from ‖Ra − Rb‖_F = 2√2 · sin(θ/2) (well conditioned at
    small angles, unlike arccos of the trace)."""
    d = np.linalg.norm(Ra - Rb) / (2 * np.sqrt(2))
    return float(np.degrees(2 * np.arcsin(min(1.0, d))))


def _close(a: np.ndarray, b: np.ndarray, mm: float, deg: float) -> bool:
    return (np.linalg.norm(a[:3, 3] - b[:3, 3]) <= mm
            and _angle_deg(a[:3, :3], b[:3, :3]) <= deg)


def _by_time(msgs: list) -> dict[float, dict[str, np.ndarray]]:
    out: dict[float, dict[str, np.ndarray]] = {}
    for m in msgs:
        out.setdefault(m.timestamp, {})[m.device_name] = np.asarray(m.matrix, dtype=float)
    return out


def test_slicer_client_receives_the_coil_through_the_calibration(polaris, calib_file):
    cfg, mr = polaris()
    proc, port = _start_stream(cfg, calib_file, mr.endpoints["tracker"])
    msgs: list = []
    client = pyigtl.OpenIGTLinkClient(host="127.0.0.1", port=port)
    try:
        deadline = Deadline(60.0)
        while len({m.timestamp for m in msgs if m.device_name == "CoilToTracker"}) < 40:
            assert not deadline.expired(), f"few messages after 60 s: {len(msgs)}"
            msgs += client.get_latest_messages()
            time.sleep(0.002)
    finally:   # the stream first: pyigtl's client stops only in a pause between messages
        code, out, err = _stop(proc)
        client.stop()
    assert code == 0, err
    assert re.search(r"stopped: \d+ tracker frames read, [1-9]\d* sent", out), out

    names = {m.device_name for m in msgs}
    assert names == NAMES
    assert all(len(n.encode()) <= 20 for n in names)
    assert {m.message_type for m in msgs} == {"TRANSFORM"}

    Z = _stored_Z(calib_file)
    coil_in_base = mr.rig.true_flange() @ mr.rig.truth.Y  # the flange rests at P0
    pairs = 0
    for frame in _by_time(msgs).values():
        if "TrackerToRobotBase" in frame:
            assert _close(frame["TrackerToRobotBase"], Z, F32_MM, F32_ROT)
        if "CoilToTracker" in frame:
            assert _close(frame["CoilToTracker"], mr.rig.true_body("probe"), 0.5, 0.5)
        if "MarkerToTracker" in frame:
            assert _close(frame["MarkerToTracker"], mr.rig.true_body("marker"), 0.5, 0.5)
        if "CoilToRobotBase" in frame:
            assert _close(frame["CoilToRobotBase"], coil_in_base, 2.0, 0.5)
            if "CoilToTracker" in frame:
                pairs += 1
                assert _close(frame["CoilToRobotBase"], Z @ frame["CoilToTracker"], F32_MM,
                              F32_ROT)
    assert pairs >= 10


def _read_all(port: int, n_messages: int, timeout_s: float = 60.0) -> list:
    """Every message, in order, from a plain socket, parsed by pyigtl's message classes; the
    CRC-64 of every body checked."""
    from pyigtl.messages import CRC64, MessageBase

    sock = socket.create_connection(("127.0.0.1", port), timeout=timeout_s)
    buf = b""
    deadline = Deadline(timeout_s)

    def take(n: int) -> bytes:
        nonlocal buf
        while len(buf) < n:
            assert not deadline.expired(), "stream stalled"
            chunk = sock.recv(65536)
            assert chunk, "stream closed the connection"
            buf += chunk
        out, buf = buf[:n], buf[n:]
        return out

    out = []
    try:
        while len(out) < n_messages:
            head = take(MessageBase.IGTL_HEADER_SIZE)
            fields = MessageBase.parse_header(head)
            body = take(fields["body_size"])
            assert struct.unpack(">Q", head[-8:])[0] == CRC64(body)
            msg = MessageBase.create_message(fields["message_type"])
            msg.unpack(fields, body)
            out.append(msg)
    finally:
        sock.close()
    return out


def test_a_tool_out_of_sight_is_not_sent_for_that_frame(polaris, calib_file):
    cfg, mr = polaris(missing_fraction=0.5)  # each tool missing in half of the frames
    proc, port = _start_stream(cfg, calib_file, mr.endpoints["tracker"], "--rate", "1000")
    try:
        msgs = _read_all(port, 400)
    finally:
        code, _, err = _stop(proc)
    assert code == 0, err
    frames = _by_time(msgs)
    del frames[msgs[-1].timestamp]  # the last frame may be cut short
    assert len(frames) >= 60
    with_coil = [f for f in frames.values() if "CoilToTracker" in f]
    with_marker = [f for f in frames.values() if "MarkerToTracker" in f]
    # Z in every frame; the probe's two transforms together or not at all
    assert all("TrackerToRobotBase" in f for f in frames.values())
    assert all(("CoilToRobotBase" in f) == ("CoilToTracker" in f) for f in frames.values())
    # P(a tool seen in all of 60 frames, or in none) = 2 · 0.5⁶⁰: both cases happen
    assert 0 < len(with_coil) < len(frames)
    assert 0 < len(with_marker) < len(frames)
    for f in with_coil:  # never a placeholder pose for a missing tool
        assert _close(f["CoilToTracker"], mr.rig.true_body("probe"), 0.5, 0.5)


def test_a_host_off_loopback_is_refused_without_allow_remote(polaris, calib_file):
    cfg, mr = polaris()
    r = subprocess.run([sys.executable, "-m", "tmscal.cli", "stream", str(cfg), "--calib",
                        str(calib_file), "--tracker-port", mr.endpoints["tracker"], "--host",
                        "0.0.0.0", "--frames", "1"], capture_output=True, text=True,
                       timeout=60)
    assert r.returncode == 2
    assert "--host" in r.stderr and "--allow-remote" in r.stderr
    assert "OpenIGTLink server" not in r.stdout


def test_only_usable_tools_are_sent_and_z_applies_to_the_probe():
    """``frame_transforms`` on hand-made frames: a tool partly out of the volume, missing or
    out of the volume is left out; the coil in the base is Z · C."""
    from tmscal.calib import Calibration
    from tmscal.drivers.base import ToolState, TrackerFrame
    from tmscal.stream import frame_transforms

    truth = tms_rig_truth()
    cal = Calibration("qr36", 10, X=truth.X, Z=truth.Z, X_raw=truth.X, Z_raw=truth.Z,
                      Y=truth.Y, Y_raw=truth.Y)
    C = np.linalg.inv(truth.Z) @ np.eye(4)
    C[:3, 3] = [10.0, -20.0, -1500.0]
    seen = ToolState(pose=C)
    for bad in (ToolState(pose=C, partially_out_of_volume=True),
                ToolState(pose=C, out_of_volume=True), ToolState(pose=None, missing=True)):
        fr = TrackerFrame(frame=1, host_time=0.0, tools={"marker": seen, "probe": bad})
        assert set(frame_transforms(fr, cal)) == {"MarkerToTracker", "TrackerToRobotBase"}
        fr = TrackerFrame(frame=1, host_time=0.0, tools={"marker": bad, "probe": seen})
        got = frame_transforms(fr, cal)
        assert set(got) == {"CoilToRobotBase", "CoilToTracker", "TrackerToRobotBase"}
        expected = truth.Z[:3, :3] @ C[:3, 3] + truth.Z[:3, 3]
        assert np.allclose(got["CoilToRobotBase"][:3, 3], expected, atol=1e-9)


# --- several clients, each with its own limits (issue 22, item 8) -----------------------------

def _drain_until_closed(sock: socket.socket, guard_s: float) -> bool:
    """Read (and drop) what the server sent until it closes the connection (True) or the
    guard expires with the connection still open (False)."""
    deadline = Deadline(guard_s)
    sock.settimeout(0.5)
    while not deadline.expired():
        try:
            if not sock.recv(1 << 20):
                return True
        except TimeoutError:
            continue
        except ConnectionResetError:
            return True
    return False


def _still_open(sock: socket.socket) -> bool:
    """True when the server has not closed ``sock``: everything it sent so far is read
    without reaching the end of the stream."""
    sock.setblocking(False)
    try:
        while True:
            try:
                if not sock.recv(1 << 20):
                    return False
            except BlockingIOError:
                return True
            except ConnectionResetError:
                return False
    finally:
        sock.setblocking(True)


def test_a_client_that_never_reads_does_not_starve_another(polaris, calib_file):
    """A connects first and never reads; B, connecting after it, receives its frames while A
    is still connected (one client at a time would keep B waiting until A is dropped)."""
    cfg, mr = polaris()
    proc, port = _start_stream(cfg, calib_file, mr.endpoints["tracker"])
    a = socket.create_connection(("127.0.0.1", port), timeout=10)
    try:
        time.sleep(0.5)  # A is the connected client before B arrives
        msgs = _read_all(port, 40, timeout_s=60.0)  # B: ten frames
        assert {m.device_name for m in msgs} == NAMES
        assert _still_open(a), "A was dropped before B was served"
    finally:
        a.close()
        code, out, err = _stop(proc)
    assert code == 0, err


def test_a_client_announcing_a_huge_body_is_closed_and_the_server_keeps_serving(
        polaris, calib_file):
    """A client sends a STRING header announcing a 3 GB body, then keeps sending body bytes:
    the server closes it at the header (it never reads the body), and serves the next
    client. A server that read the body would keep taking the bytes (up to the 256 MB this
    test sends)."""
    cfg, mr = polaris()
    proc, port = _start_stream(cfg, calib_file, mr.endpoints["tracker"])
    c = socket.create_connection(("127.0.0.1", port), timeout=10)
    try:
        head = struct.pack(">H12s20sIIQQ", 1, b"STRING", b"hostile", 0, 0, 3_000_000_000, 0)
        chunk = b"\0" * 65536
        closed, sent = False, 0
        deadline = Deadline(60.0)
        try:
            c.sendall(head)
            while sent < 256 * 2**20 and not deadline.expired():
                c.sendall(chunk)
                sent += len(chunk)
        except (BrokenPipeError, ConnectionResetError):
            closed = True
        closed = closed or _drain_until_closed(c, 30.0)
        assert closed and sent < 256 * 2**20, f"the server took {sent:,} body bytes"
        msgs = _read_all(port, 20, timeout_s=60.0)  # the server still serves
        assert {m.device_name for m in msgs} == NAMES
    finally:
        c.close()
        code, out, err = _stop(proc)
    assert code == 0, err


def test_clients_beyond_the_limit_are_closed_at_once(polaris, calib_file):
    cfg, mr = polaris()
    proc, port = _start_stream(cfg, calib_file, mr.endpoints["tracker"], "--max-clients", "2")
    first = [socket.create_connection(("127.0.0.1", port), timeout=10) for _ in range(2)]
    try:
        for s in first:  # both admitted: each receives frames
            s.settimeout(30)
            assert s.recv(58)
        extra = socket.create_connection(("127.0.0.1", port), timeout=10)
        assert _drain_until_closed(extra, 30.0)
        extra.close()
        assert all(_still_open(s) for s in first)
    finally:
        for s in first:
            s.close()
        code, out, err = _stop(proc)
    assert code == 0, err


# --- the coil through a calibration with a tracker distortion (issue 22, item 4b) -------------

def test_coil_to_robot_base_follows_the_placement_rule_under_a_tracker_scale(calib_file,
                                                                             tmp_path):
    """The mock tracker scales positions by 1.001 (0.1 %) and the calibration says so (its
    distortion D = 1.001 I): CoilToRobotBase is Z applied to the undistorted probe pose
    (positions D⁻¹ t, an isotropic scale leaves rotations; Calibration.placement), not
    Z · C as measured, which is 1.5 mm off at 1.5 m from the tracker."""
    doc = yaml.safe_load(calib_file.read_text())
    doc["distortion"] = {"model": "scale", "matrix": (1.001 * np.eye(3)).tolist(),
                         "scale_percent": 0.1}
    calib = tmp_path / "scaled.yaml"
    calib.write_text(yaml.safe_dump(doc))
    Z = np.asarray(doc["Z"], dtype=float)
    cfg = write_config(tmp_path, "mock-polaris.yaml",
                       mock={"clock": "real", "seed": 1,
                             "noise": {"fiducial_sigma_mm": 0.05, "tracker_scale": 1.001},
                             "tracker": {"model": "spectra"}})
    mr = start_mock_rig(load_config(cfg), tracker_transport="tcp")
    try:
        proc, port = _start_stream(cfg, calib, mr.endpoints["tracker"])
        try:
            msgs = _read_all(port, 200)
        finally:
            code, _, err = _stop(proc)
        coil_in_base = mr.rig.true_flange() @ mr.rig.truth.Y
    finally:
        mr.close()
    assert code == 0, err
    pairs = 0
    for frame in _by_time(msgs).values():
        if "CoilToRobotBase" in frame and "CoilToTracker" in frame:
            pairs += 1
            C = frame["CoilToTracker"].copy()
            assert np.linalg.norm(C[:3, 3]) > 1000  # far enough for 0.1 % to be > 1 mm
            C[:3, 3] /= 1.001
            assert _close(frame["CoilToRobotBase"], Z @ C, F32_MM, F32_ROT)
            assert _close(frame["CoilToRobotBase"], coil_in_base, 2.0, 0.5)
    assert pairs >= 10
