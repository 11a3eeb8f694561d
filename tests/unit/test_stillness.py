"""Settling by stillness and samples by need (``sample_pose``'s ``settle="still"`` and
``sem_mm``), against a scripted tracker.

The tracker below (a subclass of the driver contract) serves frame k at tracker time k/60 s:
each tool at its rest pose plus a damped oscillation that starts when the robot's move ends,
``a0 · exp(−t/τ) · cos(2πft)`` along a fixed direction, plus seeded Gaussian noise. Its time
is also the clock handed to ``sample_pose``, so the settle_s bound is counted in frames and no
test depends on the machine's speed. The checks compare frame times with the analytic decay
of the oscillation's envelope, and sample counts with the standard error computed here from
the positions the tracker served.
"""

from __future__ import annotations

import math
import re

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from tests.fuzz import fuzz_settings
from tmscal.acquisition.sample import (
    STILL_FLOOR_MM,
    noise_sigma_mm,
    sample_pose,
    stillness,
    window_frames,
)
from tmscal.acquisition.settings import sampling_settings as _settings
from tmscal.config import SamplingConfig, parse_config
from tmscal.drivers.base import Robot, ToolState, Tracker, TrackerFrame
from tmscal.errors import ConfigError
from tmscal.geometry import make_pose

RATE_HZ = 60.0
REST = {"marker": make_pose(np.eye(3), [120.0, -40.0, 1500.0]),
        "probe": make_pose(np.eye(3), [80.0, 10.0, 1480.0])}
A_REST = make_pose(np.eye(3), [500.0, 20.0, 400.0])
U = np.array([2.0, -1.0, 2.0]) / 3.0   # the oscillation's direction (unit)


class SwingTracker(Tracker):
    """Frame k at time k/RATE_HZ: every tool at REST plus the oscillation since the last
    ``moved()`` plus N(0, sigma_mm) per axis. ``tau_s`` None: the oscillation never decays.
    ``repeat``: every frame number is served twice (a host polling faster than the rate).
    ``missing``: tools never seen. ``served`` records (frame, {tool: position}) per new frame."""

    name = "swing-test-tracker"

    def __init__(self, seed: int, a0_mm: float, tau_s: float | None, freq_hz: float,
                 sigma_mm: float, repeat: bool = False, missing: tuple[str, ...] = ()) -> None:
        super().__init__(["marker", "probe"], frame_rate_hz=RATE_HZ)
        self.rng = np.random.default_rng(seed)
        self.a0, self.tau, self.freq, self.sigma = a0_mm, tau_s, freq_hz, sigma_mm
        self.repeat, self.missing = repeat, missing
        self.frame = 0
        self.reads = 0
        self.t_move = 0.0
        self.served: list[tuple[int, dict[str, np.ndarray]]] = []
        self._last: TrackerFrame | None = None

    def _open(self) -> None:
        pass

    def _close(self) -> None:
        pass

    def clock(self) -> float:
        """The tracker's time, s: the current frame number / rate."""
        return self.frame / RATE_HZ

    def moved(self) -> None:
        self.t_move = self.clock()

    def envelope(self, t: float) -> float:
        """The oscillation's amplitude (mm) at tracker time t."""
        dt = t - self.t_move
        return self.a0 if self.tau is None else self.a0 * math.exp(-dt / self.tau)

    def offset(self, t: float) -> np.ndarray:
        dt = t - self.t_move
        return U * self.envelope(t) * math.cos(2 * math.pi * self.freq * dt)

    def _read(self) -> TrackerFrame:
        self.reads += 1
        if self.repeat and self.reads % 2 == 0 and self._last is not None:
            return self._last
        self.frame += 1
        t = self.clock()
        tools = {}
        for b, T in REST.items():
            if b in self.missing:
                tools[b] = ToolState(pose=None, missing=True)
                continue
            P = T.copy()
            P[:3, 3] += self.offset(t) + self.rng.normal(0.0, self.sigma, 3)
            tools[b] = ToolState(pose=P)
        self.served.append((self.frame, {b: s.pose[:3, 3].copy() for b, s in tools.items()
                                         if s.pose is not None}))
        self._last = TrackerFrame(frame=self.frame, host_time=t, tools=tools)
        return self._last


