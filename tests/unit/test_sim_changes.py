"""What moved on the mock rig since its calibration (``tmscal.sim.changes``): the four changes
(tracker, marker, coil, coil_centre) against hand-worked expectations on the built-in TMS rig,
``SimRig.apply_change`` and timed ``events`` on a hand-set clock and on the Polaris mock's
fast clock, ``mock.changes`` / ``mock.events`` in a config, and that neither draws from the
rig's RNG.

The built-in rig (``tms_rig_truth``): t(X) = [12, −8, 60] mm, t(Y) = [3, 5, 110] mm, and the
tracker's axes in the base frame are x = base x, y = base z, z = −base y (so a base-frame
displacement d is seen from the tracker as R_Zᵀ·d = [d_x, d_z, −d_y]).
"""

from __future__ import annotations

import math
import re

import numpy as np
import pytest

from tests.rigs import TOOLS_DIR, quiet_tms_rig
from tmscal.config import load_config
from tmscal.errors import ConfigError
from tmscal.geometry import invert, make_pose, rot_x, rot_z, rotation_angle
from tmscal.mocks.clock import FAST
from tmscal.mocks.launch import build_sim_rig
from tmscal.mocks.polaris.frames import FrameSource
from tmscal.mocks.polaris.model import PolarisFaults
from tmscal.sim import (
    TMS_RIG_P0,
    Change,
    Event,
    Noise,
    SimRig,
    Truth,
    apply_changes,
    changed,
    facing_start,
    tms_rig_truth,
)

T = tms_rig_truth()
#: flange poses (base_from_flange, mm) around P0 the rig is observed at
POSES = [TMS_RIG_P0 @ make_pose(rot_x(math.radians(a)) @ rot_z(math.radians(b)), d)
         for a, b, d in ((0, 0, [0, 0, 0]), (8, -5, [40, -20, 10]), (-6, 12, [-30, 50, -25]))]


def _seen(rig: SimRig, body: str) -> list[np.ndarray]:
    """tracker_from_<body> (4×4 mm) at every pose of POSES, noise-free."""
    out = []
    for A in POSES:
        rig.move_flange(A)
        out.append(rig.true_body(body))
    return out


def _angle_deg(Ra: np.ndarray, Rb: np.ndarray) -> float:
    return math.degrees(float(rotation_angle(Ra.T @ Rb)))


# --- the four changes -------------------------------------------------------------------------

def test_tracker_moved_2_mm_along_base_x_moves_every_body_by_minus_2_mm_in_tracker_x():
    before, after = quiet_tms_rig(), quiet_tms_rig()
    after.apply_change("tracker", mm=[2, 0, 0])
    for body in ("marker", "probe"):
        for b, a in zip(_seen(before, body), _seen(after, body), strict=True):
            # base x is the tracker's x: the body is 2 mm nearer in −x, turned not at all
            np.testing.assert_allclose(a[:3, 3] - b[:3, 3], [-2.0, 0.0, 0.0], atol=1e-9)
            np.testing.assert_allclose(a[:3, :3], b[:3, :3], atol=1e-12)
    np.testing.assert_allclose(after.truth.Z[:3, 3] - T.Z[:3, 3], [2.0, 0.0, 0.0], atol=1e-12)


def test_tracker_moved_along_base_y_is_seen_along_minus_tracker_z():
    rig = quiet_tms_rig()
    b = _seen(rig, "marker")
    rig.apply_change("tracker", mm=[0, 3, 0])
    for old, new in zip(b, _seen(rig, "marker"), strict=True):
        np.testing.assert_allclose(new[:3, 3] - old[:3, 3], [0.0, 0.0, 3.0], atol=1e-9)


