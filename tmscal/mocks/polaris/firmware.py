"""The Polaris mock's firmware: the NDI Combined API command interpreter, transport-free.

:class:`PolarisFirmware` answers one command line at a time (:meth:`~PolarisFirmware.
handle_line`) through a table from command name to handler. It models the setup /
initialised / tracking state machine with NDI's error codes for commands in the wrong state,
the port handles and the tool definitions loaded into them, identity (VER, GETINFO) and
tracking (TX, BX; the frames come from :class:`~.frames.FrameSource`), and injects reply
faults (:class:`~.model.PolarisFaults`). Encoding and decoding go through
:mod:`tmscal.drivers.ndi.protocol`, the codec the driver uses.
"""

from __future__ import annotations

import logging
import os
import threading
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from enum import StrEnum
from pathlib import Path
from typing import ClassVar

import numpy as np

from ...drivers.ndi import protocol as p
from ...drivers.ndi.codes import ErrorCode, HandleStatus, ReplyOption, ToolInfoStatus
from ...errors import ProtocolError
from ...sim.rig import SimRig
from ..clock import REAL_TIME, Clock
from .delays import CommandDelays
from .frames import FrameSource
from .model import MODELS, MeasurementVolume, PolarisFaults

log = logging.getLogger(__name__)


class MockState(StrEnum):
    """The mock Polaris's mode: SETUP after a reset (only INIT and a few queries are
    accepted), READY after INIT (tools are loaded and enabled), TRACKING after TSTART."""

    SETUP = "setup"
    READY = "ready"
    TRACKING = "tracking"

__all__ = ["PolarisFirmware", "MockState", "MAX_HANDLES"]

MAX_HANDLES = 12
_FIRST_HANDLE = 0x01
_MAX_ROM_BYTES = 0x10000
_MAX_LINE = 4096
_TRACKING_COMMANDS = ("TX", "BX")
_MODELLED_OPTIONS = ReplyOption.TRANSFORMS | ReplyOption.OUT_OF_VOLUME


class _Handle:
    def __init__(self, number: int) -> None:
        self.number = number
        self.rom = bytearray()
        self.occupied = False
        self.initialized = False
        self.enabled = False
        self.body: str | None = None

    @property
    def status(self) -> HandleStatus:
        return ((HandleStatus.OCCUPIED if self.occupied else HandleStatus(0))
                | (HandleStatus.INITIALIZED if self.initialized else 0)
                | (HandleStatus.ENABLED if self.enabled else 0))


#: PHSR reply option → which handles it lists
_PHSR_SELECT: dict[str, Callable[[_Handle], bool]] = {
    "00": lambda h: True,
    "01": lambda h: False,  # the mock never marks handles to be freed
    "02": lambda h: h.occupied and not h.initialized,
    "03": lambda h: h.initialized and not h.enabled,
    "04": lambda h: h.enabled,
}


class _Reply(Exception):
    """Internal: answer the current command with ERRORxx."""

    def __init__(self, code: int) -> None:
        super().__init__(code)
        self.code = int(code)


@dataclass(frozen=True)
class _Spec:
    """A command: its handler, whether it is allowed before INIT (else ERROR10) and whether
    it is refused while tracking (ERROR0C, checked before the parameters)."""

    handler: Callable[[PolarisFirmware, str], bytes]
    in_setup: bool = False
    not_tracking: bool = False


