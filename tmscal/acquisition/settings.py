"""The sampling settings of a run (``SamplingSettings``): the config's ``sampling`` section
for a new run, the session header's on ``--resume`` (so every pose of a session is sampled
alike), the command line over both. Times in s, distances in mm; see docs/configs.md and
docs/session-format.md.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any

from ..config import RigConfig, SamplingConfig
from ..config.run import check_sampling
from ..errors import ConfigError

__all__ = ["SamplingSettings", "sampling_settings"]


@dataclass
class SamplingSettings(SamplingConfig):
    """The sampling settings of a run (the fields of ``SamplingConfig``, declared there
    once; ``sample_pose`` takes them as they are): from the config for a new run; on
    ``--resume`` from the session header unless overridden on the command line (``notes``
    says which)."""

    notes: list[str] = field(default_factory=list)


_COUNTS = ("samples", "robot_reads", "min_samples")
_OPTIONAL_MM = ("still_tol_mm", "sem_mm")


def _header_value(k: str, v: Any) -> tuple[bool, Any]:
    """(usable, value) for sampling key ``k`` as a session header records it: of the key's
    type (a count a whole number) and within the config's ranges (``check_sampling``, the
    one check of them); a value the config would refuse is not usable (the config's is
    kept)."""
    if v is None:
        if k not in _OPTIONAL_MM:
            return False, v
    elif k == "settle":
        if not isinstance(v, str):
            return False, v
    elif isinstance(v, bool) or not isinstance(v, int | float):
        return False, v
    elif k in _COUNTS:
        if not float(v).is_integer():
            return False, v
        v = int(v)
    else:
        v = float(v)
    try:
        check_sampling(replace(SamplingConfig(), **{k: v}), "header", floor_within_cap=False)
    except ConfigError:
        return False, v
    return True, v


def _show(v: Any) -> str:
    return f"{v:g}" if isinstance(v, int | float) and not isinstance(v, bool) else str(v)


def sampling_settings(cfg: RigConfig, header: dict[str, Any] | None, samples: int | None
              ) -> SamplingSettings:
    """Sampling settings: the config's for a new run (``header`` None); the header's on a
    resume, so that every pose of a session is sampled alike (a header from before settling
    by stillness and samples by need has no ``settle``: its poses waited settle_s and took
    every sample, and so do the resumed ones); ``samples`` overrides both."""
    c = cfg.sampling
    vals: dict[str, Any] = c.values()
    notes: list[str] = []
    recorded = (header or {}).get("sampling")
    if isinstance(recorded, dict):
        if "settle" not in recorded:
            if (c.settle, c.sem_mm) != ("fixed", None):
                notes.append("a fixed settle_s and every sample, as the session was recorded "
                             "(before settling by stillness and samples by need)")
            vals.update(settle="fixed", sem_mm=None)
        for k, v in recorded.items():
            usable, v = (_header_value(k, v) if k in SamplingConfig.HEADER_KEYS
                         else (False, v))
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
    return SamplingSettings(notes=notes, **vals)
