"""What a real Polaris asks of the driver that the mock used not to (docs/devices.md): no
COMM over socket://, TX instead of BX on firmware whose BX fails with three or more tools,
TX ``UNOCCUPIED`` rows, the newer error codes, and the wire log (``tracker.log_wire``).
Our driver against our Polaris mock over a real pty or loopback TCP, on the fast clock."""

from __future__ import annotations

import logging
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from tmscal.acquisition.devices import make_tracker
from tmscal.config import load_config
from tmscal.drivers.ndi import protocol as p
from tmscal.drivers.ndi.tracker import NDITracker
from tmscal.errors import ConfigError
from tmscal.mocks.clock import FAST
from tmscal.mocks.polaris import PolarisFaults, PolarisMock
from tmscal.sim.rig import TMS_RIG_P0, Noise, SimRig, tms_rig_truth

TOOLS_DIR = Path(__file__).resolve().parents[2] / "configs" / "tools"
ROMS = {"marker": str(TOOLS_DIR / "marker-8700340.rom"),
        "probe": str(TOOLS_DIR / "probe-8700340.rom")}


def make_rig() -> SimRig:
    return SimRig(tms_rig_truth(), noise=Noise.none(), rng=np.random.default_rng(1),
                  start=TMS_RIG_P0)


@pytest.fixture
def mock() -> Iterator[PolarisMock]:
    with PolarisMock(make_rig(), ROMS, clock=FAST, seed=3) as m:
        yield m


def test_no_comm_over_socket(mock: PolarisMock) -> None:
    """A networked tracker (Vega) takes no baud change: neither scikit-surgerynditracker
    nor PlusLib sends COMM over the network, and neither may we."""
    with NDITracker(mock.start_tcp(), ROMS, timeout_s=0.3, baud=115200) as tr:
        assert tr.read().tools["marker"].usable
    assert not [c for c in mock.commands if c.startswith("COMM")]
    assert mock.commands[0] == "INIT:"


def test_bx_falls_back_to_tx_with_three_tools(tmp_path: Path,
                                              caplog: pytest.LogCaptureFixture) -> None:
    """Polaris Spectra Rev 006/007 (the mock's default freeze tag is Rev 007): BX fails with
    three or more tools (scikit-surgerynditracker #53, #67); the driver uses TX and says so."""
    third = tmp_path / "third.rom"
    third.write_bytes(b"NDI\0third tool definition" + bytes(40))
    tools = {**ROMS, "third": str(third)}
    faults = PolarisFaults(bx_fails_from_tools=3)
    with PolarisMock(make_rig(), ROMS, clock=FAST, faults=faults, seed=3) as m:
        assert m.freeze_tag == "Polaris Spectra Rev 007"
        with caplog.at_level(logging.WARNING), \
                NDITracker(m.start_pty(), tools, timeout_s=0.2, retries=0, reset=False) as tr:
            frame = tr.read()
            assert frame.tools["marker"].usable and frame.tools["probe"].usable
            assert frame.tools["third"].missing  # no rig body behind it
        assert not [c for c in m.commands if c.startswith("BX")]
        assert [c for c in m.commands if c.startswith("TX")]
    assert any("TX" in r.getMessage() and "Rev 007" in r.getMessage() for r in caplog.records)


def test_two_tools_keep_bx(mock: PolarisMock) -> None:
    with NDITracker(mock.start_pty(), ROMS, timeout_s=0.3, reset=False) as tr:
        assert tr.read().tools["probe"].usable
    assert [c for c in mock.commands if c.startswith("BX")]


def test_decode_tx_accepts_unoccupied_rows() -> None:
    payload = ("03" + "01UNOCCUPIED\n" + "02MISSING0000003100000007\n"
               + "03UNOCCUPIED\n" + "0000")
    recs = p.decode_tx(payload).records
    assert [(r.handle, r.status) for r in recs] == [(1, "unoccupied"), (2, "missing"),
                                                   (3, "unoccupied")]
    assert all(r.missing and r.pose is None for r in recs)


def test_driver_reads_unoccupied_handles_as_missing() -> None:
    faults = PolarisFaults(unoccupied_fraction=1.0)
    with PolarisMock(make_rig(), ROMS, clock=FAST, faults=faults, seed=3) as m, \
            NDITracker(m.start_pty(), ROMS, timeout_s=0.3, reset=False, reply="tx") as tr:
        frame = tr.read()
        assert frame.tools["marker"].missing and frame.tools["probe"].missing


@pytest.mark.parametrize("code, word", [
    (0x29, "firmware corrupt"), (0x34, "does not exist"), (0x35, "value type"),
    (0x36, "value out of"), (0x37, "array index"), (0x38, "size"), (0x39, "permission")])
def test_newer_error_codes_have_texts(code: int, word: str) -> None:
    assert word in p.error_text(code)


# --- the wire log ------------------------------------------------------------------------------

def test_log_wire_records_the_traffic(mock: PolarisMock, tmp_path: Path) -> None:
    log = tmp_path / "wire.log"
    with NDITracker(mock.start_pty(), ROMS, timeout_s=0.3, reset=False, log_wire=log) as tr:
        tr.read()
    text = log.read_text()
    assert "INIT" in text and "TSTART" in text and "OKAY" in text


def test_log_wire_refuses_an_existing_file(mock: PolarisMock, tmp_path: Path) -> None:
    log = tmp_path / "wire.log"
    log.write_text("keep me")
    tr = NDITracker(mock.start_pty(), ROMS, timeout_s=0.3, reset=False, log_wire=log)
    with pytest.raises(ConfigError, match="log_wire"):
        tr.open()
    assert log.read_text() == "keep me"
    assert not mock.commands  # nothing was sent


def _config(tmp_path: Path, tracker_extra: str, port: str = "/dev/ttyUSB0") -> Path:
    cfg = tmp_path / "rig.yaml"
    cfg.write_text(f"tracker:\n  driver: ndi\n  port: {port}\n  tools:\n"
                   f"    marker: {ROMS['marker']}\n{tracker_extra}")
    return cfg


def test_config_log_wire_resolves_and_reaches_the_driver(tmp_path: Path) -> None:
    (tmp_path / "traces").mkdir()
    cfg = load_config(_config(tmp_path, "  log_wire: traces/wire.log\n"
                              "  options: {init_timeout_s: 8}\n"))
    assert cfg.tracker is not None
    assert cfg.tracker.settings.log_wire == str(tmp_path / "traces" / "wire.log")
    tr = make_tracker(cfg)
    assert isinstance(tr, NDITracker)
    assert tr.log_wire == tmp_path / "traces" / "wire.log"
    assert tr.command_timeouts["INIT"] == 8


@pytest.mark.parametrize("extra, port, match", [
    ("  log_wire: rig.yaml\n", "/dev/ttyUSB0", "input file"),
    ("  log_wire: nodir/wire.log\n", "/dev/ttyUSB0", "does not exist"),
    ("  log_wire: wire.log\n", "socket://127.0.0.1:8765", "serial device"),
    ("  options: {log_wire: wire.log}\n", "/dev/ttyUSB0", "log_wire"),
    ("  log_wire: [1]\n", "/dev/ttyUSB0", "expected a string"),
])
def test_config_refuses_bad_log_wire(tmp_path: Path, extra: str, port: str,
                                     match: str) -> None:
    with pytest.raises(ConfigError, match=match) as e:
        load_config(_config(tmp_path, extra, port))
    assert "log_wire" in str(e.value)


def test_a_spy_port_is_still_refused(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="tracker.port"):
        load_config(_config(tmp_path, "", port="spy:///dev/ttyUSB0?file=x.log"))
