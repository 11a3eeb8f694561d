"""The sim rig's ground truth: X = flange_from_marker, Y = flange_from_probe, Z =
base_from_tracker (4×4 mm) and the rig's serial arm (``tmscal.sim.arm``), as ``SimRig``
serves it, ``tmscal.sim.changes`` changes it and session headers store it
(docs/session-format.md, "truth")."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from ..geometry import make_pose, random_rotation

if TYPE_CHECKING:
    from .arm import ArmPair

__all__ = ["Truth"]


@dataclass(frozen=True)
class Truth:
    """Ground truth: X = flange_from_marker, Y = flange_from_probe (None for a marker-only
    rig), Z = base_from_tracker; 4×4 mm. ``arm``: the rig's serial arm (an
    :class:`~tmscal.sim.arm.ArmPair`: the controller's nominal model, the true one, the mount;
    None: the rig has none, its robot is kinematically perfect)."""

    X: np.ndarray
    Z: np.ndarray
    Y: np.ndarray | None = None
    arm: ArmPair | None = None

    def flange_from(self, body: str) -> np.ndarray:
        """flange_from_<body>, 4×4 mm, for body "marker" (X) or "probe" (Y)."""
        if body == "marker":
            return self.X
        if body == "probe" and self.Y is not None:
            return self.Y
        raise KeyError(f"the rig has no body {body!r}")

    def as_dict(self) -> dict[str, Any]:
        """{"X", "Z"[, "Y"]} as nested lists (mm), and "arm" (``ArmPair.as_dict``: the arm's
        name, error protocol, nominal and true geometry, mount) when the rig has one, for
        session headers (docs/session-format.md)."""
        d: dict[str, Any] = {"X": self.X.tolist(), "Z": self.Z.tolist()}
        if self.Y is not None:
            d["Y"] = self.Y.tolist()
        if self.arm is not None:
            d["arm"] = self.arm.as_dict()
        return d

    @classmethod
    def random(cls, rng: np.random.Generator, with_probe: bool = True) -> Truth:
        """The truth of Wang et al. (2018): random rotations; t(X), t(Y) entries uniform in
        [−50, 50] mm; t(Z) entries of magnitude uniform in [500, 2000] mm with random sign."""
        def rnd_small() -> np.ndarray:
            return make_pose(random_rotation(rng), rng.uniform(-50, 50, 3))
        X = rnd_small()
        Y = rnd_small() if with_probe else None
        tz = rng.uniform(500, 2000, 3) * rng.choice([-1.0, 1.0], 3)
        Z = make_pose(random_rotation(rng), tz)
        return cls(X=X, Z=Z, Y=Y)