class StillRobot(Robot):
    """Holds still at A_REST; a move ends at once and starts the tracker's oscillation."""

    name = "still-test-robot"

    def __init__(self, tracker: SwingTracker) -> None:
        super().__init__()
        self.tracker = tracker

    def _open(self) -> None:
        pass

    def _close(self) -> None:
        pass

    def _flange_pose(self) -> np.ndarray:
        return A_REST.copy()

    def _move_to(self, pose: np.ndarray, speed_mm_s: float, accel_mm_s2: float) -> None:
        self.tracker.moved()

    def _stop(self) -> None:
        pass


def _run(tr: SwingTracker, n: int = 30, **kw):
    """Move (the oscillation starts), then sample_pose on the tracker's clock; returns the
    sample and the last frame number served before sampling began."""
    rob = StillRobot(tr).open()
    tr.open()
    rob.move_to(A_REST)
    seen: dict[str, int] = {}

    def phase(name: str) -> None:
        seen[name] = tr.frame

    kw.setdefault("settle_s", 3.0)
    s = sample_pose(rob, tr, SamplingConfig(samples=n, **kw),
                    sleep=lambda _s: pytest.fail("slept"), clock=tr.clock, on_phase=phase)
    return s, seen.get("sampling")


def _t_envelope(a0: float, tau: float, level: float) -> float:
    """Seconds after the move at which a0·exp(−t/τ) falls to ``level`` (mm)."""
    return tau * math.log(a0 / level)


# --- settling ---------------------------------------------------------------------------------

A0, TAU, FREQ = 0.5, 0.25, 5.0
W = window_frames(0.2, RATE_HZ)        # 12 frames: one period of FREQ
NOISE_SPREAD_MAX = 0.02                # mm: √3·σ = 0.009 for σ = 0.005; a generous bound


@pytest.mark.parametrize("seed", range(5))
def test_sampling_starts_once_the_oscillation_has_decayed_below_the_tolerance(seed):
    tol = 0.05
    tr = SwingTracker(seed, A0, TAU, FREQ, sigma_mm=0.005)
    s, last_settle = _run(tr, still_tol_mm=tol)
    assert s.problem is None and s.still
    t_first = s.first_frame / RATE_HZ          # the first averaged frame (move at t = 0)
    t_settled = last_settle / RATE_HZ          # the window's last frame
    # never before: a window ending while the envelope is ≥ 3·tol holds one period of an
    # oscillation of amplitude ≥ 3·tol (RMS ≥ 0.64·amplitude ≈ 0.096 mm with this decay),
    # more than tol plus any noise spread
    assert t_settled >= _t_envelope(A0, TAU, 3 * tol)
    # and it does start: once the envelope at the window's start is below tol minus the
    # noise, the window's spread (≤ the envelope + the noise spread) is within tol
    window_s = (W - 1) / RATE_HZ
    assert t_settled <= _t_envelope(A0, TAU, tol - NOISE_SPREAD_MAX) + window_s + 1 / RATE_HZ
    assert t_first > t_settled                 # settling frames are not averaged in
    assert s.frames == 30 and s.samples["marker"] == 30


@pytest.mark.parametrize("seed", range(5))
def test_tolerance_from_the_noise_waits_for_the_decay(seed):
    sigma = 0.02
    tr = SwingTracker(seed, A0, TAU, FREQ, sigma_mm=sigma)
    s, last_settle = _run(tr)
    assert s.problem is None and s.still
    t_settled = last_settle / RATE_HZ
    # the tolerance is 2·√3·σ̂ ≈ 0.07 mm; an amplitude of 0.3 mm (15 σ) is never still
    assert t_settled >= _t_envelope(A0, TAU, 0.3)
    # and it does start: once the envelope at the window's start is 0.005 mm (σ/4) the
    # windows hold noise alone, whose spread (≈ √3·σ) passes against 2·√3·σ̂
    window_s = (W - 1) / RATE_HZ
    assert t_settled <= _t_envelope(A0, TAU, 0.005) + window_s + 1 / RATE_HZ
    # the mean over the samples is near the rest pose: the residual swing is small
    err = np.linalg.norm(s.bodies["marker"][:3, 3] - REST["marker"][:3, 3])
    assert err < 0.05


