"""Franka robots (FR3, Panda) through the ``franky`` client library (PyPI ``franky-control``):
``robot`` (the ``FrankaRobot`` driver) and ``frames`` (the conversions at its edge)."""
