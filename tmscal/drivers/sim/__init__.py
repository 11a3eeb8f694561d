"""The in-process sim drivers (``robot: {driver: sim}``, ``tracker: {driver: sim}``): a robot
and a tracker that run the sim rig (:mod:`tmscal.sim`) in this process, no sockets, for
notebooks, unit tests and CI, as python-can's ``virtual`` interface is a bus in the process.
Not a protocol-level mock: no wire protocol is spoken (the mocks of :mod:`tmscal.mocks` do
that). :mod:`.robot` and :mod:`.tracker` are the drivers, :mod:`.channel` the rigs they share
by channel name, :mod:`.settings` their options. docs/devices.md, "sim (in-process)"."""
