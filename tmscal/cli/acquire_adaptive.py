"""The adaptive parts of ``tmscal acquire --adaptive`` and ``tmscal demo --adaptive``
(docs/adaptive.md): running the loop with a progress display (the bars and a line per
prediction), the end-of-run report, and the demo's comparison with the mock rig's truth. The
commands live in :mod:`tmscal.cli.acquire` and :mod:`tmscal.cli.demo`; the run in
:mod:`tmscal.acquisition.adaptive_run`."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

import click

from ..acquisition.progress import Progress
from .app import Finite, as_flags

#: the command-line overrides of the ``adaptive:`` section (option → AdaptiveSettings field)
OVERRIDES = ("target_mm", "confidence", "max_poses", "bootstrap")


def adaptive_options(fn: Any) -> Any:
    """--adaptive and its overrides of the config's adaptive: section."""
    opts = [
        click.option("--adaptive", is_flag=True,
                     help="Adaptive acquisition (docs/adaptive.md): choose each next pose of "
                          "the plan by the expected reduction of the predicted coil-placement "
                          "error per second of robot time; stop at --target-mm or "
                          "--max-poses. The candidates are the config's plan with "
                          "adaptive.pool poses, all checked against the safety envelope "
                          "before anything moves."),
        click.option("--target-mm", type=Finite(0, 100, lo_open=True), default=None,
                     help="With --adaptive: stop when the predicted coil-placement error (mean "
                          "over the region, at --confidence) is at or below this, mm "
                          "(overrides adaptive.target_mm; default 0.05). With --update: the "
                          "update's predicted coil-placement error at 95 %, mm (default "
                          "0.1)."),
        click.option("--confidence", type=Finite(0.5, 0.9999), default=None,
                     help="With --adaptive: the confidence of the prediction, e.g. 0.95 "
                          "(overrides adaptive.confidence)."),
        click.option("--max-poses", type=click.IntRange(3, 100000), default=None,
                     help="With --adaptive: stop after this many poses whatever the "
                          "prediction; skipped poses count (overrides adaptive.max_poses; "
                          "default 40). With --update: at most this many poses (default 10)."),
        click.option("--bootstrap", type=click.IntRange(3, 100000), default=None,
                     help="With --adaptive: well-spread poses measured before the first "
                          "prediction (overrides adaptive.bootstrap; default 4: the 3 poses "
                          "that make the problem well posed, plus one)."),
    ]
    for o in reversed(opts):
        fn = o(fn)
    return fn


def check_adaptive_flags(adaptive: bool, resume: bool, output: Path, poses: int | None,
                          overrides: dict[str, Any]) -> bool:
    """Whether the run is adaptive: --adaptive, or --resume of an adaptive session. The
    adaptive overrides need it; --poses does not go with it (the run chooses its poses)."""
    if resume and not adaptive and is_adaptive_session(output):
        adaptive = True
    given = [k for k, v in overrides.items() if v is not None]
    if given and not adaptive:
        raise click.BadParameter("only with --adaptive (or --resume of an adaptive session)",
                                 param_hint="--" + given[0].replace("_", "-"))
    if adaptive and poses is not None:
        raise click.BadParameter("an adaptive run chooses its poses: use --max-poses to bound "
                                 "them (adaptive.pool sets the candidates)",
                                 param_hint="--poses")
    return adaptive


def is_adaptive_session(path: Path) -> bool:
    """True when ``path`` is a session recorded by ``acquire --adaptive`` (its header has
    an ``adaptive`` entry); False for other sessions and for a missing file."""
    from ..session import read_session

    if not path.exists():
        return False
    return isinstance(read_session(path).header.get("adaptive"), dict)


def _note(msg: str) -> None:
    """One line on stderr that does not tear a progress bar."""
    from tqdm import tqdm
    tqdm.write(msg, file=sys.stderr)


class PredictionLines(Progress):
    """One line on stderr per prediction of an adaptive run: the predicted coil-placement
    error (mm) at its confidence and, unless the run stops, the next pool pose with the RMS
    error it is expected to bring (mm) and its robot time (s)."""

    def predicted(self, prediction: Any, info: dict[str, Any]) -> None:
        pred = prediction
        line = (f"{pred.n_poses} poses: predicted coil-placement error {pred.coil_mm:.3g} mm "
                f"at {pred.confidence * 100:g} %")
        if info.get("next") is not None and "gain_per_s" in info:
            line += (f"; next: pool pose {info['next']} (RMS {info['rms_now_mm']:.3g} → "
                     f"{info['rms_after_mm']:.3g} mm for {info['cost_s']:.1f} s of robot "
                     "time)")
        _note(line)


