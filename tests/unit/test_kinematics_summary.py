"""``tmscal solve S --kinematics estimate`` opens with a short summary (docs/kinematics.md,
"Solving", the summary): the arm and its level, the held-out e_t before and after, the coil
placement predicted and against the truth before and after, the three deviations largest in
tolerance units; the combinations of deviations are then counted, listed only under ``-v``,
and always carried by ``--json``.

The session is a simulated VS-060 whose geometry has hidden errors (every parameter, ±2 mm /
±1°; ``tests/unit/test_kinematics_use.py``), its joints recorded. The summary's numbers are
checked against the ``--json`` output of the same solve, and the three deviations it names
are worked out here from the JSON's full table of deviations and the prior's tolerances.
Lengths in mm, angles in degrees (the JSON's deviations: rad and mm).
"""

from __future__ import annotations

import json
import math
import re

import pytest
from click.testing import CliRunner

from tests.unit.test_kinematics_use import _session as arm_session
from tmscal.cli import main

#: the summary's longest (lines), and any of its lines' (characters)
MAX_SUMMARY_LINES = 14
MAX_WIDTH = 100


def _solve(*args: str) -> str:
    r = CliRunner().invoke(main, ["solve", *args])
    assert r.exit_code == 0, r.output
    return r.output


@pytest.fixture(scope="module")
def outputs(tmp_path_factory):
    """(the --json object, the plain output, the -v output) of one session's solve."""
    path = tmp_path_factory.mktemp("kinsummary") / "vs060.jsonl"
    arm_session(path, n=24)
    base = [str(path), "--kinematics", "estimate"]
    return json.loads(_solve(*base, "--json")), _solve(*base), _solve(*base, "-v")


def _summary(text: str) -> list[str]:
    """The lines before the first blank one."""
    lines = text.splitlines()
    return lines[:lines.index("")] if "" in lines else lines


def _flat(text: str) -> str:
    return " ".join(text.split())


def _is_length(name: str) -> bool:
    """Whether a deviation is a length (mm): DH d and a, base and flange x, y, z; else an
    angle (rad): θ0, α, β, roll, pitch, yaw."""
    return name.split("_")[0] in ("d", "a") or name.endswith(("_x", "_y", "_z"))


def test_the_summary_comes_first_and_is_short(outputs) -> None:
    _, plain, verbose = outputs
    summary = _summary(plain)
    assert summary[0].startswith("summary:")
    assert len(summary) <= MAX_SUMMARY_LINES
    assert all(len(ln) <= MAX_WIDTH for ln in summary)
    # before the error table and the arm's details
    assert plain.index("calibration solved on") > plain.index(summary[-1])
    assert _summary(verbose) == summary  # -v changes what follows, not the summary


def test_the_summary_carries_the_jsons_numbers(outputs) -> None:
    """Level, e_t before (the controller's poses) and after (the estimated arm), the
    prediction, the coil placement against the truth before and after."""
    j, plain, _ = outputs
    s = _flat("\n".join(_summary(plain)))
    assert f"level {j['arm']['level']}" in s
    m = re.search(r"held-out total e_t \(.*?\): ([0-9.]+) mm on the controller's poses → "
                  r"([0-9.]+) mm with the estimated arm", s)
    assert m, s
    assert float(m.group(1)) == pytest.approx(j["nominal"]["errors"]["e_t_mm"], abs=5e-5)
    assert float(m.group(2)) == pytest.approx(j["errors"]["e_t_mm"], abs=5e-5)
    m = re.search(r"coil placement predicted ([0-9.]+) mm at ([0-9.]+) %", s)
    assert m, s
    assert float(m.group(1)) == pytest.approx(j["prediction"]["coil_placement_mm"], rel=6e-3)
    assert float(m.group(2)) == pytest.approx(j["prediction"]["confidence"] * 100)
    m = re.search(r"against the truth \(simulated\): ([0-9.]+) mm before → ([0-9.]+) mm after", s)
    assert m, s
    before = j["nominal"]["truth"]["coil_placement_mm"]
    after = j["truth"]["coil_placement_mm"]
    assert float(m.group(1)) == pytest.approx(before, abs=5e-5)
    assert float(m.group(2)) == pytest.approx(after, abs=5e-5)
    assert after < before  # the arm's millimetres are what the estimate takes out


def test_the_three_deviations_named_are_the_largest_of_the_jsons_table(outputs) -> None:
    """|δ| / τ over every deviation the JSON carries (τ: the prior's length tolerance for
    lengths, its angle tolerance for angles), the three largest in order, each printed with
    its estimate and posterior σ (mm or degrees) and its size in τ."""
    j, plain, _ = outputs
    arm = j["arm"]
    dev, sd, tol = arm["deviations"], arm["sd"], arm["tolerances"]
    assert len(dev) > 3 and set(sd) == set(dev)

    def size(n: str) -> float:
        return abs(dev[n]) / (tol["length_mm"] if _is_length(n)
                              else math.radians(tol["angle_deg"]))

    top = sorted(dev, key=size, reverse=True)[:3]
    s = _flat("\n".join(_summary(plain)))
    _, _, listed = s.partition("largest deviations")
    shown = re.findall(r"(\w+) ([-+][0-9.e+-]+) ± ([0-9.e+-]+)(°| mm) \(([0-9.e+-]+) τ\)",
                       listed)
    assert [n for n, *_ in shown] == top, listed
    for name, value, sigma, unit, in_tau in shown:
        scale = 1.0 if _is_length(name) else math.degrees(1.0)
        assert unit == (" mm" if _is_length(name) else "°")
        assert float(value) == pytest.approx(dev[name] * scale, rel=6e-3)
        assert float(sigma) == pytest.approx(sd[name] * scale, rel=6e-2)
        assert float(in_tau) == pytest.approx(size(name), rel=6e-2)


KINDS = ("identified", "weak", "unidentified")


def test_without_v_the_combinations_are_counted_not_listed(outputs) -> None:
    j, plain, _ = outputs
    arm = j["arm"]
    assert any(arm[k] for k in KINDS)
    flat = _flat(plain)
    lines = [ln.strip() for ln in plain.splitlines()]
    for kind in KINDS:
        combos = arm[kind]
        if combos:
            head = {"identified": "identified (", "weak": "weakly identified (",
                    "unidentified": "not identifiable"}[kind]
            assert [ln for ln in lines if ln.startswith(head)
                    and ln.endswith(f": {len(combos)}")], kind
        for c in combos:
            assert _flat(c["text"]) not in flat
    assert "-v lists each combination" in plain


def test_v_lists_every_combination_of_the_jsons_table(outputs) -> None:
    j, plain, verbose = outputs
    flat = _flat(verbose)
    combos = [c for k in KINDS for c in j["arm"][k]]
    assert combos
    for c in combos:
        assert _flat(c["text"]) in flat
    assert len(verbose.splitlines()) >= len(plain.splitlines()) + len(combos)
