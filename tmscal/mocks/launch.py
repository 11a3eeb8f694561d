"""Start every mock device a rig config names, all serving ONE sim rig, so the tracker sees
exactly where the robot put the coil.

Used by ``tmscal mock CONFIG`` and ``tmscal demo``. The truth of the sim rig is X =
flange_from_marker, Y = flange_from_probe, Z = base_from_tracker (4×4 mm).
"""

from __future__ import annotations

import json
import logging
import os
import select
import signal
import subprocess
import sys
from typing import Any
from urllib.parse import urlparse

import numpy as np

from ..config import RigConfig, construct
from ..errors import ConfigError
from ..net import loopback_family
from ..registry import DriverSpec, get_spec
from ..sim import (
    MOVES,
    TMS_RIG_P0,
    ArmPair,
    Change,
    Event,
    Noise,
    Settle,
    SimRig,
    Truth,
    Unreachable,
    facing_start,
    make_arm,
    tms_rig_truth,
)
from .clock import FAST, REAL_TIME, Clock

log = logging.getLogger(__name__)

__all__ = ["MockRig", "MockProcess", "build_sim_rig", "start_mock_rig", "spawn_mock_rig"]


def build_sim_rig(cfg: RigConfig) -> SimRig:
    """The sim rig of a config's ``mock`` section: truth ("tms" built-in rig, "random", or
    explicit X/Y/Z) with ``mock.changes`` applied (``sim.changes``: the rig's ``truth`` is
    the changed one; the start pose is the unchanged truth's), noise (``sim.Noise``
    fields), settling (``sim.Settle`` fields; absent: none), seed, the arm of
    ``mock.kinematics`` (absent: none; the start pose out of its reach is a ConfigError) and
    the schedule of ``mock.events``; the flange starts at P0. Neither changes nor events
    draw from the rig's RNG."""
    m = cfg.mock
    if m is None:
        raise ConfigError(f"{cfg.path}: key 'mock': this config has no mock rig")
    rng = np.random.default_rng(m.seed)
    if m.truth == "tms":
        truth, start = tms_rig_truth(), TMS_RIG_P0
    elif m.truth == "random":
        truth = Truth.random(rng)
        start = facing_start(truth)
    else:
        truth = Truth(X=m.truth["X"], Z=m.truth["Z"], Y=m.truth.get("Y"))
        start = TMS_RIG_P0
    if not isinstance(cfg.plan.start, str):
        start = np.asarray(cfg.plan.start, dtype=float)
    truth, events = _changes(cfg, truth)
    noise = construct(Noise, f"{cfg.path}: key 'mock.noise'", **m.noise)
    bodies = list(cfg.tracker.tools) if cfg.tracker else None
    settle = (None if m.settle is None
              else construct(Settle, f"{cfg.path}: key 'mock.settle'", **m.settle))
    try:
        rig = SimRig(truth, noise=noise, rng=rng, start=start, settle=settle, arm=_arm(cfg),
                     events=events)
    except Unreachable as e:
        raise ConfigError(f"{cfg.path}: key 'mock.kinematics': {e} (plan.start)") from None
    if bodies is not None:
        unknown = [b for b in bodies if b not in rig.bodies]
        if unknown:
            raise ConfigError(f"{cfg.path}: key 'tracker.tools.{unknown[0]}': the mock rig "
                              f"has bodies {rig.bodies} only")
    return rig


def _changes(cfg: RigConfig, truth: Truth) -> tuple[Truth, list[Event]]:
    """``truth`` with ``mock.changes`` applied (in the order of ``sim.changes.MOVES``,
    whatever the config's order) and the events of ``mock.events``, each checked against the
    truth it will change (a ``coil_centre`` change on a rig without a probe is a ConfigError
    naming the key)."""
    assert cfg.mock is not None
    m = cfg.mock
    for move, c in sorted((m.changes or {}).items(), key=lambda kv: MOVES.index(kv[0])):
        try:
            truth = Change(move, tuple(c["mm"]), tuple(c["deg"])).apply(truth)
        except ValueError as e:
            raise ConfigError(f"{cfg.path}: key 'mock.changes.{move}': {e}") from None
    events = [Event(e["at_s"], Change(e["move"], tuple(e["mm"]), tuple(e["deg"])))
              for e in m.events or []]
    t = truth
    for i in sorted(range(len(events)), key=lambda i: events[i].at_s):  # as the rig will
        try:
            t = events[i].change.apply(t)
        except ValueError as e:
            raise ConfigError(f"{cfg.path}: key 'mock.events[{i}].move': {e}") from None
    return truth, events


