"""The sim robot (``robot: {driver: sim}``): a robot arm that moves the sim rig of its
channel in this process (:mod:`.channel`), through the same :class:`~tmscal.drivers.base.Robot`
path as every driver, so the safety envelope, the speed and acceleration caps and the split
through P0 of ``Robot.move_to`` apply exactly as for a real robot; only the motion that
reaches ``_move_to`` moves the rig. A motion takes no time (the flange is at its target when
``_move_to`` returns).

Poses are base_from_flange 4×4 mm: ``flange_pose()`` is what the controller reports (the
commanded pose, or with an arm the nominal model's flange at the joints), while the rig's
true flange carries the positioning error drawn per move (``rot_sigma_deg``,
``trans_sigma_mm``). Options: :class:`~tmscal.drivers.sim.settings.SimRobotSettings`.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np

from ...sim import SimRig
from ..base import ConnectionLost, Envelope, Robot, RobotFault
from .channel import RigSpec, attach, detach
from .settings import SimRobotSettings

__all__ = ["SimRobot"]

#: the options' defaults, declared once in SimRobotSettings.OPTIONS
_OPT = SimRobotSettings.defaults()


class SimRobot(Robot):
    """A robot on the sim rig of ``channel`` (shared with a sim tracker on that channel).

    ``host`` is accepted (the robot section always has one) and ignored; ``envelope``,
    ``speed_mm_s`` (mm/s), ``accel_mm_s2`` (mm/s²) as for every robot. ``seed``, ``truth``,
    ``arm``, ``arm_errors``: the rig's (:class:`~tmscal.drivers.sim.channel.RigSpec`);
    ``rot_sigma_deg`` (deg) and ``trans_sigma_mm`` (mm): the positioning error per move;
    ``read_rot_sigma_deg`` (deg) and ``read_trans_sigma_mm`` (mm): the jitter of every
    reported pose, drawn per read.
    ``fail_after_moves`` k: after k motions since ``open()`` the next fails, and every one
    after it until the robot is opened again (``fault``: ``protective_stop`` raises
    ``RobotFault``; ``connection_lost`` raises ``ConnectionLost``, and so does every read).
    A pose the arm cannot reach is a ``RobotFault`` and nothing moves. ``moves_sent`` counts
    the motions that reached the rig since ``open()``."""

    name = "sim"
    real_time = False

    def __init__(self, host: str = "", *, envelope: Envelope | None = None,
                 speed_mm_s: float = 100.0, accel_mm_s2: float = 500.0,
                 channel: str = _OPT["channel"], seed: int = _OPT["seed"],
                 truth: str = _OPT["truth"], arm: str | None = _OPT["arm"],
                 arm_errors: str = _OPT["arm_errors"],
                 rot_sigma_deg: float = _OPT["rot_sigma_deg"],
                 trans_sigma_mm: float = _OPT["trans_sigma_mm"],
                 read_rot_sigma_deg: float = _OPT["read_rot_sigma_deg"],
                 read_trans_sigma_mm: float = _OPT["read_trans_sigma_mm"],
                 fail_after_moves: int | None = _OPT["fail_after_moves"],
                 fault: str = _OPT["fault"]) -> None:
        o = SimRobotSettings.check_options(
            "SimRobot", channel=channel, seed=seed, truth=truth, arm=arm,
            arm_errors=arm_errors, rot_sigma_deg=rot_sigma_deg, trans_sigma_mm=trans_sigma_mm,
            read_rot_sigma_deg=read_rot_sigma_deg, read_trans_sigma_mm=read_trans_sigma_mm,
            fail_after_moves=fail_after_moves, fault=fault)
        super().__init__(envelope=envelope, speed_mm_s=speed_mm_s, accel_mm_s2=accel_mm_s2)
        self.host = host
        self.channel: str = o["channel"]
        #: the rig options as given (the option names), and the rig they make
        self.seed, self.truth, self.arm, self.arm_errors = (o["seed"], o["truth"], o["arm"],
                                                            o["arm_errors"])
        self.spec = RigSpec(self.seed, self.truth, self.arm, self.arm_errors)
        self.rot_sigma_deg: float = o["rot_sigma_deg"]
        self.trans_sigma_mm: float = o["trans_sigma_mm"]
        self.read_rot_sigma_deg: float = o["read_rot_sigma_deg"]
        self.read_trans_sigma_mm: float = o["read_trans_sigma_mm"]
        self.fail_after_moves: int | None = o["fail_after_moves"]
        self.fault: str = o["fault"]
        self.moves_sent = 0
        self._rig: SimRig | None = None
        self._tripped = False

    @property
    def rig(self) -> SimRig | None:
        """The :class:`~tmscal.sim.SimRig` moved (None until ``open()``)."""
        return self._rig

    def _open(self) -> None:
        rig = attach(self.channel, self.spec, "robot")
        rig.noise = replace(rig.noise, robot_rot_sigma_deg=self.rot_sigma_deg,
                            robot_trans_sigma_mm=self.trans_sigma_mm,
                            robot_read_rot_sigma_deg=self.read_rot_sigma_deg,
                            robot_read_trans_sigma_mm=self.read_trans_sigma_mm)
        self._rig, self.moves_sent, self._tripped = rig, 0, False

    def _close(self) -> None:
        rig, self._rig = self._rig, None
        if rig is not None:
            detach(self.channel, rig)

    def identity(self) -> dict[str, Any]:
        """Driver, channel, the rig's seed, truth and ``arm`` (the registered arm, None: no
        arm; what ``solve --kinematics estimate`` takes as the nominal arm)."""
        return {"driver": self.name, "channel": self.channel, "seed": self.spec.seed,
                "truth": self.spec.truth, "arm": self.spec.arm}

    def _lost(self) -> None:
        if self._tripped and self.fault == "connection_lost":
            raise ConnectionLost(f"sim: connection lost (injected after "
                                 f"{self.fail_after_moves} motions)", device=self.name)

    def _on(self) -> SimRig:
        """The rig, or ConnectionLost after the injected fault of that kind."""
        self._lost()
        assert self._rig is not None  # the base class calls the hooks only while open
        return self._rig

    def _flange_pose(self) -> np.ndarray:
        return np.asarray(self._on().reported_flange(), dtype=np.float64)

    def _move_to(self, pose: np.ndarray, speed_mm_s: float, accel_mm_s2: float) -> None:
        rig = self._on()
        k = self.fail_after_moves
        if self._tripped or (k is not None and self.moves_sent >= k):
            self._tripped = True
            self._lost()
            raise RobotFault(f"sim: protective stop (injected after {k} motions); nothing "
                             "moved", device=self.name)
        if rig.reach(pose) is None:
            raise RobotFault(f"sim: pose {np.round(pose[:3, 3], 1).tolist()} mm is out of the "
                             f"{self.spec.arm} arm's reach; nothing moved", device=self.name)
        rig.move_flange(pose)
        self.moves_sent += 1

    def joint_positions(self) -> np.ndarray:
        """The joint angles now (rad), when the rig has an arm (``arm``); else
        NotImplementedError naming the option."""
        q = None if self._rig is None else self._rig.joints()
        if q is None:
            raise NotImplementedError(f"{self.name}: this robot has no arm, so no joint angles "
                                      "(set robot.options.arm)")
        return np.asarray(q, dtype=np.float64)

    def _stop(self) -> None:
        pass
