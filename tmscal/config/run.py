"""How a run goes: the ``sampling`` section (what is recorded at each pose), the ``run``
section (device faults and skipped poses) and the ``adaptive`` section (when an adaptive
acquisition stops). Times in s, lengths in mm."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from ..calib.prediction import AdaptiveSettings

from .sections import RunConfig, SamplingConfig
from .values import build, err, in_range, positive, show

__all__ = ["SETTLE_MODES", "parse_sampling", "parse_run", "parse_adaptive",
           "check_sampling"]


#: sampling.settle: wait for stillness (bounded by settle_s) or a fixed settle_s
SETTLE_MODES = ("still", "fixed")


def check_sampling(s: Any, src: str, floor_within_cap: bool = True) -> None:
    """The ``sampling`` section's ranges (a ``SamplingConfig``), each violation a ConfigError
    naming the key: counts, times and tolerances finite and in a sensible range; with
    ``sem_mm`` and ``floor_within_cap``, the floor ``min_samples`` is not above the cap
    ``samples``. The one check of the sampling settings: the config's, and ``sample_pose``'s
    (without ``floor_within_cap``: a ``--samples`` below the config's floor caps it)."""
    in_range(src, "sampling.samples", s.samples, 1, 1_000_000)
    positive(src, "sampling.settle_s", s.settle_s, allow_zero=True, at_most=3600.0)
    in_range(src, "sampling.robot_reads", s.robot_reads, 1, 1_000_000)
    if not 0 < s.min_share <= 1:
        raise err(src, "sampling.min_share", f"must be in (0, 1], got {s.min_share}")
    positive(src, "sampling.max_frames_factor", s.max_frames_factor, at_most=1000.0)
    if s.settle not in SETTLE_MODES:
        raise err(src, "sampling.settle", f"expected 'still' (wait until the tools are "
                  f"still, at most settle_s) or 'fixed' (wait settle_s), got {show(s.settle)}")
    positive(src, "sampling.still_window_s", s.still_window_s, at_most=60.0)
    if s.still_tol_mm is not None:
        positive(src, "sampling.still_tol_mm", s.still_tol_mm, at_most=10.0)
    in_range(src, "sampling.min_samples", s.min_samples, 1, 1_000_000)
    if s.sem_mm is not None:
        positive(src, "sampling.sem_mm", s.sem_mm, at_most=10.0)
        if floor_within_cap and s.min_samples > s.samples:
            raise err(src, "sampling.min_samples", f"{s.min_samples} is above samples "
                      f"{s.samples} (the floor of samples by need is above their cap)")


def parse_sampling(data: Any, src: str) -> SamplingConfig:
    """The sampling section: counts, settling, usable share, frame budget, samples by need."""
    sampling = build(SamplingConfig, data, src, "sampling")
    check_sampling(sampling, src)
    return sampling


def parse_run(data: Any, src: str) -> RunConfig:
    """The run section: reconnect attempts and the wait between them; the skip shares that
    warn and stop (in [0, 1], warn ≤ stop) and the window they are counted over (poses)."""
    run = build(RunConfig, data, src, "run")
    in_range(src, "run.retries", run.retries, 0, 1000)
    positive(src, "run.reconnect_wait_s", run.reconnect_wait_s, allow_zero=True,
             at_most=3600.0)
    in_range(src, "run.skip_window", run.skip_window, 1, 100_000)
    for key in ("warn_skip_share", "stop_skip_share"):
        v = getattr(run, key)
        if not 0 <= v <= 1:
            raise err(src, f"run.{key}", f"must be in [0, 1], got {v}")
    if run.warn_skip_share > run.stop_skip_share:
        raise err(src, "run.warn_skip_share", f"{run.warn_skip_share} is above "
                  f"run.stop_skip_share {run.stop_skip_share}: the warning must come first")
    return run


def parse_adaptive(data: Any, src: str) -> AdaptiveSettings:
    """The adaptive section (defaults when absent) as the one ``AdaptiveSettings`` dataclass,
    which checks its own ranges; a ConfigError names ``adaptive.<field>``."""
    from ..calib.prediction import AdaptiveSettings  # numerics: imported when a config is built

    return build(AdaptiveSettings, data, src, "adaptive")
