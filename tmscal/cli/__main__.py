"""``python -m tmscal.cli``: the same as the ``tmscal`` command."""

from . import main

main()
