"""The simulation of Wang et al. (2018) (docs/methods.md): a truth, a plan of robot poses and
noisy observations from a :class:`~tmscal.sim.rig.SimRig`, for ``tmscal simulate``."""

from __future__ import annotations

import numpy as np

from .rig import Noise, SimRig, Truth, facing_start


def simulate(n: int, rng: np.random.Generator, plan: str = "eq14", noise: Noise | None = None,
             truth: Truth | None = None, samples: int = 1, with_probe: bool = True,
             radius_mm: float | None = None, rotation_deg: float = 10.0
             ) -> tuple[Truth, dict[str, np.ndarray]]:
    """The simulation of Wang et al. (2018): a truth (random unless given), n poses by ``plan``
    ("random": fully random robot poses; "eq14": Eq. 14 around a P0 facing the tracker), and noisy
    observations, ``samples`` of them averaged per pose (chordal mean).

    Returns (truth, {"A", "commanded", "marker", ["probe"]}) with (n, 4, 4) mm arrays.
    """
    from ..geometry import pose_mean
    from ..poses import eq14_poses, random_poses

    truth = truth or Truth.random(rng, with_probe=with_probe)
    if plan == "random":
        P = random_poses(n, rng, r_mm=500.0 if radius_mm is None else radius_mm)
    elif plan == "eq14":
        P = eq14_poses(facing_start(truth), n, rng, r_mm=100.0 if radius_mm is None
                       else radius_mm, d_deg=rotation_deg)
    else:
        raise ValueError(f"unknown plan {plan!r}; expected 'random' or 'eq14'")
    rig = SimRig(truth, noise=noise or Noise(), rng=rng)
    out: dict[str, np.ndarray] = {"commanded": P, "A": np.empty_like(P)}
    for b in rig.bodies:
        out[b] = np.empty_like(P)
    for i, cmd in enumerate(P):
        rig.move_flange(cmd)
        out["A"][i] = rig.reported_flange()
        for b in rig.bodies:
            out[b][i] = rig.observe(b) if samples == 1 else pose_mean(rig.observe(b, samples))
    return truth, out
