"""``tmscal report``: one self-contained HTML page of a session and its calibration, to attach
to a lab notebook (docs/report.md).

The page has no external resource and no script: the figures are PNG (matplotlib's Agg
backend, extra ``plot``) embedded as base64 ``data:`` URLs, the style is inline, and a
Content-Security-Policy forbids anything else. Everything that comes from the session or the
calibration file (names, identities, skip reasons) is HTML-escaped, with control characters
and bidirectional overrides shown as visible escapes (``\x1b``, ``\u202e``;
``tmscal.escape``).

The tables are the text of :mod:`tmscal.report.text` (what ``tmscal solve`` and ``tmscal
study`` print) and two of the figures are :mod:`tmscal.report.plots`' (the convergence study,
the per-pose residuals); only the figures of the plan and of the sample spreads are drawn here.

Units: mm and degrees; frames as everywhere (A = base_from_flange, B = tracker_from_marker,
C = tracker_from_probe, X = flange_from_marker, Y = flange_from_probe, Z = base_from_tracker).
"""

from __future__ import annotations

import base64
import datetime as _dt
import os
import tempfile
from collections import Counter
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from .. import __version__
from ..calib import Calibration
from ..errors import CalibrationError
from ..escape import html_text
from ..session import Session, skip_cause
from ..solving.kinematics import applied_arrays
from ..solving.outliers import find_outliers
from ..solving.solve import (
    SolveResult,
    arm_summary,
    flat_errors,
    pose_residuals,
    solve,
    truth_errors_of,
)
from ..solving.study import study_session
from . import text
from .plots import agg_pyplot, plot_residuals, plot_study
from .text import number, plain_value
from .verdict import verdict_rows

__all__ = ["SECTIONS", "html_report"]

#: section id → heading, in page order (the ids are the page's anchors)
SECTIONS: dict[str, str] = {
    "verdict": "Verdict",
    "rig": "Rig and devices",
    "plan": "Plan and its spread",
    "samples": "Samples per pose",
    "calibration": "Calibration",
    "errors": "Held-out errors",
    "convergence": "Convergence",
    "residuals": "Residuals by pose",
}

_CSP = "default-src 'none'; img-src data:; style-src 'unsafe-inline'"
_STYLE = """
body{font-family:sans-serif;max-width:1100px;margin:1.5em auto;padding:0 1em;color:#111}
h1{font-size:1.5em}h2{border-bottom:1px solid #999;margin-top:2em}
table{border-collapse:collapse;margin:.5em 0}td,th{border:1px solid #bbb;padding:2px 8px;
text-align:left;vertical-align:top}pre{background:#f4f4f4;padding:.6em;overflow-x:auto;
font-size:.85em}img{max-width:100%}.note{color:#555;font-size:.9em}nav a{margin-right:1em}
"""

Progress = Callable[[str], None]


def _e(v: Any) -> str:
    """Text from anywhere (a session, a calibration file) as HTML text or attribute value:
    controls and bidi overrides made visible, markup characters escaped."""
    return html_text(v)


def _pre(body: str) -> str:
    return f"<pre>{html_text(body, newlines=True)}</pre>"


def _table(rows: list[list[Any]], head: list[str] | None = None) -> str:
    """An HTML table; cells that are not text are shown by ``text.plain_value`` (no Python
    reprs: none, yes/no, "key value, …")."""
    def cell(c: Any) -> str:
        return _e(c if isinstance(c, str) else plain_value(c))

    h = "" if head is None else "<tr>" + "".join(f"<th>{_e(c)}</th>" for c in head) + "</tr>"
    body = "".join("<tr>" + "".join(f"<td>{cell(c)}</td>" for c in r) + "</tr>" for r in rows)
    return f"<table>{h}{body}</table>"