def test_sampling_without_settling_would_be_biased():
    # the same tracker sampled at once (settle_s 0): the first averaged frame is the first
    # frame after the move, inside the swing; this is what the tests above rule out
    tr = SwingTracker(0, A0, TAU, FREQ, sigma_mm=0.005)
    s, _ = _run(tr, n=3, settle_s=0.0)
    assert not s.still and s.first_frame == 1
    assert s.first_frame / RATE_HZ < _t_envelope(A0, TAU, 3 * 0.05)
    err = np.linalg.norm(s.bodies["marker"][:3, 3] - REST["marker"][:3, 3])
    assert err > 0.1


@pytest.mark.parametrize("settle_s", [0.5, 1.5])
def test_a_tracker_that_never_settles_is_reported_after_settle_s(settle_s):
    amp, freq = 0.4, 4.0
    tr = SwingTracker(1, amp, None, freq, sigma_mm=0.01)
    s, _ = _run(tr, settle_s=settle_s)
    assert not s.still and s.bodies == {"marker": None, "probe": None}
    assert s.problem is not None and s.problem.startswith(f"not still after {settle_s:g} s")
    # the bound is honoured in tracker time (frames / rate), not earlier, not much later
    assert settle_s * RATE_HZ <= tr.frame <= settle_s * RATE_HZ + 1
    # the message gives the spread over the last window: a sustained sine's RMS, amp/√2,
    # over the window's 0.2 s (0.8 of a period: between 0.55 and 0.75 of amp)
    got = dict(re.findall(r"(marker|probe) ([0-9.]+) mm RMS over the last window", s.problem))
    assert set(got) == {"marker", "probe"}
    for v in got.values():
        assert 0.5 * amp <= float(v) <= 0.8 * amp
    assert s.samples == {"A": 1, "marker": 0, "probe": 0} and s.frames == 0


@pytest.mark.parametrize("amp, still", [(0.0, True), (0.4, False)])
def test_a_settle_time_shorter_than_the_window_judges_one_shorter_window(amp, still):
    # settle_s 0.05 s is 3 frames at 60 Hz: the window shrinks to settle_s, i.e. to its
    # floor of 6 frames, and that one window is judged
    tr = SwingTracker(9, amp, None, 4.0, sigma_mm=0.01)
    s, _ = _run(tr, n=5, settle_s=0.05)
    assert s.still is still
    assert (s.problem is None) is still
    assert tr.frame == 6 + (5 if still else 0)


def test_settling_frames_are_never_averaged_in_even_when_a_frame_repeats():
    tr = SwingTracker(2, A0, TAU, FREQ, sigma_mm=0.005, repeat=True)
    s, last_settle = _run(tr, still_tol_mm=0.05)
    assert s.still and s.first_frame == last_settle + 1
    assert s.frames == 30 and s.last_frame == last_settle + 30


def test_fixed_settle_waits_and_reads_no_frame():
    tr = SwingTracker(3, A0, TAU, FREQ, sigma_mm=0.005)
    rob = StillRobot(tr).open()
    tr.open()
    slept: list[float] = []
    s = sample_pose(rob, tr, SamplingConfig(samples=5, settle_s=0.7, settle="fixed"),
                    sleep=slept.append, clock=tr.clock)
    assert slept == [0.7] and s.first_frame == 1 and not s.still


def test_settle_zero_reads_no_settling_frame():
    tr = SwingTracker(3, A0, TAU, FREQ, sigma_mm=0.005)
    s, last = _run(tr, n=5, settle_s=0.0)
    assert last == 0 and s.first_frame == 1 and s.frames == 5


def test_a_body_never_seen_does_not_hold_up_settling():
    # the probe is missing: it is not judged (the usable share names it), the marker is
    tr = SwingTracker(4, A0, TAU, FREQ, sigma_mm=0.005, missing=("probe",))
    s, last_settle = _run(tr, still_tol_mm=0.05)
    assert s.still and last_settle / RATE_HZ >= _t_envelope(A0, TAU, 3 * 0.05)
    assert s.problem is not None
    assert s.problem.startswith("probe seen in 0 of 30 frames, below min_share 0.8")


