"""Random configs (NaN, ±inf, negative, huge, missing and reordered limits, options naming
safety arguments) through ``parse_config``; every accepted one builds its robot through the real
``make_robot`` path around a recording fake driver, and random P0s, target poses and speeds go
through ``Robot.move_to``. Whatever reaches the driver's ``_move_to`` hook must satisfy the
config's limits, computed here by hand from the raw config (never through ``Envelope``), all
along the straight path from where the fake robot stands (the base class's default motion law:
a linear move of the flange); a target clearly inside every limit must get through unless the
robot stands outside or both the straight path and the split route through the centre come
near a limit; one clearly outside must not."""

from __future__ import annotations

import dataclasses
import math
from unittest import mock

import numpy as np
from hypothesis import event, example, given
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from tests.fuzz import fuzz_settings
from tmscal import registry
from tmscal.acquisition.devices import envelope_for, make_robot
from tmscal.config import parse_config
from tmscal.drivers.base import Robot
from tmscal.errors import ConfigError, SafetyError

TOL = 1e-6  # band around each limit where either answer is fine (mm, deg, mm/s)


class RecordingRobot(Robot):
    """Stands in for a driver's motion hook: records (pose, speed, accel) it was given, and
    stands where the last one sent it (``here``; the test puts it somewhere first)."""

    name = "recording"

    def __init__(self, host: str = "", envelope=None, speed_mm_s: float = 100.0,
                 accel_mm_s2: float = 500.0, **options) -> None:
        super().__init__(envelope=envelope, speed_mm_s=speed_mm_s, accel_mm_s2=accel_mm_s2)
        self.sent: list[tuple[np.ndarray, float, float]] = []
        self.here = np.eye(4)

    def _open(self) -> None:
        pass

    def _close(self) -> None:
        pass

    def _flange_pose(self) -> np.ndarray:
        return self.here.copy()

    def _move_to(self, pose: np.ndarray, speed_mm_s: float, accel_mm_s2: float) -> None:
        self.sent.append((np.array(pose), speed_mm_s, accel_mm_s2))
        self.here = np.array(pose)

    def _stop(self) -> None:
        pass


# --- strategies --------------------------------------------------------------------------------

BAD = st.sampled_from([math.nan, math.inf, -math.inf, 0, -0.0, -5.0, 10**30, 10**400, True,
                       "200", [1.0], None])


def mostly(good, bad=BAD, p_bad: int = 1):
    """``good`` 16 times in 16 + p_bad, else ``bad``."""
    return st.integers(0, 15 + p_bad).flatmap(lambda i: good if i < 16 else bad)


OMIT = object()


@st.composite
def configs(draw):
    lo = [draw(st.floats(-1000, 600)) for _ in range(3)]
    hi = [a + draw(st.floats(100, 1500)) for a in lo]
    box_kind = draw(st.sampled_from(["ok"] * 25 + ["swap", "equal", "nan", "missing", "huge"]))
    if box_kind != "ok":
        ax = draw(st.integers(0, 2))
        if box_kind == "swap":
            lo[ax], hi[ax] = hi[ax], lo[ax]
        elif box_kind == "equal":
            hi[ax] = lo[ax]
        elif box_kind == "nan":
            (lo if draw(st.booleans()) else hi)[ax] = draw(st.sampled_from([math.nan, math.inf]))
        elif box_kind == "huge":
            hi[ax] = draw(st.sampled_from([10**30, 10**400, 1e300]))
    safety = {
        "max_offset_mm": draw(mostly(st.floats(1, 400))),
        "max_rotation_deg": draw(mostly(st.floats(0.5, 60))),
        "workspace_min_mm": lo, "workspace_max_mm": hi,
        "max_speed_mm_s": draw(mostly(st.floats(10, 1000))),
        "max_accel_mm_s2": draw(mostly(st.floats(100, 5000))),
    }
    if box_kind == "missing":
        del safety[draw(st.sampled_from(["workspace_min_mm", "workspace_max_mm"]))]
    for k in list(safety):
        if draw(st.integers(0, 40)) == 0:
            del safety[k]
    tp = st.lists(st.lists(st.floats(-150, 150), min_size=3, max_size=3), min_size=1,
                  max_size=5)
    points = draw(mostly(st.one_of(st.just(OMIT), tp, tp),
                         st.sampled_from([[[0, 0, math.nan]], [[0, 0]], [], [[0, 0, 1e9]]])))
    if points is not OMIT:
        safety["tool_points_mm"] = points
    cap_v = safety.get("max_speed_mm_s")
    cap_a = safety.get("max_accel_mm_s2")

    def usable(c, floor):
        return isinstance(c, float) and math.isfinite(c) and c > floor

    good_v = st.floats(1, cap_v) if usable(cap_v, 1) else st.floats(1, 100)
    good_a = st.floats(10, cap_a) if usable(cap_a, 10) else st.floats(10, 500)
    robot = {"driver": "ur", "host": "127.0.0.2",
             "speed_mm_s": draw(mostly(good_v, st.one_of(BAD, st.floats(1000, 3000)))),
             "accel_mm_s2": draw(mostly(good_a, st.one_of(BAD, st.floats(5000, 60000))))}
    opt = draw(st.sampled_from(["none"] * 10 + ["ok"] * 5 + ["envelope", "speed_mm_s",
                                                             "accel_mm_s2", "host", "port"]))
    if opt == "ok":
        robot["options"] = {"upload_script": True}
    elif opt != "none":
        robot["options"] = {opt: draw(st.sampled_from([None, 2000.0, 10**6, "x"]))}
    data = {"robot": robot}
    if draw(st.integers(0, 30)) > 0:
        data["safety"] = safety
    return data


