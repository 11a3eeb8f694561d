"""End to end, on the DENSO and Polaris mocks (real sockets and ptys): a resumed run trusts
nothing in the session header that the config and the recorded poses do not confirm, and
refuses an arm that is not where the run stopped, in position or in orientation (plan and
adaptive runs alike); it keeps the header's sampling settings; and ``run.retries`` bounds the
reconnects for one fault, not for the whole run."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from tmscal.acquisition.adaptive_run import acquire_adaptive
from tmscal.acquisition.devices import make_robot
from tmscal.acquisition.run import acquire
from tmscal.config import load_config
from tmscal.errors import SessionError
from tmscal.geometry import angle_between, rot_z
from tmscal.mocks.launch import start_mock_rig
from tmscal.session import read_session

from ..rigs import SeenPoses, endpoints_kwargs, write_config


def _edit_header(path: Path, edit) -> None:
    lines = path.read_bytes().split(b"\n")
    h = json.loads(lines[0])
    edit(h)
    lines[0] = json.dumps(h).encode()
    path.write_bytes(b"\n".join(lines))


def _denso_cfg(tmp_path: Path, **changes) -> Path:
    changes.setdefault("robot", {"port": 0})
    changes.setdefault("plan", {"poses": 12})
    changes.setdefault("sampling", {"samples": 4})
    return write_config(tmp_path, "mock-denso-polaris.yaml", **changes)


@pytest.mark.e2e
@pytest.mark.parametrize("recorded", [0, 4])
def test_resume_refuses_a_header_whose_p0_was_moved(tmp_path, recorded):
    """P0 shifted by (+120, 0, +90) mm in the header: with poses recorded, the header's plan
    no longer reproduces their commanded poses; with none, the arm is not where a run around
    that P0 would have left it. Either way nothing moves."""
    cfg = load_config(_denso_cfg(tmp_path))
    out = tmp_path / "s.jsonl"
    with start_mock_rig(cfg, tracker_transport="pty") as mr:
        kw = endpoints_kwargs(mr.endpoints)
        done: list[int] = []
        res = acquire(cfg, out, should_stop=lambda: len(done) >= recorded,
                      progress=SeenPoses(done), **kw)
        assert res.stopped and res.recorded == recorded

        def shift(h):
            h["plan"]["p0"][0][3] += 120.0
            h["plan"]["p0"][2][3] += 90.0

        _edit_header(out, shift)
        moves = mr.devices[-1].stats["moves"]
        before = out.read_bytes()
        with pytest.raises(SessionError, match="header|P0"):
            acquire(cfg, out, resume=True, **kw)
        assert mr.devices[-1].stats["moves"] == moves
    assert out.read_bytes() == before


def _turned(P: np.ndarray, deg: float, lift_mm: float = 0.0) -> np.ndarray:
    """Pose ``P`` turned by ``deg`` about its own tool (z) axis, the flange where it is (or
    ``lift_mm`` higher: a DENSO MOVE L times only the translation, so a jog that turns the
    coil must also translate to be timed; docs/safety.md)."""
    T = np.array(P, dtype=float)
    T[:3, :3] = T[:3, :3] @ rot_z(np.radians(deg))
    T[2, 3] += lift_mm
    return T


#: a wide rotation limit: an arm turned 60° from where the run stopped is inside the envelope
WIDE = {"max_rotation_deg": 90}


@pytest.mark.e2e
@pytest.mark.parametrize("kind", ["plan", "adaptive"])
def test_resume_refuses_an_arm_turned_where_the_run_stopped(tmp_path, kind):
    """Issue 22, #3: the arm where the run stopped but turned 60° about its tool axis (inside
    a 90° envelope) was resumed from; the flange's orientation is now checked too, for every
    kind of run: refused naming the angles, nothing moved, the session unchanged. Turned
    back, the same session resumes."""
    cfg = load_config(_denso_cfg(tmp_path, safety=WIDE))
    run = acquire if kind == "plan" else acquire_adaptive
    out = tmp_path / "s.jsonl"
    with start_mock_rig(cfg, tracker_transport="pty") as mr:
        kw = endpoints_kwargs(mr.endpoints)
        done: list[int] = []
        run(cfg, out, should_stop=lambda: len(done) >= 2, progress=SeenPoses(done), **kw)
        last = max(read_session(out).poses, key=lambda p: p.index).commanded
        robot = make_robot(cfg, host=kw["robot_host"], port=kw["robot_port"])
        with robot:   # the config's box and caps; no P0, so no rotation limit: a jog
            np.testing.assert_allclose(robot.flange_pose(), last, atol=1e-3)
            robot.move_to(_turned(last, 60, lift_mm=3.0))
            here = robot.flange_pose()
        assert 59 < np.degrees(angle_between(last, here)) < 61
        moves, before = mr.devices[-1].stats["moves"], out.read_bytes()
        with pytest.raises(SessionError, match=r"° from the session's P0 .* and [2-9]\d\.\d° "
                                               r"from the path where the run stopped .*20°"):
            run(cfg, out, resume=True, **kw)
        assert mr.devices[-1].stats["moves"] == moves and out.read_bytes() == before
        with robot:
            robot.move_to(last)
        res = run(cfg, out, resume=True, should_stop=lambda: len(done) >= 3,
                  progress=SeenPoses(done), **kw)
    assert res.new_poses == 1 and len(read_session(out).poses) == 3


@pytest.mark.e2e
@pytest.mark.parametrize("kind", ["plan", "adaptive"])
def test_resume_refuses_a_header_whose_p0_was_turned(tmp_path, kind):
    """P0 turned 40° about its tool axis in the header of a session with no pose yet, inside
    a 90° envelope: the plan (the adaptive pool) around it is a different one, and the arm
    (at the real P0) is 40° from it. Refused on the orientation; nothing moves."""
    cfg = load_config(_denso_cfg(tmp_path, safety=WIDE))
    run = acquire if kind == "plan" else acquire_adaptive
    out = tmp_path / "s.jsonl"
    with start_mock_rig(cfg, tracker_transport="pty") as mr:
        kw = endpoints_kwargs(mr.endpoints)
        run(cfg, out, should_stop=lambda: True, **kw)  # header only
        _edit_header(out, lambda h: h["plan"].update(
            p0=_turned(np.array(h["plan"]["p0"]), 40).tolist()))
        before = out.read_bytes()
        with pytest.raises(SessionError, match=r"0\.0 mm and 40\.0° from the session's P0"):
            run(cfg, out, resume=True, **kw)
        assert mr.devices[-1].stats["moves"] == 0
    assert out.read_bytes() == before


@pytest.mark.e2e
def test_resume_refuses_another_robot_or_plan(tmp_path):
    cfg = load_config(_denso_cfg(tmp_path))
    out = tmp_path / "s.jsonl"
    with start_mock_rig(cfg, tracker_transport="pty") as mr:
        kw = endpoints_kwargs(mr.endpoints)
        acquire(cfg, out, should_stop=lambda: True, **kw)  # header only
        _edit_header(out, lambda h: h["devices"]["robot"].update(driver="ur"))
        with pytest.raises(SessionError, match="robot driver 'ur'.*'denso'"):
            acquire(cfg, out, resume=True, **kw)
        _edit_header(out, lambda h: h["devices"]["robot"].update(driver="denso"))
        other = load_config(_denso_cfg(tmp_path, plan={"poses": 12, "seed": 99}))
        with pytest.raises(SessionError, match=r"plan\.seed"):
            acquire(other, out, resume=True, **kw)
        assert mr.devices[-1].stats["moves"] == 0


@pytest.mark.e2e
def test_resume_keeps_the_sessions_sampling_settings(tmp_path):
    """A run started with --samples 3 resumes with 3 samples per pose although the config
    says 4, and says so; an explicit override on resume wins."""
    cfg = load_config(_denso_cfg(tmp_path, plan={"poses": 6}))
    out = tmp_path / "s.jsonl"
    with start_mock_rig(cfg, tracker_transport="pty") as mr:
        kw = endpoints_kwargs(mr.endpoints)
        done: list[int] = []
        acquire(cfg, out, samples=3, should_stop=lambda: len(done) >= 2,
                progress=SeenPoses(done), **kw)
        res = acquire(cfg, out, resume=True, should_stop=lambda: len(done) >= 4,
                      progress=SeenPoses(done), **kw)
        assert any("samples 3" in n and "config says 4" in n for n in res.notes), res.notes
        res = acquire(cfg, out, resume=True, samples=5, **kw)
        assert any("samples 5" in n for n in res.notes), res.notes
    s = read_session(out)
    assert s.header["sampling"]["samples"] == 3
    assert [p.samples["B"] for p in sorted(s.poses, key=lambda p: p.index)] == \
        [3, 3, 3, 3, 5, 5]


@pytest.mark.e2e
def test_retries_count_per_fault_not_per_run(tmp_path):
    """Isolated link drops, more of them than ``run.retries``, each recovered by one
    reconnect: the run completes (it stopped at the (retries+1)-th drop before)."""
    cfg = load_config(_denso_cfg(
        tmp_path, plan={"poses": 24}, run={"retries": 1, "reconnect_wait_s": 0.0},
        mock={"robot": {"faults": {"drop_rate": 0.02, "seed": 26}}}))
    out = tmp_path / "s.jsonl"
    with start_mock_rig(cfg, tracker_transport="pty") as mr:
        res = acquire(cfg, out, **endpoints_kwargs(mr.endpoints))
        dropped = mr.devices[-1].stats["dropped"]
    # every drop during the run is one recovered fault; a drop may also land on the last
    # request of close() (after the run), which is no fault of the run
    assert res.faults > cfg.run.retries, "the fault seed must give more drops than run.retries"
    assert dropped - 1 <= res.faults <= dropped and res.recorded == 24
    s = read_session(out)
    assert sorted(p.index for p in s.poses) == list(range(24))
    got = np.stack([p.commanded for p in sorted(s.poses, key=lambda p: p.index)])
    assert np.isfinite(got).all()