def run(cfg: Any, output: Path, *, resume: bool, overrides: dict[str, Any],
        samples: int | None, tracker_port: str | None, robot_host: str | None,
        robot_port: int | None = None, should_stop: Any = lambda: False,
        quiet: bool = False, replace: bool = False, origin: Any = None) -> Any:
    """``acquire_adaptive`` with the progress display (the bars and a line per prediction on
    stderr unless ``quiet``); returns its AcquireResult."""
    from ..acquisition.adaptive_run import acquire_adaptive, settings_for
    from ..acquisition.progress import ProgressGroup
    from .progress import AcquireProgress, stderr_to_log

    settings = None if resume else settings_for(cfg, **overrides)
    with stderr_to_log(), AcquireProgress(sys.stderr) as bar:
        return acquire_adaptive(
            cfg, output, settings=settings, resume=resume, replace=replace, overrides=overrides,
            samples=samples, tracker_port=tracker_port, robot_host=robot_host,
            robot_port=robot_port, should_stop=should_stop, origin=origin,
            progress=bar if quiet else ProgressGroup(bar, PredictionLines()))


def summary(res: Any, config: Path | None, output: Path, tracker_port: str | None = None,
            robot_host: str | None = None) -> None:
    """The end-of-run report: why it stopped, the poses used, the prediction with its
    confidence and region, the robot time by phase, and what to run next."""
    from ..acquisition.resume import resume_command
    from ..report.text import format_prediction, format_robot_time

    state = "stopped early (resumable)" if res.stopped else f"done: {res.message}"
    click.echo(f"session {output}: {state}")
    click.echo(f"  poses used {res.recorded} ({res.skipped} skipped; {res.new_poses} new in "
               f"{res.elapsed_s:.1f} s); device faults recovered: {res.faults}")
    if res.prediction is not None:
        click.echo("  " + format_prediction(res.prediction, _region(res.settings)))
    click.echo("  " + format_robot_time(res.robot_time_s))
    for note in res.notes:
        click.echo(f"note: {as_flags(note)}")
    if res.stopped:
        click.echo("resume with: " + resume_command(config, output, tracker_port, robot_host))
    from ..solving.predict import RUN_METHOD

    opts = "".join(f" --option {k}={v}" for k, v in RUN_METHOD["options"].items())
    click.echo(f"next: tmscal solve {output} --method {RUN_METHOD['method']}{opts} -o "
               f"{output.with_suffix('.yaml')}   (the calibration the prediction is about)")


def _region(settings: Any) -> str:
    return f"the first {settings.region} poses of the plan (the coil-placement region)"


def demo(cfg: Any, cfg_path: Path, output: Path, transport: str, samples: int | None,
         overrides: dict[str, Any], as_json: bool, replace: bool = False) -> None:
    """``tmscal demo --adaptive``: the adaptive run on the mock rig (mocks in a child), then
    the session solved with the method whose prediction stopped the run
    (``solving.predict.RUN_METHOD``: ml, distortion scale), its prediction beside its true
    coil-placement error against the rig's truth (over the same region), as ``demo``
    prints a solve."""

    from ..mocks.launch import build_sim_rig, spawn_mock_rig
    from ..net import split_endpoint
    from ..report.text import format_result, format_robot_time, format_truth
    from ..session import read_session
    from ..solving.predict import RUN_METHOD
    from ..solving.solve import solve
    from .app import print_json

    truth = build_sim_rig(cfg).truth  # the child builds the same rig from the same config
    with spawn_mock_rig(cfg_path, transport=transport) as mp:
        ep = mp.endpoints
        if not as_json:
            click.echo("mock rig: " + ", ".join(f"{k} {v}" for k, v in ep.items()))
        host, port = split_endpoint(ep["robot"])
        res = run(cfg, output, resume=False, overrides=overrides, samples=samples,
                  tracker_port=ep["tracker"], robot_host=host, robot_port=port,
                  quiet=as_json, replace=replace)
    session = read_session(output)
    session.header["truth"] = truth.as_dict()
    result = solve(session, method=RUN_METHOD["method"],
                              options=dict(RUN_METHOD["options"]))
    true_mm = (result.truth or {}).get("coil_placement_mm")
    if as_json:
        out = result.to_json()
        out.update(robot_time_s=res.robot_time_s, poses_used=res.recorded,
                   predicted_coil_mm=None if res.prediction is None else res.prediction.coil_mm,
                   confidence=res.settings.confidence, true_coil_mm=true_mm,
                   stop_reason=res.stop, adaptive_method=RUN_METHOD["method"])
        print_json(out)
        return
    click.echo(f"{res.message}; poses used {res.recorded} ({res.skipped} skipped)")
    click.echo(format_robot_time(res.robot_time_s))
    if true_mm is not None:
        click.echo(f"true coil-placement error {true_mm:.3g} mm (the {RUN_METHOD['method']} "
                   "calibration below, the one that prediction is about, against the mock "
                   "rig's truth, mean over the same region)")
    click.echo("")
    click.echo(format_result(result))
    click.echo(format_truth(truth))
