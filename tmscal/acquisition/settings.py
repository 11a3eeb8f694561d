"""The sampling settings of a run (``SamplingSettings``): the config's ``sampling`` section
for a new run, the session header's on ``--resume`` (so every pose of a session is sampled
alike), the command line over both. Times in s, distances in mm; see docs/configs.md and
docs/session-format.md.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from ..config import SETTLE_MODES, RigConfig

__all__ = ["SamplingSettings", "sampling_settings"]


@dataclass
class SamplingSettings:
    """The sampling settings of a run: from the config for a new run; on ``--resume`` from
    the session header unless overridden on the command line (``notes`` says which).
    ``settle`` … ``sem_mm`` are ``sample_pose``'s settling and samples-by-need options."""

    samples: int
    settle_s: float
    min_share: float
    robot_reads: int
    max_frames_factor: float
    notes: list[str]
    settle: str = "still"
    still_window_s: float = 0.2
    still_tol_mm: float | None = None
    min_samples: int = 10
    sem_mm: float | None = None

    def to_header(self) -> dict[str, Any]:
        return {"samples": self.samples, "settle_s": self.settle_s,
                "min_share": self.min_share, "robot_reads": self.robot_reads,
                "settle": self.settle, "still_window_s": self.still_window_s,
                "still_tol_mm": self.still_tol_mm, "min_samples": self.min_samples,
                "sem_mm": self.sem_mm}


_COUNTS = ("samples", "robot_reads", "min_samples")
_OPTIONAL_MM = ("still_tol_mm", "sem_mm")


def _header_value(k: str, v: Any) -> tuple[bool, Any]:
    """(usable, value) for sampling key ``k`` as a session header records it; a value the
    config would refuse is not usable (the config's is kept)."""
    if k == "settle":
        return v in SETTLE_MODES, v
    if v is None:
        return k in _OPTIONAL_MM, None
    if isinstance(v, bool) or not isinstance(v, int | float):
        return False, v
    if k in _COUNTS:
        return float(v).is_integer() and v >= 1, int(v)
    if k in ("settle_s", "min_share"):
        return 0 <= v < float("inf"), float(v)
    return 0 < v < float("inf"), float(v)


def _show(v: Any) -> str:
    return f"{v:g}" if isinstance(v, int | float) and not isinstance(v, bool) else str(v)


def sampling_settings(cfg: RigConfig, header: dict[str, Any] | None, samples: int | None
              ) -> SamplingSettings:
    """Sampling settings: the config's for a new run (``header`` None); the header's on a
    resume, so that every pose of a session is sampled alike (a header from before settling
    by stillness and samples by need has no ``settle``: its poses waited settle_s and took
    every sample, and so do the resumed ones); ``samples`` overrides both."""
    c = cfg.sampling
    vals: dict[str, Any] = {"samples": c.samples, "settle_s": c.settle_s,
                            "min_share": c.min_share, "robot_reads": c.robot_reads,
                            "settle": c.settle, "still_window_s": c.still_window_s,
                            "still_tol_mm": c.still_tol_mm, "min_samples": c.min_samples,
                            "sem_mm": c.sem_mm}
    notes: list[str] = []
    recorded = (header or {}).get("sampling")
    if isinstance(recorded, dict):
        if "settle" not in recorded:
            if (c.settle, c.sem_mm) != ("fixed", None):
                notes.append("a fixed settle_s and every sample, as the session was recorded "
                             "(before settling by stillness and samples by need)")
            vals.update(settle="fixed", sem_mm=None)
        for k, v in recorded.items():
            usable, v = _header_value(k, v) if k in vals else (False, v)
            if not usable:
                continue
            if v != vals[k]:
                notes.append(f"sampling.{k} {_show(v)} as recorded in the session "
                             f"(the config says {_show(vals[k])})")
            vals[k] = v
    if samples is not None and samples != vals["samples"]:
        if header is not None:
            notes.append(f"samples {samples} from the command line (the session was "
                         f"recorded with {vals['samples']})")
        vals["samples"] = int(samples)
    return SamplingSettings(max_frames_factor=c.max_frames_factor, notes=notes, **vals)
