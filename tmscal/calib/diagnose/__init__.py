"""What moved since a calibration, and the re-registration of only that (docs/lab-day.md).

The package: :mod:`.model` (the frames, residuals, noise model and the blocks' rigid
changes), :mod:`.fitting` (one hypothesis by maximum likelihood), :mod:`.noise` (the noise model
from a calibration's data), :mod:`.decision` (which hypothesis), :mod:`.updating` (the partial
re-registration and its refusal).

A stored calibration (X = flange_from_marker, Y = flange_from_probe, Z = base_from_tracker;
4×4 mm) is held against a new session's poses (A = base_from_flange, B = tracker_from_marker,
C = tracker_from_probe). Each pose and body gives the residual E = (A X)⁻¹ Z N, written as
six numbers r = [t(E) mm; rotation vector of E in degrees]; the calibration's **noise model**
(:class:`NoiseModel`, the covariance Σ of r over the poses it was solved on) whitens them.

The hypotheses, each one rigid change Δ = [R(ω) v; 0 1] (v mm, ω a rotation vector) or, for
the arm, joint offsets δ (rad), fitted by maximum likelihood (whitened least squares,
Levenberg–Marquardt from a closed-form start) with everything else fixed:

======================  ========  =======================================================
hypothesis              block     model
======================  ========  =======================================================
``tracker`` moved       ``z``     Z' = Z Δ (Δ in the tracker's frame; every pose, both bodies)
``coil`` re-seated      ``coil``  X' = Δ X, Y' = Δ Y (one flange-frame Δ for both bodies)
``marker`` moved        ``x``     X' = X Δ (the marker on the coil; the probe untouched)
``coil_centre`` changed ``y``     Y' = Y Δ (e.g. another coil; the marker untouched)
``arm`` changed         ``arm``   A' = fk(q + δ) (only where joints and an arm model are known)
======================  ========  =======================================================

The decision (:func:`diagnose`): each hypothesis is nested in "nothing changed", so each is
tested against it with the F test of the extra sum of squares (the scale of the noise
estimated from today's residuals, so that a noisier or quieter day than the calibration's
does not pass for a change; Bonferroni over the hypotheses, family level ``ALPHA``). Among the
significant ones the winner has the smallest AICc, Akaike's criterion with the small-sample
correction of Hurvich & Tsai (1989) — 10 poses of 12 numbers and 6 parameters are few enough
that the plain AIC would favour larger models; hypotheses of equal size are then ranked by
their likelihood alone. The runner-up's evidence ratio is exp(ΔAICc / 2). "unexplained" when
the winner leaves residuals beyond ``ALLOWANCE``× the stored noise (χ², 99.9 %) or a second
change on top of it is significant (the pair is named). :func:`update` fits only the named
blocks and refuses (:class:`UpdateRefused`) when either holds, so that an update never
absorbs a second change silently.
"""

from .decision import (
    Diagnosis,
    diagnose,
)
from .fitting import (
    Fit,
    fit,
)
from .model import (
    ALLOWANCE,
    ALPHA,
    BLOCK_OF,
    CHI2_LEVEL,
    COMPONENTS,
    HYPOTHESES,
    HYPOTHESIS_OF,
    RANK_TOL,
    UPDATES,
    Frames,
    NoiseModel,
    frames,
    pose_covariance,
    residuals,
)
from .noise import (
    BOOTSTRAP_METHODS,
    BOOTSTRAP_REPS,
    calibration_noise,
    noise_from_errors,
    noise_from_residuals,
    suggested_tolerances,
)
from .updating import (
    UpdateRefused,
    blocks_of_update,
    min_poses,
    noise_after,
    placement_spread,
    update,
    updated,
)

__all__ = ["HYPOTHESES", "BLOCK_OF", "HYPOTHESIS_OF", "UPDATES", "ALPHA", "ALLOWANCE",
           "CHI2_LEVEL", "COMPONENTS", "RANK_TOL", "NoiseModel", "Frames", "frames", "residuals",
           "pose_covariance", "Fit", "fit", "noise_from_residuals", "BOOTSTRAP_METHODS",
           "BOOTSTRAP_REPS", "calibration_noise", "noise_from_errors", "suggested_tolerances",
           "Diagnosis", "diagnose", "UpdateRefused", "blocks_of_update", "min_poses", "update",
           "updated", "noise_after", "placement_spread"]