def _arm(cfg: RigConfig) -> ArmPair | None:
    """The serial arm of ``mock.kinematics`` (None when absent: no arm, as before)."""
    assert cfg.mock is not None
    k = cfg.mock.kinematics
    if k is None:
        return None
    try:
        return make_arm(k["arm"], k["errors"], k["seed"])
    except ValueError as e:
        raise ConfigError(f"{cfg.path}: key 'mock.kinematics': {e}") from None


class MockRig:
    """Running mock devices: ``endpoints`` ({"tracker": pty path, socket URL or host:port,
    "robot": host or host:port, ...}), ``rig`` (the SimRig; its truth is ``rig.truth``),
    ``close()``."""

    def __init__(self, rig: SimRig) -> None:
        self.rig = rig
        self.endpoints: dict[str, str] = {}
        self.devices: list[Any] = []

    def close(self) -> None:
        """Stop every mock device (safe twice)."""
        for d in reversed(self.devices):
            try:
                d.close()
            except Exception:
                log.warning("closing a mock failed", exc_info=True)
        self.devices.clear()

    def __enter__(self) -> MockRig:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _check_mocked(cfg: RigConfig) -> None:
    """Refuse (``ConfigError`` naming ``<kind>.driver``) a device whose driver has no mock:
    an in-process driver (``sim``) speaks no protocol, so there is nothing to serve."""
    for kind in ("robot", "tracker", "ft"):
        section = getattr(cfg, kind)
        if section is not None and get_spec(section.driver, kind).mock is None:
            raise ConfigError(f"{cfg.path}: key '{kind}.driver': driver {section.driver!r} has "
                              "no mock to serve (an in-process driver needs none: run the "
                              "config directly; docs/devices.md, \"sim (in-process)\")")


def _check_endpoints(cfg: RigConfig, tracker_transport: str,
                     robot_host: str | None) -> tuple[str, int] | None:
    """Refuse (``ConfigError``) a mock endpoint that is not on loopback, before anything
    binds. Returns the tracker's (host, port) when it is served on a ``socket://`` URL."""
    url: tuple[str, int] | None = None
    if cfg.tracker is not None and tracker_transport == "config":
        settings = cfg.tracker.settings
        address = settings.address()
        where = f"{cfg.path}: key 'tracker.{settings.ADDRESS_KEY}' ({address})"
        url = _tcp_endpoint(address, where)
        if url is not None:
            loopback_family(url[0], where)
    if cfg.robot is not None:
        host = robot_host or cfg.robot.host
        where = (f"{cfg.path}: key 'robot.host' ({host})" if robot_host is None
                 else f"robot host override ({host})")
        loopback_family(host, where)
    if cfg.ft is not None and cfg.ft.host not in (None, "robot"):
        loopback_family(cfg.ft.host, f"{cfg.path}: key 'ft.host' ({cfg.ft.host})")
    return url


def _tcp_endpoint(address: str, where: str) -> tuple[str, int] | None:
    """(host, port) of a tracker address that is a TCP endpoint (``scheme://host:port``,
    ``host:port``), else None (a device path: served on a pty). Host default 127.0.0.1."""
    url = "://" in address
    if not address or (not url and (address.startswith("/") or ":" not in address)):
        return None
    u = urlparse(address if url else f"tcp://{address}")
    try:
        port = u.port or 0
    except ValueError:
        raise ConfigError(f"{where}: not a valid port number") from None
    return (u.hostname or "127.0.0.1", port)


def start_mock_rig(cfg: RigConfig, tracker_transport: str = "config",
                   robot_host: str | None = None, robot_port: int | None = None) -> MockRig:
    """Start the mock tracker, robot and force-torque sensor (``ft``) of ``cfg`` around one
    sim rig.

    ``tracker_transport``: "pty" (a new /dev/pts), "tcp" (an ephemeral loopback port),
    or "config" (TCP at the tracker's address when it is a host and port, e.g. an NDI
    tracker's ``socket://`` port, or a ``host``/``port`` pair; else a pty).
    A tracker mock that serves TCP only (its ``TRANSPORTS``) gets an ephemeral loopback port
    where a pty was asked for.
    ``robot_host``/``robot_port`` override where the robot mock binds (loopback only).

    Every endpoint is checked before anything starts: a host that is not a loopback address
    (``socket://0.0.0.0:…``, a public address, a name that resolves elsewhere) raises
    ``ConfigError`` naming the config key and the endpoint, and nothing is bound."""
    m = cfg.mock
    if m is None:
        raise ConfigError(f"{cfg.path}: key 'mock': this config has no mock rig to serve")
    _check_mocked(cfg)
    tracker_url = _check_endpoints(cfg, tracker_transport, robot_host)
    clock = FAST if m.clock == "fast" else REAL_TIME
    mr = MockRig(build_sim_rig(cfg))
    try:
        if cfg.tracker is not None:
            tm = _tracker_mock(cfg, mr.rig, clock)
            mr.devices.append(tm)
            if clock.fast and hasattr(tm, "tracker_time_s"):
                # fast clock: the rig's time (the settling oscillation, the events' at_s) is
                # the tracker's virtual time, which advances as frames are requested
                mr.rig.use_clock(tm.tracker_time_s)
            mr.endpoints["tracker"] = _start_tracker(tm, tracker_transport, tracker_url)
        if cfg.robot is not None:
            rm = _robot_mock(cfg, mr.rig, clock, robot_host, robot_port)
            mr.devices.append(rm)
            mr.endpoints["robot"] = rm.start()
        if cfg.ft is not None:
            _ft_mock(cfg, mr, clock)
    except BaseException:
        mr.close()
        raise
    return mr


