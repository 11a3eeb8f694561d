"""``tmscal selfcal``: kinematic self-calibration of the robot arm from a wrist force-torque
sensor (Joubair et al. 2016; docs/selfcal.md).

The group lives here with ``simulate`` (the simulation study, no devices); ``acquire`` and
``identify`` register on the same group from :mod:`tmscal.cli.selfcal_acquire` and
:mod:`tmscal.cli.selfcal_identify`.
"""

from __future__ import annotations

import sys
import textwrap
from typing import Any

import click

from .app import Finite, handle_errors, main, print_json


class ArmName(click.Choice):
    """``--arm``: a registered arm's name (``tmscal.calib.kinematics.ARM_NAMES``; docs/
    kinematics.md). The names are read when the option is parsed or its help shown, not when
    the CLI starts: importing ``tmscal.calib`` loads the solvers."""

    def __init__(self) -> None:
        super().__init__((), case_sensitive=True)

    @property  # type: ignore[override]
    def choices(self) -> tuple[str, ...]:
        from ..calib.kinematics.arms import ARM_NAMES

        return ARM_NAMES

    @choices.setter
    def choices(self, value: Any) -> None:  # click.Choice.__init__ sets it: the registry's
        pass


class StudyArmName(ArmName):
    """``simulate --arm``: a registered arm's name or ``medrue``, the paper's own robot
    (``tmscal.calib.selfcal.study.simulate.STUDY_ARMS``; docs/selfcal.md)."""

    @property  # type: ignore[override]
    def choices(self) -> tuple[str, ...]:
        from ..calib.kinematics.arms import ARM_NAMES

        return (*ARM_NAMES, "medrue")

    @choices.setter
    def choices(self, value: Any) -> None:
        pass


@main.group()
def selfcal() -> None:
    """Kinematic self-calibration from a wrist force-torque sensor (Joubair et al. 2016).

    The gravity wrench that a sensor at the wrist reads in many arm configurations depends on
    the arm's kinematic parameters (joint offsets, link twists, base and sensor orientation)
    and on the tool's mass and centre of gravity; fitting it identifies the parameters it
    observes, without external measuring equipment. Joint angles are rad inside, lengths mm,
    forces N, torques N·m (docs/selfcal.md).

    \b
      tmscal selfcal simulate              the simulation study (identifiable parameters,
                                           TCP error before/after, pose-selection indices)
      tmscal selfcal acquire CONFIG -o S   move through selected configurations, record
                                           joints and wrenches
      tmscal selfcal identify S -o K.yaml  fit a session, write the calibrated parameters
    """


def _stats(d: dict[str, float]) -> str:
    return f"{d['mean_mm']:7.3f} {d['max_mm']:7.3f} {d['sd_mm']:7.3f}"


def _echo_wrapped(text: str) -> None:
    click.echo(textwrap.fill(text, width=98, subsequent_indent="  "))


def _print_table(res: Any) -> None:
    s = res.settings
    _echo_wrapped(f"arm {s['arm']}, errors {s['errors']}: ±2 mm / ±1° on {len(res.in_error)} "
                  f"parameters; wrench noise ±{s['force_n']:g} N / ±{s['torque_nm']:g} N·m, "
                  f"{s['samples']} readings averaged per configuration")
    _echo_wrapped(f"identifiable: {len(res.identifiable)} of {res.parameters} parameters: "
                  + ", ".join(res.identifiable))
    _echo_wrapped(f"{s['k']} configurations by DETMAX (O1) from a pool of {s['pool']}; "
                  f"validation on the other {s['pool'] - s['k']}; {s['trials']} noise draws; "
                  "the identified arm is the answer that does not depend on the kept columns "
                  "(docs/selfcal.md)")
    click.echo("TCP position error (mm)              mean     max      SD")
    click.echo(f"  before (nominal model)           {_stats(res.before)}")
    click.echo(f"  after  (identified)              {_stats(res.after)}")
    click.echo("after the hand/eye absorbs a rigid base transform and a TCP offset:")
    click.echo(f"  before (nominal model)           {_stats(res.before_absorbed)}")
    click.echo(f"  after  (identified)              {_stats(res.after_absorbed)}")
    gain = res.before_absorbed["mean_mm"] / res.after_absorbed["mean_mm"]
    click.echo(f"improvement of the mean after the hand/eye: {gain:.1f}×")
    if len(res.indices) > 1:
        click.echo("selection comparison (Joubair et al. 2016, Table 4): error after the "
                   "hand/eye (mm)")
        click.echo("  selection    mean     max      SD      O1      O2      O3      O4"
                   "      O5")
        for name, d in res.indices.items():
            o = d["observability"]
            click.echo(f"  {name:8s} {_stats(d['after_absorbed'])} "
                       + " ".join(f"{o[k]:7.4f}" for k in ("O1", "O2", "O3", "O4", "O5")))


