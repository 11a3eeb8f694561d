"""A Franka FR3 for the mock rig: franky-sim's embedded ``SimulationServer`` (MuJoCo physics,
libfranka's network protocol, 1 kHz in real time) serving ONE ``tmscal.sim.SimRig``.

Nobody on this project wrote the simulator: the driver (``tmscal.drivers.franka``, on the
unmodified ``franky`` client) is tested against an independent implementation of the FCI
protocol. The mock adds three things around it:

* **The rig follows the arm.** After every ``update_every`` simulation steps (5 ms by default)
  the flange pose is computed from the simulated joint angles with the FR3's own kinematic
  model (pinocchio, the URDF franky-sim ships, frame ``link8`` = the flange), independently of
  the ``O_T_EE`` / ``F_T_EE`` the controller reports, and put into the sim rig
  (``SimRig.move_flange``) when it moved by more than 1 µm or 1 µrad. The mock Polaris then
  observes marker and probe there with the rig's truth X, Y, Z. ``mock.noise``'s robot
  positioning error would be drawn anew at every update: keep ``robot_*_sigma`` at 0 (the
  simulator's own tracking error is the robot error).
* **The arm starts at the rig's start pose** (``plan.start`` or the built-in P0): the initial
  joint angles come from a damped least-squares inverse kinematics on the same model (or
  ``initial_q``, rad, from ``mock.robot``).
* **O_T_EE is the measured pose**, as libfranka documents it: franky-sim 1.0.4 reports the
  desired pose there (``_measured_o_t_ee`` says why and restores it).
* **Loopback only.** franky-sim 1.0.4 binds its TCP command port to the given host but its UDP
  state socket to 0.0.0.0; the servers here bind the UDP socket to the same loopback host.

The end effector is franky-sim's default, the Franka Hand (``F_T_NE`` = 103.4 mm along z,
−45° about z), so flange and end effector differ as on most real arms. franky-sim simulates an
FR3 and produces no controller errors (no reflexes, no joint-limit or
communication-constraint checks): ``FrankaFaults`` has no faults to inject.

``mock.clock`` must be ``real``: libfranka's control loop runs at 1 kHz of wall-clock time.
``mock.kinematics`` may name only ``fr3`` (the arm franky-sim simulates, docs/kinematics.md):
the rig then puts the flange where the TRUE arm is at the joints that reach franky-sim's
flange, so the tracker sees the hidden errors and the controller reports the nominal arm.
"""

from __future__ import annotations

import logging
import socket
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from ...calib.kinematics.ik import inverse_of
from ...errors import ConfigError, MissingExtraError
from ...geometry import angle_between
from ...net import listen_error, loopback_family
from ...sim import SimRig
from ..clock import REAL_TIME, Clock
from ..server import MockDevice

log = logging.getLogger(__name__)

__all__ = ["FrankaMock", "FrankaFaults", "flange_ik"]

_MOVED_MM = 1e-3   # the rig is updated when the flange moved more than this (mm) …
_MOVED_RAD = 1e-6  # … or turned more than this (rad)


@dataclass(frozen=True)
class FrankaFaults:
    """No faults: franky-sim produces no controller errors to inject (module docstring)."""


def _sim_modules() -> tuple[Any, Any, Any, Any]:
    """(franky_sim, its MuJoCo simulator module, its server module, pinocchio)."""
    try:
        import franky_sim
        import franky_sim.franka_gripper_server as gripper
        import franky_sim.mujoco_simulator as mj
        import pinocchio
    except ImportError as e:
        raise MissingExtraError("the 'franka' mock (franky-sim)", "test", str(e)) from e
    return franky_sim, mj, gripper, pinocchio


def _flange_model(pin: Any, urdf: str) -> tuple[Any, Any, int]:
    model = pin.buildModelFromXML(urdf)
    return model, model.createData(), model.getFrameId("link8")