# --- the oracle (by hand, from the raw config) -------------------------------------------------

def limits_from_raw(data: dict) -> dict:
    s = data["safety"]
    lim = {k: float(s[k]) for k in ("max_offset_mm", "max_rotation_deg", "max_speed_mm_s",
                                     "max_accel_mm_s2")}
    lim["lo"] = [float(x) for x in s["workspace_min_mm"]]
    lim["hi"] = [float(x) for x in s["workspace_max_mm"]]
    lim["points"] = [[float(c) for c in q] for q in s.get("tool_points_mm") or []]
    return lim


def excess(T: np.ndarray, lim: dict, p0: np.ndarray | None) -> float:
    """How far (mm or deg) the worst limit is exceeded by flange pose T (negative: inside)."""
    if T.shape != (4, 4) or not all(math.isfinite(x) for x in T.ravel()):
        return math.inf
    R = T[:3, :3]
    if (abs(R.T @ R - np.eye(3)).max() > 1e-6 or abs(np.linalg.det(R) - 1) > 1e-6
            or abs(T[3] - [0, 0, 0, 1]).max() > 1e-9):
        return math.inf
    worst = -math.inf
    t = [T[0, 3], T[1, 3], T[2, 3]]
    if p0 is not None:
        d = math.dist(t, [p0[0, 3], p0[1, 3], p0[2, 3]])
        worst = max(worst, d - lim["max_offset_mm"])
        Rr = p0[:3, :3].T @ R
        c = max(-1.0, min(1.0, (Rr[0, 0] + Rr[1, 1] + Rr[2, 2] - 1) / 2))
        worst = max(worst, math.degrees(math.acos(c)) - lim["max_rotation_deg"])
    pts = [t] + [[sum(R[i, j] * q[j] for j in range(3)) + t[i] for i in range(3)]
                 for q in lim["points"]]
    for p in pts:
        for i in range(3):
            worst = max(worst, lim["lo"][i] - p[i], p[i] - lim["hi"][i])
    return worst


def excess_all(T: np.ndarray, lim: dict, p0: np.ndarray | None) -> np.ndarray:
    """``excess`` of many rigid flange poses T (n, 4, 4) at once (mm or deg; < 0 inside)."""
    R, t = T[:, :3, :3], T[:, :3, 3]
    worst = np.full(len(T), -np.inf)
    if p0 is not None:
        worst = np.maximum(worst, np.linalg.norm(t - p0[:3, 3], axis=1) - lim["max_offset_mm"])
        Rr = np.swapaxes(R, 1, 2) @ p0[:3, :3]
        c = np.clip((np.trace(Rr, axis1=1, axis2=2) - 1) / 2, -1.0, 1.0)
        worst = np.maximum(worst, np.degrees(np.arccos(c)) - lim["max_rotation_deg"])
    q = np.array([[0.0, 0.0, 0.0]] + lim["points"])
    pts = np.einsum("nij,kj->nki", R, q) + t[:, None]
    lo, hi = np.array(lim["lo"]), np.array(lim["hi"])
    return np.maximum(worst, np.maximum(lo - pts, pts - hi).max(axis=(1, 2)))