@selfcal.command()
@click.option("--arm", type=StudyArmName(), default="ur5e", show_default=True,
              help="Nominal arm model, by its registered name (docs/kinematics.md): "
                   "Universal Robots ur3…ur20, DENSO vs060 or cobotta, Franka fr3 or panda; "
                   "or medrue, the hybrid robot of Joubair et al. 2016 (dimensions assumed).")
@click.option("--errors", type=click.Choice(["all", "seen", "paper"]), default="all",
              show_default=True,
              help="Which parameters of the true arm carry errors (±2 mm, ±1°): 'all' — every "
                   "length and angle; 'seen' — every one the gravity wrench sees, alone or in "
                   "a combination; 'paper' — exactly the columns the identification keeps, as "
                   "Joubair et al. 2016 simulate (not a figure a lab gets).")
@click.option("--pool", type=click.IntRange(50, 1_000_000), default=3000, show_default=True,
              help="Candidate configurations drawn uniformly within the joint limits (the "
                   "paper: 40000, slower). Those not selected validate.")
@click.option("--k", "k", type=click.IntRange(5, 10_000), default=100, show_default=True,
              help="Configurations selected for the identification.")
@click.option("--samples", type=click.IntRange(1, 100_000), default=100, show_default=True,
              help="Wrench readings averaged per configuration (the paper: 100).")
@click.option("--trials", type=click.IntRange(1, 100), default=3, show_default=True,
              help="Noise draws per design; the errors after are pooled over them.")
@click.option("--force-noise", type=Finite(0.0, 1000.0, lo_open=True), default=1.0,
              show_default=True, metavar="N", help="Bound of the force noise per reading (N; "
                                                   "normal, the bound is 3σ).")
@click.option("--torque-noise", type=Finite(0.0, 100.0, lo_open=True), default=0.2,
              show_default=True, metavar="NM",
              help="Bound of the torque noise per reading (N·m; normal, the bound is 3σ).")
@click.option("--no-compare", is_flag=True,
              help="Skip the selection comparison (O1…O5 greedy, random): DETMAX only.")
@click.option("--seed", type=click.IntRange(0, 2**32 - 1), default=0, show_default=True,
              help="Random seed (pool, errors, noise).")
@click.option("--json", "as_json", is_flag=True, help="Print one JSON object.")
@handle_errors
def simulate(arm: str, errors: str, pool: int, k: int, samples: int, trials: int,
             force_noise: float, torque_noise: float, no_compare: bool, seed: int,
             as_json: bool) -> None:
    """The simulation study of Joubair et al. 2016 on a serial arm or on MedRUE: a true arm
    with hidden parameter errors, k configurations chosen by the observability index O1
    (DETMAX) from a candidate pool, their gravity wrenches plus noise, identification (its
    answer independent of the kept columns), and the TCP position error (mm, mean/max/SD) on
    the rest of the pool before and after, raw and after a hand/eye calibration absorbs a
    rigid base transform and a TCP offset; then the same with the configurations chosen by
    each index O1…O5 and at random (the paper's Table 4).
    No devices; progress on stderr (docs/selfcal.md, "Simulation study")."""
    from tqdm import tqdm

    from ..calib.selfcal.study.simulate import simulate as run_study
    from ..calib.selfcal.study.simulate import stages

    if k >= pool:
        raise click.BadParameter(f"{k} must be below --pool ({pool}): the pool also supplies "
                                 "the validation configurations", param_hint="--k")
    names = stages(not no_compare)
    with tqdm(total=len(names), desc="selfcal simulate", unit="stage", disable=None,
              file=sys.stderr, leave=False) as bar:
        seen: list[str] = []

        def progress(stage: str) -> None:
            if seen:
                bar.update(1)
            seen.append(stage)
            bar.set_postfix_str(stage)

        try:
            res = run_study(arm=arm, errors=errors, pool=pool, k=k, seed=seed,
                            force_n=force_noise, torque_nm=torque_noise, samples=samples,
                            compare=not no_compare, trials=trials, progress=progress)
        except ValueError as e:
            raise click.UsageError(str(e)) from None
        bar.update(1)
    if as_json:
        print_json(res.to_dict())
    else:
        _print_table(res)
