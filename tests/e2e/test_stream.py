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

from tests.rigs import TOOLS_DIR, write_config
from tmscal.config import load_config
from tmscal.mocks.launch import start_mock_rig
from tmscal.sim import tms_rig_truth
from tmscal.timing import Deadline

pyigtl = pytest.importorskip("pyigtl")

pytestmark = pytest.mark.e2e

#: the device names docs/streaming.md promises (Slicer's "FromToTo" convention)
NAMES = {"CoilToRobotBase", "CoilToTracker", "ProbeToTracker", "MarkerToTracker",
         "TrackerToRobotBase"}

F32_MM = 5e-3  # float32 on the wire, translations up to ~2,000 mm
F32_ROT = 1e-4  # degrees (float32 rotation entries, ~1e-7 rad)
#: B · X⁻¹ · Y computed from the float32 B a client receives, against the float32 coil sent
#: (computed from the tracker's float64 B): two roundings of ~1,500 mm translations (2⁻²⁴
#: relative each, 1e-4 mm) and of B's rotation entries times the ~55 mm marker → coil offset
ON_WIRE_MM = 1e-3


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
    """(config path, running mock rig) of configs/mock-polaris.yaml on an ephemeral port;
    ``tools`` replaces its tracker's tools (the mock then serves only those)."""
    def start(tools: dict[str, str] | None = None, sigma_mm: float = 0.05, **faults: float):
        changes = {} if tools is None else {"tracker": {"tools": tools}}
        cfg = write_config(tmp_path, "mock-polaris.yaml",
                           mock={"clock": "real", "seed": 1,
                                 "noise": {"fiducial_sigma_mm": sigma_mm},
                                 "tracker": {"model": "spectra", "faults": dict(faults)}},
                           **changes)
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


def _stored_coil_on_marker(calib: Path) -> np.ndarray:
    """marker ← coil, X⁻¹ · Y of the calibration file's X and Y (read with PyYAML)."""
    doc = yaml.safe_load(calib.read_text())
    return np.linalg.inv(np.asarray(doc["X"], dtype=float)) @ np.asarray(doc["Y"], dtype=float)


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
    offset = _stored_coil_on_marker(calib_file)
    coil_in_base = mr.rig.true_flange() @ mr.rig.truth.Y  # the flange rests at P0
    pairs = 0
    for frame in _by_time(msgs).values():
        if "TrackerToRobotBase" in frame:
            assert _close(frame["TrackerToRobotBase"], Z, F32_MM, F32_ROT)
        if "ProbeToTracker" in frame:
            assert _close(frame["ProbeToTracker"], mr.rig.true_body("probe"), 0.5, 0.5)
        if "MarkerToTracker" in frame:
            assert _close(frame["MarkerToTracker"], mr.rig.true_body("marker"), 0.5, 0.5)
        # the coil from the marker, with both tools seen (docs/streaming.md)
        assert ("CoilToTracker" in frame) == ("MarkerToTracker" in frame)
        if "CoilToTracker" in frame:
            assert _close(frame["CoilToTracker"], frame["MarkerToTracker"] @ offset, F32_MM,
                          F32_ROT)
            assert _close(frame["CoilToTracker"], mr.rig.true_body("probe"), 1.0, 0.5)
        if "CoilToRobotBase" in frame:
            assert _close(frame["CoilToRobotBase"], coil_in_base, 2.0, 0.5)
            if "CoilToTracker" in frame:
                pairs += 1
                assert _close(frame["CoilToRobotBase"], Z @ frame["CoilToTracker"], F32_MM,
                              F32_ROT)
    assert pairs >= 10


def _receive(port: int, frames: int, name: str) -> list:
    """Messages a ``pyigtl.OpenIGTLinkClient`` receives (as 3D Slicer connects) until it has
    seen ``frames`` distinct frames carrying ``name``."""
    msgs: list = []
    client = pyigtl.OpenIGTLinkClient(host="127.0.0.1", port=port)
    try:
        deadline = Deadline(60.0)
        while len({m.timestamp for m in msgs if m.device_name == name}) < frames:
            assert not deadline.expired(), f"few messages after 60 s: {len(msgs)}"
            msgs += client.get_latest_messages()
            time.sleep(0.002)
    finally:
        client.stop()
    return msgs