def test_tracker_turned_keeps_its_origin_and_turns_by_the_angle_given():
    t = changed(T, "tracker", deg=[0, 0, 90])
    np.testing.assert_array_equal(t.Z[:3, 3], T.Z[:3, 3])          # turned about its origin
    np.testing.assert_allclose(t.Z[:3, :3], rot_z(math.pi / 2) @ T.Z[:3, :3], atol=1e-12)
    assert _angle_deg(T.Z[:3, :3], t.Z[:3, :3]) == pytest.approx(90.0)
    np.testing.assert_array_equal(t.X, T.X)
    np.testing.assert_array_equal(t.Y, T.Y)
    # every body keeps its distance from the tracker's origin
    rig, moved = quiet_tms_rig(), SimRig(t, noise=Noise.none(), start=TMS_RIG_P0)
    for b, a in zip(_seen(rig, "probe"), _seen(moved, "probe"), strict=True):
        assert np.linalg.norm(a[:3, 3]) == pytest.approx(np.linalg.norm(b[:3, 3]), abs=1e-9)


def test_tracker_change_angle_and_displacement_are_the_norms_given():
    mm, deg = np.array([2.0, -1.0, 0.5]), np.array([0.3, 0.0, 0.4])
    t = changed(T, "tracker", mm, deg)
    assert np.linalg.norm(t.Z[:3, 3] - T.Z[:3, 3]) == pytest.approx(np.linalg.norm(mm))
    assert _angle_deg(T.Z[:3, :3], t.Z[:3, :3]) == pytest.approx(0.5)   # ‖(0.3, 0, 0.4)‖


def test_marker_moved_on_the_coil_in_its_own_frame():
    t = changed(T, "marker", mm=[0.5, 0, 0])
    # X' = X·T([0.5, 0, 0]): the marker's origin moves 0.5 mm along the marker's own x axis
    np.testing.assert_allclose(t.X[:3, 3], T.X[:3, 3] + 0.5 * T.X[:3, 0], atol=1e-12)
    np.testing.assert_array_equal(t.X[:3, :3], T.X[:3, :3])
    np.testing.assert_array_equal(t.Y, T.Y)
    np.testing.assert_array_equal(t.Z, T.Z)
    rig, moved = quiet_tms_rig(), SimRig(t, noise=Noise.none(), start=TMS_RIG_P0)
    for b, a in zip(_seen(rig, "marker"), _seen(moved, "marker"), strict=True):
        np.testing.assert_allclose(a[:3, 3], b[:3, 3] + 0.5 * b[:3, 0], atol=1e-9)
    for b, a in zip(_seen(rig, "probe"), _seen(moved, "probe"), strict=True):
        np.testing.assert_array_equal(a, b)


def test_marker_turned_keeps_its_origin():
    t = changed(T, "marker", deg=[0, 0, 30])
    np.testing.assert_array_equal(t.X[:3, 3], T.X[:3, 3])
    np.testing.assert_allclose(t.X[:3, :3], T.X[:3, :3] @ rot_z(math.radians(30)), atol=1e-12)


def test_coil_centre_moved_in_its_own_frame_and_turned_about_itself():
    t = changed(T, "coil_centre", mm=[0, 0, 1.0])
    # Y's rotation is Rz(−20°), which keeps z: the centre moves 1 mm along the flange's z
    np.testing.assert_allclose(t.Y[:3, 3], [3.0, 5.0, 111.0], atol=1e-12)
    np.testing.assert_array_equal(t.X, T.X)
    turned = changed(T, "coil_centre", deg=[0, 0, 20])
    np.testing.assert_array_equal(turned.Y[:3, 3], T.Y[:3, 3])
    np.testing.assert_allclose(turned.Y[:3, :3], np.eye(3), atol=1e-12)   # Rz(−20°)·Rz(20°)


def test_coil_turned_about_its_centre_carries_the_marker_hand_worked():
    t = changed(T, "coil", deg=[0, 0, 90])
    # the centre stays; the marker's origin turns about it: t_X − t_Y = [9, −13, −50],
    # Rz(90°)·[9, −13, −50] = [13, 9, −50], + t_Y = [16, 14, 60]
    np.testing.assert_allclose(t.Y[:3, 3], [3.0, 5.0, 110.0], atol=1e-12)
    np.testing.assert_allclose(t.X[:3, 3], [16.0, 14.0, 60.0], atol=1e-12)
    np.testing.assert_allclose(t.X[:3, :3], rot_z(math.pi / 2) @ T.X[:3, :3], atol=1e-12)
    np.testing.assert_allclose(t.Y[:3, :3], rot_z(math.pi / 2) @ T.Y[:3, :3], atol=1e-12)


