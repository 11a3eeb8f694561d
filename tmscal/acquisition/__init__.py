"""Acquisition: pose plans with a safety envelope, tracker sampling, the acquire run
(``run``) and the adaptive run (``adaptive``, docs/adaptive.md)."""