def test_the_coil_from_the_marker_alone_with_the_probe_removed(polaris, calib_file):
    """The clinical set-up: the probe (a calibration jig) is gone and the config tracks only
    the marker (so does the mock). CoilToTracker is B · X⁻¹ · Y of the MarkerToTracker of the
    same frame and the calibration file's X, Y (PyYAML); CoilToRobotBase is Z of it; both
    where the sim rig's truth puts the coil; nothing is said about a missing probe."""
    cfg, mr = polaris(tools={"marker": str(TOOLS_DIR / "marker-8700340.rom")})
    proc, port = _start_stream(cfg, calib_file, mr.endpoints["tracker"])
    try:
        msgs = _receive(port, 40, "CoilToTracker")
    finally:
        code, out, err = _stop(proc)
    assert code == 0, err
    assert "coil: CoilToTracker = B · X⁻¹ · Y from the marker" in err
    assert "not sent" not in out + err and "ProbeToTracker" not in err
    assert {m.device_name for m in msgs} == NAMES - {"ProbeToTracker"}
    Z, offset = _stored_Z(calib_file), _stored_coil_on_marker(calib_file)
    coil_in_base = mr.rig.true_flange() @ mr.rig.truth.Y  # the flange rests at P0
    frames = [f for f in _by_time(msgs).values() if "CoilToTracker" in f]
    assert len(frames) >= 40
    for f in frames:
        B, coil = f["MarkerToTracker"], f["CoilToTracker"]
        assert np.linalg.norm(coil[:3, 3] - (B @ offset)[:3, 3]) <= ON_WIRE_MM
        assert _close(coil, B @ offset, ON_WIRE_MM, F32_ROT)
        assert _close(f["CoilToRobotBase"], Z @ coil, F32_MM, F32_ROT)
        assert _close(coil, mr.rig.true_body("probe"), 1.0, 0.5)
        assert _close(f["CoilToRobotBase"], coil_in_base, 2.0, 0.5)


def test_a_marker_only_calibration_says_once_that_it_has_no_coil(polaris, calib_file,
                                                                 tmp_path):
    """A calibration without Y on the marker-only config: the coil cannot be derived, which
    the stream says once at start; it streams the marker and Z."""
    doc = yaml.safe_load(calib_file.read_text())
    for m in (doc, doc["raw"]):
        m.pop("Y")
    calib = tmp_path / "marker-only.yaml"
    calib.write_text(yaml.safe_dump(doc))
    cfg, mr = polaris(tools={"marker": str(TOOLS_DIR / "marker-8700340.rom")})
    proc, port = _start_stream(cfg, calib, mr.endpoints["tracker"])
    try:
        msgs = _read_all(port, 20)
    finally:
        code, out, err = _stop(proc)
    assert code == 0, err
    assert err.count("cannot be derived from the marker") == 1, err
    assert {m.device_name for m in msgs} == {"MarkerToTracker", "TrackerToRobotBase"}


_CROSSCHECK = re.compile(r"cross-check, probe vs marker-derived coil over (\d+) frames: mean "
                         r"([\d.]+) mm ([\d.]+)°, max ([\d.]+) mm ([\d.]+)°")


