"""NDI Polaris (Vicra / Spectra) driver over a serial line (or anything pyserial's
``serial_for_url`` opens: ``/dev/ttyUSB0``, a pty path, ``socket://127.0.0.1:PORT``).

Session: optional reset by serial break (a serial line only; wait up to ``reset_timeout_s``
for ``RESET``, then 100 ms; no RESET answer → just INIT), INIT, VER / GETINFO for the identity,
COMM to the configured rate on a serial line (never over ``socket://``: a networked tracker
takes no baud change; the host switches after the OKAY), passive tools loaded from .rom files
(each checked first by :mod:`.rom`: at most 1024 bytes, ``NDI`` header, binary; then PHRQ,
PVWR in 64-byte chunks, PINIT, PENA D) after freeing stale handles, TSTART. INIT,
PINIT and TSTART get their own long timeouts. BX falls back to TX on the firmware revisions
whose BX fails with three or more tools. Every :meth:`NDITracker.read` sends BX (or TX) and
returns a
:class:`~tmscal.drivers.base.TrackerFrame` whose tools are keyed by OUR tool names, each pose
tracker_from_tool 4×4 in mm. ``close()`` sends TSTOP and closes the port, also after errors.

Errors: a corrupt (CRC) or torn reply and a reply that does not come in time are retried up
to ``retries`` times (the command is re-sent), then raised as ``ProtocolError`` /
``DeviceTimeout`` naming the command; ``ERRORxx`` replies raise ``DeviceError`` with
``code`` (int NDI code) and ``text`` (its meaning) at once. ``RESET`` as the answer to a
command means the device reset (power, a break) and lost its tools: :class:`DeviceReset`
(a ``ConnectionLost``, so a run reconnects), naming the command. The input is flushed before
every command, so a late reply is never taken for the next command's. Device facts relied on:
docs/devices.md.
"""

from __future__ import annotations

import logging
import os
import time
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import serial

from ...errors import ConnectionLost, DeviceError, DeviceTimeout, ProtocolError
from ...timing import Deadline
from ..base import ToolState, Tracker, TrackerFrame
from . import protocol as p
from .codes import ErrorCode, HandleStatus, PortStatus, SystemStatus, flag_names
from .replies import ReplyKind
from .rom import read_roms
from .settings import NDISettings
from .wire import open_port, silence_message

#: the options' defaults, declared once in NDISettings.OPTIONS
_OPT = NDISettings.defaults()

log = logging.getLogger(__name__)

__all__ = ["NDITracker", "DeviceReset", "BX_UNRELIABLE_FIRMWARE"]

#: VER freeze tags whose BX fails with three or more tools (scikit-surgerynditracker issues
#: #53 and #67, fixed there by using TX for these revisions): the driver uses TX on them
BX_UNRELIABLE_FIRMWARE = ("Polaris Spectra Rev 006", "Polaris Spectra Rev 007")
_BX_UNRELIABLE_FROM_TOOLS = 3
#: pause after RESET before the next command (ndicapi's ndiSerialProbe sleeps 100 ms)
_AFTER_RESET_S = 0.1

_PHRQ_PASSIVE = "*********1****"
#: errors that, on a re-sent command, mean the first (unanswered) attempt already worked.
#: PHRQ is not idempotent: a lost PHRQ reply leaves an empty handle behind (harmless).
_DONE_ON_RETRY: dict[str, tuple[int, ...]] = {
    "TSTART": (ErrorCode.INVALID_MODE,), "TSTOP": (ErrorCode.INVALID_MODE,),
    "PHF": (ErrorCode.INVALID_PORT_HANDLE, ErrorCode.HANDLE_NOT_ALLOCATED)}
#: every reply is ≥ 6 bytes (BX header; shortest text: "0" + CRC + CR)
_MIN_REPLY = 6
#: port status bits a ToolState carries; the driver logs the others when they change
_TOOL_STATE_BITS = int(PortStatus.OCCUPIED | PortStatus.INITIALIZED | PortStatus.ENABLED
                       | PortStatus.OUT_OF_VOLUME | PortStatus.PARTIALLY_OUT_OF_VOLUME)


