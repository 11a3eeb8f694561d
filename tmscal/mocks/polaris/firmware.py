"""A protocol-level NDI Polaris (Spectra / Vicra) mock serving a :class:`~tmscal.sim.rig.SimRig`.

It speaks the NDI Combined API (NDI's Polaris API Guide) over a Linux pty
(:meth:`PolarisMock.start_pty`, returns the ``/dev/pts/N`` path that ndicapi,
scikit-surgerynditracker or our driver open as a serial port) or TCP on loopback
(:meth:`PolarisMock.start_tcp`, returns ``socket://127.0.0.1:PORT`` for pyserial's
``serial_for_url``). All encoding and decoding goes through
:mod:`tmscal.drivers.ndi.protocol`, the same codec the driver uses.

What it models:

* the setup / initialised / tracking state machine with NDI error codes for commands in the
  wrong state (e.g. TX/BX before TSTART → ERROR0C, tool commands before INIT → ERROR10,
  unknown or unallocated port handles → ERROR08, PENA on an uninitialised handle → ERROR0E,
  PINIT with no tool data → ERROR0D, bad CRC → ERROR04, unknown command → ERROR01);
* passive tools loaded from .rom files (PHRQ, PVWR, PINIT, PENA, PHSR, PHF, PHINF). A loaded
  definition is matched to a rig body by comparing its bytes (zero padding stripped) with the
  configured ROM files; unmatched definitions take the remaining bodies in order of loading;
* VER (multi-line, with ``Freeze Tag:``), GETINFO (simplified ``name=value``), COMM (baud
  changes are acknowledged and ignored), BEEP, APIREV, TSTART (``TSTART:80`` resets the frame
  counter), TSTOP, TX and BX (options 0001 and 0800) with a CRC on every reply;
* the frame counter: on the real-time clock it advances at the model's rate (Spectra 60 Hz,
  Vicra 20 Hz); on the fast clock once per TX/BX request. A new noisy observation
  (``rig.observe``) is taken only when the frame number changes;
* a measurement volume (:class:`MeasurementVolume`, a Spectra-like pyramid in tracker
  coordinates): a tool with all spheres inside is healthy, some inside → partially out of
  volume (0x80, pose reported), none inside → out of volume (0x40; reported MISSING unless
  the request has option 0800). Line of sight and marker orientation are not modelled;
* faults (:class:`PolarisFaults`): corrupted reply CRCs, dropped replies, tools missing in a
  fraction of frames, IR interference; all from one seeded RNG so tests are reproducible.

Threads: one daemon thread per transport (and per TCP connection); every loop polls a stop
flag with a short timeout, so ``close()`` returns promptly. Binds to loopback only.
"""

from __future__ import annotations

import errno
import logging
import os
import select
import socket
import threading
import tty
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..drivers.ndi import protocol as p
from ..errors import ProtocolError
from ..sim.rig import SimRig
from .clock import REAL_TIME, Clock
from .net import loopback_family, url_host

log = logging.getLogger(__name__)

MODELS: dict[str, dict[str, object]] = {
    "spectra": {"rate_hz": 60.0, "title": "Polaris Spectra Control Firmware",
                "freeze_tag": "Polaris Spectra Rev 007", "serial": "P6-00001"},
    "vicra": {"rate_hz": 20.0, "title": "Polaris Vicra Control Firmware",
              "freeze_tag": "Polaris Vicra Rev 007", "serial": "P5-00001"},
}
MAX_HANDLES = 12
_FIRST_HANDLE = 0x01
_MAX_ROM_BYTES = 0x10000
_MAX_LINE = 4096
_OBS_BATCH = 32


