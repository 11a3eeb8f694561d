"""A small fixed set of realistic bugs ("mutants") in the motion-safety code (issue 22: the
envelope over the whole motion) and in the code of the audit's other breaks (resume, stream,
escaping, units): each is applied to a fresh copy of the repository, and the
tests that guard that code must FAIL on it. A mutant that survives means a test is missing.

    .venv/bin/python benchmarks/mutation.py            # every mutant (about 5 minutes)
    .venv/bin/python benchmarks/mutation.py --list     # names only
    .venv/bin/python benchmarks/mutation.py --only sag-margin --only tcp-frame
    .venv/bin/python benchmarks/mutation.py --baseline # the unmutated copy must pass first

Exit status 0 when every mutant was killed (and, with --baseline, the copy passed), 1
otherwise, so CI can run it. The copy holds tmscal/, tests/, configs/ and pyproject.toml;
pytest runs in it with PYTHONPATH pointing there (checked: ``tmscal.__file__`` must be in the
copy), so the child processes the e2e tests start import the mutated code too. The working tree
is never edited, so an interrupted run leaves it as it was. ``tests/unit/test_safety_mutants.py``
runs a few of these mutants in the test suite through ``copy_tree``, ``apply``,
``imports_the_copy`` and ``pytest_in``.
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


@dataclass(frozen=True)
class Mutant:
    """``old`` (exactly once in ``path``) replaced by ``new``; ``tests``: the pytest node ids
    that must fail."""

    name: str
    what: str
    path: str
    old: str
    new: str
    tests: tuple[str, ...]


PM = "tests/unit/test_path_math.py::"
PL = "tests/unit/test_path_laws.py::"
E2E = "tests/e2e/test_path_safety.py::"

MUTANTS = [
    Mutant("rotation-peak", "wrong inequality: a rotation peak inside the move is never looked at",
           "tmscal/safety/paths.py", "if 0.0 < u < geo.theta:", "if 0.0 < u > geo.theta:",
           (PM + "test_the_rotation_from_p0_can_peak_mid_path",)),
    Mutant("sag-margin", "the chord-sag margin between samples dropped",
           "tmscal/safety/paths.py",
           "        margin = weight[None] * ((fb - fa) ** 2)[:, None]\n        bad =",
           "        margin = 0.0 * weight[None]\n        bad =",
           (PM + "test_a_wall_between_two_samples_is_found_by_the_sag_margin",)),
    Mutant("tcp-frame", "the UR driver declares the flange, not its TCP, as what moveL moves",
           "tmscal/drivers/ur/robot.py", "LinearPath(self.flange_from_tcp)", "LinearPath()",
           (E2E + "test_a_tcp_offset_makes_the_flange_swing_round_the_tcp",)),
    Mutant("speed-times-r", "×r dropped from the tool point's speed bound",
           "tmscal/safety/laws.py", "    way = d + theta * rho\n    if D <= 0:",
           "    way = d + theta\n    if D <= 0:",
           (PL + "test_the_audits_coil_speed_before_and_after",)),
    Mutant("inversion", "dropped inversion: the flange from the controller's frame taken as "
           "the frame from the flange", "tmscal/safety/paths.py",
           "A[:3, :3].copy(), theta, n,\n                           phi, invert(phi))",
           "A[:3, :3].copy(), theta, n,\n                           phi, phi)",
           (PM + "test_a_controller_that_moves_the_tcp_swings_the_flange_instead",)),
    Mutant("deg-for-rad", "unit slip: the rotation timed in degrees where radians are meant",
           "tmscal/safety/laws.py",
           "    D = max(d, law.rotation_mm_per_rad * theta)\n    way",
           "    D = max(d, law.rotation_mm_per_rad * math.degrees(theta))\n    way",
           (PL + "test_a_ur_turn_on_the_spot_is_timed_by_its_rotation",)),
    Mutant("split-condition", "wrong inequality: the split route replaces the straight path "
           "when that one is fine, never when it leaves", "tmscal/safety/route.py",
           "    if straight is not None:", "    if straight is None:",
           (PM + "test_the_split_route_goes_through_p0_and_stays_inside",
            E2E + "test_the_audits_127_degree_turn_leaves_the_box_on_a_straight_movel_but_"
            "not_through_tmscal")),
    Mutant("denso-accel", "wrong inequality: the DENSO driver never sends a lower ACCEL",
           "tmscal/drivers/denso/robot.py", "if accel_mm_s2 < full:", "if accel_mm_s2 > full:",
           (E2E + "test_denso_lowers_the_acceleration_of_a_turning_move_for_the_coil",)),
    Mutant("box-wall-sign", "wrong sign: the box's upper walls checked the wrong way round",
           "tmscal/safety/paths.py", "g = np.stack([lo - pts, pts - hi], axis=-1)",
           "g = np.stack([lo - pts, hi - pts], axis=-1)",
           (PM + "test_the_audit_sweep_leaves_the_box_mid_path_although_both_ends_are_inside",
            PM + "test_a_controller_that_moves_the_tcp_swings_the_flange_instead")),
    # beyond the motion code: the audit's other breaks (issue 22, item 4)
    Mutant("resume-after-max", "a resumed plan run starts after the highest pose recorded: a "
           "damaged middle line's pose is never measured again", "tmscal/acquisition/strategy.py",
           "        self._done = session.indices()\n        self._next = 0",
           "        self._done = session.indices()\n        self._next = max(self._done, "
           "default=-1) + 1",
           ("tests/e2e/test_acquire.py::test_resume_reacquires_a_damaged_middle_line",)),
    Mutant("stream-raw-z", "dropped correction: the streamed coil pose is Z · C, not the "
           "placement rule (C undistorted)", "tmscal/stream.py",
           "        return np.asarray(cal.exported()[\"Z\"], dtype=float) @ targets[0]",
           "        return np.asarray(cal.exported()[\"Z\"], dtype=float) @ C",
           ("tests/e2e/test_stream.py::test_coil_to_robot_base_follows_the_placement_rule_"
            "under_a_tracker_scale",)),
    Mutant("html-escape", "removed escape: the report's text is made visible but not "
           "HTML-escaped", "tmscal/escape.py",
           "    return html.escape(visible(s, newlines=newlines), quote=True)",
           "    return visible(s, newlines=newlines)",
           ("tests/unit/test_report_html.py::test_session_text_is_escaped",)),
    Mutant("units-speed", "unit slip: a speed in m/s (0.05) accepted as mm/s",
           "tmscal/config/safety.py", "MIN_MOTION = 1.0", "MIN_MOTION = 0.01",
           ("tests/unit/test_config_safety.py::test_values_in_metres_are_refused_in_one_short_"
            "line[speed]",)),
]


def copy_tree(dest: Path | None = None) -> Path:
    """A fresh copy of what the tests need (tmscal/, tests/, configs/, pyproject.toml) in
    ``dest`` (an empty or missing directory), by default a new temporary directory; returns
    it."""
    d = Path(tempfile.mkdtemp(prefix="tmscal-mutant-")) if dest is None else dest
    ignore = shutil.ignore_patterns("__pycache__", "*.pyc", ".hypothesis")
    for name in ("tmscal", "tests", "configs"):
        shutil.copytree(ROOT / name, d / name, ignore=ignore, symlinks=True)
    shutil.copy2(ROOT / "pyproject.toml", d / "pyproject.toml")
    return d


def apply(m: Mutant, copy: Path) -> bool:
    """Apply ``m`` to the copy at ``copy``; False (nothing changed) unless ``m.old`` occurs
    exactly once in its file."""
    f = copy / m.path
    text = f.read_text()
    if text.count(m.old) != 1:
        return False
    f.write_text(text.replace(m.old, m.new))
    return True


def _env(copy: Path) -> dict[str, str]:
    return {**os.environ, "PYTHONPATH": str(copy), "PYTHONDONTWRITEBYTECODE": "1"}


def imports_the_copy(copy: Path) -> bool:
    """True when Python started in ``copy`` (as ``pytest_in`` starts it) imports the copy's
    tmscal, not the installed one."""
    out = subprocess.run([sys.executable, "-c", "import tmscal; print(tmscal.__file__)"],
                         cwd=copy, env=_env(copy), capture_output=True, text=True)
    return out.returncode == 0 and out.stdout.strip().startswith(str(copy))


def pytest_in(copy: Path, tests: tuple[str, ...], *args: str,
              timeout_s: float = 900.0) -> subprocess.CompletedProcess[str]:
    """``python -m pytest -q -p no:cacheprovider ARGS TESTS`` run in ``copy`` on the copy's
    code; the finished process (stdout and stderr as text). ``timeout_s`` is a hang guard."""
    return subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider",
                           *args, *tests], cwd=copy, env=_env(copy), capture_output=True,
                          text=True, timeout=timeout_s, stdin=subprocess.DEVNULL)


def _pytest(copy: Path, tests: tuple[str, ...]) -> tuple[int, str]:
    proc = pytest_in(copy, tests, "-x")
    tail = (proc.stdout.strip().splitlines() or ["(no output)"])[-1]
    return proc.returncode, tail


def run(mutants: list[Mutant], baseline: bool) -> bool:
    ok = True
    if baseline:
        copy = copy_tree()
        try:
            if not imports_the_copy(copy):
                print("baseline: the copy's tmscal is not the one imported")
                return False
            tests = tuple(dict.fromkeys(t for m in mutants for t in m.tests))
            code, tail = _pytest(copy, tests)
            print(f"{'baseline':16s} {'passes' if code == 0 else 'FAILS'}  ({tail})")
            ok = code == 0
        finally:
            shutil.rmtree(copy, ignore_errors=True)
    for m in mutants:
        copy = copy_tree()
        try:
            if not apply(m, copy):
                print(f"{m.name:16s} NOT APPLIED: the text to replace occurs "
                      f"{(copy / m.path).read_text().count(m.old)} times in {m.path}")
                ok = False
                continue
            if not imports_the_copy(copy):
                print(f"{m.name:16s} NOT RUN: the copy's tmscal is not the one imported")
                ok = False
                continue
            t0 = time.monotonic()
            code, tail = _pytest(copy, m.tests)
            killed = code != 0
            ok &= killed
            print(f"{m.name:16s} {'killed' if killed else 'SURVIVED'} in "
                  f"{time.monotonic() - t0:5.1f} s  {m.what}  ({tail})")
        finally:
            shutil.rmtree(copy, ignore_errors=True)
    return ok


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--only", action="append", metavar="NAME", help="run only this mutant")
    ap.add_argument("--list", action="store_true", help="list the mutants and exit")
    ap.add_argument("--baseline", action="store_true",
                    help="first check that the unmutated copy passes the tests")
    args = ap.parse_args()
    if args.list:
        for m in MUTANTS:
            print(f"{m.name:16s} {m.path}: {m.what}")
        return 0
    chosen = [m for m in MUTANTS if not args.only or m.name in args.only]
    unknown = set(args.only or []) - {m.name for m in MUTANTS}
    if unknown:
        print(f"unknown mutant(s): {', '.join(sorted(unknown))}", file=sys.stderr)
        return 2
    return 0 if run(chosen, args.baseline) else 1


if __name__ == "__main__":
    sys.exit(main())
