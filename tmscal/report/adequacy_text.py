"""The adequacy warning of ``tmscal solve`` (docs/adequacy.md): nothing when the rigid
model explains the session, else what is wrong, the statistic and the command that fixes
it. The verdict comes from :mod:`tmscal.solving.adequacy` (``SolveResult.adequacy``)."""

from __future__ import annotations

import textwrap
from typing import Any

from ..escape import visible

__all__ = ["adequacy_text"]


def _wrap(text: str, first: str, rest: str) -> list[str]:
    return textwrap.wrap(visible(text), 92, initial_indent=first, subsequent_indent=rest)


def adequacy_text(adequacy: dict[str, Any] | None) -> str:
    """The warning lines for an inadequate verdict (``SolveResult.adequacy``), "" for an
    adequate one or none: the likely cause (``message``), the variance ratio
    (``chi2_per_dof``) and adjusted p-value, the ``fix``, and the other rules that fired."""
    if not adequacy or adequacy.get("verdict") != "inadequate":
        return ""
    cause = adequacy.get("likely_cause")
    ratio = adequacy.get("chi2_per_dof")
    stat = (f"residual variance {ratio:.3g}× the noise its model leaves, " if ratio else "")
    lines = _wrap("WARNING: the rigid hand/eye model does not explain this session; do not "
                  "use the calibration until this is fixed (docs/adequacy.md)", "", "  ")
    lines += _wrap(f"likely cause: {adequacy.get('message') or cause} "
                   f"({stat}p = {adequacy.get('p_value', 0):.2g} after Bonferroni over "
                   f"{len(adequacy.get('rules', []))} rules)", "  ", "    ")
    if adequacy.get("fix"):
        lines += _wrap(f"fix: {adequacy['fix']}", "  ", "    ")
    alpha = float((adequacy.get("test") or {}).get("alpha", 0.01))
    also = [r["cause"] for r in adequacy.get("rules", [])
            if r.get("cause") != cause and float(r.get("p_adjusted", 1.0)) < alpha]
    if also:
        lines += _wrap("also significant (often a consequence of the first): "
                       + ", ".join(also), "  ", "    ")
    return "\n".join(lines)