def _figure(draw: Callable[[str], None], alt: str) -> str:
    """An <img> of the PNG that ``draw(path)`` writes, embedded as base64."""
    fd, path = tempfile.mkstemp(suffix=".png", prefix="tmscal-report-")
    os.close(fd)
    try:
        draw(path)
        data = Path(path).read_bytes()
    finally:
        Path(path).unlink(missing_ok=True)
    return (f'<img alt="{_e(alt)}" src="data:image/png;base64,'
            f'{base64.b64encode(data).decode("ascii")}">')


def _section(key: str, body: str) -> str:
    return f'<section id="{key}"><h2>{_e(SECTIONS[key])}</h2>\n{body}\n</section>'


# --- rig, plan, samples ------------------------------------------------------------------------

def _rig(session: Session, sha256: str) -> str:
    h = session.header
    cfg = h.get("config") or {}
    name = cfg.get("name") if isinstance(cfg, dict) else None
    rows = [["session file", str(session.path)], ["SHA-256", sha256],
            ["created", h.get("created", "?")], ["config", name or "(no name)"],
            ["bodies", ", ".join(session.bodies)],
            ["poses recorded", len(session.poses)]]
    if isinstance(cfg, dict) and isinstance(cfg.get("simulate"), dict):
        rows.append(["simulated", plain_value(cfg["simulate"])])
    if h.get("sampling"):
        rows.append(["sampling", plain_value(h["sampling"])])
    if session.truth:
        rows.append(["truth", "simulated session: the header carries X, Y, Z"])
    if session.damaged or session.torn_tail:
        rows.append(["damaged lines", session.damage_summary() or "a torn last line ignored"])
    out = [_table(rows)]
    for kind, ident in (h.get("devices") or {}).items():
        if isinstance(ident, dict):
            out.append(f"<h3>{_e(kind)}</h3>")
            out.append(_table([[k, v] for k, v in ident.items()]))
    return "\n".join(out)


def _plan_offsets(session: Session) -> tuple[np.ndarray, np.ndarray, str] | None:
    """(translation offsets (n, 3) mm in the base frame, rotation angles (n,) deg, what they
    are relative to) of the commanded flange poses (else the measured A) from P0."""
    poses = sorted(session.poses, key=lambda p: p.index)
    given = [p.commanded if p.commanded is not None else p.A for p in poses]
    mats = [m for m in given if m is not None]
    if not mats:
        return None
    P = np.stack(mats)
    p0 = (session.header.get("plan") or {}).get("p0")
    ref, what = (np.asarray(p0, float), "P0") if p0 is not None else (P[0], "the first pose")
    t = P[:, :3, 3] - ref[:3, 3]
    R = np.einsum("ji,njk->nik", ref[:3, :3], P[:, :3, :3])
    ang = np.degrees(np.arccos(np.clip((np.trace(R, axis1=1, axis2=2) - 1) / 2, -1, 1)))
    return t, ang, what


def _draw_plan(t: np.ndarray, ang: np.ndarray, what: str, path: str) -> None:
    plt = agg_pyplot()
    fig, ax = plt.subplots(1, 2, figsize=(10, 3.8), layout="constrained")
    for k, axis in enumerate("xyz"):
        ax[0].hist(t[:, k], bins=30, histtype="step", lw=1.4, label=axis)
    ax[0].set_xlabel(f"flange offset from {what}, robot base frame (mm)")
    ax[0].set_ylabel("poses")
    ax[0].legend(frameon=False)
    ax[1].hist(ang, bins=30, color="0.4")
    ax[1].set_xlabel(f"flange rotation away from {what} (deg)")
    ax[1].set_ylabel("poses")
    from matplotlib.ticker import MaxNLocator
    for a in ax:  # pose counts are whole numbers
        a.yaxis.set_major_locator(MaxNLocator(integer=True))
    fig.suptitle(f"plan spread: {len(t)} poses", fontsize=11)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _plan(session: Session) -> str:
    plan = session.header.get("plan") or {}
    rows = [[k, v] for k, v in plan.items() if k != "p0"]
    out = [_table(rows) if rows else '<p class="note">The header records no plan.</p>']
    off = _plan_offsets(session)
    if off is None:
        return "\n".join(out + ['<p class="note">No robot poses recorded.</p>'])
    t, ang, what = off
    rows = [[f"{a} offset (mm)", number(t[:, k].min(), ".1f"), number(t[:, k].max(), ".1f"),
             number(t[:, k].std(), ".1f")] for k, a in enumerate("xyz")]
    rows.append(["rotation (deg)", number(ang.min(), ".2f"), number(ang.max(), ".2f"),
                 number(ang.std(), ".2f")])
    out.append(_table(rows, [f"commanded flange pose relative to {what}", "min", "max", "SD"]))
    out.append(_figure(lambda p: _draw_plan(t, ang, what, p), "plan spread"))
    return "\n".join(out)