@pytest.mark.parametrize("mm, deg", [([0, 0.3, 0], [0.2, 0, 0]), ([1.0, -2.0, 0.5], [0, 0, 0]),
                                     ([0, 0, 0], [3.0, -4.0, 0.0]), ([5, 5, 5], [10, 20, 30])])
def test_coil_moves_its_centre_by_mm_and_the_marker_rigidly_with_it(mm, deg):
    t = changed(T, "coil", mm, deg)
    assert np.linalg.norm(t.Y[:3, 3] - T.Y[:3, 3]) == pytest.approx(np.linalg.norm(mm),
                                                                     abs=1e-12)
    np.testing.assert_allclose(t.Y[:3, 3], T.Y[:3, 3] + mm, atol=1e-12)
    # marker and coil moved together: the marker as seen from the coil is unchanged
    np.testing.assert_allclose(invert(t.Y) @ t.X, invert(T.Y) @ T.X, atol=1e-12)
    # both turned by the angle given (the change rotates flange-frame vectors)
    for a, b in ((T.X, t.X), (T.Y, t.Y)):
        assert _angle_deg(a[:3, :3], b[:3, :3]) == pytest.approx(np.linalg.norm(deg),
                                                                 abs=1e-9)
    np.testing.assert_array_equal(t.Z, T.Z)


def test_coil_on_a_marker_only_rig_turns_about_the_marker_origin():
    t0 = Truth(X=T.X, Z=T.Z)
    t = changed(t0, "coil", mm=[1, 2, 2], deg=[0, 0, 45])
    np.testing.assert_allclose(t.X[:3, 3], T.X[:3, 3] + [1, 2, 2], atol=1e-12)
    np.testing.assert_allclose(t.X[:3, :3], rot_z(math.pi / 4) @ T.X[:3, :3], atol=1e-12)
    assert t.Y is None
    with pytest.raises(ValueError, match="no probe"):
        changed(t0, "coil_centre", mm=[1, 0, 0])


def test_zero_change_is_the_identity_and_the_arm_is_kept():
    for move in ("tracker", "marker", "coil", "coil_centre"):
        t = changed(T, move)
        for a, b in ((t.X, T.X), (t.Y, T.Y), (t.Z, T.Z)):
            np.testing.assert_allclose(a, b, atol=1e-12)
    marker = object()
    assert changed(Truth(X=T.X, Z=T.Z, arm=marker), "tracker", [1, 0, 0]).arm is marker


@pytest.mark.parametrize("args, match", [(("camera", [1, 0, 0]), "move"),
                                         (("tracker", [1, 0]), "mm"),
                                         (("tracker", [0, 0, 0], [0, math.nan, 0]), "deg"),
                                         (("marker", [math.inf, 0, 0]), "mm")])
def test_bad_change_is_a_value_error(args, match):
    with pytest.raises(ValueError, match=match):
        changed(T, *args)
    with pytest.raises(ValueError, match=match):
        Change(*args)


def test_several_changes_apply_in_the_order_tracker_marker_coil_coil_centre():
    cs = [Change("coil_centre", (1.0, 0, 0)), Change("coil", (0, 0, 0), (0, 0, 90)),
          Change("tracker", (2, 0, 0))]
    t = apply_changes(T, cs)
    by_hand = changed(changed(changed(T, "tracker", [2, 0, 0]), "coil", deg=[0, 0, 90]),
                      "coil_centre", [1.0, 0, 0])
    for a, b in ((t.X, by_hand.X), (t.Y, by_hand.Y), (t.Z, by_hand.Z)):
        np.testing.assert_array_equal(a, b)
    # coil first: the centre is turned by Rz(90°) about itself, then moved 1 mm along its
    # own (turned) x axis: t_Y + Rz(90°)·R_Y·[1, 0, 0]
    np.testing.assert_allclose(t.Y[:3, 3], T.Y[:3, 3] + rot_z(math.pi / 2) @ T.Y[:3, 0],
                               atol=1e-12)
    # the list's order (centre first, then the coil about the moved centre) differs
    other = changed(changed(T, "coil_centre", [1.0, 0, 0]), "coil", deg=[0, 0, 90])
    np.testing.assert_allclose(other.Y[:3, 3], T.Y[:3, 3] + T.Y[:3, 0], atol=1e-12)
    with pytest.raises(ValueError, match="more than once"):
        apply_changes(T, [Change("marker"), Change("marker", (1, 0, 0))])


