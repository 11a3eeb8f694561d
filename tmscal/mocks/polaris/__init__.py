"""A protocol-level NDI Polaris (Spectra / Vicra) mock serving a :class:`~tmscal.sim.rig.SimRig`.

It speaks the NDI Combined API (NDI's Polaris Application Program Interface Guide) over a
Linux pty (:meth:`PolarisMock.start_pty`, returns the ``/dev/pts/N`` path that ndicapi,
scikit-surgerynditracker or our driver open as a serial port) or TCP on loopback
(:meth:`PolarisMock.start_tcp`, returns ``socket://127.0.0.1:PORT`` for pyserial's
``serial_for_url``). All encoding and decoding goes through
:mod:`tmscal.drivers.ndi.protocol`, the same codec the driver uses.

What it models (modules of this package):

* :mod:`.firmware`: the setup / initialised / tracking state machine with NDI error codes
  for commands in the wrong state (e.g. TX/BX before TSTART → ERROR0C, tool commands before
  INIT → ERROR10, unknown or unallocated port handles → ERROR08, PENA on an uninitialised
  handle → ERROR0E, PINIT with no tool data → ERROR0D, bad CRC → ERROR04, unknown command →
  ERROR01); passive tools loaded from .rom files (PHRQ, PVWR, PINIT, PENA, PHSR, PHF,
  PHINF), matched to rig bodies by their bytes; VER (multi-line, with ``Freeze Tag:``),
  GETINFO (simplified ``name=value``), COMM (baud changes are acknowledged and ignored),
  BEEP, APIREV, TSTART (``TSTART:80`` resets the frame counter), TSTOP, TX and BX (options
  0001 and 0800) with a CRC on every reply;
* :mod:`.frames`: the frame counter (on the real-time clock it advances at the model's rate,
  Spectra 60 Hz, Vicra 20 Hz; on the fast clock once per TX/BX request) and one noisy
  observation (``rig.observe``) per frame number;
* :mod:`.model`: a measurement volume (:class:`MeasurementVolume`, a Spectra-like pyramid
  in tracker coordinates): a tool with all spheres inside is healthy, some inside →
  partially out of volume (0x80, pose reported), none inside → out of volume (0x40; reported
  MISSING unless the request has option 0800). Line of sight and marker orientation are not
  modelled. Faults (:class:`PolarisFaults`): corrupted reply CRCs, dropped replies, tools
  missing in a fraction of frames, IR interference; all from one seeded RNG so tests are
  reproducible;
* :mod:`.mock`: the transports. One daemon thread per transport (and per TCP connection);
  every loop polls a stop flag with a short timeout, so ``close()`` returns promptly. Binds
  to loopback only.
"""

from __future__ import annotations

from .firmware import MAX_HANDLES, PolarisFirmware
from .mock import PolarisMock
from .model import MODELS, MeasurementVolume, PolarisFaults

__all__ = ["PolarisMock", "PolarisFirmware", "PolarisFaults", "MeasurementVolume", "MODELS",
           "MAX_HANDLES"]
