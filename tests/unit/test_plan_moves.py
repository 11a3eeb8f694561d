"""The dry run looks at the way between a plan's poses, not only at the poses (issue 22, item 1;
docs/safety.md): a move whose straight path swings a coil point out of the box is reported as
split through P0, one that no route keeps inside is a refusal naming it, and a plan of short
moves has neither. The geometry (a 127° wrist turn by the x-min wall, like the audit's) is
checked by hand first."""

from __future__ import annotations

import numpy as np

from tmscal.acquisition.plan import check_plan_moves
from tmscal.geometry import make_pose, rot_z
from tmscal.safety import Envelope

DOWN = np.diag([1.0, -1.0, -1.0])     # flange z down
TOOL = [[0.0, 100.0, 100.0]]          # a coil point (flange frame, mm)
P0 = make_pose(DOWN, [500.0, 0.0, 400.0])
BOX_Y_Z = ((-200.0, 200.0), (100.0, 600.0))


def turned(x: float, deg: float) -> np.ndarray:
    return make_pose(DOWN @ rot_z(np.radians(deg)), [x, 0.0, 400.0])


def tool_x_min(x: float, deg: float) -> float:
    """By hand: the coil point's lowest x on the straight move (flange fixed at x, turning
    0 → deg about its own z): DOWN·Rz(θ)·[0, 100, 100] has x = −100 sin θ."""
    th = np.radians(np.linspace(0.0, deg, 20_001))
    return float((x - 100.0 * np.sin(th)).min())


def envelope(x_min: float) -> Envelope:
    return Envelope(center=P0, max_offset_mm=300.0, max_rotation_deg=170.0,
                    box_min_mm=(x_min, BOX_Y_Z[0][0], BOX_Y_Z[1][0]),
                    box_max_mm=(700.0, BOX_Y_Z[0][1], BOX_Y_Z[1][1]), tool_points_mm=TOOL)


def test_a_move_whose_straight_path_leaves_goes_through_p0():
    env = envelope(330.0)
    a, b = turned(420, 0), turned(420, 127)
    assert env.violations(a) == [] and env.violations(b) == []
    assert tool_x_min(420, 127) < 330.0 < tool_x_min(500, 127)   # out on the way; not at P0
    plan = np.array([a, b, turned(425, 125)])
    assert check_plan_moves(plan, env, P0) == ([1], [])


def test_a_move_that_no_route_keeps_inside_is_refused_naming_it():
    env = envelope(405.0)
    a, b = turned(490, 0), turned(490, 127)
    assert env.violations(a) == [] and env.violations(b) == []
    assert tool_x_min(490, 127) < 405.0 and tool_x_min(500, 127) < 405.0  # at P0 too
    split, refused = check_plan_moves(np.array([a, b]), env, P0)
    assert split == [] and len(refused) == 1
    assert refused[0].startswith("move to plan pose 1 (490.0, 0.0, 400.0) → (490.0, 0.0, "
                                 "400.0) mm refused"), refused[0]
    assert "x-min wall (405.0 mm)" in refused[0] and refused[0].endswith("Nothing was moved.")


def test_short_moves_are_neither_split_nor_refused():
    env = Envelope(center=P0, max_offset_mm=100.0, max_rotation_deg=20.0,
                   box_min_mm=(300.0, -200.0, 200.0), box_max_mm=(700.0, 200.0, 600.0),
                   tool_points_mm=[[0.0, 0.0, 150.0]])
    rng = np.random.default_rng(3)
    plan = []
    for _ in range(20):
        P = turned(500.0, rng.uniform(-15, 15))
        P[:3, 3] += rng.uniform(-50, 50, 3)
        plan.append(P)
    assert check_plan_moves(np.array(plan), env, P0) == ([], [])