@dataclass(frozen=True)
class MeasurementVolume:
    """A frustum-shaped (pyramid) measurement volume in tracker coordinates, mm.

    The tracker looks along −z: a point (x, y, z) is inside when ``z_far_mm <= z <=
    z_near_mm`` and |x|, |y| are within half-widths that grow linearly from the near plane
    (``half_x_near_mm``, ``half_y_near_mm``) to the far plane (``half_x_far_mm``,
    ``half_y_far_mm``). Defaults resemble a Polaris Spectra pyramid, with generous widths.
    """

    z_near_mm: float = -950.0
    z_far_mm: float = -2400.0
    half_x_near_mm: float = 500.0
    half_x_far_mm: float = 900.0
    half_y_near_mm: float = 450.0
    half_y_far_mm: float = 800.0

    def __post_init__(self) -> None:
        if not self.z_far_mm < self.z_near_mm:
            raise ValueError(f"z_far_mm ({self.z_far_mm}) must be < z_near_mm "
                             f"({self.z_near_mm})")

    def contains(self, points_mm: np.ndarray) -> np.ndarray:
        """Boolean per point (k, 3) in tracker coordinates (mm): inside the volume?"""
        pts = np.atleast_2d(np.asarray(points_mm, dtype=np.float64))
        z = pts[:, 2]
        s = (self.z_near_mm - z) / (self.z_near_mm - self.z_far_mm)  # 0 near .. 1 far
        hx = self.half_x_near_mm + s * (self.half_x_far_mm - self.half_x_near_mm)
        hy = self.half_y_near_mm + s * (self.half_y_far_mm - self.half_y_near_mm)
        return ((z <= self.z_near_mm) & (z >= self.z_far_mm)
                & (np.abs(pts[:, 0]) <= hx) & (np.abs(pts[:, 1]) <= hy))


@dataclass(frozen=True)
class PolarisFaults:
    """Injected faults (all probabilities in [0, 1], drawn from the mock's seeded RNG).

    ``crc_error_prob``: a reply goes out with a corrupted CRC. ``drop_reply_prob``: a reply
    is not sent at all. Both apply to TX/BX replies only unless ``tracking_only`` is False
    (then to every reply). ``missing_fraction``: per frame and tool, the tool is reported
    MISSING. ``ir_interference_fraction``: per frame, every tool's port status gets 0x200
    (IR interference) and the system status 0x02 (too much IR); poses are still reported.
    """

    crc_error_prob: float = 0.0
    drop_reply_prob: float = 0.0
    missing_fraction: float = 0.0
    ir_interference_fraction: float = 0.0
    tracking_only: bool = True

    def __post_init__(self) -> None:
        for name in ("crc_error_prob", "drop_reply_prob", "missing_fraction",
                     "ir_interference_fraction"):
            v = getattr(self, name)
            if not 0.0 <= v <= 1.0:
                raise ValueError(f"PolarisFaults.{name} must be in [0, 1], got {v}")


class _Handle:
    def __init__(self, number: int, order: int) -> None:
        self.number = number
        self.order = order  # order of allocation, for the fallback body match
        self.rom = bytearray()
        self.occupied = False
        self.initialized = False
        self.enabled = False
        self.priority = ""
        self.body: str | None = None

    @property
    def status(self) -> int:
        return ((p.HANDLE_OCCUPIED if self.occupied else 0)
                | (p.HANDLE_INITIALIZED if self.initialized else 0)
                | (p.HANDLE_ENABLED if self.enabled else 0))


class _Reply(Exception):
    """Internal: answer the current command with ERRORxx."""

    def __init__(self, code: int) -> None:
        super().__init__(code)
        self.code = code