def _start_tracker(tm: Any, transport: str, url: tuple[str, int] | None) -> str:
    """Serve the tracker mock ``tm`` and return its endpoint: at the config's TCP address
    ``url`` (transport "config"), else on a pty when asked for one ("pty", or "config" with a
    device path) and the mock serves on one (its ``TRANSPORTS``), else on an ephemeral
    loopback TCP port. A driver whose protocol runs over TCP only thus gets TCP whatever the
    transport, and its settings take the ``host:port`` back (``with_address``)."""
    if url is not None:
        return str(tm.start_tcp(*url))
    if transport in ("pty", "config") and "pty" in tm.TRANSPORTS:
        return str(tm.start_pty())
    if transport == "pty":
        log.info("the %s serves TCP only: serving it on loopback TCP, not a pty",
                 type(tm).__name__)
    return str(tm.start_tcp("127.0.0.1", 0))


def _ft_mock(cfg: RigConfig, mr: MockRig, clock: Clock) -> None:
    """Serve the force-torque sensor of ``cfg.ft`` from the same rig: its gravity wrench
    (``mocks.wrench.gravity_wrench_source``: the true arm's, when the rig has one) plus the
    noise of ``mock.ft``. A driver whose mock is the robot's (``ur_wrench``: the UR's
    built-in sensor) is served by the running robot mock (``ft_raw_wrench`` and
    ``actual_TCP_force``); any other gets its own mock (the Net F/T on UDP at ``ft.host``,
    ``ft.port`` or the driver's default), started here. Endpoint ``"ft"``."""
    from .wrench import URWrenchOutputs, gravity_wrench_source

    assert cfg.ft is not None and cfg.mock is not None
    spec = get_spec(cfg.ft.driver, "ft")
    opts = dict(cfg.mock.ft)
    where = f"{cfg.path}: key 'mock.ft'"
    source = gravity_wrench_source(mr.rig)
    robot_spec = get_spec(cfg.robot.driver, "robot") if cfg.robot is not None else None
    if robot_spec is not None and spec.mock == robot_spec.mock:
        _not_overriding(cfg, "mock.ft", opts, {"seed": None})
        mr.devices[-1].wrench = construct(URWrenchOutputs, where, source, seed=cfg.mock.seed,
                                          **opts)
        mr.endpoints["ft"] = mr.endpoints["robot"]
        return
    if spec.mock is not None and any(spec.mock == s.mock for s in _robot_specs()):
        raise ConfigError(f"{cfg.path}: key 'ft.driver': {cfg.ft.driver!r} is served by its "
                          "robot's mock; the config needs that robot in its robot section")
    f = cfg.ft
    kw: dict[str, Any] = dict(
        source=source, host=f.host if f.host not in (None, "robot") else "127.0.0.1",
        port=f.port if f.port is not None else spec.default_port, clock=clock,
        faults=_faults(cfg, spec, opts.pop("faults", {})), seed=cfg.mock.seed)
    if f.settings is not None:
        kw.update(f.settings.mock_kwargs())
    _not_overriding(cfg, "mock.ft", opts, kw)
    fm = construct(spec.load_mock(), where, **kw, **opts)
    mr.devices.append(fm)
    mr.endpoints["ft"] = fm.start()


def _robot_specs() -> list[DriverSpec]:
    from ..registry import driver_names

    return [get_spec(n, "robot") for n in driver_names("robot")]


def _faults(cfg: RigConfig, spec: DriverSpec, data: Any) -> Any:
    """The driver's mock fault settings from ``mock.<kind>.faults`` (empty: none)."""
    return construct(spec.load_mock("mock_faults"),
                     f"{cfg.path}: key 'mock.{spec.kind}.faults'", **(data or {}))