def path_excess(A: np.ndarray, B: np.ndarray, lim: dict, p0: np.ndarray | None,
                n: int = 801) -> float:
    """The worst ``excess`` along the straight move of the flange from A to B (translation
    on the line, rotation on the geodesic, one share), sampled at n shares (by hand, scipy)."""
    f = np.linspace(0.0, 1.0, n)
    rv = Rotation.from_matrix(A[:3, :3].T @ B[:3, :3]).as_rotvec()
    T = np.zeros((n, 4, 4))
    T[:, 3, 3] = 1.0
    T[:, :3, :3] = A[:3, :3] @ Rotation.from_rotvec(f[:, None] * rv).as_matrix()
    T[:, :3, 3] = A[:3, 3] + f[:, None] * (B[:3, 3] - A[:3, 3])
    return float(excess_all(T, lim, p0).max())


def split_excess(A: np.ndarray, B: np.ndarray, lim: dict, p0: np.ndarray | None) -> float:
    """The worst ``excess`` of the split route (A's orientation to the centre, turn there,
    out to B; docs/safety.md), the centre being P0's position or the box's centre."""
    c = p0[:3, 3] if p0 is not None else (np.array(lim["lo"]) + np.array(lim["hi"])) / 2
    w1, w2 = A.copy(), B.copy()
    w1[:3, 3] = c
    w2[:3, 3] = c
    return max(path_excess(a, b, lim, p0) for a, b in ((A, w1), (w1, w2), (w2, B)))


def turning_excess(A: np.ndarray, B: np.ndarray, lim: dict, p0: np.ndarray | None) -> float:
    """The better of the two split routes without a turn on the spot (docs/safety.md: for a
    controller that times only the translation): to the centre turning to B's orientation,
    then on to B; or to the centre in A's orientation, then on to B turning. A leg that turns
    without translating counts as outside (it cannot be timed)."""
    c = p0[:3, 3] if p0 is not None else (np.array(lim["lo"]) + np.array(lim["hi"])) / 2
    worst = []
    for R in (B[:3, :3], A[:3, :3]):
        w = np.eye(4)
        w[:3, :3], w[:3, 3] = R, c
        legs = [(A, w), (w, B)]
        if any(np.linalg.norm(b[:3, 3] - a[:3, 3]) < 1e-6
               and Rotation.from_matrix(a[:3, :3].T @ b[:3, :3]).magnitude() > 1e-9
               for a, b in legs):
            worst.append(math.inf)
            continue
        worst.append(max(path_excess(a, b, lim, p0) for a, b in legs))
    return min(worst)


def random_rotation(rng: np.random.Generator, max_deg: float) -> np.ndarray:
    axis = rng.standard_normal(3)
    axis /= np.linalg.norm(axis)
    a = math.radians(rng.uniform(0, max_deg))
    K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + math.sin(a) * K + (1 - math.cos(a)) * K @ K


def targets(rng: np.random.Generator, p0: np.ndarray, lim: dict, n: int) -> list[np.ndarray]:
    out = []
    for _ in range(n):
        kind = rng.integers(0, 10)
        T = np.eye(4)
        if kind < 5:    # around P0, near the offset and rotation limits
            d = rng.standard_normal(3)
            d *= rng.uniform(0, 1.3) * lim["max_offset_mm"] / np.linalg.norm(d)
            T[:3, :3] = p0[:3, :3] @ random_rotation(rng, min(180.0, 1.3 * lim["max_rotation_deg"]))
            T[:3, 3] = p0[:3, 3] + d
        elif kind < 9:  # anywhere near the box, any orientation
            lo, hi = np.array(lim["lo"]), np.array(lim["hi"])
            T[:3, :3] = random_rotation(rng, 180.0)
            T[:3, 3] = rng.uniform(lo - 0.2 * (hi - lo) - 5, hi + 0.2 * (hi - lo) + 5)
        else:           # garbage
            T = rng.choice([np.full((4, 4), np.nan), 2.0 * p0, p0 + 1e-3])
        out.append(T)
    return out


def speeds(rng: np.random.Generator, cap: float, n: int) -> list:
    pool = [None, cap, cap * 1.01, cap * 0.99, 0.0, -1.0, math.nan, math.inf, cap * 10]
    return [pool[rng.integers(0, len(pool))] if rng.integers(0, 3) == 0
            else float(rng.uniform(0.5, 1.2) * cap) for _ in range(n)]


@fuzz_settings(600)
@given(configs(), st.integers(0, 2**32 - 1))
@example(  # CI found it: a split route's turn at the centre, untimed by a linear-move law
    {"robot": {"driver": "ur", "host": "127.0.0.2", "speed_mm_s": 1.0, "accel_mm_s2": 10.0},
     "safety": {"max_offset_mm": 3.0, "max_rotation_deg": 1.0,
                "workspace_min_mm": [0.0, 0.0, 0.0], "workspace_max_mm": [142.0, 284.0, 620.0],
                "max_speed_mm_s": 10.0, "max_accel_mm_s2": 100.0,
                "tool_points_mm": [[0.0, 36.0, 83.0]]}}, 65536)
