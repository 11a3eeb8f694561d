"""Package data: the shipped rig configs and tool ROMs (``tmscal/data/configs/``).

Load them with :mod:`importlib.resources` (``files("tmscal.data") / "configs" / ...``) so they
work from an installed wheel as well as from a clone; in a clone, the top-level ``configs``
symlink points here.
"""