@pytest.mark.parametrize("kw", [{"settle": "wait"}, {"still_window_s": 0.0},
                                {"still_tol_mm": -1.0}, {"sem_mm": 0.0},
                                {"min_samples": 0}, {"sem_mm": float("nan")},
                                # the config's ranges hold here too: one check of them
                                {"min_share": 1.5}, {"settle_s": 5000.0},
                                {"max_frames_factor": 0.0}])
def test_bad_options_are_named(kw):
    tr = SwingTracker(0, 0.0, None, 1.0, sigma_mm=0.0)
    with pytest.raises(ValueError, match=next(iter(kw))):
        sample_pose(StillRobot(tr).open(), tr.open(), SamplingConfig(samples=5, **kw))


# --- the rule itself --------------------------------------------------------------------------

def test_noise_estimate_is_the_white_noise_sigma():
    rng = np.random.default_rng(7)
    sigma = 0.03
    est = noise_sigma_mm(rng.normal(0.0, sigma, (3000, 3)))
    # median of 9000 |second differences|: relative standard error ≈ 1.5 %; 6 % is 4 SE
    assert abs(est / sigma - 1) < 0.06


def test_a_slow_oscillation_is_not_mistaken_for_noise():
    # 4 Hz at 60 Hz over a 0.2 s window, amplitude 0.2 mm = 10 σ: the noise estimate is
    # barely raised, the spread is not, so the window is not still; without the swing it is
    rng = np.random.default_rng(11)
    sigma, t = 0.02, np.arange(W) / RATE_HZ
    moving = still = 0
    for _ in range(400):
        noise = rng.normal(0.0, sigma, (W, 3))
        phase = rng.uniform(0, 2 * np.pi)
        swing = 0.2 * np.cos(2 * np.pi * 4.0 * t + phase)[:, None] * U
        spread, tol = stillness(noise + swing)
        moving += spread > tol
        spread, tol = stillness(noise)
        still += spread <= tol
    # seeded; the share of windows judged right, each with a margin of several SE
    assert moving / 400 >= 0.95
    assert still / 400 >= 0.95


@given(st.lists(st.floats(-1.0, 1.0), min_size=3 * 8, max_size=3 * 8),
       st.floats(-2000.0, 2000.0), st.floats(0.1, 10.0))
@fuzz_settings(100)
def test_stillness_ignores_where_the_body_is_and_scales_with_its_motion(vals, shift, scale):
    p = np.asarray(vals).reshape(8, 3)
    s0, t0 = stillness(p)
    s1, t1 = stillness(p + shift)
    assert s1 == pytest.approx(s0, abs=1e-9) and t1 == pytest.approx(t0, abs=1e-9)
    s2, t2 = stillness(p * scale)
    assert s2 == pytest.approx(s0 * scale, rel=1e-9, abs=1e-12)
    assert t2 >= STILL_FLOOR_MM
    if t0 > STILL_FLOOR_MM and t0 * scale > STILL_FLOOR_MM:
        assert t2 == pytest.approx(t0 * scale, rel=1e-9)
    assert stillness(p, 0.123)[1] == 0.123


def test_window_is_still_window_s_of_frames_with_a_floor():
    assert window_frames(0.2, 60.0) == 12
    assert window_frames(0.2, 20.0) == 6 and window_frames(0.01, 400.0) == 6
    assert window_frames(0.5, 250.0) == 125


# --- samples by need --------------------------------------------------------------------------

def _sem_at_each_k(served: list, body: str, first: int, kmax: int) -> np.ndarray:
    """Standard error (RMS spread / √k, mm) of a body's first k averaged positions, for
    k = 1..kmax, computed here from the positions the tracker served."""
    pts = np.stack([p[body] for f, p in served if f >= first][:kmax])
    out = []
    for k in range(1, kmax + 1):
        d = pts[:k] - pts[:k].mean(axis=0)
        out.append(math.sqrt(np.mean(np.sum(d ** 2, axis=1))) / math.sqrt(k))
    return np.asarray(out)


