"""The solve service: a recorded session in, a calibration and its evaluation out.

Everything that solves, evaluates or predicts from a session, and reads the session header to
do so, lives here, below its users (``tmscal.acquisition``, ``tmscal.exports``,
``tmscal.stream``, ``tmscal.report`` and ``tmscal.cli``), which render or store its results;
it imports none of them (docs/architecture.md). Its errors name the arguments of its calls
(``kinematics='estimate'``, ``train=N``), never a command-line option. No I/O: sessions come in as
:class:`tmscal.session.Session` objects.

- :mod:`.solve`: ``solve`` (``solve(session, method=..., kinematics=..., ...)``, by named
  arguments: one ``SolveResult`` carrying the calibration, its cross-validated, held-out or
  in-sample errors, the truth errors, the outlier poses and its prediction, each computed
  once for that calibration; with ``kinematics="estimate"`` the arm's kinematics estimated
  with X, Y, Z), ``pose_residuals``,
  ``truth_errors_of``, ``with_kinematics`` (A recomputed from the joints under an identified
  arm model).
- :mod:`.kinematics`: the arm in the service (docs/kinematics.md, "Using it"): a session's
  joints and recorded arm, the robot poses a calibration with an arm applies, a kinematics
  file's arm made the calibration's, and the coil placement against a truth through the flange
  commands and the truth arm's controller.
- :mod:`.study`: ``study_session``, the convergence study of Wang et al. (2018).
- :mod:`.compare`: ``compare_session`` / ``compare_arrays``, the method comparison of
  ``tmscal compare``.
- :mod:`.predict`: the adaptive header entry (``adaptive_header``, ``settings_from_header``),
  the prediction's inputs, robot time by phase, ``predict_session`` (the adaptive run's
  prediction), ``predict_calibration`` / ``calibration_prediction`` (the one place that
  decides which prediction belongs to a calibration: its method, its arm) and
  ``model_error_hint`` (why an adaptive run cannot reach its target).
- :mod:`.selfcal`: ``identify_session``, the self-calibration of a recorded force-torque
  session (Joubair et al. 2016; the arm written in a form that does not depend on the kept
  columns; docs/selfcal.md, "Running it").
- :mod:`.outliers`: the robust rule that names outlier poses (Leys et al. 2013).
- :mod:`.adequacy`: ``session_adequacy``, whether the rigid model explains a solve's session
  (the rules of ``calib.adequacy`` on its poses; the likely cause and its fix;
  docs/adequacy.md), ``SolveResult.adequacy``.

Frames: A = base_from_flange, B = tracker_from_marker, C = tracker_from_probe,
X = flange_from_marker, Y = flange_from_probe, Z = base_from_tracker; 4×4 mm.
"""

from __future__ import annotations

from .compare import compare_arrays, compare_session
from .outliers import find_outliers
from .predict import adaptive_header, predict_session, settings_from_header
from .solve import SolveResult, pose_residuals, solve, truth_errors_of, with_kinematics
from .study import study_session

__all__ = ["SolveResult", "solve", "pose_residuals", "truth_errors_of",
           "with_kinematics", "study_session", "compare_session", "compare_arrays",
           "predict_session", "adaptive_header", "settings_from_header", "find_outliers"]