def flange_ik(target_mm: np.ndarray, q0: Sequence[float], iterations: int = 200
              ) -> np.ndarray:
    """Joint angles (7, rad) that put the simulated FR3's flange (``link8``) at ``target_mm``
    (base_from_flange, 4×4 mm), from ``q0`` by tmscal's one inverse kinematics
    (:func:`tmscal.calib.kinematics.ik.inverse_of`) on the URDF model's forward kinematics.
    ``ValueError`` when it does not converge within the joint limits."""
    franky_sim, _, _, pin = _sim_modules()
    model, data, fid = _flange_model(pin, franky_sim.FR3_URDF)

    def forward(Q: np.ndarray) -> np.ndarray:
        out = np.empty((len(Q), 4, 4))
        for k, q in enumerate(Q):
            pin.forwardKinematics(model, data, q)
            pin.updateFramePlacement(model, data, fid)
            out[k] = data.oMf[fid].homogeneous
        out[:, :3, 3] *= 1000.0
        return out

    limits = np.stack([model.lowerPositionLimit, model.upperPositionLimit], axis=1)
    q = inverse_of(forward, np.asarray(target_mm, dtype=np.float64),
                   [np.asarray(q0, dtype=np.float64)], limits, max_iter=iterations)
    if q is None:
        raise ValueError(f"the simulated FR3 cannot reach the start pose "
                         f"{np.round(target_mm[:3, 3], 1).tolist()} mm within its joint limits "
                         "(no IK solution)")
    return q


def _loopback_servers(franky_sim: Any, gripper_mod: Any) -> tuple[type, type]:
    """franky-sim's robot and gripper servers with the UDP socket bound to the command host
    (franky-sim 1.0.4 binds it to 0.0.0.0). The override writes the same attributes as the
    library's ``FrankaServer._setup_udp_connection``."""
    from franky_sim.franka_server import FrankaServer, NonBlockingReceiver

    def setup_udp(self: Any, network_udp_port: int) -> None:
        s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        s.bind((self.hostname, 0))
        s.setblocking(False)
        self._FrankaServer__client_udp_port = network_udp_port
        self._FrankaServer__udp_socket = s
        self._FrankaServer__udp_receiver = NonBlockingReceiver(s)
        self._FrankaServer__message_id = 0

    if not hasattr(FrankaServer, "_setup_udp_connection"):  # pragma: no cover - other version
        raise ConfigError("the 'franka' mock needs franky-sim 1.0.x (its UDP socket setup "
                          "changed): pip install 'franky-sim>=1.0.4,<1.1'")
    gripper = type("LoopbackGripperServer", (gripper_mod.FrankaGripperServer,),
                   {"_setup_udp_connection": setup_udp})

    def bind_children(self: Any, hostname: str) -> None:
        if self._FrankaRobotServer__robot.has_gripper:
            g = gripper(self._FrankaRobotServer__robot, hostname)
            g.init()
            self._FrankaRobotServer__gripper_server = g

    robot = type("LoopbackRobotServer", (franky_sim.FrankaRobotServer,),
                 {"_setup_udp_connection": setup_udp, "_bind_children": bind_children})
    return robot, gripper


def _measured_o_t_ee(robot: Any) -> None:
    """franky-sim 1.0.4's ``BaseRobot.kinematics`` returns pinocchio's frame placement by
    reference, and the desired pose ``O_T_EE_d`` is computed after the measured ``O_T_EE`` in
    every step, so the reported ``O_T_EE`` aliases ``O_T_EE_d`` (the commanded pose, not the
    measured one libfranka documents). A copy per call, on this robot only, restores it."""
    kinematics = robot.kinematics
    robot.kinematics = lambda q: kinematics(q).copy()


