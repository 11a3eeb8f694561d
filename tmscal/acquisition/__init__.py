"""Acquisition: pose plans with a safety envelope, tracker sampling, and the acquire run."""
