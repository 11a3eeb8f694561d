"""Kinematic self-calibration from a wrist force-torque sensor (Joubair, Zhao, Bigras and Bonev
2016): the arm model and its gravity wrench (:mod:`.model`), identifiability and identification
(:mod:`.identify`), pose selection (:mod:`.design`) and the simulation study (:mod:`.simulate`).
Pure numerics, no I/O; docs/selfcal.md."""
