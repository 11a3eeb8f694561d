"""Which arm a Universal Robots controller drives, from what its dashboard server says
(docs/kinematics.md, "Which arm the controller is").

* ``get robot model`` (PolyScope 3.12 / 5.6 and later) answers the size only, the same on both
  generations: ``UR3``, ``UR5``, ``UR10``, ``UR16``, ``UR20`` (an answer ending in "e" is taken
  as e-Series too).
* The generation comes from the software: ``PolyscopeVersion`` 3.x runs only on CB3
  controllers, 5.x (and PolyScope X, 10.x) only on e-Series and later ones (UR20, UR30).
* Failing that, from ``get serial number``: Universal Robots' "Serial numbers" article gives the
  arm's number as YYYY G S NNNN(N), the generation digit G being 3 on CB3 (e.g. 2016351864, a
  UR5) and 5 on e-Series (e.g. 20185500000, a UR5e). Other formats (the UR20/UR30's, the
  2025 format) tell nothing here.

The registry (``tmscal.calib.kinematics.find_arm``) turns (model, generation) into a name:
``ur5`` / ``ur5e``; None when the controller does not tell (no answer, an unknown model, a
UR5 of unknown generation).
"""

from __future__ import annotations

import re

from ...calib.kinematics.arms import find_arm

__all__ = ["ur_generation", "ur_arm", "VENDOR"]

#: the vendor name of UR arms in the arm registry
VENDOR = "Universal Robots"
_VERSION = re.compile(r"(\d+)\.\d+")
_SERIAL = re.compile(r"(?:19|20)\d\d([35])\d\d{4,5}")


def ur_generation(version: str | None, serial: str | None) -> str | None:
    """"CB3" or "e-Series" from the ``PolyscopeVersion`` reply (``URSoftware 5.11.0.108249
    (…)`` or ``5.11.0.108249``), else from the serial number (module docstring); None when
    neither tells."""
    m = _VERSION.search(version or "")
    if m is not None:
        major = int(m.group(1))
        if major == 3:
            return "CB3"
        if major == 5 or major >= 10:
            return "e-Series"
    s = _SERIAL.fullmatch((serial or "").strip())
    if s is not None:
        return "CB3" if s.group(1) == "3" else "e-Series"
    return None


def ur_arm(model: str | None, version: str | None, serial: str | None) -> str | None:
    """The registered arm (``ur5``, ``ur5e``, …) a controller answering ``get robot model``
    ``model``, ``PolyscopeVersion`` ``version`` and ``get serial number`` ``serial`` drives;
    None when it does not tell (module docstring)."""
    name = (model or "").strip()
    generation = ur_generation(version, serial)
    if len(name) > 1 and name[-1] in "eE" and name[-2].isdigit():
        name, generation = name[:-1], "e-Series"
    return find_arm(VENDOR, name, generation)