def _tracker_mock(cfg: RigConfig, rig: SimRig, clock: Clock) -> Any:
    """The mock serving the configured tracker driver (from the driver registry), not yet
    started: faults and measurement volume ('default', null or a mapping) from
    ``mock.tracker``, the tools' ROM files from ``tracker.tools``."""
    assert cfg.tracker is not None and cfg.mock is not None
    spec = get_spec(cfg.tracker.driver, "tracker")
    opts = dict(cfg.mock.tracker)
    faults = _faults(cfg, spec, opts.pop("faults", {}))
    vol = opts.pop("volume", "default")
    volume_cls = spec.load_mock("mock_volume")
    volume = (volume_cls() if vol == "default" else None if vol is None
              else construct(volume_cls, f"{cfg.path}: key 'mock.tracker.volume'", **vol))
    tools = {k: v for k, v in cfg.tracker.tools.items() if v is not None} or None
    kw = dict(clock=clock, faults=faults, volume=volume, seed=cfg.mock.seed)
    _not_overriding(cfg, "mock.tracker", opts, kw)
    return construct(spec.load_mock(), f"{cfg.path}: key 'mock.tracker'", rig, tools, **kw,
                     **opts)


def _robot_mock(cfg: RigConfig, rig: SimRig, clock: Clock, host: str | None,
                port: int | None) -> Any:
    """The mock serving the configured robot driver (from the driver registry), not yet
    started, on ``host`` (default ``robot.host``) and, for a driver with a default port,
    ``port`` (default ``robot.port``, then the driver's default)."""
    assert cfg.robot is not None and cfg.mock is not None
    spec = get_spec(cfg.robot.driver, "robot")
    opts = dict(cfg.mock.robot)
    kw: dict[str, Any] = dict(host=host or cfg.robot.host, clock=clock,
                              faults=_faults(cfg, spec, opts.pop("faults", {})))
    if spec.default_port is not None:
        port = cfg.robot.port if port is None else port
        kw["port"] = spec.default_port if port is None else port
    _not_overriding(cfg, "mock.robot", opts, kw)
    return construct(spec.load_mock(), f"{cfg.path}: key 'mock.robot'", rig, **kw, **opts)


def _not_overriding(cfg: RigConfig, section: str, opts: dict[str, Any],
                    given: dict[str, Any]) -> None:
    """A mock option may not name an argument that comes from elsewhere in the config."""
    for k in opts:
        if k in given:
            raise ConfigError(f"{cfg.path}: key '{section}.{k}': '{k}' cannot be set here; it "
                              "comes from the rest of the config")


class MockProcess:
    """``tmscal mock CONFIG --json`` running in a child process (needed for ur_rtde, whose
    constructors hold the GIL and so cannot talk to a mock thread of the same process).
    ``endpoints`` as printed by the child; ``close()`` sends SIGTERM and waits."""

    def __init__(self, config: str | os.PathLike[str], transport: str = "pty",
                 timeout_s: float = 30.0, extra_args: list[str] | None = None) -> None:
        cmd = [sys.executable, "-m", "tmscal.cli", "mock", str(config), "--json",
               "--transport", transport, *(extra_args or [])]
        self.proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                     stdin=subprocess.DEVNULL, text=True)
        self.endpoints: dict[str, str] = {}
        line = self._first_line(timeout_s)
        try:
            self.endpoints = json.loads(line)
        except json.JSONDecodeError:
            err = self._stop_and_stderr()
            last = (err or line).strip().splitlines()
            raise ConfigError(f"mock for {config} did not start: "
                              f"{last[-1] if last else 'no output'}") from None

    def _first_line(self, timeout_s: float) -> str:
        assert self.proc.stdout is not None
        ready, _, _ = select.select([self.proc.stdout], [], [], timeout_s)
        if not ready:
            self._stop_and_stderr()
            raise ConfigError(f"mock did not print its endpoints within {timeout_s:g} s")
        return self.proc.stdout.readline()

    def _stop_and_stderr(self) -> str:
        self.close()
        assert self.proc.stderr is not None
        try:
            return self.proc.stderr.read()
        except ValueError:
            return ""

    def close(self) -> None:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(5)

    def __enter__(self) -> MockProcess:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def spawn_mock_rig(config: str | os.PathLike[str], transport: str = "pty",
                   timeout_s: float = 30.0) -> MockProcess:
    """Start ``tmscal mock CONFIG`` in a child process and return it once it has printed its
    endpoints ({"tracker": ..., "robot": ...})."""
    return MockProcess(config, transport, timeout_s)