def _draw_spreads(session: Session, path: str) -> None:
    plt = agg_pyplot()
    poses = sorted((p for p in session.poses if p.spread), key=lambda p: p.index)
    fig, ax = plt.subplots(2, 1, figsize=(10, 5.5), sharex=True, layout="constrained")
    for body in session.bodies:
        idx = [p.index for p in poses if body in p.spread]
        for a, key in zip(ax, ("trans_mm", "rot_deg")):
            a.plot(idx, [p.spread[body][key] for p in poses if body in p.spread], ".", ms=3,
                   label=body)
    skipped = [p.index for p in session.poses if p.skipped is not None]
    for a, label in zip(ax, ("RMS spread of the samples (mm)", "RMS spread (deg)")):
        for i in skipped:
            a.axvline(i, color="red", lw=0.6, alpha=0.5)
        a.set_ylabel(label)
        a.grid(True, alpha=0.3)
    ax[0].legend(frameon=False, title="red lines: skipped poses" if skipped else None)
    ax[1].set_xlabel("session pose index")
    from matplotlib.ticker import MaxNLocator
    ax[1].xaxis.set_major_locator(MaxNLocator(integer=True))
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _samples(session: Session) -> str:
    out = ["<p>Each pose averages many tracker frames (and robot reads); the spread is the "
           "RMS distance (mm) and angle (deg) of those samples about their mean "
           "(docs/session-format.md).</p>"]
    if any(p.spread for p in session.poses):
        out.append(_figure(lambda p: _draw_spreads(session, p), "sample spreads by pose"))
    skipped = sorted((p for p in session.poses if p.skipped is not None), key=lambda p: p.index)
    if not skipped:
        out.append("<p>No pose was skipped.</p>")
        return "\n".join(out)
    causes = Counter(skip_cause(p.skipped or "") for p in skipped)
    out.append(f"<p>{len(skipped)} of {len(session.poses)} poses were skipped "
               "(not used by the solvers):</p>")
    out.append(_table([[c, n] for c, n in causes.most_common()], ["cause", "poses"]))
    out.append(_table([[p.index, p.skipped] for p in skipped], ["pose", "reason"]))
    return "\n".join(out)


# --- calibration, errors, convergence, residuals -------------------------------------------------

def _stored_result(session: Session, cal: Calibration, doc: dict[str, Any],
                   sha256: str) -> SolveResult:
    """A stored calibration evaluated on every usable pose of ``session``: held out, unless
    the calibration file names this very session (then in-sample); with an identified arm,
    the robot poses recomputed from the joints (``solving.kinematics.applied_arrays``)."""
    A, B, C, _, q = applied_arrays(session, cal, need_probe=cal.Y is not None
                                   and "probe" in session.bodies)
    if len(A) == 0:
        raise CalibrationError(f"{session.path}: no usable poses in the session")
    if cal.Y is None or "probe" not in session.bodies:
        C = None
    same = (doc.get("session") or {}).get("sha256") == sha256
    raw = {"X": cal.X_raw, "Y": cal.Y_raw, "Z": cal.Z_raw}
    return SolveResult(
        method=cal.method, applied=str(cal.applied), n_solve=cal.n_poses, n_test=len(A),
        errors_on="in-sample" if same else "held-out",
        n_skipped=sum(p.skipped is not None for p in session.poses), X=cal.X, Y=cal.Y,
        Z=cal.Z, raw=raw, errors=flat_errors(cal.errors(A, B, C)), Z_probe=cal.Z_probe,
        truth=truth_errors_of(session, cal, C, q),
        outliers=find_outliers(pose_residuals(session, cal)),
        uncertainty=cal.uncertainty, distortion=cal.distortion,
        arm=None if cal.arm is None else arm_summary(cal.arm))