# --- the rig: a change now, events on its clock ------------------------------------------------

class FakeTime:
    """A clock the test sets by hand (seconds)."""

    def __init__(self, t: float = 100.0) -> None:
        self.t = t

    def __call__(self) -> float:
        return self.t


def test_apply_change_keeps_the_cached_tracker_from_base_in_step():
    rig = quiet_tms_rig()
    rig.move_flange(POSES[1])
    new = rig.apply_change("tracker", [2, 0, 0], [0, 0, 0.5])
    assert new is rig.truth
    np.testing.assert_allclose(rig.true_body("marker"),
                               invert(new.Z) @ POSES[1] @ new.X, atol=1e-9)
    np.testing.assert_array_equal(rig.reported_flange(), POSES[1])   # the robot sees nothing
    with pytest.raises(ValueError):
        rig.apply_change("camera", [1, 0, 0])
    assert rig.truth is new                                          # nothing changed


def test_events_fire_once_in_time_order_at_the_first_read_at_or_after_their_time():
    clock = FakeTime(100.0)
    late = Event(2.0, Change("marker", (0.5, 0, 0)))
    early = Event(1.0, Change("tracker", (2, 0, 0)))
    rig = quiet_tms_rig(time_s=clock, events=[late, early])   # any order given
    start = rig.true_body("marker")
    clock.t = 100.999
    np.testing.assert_array_equal(rig.true_body("marker"), start)
    assert rig.fired == [] and rig.pending == [early, late]
    clock.t = 101.0                                           # exactly at: fires
    np.testing.assert_allclose(rig.true_body("marker")[:3, 3] - start[:3, 3], [-2, 0, 0],
                               atol=1e-9)
    assert rig.fired == [(early, 1.0)] and rig.pending == [late]
    clock.t = 150.0                                           # long after: fires once
    rig.true_flange()
    rig.true_flange()
    assert rig.fired == [(early, 1.0), (late, 50.0)] and rig.pending == []
    want = changed(changed(T, "tracker", [2, 0, 0]), "marker", [0.5, 0, 0])
    np.testing.assert_array_equal(rig.truth.X, want.X)
    np.testing.assert_array_equal(rig.truth.Z, want.Z)


def test_events_due_together_apply_in_time_order_and_observe_sees_them():
    clock = FakeTime(0.0)
    rig = quiet_tms_rig(time_s=clock, events=[Event(3.0, Change("coil_centre", (0, 0, 1.0))),
                                              Event(2.0, Change("coil", (0, 0, 0), (0, 0, 90)))])
    clock.t = 5.0
    rig.observe("probe")
    assert [e.at_s for e, _ in rig.fired] == [2.0, 3.0]
    want = changed(changed(T, "coil", deg=[0, 0, 90]), "coil_centre", [0, 0, 1.0])
    np.testing.assert_array_equal(rig.truth.Y, want.Y)


def test_use_clock_restarts_the_events_time():
    rig = quiet_tms_rig(events=[Event(0.5, Change("tracker", (1, 0, 0)))])  # monotonic
    clock = FakeTime(7.0)
    rig.use_clock(clock)
    clock.t = 7.4
    rig.true_body("marker")
    assert rig.fired == [] and rig.elapsed() == pytest.approx(0.4)
    clock.t = 7.5
    rig.true_body("marker")
    assert len(rig.fired) == 1


