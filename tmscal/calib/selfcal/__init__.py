"""Kinematic self-calibration from a wrist force-torque sensor (Joubair, Zhao, Bigras and Bonev
2016): the arm model with its sensor and the gravity wrench (:mod:`.model`), the identification
of a session's arm by the one kinematic estimator with wrench rows (:mod:`.estimate`), the
paper's column-selection identifiability and identification (:mod:`.identify`), pose selection
(:mod:`.design`); the paper's simulation study apart, in :mod:`.study`. Pure numerics, no I/O;
docs/selfcal.md."""

from .identify import Fit, Identifiability, error_stats, identifiable, identify, position_errors
from .model import G_STANDARD, NOMINAL, UR5E, VS060, ArmModel, forward, jacobian, perturb, wrench

__all__ = ["ArmModel", "G_STANDARD", "NOMINAL", "UR5E", "VS060", "forward", "wrench",
           "jacobian", "perturb", "Identifiability", "identifiable", "Fit", "identify",
           "position_errors", "error_stats"]