def _calibration(cal: Calibration, res: SolveResult, source: str,
                 unc: tuple[SolveResult | None, str]) -> str:
    out = [f"<p>{_e(source)}</p>"]
    frames = {"X": "flange_from_marker", "Y": "flange_from_probe", "Z": "base_from_tracker",
              "Z_probe": "base_from_tracker of the probe (QR24)"}
    for k, name in frames.items():
        M = getattr(cal, k)
        if M is not None:
            out.append(f"<h3>{k} = {name} (orthonormal, mm)</h3>{_pre(text.format_matrix(M))}")
    shown, note = unc
    out.append("<h3>Uncertainty</h3>")
    if shown is not None:  # the solver's own, and the calibration's predicted placement
        rows = text.uncertainty_rows(shown) + text.prediction_rows(shown)
        out.append(_pre("\n".join(rows)) if rows else "")
    if note:
        out.append(f'<p class="note">{_e(note)}</p>')
    return "\n".join(out)


def _verdict(res: SolveResult, judged: dict[str, Any] | None, session: Session,
             stored: bool) -> str:
    """The verdict section: ``verdict_rows`` as a list, the PASS/FAIL line in bold."""
    rows = verdict_rows(res, judged, session, stored)
    items = "".join(f"<li>{'<strong>' if i == 0 and judged else ''}{_e(r)}"
                    f"{'</strong>' if i == 0 and judged else ''}</li>"
                    for i, r in enumerate(rows))
    return f"<ul>{items}</ul>"


def _errors(res: SolveResult, stored: bool) -> str:
    if not stored:
        return _pre(text.format_result(res, show_matrices=False, verbose=True))
    head = ("errors: IN-SAMPLE: the calibration file was solved on this session"
            if res.errors_on == "in-sample" else
            f"errors: the stored {res.method.upper()} calibration applied to the {res.n_test} "
            "usable poses of this session (held out: none of them was solved on)")
    lines = [head, ""] + text.error_rows(res)
    if res.truth is not None:
        lines += [""] + text.truth_rows(res)
    lines += [""] + text.outlier_lines(res) + [""] + text.legend_lines(res)
    return _pre("\n".join(lines))