def test_sem_stops_at_the_floor_on_a_quiet_tracker():
    tr = SwingTracker(5, 0.0, None, 1.0, sigma_mm=0.002)
    s, _ = _run(tr, n=100, settle_s=0.0, sem_mm=0.01, min_samples=10)
    assert s.problem is None and s.frames == 10
    assert s.samples["marker"] == s.samples["probe"] == 10
    assert s.samples["A"] == 10          # robot reads spread over the floor's frames


@pytest.mark.parametrize("floor", [4, 25])
def test_sem_respects_the_floor(floor):
    tr = SwingTracker(6, 0.0, None, 1.0, sigma_mm=0.002)
    s, _ = _run(tr, n=100, settle_s=0.0, sem_mm=0.01, min_samples=floor)
    assert s.frames == floor


def test_sem_runs_to_the_cap_on_a_noisy_tracker():
    tr = SwingTracker(7, 0.0, None, 1.0, sigma_mm=0.5)
    s, _ = _run(tr, n=60, settle_s=0.0, sem_mm=0.01, min_samples=10)
    assert s.problem is None and s.frames == 60 and s.samples["marker"] == 60


def test_a_floor_above_the_cap_gives_the_cap():
    tr = SwingTracker(8, 0.0, None, 1.0, sigma_mm=0.002)
    s, _ = _run(tr, n=5, settle_s=0.0, sem_mm=0.01, min_samples=10)
    assert s.frames == 5


@pytest.mark.parametrize("seed", range(3))
def test_sem_stops_at_the_first_count_whose_standard_error_is_small_enough(seed):
    # σ = 0.05 mm per axis, sem_mm 0.01: about 3σ²/sem² = 75 frames. The count must be the
    # first k ≥ the floor at which both bodies' standard errors are within the target
    sem, floor, cap = 0.01, 10, 400
    tr = SwingTracker(10 + seed, 0.0, None, 1.0, sigma_mm=0.05)
    s, _ = _run(tr, n=cap, settle_s=0.0, sem_mm=sem, min_samples=floor)
    sems = {b: _sem_at_each_k(tr.served, b, s.first_frame, cap) for b in REST}
    ok = (sems["marker"] <= sem) & (sems["probe"] <= sem)
    want = floor + int(np.argmax(ok[floor - 1:]))
    assert ok[floor - 1:].any() and 30 < want < cap
    assert s.frames == want
    for b in REST:
        spread = s.spread[b]["trans_mm"]
        assert spread / math.sqrt(want) == pytest.approx(sems[b][want - 1], rel=1e-6)


def test_sem_with_settling_records_counts_and_spread_as_a_fixed_count_does():
    tr = SwingTracker(20, A0, TAU, FREQ, sigma_mm=0.02)
    s, last_settle = _run(tr, n=200, sem_mm=0.005, min_samples=10)
    assert s.still and s.first_frame > last_settle
    assert s.samples["marker"] == s.frames and s.share["marker"] == 1.0
    assert set(s.spread) == {"A", "marker", "probe"}


# --- the config keys --------------------------------------------------------------------------

def _sampling(**kw):
    return parse_config({"sampling": kw}, "rig.yaml").sampling


def test_config_defaults_settle_by_stillness_with_a_fixed_count():
    s = _sampling()
    assert (s.settle, s.still_window_s, s.still_tol_mm, s.min_samples, s.sem_mm) == \
        ("still", 0.2, None, 10, None)
    s = _sampling(settle="fixed", still_window_s=0.5, still_tol_mm=0.04, min_samples=20,
                  sem_mm=0.01, settle_s=0.1)
    assert (s.settle, s.still_window_s, s.still_tol_mm, s.min_samples, s.sem_mm) == \
        ("fixed", 0.5, 0.04, 20, 0.01)


