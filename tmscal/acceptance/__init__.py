"""The rig acceptance checks (``docs/acceptance.md``): ``checks``, each check of the driver
contract on the devices of a rig config and the text report; ``rig``, the rig under test (the
devices built as ``tmscal acquire`` builds them, the checks in order with their skips, the
report written whole). ``tmscal selftest --rig CONFIG`` (:mod:`tmscal.cli.selftest`) and
``pytest tests/acceptance --rig CONFIG`` run them.

They move the robot but record no session, so they are not an acquisition run: they sit above
:mod:`tmscal.acquisition` and use only its device builders (``acquisition.devices``).
Units as in :mod:`tmscal.acceptance.checks`: poses 4×4 mm, angles degrees, rates Hz, times s.
"""