class FrankaMock(MockDevice):
    """franky-sim serving ``rig`` on ``host`` (loopback; libfranka's fixed ports, TCP 1337).

    ``start()`` returns the host. ``initial_q`` (7 rad) overrides the joint angles computed
    from the rig's start pose; ``update_every`` is how many 1 ms simulation steps pass between
    two updates of the rig's flange. ``clock`` must be the real-time clock."""

    def __init__(self, rig: SimRig, host: str = "127.0.0.2", clock: Clock = REAL_TIME,
                 faults: FrankaFaults | None = None, initial_q: Sequence[float] | None = None,
                 update_every: int = 5) -> None:
        loopback_family(host, "franka mock host")
        if rig.arm_nominal is not None and rig.arm_nominal.name != "fr3":
            raise ValueError(f"franky-sim simulates an FR3: mock.kinematics.arm must be fr3 (its "
                             f"hidden errors then move the flange the tracker sees) or absent, "
                             f"not {rig.arm_nominal.name}")
        if clock.fast:
            raise ValueError("the franka mock runs franky-sim, whose 1 kHz control loop needs "
                             "wall-clock time: set mock.clock: real")
        if isinstance(update_every, bool) or not isinstance(update_every, int) \
                or not 1 <= update_every <= 1000:
            raise ValueError(f"update_every must be an integer in 1..1000, got {update_every!r}")
        if initial_q is not None:
            q = np.array(initial_q, dtype=np.float64)
            if q.shape != (7,) or not np.isfinite(q).all():
                raise ValueError(f"initial_q must be 7 finite joint angles (rad), got "
                                 f"{initial_q!r}")
        self.rig = rig
        self.host = host
        self.faults = faults or FrankaFaults()
        self.initial_q = None if initial_q is None else [float(v) for v in initial_q]
        self.update_every = update_every
        self._sim: Any = None
        self._server: Any = None
        self._steps = 0
        self._last: np.ndarray | None = None

    def _start(self) -> str:
        franky_sim, mj, gripper_mod, pin = _sim_modules()
        from franky_sim import DEFAULT_INITIAL_JOINT_POS, SimulationServer
        q0 = self.initial_q
        if q0 is None:
            q0 = flange_ik(self.rig.reported_flange(), DEFAULT_INITIAL_JOINT_POS).tolist()
        robot_server, _ = _loopback_servers(franky_sim, gripper_mod)

        class Server(SimulationServer):
            def init(self) -> None:  # as SimulationServer.init, with the loopback servers
                for robot in self.sim.robots:
                    rs = robot_server(robot, self._remaining_hostname_candidates)
                    rs.init()
                    self.robot_servers.append(rs)
                self.sim.start()

        self._model, self._data, self._fid = _flange_model(pin, franky_sim.FR3_URDF)
        self._pin = pin
        self._sim = mj.MujocoSimulator()
        self._sim.init()
        self._robot = self._sim.add_robot(initial_q=tuple(q0))
        _measured_o_t_ee(self._robot)
        self._server = Server(self._sim, hostname_candidates=[self.host])
        try:
            self._server.init()
        except OSError as e:
            raise listen_error(e, "franka mock", self.host, 1337) from e
        self._sim.register_post_step_callback(self._after_step)
        self._update_rig(force=True)
        self._server.run_async()
        log.info("franka mock (franky-sim FR3) on %s", self.host)
        return self.host

    def _flange_mm(self) -> np.ndarray:
        """base_from_flange (4×4 mm) from the simulated joint angles (the model's link8)."""
        q = np.asarray(self._robot.inner_state.q, dtype=np.float64)
        self._pin.forwardKinematics(self._model, self._data, q)
        self._pin.updateFramePlacement(self._model, self._data, self._fid)
        T = np.array(self._data.oMf[self._fid].homogeneous)
        T[:3, 3] *= 1000.0
        return T

    def _after_step(self, sim: Any) -> None:
        self._steps += 1
        if self._steps % self.update_every == 0:
            self._update_rig()

    def _update_rig(self, force: bool = False) -> None:
        T = self._flange_mm()
        last = self._last
        if not force and last is not None \
                and np.linalg.norm(T[:3, 3] - last[:3, 3]) <= _MOVED_MM \
                and float(angle_between(last, T)) <= _MOVED_RAD:
            return
        self._last = T
        self.rig.move_flange(T)

    @property
    def _sockets(self) -> list[socket.socket]:
        """Every socket franky-sim's servers hold now (the listening TCP socket, a client's
        TCP connection, the UDP state socket once a client connected; the gripper's too), so
        tests can check what the mock binds."""
        out: list[socket.socket] = []
        servers = list(self._server.robot_servers) if self._server is not None else []
        servers += [g for rs in servers
                    if (g := getattr(rs, "_FrankaRobotServer__gripper_server", None))]
        for srv in servers:
            for name in ("server_socket", "tcp_socket", "udp_socket"):
                sock = getattr(srv, f"_FrankaServer__{name}", None)
                if sock is not None and sock.fileno() >= 0:
                    out.append(sock)
        return out

    def flange(self) -> np.ndarray:
        """The flange pose (base_from_flange, 4×4 mm) last put into the rig."""
        assert self._last is not None, "franka mock not started"
        return self._last.copy()

    def _close(self) -> None:
        server, sim, self._server, self._sim = self._server, self._sim, None, None
        if server is not None:
            try:
                server.cleanup()
            except Exception:  # franky-sim's own errors at shutdown: best effort
                log.warning("franka mock: server cleanup failed", exc_info=True)
        if sim is not None and sim.is_initialized and not sim.is_cleaned_up:
            try:
                sim.cleanup()
            except Exception:
                log.warning("franka mock: simulator cleanup failed", exc_info=True)
