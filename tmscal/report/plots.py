"""Figures: the convergence study (Figure 3 of Wang et al. 2018) and the per-pose errors of a
solve with its outlier poses named. PNG files; need matplotlib (extra ``plot``), imported
only when a figure is drawn.

Units: mm and degrees, named on every axis. The metrics are those of docs/methods.md.
"""

from __future__ import annotations

import textwrap
from typing import Any

import numpy as np

__all__ = ["plot_study", "plot_residuals", "plot_compare", "METRICS_CAPTION", "agg_pyplot"]

#: the metric definitions printed under the study figure (docs/methods.md)
METRICS_CAPTION = (
    "Hold-out error on the test poses of a calibration solved on the first n poses. Per pose "
    "and body, E = (AX)⁻¹ZB (marker) or (AY)⁻¹ZC (probe); e = ‖t(E⊥)‖, θ = rotation angle of "
    "E⊥, averaged over the test poses. e_t = e_marker + e_probe and θ_t = θ_marker + θ_probe; "
    "for QR24, which solves a separate Z for each body, e_z = ‖t(Z_P) − t(Z_M)‖ and θ_z are "
    "added (Wang et al. 2018). Noise floor: the same e_t, θ_t of the true X, Y, Z.")

_THRESHOLDS_MM = (0.4, 0.3)  # Wang et al. (2018), Table 3