def test_an_event_fires_at_the_polaris_fast_clock_frame_of_its_time():
    rate = 60.0
    rig = quiet_tms_rig(events=[Event(30 / rate, Change("tracker", (2, 0, 0)))])
    frames = FrameSource(rig, FAST, rate, None, PolarisFaults(), np.random.default_rng(0), 0.1)
    rig.use_clock(frames.time_s)
    xs = [frames.records([(1, "marker")], 0)[0][0].translation_mm for _ in range(40)]
    rest = (invert(T.Z) @ TMS_RIG_P0 @ T.X)[:3, 3]
    # frame k (1-based) is read at k/60 s of the tracker's time: frames 1…29 before the
    # event, frame 30 (0.5 s) and on after it
    np.testing.assert_allclose(xs[:29], np.tile(rest, (29, 1)), atol=1e-6)
    np.testing.assert_allclose(xs[29:], np.tile(rest + [-2, 0, 0], (11, 1)), atol=1e-6)
    assert rig.fired[0][1] == 0.5


def test_changes_and_events_draw_nothing_from_the_rigs_rng():
    def draws(moved: bool) -> tuple[dict, list[np.ndarray]]:
        """The RNG's state after a run and the robot's positioning errors it drew."""
        clock = FakeTime(0.0)
        events = [Event(0.5, Change("tracker", (2, 0, 0), (0, 0, 0.5)))] if moved else []
        rig = SimRig(T, rng=np.random.default_rng(3), start=TMS_RIG_P0, time_s=clock,
                     events=events)
        errors = []
        for i, A in enumerate(POSES):
            clock.t = float(i)
            rig.move_flange(A)
            errors.append(invert(A) @ rig.flange)
            rig.observe("marker", 5)
            if moved and i == 1:
                rig.apply_change("coil", (1, 0, 0), (0, 1, 0))
        assert len(rig.fired) == (1 if moved else 0)
        return rig.rng.bit_generator.state, errors
    plain_state, plain_errors = draws(False)
    state, errors = draws(True)
    assert state == plain_state
    for a, b in zip(errors, plain_errors, strict=True):
        np.testing.assert_array_equal(a, b)


# --- the config keys -------------------------------------------------------------------------

CHANGES = {"tracker": {"mm": [2, 0, 0], "deg": [0, 0, 0.5]},
           "marker": {"mm": [0.5, 0, 0]},
           "coil": {"mm": [0, 0.3, 0], "deg": [0.2, 0, 0]},
           "coil_centre": {"deg": [0, 0, 1.0]}}


def test_mock_changes_give_the_changed_truth_and_the_same_start_and_draws(mock_config):
    plain = build_sim_rig(load_config(mock_config("mock-ur-polaris.yaml")))
    rig = build_sim_rig(load_config(mock_config("mock-ur-polaris.yaml",
                                                mock={"changes": CHANGES})))
    want = apply_changes(T, [Change(k, tuple(v.get("mm", (0, 0, 0))),
                                    tuple(v.get("deg", (0, 0, 0)))) for k, v in CHANGES.items()])
    for a, b in ((rig.truth.X, want.X), (rig.truth.Y, want.Y), (rig.truth.Z, want.Z)):
        np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(rig.flange, plain.flange)     # the robot starts alike
    assert rig.rng.bit_generator.state == plain.rng.bit_generator.state
    assert rig.pending == [] and plain.pending == []
    np.testing.assert_array_equal(plain.truth.Z, T.Z)


def test_random_truth_changes_start_from_the_unchanged_truths_start(mock_config):
    def rig(**mock):
        return build_sim_rig(load_config(mock_config("mock-ur-polaris.yaml",
                                                     mock={"truth": "random", **mock})))
    plain, moved = rig(), rig(changes={"tracker": {"mm": [0, 0, 5]}})
    np.testing.assert_array_equal(moved.flange, facing_start(plain.truth))
    np.testing.assert_allclose(moved.truth.Z[:3, 3] - plain.truth.Z[:3, 3], [0, 0, 5],
                               atol=1e-9)
    np.testing.assert_array_equal(moved.truth.X, plain.truth.X)
    assert moved.rng.bit_generator.state == plain.rng.bit_generator.state


