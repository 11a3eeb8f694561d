"""The simulation study of force-torque self-calibration (Joubair, Zhao, Bigras and Bonev 2016)
as tmscal reproduces it (``tmscal selfcal simulate``, ``benchmarks/selfcal.py``;
docs/selfcal.md, "The simulation study"): the paper's protocols (:mod:`.simulate`), its own
robot, the MedRUE hybrid (:mod:`.medrue`, dimensions assumed), and how identified arms are
compared (:mod:`.compare`). Pure numerics, no I/O. Nothing in acquisition or solving uses it:
a session's arm is identified by the one kinematic estimator
(:mod:`tmscal.calib.selfcal.estimate`)."""