def agg_pyplot() -> Any:
    """matplotlib.pyplot on the Agg backend (files only, no display); ImportError without
    matplotlib (the ``plot`` extra)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    return plt


def plot_study(study: dict[str, Any], path: str, title: str | None = None) -> None:
    """Figure 3 of Wang et al. (2018): e_t (mm, left) and θ_t (deg, right) against the
    number of poses solved on, one colour per method in both panels (QR24's e_z dashed),
    the 0.4 and 0.3 mm thresholds of their Table 3, the noise floor when the study has one
    (``study["noise_floor"]``), the legend and the metric definitions below the axes."""
    plt = agg_pyplot()
    ns = study["n"]
    fig, axes = plt.subplots(1, 2, figsize=(11, 6.2))
    fig.subplots_adjust(left=0.07, right=0.98, top=0.86, bottom=0.34, wspace=0.22)
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for i, (m, c) in enumerate(study["curves"].items()):
        col = colours[i % len(colours)]
        axes[0].plot(ns, c["e_t_mm"], color=col, lw=1.4, label=f"{m.upper()}: e_t, θ_t")
        if "e_z_mm" in c:
            axes[0].plot(ns, c["e_z_mm"], "--", color=col, lw=1.1,
                         label=f"{m.upper()}: e_z (included in its e_t)")
        axes[1].plot(ns, c["theta_t_deg"], color=col, lw=1.4)
    for t, style in zip(_THRESHOLDS_MM, (":", "-.")):
        axes[0].axhline(t, color="0.35", ls=style, lw=1.0,
                        label=f"{t:g} mm (Wang et al. 2018, Table 3)")
    floor = study.get("noise_floor")
    if floor:
        for ax, key in zip(axes, ("e_t_mm", "theta_t_deg")):
            ax.axhline(floor[key], color="k", ls=(0, (6, 3)), lw=1.0,
                       label="noise floor (true X, Y, Z)" if ax is axes[0] else None)
    _study_axes(plt, axes, ns)
    handles, labels = axes[0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="upper center", bbox_to_anchor=(0.5, 0.225),
               ncol=3, frameon=False, fontsize=9)
    fig.suptitle((title or "convergence") + f"\nhold-out error on {study['n_test']} test "
                 f"poses (those after pose {ns[-1]})", fontsize=11)
    fig.text(0.5, 0.08, textwrap.fill(METRICS_CAPTION, 160), ha="center", va="top",
             fontsize=8)
    fig.savefig(path, dpi=150)
    plt.close(fig)


def _minor_label(v: float, _: Any) -> str:
    """Label the minor log ticks 2, 3 and 5 × 10^k (a panel within one decade keeps labels)."""
    if v <= 0:
        return ""
    lead = round(v / 10 ** np.floor(np.log10(v)))
    return f"{v:.3g}" if lead in (2, 3, 5) else ""


def _study_axes(plt: Any, axes: Any, ns: list[int]) -> None:
    """Labels, log scale with plain tick numbers, and grids for the two study panels."""
    from matplotlib.ticker import FuncFormatter, MaxNLocator

    plain = FuncFormatter(lambda v, _: f"{v:g}")
    for ax, label in zip(axes, ("(a) translation e_t (mm)", "(b) rotation θ_t (deg)")):
        ax.set_xlabel("poses solved on (n)")
        ax.xaxis.set_major_locator(MaxNLocator(integer=True))  # pose counts are whole
        ax.set_ylabel(label)
        ax.set_yscale("log")
        ax.yaxis.set_major_formatter(plain)
        ax.yaxis.set_minor_formatter(FuncFormatter(_minor_label))
        ax.set_xlim(ns[0], ns[-1])
        ax.grid(True, which="major", alpha=0.4)
        ax.grid(True, which="minor", alpha=0.15)


def plot_residuals(res: dict[str, Any], n_solve: int, path: str, title: str,
                   outliers: list[dict[str, Any]] | None = None) -> None:
    """Per-pose translation (mm) and rotation (deg) errors of each body against the session
    pose index (``solving.solve.pose_residuals``), the solve set shaded when only part of
    the poses were solved on; the ``outliers`` (``solving.outliers.find_outliers``) ringed and
    named by pose index, the rule under the axes. PNG."""
    from ..solving.outliers import RULE, outlier_threshold

    plt = agg_pyplot()
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    handles: list[Any] = []
    idx = list(res["index"])
    pos = {p: i for i, p in enumerate(idx)}
    fig, axes = plt.subplots(2, 1, figsize=(10, 6.5), sharex=True, layout="constrained")
    for body in ("marker", "probe"):
        if body in res:
            for ax, key in zip(axes, ("trans_mm", "rot_deg")):
                (dots,) = ax.plot(idx, res[body][key], ".", ms=3)
                thr = outlier_threshold(res[body][key])
                if np.isfinite(thr):
                    ax.axhline(thr, color=dots.get_color(), ls=":", lw=0.9)
            handles.append(Line2D([], [], ls="", marker=".", ms=9, color=dots.get_color(),
                                  label=body))
            handles.append(Line2D([], [], ls=":", color=dots.get_color(),
                                  label=f"{body} outlier threshold"))
    if n_solve < len(idx):
        for ax in axes:
            ax.axvspan(idx[0], idx[n_solve - 1], color="0.9", zorder=0)
        handles.append(Patch(color="0.9", label="poses solved on"))
    keys = {"translation": (0, "trans_mm"), "rotation": (1, "rot_deg")}
    for o in outliers or []:
        for f in o["flags"]:
            row, key = keys[f["metric"]]
            y = res[f["body"]][key][pos[o["index"]]]
            axes[row].plot([o["index"]], [y], "o", mfc="none", mec="red", ms=9, mew=1.3)
            axes[row].annotate(f"pose {o['index']}", (o["index"], y), xytext=(6, 4),
                               textcoords="offset points", color="red", fontsize=8)
    for ax, unit in zip(axes, ("translation error e (mm)", "rotation error θ (deg)")):
        ax.set_ylabel(unit)
        ax.margins(y=0.15)
        ax.set_ylim(bottom=0)
        ax.grid(True, alpha=0.3)
    axes[1].set_xlabel("session pose index")
    from matplotlib.ticker import MaxNLocator
    axes[1].xaxis.set_major_locator(MaxNLocator(integer=True))  # pose indices are whole
    if outliers:
        handles.append(Line2D([], [], ls="", marker="o", mfc="none", mec="red", ms=8,
                              label="outlier pose"))
    fig.legend(handles=handles, loc="outside right upper", frameon=False, fontsize=9)
    names = ", ".join(str(o["index"]) for o in outliers or []) or "none"
    fig.suptitle(f"{title}\noutlier poses (session pose index): {names}", fontsize=11)
    caption = ("Per pose: E = (AX)⁻¹ZB (marker), (AY)⁻¹ZC (probe); e = ‖t(E⊥)‖, θ = rotation "
               f"angle of E⊥ (docs/methods.md). Outlier rule: {RULE}.")
    fig.text(0.5, 0.0, textwrap.fill(caption, 140), ha="center", va="top", fontsize=8)
    fig.savefig(path, dpi=150, bbox_inches="tight")
    plt.close(fig)


def _curve(ax: Any, ns: list[int], d: dict[str, list[float]], col: str, label: str | None
           ) -> None:
    """A mean curve with its ±SD band (NaNs leave gaps)."""
    mean = np.asarray(d["mean"], dtype=float)
    sd = np.asarray(d.get("sd") or [np.nan] * len(mean), dtype=float)
    ax.plot(ns, mean, "o-", color=col, lw=1.4, ms=3.5, label=label)
    ok = np.isfinite(sd)
    if ok.any():
        ax.fill_between(np.asarray(ns)[ok], (mean - sd)[ok], (mean + sd)[ok], color=col,
                        alpha=0.15, lw=0)


def plot_compare(res: dict[str, Any], paths: dict[str, str], title: str | None = None
                 ) -> None:
    """The figures of ``tmscal compare`` (``solving.compare.compare_arrays``), as Figure 2 of the
    Panda/Vicra TMS study: ``paths["errors"]``: held-out position e_t (mm) and orientation
    θ_t (deg) against n; ``paths["time"]``: solve time (ms) against n; ``paths["truth"]``
    (only with a truth): the ground-truth translation error of Y (X when marker-only) and the
    bound when there is one. One colour per method, mean ± SD over folds as a band."""
    plt = agg_pyplot()
    ns = res["ns"]
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    col = {m: colours[i % len(colours)] for i, m in enumerate(res["methods"])}
    head = (title or "comparison") + f": {res['n_poses']} poses, {res['folds']} folds"
    fig, axes = plt.subplots(1, 2, figsize=(11, 5), layout="constrained")
    for m, r in res["methods"].items():
        for ax, key in zip(axes, ("e_t_mm", "theta_t_deg")):
            if key in r:
                _curve(ax, ns, r[key], col[m], m.upper() if ax is axes[0] else None)
    for ax, lab in zip(axes, ("(a) position error e_t (mm)", "(b) orientation error θ_t "
                                                                "(deg)")):
        _compare_axes(ax, lab, ns)
    fig.legend(loc="outside lower center", ncol=max(1, len(res["methods"])), frameon=False)
    fig.suptitle(head + "\nheld-out error, mean ± SD over folds (docs/methods.md)",
                 fontsize=11)
    fig.savefig(paths["errors"], dpi=150)
    plt.close(fig)
    fig, ax = plt.subplots(figsize=(6.5, 4.8), layout="constrained")
    for m, r in res["methods"].items():
        if "time_ms" in r:
            _curve(ax, ns, r["time_ms"], col[m], m.upper())
    _compare_axes(ax, "solve time (ms)", ns)
    ax.legend(frameon=False, fontsize=9)
    ax.set_title(head + "\nwall time per solve, mean ± SD over folds", fontsize=10)
    fig.savefig(paths["time"], dpi=150)
    plt.close(fig)
    if res["truth"] and "truth" in paths:
        _plot_compare_truth(plt, res, paths["truth"], col, head)


def _plot_compare_truth(plt: Any, res: dict[str, Any], path: str, col: dict[str, str],
                        head: str) -> None:
    ns = res["ns"]
    key = "Y_trans_mm" if "probe" in res["bodies"] else "X_trans_mm"
    fig, ax = plt.subplots(figsize=(6.5, 4.8), layout="constrained")
    for m, r in res["methods"].items():
        t = r.get("truth", {})
        if key in t:
            _curve(ax, ns, t[key], col[m], m.upper())
    bound = res.get("bound") or {}
    if key in bound:
        ax.plot(ns, bound[key], "k--", lw=1.2, label="Cramér–Rao bound (RMS)")
    _compare_axes(ax, f"error of {key[0]}'s translation against the truth (mm)", ns)
    ax.legend(frameon=False, fontsize=9)
    ax.set_title(head + "\nground-truth error, mean ± SD over folds", fontsize=10)
    fig.savefig(path, dpi=150)
    plt.close(fig)


def _compare_axes(ax: Any, label: str, ns: list[int]) -> None:
    from matplotlib.ticker import FuncFormatter

    plain = FuncFormatter(lambda v, _: f"{v:g}")
    ax.set_xlabel("poses solved on (n)")
    ax.set_ylabel(label)
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.xaxis.set_major_formatter(plain)
    ax.yaxis.set_major_formatter(plain)
    ax.yaxis.set_minor_formatter(FuncFormatter(_minor_label))
    ax.set_xticks(ns)
    ax.grid(True, which="major", alpha=0.4)
    ax.grid(True, which="minor", alpha=0.15)