def test_mock_events_are_scheduled(mock_config):
    events = [{"at_s": 20, "move": "tracker", "mm": [2, 0, 0], "deg": [0, 0, 0.5]},
              {"at_s": 5, "move": "coil"}]
    rig = build_sim_rig(load_config(mock_config("mock-ur-polaris.yaml",
                                                mock={"events": events})))
    assert rig.pending == [Event(5.0, Change("coil")),
                           Event(20.0, Change("tracker", (2, 0, 0), (0, 0, 0.5)))]
    np.testing.assert_array_equal(rig.truth.Z, T.Z)       # nothing moved yet


@pytest.mark.parametrize("mock, key, words", [
    ({"events": [{"at_s": 1, "move": "tracker"}, {"at_s": 2, "move": "camera"}]},
     "mock.events[1].move", "expected one of tracker, marker, coil, coil_centre"),
    ({"events": [{"move": "tracker"}]}, "mock.events[0].at_s", "missing"),
    ({"events": [{"at_s": -0.1, "move": "tracker"}]}, "mock.events[0].at_s", "0…1e+06"),
    ({"events": [{"at_s": 2e6, "move": "tracker"}]}, "mock.events[0].at_s", "0…1e+06"),
    ({"events": [{"at_s": 1, "move": "marker", "when": 3}]}, "mock.events[0].when",
     "unknown key"),
    ({"events": [{"at_s": 0, "move": "tracker"}] * 1001}, "mock.events", "at most 1000"),
    ({"events": {"at_s": 0}}, "mock.events", "expected a list"),
    ({"changes": {"camera": {"mm": [1, 0, 0]}}}, "mock.changes.camera", "unknown key"),
    ({"changes": {"tracker": {"mm": [1, 0]}}}, "mock.changes.tracker.mm", "3 finite"),
    ({"changes": {"tracker": {"mm": [1001, 0, 0]}}}, "mock.changes.tracker.mm", "±1000"),
    ({"changes": {"marker": {"deg": [0, 181, 0]}}}, "mock.changes.marker.deg", "±180"),
    ({"changes": {"marker": {"deg": [150, 150, 0]}}}, "mock.changes.marker.deg",
     "rotation angle"),
    ({"changes": {"coil": {"mm": [0, "1", 0]}}}, "mock.changes.coil.mm", "finite numbers"),
    ({"changes": {"coil": {"turn": [0, 0, 0]}}}, "mock.changes.coil.turn", "unknown key"),
    ({"changes": {"coil": [0, 0, 1]}}, "mock.changes.coil", "expected a mapping"),
    ({"changes": [1, 2]}, "mock.changes", "expected a mapping"),
])
def test_bad_changes_and_events_are_config_errors_naming_the_key(mock_config, mock, key,
                                                                 words):
    path = mock_config("mock-ur-polaris.yaml", mock=mock)
    with pytest.raises(ConfigError) as e:
        load_config(path)
    assert f"key '{key}'" in str(e.value) and words in str(e.value), str(e.value)
    assert path.name in str(e.value)


def test_coil_centre_change_on_a_rig_without_a_probe_names_the_key(mock_config):
    X = np.eye(4).tolist()
    Z = make_pose(np.eye(3), [0, 0, 1500]).tolist()
    tools = {"marker": str(TOOLS_DIR / "marker-8700340.rom")}
    for mock, key in (({"changes": {"coil_centre": {"mm": [1, 0, 0]}}},
                       "mock.changes.coil_centre"),
                      ({"events": [{"at_s": 1, "move": "tracker"},
                                   {"at_s": 0, "move": "coil_centre"}]}, "mock.events[1].move")):
        cfg = load_config(mock_config("mock-polaris.yaml", tracker={"tools": tools},
                                      mock={"truth": {"X": X, "Z": Z}, **mock}))
        with pytest.raises(ConfigError, match=rf"key '{re.escape(key)}': .*no probe"):
            build_sim_rig(cfg)
