"""``tmscal simulate``: write a simulated session (no devices)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import click
import numpy as np

from .app import FORCE_HELP, Finite, check_outputs, handle_errors, main
from .selfcal import ArmName


class _Triple(click.ParamType[tuple[float, float, float], Any]):
    """Three comma-separated finite numbers in [lo, hi] ('1.001,1,1'); with ``broadcast`` one
    number stands for all three."""

    name = "x[,y,z]"

    def __init__(self, lo: float, hi: float, broadcast: bool = False) -> None:
        self.lo, self.hi, self.broadcast = lo, hi, broadcast

    def convert(self, value: Any, param: Any, ctx: Any) -> tuple[float, float, float]:
        if isinstance(value, tuple):
            return value
        parts = [p.strip() for p in str(value).split(",")]
        if self.broadcast and len(parts) == 1:
            parts *= 3
        try:
            vals = [float(p) for p in parts]
        except ValueError:
            self.fail(f"{value!r}: expected numbers separated by commas", param, ctx)
        if len(vals) != 3:
            self.fail(f"{value!r}: expected {'one or ' if self.broadcast else ''}three "
                      "numbers", param, ctx)
        for v in vals:
            if not (np.isfinite(v) and self.lo <= v <= self.hi):
                self.fail(f"{value!r}: each number must be in {self.lo:g}…{self.hi:g}",
                          param, ctx)
        return (vals[0], vals[1], vals[2])


@main.command()
@click.option("-o", "--output", type=click.Path(dir_okay=False, path_type=Path), required=True,
              help="Session file to write (JSON Lines).")
@click.option("--poses", type=click.IntRange(1, 100000), default=500, show_default=True,
              help="Number of robot poses.")
@click.option("--plan", type=click.Choice(["eq14", "random"]), default="eq14",
              show_default=True,
              help="eq14: the experiment plan of Wang et al. 2018 (their Eq. 14: ±100 mm, "
                   "±10° around P0); random: fully random robot poses (their simulation).")
@click.option("--seed", type=click.IntRange(0), default=0, show_default=True,
              help="Random seed (≥ 0).")
@click.option("--samples", type=click.IntRange(1, 10000), default=1, show_default=True,
              help="Tracker observations averaged per pose.")
@click.option("--fiducial-sigma", type=Finite(0, 100), default=0.05, show_default=True,
              help="Tracker fiducial noise σ per coordinate, mm.")
@click.option("--robot-rot-sigma", type=Finite(0, 90), default=0.05, show_default=True,
              help="Robot rotation noise σ, degrees.")
@click.option("--robot-trans-sigma", type=Finite(0, 100), default=0.05,
              show_default=True, help="Robot translation noise σ per axis, mm.")
@click.option("--radius", type=Finite(0, 1e5), default=None,
              help="Translation range ±mm per axis (default 100 for eq14, 500 for random).")
@click.option("--rotation", type=Finite(0, 180), default=10.0, show_default=True,
              help="eq14 rotation range ±degrees per axis.")
@click.option("--tracker-scale", type=_Triple(0.5, 2.0, broadcast=True), default="1",
              show_default=True,
              help="Tracker distortion: scale of tracker-frame positions about the tracker "
                   "origin, one factor (e.g. 1.001 = +0.1 %) or three 'sx,sy,sz'.")
@click.option("--tracker-shear", type=_Triple(-0.5, 0.5), default="0,0,0", show_default=True,
              help="Tracker distortion: shear 'xy,xz,yz' (dimensionless), added above the "
                   "diagonal of the scale matrix (docs/methods.md).")
@click.option("--marker-only", is_flag=True, help="Simulate the marker only (no probe).")
@click.option("--arm", type=ArmName(), default=None,
              help="Move a serial arm, by its registered name (ur3…ur20, vs060, cobotta, fr3, "
                   "panda; docs/kinematics.md), placed as on the mock rig: the poses are "
                   "around the mock's start pose (flange at 500, 0, 400 mm, tool down), the "
                   "joints come from inverse kinematics on the arm's NOMINAL model (as its "
                   "controller computes them), A is the nominal forward kinematics of those "
                   "joints, B and C what the tracker sees of the TRUE arm (with the robot "
                   "noise, as without an arm). Every pose records its joints; the header's "
                   "truth carries the arm (nominal, true, mount). A pose out of reach is "
                   "re-drawn. With --plan random: the nominal flange of joint configurations "
                   "drawn within the joint limits (--radius does not apply).")
@click.option("--kinematic-errors", type=click.Choice(["none", "paper", "all", "realistic"]),
              default=None,
              help="With --arm: the arm's hidden errors (drawn from --seed). realistic "
                   "(default): every geometric parameter, N(0, σ) with σ 0.0004 × the arm's "
                   "reach on lengths (0.34 mm on a UR5e) and 0.03° on angles, base and flange "
                   "included; paper / all: ±2 mm / ±1° on the wrench-identifiable / on every "
                   "parameter (Joubair et al. 2016); none: the true arm is the nominal one.")
@click.option("--force", is_flag=True, help=FORCE_HELP)
@handle_errors
def simulate(output: Path, poses: int, plan: str, seed: int, samples: int,
             fiducial_sigma: float, robot_rot_sigma: float, robot_trans_sigma: float,
             radius: float | None, rotation: float, tracker_scale: tuple[float, float, float],
             tracker_shear: tuple[float, float, float], marker_only: bool, arm: str | None,
             kinematic_errors: str | None, force: bool) -> None:
    """Write a simulated session (the simulation of Wang et al. 2018, docs/methods.md); the
    header carries the truth (and the tracker distortion, when one is simulated).

    With --arm, a serial arm with hidden kinematic errors moves the flange (docs/
    kinematics.md, "Realistic arm errors"): the session records each pose's joint angles and
    the header's truth the arm's nominal and true models."""
    from ..errors import ConfigError
    from ..session import make_header, records_from_arrays, write_session
    from ..sim import Noise, make_arm
    from ..sim import simulate as run_sim

    if kinematic_errors is not None and arm is None:
        raise click.BadParameter("needs --arm (the arm whose errors these are)",
                                 param_hint="--kinematic-errors")
    errors = kinematic_errors or "realistic"
    check_outputs({"--output": output}, [], force)
    rng = np.random.default_rng(seed)
    noise = Noise(fiducial_sigma, robot_rot_sigma, robot_trans_sigma,
                  tracker_scale=tracker_scale, tracker_shear=tracker_shear)  # _Triple's tuples
    pair = None if arm is None else make_arm(arm, errors, seed)
    try:
        truth, d = run_sim(poses, rng, plan=plan, noise=noise, samples=samples,
                           with_probe=not marker_only, radius_mm=radius,
                           rotation_deg=rotation, arm=pair)
    except ValueError as e:
        raise ConfigError(f"--arm {arm}: {e}") from None
    bodies = ["marker"] if marker_only else ["marker", "probe"]
    robot: dict[str, Any] = {"driver": "sim"} if arm is None else {"driver": "sim", "arm": arm}
    header = make_header(
        bodies, truth=truth.as_dict(),
        config={"simulate": {"poses": poses, "plan": plan, "seed": seed, "samples": samples,
                             "fiducial_sigma_mm": fiducial_sigma,
                             "robot_rot_sigma_deg": robot_rot_sigma,
                             "robot_trans_sigma_mm": robot_trans_sigma,
                             "radius_mm": radius, "rotation_deg": rotation,
                             "tracker_scale": list(noise.tracker_scale),  # type: ignore
                             "tracker_shear": list(noise.tracker_shear),
                             "arm": arm, "kinematic_errors": None if arm is None else errors}},
        devices={"robot": robot, "tracker": {"driver": "sim"}})
    recs = records_from_arrays(d["A"], d["marker"], d.get("probe"), d["commanded"], samples,
                               joints=d.get("joints"))
    write_session(output, header, recs, overwrite=force)
    kin = "" if arm is None else (
        f"; arm {arm} with {errors} kinematic errors, joints recorded"
        + _redrawn(int(d["redrawn"])))
    click.echo(f"wrote {output}: {poses} poses ({plan} plan, seed {seed}), bodies "
               f"{', '.join(bodies)}, truth in the header{kin}")


def _redrawn(k: int) -> str:
    """", 3 poses out of reach re-drawn" (nothing when k is 0)."""
    return f", {k} pose{'s' if k != 1 else ''} out of reach re-drawn" if k else ""
