"""What an optical tracker sees of the sim rig's bodies, for every tracker mock (the NDI
Polaris, the OpenIGTLink tracker): one noisy observation per frame, and whether the body's
marker spheres are inside the measurement volume."""

from __future__ import annotations

from enum import StrEnum
from typing import Protocol

import numpy as np

from ..sim.rig import SimRig

__all__ = ["BodyObserver", "Visibility", "Volume"]

#: observations drawn from the rig at once per body (each frame takes one)
_OBS_BATCH = 32


class Volume(Protocol):
    """A measurement volume: which points (k, 3), tracker coordinates in mm, are inside."""

    def contains(self, points_mm: np.ndarray) -> np.ndarray: ...


class Visibility(StrEnum):
    """A body against the measurement volume: all spheres inside, some, or none."""

    INSIDE = "inside"
    PARTIAL = "partial"
    OUTSIDE = "outside"


class BodyObserver:
    """Observations of ``rig``'s bodies (tracker_from_body, 4×4 mm) and their visibility in
    ``volume`` (None: unlimited)."""

    def __init__(self, rig: SimRig, volume: Volume | None) -> None:
        self.rig = rig
        self.volume = volume
        self._cache: dict[str, tuple[np.ndarray, list[np.ndarray]]] = {}

    def forget(self) -> None:
        """Drop the observations drawn but not used yet."""
        self._cache = {}

    def observe(self, body: str) -> np.ndarray:
        """One noisy ``rig.observe(body)`` (tracker_from_body, 4×4 mm). Observations are
        drawn from the rig in batches of ``_OBS_BATCH`` at the current true pose and used one
        per frame; a batch is discarded as soon as the true pose changes (the robot moved),
        so each frame still gets an independent observation of where the body is now."""
        true = self.rig.true_body(body)
        cached = self._cache.get(body)
        if cached is None or not np.array_equal(cached[0], true) or not cached[1]:
            batch = self.rig.observe(body, _OBS_BATCH)
            cached = (true, list(batch[::-1]))
            self._cache[body] = cached
        return cached[1].pop()

    def visibility(self, body: str, pose: np.ndarray) -> Visibility:
        """``body`` at ``pose`` (tracker_from_body, mm) against the volume: its marker
        spheres (the rig's tool geometry; its origin when it has none) all inside, some, or
        none."""
        if self.volume is None:
            return Visibility.INSIDE
        spheres = np.asarray((self.rig.tools or {}).get(body, np.zeros((1, 3))))
        inside = self.volume.contains(spheres @ pose[:3, :3].T + pose[:3, 3])
        if not inside.any():
            return Visibility.OUTSIDE
        return Visibility.INSIDE if inside.all() else Visibility.PARTIAL
