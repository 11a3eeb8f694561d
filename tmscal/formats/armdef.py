"""Which arm ``--arm`` names, and the arm's definition as a session or a calibration records it
(docs/kinematics.md, "Arm files").

``--arm`` (and ``arm=`` of the solve service) takes

* a name of tmscal's arm registry (``ur5e``, ``fr3``, …; ``tmscal.calib.kinematics.ARMS``);
* a name of an arm file shipped with tmscal (in ``tmscal/data/arms/``: the registry's
  arms, and arms the mock rig does not simulate, e.g. ``kuka_lbr_iiwa7``);
* a path: a URDF (``.urdf``; the chain from ``--urdf-base`` to ``--urdf-flange``, by default
  ``base_link`` and ``tool0``; :mod:`.urdf`) or a tmscal arm file (a kinematics file,
  :mod:`.kinfile`, YAML or JSON; any other suffix).

The definition (:meth:`ArmDefinition.record`) is what a session header or a calibration file
keeps so that the arm can be rebuilt without the file: ``{kind: registry, name}`` for a
registered arm, else ``{kind: arm-file | urdf, name, path, sha256, content}`` (the file's
text and its SHA-256; a URDF's with ``urdf_base`` and ``urdf_flange``). Problems are typed:
ConfigError for an ``--arm`` that names nothing, CalibrationError naming the file and the key
or element for a file that is not a valid arm, and for a recorded definition whose content
does not match its hash.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Any

from ..errors import CalibrationError, ConfigError
from .kinfile import parse_kinematics
from .textfile import load_text, read_text_file
from .urdf import URDF_BASE, URDF_FLANGE, parse_urdf

__all__ = ["ArmDefinition", "resolve_arm", "arm_from_record", "shipped_arm_names",
           "shipped_arm_text", "DEFINITION_KINDS"]

#: the kinds of definition a record may have
DEFINITION_KINDS = ("registry", "arm-file", "urdf")
_MAX_CONTENT = 4_000_000


@dataclass(frozen=True)
class ArmDefinition:
    """An arm and where it came from: ``arm`` (an :class:`~tmscal.calib.kinematics.Arm`, mm,
    rad), ``kind`` (one of :data:`DEFINITION_KINDS`), ``name`` (the arm's name), and for a
    file its ``path`` (as given, or ``tmscal/data/arms/…`` for a shipped one), ``content``
    (the text), ``sha256`` (of the UTF-8 text) and, for a URDF, the chain's ``urdf_base`` and
    ``urdf_flange`` links."""

    arm: Any
    kind: str
    name: str
    path: str | None = None
    content: str | None = None
    sha256: str | None = None
    urdf_base: str | None = None
    urdf_flange: str | None = None

    def record(self) -> dict[str, Any]:
        """The plain record a session header or a calibration keeps (module docstring)."""
        if self.kind == "registry":
            return {"kind": "registry", "name": self.name}
        out = {"kind": self.kind, "name": self.name, "path": self.path, "sha256": self.sha256,
               "content": self.content}
        if self.kind == "urdf":
            out.update(urdf_base=self.urdf_base, urdf_flange=self.urdf_flange)
        return out

    def describe(self) -> str:
        """"the ur5e arm" / "the arm file x.yaml (sha256 1a2b3c4d…)" for messages."""
        if self.kind == "registry":
            return f"the registry's {self.name} arm"
        what = "URDF" if self.kind == "urdf" else "arm file"
        return f"the {what} {self.path} ({self.name}, sha256 {str(self.sha256)[:12]}…)"

    def same_as(self, other: ArmDefinition) -> bool:
        """The same arm definition: the same registry name, or files of the same content (and,
        for a URDF, the same chain)."""
        if self.kind == "registry" or other.kind == "registry":
            return self.kind == other.kind and self.name == other.name
        return (self.sha256, self.urdf_base, self.urdf_flange) == \
            (other.sha256, other.urdf_base, other.urdf_flange)


def _sha(text: str) -> str:
    return hashlib.sha256(text.encode("utf-8")).hexdigest()


def shipped_arm_names() -> list[str]:
    """The names of the arm files shipped in ``tmscal/data/arms/`` (sorted)."""
    d = resources.files("tmscal.data") / "arms"
    try:
        return sorted(p.name[:-5] for p in d.iterdir() if p.name.endswith(".yaml"))
    except (FileNotFoundError, NotADirectoryError):
        return []


def shipped_arm_text(name: str) -> str:
    """The text of the shipped arm file ``name`` (``name``.yaml in ``tmscal/data/arms/``)."""
    return (resources.files("tmscal.data") / "arms" / f"{name}.yaml").read_text("utf-8")


def _from_text(text: str, kind: str, src: str, urdf_base: str | None,
               urdf_flange: str | None) -> Any:
    if kind == "urdf":
        return parse_urdf(text, src, urdf_base or URDF_BASE, urdf_flange or URDF_FLANGE)
    kf = parse_kinematics(load_text(text, src), src)
    if hasattr(kf.model, "flange_from_sensor"):
        from ..calib.kinematics.model import Arm

        m = kf.model
        return Arm(name=m.name, dh=m.dh, base=m.base, joint_limits_rad=m.joint_limits_rad,
                   convention=m.convention, flange=m.flange, beta=m.beta,
                   joint_types=m.joint_types, joint_map=m.joint_map, root=m.root)
    return kf.model


def resolve_arm(value: Any, where: str = "--arm", urdf_base: str | None = None,
                urdf_flange: str | None = None) -> ArmDefinition:
    """The arm ``value`` names (module docstring): a registry name, a shipped arm file's name,
    or the path of a URDF or an arm file. ``urdf_base``/``urdf_flange`` (URDF only; default
    ``base_link``, ``tool0``). ConfigError naming ``where`` when it names nothing,
    CalibrationError naming the file for a file that is not an arm."""
    from ..calib.kinematics.arms import ARM_NAMES, ARMS

    if not isinstance(value, str | Path) or not str(value):
        raise ConfigError(f"{where}: expected an arm's name or the path of a URDF or arm file")
    s = str(value)
    is_urdf = s.lower().endswith(".urdf")
    if (urdf_base or urdf_flange) and not is_urdf:
        raise ConfigError(f"{where}: --urdf-base and --urdf-flange go with a URDF (.urdf), "
                          f"not {s[:80]!r}")
    if s in ARMS and not isinstance(value, Path):
        return ArmDefinition(arm=ARMS[s].arm, kind="registry", name=s)
    shipped = shipped_arm_names()
    if s in shipped and not isinstance(value, Path):
        text = shipped_arm_text(s)
        src = f"tmscal/data/arms/{s}.yaml"
        arm = _from_text(text, "arm-file", src, None, None)
        return ArmDefinition(arm=arm, kind="arm-file", name=arm.name, path=src, content=text,
                             sha256=_sha(text))
    p = Path(s)
    if not p.exists():
        shown = repr(s) if len(s) <= 80 else repr(s[:79] + "…")
        raise ConfigError(f"{where}: unknown arm {shown}; expected one of: "
                          f"{', '.join(ARM_NAMES)} (the registry), "
                          f"{', '.join(shipped) or 'none'} (shipped arm files), or the path of "
                          "an existing URDF (.urdf) or arm file")
    kind = "urdf" if is_urdf else "arm-file"
    text = read_text_file(p, "URDF" if is_urdf else "arm file",
                          "urdf" if is_urdf else "kinematics")
    arm = _from_text(text, kind, str(p), urdf_base, urdf_flange)
    return ArmDefinition(arm=arm, kind=kind, name=arm.name, path=str(p), content=text,
                         sha256=_sha(text),
                         urdf_base=(urdf_base or URDF_BASE) if is_urdf else None,
                         urdf_flange=(urdf_flange or URDF_FLANGE) if is_urdf else None)


def arm_from_record(rec: Any, where: str) -> ArmDefinition:
    """The :class:`ArmDefinition` a record (:meth:`ArmDefinition.record`) keeps, rebuilt from
    its content (no file is read). CalibrationError naming ``where`` (the file and key that
    hold the record) for a record that is not one, a content that does not match its
    sha256, or a content that is not a valid arm."""
    from ..calib.kinematics.arms import ARMS

    if not isinstance(rec, dict) or rec.get("kind") not in DEFINITION_KINDS:
        raise CalibrationError(f"{where}: expected an arm definition (a mapping with kind "
                               f"{', '.join(DEFINITION_KINDS)})")
    name = rec.get("name")
    if rec["kind"] == "registry":
        if not isinstance(name, str) or name not in ARMS:
            raise CalibrationError(f"{where}.name: {str(name)[:60]!r} is not an arm of this "
                                   f"tmscal's registry ({', '.join(ARMS)})")
        return ArmDefinition(arm=ARMS[name].arm, kind="registry", name=name)
    text, sha = rec.get("content"), rec.get("sha256")
    if not isinstance(text, str) or len(text) > _MAX_CONTENT:
        raise CalibrationError(f"{where}.content: expected the arm file's text")
    if sha != _sha(text):
        raise CalibrationError(f"{where}.sha256: does not match the recorded content (the "
                               "record was edited)")
    urdf_base, urdf_flange = rec.get("urdf_base"), rec.get("urdf_flange")
    for k, v in (("urdf_base", urdf_base), ("urdf_flange", urdf_flange)):
        if v is not None and not isinstance(v, str):
            raise CalibrationError(f"{where}.{k}: expected a link's name")
    path = rec.get("path")
    src = f"{where} (recorded {rec['kind']} {str(path)[:80]})"
    arm = _from_text(text, rec["kind"], src, urdf_base, urdf_flange)
    return ArmDefinition(arm=arm, kind=rec["kind"], name=arm.name,
                         path=str(path) if path is not None else None, content=text, sha256=sha,
                         urdf_base=urdf_base if rec["kind"] == "urdf" else None,
                         urdf_flange=urdf_flange if rec["kind"] == "urdf" else None)


# --- the registry's arms as arm files -------------------------------------------------------

_REGISTRY_NOTE = ("generated from tmscal's arm registry (tmscal/calib/kinematics/arms.py) by "
                  "`python -m tmscal.formats.armdef`; tests/unit/test_arm_files.py checks that it "
                  "still is")


def registry_arm_doc(name: str) -> dict[str, Any]:
    """The arm-file document (plain types) of the registry's arm ``name``: its kinematics
    (:func:`~.kinfile.kinematics_doc`, without the creation time), its ``description``
    (vendor, model, source, approximate, controller model, generation, reach) and its ``mock``
    placement (serial, mount 4×4 mm, home joints deg)."""
    import numpy as np

    from ..calib.kinematics.arms import ARMS
    from .kinfile import kinematics_doc

    spec = ARMS[name]
    doc = kinematics_doc(spec.arm)
    doc.pop("created", None)
    about: dict[str, Any] = {"vendor": spec.vendor, "model": spec.model, "source": spec.source,
                             "approximate": spec.approximate,
                             "controller_model": spec.controller_model}
    if spec.generation is not None:
        about["generation"] = spec.generation
    about.update(reach_mm=spec.reach_mm, notes=_REGISTRY_NOTE)
    doc["description"] = about
    mock: dict[str, Any] = {}
    if spec.mock_serial is not None:
        mock["serial"] = spec.mock_serial
    mock.update(mount=np.asarray(spec.mount, dtype=float).tolist(),
                home_deg=np.degrees(np.asarray(spec.home_q, dtype=float)).tolist())
    doc["mock"] = mock
    return doc


def registry_arm_yaml(name: str) -> str:
    """The text of the shipped arm file of the registry's arm ``name``."""
    import yaml

    doc = registry_arm_doc(name)
    about, mock = doc.pop("description"), doc.pop("mock")

    def dump(d: dict[str, Any], flow: bool | None) -> str:
        return yaml.safe_dump(d, sort_keys=False, default_flow_style=flow, width=100,
                              allow_unicode=True)

    return dump(doc, None) + dump({"description": about}, False) + dump({"mock": mock}, None)


def _write_registry_files(directory: Path) -> list[Path]:
    from ..calib.kinematics.arms import ARM_NAMES

    out = []
    for name in ARM_NAMES:
        p = directory / f"{name}.yaml"
        p.write_text(registry_arm_yaml(name), encoding="utf-8")
        out.append(p)
    return out


if __name__ == "__main__":  # regenerate the registry's shipped arm files (git diff shows them)
    _here = Path(__file__).resolve().parents[1] / "data" / "arms"
    _here.mkdir(exist_ok=True)
    _write_registry_files(_here)