@pytest.mark.parametrize("kw, key", [
    ({"settle": "wait"}, "sampling.settle"),
    ({"settle": 1}, "sampling.settle"),
    ({"still_window_s": 0}, "sampling.still_window_s"),
    ({"still_window_s": 600}, "sampling.still_window_s"),
    ({"still_window_s": float("nan")}, "sampling.still_window_s"),
    ({"still_tol_mm": -0.1}, "sampling.still_tol_mm"),
    ({"still_tol_mm": 50}, "sampling.still_tol_mm"),
    ({"still_tol_mm": "0.1"}, "sampling.still_tol_mm"),
    ({"min_samples": 0}, "sampling.min_samples"),
    ({"min_samples": 2.5}, "sampling.min_samples"),
    ({"sem_mm": 0}, "sampling.sem_mm"),
    ({"sem_mm": float("inf")}, "sampling.sem_mm"),
    ({"sem_mm": True}, "sampling.sem_mm"),
    ({"sem_mm": 0.01, "samples": 5}, "sampling.min_samples"),
])
def test_config_refuses_bad_sampling_keys_naming_them(kw, key):
    with pytest.raises(ConfigError, match=re.escape(f"rig.yaml: key '{key}'")):
        _sampling(**kw)


_KEYS = ["settle", "still_window_s", "still_tol_mm", "min_samples", "sem_mm"]


@given(st.dictionaries(st.sampled_from(_KEYS),
                       st.one_of(st.none(), st.booleans(), st.integers(-10, 10 ** 7),
                                 st.floats(allow_nan=True, allow_infinity=True),
                                 st.sampled_from(["still", "fixed", "Still", ""])),
                       max_size=5))
@fuzz_settings(200)
def test_config_sampling_keys_are_accepted_in_range_or_refused_by_name(kw):
    try:
        s = _sampling(**kw)
    except ConfigError as e:
        assert re.match(r"rig\.yaml: key 'sampling\.(\w+)'", str(e))
        assert re.match(r"rig\.yaml: key 'sampling\.(\w+)'", str(e)).group(1) in _KEYS
        return
    assert s.settle in ("still", "fixed")
    assert 0 < s.still_window_s <= 60 and 1 <= s.min_samples
    assert s.still_tol_mm is None or 0 < s.still_tol_mm <= 10
    assert s.sem_mm is None or (0 < s.sem_mm <= 10 and s.min_samples <= s.samples)


# --- a run's sampling settings: new, and resumed from a session header -----------------------

def _cfg(**sampling):
    return parse_config({"sampling": sampling}, "rig.yaml")


def test_a_new_run_records_every_sampling_option_in_the_header():
    st_ = _settings(_cfg(settle_s=0.5, sem_mm=0.01, min_samples=12, still_tol_mm=0.05), None,
                    None)
    h = st_.to_header()
    assert h == {"samples": 100, "settle_s": 0.5, "min_share": 0.8, "robot_reads": 10,
                 "settle": "still", "still_window_s": 0.2, "still_tol_mm": 0.05,
                 "min_samples": 12, "sem_mm": 0.01}
    # and a resume with that header under the default config takes every one back
    back = _settings(_cfg(), {"sampling": h}, None)
    assert back.to_header() == h
    assert len(back.notes) == 4          # settle_s, still_tol_mm, min_samples, sem_mm


def test_a_session_from_before_stillness_resumes_as_it_was_recorded():
    old = {"sampling": {"samples": 50, "settle_s": 1.0, "min_share": 0.8, "robot_reads": 10}}
    st_ = _settings(_cfg(sem_mm=0.01), old, None)
    assert (st_.settle, st_.sem_mm, st_.samples, st_.settle_s) == ("fixed", None, 50, 1.0)
    assert any("before settling by stillness" in n for n in st_.notes)


@pytest.mark.parametrize("bad", [{"settle": "wait"}, {"settle": None},
                                 {"still_tol_mm": -1.0}, {"sem_mm": "0.01"},
                                 {"min_samples": 0}, {"min_samples": 2.5},
                                 {"still_window_s": None}, {"sem_mm": float("inf")},
                                 # beyond the config's ranges (check_sampling, the one check)
                                 {"min_share": 0.0}, {"settle_s": 5000.0},
                                 {"still_window_s": 61.0}, {"sem_mm": 11.0}])
def test_a_header_value_the_config_would_refuse_is_ignored(bad):
    cfg = _cfg(sem_mm=0.02, still_tol_mm=0.05)
    h = {**_settings(cfg, None, None).to_header(), **bad}
    st_ = _settings(cfg, {"sampling": h}, None)
    assert st_.to_header() == _settings(cfg, None, None).to_header()
    assert st_.notes == []
