"""Kinematic self-calibration from a wrist force-torque sensor (Joubair, Zhao, Bigras and Bonev
2016): the arm model and its gravity wrench (:mod:`.model`), identifiability and identification
(:mod:`.identify`), pose selection (:mod:`.design`) and the simulation study (:mod:`.simulate`).
Pure numerics, no I/O; docs/selfcal.md."""

from .identify import Fit, Identifiability, error_stats, identifiable, identify, position_errors
from .model import G_STANDARD, NOMINAL, UR5E, VS060, ArmModel, forward, jacobian, perturb, wrench

__all__ = ["ArmModel", "G_STANDARD", "NOMINAL", "UR5E", "VS060", "forward", "wrench",
           "jacobian", "perturb", "Identifiability", "identifiable", "Fit", "identify",
           "position_errors", "error_stats"]