class NDITracker(Tracker):
    """NDI Polaris tracker driver.

    Parameters (keywords):

    * ``port``: serial device or pyserial URL (``/dev/ttyUSB0``, ``/dev/pts/3``,
      ``socket://127.0.0.1:8765``).
    * ``tools``: our tool name → .rom file path, e.g. ``{"marker": "marker.rom",
      "probe": "probe.rom"}``. A ``None`` path means "use a tool already loaded on the
      device": such names take the remaining enabled/initialised handles in handle order.
    * ``baud``: line rate after COMM (9600 … 921600, 230400, 1228739); the device starts at
      9600.
    * ``frame_rate_hz``: the tracker's frame rate (Spectra 60, Vicra 20), for callers.
    * ``reply``: ``"bx"`` (binary, default) or ``"tx"`` (text) tracking replies.
    * ``timeout_s``: per-command reply timeout (s). ``retries``: re-sends after a corrupt,
      torn or missing reply.
    * ``reset``: send a serial break first (None = only when every tool has a .rom file,
      since a reset unloads the tools on the device; never over ``socket://``).
      ``reset_timeout_s``: how long to wait for the ``RESET`` answer to the break (7 s, as
      ndicapi) before carrying on with INIT.
    * ``init_timeout_s``, ``pinit_timeout_s``, ``tstart_timeout_s``: reply timeouts of INIT,
      PINIT and TSTART (5 s each; never shorter than ``timeout_s``).
    * ``reply_options``: TX/BX reply option word (default 0x0801: transforms incl. out-of-volume).
    * ``log_wire``: a file that records the serial traffic (pyserial's ``spy://`` hex dump;
      device paths only). It must not exist yet; a reconnect writes ``NAME.1``, ``NAME.2`` …
    """

    name = "ndi"

    def __init__(self, port: str, tools: Mapping[str, str | os.PathLike[str] | None], *,
                 baud: int = 115200, frame_rate_hz: float = 60.0, reply: str = "bx",
                 timeout_s: float = _OPT["timeout_s"], retries: int = _OPT["retries"],
                 reset: bool | None = _OPT["reset"],
                 reset_timeout_s: float = _OPT["reset_timeout_s"],
                 init_timeout_s: float = _OPT["init_timeout_s"],
                 pinit_timeout_s: float = _OPT["pinit_timeout_s"],
                 tstart_timeout_s: float = _OPT["tstart_timeout_s"],
                 reply_options: int = _OPT["reply_options"],
                 log_wire: str | os.PathLike[str] | None = None) -> None:
        if not tools:
            raise ValueError("NDITracker needs at least one tool")
        if reply not in ("bx", "tx"):
            raise ValueError(f"reply must be 'bx' or 'tx', got {reply!r}")
        if baud not in p.BAUD_CODES:
            raise ValueError(f"unsupported baud {baud}; choose from {sorted(p.BAUD_CODES)}")
        o = NDISettings.check_options(
            "NDITracker", timeout_s=timeout_s, retries=retries, reset=reset,
            reset_timeout_s=reset_timeout_s, init_timeout_s=init_timeout_s,
            pinit_timeout_s=pinit_timeout_s, tstart_timeout_s=tstart_timeout_s,
            reply_options=reply_options)
        super().__init__(list(tools), frame_rate_hz)
        self.port = port
        self.rom_paths: dict[str, Path | None] = {
            k: (Path(v) if v is not None else None) for k, v in tools.items()}
        self.baud = int(baud)
        self.reply = reply
        self.timeout_s: float = o["timeout_s"]
        self.retries: int = o["retries"]
        self.reset: bool | None = o["reset"]
        self.reset_timeout_s: float = o["reset_timeout_s"]
        #: per-command reply timeouts longer than ``timeout_s``
        self.command_timeouts = {"INIT": o["init_timeout_s"], "PINIT": o["pinit_timeout_s"],
                                 "TSTART": o["tstart_timeout_s"]}
        self.reply_options: int = o["reply_options"]
        self.log_wire = Path(log_wire) if log_wire is not None else None
        self._opens = 0
        self.handles: dict[str, int] = {}
        self._ser: Any = None
        self._tracking = False
        self._identity: dict[str, Any] = {}
        #: status bits last logged, per "system" / tool name (see ``_log_status``)
        self._status_seen: dict[str, int] = {}
        #: since the port was opened: any byte arrived (a device is there), a break was sent
        self._heard = self._broke = False

    # --- lifecycle ---------------------------------------------------------------------------
    def _open(self) -> None:
        roms = self._read_roms()
        self._ser = open_port(self.name, self.port, self.timeout_s, self._wire_log_path())
        self._opens += 1
        self._ser.reset_input_buffer()
        self._status_seen.clear()
        self._heard = self._broke = False
        do_reset = self.reset if self.reset is not None else all(
            v is not None for v in self.rom_paths.values())
        if do_reset and not self.networked:
            self._break_reset()
        try:
            self._init()
        except DeviceTimeout as e:
            if self._heard:
                raise
            raise DeviceTimeout(silence_message(self.name, self.port, self.baud, self._broke),
                                device=self.name) from e
        self._identify()
        if self.baud != 9600 and not self.networked:
            self._command("COMM", f"{p.BAUD_CODES[self.baud]}0000")
            time.sleep(0.1)  # the device switches after its OKAY
            self._ser.baudrate = self.baud
        self._choose_reply()
        self._load_tools(roms)
        self._command("TSTART")
        self._tracking = True
        log.info("%s: tracking on %s, handles %s", self.name, self.port, self.handles)

    @property
    def networked(self) -> bool:
        """Whether the port is ``socket://`` (a networked tracker, or a mock): no serial
        line, so no break and no COMM."""
        return self.port.lower().startswith("socket://")

    def _wire_log_path(self) -> Path | None:
        """Where this open records the traffic: ``log_wire`` the first time, then
        ``NAME.1``, ``NAME.2`` … (the first free one), so a reconnect overwrites nothing."""
        if self.log_wire is None:
            return None
        if self._opens == 0:
            return self.log_wire
        n = self._opens
        while (cand := self.log_wire.with_name(f"{self.log_wire.name}.{n}")).exists():
            n += 1
        return cand

    def _choose_reply(self) -> None:
        """TX instead of BX on the firmware revisions whose BX fails with three or more
        tools (:data:`BX_UNRELIABLE_FIRMWARE`), said in the log."""
        tag = self._identity.get("firmware") or ""
        if self.reply == "bx" and len(self.tools) >= _BX_UNRELIABLE_FROM_TOOLS \
                and tag.strip() in BX_UNRELIABLE_FIRMWARE:
            log.warning("%s: %s: BX fails on this firmware with %d or more tools; using TX "
                        "(text) tracking replies instead", self.name, tag.strip(),
                        _BX_UNRELIABLE_FROM_TOOLS)
            self.reply = "tx"

    def _read_roms(self) -> dict[str, bytes]:
        """The tool definitions of the tools that have a .rom file, each checked before
        anything is sent (:func:`.rom.read_rom`: ``ConfigError`` naming the tool and the
        file), and a warning when they go to a tracker on another host."""
        return read_roms(self.rom_paths, self.port)

    def _close(self) -> None:
        ser = self._ser
        if ser is None:
            return
        try:
            if self._tracking:
                try:
                    self._command("TSTOP")
                except DeviceError as e:
                    log.warning("%s: TSTOP failed on close: %s", self.name, e)
        finally:
            self._tracking = False
            self._ser = None
            try:
                ser.close()
            except Exception:  # pragma: no cover - best effort
                log.debug("%s: closing the port raised", self.name, exc_info=True)

    def _break_reset(self) -> None:
        """Serial break; a real Polaris answers ``RESET`` seconds later (ndicapi waits up to
        7 s). Without that answer (no break possible, a pty) carry on with INIT."""
        self._ser.reset_input_buffer()
        try:
            self._ser.send_break(0.25)
        except (serial.SerialException, OSError, NotImplementedError) as e:
            log.debug("%s: send_break not possible (%s); INIT only", self.name, e)
            return
        self._broke = True
        raw = self._read_reply(self.reset_timeout_s)
        if raw == p.RESET_REPLY:
            log.info("%s: device reset", self.name)
            time.sleep(_AFTER_RESET_S)
        else:
            log.debug("%s: no RESET answer to the break within %g s (%r); INIT only",
                      self.name, self.reset_timeout_s, raw[:20])
        self._ser.reset_input_buffer()

    def _init(self) -> None:
        try:
            self._init_once()
        except DeviceTimeout:
            if self.baud == 9600 or self.networked:
                raise
            # a device left at the working rate by an earlier session without reset (one
            # running answers at once: after silence at 9600 the short timeout is enough)
            log.info("%s: no answer at 9600 baud; trying INIT at %d", self.name, self.baud)
            self._ser.baudrate = self.baud
            self._init_tracking_aware(None if self._heard else self.timeout_s)
        except DeviceError as e:
            if e.code != ErrorCode.INVALID_MODE:
                raise
            self._stop_then_init()

    def _init_once(self) -> None:
        """INIT; a ``RESET`` answer means the device was still resetting (a break, power-up):
        wait 100 ms and send INIT again, once."""
        try:
            self._command("INIT")
        except DeviceReset:
            log.info("%s: the device reset before INIT; sending INIT again", self.name)
            time.sleep(_AFTER_RESET_S)
            self._command("INIT")

    def _init_tracking_aware(self, timeout_s: float | None = None) -> None:
        try:
            self._command("INIT", timeout_s=timeout_s)
        except DeviceError as e:
            if isinstance(e, DeviceTimeout) or e.code != ErrorCode.INVALID_MODE:
                raise
            self._stop_then_init()

    def _stop_then_init(self) -> None:
        """INIT was refused in tracking mode (ERROR0C): an earlier host died without TSTOP and
        no break reached the device (pty, TCP). Stop tracking, then initialise."""
        log.info("%s: INIT refused in tracking mode; sending TSTOP first", self.name)
        self._command("TSTOP")
        self._command("INIT")

    def _identify(self) -> None:
        ident: dict[str, Any] = {"driver": self.name, "port": self.port}
        try:
            ver = p.parse_ver(self._command("VER", "4").text)
        except DeviceError as e:
            log.debug("%s: VER:4 refused (%s); trying VER:0", self.name, e)
            ver = p.parse_ver(self._command("VER", "0").text)
        tag = ver.get("Freeze Tag", "")
        ident["model"] = tag.rsplit(" Rev", 1)[0].strip() if " Rev" in tag \
            else ver.get("title", "unknown").replace(" Control Firmware", "")
        ident["firmware"] = tag or None
        ident["serial"] = ver.get("Serial Number") or ver.get("NDI S/N")
        try:
            info = self._command("GETINFO", "Features.Firmware.Version").text
            ident["firmware_version"] = info.partition("=")[2].split(";")[0] or info
        except DeviceError as e:
            log.debug("%s: GETINFO unavailable: %s", self.name, e)
        self._identity = ident

    def identity(self) -> dict[str, Any]:
        """{"driver", "port", "model", "firmware" (VER freeze tag), "serial",
        "firmware_version" (GETINFO, when the device has it), "handles"}."""
        return {"driver": self.name, "port": self.port, **self._identity,
                "handles": dict(self.handles)}

    def _free_handles(self, which: str) -> None:
        """PHF every handle PHSR lists for ``which`` ("00": all, "01": to be freed)."""
        for h, _ in p.decode_phsr(self._command("PHSR", which).text):
            self._command("PHF", f"{h:02X}")

    def _load_tools(self, roms: Mapping[str, bytes]) -> None:
        self._free_handles("01")
        preloaded = [t for t, path in self.rom_paths.items() if path is None]
        if not preloaded:  # we load every tool: free whatever an earlier session left
            self._free_handles("00")
        for tool, rom in roms.items():
            h = p.decode_phrq(self._command("PHRQ", _PHRQ_PASSIVE).text)
            for addr, chunk in p.rom_chunks(rom):
                self._command("PVWR", p.pvwr_params(h, addr, chunk))
            self._command("PINIT", f"{h:02X}")
            self._command("PENA", f"{h:02X}D")
            self.handles[tool] = h
        if preloaded:
            self._adopt_loaded_tools(preloaded)

    def _adopt_loaded_tools(self, preloaded: list[str]) -> None:
        """Give the tools without a .rom file the occupied handles not loaded by us, in
        handle order, initialising and enabling them where needed."""
        ours = set(self.handles.values())
        avail = [(h, s) for h, s in p.decode_phsr(self._command("PHSR", "00").text)
                 if h not in ours and s & HandleStatus.OCCUPIED]
        if len(avail) < len(preloaded):
            raise DeviceError(f"{self.name}: {len(preloaded)} tools {preloaded} should be "
                              f"loaded on the device, but only {len(avail)} occupied handles "
                              f"are free", device=self.name)
        for tool, (h, s) in zip(preloaded, sorted(avail), strict=False):
            if not s & HandleStatus.INITIALIZED:
                self._command("PINIT", f"{h:02X}")
            if not s & HandleStatus.ENABLED:
                self._command("PENA", f"{h:02X}D")
            self.handles[tool] = h

    # --- reading -----------------------------------------------------------------------------
    def _read(self) -> TrackerFrame:
        data = self._request_tracking()
        host_time = time.monotonic()
        by_handle = data.by_handle()
        self._log_status("system", int(data.system_status), SystemStatus)
        tools: dict[str, ToolState] = {}
        for tool in self.tools:
            rec = by_handle.get(self.handles.get(tool, -1))
            if rec is None:
                tools[tool] = ToolState(pose=None, missing=True)
                continue
            self._log_status(tool, int(rec.port_status) & ~_TOOL_STATE_BITS, PortStatus)
            tools[tool] = ToolState(
                pose=rec.pose if not rec.missing else None, missing=rec.missing,
                out_of_volume=rec.out_of_volume,
                partially_out_of_volume=rec.partially_out_of_volume,
                error_mm=rec.error_mm, port_status=rec.port_status)
        frame = data.frame
        return TrackerFrame(frame=frame if frame is not None else -1, host_time=host_time,
                            tools=tools, system_status=data.system_status)

    def _request_tracking(self) -> p.TrackingReply:
        """Send BX (or TX) with our reply options and decode the answer."""
        opts = f"{self.reply_options:04X}"
        if self.reply == "tx":
            return p.decode_tx(self._command("TX", opts).text)
        raw, _ = self._transact("BX", opts)
        if not p.is_bx(raw):
            p.raise_for_error(self._parse_text(raw, "BX"), f"BX:{opts}", self.name)
            raise ProtocolError(f"{self.name}: BX answered with text {raw[:40]!r}",
                                device=self.name)
        return p.decode_bx(raw)

    def _log_status(self, where: str, bits: int, flags: type[PortStatus | SystemStatus]
                    ) -> None:
        """Log status ``bits`` that a TrackerFrame does not spell out (the system status;
        port status bits beyond the ToolState fields) when they change, not every frame:
        HARDWARE_FAILURE as an error, the others as warnings."""
        if bits == self._status_seen.get(where, 0):
            return
        self._status_seen[where] = bits
        if not bits:
            log.info("%s: %s status clear again", self.name, where)
            return
        level = logging.ERROR if flags is SystemStatus \
            and bits & SystemStatus.HARDWARE_FAILURE else logging.WARNING
        log.log(level, "%s: %s status %s", self.name, where, flag_names(flags(bits)))

    # --- command / reply ---------------------------------------------------------------------
    def _command(self, name: str, params: str = "", timeout_s: float | None = None
                 ) -> p.Reply:
        """Send a text command and return its (non-error) reply; ERRORxx → DeviceError.
        ``timeout_s`` overrides the command's reply timeout."""
        raw, attempts = self._transact(name, params, timeout_s)
        reply = self._parse_text(raw, name)
        if attempts > 1 and reply.kind == ReplyKind.ERROR \
                and reply.code in _DONE_ON_RETRY.get(name, ()):
            # the first attempt was executed but its reply was lost or corrupt
            log.info("%s: %s already done before the retry (ERROR%02X)", self.name, name,
                     reply.code)
            return p.Reply(ReplyKind.OKAY, "OKAY")
        return p.raise_for_error(reply, f"{name}:{params}"[:40], self.name)

    def _parse_text(self, raw: bytes, name: str) -> p.Reply:
        reply = p.parse_reply(raw)
        if reply.kind == ReplyKind.RESET:
            self._tracking = False  # the device is back in setup mode
            raise DeviceReset(f"{self.name}: {name} was answered RESET: the device reset "
                              "(power, a serial break) and unloaded its tools; reconnect",
                              device=self.name)
        if reply.kind == ReplyKind.WARNING:
            log.warning("%s %s: WARNING%02X (%s)", self.name, name, reply.code, reply.meaning)
        return reply

    def _transact(self, name: str, params: str = "", timeout_s: float | None = None
                  ) -> tuple[bytes, int]:
        """Send ``name:params`` with CRC and return (raw reply, attempts used), re-sending
        after corrupt, torn or missing replies up to ``retries`` times; not into a line on
        which nothing has answered since the port was opened (nothing is there to answer)."""
        if self._ser is None:
            raise DeviceError(f"{self.name}: {name} on a closed port", device=self.name)
        cmd = p.encode_command(name, params)
        if timeout_s is None:
            timeout_s = max(self.timeout_s, self.command_timeouts.get(name, 0.0))
        last: DeviceError | None = None
        for attempt in range(self.retries + 1):
            if attempt:
                log.info("%s: retrying %s (attempt %d): %s", self.name, name, attempt + 1, last)
            try:
                # a late reply to an earlier command must not be taken for this one's
                self._ser.reset_input_buffer()
                self._ser.write(cmd)
            except (serial.SerialException, OSError) as e:
                raise ConnectionLost(f"{self.name}: writing {name} failed: {e}",
                                     device=self.name) from e
            raw, last = self._receive(name, timeout_s)
            if last is None:
                return raw, attempt + 1
            if not self._heard:
                break
        assert last is not None
        tries = (f"after {attempt + 1} attempts" if self._heard
                 else "not re-sent: nothing has answered on this port yet")
        raise type(last)(f"{last} ({tries})", code=last.code, text=last.text,
                         device=self.name)

    def _receive(self, name: str, timeout_s: float) -> tuple[bytes, DeviceError | None]:
        """One reply to ``name`` with its framing and CRC checked, or the problem (a corrupt,
        torn or missing reply) that makes re-sending the command worth it."""
        try:
            raw = self._read_reply(timeout_s)
        except ProtocolError as e:
            return b"", self._protocol_error(name, e)
        if not raw:
            return raw, DeviceTimeout(f"{self.name}: no reply to {name} within "
                                      f"{timeout_s:g} s", device=self.name)
        need = p.reply_length(raw)
        if need is None or len(raw) < need:
            return raw, ProtocolError(f"{self.name} {name}: torn reply {raw[:60]!r} (timed out "
                                      f"after {timeout_s:g} s)", device=self.name)
        try:
            if p.is_bx(raw):
                p.check_bx(raw)  # CRC check here so a corrupt BX is retried
            else:
                p.split_reply(raw)
        except ProtocolError as e:
            return raw, self._protocol_error(name, e)
        return raw, None

    def _protocol_error(self, name: str, e: ProtocolError) -> ProtocolError:
        """``e`` naming this device and the command ``name``, its code and text kept."""
        return ProtocolError(f"{self.name} {name}: {e}", code=e.code, text=e.text,
                             device=self.name)

    def _read_reply(self, timeout_s: float) -> bytes:
        """Bytes of one reply, or what arrived before ``timeout_s`` (possibly empty)."""
        ser = self._ser
        buf = bytearray()
        deadline = Deadline(timeout_s)
        while True:
            need = p.reply_length(buf)
            if need is not None and len(buf) >= need:
                return bytes(buf[:need])
            if deadline.expired():
                return bytes(buf)
            # ask for 6 bytes at once, then exactly the rest of a BX, or what is waiting of a
            # text reply
            want = (need - len(buf)) if need is not None else \
                max(_MIN_REPLY - len(buf), ser.in_waiting, 1)
            try:
                chunk = ser.read(want)
            except (serial.SerialException, OSError) as e:
                raise ConnectionLost(f"{self.name}: reading from {self.port} failed: {e}",
                                     device=self.name) from e
            self._heard = self._heard or bool(chunk)
            buf += chunk



class DeviceReset(ConnectionLost):
    """The tracker answered a command with ``RESET``: it reset (power, a serial break) and
    lost its initialisation and tools. A ``ConnectionLost``: reconnecting sets it up again."""