class PolarisFirmware:
    """An NDI Polaris's command interpreter serving ``rig`` (transport-free).

    Parameters (keyword-only after ``rig``):

    * ``rig``: the :class:`SimRig` whose bodies are tracked (poses tracker_from_body, mm).
    * ``tools``: our tool/body name → path of the .rom file that identifies it (e.g.
      ``{"marker": "configs/tools/marker-8700340.rom", "probe": ...}``); every name must be a
      rig body. ``None``: the rig's bodies, matched in order of loading. A loaded definition
      is matched to a body by comparing its bytes (zero padding stripped) with these files;
      unmatched definitions take the remaining bodies in order of loading.
    * ``model``: ``"spectra"`` (60 Hz) or ``"vicra"`` (20 Hz).
    * ``clock``: :data:`~tmscal.mocks.clock.REAL_TIME` or :data:`~tmscal.mocks.clock.FAST`.
    * ``volume``: :class:`MeasurementVolume` (default Spectra-like) or None for no limits.
    * ``faults``: :class:`PolarisFaults` (default: none).
    * ``seed``: seeds the fault RNG.
    * ``freeze_tag``: override the ``Freeze Tag:`` of VER (scikit-surgerynditracker picks TX
      instead of BX for "Polaris Spectra Rev 007"; the Vicra tag makes it use BX).
    * ``error_mm``: the RMS fit error reported for every tool (mm).
    * ``reset_delay_s``: from a break (:meth:`serial_break`) or the RESET command to the
      ``RESET`` reply, during which nothing is answered (None: 3 s on the real-time clock, 0
      on the fast one). ``init_delay_s``, ``pinit_delay_s``, ``tstart_delay_s``: how long
      INIT, PINIT and TSTART take (default 0). See :mod:`.delays`.
    """

    def __init__(self, rig: SimRig, tools: Mapping[str, str | os.PathLike[str]] | None = None,
                 *, model: str = "spectra", clock: Clock = REAL_TIME,
                 volume: MeasurementVolume | None = MeasurementVolume(),
                 faults: PolarisFaults | None = None, seed: int = 0,
                 freeze_tag: str | None = None, error_mm: float = 0.1,
                 reset_delay_s: float | None = None, init_delay_s: float = 0.0,
                 pinit_delay_s: float = 0.0, tstart_delay_s: float = 0.0) -> None:
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
        self.delays = CommandDelays.make(clock, reset_delay_s, init_delay_s, pinit_delay_s,
                                         tstart_delay_s)
        #: monotonic time at which a reset in progress ends with RESET (None: no reset)
        self._reset_until: float | None = None
        #: set when the mock closes: cuts a command delay short
        self._stopping = threading.Event()
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
        s_frame, s_reply = np.random.SeedSequence(seed).spawn(2)
        self._reply_rng = np.random.default_rng(s_reply)
        self._frames = FrameSource(rig, clock, self.rate_hz, volume, self.faults,
                                   np.random.default_rng(s_frame), self.error_mm)
        self._lock = threading.RLock()
        #: every command line received (decoded, CRC stripped), for tests asserting sequences
        self.commands: list[str] = []
        self._power_up()

    def tracker_time_s(self) -> float:
        """The tracker's time in seconds: on the fast clock frames served / frame rate (it
        advances only as TX/BX requests are answered), else the clock's monotonic time. The
        mock rig makes it the sim rig's time base on the fast clock."""
        return self._frames.time_s()

    # --- state -------------------------------------------------------------------------------
    def _power_up(self) -> None:
        with self._lock:
            self.state = MockState.SETUP  # SETUP → INIT → READY → TSTART → TRACKING
            self._handles: dict[int, _Handle] = {}
            self._frames.restart()

    def serial_break(self) -> None:
        """What a serial break does to a real Polaris: it resets (:meth:`reset`), answers
        nothing for ``reset_delay_s`` and then sends ``RESET`` by itself (see
        :meth:`pending_output`). A pty or TCP link cannot carry a break, so tests call this."""
        with self._lock:
            self._power_up()
            self._reset_until = self.clock.now() + self.delays.reset_s

    def pending_output(self) -> list[bytes]:
        """Replies the device sends by itself now (the ``RESET`` that ends a reset); the
        transports call this between reads."""
        with self._lock:
            if self._reset_until is None or self.clock.now() < self._reset_until:
                return []
            self._reset_until = None
            return [p.RESET_REPLY]

    def reset(self) -> None:
        """Device reset (what a serial break does on real hardware): handles freed, back to
        setup mode, frame counter restarted."""
        self._power_up()

    @property
    def handles(self) -> dict[int, str | None]:
        """Allocated port handles → the rig body each was identified as (None if none)."""
        with self._lock:
            return {h.number: h.body for h in self._handles.values()}

    # --- lines in, replies out ---------------------------------------------------------------
    def _feed(self, buf: bytearray, data: bytes) -> list[bytes]:
        """Append received bytes to a connection's ``buf``; answer every complete command
        line (a line longer than the device accepts is answered ERROR02 and dropped)."""
        buf += data
        out = []
        while True:
            i = buf.find(b"\r")
            if i < 0:
                if len(buf) > _MAX_LINE:
                    buf.clear()
                    out.append(p.encode_error(ErrorCode.COMMAND_TOO_LONG))
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

    def handle_line(self, line: bytes) -> bytes | None:
        """Answer one command line (without ``\\r``); None means the reply is dropped (fault
        injection). Transport-independent; thread-safe."""
        with self._lock:
            if self._reset_until is not None:  # resetting: the device reads nothing
                log.debug("Polaris mock: resetting, %r ignored", line[:20])
                return None
            try:
                cmd = p.parse_command(line)
            except ProtocolError as e:
                self.commands.append(line.decode("ascii", "replace"))
                return self._maybe_fault(p.encode_error(int(e.code or 1)), tracking=False)
            self.commands.append(f"{cmd.name}:{cmd.params}" if cmd.had_crc
                                 else f"{cmd.name} {cmd.params}".rstrip())
            try:
                reply = self._dispatch(cmd)
            except _Reply as r:
                reply = p.encode_error(r.code)
        delay = self.delays.of(cmd.name)
        if delay > 0:  # a slow command: the reply comes late (close() cuts it short)
            self._stopping.wait(delay)
        if not reply:  # a command the device leaves unanswered
            return None
        with self._lock:
            return self._maybe_fault(reply, cmd.name in _TRACKING_COMMANDS)

    def _maybe_fault(self, reply: bytes, tracking: bool) -> bytes | None:
        f = self.faults
        if f.tracking_only and not tracking:
            return reply
        if f.drop_reply_prob > 0 and self._reply_rng.random() < f.drop_reply_prob:
            log.debug("Polaris mock: dropping reply %r", reply[:20])
            return None
        if f.crc_error_prob > 0 and self._reply_rng.random() < f.crc_error_prob:
            b = bytearray(reply)
            if p.is_bx(b):
                b[-1] ^= 0x5A  # body CRC (header stays exact so the length is readable)
            else:
                k = len(b) - 2  # last CRC digit, kept a hex digit
                b[k] = ord("0") if b[k] != ord("0") else ord("1")
            return bytes(b)
        return reply

    def _dispatch(self, cmd: p.Command) -> bytes:
        spec = self._COMMANDS.get(cmd.name)
        if spec is None:
            raise _Reply(ErrorCode.INVALID_COMMAND)
        if self.state == MockState.SETUP and not spec.in_setup:
            raise _Reply(ErrorCode.SYSTEM_NOT_INITIALIZED)
        if spec.not_tracking and self.state == MockState.TRACKING:
            raise _Reply(ErrorCode.INVALID_MODE)
        return spec.handler(self, cmd.params.strip())

    def _handle(self, text: str) -> _Handle:
        try:
            h = int(text, 16)
        except ValueError:
            raise _Reply(ErrorCode.INVALID_PORT_HANDLE) from None
        if len(text) != 2 or h not in self._handles:
            raise _Reply(ErrorCode.INVALID_PORT_HANDLE)
        return self._handles[h]

    @staticmethod
    def _need_length(prm: str, *lengths: int) -> None:
        if len(prm) not in lengths:
            raise _Reply(ErrorCode.WRONG_PARAMETER_COUNT)

    # --- system ------------------------------------------------------------------------------
    def _cmd_init(self, prm: str) -> bytes:
        self.state = MockState.READY
        return p.OKAY_REPLY

    def _cmd_reset(self, prm: str) -> bytes:
        self._power_up()
        return p.frame_reply("RESET")

    def _cmd_comm(self, prm: str) -> bytes:
        if len(prm) != 5 or prm[0].upper() not in p.BAUD_FROM_CODE or prm[1] not in "01" \
                or prm[2] not in "012" or prm[3] not in "01" or prm[4] not in "01":
            raise _Reply(ErrorCode.BAD_COMM_PARAMETERS)
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
            raise _Reply(ErrorCode.PARAMETER_OUT_OF_RANGE)
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
            raise _Reply(ErrorCode.PARAMETER_OUT_OF_RANGE)
        return p.frame_reply(f"{prm}={info[prm]}")

    def _cmd_beep(self, prm: str) -> bytes:
        if prm not in tuple("123456789"):
            raise _Reply(ErrorCode.PARAMETER_OUT_OF_RANGE)
        return p.frame_reply("1")

    def _cmd_apirev(self, prm: str) -> bytes:
        return p.frame_reply("G.001.005")

    # --- port handles ------------------------------------------------------------------------
    def _cmd_phrq(self, prm: str) -> bytes:
        self._need_length(prm, 14)
        free = [n for n in range(_FIRST_HANDLE, _FIRST_HANDLE + MAX_HANDLES)
                if n not in self._handles]
        if not free:
            raise _Reply(ErrorCode.NO_MORE_HANDLES)
        h = _Handle(free[0])
        self._handles[h.number] = h
        return p.frame_reply(f"{h.number:02X}")

    def _cmd_pvwr(self, prm: str) -> bytes:
        self._need_length(prm, 2 + 4 + 128)
        h = self._handle(prm[:2])
        try:
            addr = int(prm[2:6], 16)
            chunk = bytes.fromhex(prm[6:])
        except ValueError:
            raise _Reply(ErrorCode.PARAMETER_OUT_OF_RANGE) from None
        if addr % 64 or addr + 64 > _MAX_ROM_BYTES:
            raise _Reply(ErrorCode.PARAMETER_OUT_OF_RANGE)
        if h.initialized:
            raise _Reply(ErrorCode.INVALID_MODE)
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
        self._need_length(prm, 2)
        h = self._handle(prm)
        if not h.occupied:
            raise _Reply(ErrorCode.NO_TOOL)
        if not h.initialized:
            h.body = self._identify(h)
            h.initialized = True
            log.debug("Polaris mock: handle %02X is %s", h.number, h.body)
        return p.OKAY_REPLY

    def _cmd_pena(self, prm: str) -> bytes:
        self._need_length(prm, 3)
        h = self._handle(prm[:2])
        if prm[2].upper() not in "SDB":
            raise _Reply(ErrorCode.INVALID_PRIORITY)
        if not h.initialized:
            raise _Reply(ErrorCode.HANDLE_NOT_INITIALIZED)
        h.enabled = True
        return p.OKAY_REPLY

    def _cmd_pdis(self, prm: str) -> bytes:
        h = self._handle(prm[:2])
        if not h.enabled:
            raise _Reply(ErrorCode.HANDLE_NOT_ENABLED)
        h.enabled = False
        return p.OKAY_REPLY

    def _cmd_phf(self, prm: str) -> bytes:
        self._need_length(prm, 2)
        h = self._handle(prm)
        del self._handles[h.number]
        return p.OKAY_REPLY

    def _cmd_phsr(self, prm: str) -> bytes:
        select = _PHSR_SELECT.get(prm or "00")
        if select is None:
            raise _Reply(ErrorCode.PARAMETER_OUT_OF_RANGE)
        hs = sorted(self._handles.values(), key=lambda h: h.number)
        return p.frame_reply(p.encode_phsr([(h.number, h.status) for h in hs if select(h)]))

    def _cmd_phinf(self, prm: str) -> bytes:
        self._need_length(prm, 2, 6)
        h = self._handle(prm[:2])
        if not h.occupied:
            return p.frame_reply("UNOCCUPIED")
        status = ToolInfoStatus.OCCUPIED \
            | (ToolInfoStatus.INITIALIZED if h.initialized else 0) \
            | (ToolInfoStatus.ENABLED if h.enabled else 0)
        text = ("0A000000" + "NDI".ljust(12) + "000" + f"{0x8700340 + h.number:08X}"
                + f"{status:02X}")
        return p.frame_reply(text)

    # --- tracking ----------------------------------------------------------------------------
    def _cmd_tstart(self, prm: str) -> bytes:
        if prm not in ("", "80"):
            raise _Reply(ErrorCode.PARAMETER_OUT_OF_RANGE)
        if prm == "80":
            self._frames.restart(observations=False)
        self.state = MockState.TRACKING
        return p.OKAY_REPLY

    def _cmd_tstop(self, prm: str) -> bytes:
        if self.state != MockState.TRACKING:
            raise _Reply(ErrorCode.INVALID_MODE)
        self.state = MockState.READY
        return p.OKAY_REPLY

    def _options(self, prm: str) -> int:
        if prm == "":
            return ReplyOption.TRANSFORMS
        try:
            opt = int(prm, 16)
        except ValueError:
            raise _Reply(ErrorCode.PARAMETER_OUT_OF_RANGE) from None
        if len(prm) != 4 or opt & ~_MODELLED_OPTIONS or not opt & ReplyOption.TRANSFORMS:
            raise _Reply(ErrorCode.PARAMETER_OUT_OF_RANGE)  # other options are not modelled
        return opt

    def _tracking_records(self, prm: str) -> tuple[list[p.HandleRecord], int]:
        opt = self._options(prm)
        if self.state != MockState.TRACKING:
            raise _Reply(ErrorCode.INVALID_MODE)
        enabled = [(h.number, h.body)
                   for h in sorted(self._handles.values(), key=lambda h: h.number) if h.enabled]
        return self._frames.records(enabled, opt)

    def _cmd_tx(self, prm: str) -> bytes:
        return p.frame_reply(p.encode_tx(*self._tracking_records(prm)))

    def _cmd_bx(self, prm: str) -> bytes:
        limit = self.faults.bx_fails_from_tools
        if limit and sum(h.enabled for h in self._handles.values()) >= limit:
            return b""  # the firmware fault: no BX reply with this many tools (TX works)
        return p.encode_bx(*self._tracking_records(prm))

    _COMMANDS: ClassVar[dict[str, _Spec]] = {
        "INIT": _Spec(_cmd_init, in_setup=True, not_tracking=True),
        "RESET": _Spec(_cmd_reset, in_setup=True),
        "COMM": _Spec(_cmd_comm, in_setup=True),
        "VER": _Spec(_cmd_ver, in_setup=True),
        "GETINFO": _Spec(_cmd_getinfo, in_setup=True),
        "BEEP": _Spec(_cmd_beep, in_setup=True),
        "APIREV": _Spec(_cmd_apirev, in_setup=True),
        "PHRQ": _Spec(_cmd_phrq, not_tracking=True),
        "PVWR": _Spec(_cmd_pvwr, not_tracking=True),
        "PINIT": _Spec(_cmd_pinit, not_tracking=True),
        "PENA": _Spec(_cmd_pena, not_tracking=True),
        "PDIS": _Spec(_cmd_pdis, not_tracking=True),
        "PHF": _Spec(_cmd_phf, not_tracking=True),
        "PHSR": _Spec(_cmd_phsr, not_tracking=True),
        "PHINF": _Spec(_cmd_phinf, not_tracking=True),
        "TSTART": _Spec(_cmd_tstart, not_tracking=True),
        "TSTOP": _Spec(_cmd_tstop),
        "TX": _Spec(_cmd_tx),
        "BX": _Spec(_cmd_bx),
    }