def test_nothing_outside_the_config_reaches_the_driver(data, seed):
    try:
        cfg = parse_config(data, "fuzz.yaml")
    except ConfigError as e:
        assert str(e).startswith("fuzz.yaml: key '"), e
        event("refused")
        return
    event("accepted")
    # accepted: every limit is a finite positive number and the box is ordered (by hand)
    lim = limits_from_raw(data)
    for k in ("max_offset_mm", "max_rotation_deg", "max_speed_mm_s", "max_accel_mm_s2"):
        assert math.isfinite(lim[k]) and lim[k] > 0, k
    assert all(math.isfinite(a) and math.isfinite(b) and a < b
               for a, b in zip(lim["lo"], lim["hi"]))
    assert all(math.isfinite(c) for q in lim["points"] for c in q)
    opts = data["robot"].get("options") or {}
    assert not set(opts) & {"envelope", "speed_mm_s", "accel_mm_s2", "host", "port"}
    v0, a0 = float(data["robot"]["speed_mm_s"]), float(data["robot"]["accel_mm_s2"])
    assert 0 < v0 <= lim["max_speed_mm_s"] and 0 < a0 <= lim["max_accel_mm_s2"]

    rng = np.random.default_rng(seed)
    lo, hi = np.array(lim["lo"]), np.array(lim["hi"])
    p0 = np.eye(4)
    p0[:3, :3] = random_rotation(rng, 180.0)
    p0[:3, 3] = rng.uniform(lo - 20, hi + 20)
    path = f"{__name__}:RecordingRobot"
    fakes = {n: dataclasses.replace(registry.SPECS[n], cls=path, requires=())
             for n in ("ur", "denso")}
    with mock.patch.dict(registry.SPECS, fakes):
        for centre in (None, p0):  # before P0 is known (caps, box), then around P0
            env = None if centre is None else envelope_for(cfg, centre)
            robot = make_robot(cfg, env)
            assert isinstance(robot, RecordingRobot)
            robot.here = p0.copy()
            n = 30
            with robot:
                for T, v in zip(targets(rng, p0, lim, n), speeds(rng, lim["max_speed_mm_s"], n)):
                    sent_before = len(robot.sent)
                    here = robot.here.copy()
                    try:
                        robot.move_to(T, v)
                    except SafetyError:
                        pass
                    legs = robot.sent[sent_before:]
                    e = excess(np.asarray(T, dtype=float), lim, centre)
                    speed = v0 if v is None else v
                    speed_ok = (isinstance(speed, float) and math.isfinite(speed)
                                and 0 < speed <= lim["max_speed_mm_s"])
                    if legs:
                        np.testing.assert_array_equal(legs[-1][0], T)
                        assert e <= TOL, (e, T)
                        assert speed_ok
                        start = here
                        for pose, sv, sa in legs:   # every leg inside all the way
                            assert path_excess(start, pose, lim, centre) <= TOL, (start, pose)
                            assert 0 < sv <= speed + TOL and math.isfinite(sv)
                            assert 0 < sa <= lim["max_accel_mm_s2"] + TOL and math.isfinite(sa)
                            start = pose
                        event(f"legs: {len(legs)}")
                    elif e < -TOL and speed_ok and speed <= lim["max_speed_mm_s"] - TOL:
                        # refused although the target is inside: only when the robot stands
                        # outside, or both routes come within sampling slack of a limit
                        slack = 0.5   # mm or deg: what 801 samples can miss of a path's worst
                        outside_now = excess(here, lim, centre) > -TOL
                        # a law that times only the translation cannot time the split
                        # route's turn at the centre when tool points are carried: it turns
                        # while translating instead (docs/safety.md)
                        untimed = (robot.motion_law().timing.rotation_mm_per_rad == 0
                                   and bool(lim["points"]))
                        split = (turning_excess if untimed else split_excess)(
                            here, T, lim, centre)
                        blocked = path_excess(here, T, lim, centre) > -slack and split > -slack
                        if not (outside_now or blocked):
                            raise AssertionError(f"a target {-e:.3g} inside every limit, "
                                                 "reachable inside, was refused: "
                                                 f"{here.tolist()} → {T.tolist()} at {speed}")
            event(f"moves sent: {'none' if not robot.sent else 'some'}")