def _crosscheck(cfg: Path, calib: Path, tracker: str, frames: int = 90) -> tuple[int, float,
                                                                                   float]:
    """(frames, mean mm, mean degrees) of the cross-check ``tmscal stream --frames`` prints
    when it stops."""
    r = subprocess.run([sys.executable, "-m", "tmscal.cli", "stream", str(cfg), "--calib",
                        str(calib), "--tracker-port", tracker, "--port", "0", "--frames",
                        str(frames)], capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    assert "cross-checked" in r.stderr  # said once at start
    out = r.stdout
    m = _CROSSCHECK.search(out)
    assert m, out
    n, mm, deg, max_mm, max_deg = int(m[1]), *map(float, m.groups()[1:])
    assert mm <= max_mm and deg <= max_deg
    return n, mm, deg


def _wrong_y(calib: Path, T: np.ndarray, out: Path) -> Path:
    """A copy of the calibration file whose Y (and raw Y) is off by T: Y · T."""
    doc = yaml.safe_load(calib.read_text())
    doc["Y"] = (np.asarray(doc["Y"], dtype=float) @ T).tolist()
    doc["raw"]["Y"] = (np.asarray(doc["raw"]["Y"], dtype=float) @ T).tolist()
    out.write_text(yaml.safe_dump(doc))
    return out


def test_the_probe_cross_checks_the_marker_derived_coil(polaris, calib_file, tmp_path):
    """Both tools seen: the reported difference between the probe-measured coil and the
    marker-derived one is small: the mock's noise, beside the calibration's own error on
    marker ← coil (tenths of a mm and degree at most). With the calibration's Y wrong by a
    known offset T (3 mm along the coil's y, 2° about its z) it grows to that offset, to
    within the difference with the right Y (the triangle inequality, frame by frame)."""
    from tmscal.geometry import make_pose, rot_z
    from tmscal.stream import coil_difference

    cfg, mr = polaris()
    n, mm, deg = _crosscheck(cfg, calib_file, mr.endpoints["tracker"])
    assert n == 90  # every frame saw both tools
    B = mr.rig.true_body("marker")
    own_mm, own_deg = coil_difference(B @ np.linalg.inv(mr.rig.truth.X) @ mr.rig.truth.Y,
                                      B @ _stored_coil_on_marker(calib_file))
    assert mm < own_mm + 0.25 and deg < own_deg + 0.25, (mm, deg, own_mm, own_deg)

    T = make_pose(rot_z(np.radians(2.0)), [0.0, 3.0, 0.0])
    wrong = _wrong_y(calib_file, T, tmp_path / "wrong-y.yaml")
    n2, mm2, deg2 = _crosscheck(cfg, wrong, mr.endpoints["tracker"])
    assert n2 == 90
    assert abs(mm2 - 3.0) <= mm + 0.05, (mm2, mm)
    assert abs(deg2 - 2.0) <= deg + 0.05, (deg2, deg)


def test_without_noise_the_cross_check_is_the_calibration_s_own_error(polaris, calib_file,
                                                                      tmp_path):
    """A noise-free mock: the reported difference is exactly (to the 3 decimals printed,
    and the float32 of NDI's BX replies) the difference between the true coil and the one
    the calibration puts on the true marker, with the right Y and with Y off by T."""
    from tmscal.geometry import make_pose, rot_z
    from tmscal.stream import coil_difference

    cfg, mr = polaris(sigma_mm=0.0)
    truth = mr.rig.truth
    B, C = mr.rig.true_body("marker"), mr.rig.true_body("probe")
    T = make_pose(rot_z(np.radians(2.0)), [0.0, 3.0, 0.0])
    for calib in (calib_file, _wrong_y(calib_file, T, tmp_path / "wrong-y.yaml")):
        _, mm, deg = _crosscheck(cfg, calib, mr.endpoints["tracker"], frames=20)
        want_mm, want_deg = coil_difference(C, B @ _stored_coil_on_marker(calib))
        assert mm == pytest.approx(want_mm, abs=2e-3)
        assert deg == pytest.approx(want_deg, abs=2e-3)
    assert np.allclose(C, B @ np.linalg.inv(truth.X) @ truth.Y)  # the truth the rig serves
    assert want_mm == pytest.approx(3.0, abs=0.05) and want_deg == pytest.approx(2.0, abs=0.05)


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
    with_probe = [f for f in frames.values() if "ProbeToTracker" in f]
    with_marker = [f for f in frames.values() if "MarkerToTracker" in f]
    # Z in every frame; the coil's two transforms with the marker they come from, or not at
    # all (the probe has no part in them)
    assert all("TrackerToRobotBase" in f for f in frames.values())
    assert all(("CoilToRobotBase" in f) == ("CoilToTracker" in f) == ("MarkerToTracker" in f)
               for f in frames.values())
    # P(a tool seen in all of 60 frames, or in none) = 2 · 0.5⁶⁰: both cases happen
    assert 0 < len(with_probe) < len(frames)
    assert 0 < len(with_marker) < len(frames)
    # and the coil is sent in frames without the probe
    assert any("CoilToTracker" in f and "ProbeToTracker" not in f for f in frames.values())
    for f in with_probe:  # never a placeholder pose for a missing tool
        assert _close(f["ProbeToTracker"], mr.rig.true_body("probe"), 0.5, 0.5)
    for f in with_marker:
        assert _close(f["CoilToTracker"], mr.rig.true_body("probe"), 1.0, 0.5)


def test_a_host_off_loopback_is_refused_without_allow_remote(polaris, calib_file):
    cfg, mr = polaris()
    r = subprocess.run([sys.executable, "-m", "tmscal.cli", "stream", str(cfg), "--calib",
                        str(calib_file), "--tracker-port", mr.endpoints["tracker"], "--host",
                        "0.0.0.0", "--frames", "1"], capture_output=True, text=True,
                       timeout=60)
    assert r.returncode == 2
    assert "--host" in r.stderr and "--allow-remote" in r.stderr
    assert "OpenIGTLink server" not in r.stdout


def test_only_usable_tools_are_sent_and_z_applies_to_the_coil():
    """``frame_transforms`` on hand-made frames: a tool partly out of the volume, missing or
    out of the volume is left out, and so is the coil derived from it; the coil comes from
    the marker (B · X⁻¹ · Y), or from the probe when the stream's source is the probe; the
    coil in the base is Z · coil."""
    from tmscal.calib import Calibration
    from tmscal.drivers.base import ToolState, TrackerFrame
    from tmscal.stream import frame_transforms

    truth = tms_rig_truth()
    cal = Calibration("qr36", 10, X=truth.X, Z=truth.Z, X_raw=truth.X, Z_raw=truth.Z,
                      Y=truth.Y, Y_raw=truth.Y)
    P = np.linalg.inv(truth.Z) @ np.eye(4)
    P[:3, 3] = [10.0, -20.0, -1500.0]
    seen = ToolState(pose=P)
    coil_on_marker = P @ np.linalg.inv(truth.X) @ truth.Y
    for bad in (ToolState(pose=P, partially_out_of_volume=True),
                ToolState(pose=P, out_of_volume=True), ToolState(pose=None, missing=True)):
        fr = TrackerFrame(frame=1, host_time=0.0, tools={"marker": seen, "probe": bad})
        got = frame_transforms(fr, cal)
        assert set(got) == {"CoilToRobotBase", "CoilToTracker", "MarkerToTracker",
                            "TrackerToRobotBase"}
        np.testing.assert_allclose(got["CoilToTracker"], coil_on_marker, atol=1e-9)
        np.testing.assert_allclose(got["CoilToRobotBase"], truth.Z @ coil_on_marker,
                                   atol=1e-9)
        assert set(frame_transforms(fr, cal, coil_from="probe")) == {"MarkerToTracker",
                                                                     "TrackerToRobotBase"}
        fr = TrackerFrame(frame=1, host_time=0.0, tools={"marker": bad, "probe": seen})
        assert set(frame_transforms(fr, cal)) == {"ProbeToTracker", "TrackerToRobotBase"}
        got = frame_transforms(fr, cal, coil_from="probe")
        assert set(got) == {"CoilToRobotBase", "CoilToTracker", "ProbeToTracker",
                            "TrackerToRobotBase"}
        expected = truth.Z[:3, :3] @ P[:3, 3] + truth.Z[:3, 3]
        assert np.allclose(got["CoilToRobotBase"][:3, 3], expected, atol=1e-9)
        assert set(frame_transforms(fr, cal, coil_from=None)) == {"ProbeToTracker",
                                                                  "TrackerToRobotBase"}


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
    distortion D = 1.001 I): CoilToRobotBase is Z applied to the coil on the undistorted
    marker pose (positions D⁻¹ t, an isotropic scale leaves rotations; then X⁻¹ · Y, rigid;
    Calibration.placement), not Z · B · X⁻¹ · Y as measured, which is 1.5 mm off at 1.5 m
    from the tracker."""
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
    offset = _stored_coil_on_marker(calib)
    pairs = 0
    for frame in _by_time(msgs).values():
        if "CoilToRobotBase" in frame and "MarkerToTracker" in frame:
            pairs += 1
            B = frame["MarkerToTracker"].copy()
            assert np.linalg.norm(B[:3, 3]) > 1000  # far enough for 0.1 % to be > 1 mm
            B[:3, 3] /= 1.001
            assert _close(frame["CoilToRobotBase"], Z @ B @ offset, F32_MM, F32_ROT)
            assert not _close(frame["CoilToRobotBase"], Z @ frame["CoilToTracker"], 1.0, 1.0)
            assert _close(frame["CoilToRobotBase"], coil_in_base, 2.0, 0.5)
    assert pairs >= 10
