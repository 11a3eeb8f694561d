"""End to end: a joints plan (plan kind ``joints``, docs/kinematics.md) acquired on the mock
DENSO VS-060 with realistic arm errors through the b-CAP and Polaris protocols (the mocks in a
child process), stopped and resumed: every commanded pose inside the config's envelope, the
arm at the planned configurations (its reported pose the nominal kinematics of its reported
joints), nothing lost or duplicated; a resume refuses an edited plan."""

from __future__ import annotations

import json

import numpy as np
import pytest

from tmscal.acquisition.devices import envelope_for
from tmscal.acquisition.run import acquire
from tmscal.calib.kinematics import arm_by_name, base_from_flange
from tmscal.config import load_config
from tmscal.errors import SessionError
from tmscal.geometry import angle_between
from tmscal.mocks.launch import spawn_mock_rig
from tmscal.session import read_session

from ..rigs import SeenPoses, endpoints_kwargs

PLAN = {"kind": "joints", "poses": 10, "radius_mm": 200, "rotation_deg": 20, "seed": 5,
        "pool": 2000}


@pytest.mark.e2e
def test_joints_plan_acquired_inside_the_envelope_and_resumed(tmp_path, mock_config):
    cfg_path = mock_config("mock-denso-polaris-kin.yaml", robot={"port": 0}, plan=PLAN,
                           sampling={"samples": 5})
    cfg = load_config(cfg_path)
    out = tmp_path / "s.jsonl"
    with spawn_mock_rig(cfg_path, transport="tcp") as mp:
        kw = endpoints_kwargs(mp.endpoints)
        calls: list = []
        res = acquire(cfg, out, should_stop=lambda: len(calls) >= 4,
                      progress=SeenPoses(calls), **kw)
        assert res.stopped and res.recorded == 4
        res2 = acquire(cfg, out, resume=True, **kw)
        assert (res2.new_poses, res2.recorded, res2.skipped) == (6, 10, 0)
        assert not res2.stopped

        s = read_session(out)
        assert [p.index for p in s.poses] == list(range(10))
        plan = s.header["plan"]
        assert plan["kind"] == "joints" and plan["joints"]["arm"] == "vs060"
        p0 = np.array(plan["p0"])
        env = envelope_for(cfg, p0)
        nominal = arm_by_name("vs060")
        M = np.array(plan["joints"]["frame"])
        q0 = np.array(plan["joints"]["q0_rad"])
        q = np.array([p.joints_rad for p in s.poses])
        for p in s.poses:
            assert env.violations(p.commanded) == [], p.index
            assert np.linalg.norm(p.commanded[:3, 3] - p0[:3, 3]) <= 200 + 1e-9
            assert np.degrees(angle_between(p0, p.commanded)) <= 20 + 1e-9
            # the controller went to the commanded pose, and reports the nominal kinematics
            # of the joints it reports
            A = M @ base_from_flange(nominal, np.array(p.joints_rad))
            assert np.abs(A - p.A).max() < 1e-3, p.index
            assert np.linalg.norm(p.A[:3, 3] - p.commanded[:3, 3]) < 0.01, p.index
        # the joints within the plan's span of P0's, and spread over it
        assert np.degrees(np.abs(q - q0)).max() <= 30 + 0.01
        assert (np.degrees(q.max(0) - q.min(0)) > 12).all(), np.degrees(q.max(0) - q.min(0))

        # a header whose plan was edited (another q0) is refused before anything moves
        lines = out.read_text().splitlines()
        head = json.loads(lines[0])
        head["plan"]["joints"]["q0_rad"][0] += 0.05
        edited = tmp_path / "e.jsonl"
        edited.write_text("\n".join([json.dumps(head)] + lines[1:6]) + "\n")
        with pytest.raises(SessionError, match="q0_rad put the vs060 arm's flange"):
            acquire(cfg, edited, resume=True, **kw)
