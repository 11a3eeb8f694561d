"""The simulated rig: the simulation protocol of Wang et al. (2018), after Ernst et al. (2012);
see docs/methods.md.

Frames: ``base_from_flange`` (A), ``tracker_from_<body>`` (B for the marker, C for the probe),
``flange_from_<body>`` (X for the marker, Y for the probe), ``base_from_tracker`` (Z). All
4×4, mm.

The rig knows the truth and the current flange pose, and returns noisy observations:

* tracker noise: each body carries a four-sphere passive tool; the spheres are placed at the
  true pose, every coordinate gets Gaussian noise (σ = ``fiducial_sigma_mm``), and the pose is
  recovered by Horn's absolute orientation without scale;
* robot noise: the flange ends up at commanded · δ, δ a rotation about a random axis by an
  angle ~ N(0, ``robot_rot_sigma_deg``) and a translation ~ N(0, ``robot_trans_sigma_mm``) per
  component. The robot reports the commanded pose (its encoders are repeatable; the error is
  kinematic), so the reported A differs from the true flange pose by δ, exactly as in the paper's
  "distort the robot matrices". ``robot_read_sigma_*`` adds independent jitter per reading.

The mocks (Polaris, UR, DENSO) all serve one ``SimRig``: the robot mock calls
``move_flange`` and reads ``reported_flange``; the tracker mock calls ``observe``.
The rig is thread-safe (one lock) because mock servers run in threads.

Two time-dependent effects make what the tracker sees move (the controller's reported pose
never does):

* motion: while a robot mock runs a move it hands the rig the move's path
  (``follow(path)``: a function giving the commanded base_from_flange now); the true flange
  follows that path, with the previous move's positioning error, until ``move_flange`` ends
  the move;
* settling (``settle``: a :class:`Settle`, off when None): after every ``move_flange`` the
  true flange oscillates, a damped oscillation along a direction drawn per move.

Both read the rig's time base ``time_s`` (seconds; None: ``time.monotonic``). On the mocks'
fast clock the mock rig sets it to the tracker's virtual time (frames served / frame rate),
so the oscillation decays as frames are read, not as wall time passes: a client that only
sleeps does not advance fast time (see docs/devices.md).

What moved since the calibration (``tmscal.sim.changes``: the tracker, the marker, the coil
re-seated on the flange, the coil's centre) changes the truth: ``apply_change`` now, or
``events`` (:class:`~tmscal.sim.changes.Event`) at a time of the rig's clock, each applied
once, the first time the rig's state is read (``true_flange``, ``true_body``, ``observe``)
at or after it. Neither draws from the rig's RNG.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections import deque
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from ..calib.selfcal.model import ArmModel
from ..geometry import (
    absolute_orientation,
    compose,
    invert,
    make_pose,
    matrix_from_rotvec,
    rotvec_from_matrix,
)
from .arm import ArmPair, Unreachable
from .changes import Change, Event
from .truth import Truth

log = logging.getLogger(__name__)

#: A four-sphere passive tool modelled on NDI 8700340 (inter-sphere distances ≈ 50, 103, 138,
#: 56, 89, 62 mm). Sphere centres in the tool frame, mm; the origin is the centroid. The
#: exact ROM geometry was a figure in Wang et al. (2018); this planar layout reproduces those
#: distances to within 2 mm, which is what matters for the noise of Horn's fit.
TOOL_8700340_MM = np.array([
    [0.0, 0.0, 0.0],
    [50.0, 0.0, 0.0],
    [99.73, 25.75, 0.0],
    [136.23, -22.05, 0.0],
])
TOOL_8700340_MM = TOOL_8700340_MM - TOOL_8700340_MM.mean(axis=0)


#: Start pose P0 of the built-in TMS rig: base_from_flange, flange 500 mm in front of the
#: base, 400 mm up, tool axis (flange z) pointing down. mm.
TMS_RIG_P0 = make_pose(np.diag([1.0, -1.0, -1.0]), [500.0, 0.0, 400.0])


def tms_rig_truth(distance_mm: float = 1500.0) -> Truth:
    """A plausible robotized-TMS rig (fixed, for mocks and the demo).

    The coil hangs below the flange: the marker sits on top of the coil (X: 60 mm along the
    tool axis, tilted 15°) and the probe at the coil's effective centre (Y: 110 mm along the
    tool axis). The tracker stands ``distance_mm`` away from the coil at P0, looking at it, so
    both tools appear near (0, 0, −distance) in tracker coordinates, like the set-up of Wang et
    al. (2018) (|x|, |y| < 100 mm, z ≈ −1500 mm). All 4×4, mm.
    """
    from ..geometry import rot_x, rot_z
    X = make_pose(rot_z(np.radians(30)) @ rot_x(np.radians(-15)), [12.0, -8.0, 60.0])
    Y = make_pose(rot_z(np.radians(-20)), [3.0, 5.0, 110.0])
    coil_centre = (TMS_RIG_P0 @ Y)[:3, 3]
    # tracker in front of the rig along −y of the base, its +z pointing away from the scene
    z_axis = np.array([0.0, -1.0, 0.0])
    x_axis = np.array([1.0, 0.0, 0.0])
    y_axis = np.cross(z_axis, x_axis)
    R = np.stack([x_axis, y_axis, z_axis], axis=1)
    Z = make_pose(R, coil_centre + distance_mm * z_axis)
    return Truth(X=X, Z=Z, Y=Y)


@dataclass(frozen=True)
class Noise:
    """Noise model: tracker fiducial σ (mm), robot positioning error σ (deg, mm) per move,
    optional robot reading jitter σ (deg, mm) per read. Defaults are those of Wang et al. (2018).

    Tracker distortion (default none): every tracker-frame position p (the sphere centres) is
    measured as D p, about the tracker origin, with D = diag(sx, sy, sz) + the shear
    [xy, xz, yz] above the diagonal (D[0, 1], D[0, 2], D[1, 2]). ``tracker_scale`` is one
    factor (isotropic, e.g. 1.001 for +0.1 %) or three; ``tracker_shear`` three
    dimensionless entries. The pose is then fitted rigidly (Horn), as a tracker does, so an
    isotropic scale multiplies the tracked translations and leaves the rotations."""

    fiducial_sigma_mm: float = 0.05
    robot_rot_sigma_deg: float = 0.05
    robot_trans_sigma_mm: float = 0.05
    robot_read_rot_sigma_deg: float = 0.0
    robot_read_trans_sigma_mm: float = 0.0
    tracker_scale: float | tuple[float, float, float] = 1.0
    tracker_shear: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def __post_init__(self) -> None:
        scale = _three(self.tracker_scale, "tracker_scale", broadcast=True)
        if not all(0.5 <= v <= 2.0 for v in scale):
            raise ValueError(f"tracker_scale {list(scale)}: each factor must be in 0.5…2")
        shear = _three(self.tracker_shear, "tracker_shear", broadcast=False)
        if not all(abs(v) <= 0.5 for v in shear):
            raise ValueError(f"tracker_shear {list(shear)}: each entry must be in −0.5…0.5")
        object.__setattr__(self, "tracker_scale", scale)
        object.__setattr__(self, "tracker_shear", shear)

    @property
    def tracker_distortion(self) -> np.ndarray:
        """D (3×3): the tracker measures a tracker-frame position p as D p."""
        sx, sy, sz = self.tracker_scale  # type: ignore[misc]
        xy, xz, yz = self.tracker_shear
        return np.array([[sx, xy, xz], [0.0, sy, yz], [0.0, 0.0, sz]])

    @property
    def distorted(self) -> bool:
        """True when the tracker distortion is not the identity."""
        return not np.array_equal(self.tracker_distortion, np.eye(3))

    @classmethod
    def none(cls) -> Noise:
        """No noise at all (exact observations)."""
        return cls(0.0, 0.0, 0.0, 0.0, 0.0)


#: below this share of its initial amplitude the oscillation is exactly zero (the flange is
#: then exactly still, as a real one is once its motion is far below the tracker's noise)
_QUIET = 1e-12


@dataclass(frozen=True)
class Settle:
    """The coil's settling after a move: a damped oscillation of the true flange that the
    tracker sees and the robot controller does not report.

    ``t`` seconds after a move ends the flange is offset by
    ``amplitude_mm · exp(−t/tau_s) · cos(2π · freq_hz · t)`` along a unit direction u (base
    frame, mm) and, when ``rotation_deg`` > 0, rotated about its own origin by
    ``rotation_deg · exp(−t/tau_s) · cos(2π · freq_hz · t)`` about a unit axis w (flange
    frame); u and w are drawn per move from the rig's RNG. ``freq_hz`` 0: a pure exponential
    decay. Once the envelope exp(−t/τ) is below 1e-12 the offset is exactly zero."""

    amplitude_mm: float = 0.3
    tau_s: float = 0.25
    freq_hz: float = 4.0
    rotation_deg: float = 0.0

    def __post_init__(self) -> None:
        for name, lo, hi, open_lo in (("amplitude_mm", 0.0, 50.0, False),
                                      ("tau_s", 0.0, 60.0, True),
                                      ("freq_hz", 0.0, 1000.0, False),
                                      ("rotation_deg", 0.0, 5.0, False)):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)):
                raise ValueError(f"{name}: expected a number, got {v!r}")
            v = float(v)
            if not (math.isfinite(v) and (v > lo if open_lo else v >= lo) and v <= hi):
                rng = f"{'(' if open_lo else '['}{lo:g}, {hi:g}]"
                raise ValueError(f"{name} must be in {rng}, got {v!r}")
            object.__setattr__(self, name, v)

    @property
    def quiet_after_s(self) -> float:
        """Seconds after a move from which the offset is exactly zero."""
        return self.tau_s * math.log(1.0 / _QUIET)

    def factor(self, t: float) -> float:
        """exp(−t/τ)·cos(2πft) at ``t`` s after the move (0 before the move ends, i.e. t < 0,
        and from ``quiet_after_s`` on)."""
        if t < 0 or t >= self.quiet_after_s:
            return 0.0
        return math.exp(-t / self.tau_s) * math.cos(2.0 * math.pi * self.freq_hz * t)

    def offset(self, t: float, direction: np.ndarray, axis: np.ndarray
               ) -> tuple[np.ndarray, np.ndarray] | None:
        """(translation in the base frame (3,) mm, rotation in the flange frame 3×3) at
        ``t`` s after the move, for the move's unit ``direction`` and ``axis``; None when the
        offset is zero."""
        f = self.factor(t)
        if f == 0.0:
            return None
        R = (matrix_from_rotvec(axis * math.radians(self.rotation_deg * f))
             if self.rotation_deg > 0 else np.eye(3))
        return direction * (self.amplitude_mm * f), R


def straight_path(start: np.ndarray, target: np.ndarray, f: float) -> np.ndarray:
    """The pose (base_from_flange 4×4 mm) at share ``f`` (0…1) of a straight Cartesian move
    from ``start`` to ``target``: the translation on the straight line, the rotation on the
    geodesic (the path a UR ``movel`` or a DENSO ``MOVE L`` takes)."""
    if f >= 1.0:
        return np.array(target, dtype=np.float64)
    out = np.eye(4)
    out[:3, 3] = start[:3, 3] + f * (target[:3, 3] - start[:3, 3])
    rel = rotvec_from_matrix(start[:3, :3].T @ target[:3, :3])
    out[:3, :3] = start[:3, :3] @ matrix_from_rotvec(f * rel)
    return out


def _three(value: object, name: str, broadcast: bool) -> tuple[float, float, float]:
    """A finite float triple from a number (if ``broadcast``) or a sequence of three."""
    if isinstance(value, bool):
        raise ValueError(f"{name}: expected a number or a list of three numbers")
    if isinstance(value, (int, float)) and broadcast:
        vals = [float(value)] * 3
    else:
        try:
            vals = [float(v) for v in value]  # type: ignore[attr-defined]
        except (TypeError, ValueError):
            what = "a number or a list of three numbers" if broadcast else "a list of three"
            raise ValueError(f"{name}: expected {what}, got {value!r}") from None
    if len(vals) != 3 or not all(np.isfinite(vals)):
        raise ValueError(f"{name}: expected three finite numbers, got {value!r}")
    return (vals[0], vals[1], vals[2])


def _perturbation(rng: np.random.Generator, rot_sigma_deg: float, trans_sigma_mm: float,
                  n: int | None = None) -> np.ndarray:
    """Random small rigid motion(s): rotation about a random axis by N(0, σ_rot) degrees,
    translation N(0, σ_t) mm per component."""
    m = 1 if n is None else n
    axis = rng.standard_normal((m, 3))
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    ang = np.radians(rng.normal(0.0, rot_sigma_deg, m)) if rot_sigma_deg > 0 else np.zeros(m)
    t = rng.normal(0.0, trans_sigma_mm, (m, 3)) if trans_sigma_mm > 0 else np.zeros((m, 3))
    T = make_pose(matrix_from_rotvec(axis * ang[:, None]), t)
    return T[0] if n is None else T


@dataclass
class SimRig:
    """A simulated robot + tracker rig with known truth.

    ``tools`` maps body names to sphere centres (k, 3) in the body frame, mm (default: the
    8700340-like tool for every body of the truth). ``flange`` is the true base_from_flange
    where the flange comes to rest (with the robot's positioning error; ``true_flange()``
    adds the motion under way and the settling oscillation) and ``commanded`` the last
    commanded one (what the robot reports). ``settle``: the settling model (None: none);
    ``time_s``: the time base in seconds (None: ``time.monotonic``). ``arm``: a serial arm
    (:class:`~tmscal.sim.arm.ArmPair`, None: none): the robot then moves in joint space,
    reports the nominal model's flange pose and really puts the flange where the true model
    says (``tmscal.sim.arm``); without one, behaviour and random draws are as before. The
    rig's ``truth`` carries the arm (``Truth.arm``): given on either, it is set on both; a
    different arm on each is a ValueError.

    ``truth`` is the truth now: ``apply_change`` changes it (``tmscal.sim.changes``), and so
    does each of ``events`` (:class:`~tmscal.sim.changes.Event`, any order; applied in time
    order) once the rig's clock has run ``at_s`` seconds: ``now()`` minus its value when the
    rig was built or its time base last set (``use_clock``). It is applied the first time the
    rig's state is read at or after that time (``true_flange``, ``true_body``, ``observe``)
    and listed in ``fired``. Without events and changes, behaviour and random draws are as
    before.
    """

    truth: Truth
    noise: Noise = field(default_factory=Noise)
    rng: np.random.Generator = field(default_factory=lambda: np.random.default_rng(0))
    tools: Mapping[str, np.ndarray] | None = None
    start: np.ndarray | None = None
    settle: Settle | None = None
    time_s: Callable[[], float] | None = None
    arm: ArmPair | None = None
    events: Sequence[Event] = ()

    def __post_init__(self) -> None:
        self._lock = threading.RLock()
        #: events not applied yet, in time order (a stable sort: equal times as given)
        self._events: list[Event] = sorted(self.events, key=lambda e: e.at_s)
        self._epoch = self.now()
        #: every event applied, in order: (the event, the rig's time (s, since ``_epoch``)
        #: when the state read that applied it was made)
        self.fired: list[tuple[Event, float]] = []
        if self.arm is None:
            self.arm = self.truth.arm
        elif self.truth.arm is None:
            self.truth = replace(self.truth, arm=self.arm)
        elif self.truth.arm is not self.arm:
            raise ValueError("the truth's arm and the rig's arm differ")
        if self.tools is None:
            names = ["marker"] + (["probe"] if self.truth.Y is not None else [])
            self.tools = {n: TOOL_8700340_MM for n in names}
        self._tracker_from_base = invert(self.truth.Z)
        p0 = np.eye(4) if self.start is None else np.asarray(self.start, dtype=float)
        self.commanded = p0.copy()
        self.flange = p0.copy()
        self._q: np.ndarray | None = None
        self._reach_cache: tuple[bytes, np.ndarray] | None = None
        if self.arm is not None:
            q = self.arm.solve(p0, None)
            if q is None:
                raise Unreachable(f"the start pose {np.round(p0[:3, 3], 1).tolist()} mm is out "
                                  f"of the {self.arm.nominal.name} arm's reach")
            self._q = q
            self.flange = self.arm.actual(q)
        #: every commanded base_from_flange (4×4 mm) passed to move_flange, oldest first
        #: (bounded: the last 100,000), so tests can see what a robot mock was told
        self.moves: deque[np.ndarray] = deque(maxlen=100_000)
        self._path: Callable[[], np.ndarray] | None = None
        #: the current oscillation: (time the move ended (s), direction u, axis w) or None
        self._swing: tuple[float, np.ndarray, np.ndarray] | None = None

    def now(self) -> float:
        """The rig's time base, seconds (``time_s``, else ``time.monotonic``)."""
        return float(self.time_s()) if self.time_s is not None else time.monotonic()

    def use_clock(self, time_s: Callable[[], float] | None) -> None:
        """Make ``time_s`` (seconds; None: ``time.monotonic``) the rig's time base; the
        events' times count from its value now (the mock rig calls this with the tracker's
        virtual time on the fast clock, before any frame is served)."""
        with self._lock:
            self.time_s = time_s
            self._epoch = self.now()

    def elapsed(self) -> float:
        """Seconds of the rig's time since its clock started (``use_clock``, else since the
        rig was built): the time the events' ``at_s`` are compared with."""
        with self._lock:
            return self.now() - self._epoch

    # --- what moved ---
    def apply_change(self, move: str, mm: Sequence[float] = (0.0, 0.0, 0.0),
                     deg: Sequence[float] = (0.0, 0.0, 0.0)) -> Truth:
        """Change the rig now (``tmscal.sim.changes.changed``: ``move`` one of tracker,
        marker, coil, coil_centre; ``mm`` a translation in mm, ``deg`` a rotation vector in
        degrees) and return the new truth. The tracker sees it from the next frame read;
        the robot's reported pose is unchanged. ValueError for a bad change (nothing
        changes)."""
        change = Change(move, mm, deg)  # type: ignore[arg-type]  # Change checks: 3 numbers
        with self._lock:
            self._set_truth(change.apply(self.truth))
            return self.truth

    def schedule(self, events: Iterable[Event]) -> None:
        """Add ``events`` to those not applied yet (their ``at_s`` on the rig's clock, as
        ``elapsed`` counts it; one already due applies at the next state read)."""
        with self._lock:
            self._events = sorted([*self._events, *events], key=lambda e: e.at_s)

    @property
    def pending(self) -> list[Event]:
        """The events not applied yet, in time order."""
        with self._lock:
            return list(self._events)

    def _set_truth(self, truth: Truth) -> None:
        self.truth = truth
        self._tracker_from_base = invert(truth.Z)

    def _fire_due(self) -> None:
        """Apply every event whose time has come, in time order (each once)."""
        if not self._events:
            return
        with self._lock:
            t = self.now() - self._epoch
            while self._events and self._events[0].at_s <= t:
                e = self._events.pop(0)
                self._set_truth(e.change.apply(self.truth))
                self.fired.append((e, t))
                c = e.change
                log.info("mock rig: %s moved by %s mm, %s deg at %.3f s (event at %g s)",
                         c.move, list(c.mm), list(c.deg), t, e.at_s)

    @property
    def bodies(self) -> list[str]:
        """Names of the tracked bodies, e.g. ["marker", "probe"]."""
        return list(self.tools or {})

    # --- robot side ---
    @property
    def arm_nominal(self) -> ArmModel | None:
        """The controller's kinematic model (None: the rig has no arm)."""
        return None if self.arm is None else self.arm.nominal

    @property
    def arm_true(self) -> ArmModel | None:
        """The arm's true kinematic model, hidden errors included (None: no arm)."""
        return None if self.arm is None else self.arm.true

    def joints(self) -> np.ndarray | None:
        """The joint angles now (rad; None when the rig has no arm): where the last
        ``move_flange`` put them (a move under way is reported at its start)."""
        with self._lock:
            return None if self._q is None else self._q.copy()

    def reach(self, base_from_flange: np.ndarray) -> np.ndarray | None:
        """The joint angles (rad) at which the controller reports ``base_from_flange``
        (4×4 mm), on the NOMINAL model (``ArmPair.solve``: from the current joints first), or
        None when the arm cannot reach it. Without an arm: an empty array (every pose is
        reachable)."""
        if self.arm is None:
            return np.zeros(0)
        cmd = np.asarray(base_from_flange, dtype=np.float64)
        key = cmd.tobytes()
        with self._lock:
            if self._reach_cache is not None and self._reach_cache[0] == key:
                return self._reach_cache[1].copy()
            q = self.arm.solve(cmd, self._q)
            if q is not None:
                self._reach_cache = (key, q.copy())
            return q

    def move_flange(self, base_from_flange: np.ndarray) -> None:
        """Put the flange at the commanded pose (4×4 mm, base frame), with the robot's
        positioning error applied to the true pose. With an arm, the joints go to the
        nominal inverse kinematics of the pose and the flange to where the TRUE arm puts
        them (``ArmPair.actual``); a pose out of reach raises :class:`Unreachable` and nothing
        moves (a robot mock checks ``reach`` before it starts a move)."""
        cmd = np.asarray(base_from_flange, dtype=np.float64)
        with self._lock:
            q = None
            if self.arm is not None:
                q = self.reach(cmd)
                if q is None:
                    raise Unreachable(f"pose {np.round(cmd[:3, 3], 1).tolist()} mm is out of "
                                      f"the {self.arm.nominal.name} arm's reach")
            d = _perturbation(self.rng, self.noise.robot_rot_sigma_deg,
                              self.noise.robot_trans_sigma_mm)
            self.commanded = cmd.copy()
            if q is None:
                self.flange = cmd @ d
            else:
                assert self.arm is not None
                self._q = q
                self.flange = self.arm.actual(q) @ d
            self.moves.append(cmd.copy())
            self._path = None
            if self.settle is not None:
                u = self.rng.standard_normal(3)
                w = self.rng.standard_normal(3)
                self._swing = (self.now(), u / np.linalg.norm(u), w / np.linalg.norm(w))

    def follow(self, path: Callable[[], np.ndarray]) -> None:
        """A move is under way: until the next ``move_flange`` the true flange is ``path()``
        (the commanded base_from_flange now, 4×4 mm, as the robot mock's motion model gives
        it) with the positioning error of the pose the move started from. The controller's
        reported pose is the robot mock's business (``reported_flange`` is unchanged)."""
        with self._lock:
            self._path = path
            self._swing = None

    def true_flange(self) -> np.ndarray:
        """The true base_from_flange now (4×4 mm): on the move's path while a move runs, else
        where the flange came to rest plus the settling oscillation. Applies the events
        due first."""
        with self._lock:
            self._fire_due()
            if self._path is not None:
                return self._path() @ invert(self.commanded) @ self.flange
            if self._swing is None or self.settle is None:
                return self.flange.copy()
            t0, u, w = self._swing
            t = self.now() - t0
            if t >= self.settle.quiet_after_s:
                self._swing = None  # at rest for good
            off = self.settle.offset(t, u, w)
            if off is None:
                return self.flange.copy()
            out = self.flange.copy()
            out[:3, :3] = out[:3, :3] @ off[1]
            out[:3, 3] += off[0]
            return out

    def reported_flange(self) -> np.ndarray:
        """What the controller reports: base_from_flange 4×4 mm (the commanded pose; with an
        arm, the nominal model's flange at the joints, ``ArmPair.reported``, which is the
        commanded pose to within the IK tolerance), plus read jitter if configured."""
        with self._lock:
            rep = (self.commanded if self._q is None or self.arm is None
                   else self.arm.reported(self._q))
            if self.noise.robot_read_rot_sigma_deg or self.noise.robot_read_trans_sigma_mm:
                return rep @ _perturbation(self.rng, self.noise.robot_read_rot_sigma_deg,
                                           self.noise.robot_read_trans_sigma_mm)
            return rep.copy()

    # --- tracker side ---
    def true_body(self, body: str) -> np.ndarray:
        """Noise-free tracker_from_<body> = Z⁻¹ · A_true · (X or Y), 4×4 mm, A_true the true
        flange now (``true_flange``: moving or settling included), on the truth now (the
        events due applied first)."""
        with self._lock:
            self._fire_due()
            flange = self.true_flange()
            return self._tracker_from_base @ flange @ self.truth.flange_from(body)

    def observe(self, body: str, n: int | None = None) -> np.ndarray:
        """Noisy tracker_from_<body> (4×4 mm), or n independent observations (n, 4, 4):
        fiducials at the true pose, distorted by the tracker distortion D (``Noise``), + N(0, σ)
        per coordinate, pose by Horn's method."""
        T = self.true_body(body)
        assert self.tools is not None
        pts = np.asarray(self.tools[body], dtype=np.float64)
        m = 1 if n is None else n
        world = (T[:3, :3] @ pts.T).T + T[:3, 3]
        distorted = self.noise.distorted
        if distorted:
            world = world @ self.noise.tracker_distortion.T
        with self._lock:
            noisy = world[None] + (self.rng.normal(0.0, self.noise.fiducial_sigma_mm,
                                                   (m,) + world.shape)
                                   if self.noise.fiducial_sigma_mm > 0 else 0.0)
        if self.noise.fiducial_sigma_mm == 0 and not distorted:
            out = np.repeat(T[None], m, axis=0)
        else:
            out = absolute_orientation(pts, noisy)
        return out[0] if n is None else out


def facing_start(truth: Truth, distance_mm: float = 1500.0) -> np.ndarray:
    """A start pose P0 (base_from_flange, mm) that puts the marker at (0, 0, −distance) in
    tracker coordinates, as in the experiment of Wang et al. (2018): tools near the centre of
    the measurement volume."""
    target = make_pose(np.eye(3), [0.0, 0.0, -distance_mm])
    return compose(truth.Z, target, invert(truth.X))
