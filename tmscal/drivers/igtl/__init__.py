"""OpenIGTLink tracker driver (``tracker: {driver: igtl}``): TRANSFORM messages of a
PlusServer or any OpenIGTLink source as tracker frames. :mod:`.tracker` is the driver,
:mod:`.frames` the frame and validity rules, :mod:`.wire` the message codec (through pyigtl),
:mod:`.settings` its config keys. docs/devices.md, "OpenIGTLink tracker (PlusServer)"."""
