"""The ATI Net F/T's config (``ft: {driver: ati, ...}``): the sensor calibration's counts per
unit, which the driver needs and has no default for, and ``ATINetFT``'s options
(docs/configs.md, docs/devices.md "ATI Net F/T")."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar, Self

from ...config.settings import FTSettings, Option
from ...config.values import err, positive

__all__ = ["ATISettings"]


@dataclass(frozen=True)
class ATISettings(FTSettings):
    """An ATI Net F/T: ``counts_per_force`` (counts per N) and ``counts_per_torque`` (counts
    per N·m), the calibration's ``cfgcpf``/``cfgcpt`` (its web page or ``netftapi2.xml``);
    both required, a wrong value scales every reading. Options: ``timeout_s`` (the longest
    wait for a record, s) and ``max_lost_share`` (the share of records that may be lost in
    one read)."""

    KEYS: ClassVar[tuple[str, ...]] = ("counts_per_force", "counts_per_torque")
    OPTIONS: ClassVar[Mapping[str, Option]] = {
        "timeout_s": Option(float, above=0, hi=3600, default=1.0, unit="s",
                            help="the longest wait for a record"),
        "max_lost_share": Option(float, lo=0, below=1, default=0.05,
                                 help="the share of records one read may lose"),
    }

    counts_per_force: float | None = None
    counts_per_torque: float | None = None

    @classmethod
    def parse(cls, section: Mapping[str, Any], src: str, base_dir: Path | None,
              check_files: bool) -> Self:
        """Both counts given, > 0 and plausible (≤ 1e12)."""
        s = super().parse(section, src, base_dir, check_files)
        for key in cls.KEYS:
            v = getattr(s, key)
            if v is None:
                raise err(src, f"ft.{key}", "driver 'ati' needs the sensor calibration's "
                          "counts per unit (its web page or netftapi2.xml: cfgcpf per N, "
                          "cfgcpt per N·m); there is no default")
            positive(src, f"ft.{key}", v, at_most=1e12)
        return s

    def mock_kwargs(self) -> dict[str, Any]:
        """The counts per unit the mock scales its records by (the driver's)."""
        return self.kwargs()
