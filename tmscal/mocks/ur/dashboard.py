"""The UR mock's dashboard server (port 29999): its command table, answering as an e-Series
controller does (UR's "Dashboard Server e-Series, port 29999" article): one reply line per
command line; in Local Control the commands that act on the robot are refused."""

from __future__ import annotations

from collections.abc import Callable

from .controller import (
    ROBOT_MODE_NAMES,
    RUNTIME_PAUSED,
    RUNTIME_PLAYING,
    RUNTIME_STOPPED,
    SAFETY_NORMAL,
    URController,
)

DASHBOARD_BANNER = b"Connected: Universal Robots Dashboard Server\n"
#: The control program's name as the dashboard reports it.
PROGRAM_NAME = "rtde_control"


class Dashboard:
    """The dashboard server's command table: a fixed reply, or a handler of the command line
    (exact commands, then prefixes), all lower-cased; anything else gets the real server's
    ``could not understand: '…'``."""

    FIXED = {
        "close safety popup": "closing safety popup",
        "close popup": "closing popup", "isprogramsaved": f"true {PROGRAM_NAME}.urp",
    }
    #: commands an e-Series controller in Local Control refuses over the network
    REMOTE_ONLY = frozenset({
        "play", "stop", "pause", "power on", "power off", "brake release",
        "unlock protective stop", "restart safety", "shutdown", "close safety popup",
        "close popup", "load", "popup"})
    LOCAL_REFUSAL = ("Command is not allowed due to safety reasons, please switch robot to "
                     "Remote Control mode and reconnect to port 29999")
    HANG_UP = {"quit": "Disconnected", "shutdown": "Shutting down"}

    def __init__(self, controller: URController, version: tuple[int, ...], serial: str,
                 model: str, urcap_play: Callable[[], bool] | None = None) -> None:
        mock = self.mock = controller
        #: Play with the External Control URCap: its program node fetches and runs the script
        self.urcap_play = urcap_play
        self.version = version
        self.commands: dict[str, Callable[[str], str]] = {
            "polyscopeversion": self._version,
            "get serial number": lambda cmd: serial,
            "get robot model": lambda cmd: model,
            "stop": self._stop,
            "play": self._play,
            "pause": self._pause,
            "unlock protective stop": self._unlock,
            "restart safety": self._restart_safety,
            "running": self._running,
            "programstate": self._program_state,
            "get loaded program": self._loaded_program,
            "safetymode": lambda cmd: f"Safetymode: {self._safety()}",
            "is in remote control": lambda cmd: str(mock.remote_control).lower(),
            "robotmode": lambda cmd: "Robotmode: " + ROBOT_MODE_NAMES.get(
                mock.robot_mode, str(mock.robot_mode)),
            "power on": self._power_on,
            "power off": self._power_off,
            "brake release": self._brake_release,
            "safetystatus": lambda cmd: f"Safetystatus: {self._safety()}",
        }
        self.prefixes: list[tuple[str, Callable[[str], str]]] = [
            ("popup ", lambda cmd: "showing popup"),
            ("load ", lambda cmd: f"Loading program: {cmd[5:]}"),
            ("addtolog ", lambda cmd: "Added log message"),
            ("setuserrole ", lambda cmd: "Setting user role: " + cmd[12:]),
        ]

    def reply(self, line: str) -> tuple[str, bool]:
        """The answer to one command line, and whether to hang up after it."""
        cmd = line.strip()
        low = cmd.lower()
        if not self.mock.remote_control and (low in self.REMOTE_ONLY
                                             or low.split(" ")[0] in self.REMOTE_ONLY):
            return self.LOCAL_REFUSAL, False
        if low in self.FIXED:
            return self.FIXED[low], False
        if low in self.HANG_UP:
            return self.HANG_UP[low], True
        handler = self.commands.get(low)
        if handler is None:
            handler = next((h for p, h in self.prefixes if low.startswith(p)), None)
        if handler is None:
            return f"could not understand: '{cmd}'", False
        with self.mock._lock:
            return handler(cmd), False

    def _version(self, cmd: str) -> str:
        return f"URSoftware {'.'.join(str(x) for x in self.version)} (Mar 24 2021)"

    def _stop(self, cmd: str) -> str:
        # A real controller answers "Stopped" even when the program has just ended
        # (ur_rtde sends STOP_SCRIPT and then "stop", and insists on "Stopped").
        if self.mock.runtime_state != RUNTIME_STOPPED:
            self.mock._stop_program("dashboard stop")
        return "Stopped"

    def _power_on(self, cmd: str) -> str:
        self.mock.power_on()
        return "Powering on"

    def _power_off(self, cmd: str) -> str:
        self.mock.power_off("dashboard power off")
        return "Powering off"

    def _brake_release(self, cmd: str) -> str:
        self.mock.release_brakes()
        return "Brake releasing"

    def _play(self, cmd: str) -> str:
        m = self.mock
        if self.urcap_play is not None:
            return "Starting program" if self.urcap_play() else "Failed to execute: play"
        if not m._program_loaded or m.why_no_program(network=False) is not None:
            return "Failed to execute: play"
        if m.runtime_state == RUNTIME_PAUSED:
            m._resume()
        else:
            m._start_program("dashboard play")
        return "Starting program"

    def _pause(self, cmd: str) -> str:
        if self.mock.runtime_state != RUNTIME_PLAYING:
            return "Failed to execute: pause"
        self.mock._pause()
        return "Pausing program"

    def _unlock(self, cmd: str) -> str:
        self.mock.safety_mode = SAFETY_NORMAL
        return "Protective stop releasing"

    def _restart_safety(self, cmd: str) -> str:
        self.mock.safety_mode = SAFETY_NORMAL
        return "Restarting safety"

    def _running(self, cmd: str) -> str:
        return f"Program running: {str(self.mock.runtime_state == RUNTIME_PLAYING).lower()}"

    def _program_state(self, cmd: str) -> str:
        state = {RUNTIME_PLAYING: "PLAYING", RUNTIME_PAUSED: "PAUSED"}.get(
            self.mock.runtime_state, "STOPPED")
        return f"{state} {PROGRAM_NAME}.urp"

    def _loaded_program(self, cmd: str) -> str:
        if self.mock._program_loaded:
            return f"Loaded program: /programs/{PROGRAM_NAME}.urp"
        return "No program loaded"

    def _safety(self) -> str:
        return "PROTECTIVE_STOP" if self.mock.protective_stopped else "NORMAL"
