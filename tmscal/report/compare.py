"""The table of ``tmscal compare`` (docs/methods.md, "Comparing the methods"): the result of
:func:`tmscal.solving.compare.compare_arrays` as text, one block per pose count, one row per
method. Units: mm, degrees and ms, named in the column headers.
"""

from __future__ import annotations

import textwrap
from typing import Any

import numpy as np

from ..solving.compare import handheld_options

__all__ = ["format_compare"]


def _pm(mean: float, sd: float, w: int = 18, digits: int = 4) -> str:
    if not np.isfinite(mean):
        return f"{'—':>{w}}"
    s = f"{mean:.{digits}f}" + (f" ± {sd:.{digits}f}" if np.isfinite(sd) else "")
    return f"{s:>{w}}"


def format_compare(res: dict[str, Any]) -> str:
    """The ``tmscal compare`` table: one block per n, one row per method (held-out e_t, θ_t
    mean ± SD over folds, solve time; with truth the mean ground-truth error of Y's (or, on a
    marker-only session, X's) translation and the coil placement error, and the bound)."""
    where = res.get("session", "the poses")
    sizes = sorted({min(res["fold_sizes"]), max(res["fold_sizes"])})
    intro = (f"method comparison on {where}: {res['n_poses']} poses, {res['folds']} contiguous "
             f"folds of {'–'.join(map(str, sizes))} poses; for each n, each method is solved "
             "on the first n poses outside a fold and tested on the fold. Mean ± SD over "
             "folds; e_t, θ_t: hold-out errors (marker + probe, + e_z for QR24; "
             "docs/methods.md); time: wall time per solve.")
    lines = textwrap.wrap(intro, 98, subsequent_indent="  ") + [""]
    tkey = "Y_trans_mm" if "probe" in res["bodies"] else "X_trans_mm"
    head = (f"  {'n':>4}  {'method':<9}{'e_t mm':>18}{'θ_t deg':>18}{'time ms':>20}")
    if res["truth"]:
        head += f"{'truth ' + tkey[0] + ' mm':>14}" + (
            f"{'coil mm':>10}" if "probe" in res["bodies"] else "")
    bound = res.get("bound")
    bkey = _bound_key(bound, tkey)
    lines.append(head)
    for i, n in enumerate(res["ns"]):
        for m, r in res["methods"].items():
            row = f"  {n:>4}  {m:<9}"
            for k in ("e_t_mm", "theta_t_deg", "time_ms"):
                d = r.get(k, {"mean": [float("nan")] * len(res["ns"]), "sd": []})
                row += _pm(d["mean"][i], d["sd"][i] if d["sd"] else float("nan"),
                           w=20 if k == "time_ms" else 18, digits=2 if k == "time_ms" else 4)
            if res["truth"]:
                t = r.get("truth", {})
                row += _cell(t, tkey, i, 14)
                if "probe" in res["bodies"]:
                    row += _cell(t, "coil_placement_mm", i, 10)
            if n in r.get("failed", {}):
                row += "  (failed on some folds)"
            lines.append(row)
        if bkey and bound:  # a bound key only comes with a bound (_bound_key)
            lines.append(f"  {n:>4}  {'bound':<9}{'':>56}{bound[bkey][i]:>14.4f}")
        lines.append("")
    if any("handheld_B" in handheld_options(m, np.eye(4)[None], np.eye(4)[None])
           for m in res["methods"]):
        lines += textwrap.wrap("handheld: Y from the first training pose's marker and probe "
                               "(one measurement with the probe at the coil centre)", 98,
                               initial_indent="  ", subsequent_indent="    ")
    for m, why in res["skipped"].items():
        lines += textwrap.wrap(f"skipped {m}: {why}", 98, initial_indent="  ",
                               subsequent_indent="    ")
    if res["truth"]:
        notes = [f"truth: the mean error of the solved {tkey[0]}'s translation against the "
                 "session's truth"
                 + ("; coil: the coil placement error (mm) on the fold's targets"
                    if "probe" in res["bodies"] else ""),
                 "bound: " + (f"the Cramér–Rao bound of the RMS error of {tkey[0]}'s "
                              "translation (the best any unbiased method can do), on the "
                              "first fold's training poses, in the truth column" if bkey else
                              "no Cramér–Rao bound (needs tmscal.calib.bound and a session "
                              "from tmscal simulate, whose header gives the noise)")]
        lines += [w for ln in notes for w in textwrap.wrap(ln, 98, initial_indent="  ",
                                                           subsequent_indent="    ")]
    return "\n".join(lines).rstrip()


def _cell(t: dict[str, Any], key: str, i: int, w: int) -> str:
    v = t.get(key, {}).get("mean", [])
    return f"{v[i]:>{w}.4f}" if v and np.isfinite(v[i]) else f"{'—':>{w}}"


def _bound_key(bound: dict[str, Any] | None, tkey: str) -> str | None:
    """The bound's entry for the translation shown in the truth column, if it has one."""
    return tkey if bound and tkey in bound else None
