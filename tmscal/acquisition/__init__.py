"""Acquisition: one engine (``engine``: devices, envelope, reconnect, stop, resume, the session
file, progress) runs three strategies (``strategy``): the plan run (``run``), the adaptive
run (``adaptive_run``, docs/adaptive.md) and the self-calibration run (``selfcal``,
docs/selfcal.md); with pose plans and their safety check (``plan``), tracker sampling
(``sample``), the devices (``devices``), the resume checks (``resume``) and ``Progress``."""