def _convergence(session: Session, progress: Callable[[int], None] | None) -> str:
    n = len(session.arrays()[0])
    n_max = min(250, n // 2)
    if n_max < 5:
        return (f'<p class="note">{n} usable poses are too few for a convergence curve '
                "(at least 10 are needed).</p>")
    methods = ["qr24", "qr36"] if "probe" in session.bodies else ["qr24"]
    study = study_session(session, methods, n_max=n_max, progress=progress)
    intro = (f"<p>Held-out error of {' and '.join(m.upper() for m in methods)} solved on the "
             f"first n poses, n = 5…{n_max}, tested on the {study['n_test']} poses after "
             f"pose {n_max}: how many poses this rig needs (Wang et al. 2018, Figure 3).</p>")
    fig = _figure(lambda p: plot_study(study, p, title="convergence"), "convergence curve")
    return "\n".join([intro, fig, _pre(text.format_study(study))])


def _residuals(session: Session, cal: Calibration, res: SolveResult, stored: bool) -> str:
    r = pose_residuals(session, cal)
    n_solve = len(r["index"]) if stored else res.n_solve  # shade the poses solved on, if any
    fig = _figure(lambda p: plot_residuals(r, n_solve, p, "per-pose errors",
                                           outliers=res.outliers), "residuals by pose")
    if not res.outliers:
        table = "<p>No outlier pose.</p>"
    else:
        table = _table([[o["index"], "; ".join(
            f"{f['body']} {f['metric']} {f['value']:.4f} {f['unit']} > "
            f"{f['threshold']:.4f} {f['unit']}" for f in o["flags"])] for o in res.outliers],
            ["outlier pose (session pose index)", "why"])
    return "\n".join([fig, table])


def html_report(session: Session, sha256: str, *, method: str = "qr36",
                calib: Any = None, folds: int = 5, progress: Progress | None = None,
                solves: Callable[[int], None] | None = None,
                judge: Callable[[dict[str, Any]], dict[str, Any] | None] | None = None) -> str:
    """The whole page (str) for ``session`` (its file's ``sha256``). The calibration is
    solved with ``method`` (errors ``folds``-fold cross-validated, as ``tmscal solve``), or
    is ``calib``, a :class:`tmscal.formats.calibfile.CalibrationFile` evaluated on the
    session. ``judge(errors)``: the decision on the held-out errors (e_t_mm, theta_t_deg) for
    the verdict, ``tmscal.check.verdict`` with the tolerances (None: none given).
    ``progress(stage)`` is called before each slow stage, ``solves(n)`` after n more
    solves of the convergence study. Raises CalibrationError for a session that cannot be
    solved; MissingExtraError without matplotlib."""
    say = progress or (lambda s: None)
    parts = [_section("rig", _rig(session, sha256)), _section("plan", _plan(session)),
             _section("samples", _samples(session))]
    say("calibration")
    if calib is None:
        res = solve(session, method=method, folds=folds)
        cal = res.calibration
        assert cal is not None  # solve() always returns the calibration it evaluated
        source = (f"{res.method.upper()} solved on the {res.n_solve} usable poses of this "
                  "session (tmscal solve).")
        # res.prediction: this calibration's (the solve service's)
        unc: tuple[SolveResult | None, str] = (res, "")
    else:
        cal = calib.calibration
        res = _stored_result(session, cal, calib.doc, sha256)
        origin = (calib.session or {}).get("path", "an unnamed session")
        source = (f"Stored in {calib.path}: {cal.method.upper()} solved on {cal.n_poses} poses "
                  f"of {origin}" + (f", written {calib.created}" if calib.created else "") + ".")
        unc = (None, "the calibration file stores no uncertainty")
    judged = None if judge is None else judge(res.errors)
    parts.insert(0, _section("verdict", _verdict(res, judged, session, calib is not None)))
    parts += [_section("calibration", _calibration(cal, res, source, unc)),
              _section("errors", _errors(res, calib is not None))]
    say("convergence")
    parts.append(_section("convergence", _convergence(session, solves)))
    say("residuals")
    parts.append(_section("residuals", _residuals(session, cal, res, calib is not None)))
    return _page(session, parts)


def _page(session: Session, parts: list[str]) -> str:
    name = Path(str(session.path)).name if session.path else "session"
    now = _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds")
    nav = "".join(f'<a href="#{k}">{_e(v)}</a>' for k, v in SECTIONS.items())
    return ("<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">"
            f'<meta http-equiv="Content-Security-Policy" content="{_CSP}">'
            f"<title>tmscal report: {_e(name)}</title><style>{_STYLE}</style></head>\n<body>"
            f"<h1>Calibration report: {_e(name)}</h1>"
            f'<p class="note">tmscal {_e(__version__)}, {now}. Lengths in mm, angles in '
            "degrees; A = base_from_flange, B = tracker_from_marker, C = tracker_from_probe, "
            "X = flange_from_marker, Y = flange_from_probe, Z = base_from_tracker "
            "(docs/conventions.md).</p>"
            f"<nav>{nav}</nav>\n" + "\n".join(parts) + "\n</body></html>\n")