class PolarisMock:
    """An NDI Polaris serving ``rig`` over a pty and/or loopback TCP.

    Parameters (keyword-only after ``rig``):

    * ``rig``: the :class:`SimRig` whose bodies are tracked (poses tracker_from_body, mm).
    * ``tools``: our tool/body name → path of the .rom file that identifies it (e.g.
      ``{"marker": "configs/tools/marker-8700340.rom", "probe": ...}``); every name must be a
      rig body. ``None``: the rig's bodies, matched in order of loading.
    * ``model``: ``"spectra"`` (60 Hz) or ``"vicra"`` (20 Hz).
    * ``clock``: :data:`~tmscal.mocks.clock.REAL_TIME` or :data:`~tmscal.mocks.clock.FAST`.
    * ``volume``: :class:`MeasurementVolume` (default Spectra-like) or None for no limits.
    * ``faults``: :class:`PolarisFaults` (default: none).
    * ``seed``: seeds the fault RNG.
    * ``freeze_tag``: override the ``Freeze Tag:`` of VER (scikit-surgerynditracker picks TX
      instead of BX for "Polaris Spectra Rev 007"; the Vicra tag makes it use BX).
    * ``error_mm``: the RMS fit error reported for every tool (mm).
    """

    def __init__(self, rig: SimRig, tools: Mapping[str, str | os.PathLike[str]] | None = None,
                 *, model: str = "spectra", clock: Clock = REAL_TIME,
                 volume: MeasurementVolume | None = MeasurementVolume(),
                 faults: PolarisFaults | None = None, seed: int = 0,
                 freeze_tag: str | None = None, error_mm: float = 0.1) -> None:
        if model not in MODELS:
            raise ValueError(f"unknown Polaris model {model!r}; known: {sorted(MODELS)}")
        self.rig = rig
        self.model = model
        self.clock = clock
        self.volume = volume
        self.faults = faults or PolarisFaults()
        self.rate_hz = float(MODELS[model]["rate_hz"])  # type: ignore[arg-type]
        self.freeze_tag = freeze_tag or str(MODELS[model]["freeze_tag"])
        self.error_mm = float(error_mm)
        self._bodies: list[str] = list(tools) if tools is not None else list(rig.bodies)
        for b in self._bodies:
            if b not in rig.bodies:
                raise ValueError(f"tool {b!r} is not a body of the rig ({rig.bodies})")
        self._roms: dict[str, bytes] = {}
        for body, path in (tools or {}).items():
            try:
                self._roms[body] = Path(path).read_bytes().rstrip(b"\0")
            except OSError as e:
                raise ValueError(f"cannot read ROM file for tool {body!r}: {e}") from e
        seq = np.random.SeedSequence(seed)
        s_frame, s_reply = seq.spawn(2)
        self._frame_rng = np.random.default_rng(s_frame)
        self._reply_rng = np.random.default_rng(s_reply)
        self._lock = threading.RLock()
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self._fds: list[int] = []
        self._sockets: list[socket.socket] = []
        self.endpoints: dict[str, str] = {}
        #: every command line received (decoded, CRC stripped), for tests asserting sequences
        self.commands: list[str] = []
        self._power_up()

    # --- state -------------------------------------------------------------------------------
    def _power_up(self) -> None:
        with self._lock:
            self.state = "setup"  # "setup" → INIT → "ready" → TSTART → "tracking"
            self._handles: dict[int, _Handle] = {}
            self._alloc_count = 0
            self._t0 = self.clock.now()
            self._fast_frame = 0
            self._obs_cache: dict[str, tuple[np.ndarray, list[np.ndarray]]] = {}
            self._frame_cache: tuple[int, dict[int, tuple[str, np.ndarray | None, int]],
                                     int] | None = None

    def reset(self) -> None:
        """Device reset (what a serial break does on real hardware): handles freed, back to
        setup mode, frame counter restarted."""
        self._power_up()

    @property
    def handles(self) -> dict[int, str | None]:
        """Allocated port handles → the rig body each was identified as (None if none)."""
        with self._lock:
            return {h.number: h.body for h in self._handles.values()}

    # --- transports --------------------------------------------------------------------------
    def start(self, *, pty: bool = True, tcp: bool = False, host: str = "127.0.0.1",
              port: int = 0) -> dict[str, str]:
        """Start the requested transports; returns {"pty": path, "tcp": url} for those
        started."""
        if pty and "pty" not in self.endpoints:
            self.start_pty()
        if tcp and "tcp" not in self.endpoints:
            self.start_tcp(host, port)
        return dict(self.endpoints)

    def start_pty(self) -> str:
        """Serve on a new pty; returns the slave path (``/dev/pts/N``) clients open."""
        master, slave = os.openpty()
        tty.setraw(slave)
        os.set_blocking(master, False)
        path = os.ttyname(slave)
        self._fds += [master, slave]  # the slave stays open: the master reads EIO otherwise
        t = threading.Thread(target=self._serve_pty, args=(master,), daemon=True,
                             name=f"polaris-mock-pty{path}")
        self._threads.append(t)
        t.start()
        self.endpoints["pty"] = path
        log.info("Polaris mock (%s) on %s", self.model, path)
        return path

    def start_tcp(self, host: str = "127.0.0.1", port: int = 0) -> str:
        """Serve on TCP ``host:port`` (loopback only: 127.0.0.0/8, ::1 or localhost, else
        ``ConfigError``; port 0 picks a free one); returns ``socket://HOST:PORT`` for
        ``serial.serial_for_url``."""
        family = loopback_family(host, "Polaris mock TCP host")
        srv = socket.create_server((host, port), family=family)
        srv.settimeout(0.1)
        self._sockets.append(srv)
        real_port = srv.getsockname()[1]
        t = threading.Thread(target=self._serve_tcp, args=(srv,), daemon=True,
                             name=f"polaris-mock-tcp{real_port}")
        self._threads.append(t)
        t.start()
        url = f"socket://{url_host(host)}:{real_port}"
        self.endpoints["tcp"] = url
        log.info("Polaris mock (%s) on %s", self.model, url)
        return url

    def close(self) -> None:
        """Stop serving and release the pty / sockets; safe to call twice."""
        self._stop.set()
        for t in self._threads:
            t.join(timeout=2.0)
        self._threads.clear()
        for s in self._sockets:
            try:
                s.close()
            except OSError:
                pass
        self._sockets.clear()
        for fd in self._fds:
            try:
                os.close(fd)
            except OSError:
                pass
        self._fds.clear()

    def __enter__(self) -> PolarisMock:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _serve_pty(self, master: int) -> None:
        buf = bytearray()
        while not self._stop.is_set():
            try:
                r, _, _ = select.select([master], [], [], 0.05)
            except (OSError, ValueError):
                return
            if not r:
                continue
            try:
                data = os.read(master, 4096)
            except BlockingIOError:
                continue
            except OSError as e:  # EIO while no client has the slave open (should not happen)
                if e.errno == errno.EIO:
                    self._stop.wait(0.01)
                    continue
                return
            if not data:
                continue
            for reply in self._feed(buf, data):
                self._write_fd(master, reply)

    def _write_fd(self, fd: int, data: bytes) -> None:
        view = memoryview(data)
        for _ in range(1000):  # bounded: give up on a reader that never drains
            if not view:
                return
            try:
                n = os.write(fd, view)
                view = view[n:]
            except BlockingIOError:
                select.select([], [fd], [], 0.01)
            except OSError:
                return
        log.warning("Polaris mock: pty reader not draining; reply dropped")

    def _serve_tcp(self, srv: socket.socket) -> None:
        while not self._stop.is_set():
            try:
                conn, _ = srv.accept()
            except TimeoutError:
                continue
            except OSError:
                return
            t = threading.Thread(target=self._serve_conn, args=(conn,), daemon=True,
                                 name="polaris-mock-conn")
            self._threads.append(t)
            t.start()

    def _serve_conn(self, conn: socket.socket) -> None:
        conn.settimeout(0.05)
        conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        buf = bytearray()
        with conn:
            while not self._stop.is_set():
                try:
                    data = conn.recv(4096)
                except TimeoutError:
                    continue
                except OSError:
                    return
                if not data:
                    return
                for reply in self._feed(buf, data):
                    try:
                        conn.sendall(reply)
                    except OSError:
                        return

    def _feed(self, buf: bytearray, data: bytes) -> list[bytes]:
        """Append received bytes; answer every complete command line."""
        buf += data
        out = []
        while True:
            i = buf.find(b"\r")
            if i < 0:
                if len(buf) > _MAX_LINE:
                    buf.clear()
                    out.append(p.encode_error(0x02))
                break
            line = bytes(buf[:i])
            del buf[:i + 1]
            line = line.lstrip(b"\n")
            if not line:
                continue
            reply = self.handle_line(line)
            if reply is not None:
                out.append(reply)
        return out

    # --- commands ----------------------------------------------------------------------------
    def handle_line(self, line: bytes) -> bytes | None:
        """Answer one command line (without ``\\r``); None means the reply is dropped (fault
        injection). Transport-independent; thread-safe."""
        with self._lock:
            try:
                cmd = p.parse_command(line)
            except ProtocolError as e:
                self.commands.append(line.decode("ascii", "replace"))
                return self._maybe_fault(p.encode_error(int(e.code or 1)), tracking=False)
            self.commands.append(f"{cmd.name}:{cmd.params}" if cmd.had_crc
                                 else f"{cmd.name} {cmd.params}".rstrip())
            tracking = cmd.name in ("TX", "BX")
            try:
                reply = self._dispatch(cmd)
            except _Reply as r:
                reply = p.encode_error(r.code)
            return self._maybe_fault(reply, tracking)

    def _maybe_fault(self, reply: bytes, tracking: bool) -> bytes | None:
        f = self.faults
        if f.tracking_only and not tracking:
            return reply
        if f.drop_reply_prob > 0 and self._reply_rng.random() < f.drop_reply_prob:
            log.debug("Polaris mock: dropping reply %r", reply[:20])
            return None
        if f.crc_error_prob > 0 and self._reply_rng.random() < f.crc_error_prob:
            b = bytearray(reply)
            if b[:2] == b"\xc4\xa5":
                b[-1] ^= 0x5A  # body CRC (header stays exact so the length is readable)
            else:
                k = len(b) - 2  # last CRC digit, kept a hex digit
                b[k] = ord("0") if b[k] != ord("0") else ord("1")
            return bytes(b)
        return reply

    def _dispatch(self, cmd: p.Command) -> bytes:
        name, prm = cmd.name, cmd.params.strip()
        handler = getattr(self, f"_cmd_{name.lower()}", None)
        if handler is None:
            raise _Reply(0x01)
        if name not in ("INIT", "COMM", "VER", "GETINFO", "BEEP", "APIREV", "RESET") \
                and self.state == "setup":
            raise _Reply(0x10)
        return handler(prm)

    def _handle(self, text: str) -> _Handle:
        try:
            h = int(text, 16)
        except ValueError:
            raise _Reply(0x08) from None
        if len(text) != 2 or h not in self._handles:
            raise _Reply(0x08)
        return self._handles[h]

    def _not_tracking(self) -> None:
        if self.state == "tracking":
            raise _Reply(0x0C)

    # system
    def _cmd_init(self, prm: str) -> bytes:
        self._not_tracking()
        self.state = "ready"
        return p.OKAY_REPLY

    def _cmd_reset(self, prm: str) -> bytes:
        self._power_up()
        return p.frame_reply("RESET")

    def _cmd_comm(self, prm: str) -> bytes:
        if len(prm) != 5 or prm[0].upper() not in p.BAUD_FROM_CODE or prm[1] not in "01" \
                or prm[2] not in "012" or prm[3] not in "01" or prm[4] not in "01":
            raise _Reply(0x06)
        return p.OKAY_REPLY  # the line rate is ignored (pty / TCP)

    def _ver_text(self) -> str:
        m = MODELS[self.model]
        return "\n".join([
            str(m["title"]),
            "Copyright (C) Northern Digital Inc. (tmscal mock)",
            f"Serial Number: {m['serial']}",
            "Characterization Date: 01/01/24",
            f"Freeze Tag: {self.freeze_tag}",
            "Freeze Date: 01/01/24",
            "",
        ])

    def _cmd_ver(self, prm: str) -> bytes:
        if prm not in ("", "0", "1", "2", "3", "4", "5"):
            raise _Reply(0x23)
        return p.frame_reply(self._ver_text())

    def _cmd_getinfo(self, prm: str) -> bytes:
        tag = self.freeze_tag
        info = {
            "Features.Firmware.Version": tag.rsplit(" ", 1)[-1],
            "Features.Firmware.Major Version": tag.rsplit(" ", 1)[-1],
            "Config.Serial Number": str(MODELS[self.model]["serial"]),
            "Config.Type Of System": "Polaris " + self.model.capitalize(),
        }
        if prm not in info:
            raise _Reply(0x23)
        return p.frame_reply(f"{prm}={info[prm]}")

    def _cmd_beep(self, prm: str) -> bytes:
        if prm not in tuple("123456789"):
            raise _Reply(0x23)
        return p.frame_reply("1")

    def _cmd_apirev(self, prm: str) -> bytes:
        return p.frame_reply("G.001.005")

    # handles
    def _cmd_phrq(self, prm: str) -> bytes:
        self._not_tracking()
        if len(prm) != 14:
            raise _Reply(0x07)
        free = [n for n in range(_FIRST_HANDLE, _FIRST_HANDLE + MAX_HANDLES)
                if n not in self._handles]
        if not free:
            raise _Reply(0x2D)
        self._alloc_count += 1
        h = _Handle(free[0], self._alloc_count)
        self._handles[h.number] = h
        return p.frame_reply(f"{h.number:02X}")

    def _cmd_pvwr(self, prm: str) -> bytes:
        self._not_tracking()
        if len(prm) != 2 + 4 + 128:
            raise _Reply(0x07)
        h = self._handle(prm[:2])
        try:
            addr = int(prm[2:6], 16)
            chunk = bytes.fromhex(prm[6:])
        except ValueError:
            raise _Reply(0x23) from None
        if addr % 64 or addr + 64 > _MAX_ROM_BYTES:
            raise _Reply(0x23)
        if h.initialized:
            raise _Reply(0x0C)
        if len(h.rom) < addr + 64:
            h.rom.extend(bytes(addr + 64 - len(h.rom)))
        h.rom[addr:addr + 64] = chunk
        h.occupied = True
        return p.OKAY_REPLY

    def _identify(self, h: _Handle) -> str | None:
        data = bytes(h.rom).rstrip(b"\0")
        taken = {o.body for o in self._handles.values() if o is not h and o.body}
        for body, rom in self._roms.items():
            if rom == data and body not in taken:
                return body
        # fallback, in order of loading: the next body whose ROM is not loaded elsewhere
        loaded = {bytes(o.rom).rstrip(b"\0") for o in self._handles.values() if o is not h}
        for body in self._bodies:
            if body not in taken and self._roms.get(body) not in loaded:
                return body
        return None

    def _cmd_pinit(self, prm: str) -> bytes:
        self._not_tracking()
        if len(prm) != 2:
            raise _Reply(0x07)
        h = self._handle(prm)
        if not h.occupied:
            raise _Reply(0x0D)
        if not h.initialized:
            h.body = self._identify(h)
            h.initialized = True
            log.debug("Polaris mock: handle %02X is %s", h.number, h.body)
        return p.OKAY_REPLY

    def _cmd_pena(self, prm: str) -> bytes:
        self._not_tracking()
        if len(prm) != 3:
            raise _Reply(0x07)
        h = self._handle(prm[:2])
        if prm[2].upper() not in "SDB":
            raise _Reply(0x09)
        if not h.initialized:
            raise _Reply(0x0E)
        h.enabled = True
        h.priority = prm[2].upper()
        return p.OKAY_REPLY

    def _cmd_pdis(self, prm: str) -> bytes:
        self._not_tracking()
        h = self._handle(prm[:2])
        if not h.enabled:
            raise _Reply(0x0F)
        h.enabled = False
        return p.OKAY_REPLY

    def _cmd_phf(self, prm: str) -> bytes:
        self._not_tracking()
        if len(prm) != 2:
            raise _Reply(0x07)
        h = self._handle(prm)
        del self._handles[h.number]
        return p.OKAY_REPLY

    def _cmd_phsr(self, prm: str) -> bytes:
        self._not_tracking()
        opt = prm or "00"
        hs = sorted(self._handles.values(), key=lambda h: h.number)
        if opt == "00":
            sel = hs
        elif opt == "01":
            sel = []  # the mock never marks handles to be freed
        elif opt == "02":
            sel = [h for h in hs if h.occupied and not h.initialized]
        elif opt == "03":
            sel = [h for h in hs if h.initialized and not h.enabled]
        elif opt == "04":
            sel = [h for h in hs if h.enabled]
        else:
            raise _Reply(0x23)
        return p.frame_reply(p.encode_phsr([(h.number, h.status) for h in sel]))

    def _cmd_phinf(self, prm: str) -> bytes:
        self._not_tracking()
        if len(prm) not in (2, 6):
            raise _Reply(0x07)
        h = self._handle(prm[:2])
        if not h.occupied:
            return p.frame_reply("UNOCCUPIED")
        status = p.PORT_OCCUPIED | (p.PORT_INITIALIZED if h.initialized else 0) \
            | (p.PORT_ENABLED if h.enabled else 0)
        text = ("0A000000" + "NDI".ljust(12) + "000" + f"{0x8700340 + h.number:08X}"
                + f"{status:02X}")
        return p.frame_reply(text)

    # tracking
    def _cmd_tstart(self, prm: str) -> bytes:
        if self.state == "tracking":
            raise _Reply(0x0C)
        if prm not in ("", "80"):
            raise _Reply(0x23)
        if prm == "80":
            self._t0 = self.clock.now()
            self._fast_frame = 0
            self._frame_cache = None
        self.state = "tracking"
        return p.OKAY_REPLY

    def _cmd_tstop(self, prm: str) -> bytes:
        if self.state != "tracking":
            raise _Reply(0x0C)
        self.state = "ready"
        return p.OKAY_REPLY

    def _options(self, prm: str) -> int:
        if prm == "":
            return p.OPT_TRANSFORMS
        try:
            opt = int(prm, 16)
        except ValueError:
            raise _Reply(0x23) from None
        if len(prm) != 4 or opt & ~(p.OPT_TRANSFORMS | p.OPT_OUT_OF_VOLUME) \
                or not opt & p.OPT_TRANSFORMS:
            raise _Reply(0x23)  # other reply options are not modelled
        return opt

    def _cmd_tx(self, prm: str) -> bytes:
        opt = self._options(prm)
        if self.state != "tracking":
            raise _Reply(0x0C)
        recs, sys_status = self._records(opt)
        return p.frame_reply(p.encode_tx(recs, sys_status))

    def _cmd_bx(self, prm: str) -> bytes:
        opt = self._options(prm)
        if self.state != "tracking":
            raise _Reply(0x0C)
        recs, sys_status = self._records(opt)
        return p.encode_bx(recs, sys_status)

    # --- frames ------------------------------------------------------------------------------
    def _current_frame(self) -> int:
        if self.clock.fast:
            self._fast_frame += 1
            return self._fast_frame
        return int((self.clock.now() - self._t0) * self.rate_hz) & 0xFFFFFFFF

    def _frame_state(self, frame: int) -> tuple[dict[int, tuple[str, np.ndarray | None, int]],
                                                 int]:
        """Per enabled handle: (kind, pose, port status) for this frame, computed once per
        frame number (same frame → same observation)."""
        if self._frame_cache is not None and self._frame_cache[0] == frame:
            return self._frame_cache[1], self._frame_cache[2]
        f = self.faults
        rng = self._frame_rng
        ir = f.ir_interference_fraction > 0 and rng.random() < f.ir_interference_fraction
        sys_status = p.SYS_TOO_MUCH_IR if ir else 0
        out: dict[int, tuple[str, np.ndarray | None, int]] = {}
        for h in sorted(self._handles.values(), key=lambda h: h.number):
            if not h.enabled:
                continue
            status = p.PORT_HEALTHY | (p.PORT_IR_INTERFERENCE if ir else 0)
            if h.body is None:
                out[h.number] = ("missing", None, status)
                continue
            if f.missing_fraction > 0 and rng.random() < f.missing_fraction:
                out[h.number] = ("missing", None, status)
                continue
            pose = self._observe(h.body)
            kind = "valid"
            if self.volume is not None:
                spheres = np.asarray((self.rig.tools or {}).get(h.body, np.zeros((1, 3))))
                world = spheres @ pose[:3, :3].T + pose[:3, 3]
                inside = self.volume.contains(world)
                if not inside.any():
                    status |= p.PORT_OUT_OF_VOLUME
                    kind = "oov"
                elif not inside.all():
                    status |= p.PORT_PARTIALLY_OUT_OF_VOLUME
            out[h.number] = (kind, pose, status)
        self._frame_cache = (frame, out, sys_status)
        return out, sys_status

    def _observe(self, body: str) -> np.ndarray:
        """One noisy ``rig.observe(body)`` (tracker_from_body, 4×4 mm). Observations are
        drawn from the rig in batches of ``_OBS_BATCH`` at the current true pose and used one
        per frame; a batch is discarded as soon as the true pose changes (the robot moved),
        so each frame still gets an independent observation of where the body is now."""
        true = self.rig.true_body(body)
        cached = self._obs_cache.get(body)
        if cached is None or not np.array_equal(cached[0], true) or not cached[1]:
            batch = self.rig.observe(body, _OBS_BATCH)
            cached = (true, list(batch[::-1]))
            self._obs_cache[body] = cached
        return cached[1].pop()

    def _records(self, options: int) -> tuple[list[p.HandleRecord], int]:
        frame = self._current_frame()
        state, sys_status = self._frame_state(frame)
        seen = [(number, pose, self.error_mm, status, frame)
                for number, (kind, pose, status) in state.items()
                if kind == "valid" or (kind == "oov" and options & p.OPT_OUT_OF_VOLUME)]
        valid = {r.handle: r for r in p.records_from_poses(seen)}  # type: ignore[arg-type]
        recs = [valid.get(number) or p.HandleRecord.missing_tool(number, status, frame)
                for number, (_, _, status) in state.items()]
        return recs, sys_status


__all__ = ["PolarisMock", "PolarisFaults", "MeasurementVolume", "MODELS"]
