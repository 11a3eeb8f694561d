"""``tmscal solve``: solve a session for X, Y, Z (or, with ``--calib``, check a stored
calibration on it; the check itself is :mod:`tmscal.cli.check`)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import click

from .app import (
    FORCE_HELP,
    INPUT_FILE,
    STRICT_HELP,
    Finite,
    as_flags,
    check_outputs,
    handle_errors,
    main,
    output_files,
    print_json,
    read_session_file,
    run_plot,
    write_atomic,
)
from .check import check_options, check_stored


class _Kinematics(click.ParamType):
    """``estimate`` (the keyword), or an existing kinematics file (``./estimate`` for a file
    of that name)."""

    name = "estimate|file"

    def convert(self, value: Any, param: Any, ctx: Any) -> str | Path:
        if isinstance(value, Path) or value == "estimate":
            return value
        return INPUT_FILE.convert(value, param, ctx)


_KINEMATICS = _Kinematics()


class MethodChoice(click.Choice):
    """The registered calibration methods (``tmscal.calib.METHODS``), read when used so that
    every method registered is offered."""

    def __init__(self) -> None:
        super().__init__([], case_sensitive=False)

    @property  # type: ignore[override]
    def choices(self) -> list[str]:
        from ..calib import METHODS
        return list(METHODS)

    @choices.setter
    def choices(self, value: Any) -> None:
        pass


def _parse_options(pairs: tuple[str, ...]) -> dict[str, Any]:
    """``--option KEY=VALUE`` pairs as method options, each VALUE read as YAML (numbers,
    lists, true/false, strings)."""
    import yaml

    out: dict[str, Any] = {}
    for p in pairs:
        key, sep, val = p.partition("=")
        if not sep or not key.strip().isidentifier():
            raise click.BadParameter(f"{p!r}: expected KEY=VALUE", param_hint="--option")
        try:
            out[key.strip()] = yaml.safe_load(val)
        except yaml.YAMLError:
            raise click.BadParameter(f"{p!r}: the value is not a number, list or word",
                                     param_hint="--option") from None
    return out


def _handheld_options(session: Any, index: int) -> dict[str, Any]:
    """The handheld measurement of pose ``index`` of a session: its marker and probe poses."""
    from ..errors import CalibrationError

    for p in session.poses:
        if p.index == index and p.B is not None and p.C is not None:
            return {"handheld_B": p.B, "handheld_C": p.C}
    raise CalibrationError(f"--handheld-pose {index}: the session has no pose {index} with "
                           "both marker and probe")


@main.command()
@click.argument("session_file", type=INPUT_FILE)
@click.option("--method", type=MethodChoice(), default="qr36", show_default=True,
              help="qr36: X, Y, Z jointly (Wang et al. 2018); qr24: each body on its own "
                   "(Ernst et al. 2012); and every other registered method (sgo, quat, shah, "
                   "li, handheld, ml; docs/methods.md). tmscal compare runs them side by side.")
@click.option("--option", "options", multiple=True, metavar="KEY=VALUE",
              help="A method option (repeatable), VALUE read as YAML, e.g. --option "
                   "distortion=scale for ml (docs/methods.md lists each method's options).")
@click.option("--handheld-pose", type=click.IntRange(0), default=None, metavar="INDEX",
              help="handheld: take the extra measurement (marker and probe seen together, "
                   "the probe at the coil centre) from this session pose.")
@click.option("--train", type=int, default=None,
              help="Solve on poses [0, N) and report errors held out on the rest (default: "
                   "solve on all poses, errors by cross-validation, see --folds).")
@click.option("--folds", type=click.IntRange(2, 100), default=5, show_default=True,
              help="Without --train: k-fold cross-validation, the poses cut in order into k "
                   "contiguous folds, each held out in turn; reports mean ± SD over folds. "
                   "The calibration printed and written is solved on all poses.")
@click.option("--in-sample", is_flag=True,
              help="Report errors on the poses solved on (optimistic; labelled in-sample) "
                   "instead of cross-validating.")
@click.option("--orthonormal", is_flag=True,
              help="Apply the orthonormal matrices (rotations projected, translations "
                   "re-solved) instead of the raw non-orthogonal ones (the paper's way) in "
                   "the errors. The matrices printed, stored as X, Y, Z and exported are "
                   "the orthonormal ones either way (docs/exports.md).")
@click.option("--json", "as_json", is_flag=True, help="Print one JSON object.")
@click.option("-o", "--output", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="Write the calibration YAML here.")
@click.option("--plot", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="Write a PNG of the per-pose errors (spot outlier poses).")
@click.option("--calib", "calib_file", type=INPUT_FILE, default=None, metavar="CALIB",
              help="Check a stored calibration (a file of tmscal solve -o, or a json export) "
                   "on this session instead of solving: every pose held out, the errors beside "
                   "the stored ones, coil placement against the truth when the session has "
                   "one, the calibration's provenance. No fitting; the daily check before a "
                   "TMS session.")
@check_options
@click.option("--kinematics", "kinematics", type=_KINEMATICS, default=None,
              metavar="estimate|KIN",
              help="'estimate': estimate the arm's kinematic deviations together with X, Y, "
                   "Z (maximum likelihood from the tracker poses and the recorded joints; "
                   "the calibration then carries the identified arm, and -o stores it; "
                   "docs/kinematics.md). KIN: recompute every robot pose A from the recorded "
                   "joints with the arm's calibrated kinematics (a file of tmscal selfcal "
                   "identify -o) instead of taking the controller's reported pose "
                   "(docs/selfcal.md). Every pose used needs joint angles.")
@click.option("--arm", default=None, metavar="NAME|FILE",
              help="With --kinematics estimate: the nominal arm: a registered name (ur5e, "
                   "vs060, fr3, …), a shipped arm file's name (kuka_lbr_iiwa7, xarm6, …), or "
                   "the path of a URDF (.urdf) or a tmscal arm file (docs/kinematics.md, "
                   "\"Arm files\"). Default: the arm the session recorded; another one is an "
                   "error.")
@click.option("--urdf-base", default=None, metavar="LINK",
              help="With --arm FILE.urdf: the chain's base link (default base_link).")
@click.option("--urdf-flange", default=None, metavar="LINK",
              help="With --arm FILE.urdf: the chain's flange link (default tool0).")
@click.option("--level", type=click.Choice(["auto", "none", "offsets", "full"]),
              default="auto", show_default=True,
              help="With --kinematics estimate: which deviations to estimate: none (X, Y, Z "
                   "on the nominal arm), offsets (the joints' zero offsets), full (every DH "
                   "parameter, and β on parallel axes); auto chooses by held-out error.")
@click.option("--tolerance-length", type=Finite(0, lo_open=True), default=None,
              metavar="MM",
              help="With --kinematics estimate: the prior σ of each length deviation, mm "
                   "(default 0.5; docs/kinematics.md).")
@click.option("--tolerance-angle", type=Finite(0, lo_open=True), default=None,
              metavar="DEG",
              help="With --kinematics estimate: the prior σ of each angle deviation, degrees "
                   "(default 0.1).")
@click.option("-v", "--verbose", is_flag=True,
              help="With --kinematics estimate: list every combination of deviations "
                   "(identified, weak, not identifiable) with its estimate and σ; without it "
                   "they are counted under a short summary (--json always carries them).")
@click.option("--force", is_flag=True, help=FORCE_HELP)
@click.option("--strict", is_flag=True, help=STRICT_HELP)
@handle_errors
def solve(session_file: Path, method: str, options: tuple[str, ...], handheld_pose: int | None,
          train: int | None, folds: int, in_sample: bool, orthonormal: bool, as_json: bool,
          output: Path | None, plot: Path | None, calib_file: Path | None,
          tolerance_mm: float | None, tolerance_deg: float | None,
          update: tuple[str, ...], kinematics: str | Path | None, arm: str | None,
          urdf_base: str | None, urdf_flange: str | None, level: str,
          tolerance_length: float | None, tolerance_angle: float | None, verbose: bool,
          force: bool, strict: bool) -> None:
    """Solve a session for X, Y, Z and report the errors (the metrics of Wang et al. 2018;
    docs/methods.md): by default cross-validated, mean ± SD over folds. Names outlier poses.
    With --calib, check a stored calibration on the session instead (no fitting; a calibration
    with an identified arm recomputes the session's robot poses from its joints first) and say
    what moved since it was solved (docs/lab-day.md); with --calib and --update, re-register
    only the named transforms. With --kinematics estimate, the arm's kinematics are estimated
    with X, Y, Z: the output opens with a short summary (the level, the held-out error and the
    coil placement before and after, the three largest deviations), then the level chosen and
    why (the held-out table); -v lists every identified combination of deviations with its σ,
    the weakly identified and what could not be identified and why (docs/kinematics.md, "Using
    it"). With --kinematics KIN, the robot poses come from the recorded joints and the arm's
    calibrated kinematics."""
    from ..formats.calibfile import calibration_yaml
    from ..report.text import format_result, plot_residuals
    from ..session import sha256_of
    from ..solving.solve import pose_residuals
    from ..solving.solve import solve as solve_service
    from .progress import with_fit_bar

    estimate = kinematics == "estimate"
    kin_file = kinematics if isinstance(kinematics, Path) else None
    if not estimate:
        for opt, given in (("--arm", arm is not None), ("--level", level != "auto"),
                           ("--urdf-base", urdf_base is not None),
                           ("--urdf-flange", urdf_flange is not None),
                           ("--tolerance-length", tolerance_length is not None),
                           ("--tolerance-angle", tolerance_angle is not None)):
            if given:
                raise click.BadParameter("only with --kinematics estimate", param_hint=opt)
    if calib_file is not None:
        if estimate:
            raise click.BadParameter("--kinematics estimate solves; --calib only checks a "
                                     "stored calibration (which applies its own arm)",
                                     param_hint="--calib")
        check_stored(session_file, calib_file, as_json, strict, output=output, plot=plot,
                     fitting=bool(options or handheld_pose is not None or train is not None
                                  or in_sample or orthonormal or method.lower() != "qr36"),
                     kin_file=kin_file, tolerance_mm=tolerance_mm, tolerance_deg=tolerance_deg,
                     update=list(update), force=force)
        return
    if update:
        raise click.BadParameter("only with --calib CALIB (the calibration to update)",
                                 param_hint="--update")
    for opt, tol in (("--tolerance-mm", tolerance_mm), ("--tolerance-deg", tolerance_deg)):
        if tol is not None:
            raise click.BadParameter("only with --calib CALIB (the daily check's verdict)",
                                     param_hint=opt)
    if estimate:
        src = click.get_current_context().get_parameter_source("method")
        if src == click.core.ParameterSource.DEFAULT:
            method = "ml"
    opts = _parse_options(options)
    check_outputs({"--output": output, "--plot": plot}, [session_file], force)
    session = read_session_file(session_file, strict)
    if handheld_pose is not None:
        opts.update(_handheld_options(session, handheld_pose))
    nominal: Any = arm
    if arm is not None and (urdf_base is not None or urdf_flange is not None):
        from ..formats.armdef import resolve_arm

        nominal = resolve_arm(arm, "--arm", urdf_base, urdf_flange)
    res = with_fit_bar(solve_service)(session, method=method.lower(), train=train,
                        orthonormal=orthonormal, folds=folds, in_sample=in_sample,
                        options=opts, arm=nominal, level=level,
                        tolerances=_tolerances(tolerance_length, tolerance_angle, estimate),
                        **_kinematics_args(kinematics))
    cal = res.calibration
    if res.arm is not None and res.arm.get("named_by"):
        res.arm["named_by"] = as_flags(res.arm["named_by"])
    if output is not None:
        from ..formats.calibfile import calibration_p0, provenance
        write_atomic(output, calibration_yaml(
            cal, res.to_json(), str(session_file), sha256_of(session_file),
            provenance=provenance(session.header), p0=calibration_p0(session)), force)
    if plot is not None:
        with output_files({"plot": plot}, force) as tmp:
            run_plot(plot_residuals, res.residuals or pose_residuals(session, cal), res.n_solve,
                     tmp["plot"], f"{session_file.name}: {res.method.upper()} per-pose errors",
                     outliers=res.outliers)
    pred = _adaptive_prediction(session, res, numbers=as_json)
    if as_json:
        out = res.to_json() if pred is None else {**res.to_json(), "adaptive": pred[0]}
        print_json(out if kin_file is None else {**out, "kinematics": str(kin_file)})
    else:
        if kin_file is not None:
            click.echo(f"robot poses A recomputed from the recorded joints with {kin_file}\n")
        click.echo(format_result(res, verbose=verbose))
        from ..report.adequacy_text import adequacy_text
        if warn := adequacy_text(res.adequacy):
            click.echo("\n" + warn)
        if pred is not None:
            click.echo("\n" + pred[1])
        for f in (output, plot):
            if f is not None:
                click.echo(f"\nwrote {f}")


def _tolerances(length_mm: float | None, angle_deg: float | None, estimate: bool) -> Any:
    """The prior of ``--kinematics estimate`` (``Tolerances``; its defaults for what is not
    given), or None."""
    if not estimate or (length_mm is None and angle_deg is None):
        return None
    from ..calib.kinematics.estimate import Tolerances

    d = Tolerances()
    return Tolerances(length_mm=d.length_mm if length_mm is None else length_mm,
                      angle_deg=d.angle_deg if angle_deg is None else angle_deg)


def _kinematics_args(kinematics: str | Path | None) -> dict[str, Any]:
    """``solving.solve``'s ``kinematics`` (and ``kinematics_source``) for --kinematics."""
    if kinematics is None or kinematics == "estimate":
        return {"kinematics": kinematics}
    from ..formats.kinfile import load_arm
    return {"kinematics": load_arm(kinematics), "kinematics_source": str(kinematics)}


def _adaptive_prediction(session: Any, res: Any, numbers: bool
                         ) -> tuple[dict[str, Any] | None, str] | None:
    """For a session recorded by ``acquire --adaptive``: the prediction that run stopped on
    (docs/adaptive.md), as ({method, options, predicted_coil_mm, confidence, sigma_mm,
    n_poses, …, region, robot_time_s} or None, its text); None for other sessions. The text
    names the calibration that prediction is about, prints no second number (the solve
    result ``res``'s own prediction is the written calibration's; the same one when ``res``
    is solved with the run's method, ``solving.predict.RUN_METHOD``) and so needs no fit:
    only the session's robot time. With ``numbers`` (``--json``) the run's prediction is
    recomputed from the session (``solving.predict.predict_session``: QR36 then ml, the
    run's calibration, another fit than ``res``'s)."""
    if not isinstance(session.header.get("adaptive"), dict):
        return None
    from ..report.text import format_robot_time
    from ..solving.predict import RUN_METHOD, predict_session, robot_time_of

    opts = " ".join(f"--option {k}={v}" for k, v in RUN_METHOD["options"].items())
    same = (res.method == RUN_METHOD["method"] and res.arm is None
            and (res.distortion or {}).get("model", "none")
            == RUN_METHOD["options"]["distortion"])
    about = ("this calibration" if same else f"the calibration tmscal solve {session.path} "
             f"--method {RUN_METHOD['method']} {opts} writes")
    text = ("adaptive acquisition (docs/adaptive.md): the run stopped on the prediction of "
            f"{about}\n  " + format_robot_time(robot_time_of(session.poses)))
    if not numbers:
        return None, text
    pred, info = predict_session(session)
    return ({"method": RUN_METHOD["method"], "options": dict(RUN_METHOD["options"]),
             **pred.as_dict(), "region": info["region"],
             "robot_time_s": info["robot_time_s"]}, text)
