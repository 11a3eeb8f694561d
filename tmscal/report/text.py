"""Human-readable tables, the calibration YAML export, and the study plot.

Units: mm and degrees, named in every column header.
"""

from __future__ import annotations

import datetime as _dt
from typing import TYPE_CHECKING, Any

import numpy as np
import yaml

if TYPE_CHECKING:
    from .evaluate import SolveResult

__all__ = ["format_result", "format_study", "calibration_yaml", "plot_study", "plot_residuals",
           "format_matrix"]


def format_matrix(M: Any, indent: str = "    ") -> str:
    """A 4×4 matrix as aligned rows (mm in the last column)."""
    A = np.asarray(M, dtype=float)
    return "\n".join(indent + "  ".join(f"{v:>11.5f}" for v in row) for row in A)


def format_result(res: SolveResult, show_matrices: bool = True) -> str:
    """The ``tmscal solve`` human output: a short aligned table."""
    lines = [f"method {res.method} ({res.applied} matrices applied), solved on "
             f"{res.n_solve} poses, errors {res.errors_on} on {res.n_test} poses"]
    if res.n_skipped:
        lines.append(f"({res.n_skipped} poses of the session were skipped at acquisition "
                     "and are not used)")
    e = res.errors
    lines.append("")
    lines.append(f"  {'error':<26}{'translation mm':>16}{'rotation deg':>15}")
    for b in ("marker", "probe"):
        if b in e:
            lines.append(f"  {b + ' (E = (AX)⁻¹ZB)':<26}{e[b]['trans_mm']:>16.4f}"
                         f"{e[b]['rot_deg']:>15.4f}")
    if "e_z_mm" in e:
        lines.append(f"  {'Z_P vs Z_M (e_z)':<26}{e['e_z_mm']:>16.4f}{e['theta_z_deg']:>15.4f}")
    lines.append(f"  {'total (e_t, θ_t)':<26}{e['e_t_mm']:>16.4f}{e['theta_t_deg']:>15.4f}")
    if res.truth is not None:
        lines.append("")
        lines.append(f"  {'against the truth':<26}{'translation mm':>16}{'rotation deg':>15}")
        for k in ("X", "Y", "Z"):
            if k in res.truth:
                t = res.truth[k]
                lines.append(f"  {k:<26}{t['trans_mm']:>16.4f}{t['rot_deg']:>15.4f}")
        if "coil_placement_mm" in res.truth:
            t = res.truth
            lines.append(f"  {'coil placement (mean/max)':<26}{t['coil_placement_mm']:>16.4f}"
                         f"{t['coil_placement_max_mm']:>15.4f} mm")
    if show_matrices:
        for k, name in (("X", "flange_from_marker"), ("Y", "flange_from_probe"),
                        ("Z", "base_from_tracker")):
            M = getattr(res, k)
            if M is not None:
                lines.append("")
                lines.append(f"  {k} = {name} (orthonormal, mm)")
                lines.append(format_matrix(M))
    return "\n".join(lines)


def format_study(study: dict[str, Any], paper: dict[str, Any] | None = None) -> str:
    """Tables 1 and 3 of Wang et al. (2018) for a study result."""
    out = [f"convergence study: train on the first n poses (n = {study['n'][0]}…"
           f"{study['n'][-1]}), test on {study['n_test']} later poses", ""]
    hdr = f"  {'method':<7}{'metric':<16}" + "".join(
        f"{h:>16}" for h in ("min (n)", "25% (n)", "median (n)", "75% (n)", "max (n)"))
    out.append(hdr)
    for m, t in study["table"].items():
        for metric in ("e_t_mm", "theta_t_deg", "e_z_mm", "marker_trans_mm", "probe_trans_mm"):
            s = t["stats"].get(metric)
            if not s:
                continue
            cells = "".join(f"{s[k]['value']:>10.4f} ({s[k]['n']:>3})"
                            for k in ("min", "p25", "median", "p75", "max"))
            out.append(f"  {m:<7}{metric:<16}{cells}")
    out.append("")
    out.append("  smallest n after which e_t stays below:")
    for m, t in study["table"].items():
        thr = ", ".join(f"{k} mm: {'never' if v is None else v}"
                        for k, v in t["n_below_mm"].items())
        out.append(f"    {m:<7}{thr}")
    return "\n".join(out)


def calibration_yaml(res: SolveResult, session_path: str, session_sha256: str) -> str:
    """The calibration YAML (docs/conventions.md): X, Y, Z orthonormal, raw matrices, method, poses
    used, held-out errors, and the session's SHA-256. Units mm."""
    j = res.to_json()
    doc = {
        "format": "tmscal-calibration",
        "version": 1,
        "created": _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds"),
        "units": {"length": "mm", "angles": "deg"},
        "frames": {"X": "flange_from_marker", "Y": "flange_from_probe",
                   "Z": "base_from_tracker"},
        "method": j["method"],
        "applied": j["applied"],
        "session": {"path": session_path, "sha256": session_sha256},
        "poses": {"solve": j["n_solve"], "test": j["n_test"],
                  "errors_on": j["errors_on"]},
        "X": j["X"], "Y": j["Y"], "Z": j["Z"],
        "raw": j["raw"],
        "errors": j["errors"],
    }
    if res.truth is not None:
        doc["truth_errors"] = res.truth
    return yaml.safe_dump(doc, sort_keys=False, default_flow_style=None, width=120)


def plot_study(study: dict[str, Any], path: str, title: str | None = None) -> None:
    """Figure 3 of Wang et al. (2018): e_t (and θ_t) against the number of poses, one line
    per method. Writes a PNG; needs matplotlib (extra ``plot``)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ns = study["n"]
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2))
    for m, c in study["curves"].items():
        axes[0].plot(ns, c["e_t_mm"], label=f"{m} e_t")
        if "e_z_mm" in c:
            axes[0].plot(ns, c["e_z_mm"], "--", label=f"{m} e_z")
        axes[1].plot(ns, c["theta_t_deg"], label=f"{m} θ_t")
    for ax, unit in zip(axes, ("translation error (mm)", "rotation error (deg)")):
        ax.set_xlabel("poses used for the solve (n)")
        ax.set_ylabel(unit)
        ax.set_yscale("log")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend()
    fig.suptitle(title or f"hold-out error on {study['n_test']} poses")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def plot_residuals(res: dict[str, Any], n_solve: int, path: str, title: str) -> None:
    """Per-pose translation (mm) and rotation (deg) errors of each body against the pose
    index, the solve set shaded: outliers (a bumped tool, a bad frame) stand out. PNG."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    idx = res["index"]
    fig, axes = plt.subplots(2, 1, figsize=(10, 5.5), sharex=True)
    for body in ("marker", "probe"):
        if body in res:
            axes[0].plot(idx, res[body]["trans_mm"], ".", ms=3, label=body)
            axes[1].plot(idx, res[body]["rot_deg"], ".", ms=3, label=body)
    for ax, unit in zip(axes, ("translation error (mm)", "rotation error (deg)")):
        if n_solve < len(idx):
            ax.axvspan(idx[0], idx[n_solve - 1], color="0.9", label="solve set")
        ax.set_ylabel(unit)
        ax.grid(True, alpha=0.3)
        ax.legend(loc="upper right")
    axes[1].set_xlabel("pose index")
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
