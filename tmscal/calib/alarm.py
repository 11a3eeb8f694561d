"""The live monitor's decision rule (``tmscal monitor``, docs/lab-day.md, "Monitor"): pure
numerics on residual vectors, no I/O.

Each tracker frame taken while the robot holds still gives, per body seen, the residual
r = [t(E) mm; rotation vector of E in degrees] of E = (A X)⁻¹ Z N (``calib.diagnose``:
N = B for the marker, C for the probe), the bodies stacked (q = 6 or 12 numbers). On an
unchanged rig, within one still phase (a *hold*: the robot at one pose),

    r_t = u + e_t,   u ~ N(0, S),   e_t ~ N(0, Σ_f) independent per frame,

u shared by every frame of the hold (the robot's positioning error at that pose and the
calibration's own error there: S = Σ + J C Jᵀ, the calibration's noise model,
``diagnose.pose_covariance``) and e_t the tracker's frame-to-frame noise (Σ_f, estimated on
line from successive differences: Var(r_t − r_{t−1}) = 2 Σ_f; :class:`FrameNoise`).

The rule (:class:`Detector`): the mean m of the last ``window`` residuals of the hold, and
its statistic T = mᵀ (S + Σ_f / window)⁻¹ m, which is χ²_q on an unchanged rig. A frame is
*over* when T exceeds the χ²_q quantile at 1 − ``level`` (and, when tolerances are given,
the mean's translation or rotation of some body exceeds them: a change too small to matter
is not an alarm). The alarm is raised after ``persistence`` consecutive frames over; the
default persistence is ``window`` + 1, so that one bad frame, which stays in the window's
mean for ``window`` frames, cannot raise it alone. The alarm clears after ``persistence``
consecutive frames under. A frame that is not usable (the robot moving or settling, a body
missing, the tracker's tools jumping) empties the window and resets both counts.

False alarms: T is dominated by u, which is the same for the whole hold, so the
probability that an unchanged hold raises an alarm is about ``level`` (the frame noise
adds a little: :func:`simulate_holds` measures it); a session of h holds an hour expects
about h · ``level`` false alarms an hour.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy.stats import chi2

from ..errors import CalibrationError

__all__ = ["Rule", "FrameNoise", "Detector", "Step", "simulate_holds", "LEVEL"]

#: default false-alarm probability of one hold (one still phase of an unchanged rig)
LEVEL = 1e-6


@dataclass(frozen=True)
class Rule:
    """The decision rule's parameters: ``window`` frames averaged, ``persistence``
    consecutive frames over (under) the bound to raise (clear) the alarm (None: window + 1),
    ``level`` the false-alarm probability of one hold, ``tolerance_mm`` / ``tolerance_deg``
    the smallest change that matters (the window mean's ‖t‖ mm or rotation angle degrees of
    some body; None: any significant change)."""

    window: int = 15
    persistence: int | None = None
    level: float = LEVEL
    tolerance_mm: float | None = None
    tolerance_deg: float | None = None

    def __post_init__(self) -> None:
        if not (isinstance(self.window, int | np.integer) and self.window >= 1):
            raise CalibrationError(f"window must be an integer ≥ 1 frame, got {self.window!r}")
        if self.persistence is not None and not (
                isinstance(self.persistence, int | np.integer) and self.persistence >= 1):
            raise CalibrationError(f"persistence must be an integer ≥ 1 frame, got "
                                   f"{self.persistence!r}")
        if not (0 < self.level < 1):
            raise CalibrationError(f"level must be in (0, 1), got {self.level!r}")
        for name in ("tolerance_mm", "tolerance_deg"):
            v = getattr(self, name)
            if v is not None and not (np.isfinite(v) and v > 0):
                raise CalibrationError(f"{name} must be a finite number > 0, got {v!r}")

    @property
    def frames_to_alarm(self) -> int:
        """Consecutive frames over the bound that raise the alarm."""
        return int(self.persistence if self.persistence is not None else self.window + 1)

    def threshold(self, q: int) -> float:
        """The χ²_q quantile at 1 − ``level``: the bound on T for q residual numbers."""
        return float(chi2.isf(self.level, q))


class FrameNoise:
    """The tracker's frame-to-frame noise Σ_f of each body's residual (6×6, mm and deg),
    from successive differences d = r_t − r_{t−1} of still frames: Σ_f = Σ d dᵀ / (2 n).
    ``ready`` after ``warmup`` differences of every body; differences then stop being
    added (a change after the warm-up is not learnt as noise). A gross jump (‖d‖ above 10×
    the median of the differences so far, e.g. the step of a bump) is left out."""

    def __init__(self, bodies: Sequence[str], warmup: int = 60) -> None:
        self.bodies = tuple(bodies)
        self.warmup = int(warmup)
        self._d: dict[str, list[np.ndarray]] = {b: [] for b in self.bodies}
        self._cov: dict[str, np.ndarray] = {}
        self._stacked: dict[tuple[str, ...], np.ndarray] = {}

    @property
    def ready(self) -> bool:
        return len(self._cov) == len(self.bodies)

    def add(self, body: str, d: np.ndarray) -> None:
        """One successive difference (6,) of ``body``'s residual."""
        if body in self._cov:
            return
        xs = self._d[body]
        xs.append(np.asarray(d, dtype=float))
        if len(xs) >= self.warmup:
            D = np.asarray(xs)
            n = np.linalg.norm(D, axis=1)
            keep = D[n <= 10 * max(float(np.median(n)), 1e-12)]
            S = keep.T @ keep / (2 * len(keep))
            self._cov[body] = S + (1e-12 + 1e-9 * float(np.max(np.diag(S)))) * np.eye(6)
            xs.clear()

    def cov(self, bodies: Sequence[str]) -> np.ndarray:
        """Σ_f of the stacked ``bodies`` (block diagonal: two tools' frame noise is
        independent); zeros before the warm-up ends. The same array while nothing changes."""
        key = tuple(bodies)
        if self.ready and key in self._stacked:
            return self._stacked[key]
        q = 6 * len(key)
        out = np.zeros((q, q))
        for i, b in enumerate(key):
            if b in self._cov:
                out[6 * i:6 * i + 6, 6 * i:6 * i + 6] = self._cov[b]
        if self.ready:
            self._stacked[key] = out
        return out


@dataclass
class Step:
    """What one frame did: ``statistic`` T (None while the window fills or the frame is not
    usable), ``threshold``, ``over`` (T above it and the size above the tolerances),
    ``alarm`` (the alarm is raised now), ``clear`` (it clears now), ``mean`` (the window's
    mean residual, (q,), None while it fills)."""

    statistic: float | None = None
    threshold: float | None = None
    over: bool = False
    alarm: bool = False
    clear: bool = False
    mean: np.ndarray | None = None


@dataclass
class Detector:
    """The sequential rule of :class:`Rule` on one stream of residuals. :meth:`update` takes
    each frame's residual (q,) with its bodies and the hold's covariance S (q×q, from the
    noise model) and Σ_f (q×q), or None for a frame that is not usable."""

    rule: Rule
    alarmed: bool = False
    _win: deque[np.ndarray] = field(default_factory=deque)
    _sum: np.ndarray | None = None
    _bodies: tuple[str, ...] = ()
    _over: int = 0
    _under: int = 0
    _inv: tuple[object, object, np.ndarray] | None = None  # (S, Sf, (S + Sf/w)⁻¹)
    _h: dict[int, float] = field(default_factory=dict)

    def reset(self) -> None:
        """Empty the window and the counts (a frame that is not usable, a new hold)."""
        self._win.clear()
        self._sum = None
        self._over = self._under = 0

    def _inverse(self, S: np.ndarray, Sf: np.ndarray | None) -> np.ndarray:
        c = self._inv
        if c is not None and c[0] is S and c[1] is Sf:
            return c[2]
        C = S + (np.zeros_like(S) if Sf is None else Sf / self.rule.window)
        inv = np.linalg.inv(C)
        self._inv = (S, Sf, (inv + inv.T) / 2)
        return self._inv[2]

    def update(self, r: np.ndarray | None, bodies: Sequence[str] = (),
               S: np.ndarray | None = None, Sf: np.ndarray | None = None) -> Step:
        """One frame: ``r`` its residual (q,) of ``bodies`` (None: not usable), ``S`` the
        hold's residual covariance and ``Sf`` the frame noise (q×q)."""
        if r is None or S is None:
            self.reset()
            return Step()
        bodies = tuple(bodies)
        if bodies != self._bodies:
            self.reset()
            self._bodies = bodies
        w = self.rule.window
        r = np.asarray(r, dtype=float)
        self._win.append(r)
        self._sum = r.copy() if self._sum is None else self._sum + r
        if len(self._win) > w:
            self._sum -= self._win.popleft()
        if len(self._win) < w:
            return Step()
        m = self._sum / w
        T = float(m @ self._inverse(S, Sf) @ m)
        q = len(m)
        if q not in self._h:
            self._h[q] = self.rule.threshold(q)
        h = self._h[q]
        over = T > h and self._big(m)
        st = Step(statistic=T, threshold=h, over=over, mean=m)
        if over:
            self._over += 1
            self._under = 0
        else:
            self._under += 1
            self._over = 0
        k = self.rule.frames_to_alarm
        if not self.alarmed and self._over >= k:
            self.alarmed = st.alarm = True
        elif self.alarmed and self._under >= k:
            self.alarmed = False
            st.clear = True
        return st

    def _big(self, m: np.ndarray) -> bool:
        tm, td = self.rule.tolerance_mm, self.rule.tolerance_deg
        if tm is None and td is None:
            return True
        for i in range(len(m) // 6):
            if tm is not None and np.linalg.norm(m[6 * i:6 * i + 3]) > tm:
                return True
            if td is not None and np.linalg.norm(m[6 * i + 3:6 * i + 6]) > td:
                return True
        return False


def simulate_holds(rule: Rule, S: np.ndarray, Sf: np.ndarray, holds: int, frames: int,
                   rng: np.random.Generator, step: np.ndarray | None = None,
                   step_at: int | None = None) -> dict[str, object]:
    """The rule on simulated holds of an unchanged rig (or with a change): each hold draws
    u ~ N(0, S) and ``frames`` frames of e_t ~ N(0, Sf) (q×q; mm and deg as the
    residuals), r_t = u + e_t, plus ``step`` (q,) from frame ``step_at`` on. Returns
    {"holds", "alarms": holds that raised an alarm, "share", "delays": per hold with an
    alarm, the frames from ``step_at`` (or from the hold's start) to it}."""
    q = len(S)
    Lu = np.linalg.cholesky(S)
    Lf = np.linalg.cholesky(Sf + 1e-18 * np.eye(q))
    bodies = tuple(f"b{i}" for i in range(q // 6))
    alarms = 0
    delays: list[int] = []
    start = 0 if step_at is None else step_at
    for _ in range(holds):
        det = Detector(rule)
        u = Lu @ rng.standard_normal(q)
        e = rng.standard_normal((frames, q)) @ Lf.T
        for t in range(frames):
            r = u + e[t]
            if step is not None and step_at is not None and t >= step_at:
                r = r + step
            if det.update(r, bodies, S, Sf).alarm:
                alarms += 1
                delays.append(t - start + 1)
                break
    return {"holds": holds, "alarms": alarms, "share": alarms / max(holds, 1),
            "delays": delays}
