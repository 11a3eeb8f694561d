"""The calibration file: what ``tmscal solve -o`` writes (YAML, :func:`calibration_yaml`), and
what it and ``tmscal export --format json`` wrote read back into the
:class:`tmscal.calib.Calibration` that ``solve`` returned, its identified arm
(``Calibration.arm``, the ``arm`` section of :mod:`.armfile`) included.

Frames and units (docs/conventions.md): X = flange_from_marker, Y = flange_from_probe,
Z = base_from_tracker (Z_probe: QR24's separate Z of the probe), 4×4, mm; the orthonormal
matrices at the top level, the solver's matrices under ``raw``.

Every problem is one ``CalibrationError`` naming the file and the dotted key
(``"c.yaml: key 'raw.Z': …"``): not a mapping, a missing or malformed matrix (shape, NaN, last
row, a rotation that is not rigid), an unknown format or version, a YAML anchor/alias bomb or
recursion (the document is bounded as the rig config is: 32 levels, 100,000 values with
aliases expanded, 4 MB).
"""

from __future__ import annotations

import datetime as _dt
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from ..calib import Applied, Calibration
from ..calib.diagnose import COMPONENTS, NoiseModel
from ..config.values import check_tree
from ..errors import CalibrationError, ConfigError
from ..geometry import orthonormalize
from ..safety.origin import CalibratedP0
from ..session import plain
from .armfile import arm_section, parse_arm_section
from .textfile import MAX_BYTES, read_text_file
from .textfile import bad as _bad
from .textfile import check_matrix as _matrix
from .textfile import load_text as _load_text

__all__ = ["FORMAT", "VERSION", "MAX_BYTES", "CalibrationFile", "calibration_yaml",
           "updated_calibration_yaml", "parse_noise_model",
           "read_calibration", "parse_calibration", "load_calibration", "provenance",
           "calibration_p0"]

FORMAT = "tmscal-calibration"
VERSION = 1
_MATRICES = ("X", "Y", "Z", "Z_probe")


@dataclass
class CalibrationFile:
    """A calibration file read back: the ``calibration``, the ``path`` it came from and the
    whole checked ``doc`` (errors, session provenance, cross-validation …, plain types)."""

    calibration: Calibration
    path: Path
    doc: dict[str, Any] = field(default_factory=dict)

    @property
    def session(self) -> dict[str, Any]:
        """{"path", "sha256"} of the session the calibration was solved on ({} if unknown)."""
        s = self.doc.get("session")
        return dict(s) if isinstance(s, dict) else {}

    @property
    def noise_model(self) -> NoiseModel | None:
        """The calibration's noise model (``noise_model``, docs/lab-day.md), or None in a
        file written before it was stored."""
        d = self.doc.get("noise_model")
        return None if d is None else NoiseModel.from_json(d)

    @property
    def p0(self) -> CalibratedP0 | None:
        """Where the calibration was made (``p0``: its session's P0, base_from_flange 4×4 mm,
        and the region of its poses; docs/safety.md), or None in a file written before it
        was stored."""
        d = self.doc.get("p0")
        return None if d is None else CalibratedP0.from_doc(d)

    @property
    def created(self) -> str | None:
        """When the file was written (ISO 8601, UTC), if recorded."""
        c = self.doc.get("created")
        return str(c) if c is not None else None


def _number_matrix(v: Any, src: str, key: str, shape: tuple[int, ...] | None) -> np.ndarray:
    try:
        a = np.array(v, dtype=float)
    except (TypeError, ValueError):
        raise _bad(src, key, "expected a matrix of numbers") from None
    if (shape is not None and a.shape != shape) or (shape is None and (
            a.ndim != 2 or a.shape[0] != a.shape[1])):
        want = "×".join(map(str, shape)) if shape else "square"
        raise _bad(src, key, f"expected a {want} matrix, got shape {a.shape}")
    if not np.isfinite(a).all():
        raise _bad(src, key, "contains NaN or infinity")
    return a


def _mapping(v: Any, src: str, key: str) -> dict[str, Any] | None:
    if v is None:
        return None
    if not isinstance(v, dict):
        raise _bad(src, key, f"expected a mapping, got {type(v).__name__}")
    return v


def _distortion(d: Any, src: str) -> dict[str, Any] | None:
    d = _mapping(d, src, "distortion")
    if d is None:
        return None
    out = dict(d)
    for k in ("matrix", "undistort"):
        if out.get(k) is not None:
            out[k] = _number_matrix(out[k], src, f"distortion.{k}", (3, 3))
            if abs(np.linalg.det(out[k])) < 1e-6:
                raise _bad(src, f"distortion.{k}", "the matrix is singular")
    if out.get("axis_scale_percent") is not None:
        out["axis_scale_percent"] = _number_matrix(out["axis_scale_percent"], src,
                                                   "distortion.axis_scale_percent", (3,))
    moments = _mapping(out.get("tool_moments"), src, "distortion.tool_moments")
    if moments is not None:
        out["tool_moments"] = {k: None if m is None else _number_matrix(
            m, src, f"distortion.tool_moments.{k}", None) for k, m in moments.items()}
    return out


def _uncertainty(u: Any, src: str) -> dict[str, Any] | None:
    u = _mapping(u, src, "uncertainty")
    if u is None:
        return None
    out = dict(u)
    if out.get("target") is not None:
        out["target"] = _matrix(out["target"], src, "uncertainty.target", rigid=True)
    for k, v in u.items():
        if isinstance(v, dict) and v.get("covariance") is not None:
            out[k] = dict(v, covariance=_number_matrix(v["covariance"], src,
                                                       f"uncertainty.{k}.covariance", (3, 3)))
    return out


def _spd(v: Any, src: str, key: str, size: int) -> np.ndarray:
    M = _number_matrix(v, src, key, (size, size))
    if not np.allclose(M, M.T, rtol=1e-9, atol=1e-12 * max(1.0, float(np.abs(M).max()))):
        raise _bad(src, key, "expected a symmetric matrix")
    try:
        np.linalg.cholesky(M)
    except np.linalg.LinAlgError:
        raise _bad(src, key, "expected a positive definite covariance") from None
    return M


def parse_noise_model(d: Any, src: str) -> NoiseModel:
    """The ``noise_model`` section (docs/lab-day.md): ``bodies`` (marker, then probe), the
    residual ``covariance`` ((6·bodies)², mm and deg), ``poses``, ``source`` and optionally
    ``calibration`` ({blocks, covariance}: the calibration's own uncertainty, per block
    [v mm; ω rad]). CalibrationError naming ``src`` and the key."""
    d = _mapping(d, src, "noise_model")
    if d is None:
        raise _bad(src, "noise_model", "expected a mapping (bodies, covariance, poses)")
    bodies = d.get("bodies")
    if bodies not in (["marker"], ["marker", "probe"]):
        raise _bad(src, "noise_model.bodies", "expected [marker] or [marker, probe]")
    q = 6 * len(bodies)
    comps = d.get("components", list(COMPONENTS) * len(bodies))
    if not isinstance(comps, list) or len(comps) not in (6, q):
        raise _bad(src, "noise_model.components", f"expected the {6} component names")
    cov = _spd(d.get("covariance"), src, "noise_model.covariance", q)
    n = d.get("poses", 0)
    if isinstance(n, bool) or not isinstance(n, int) or n < 0:
        raise _bad(src, "noise_model.poses", "expected the number of poses (≥ 0)")
    out = {"bodies": bodies, "covariance": cov.tolist(), "poses": n,
           "source": str(d.get("source", "residuals"))}
    c = d.get("calibration")
    if c is not None:
        c = _mapping(c, src, "noise_model.calibration")
        if c is None:
            raise _bad(src, "noise_model.calibration", "expected a mapping (blocks, "
                       "covariance)")
        blocks = c.get("blocks")
        if not isinstance(blocks, list) or not blocks or \
                any(b not in ("z", "x", "y") for b in blocks) or len(set(blocks)) != len(blocks):
            raise _bad(src, "noise_model.calibration.blocks", "expected blocks of z, x, y")
        cc = _spd(c.get("covariance"), src, "noise_model.calibration.covariance",
                  6 * len(blocks))
        out["calibration"] = {"blocks": blocks, "covariance": cc.tolist()}
    return NoiseModel.from_json(out)


def calibration_yaml(cal: Calibration, evaluation: Mapping[str, Any], session_path: str,
                     session_sha256: str, provenance: dict[str, Any] | None = None,
                     p0: CalibratedP0 | None = None) -> str:
    """The calibration YAML (docs/conventions.md, docs/exports.md) of the calibration ``cal``:
    its X, Y, Z orthonormal (and QR24's Z_probe), raw matrices, method and how its matrices
    are applied, a statistical solver's predicted uncertainty, tracker distortion and
    parameter covariance (with the parameters it is ordered by), its identified arm
    (``Calibration.arm``: the ``arm`` section of :mod:`.armfile`, in the kinematics format);
    from its ``evaluation`` (plain types, as ``SolveResult.to_json()`` of the solve service
    gives them): the poses used (``n_solve``, ``n_test``, ``errors_on``), the errors
    (cross-validated by default, with their SD over folds: ``errors``, ``errors_sd``,
    ``cv``), the outlier poses (``outliers``: [{index, …}]), and where present
    ``truth``, ``options`` and ``noise_model``; the session's path and SHA-256; the
    ``provenance`` (tmscal/Python/NumPy versions, the session's config and devices); where it
    was made, ``p0`` (the session's P0 and region, base_from_flange mm;
    ``CalibrationFile.p0``). Units mm. :func:`load_calibration` reads it back."""
    ev = evaluation
    doc = {
        "format": "tmscal-calibration",
        "version": 1,
        "created": _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds"),
        "units": {"length": "mm", "angles": "deg"},
        "frames": {"X": "flange_from_marker", "Y": "flange_from_probe",
                   "Z": "base_from_tracker"},
        "method": cal.method,
        "applied": str(cal.applied),
        "session": {"path": session_path, "sha256": session_sha256},
        "poses": {"solve": ev["n_solve"], "test": ev["n_test"],
                  "errors_on": ev["errors_on"]},
        "cross_validation": ev.get("cv"),
        "errors_sd": ev.get("errors_sd"),
        "outlier_poses": [o["index"] for o in ev.get("outliers") or []],
        "X": _list(cal.X), "Y": _list(cal.Y), "Z": _list(cal.Z),
        **({"Z_probe": _list(cal.Z_probe)} if cal.Z_probe is not None else {}),
        "raw": {k: _list(v) for k, v in _raw(cal).items()},
        "errors": ev["errors"],
    }
    if ev.get("truth") is not None:
        doc["truth_errors"] = ev["truth"]
    for k, v in (("uncertainty", cal.uncertainty), ("distortion", cal.distortion),
                 ("options", ev.get("options")), ("noise_model", ev.get("noise_model"))):
        if v is not None:
            doc[k] = plain(v)
    if cal.covariance is not None:
        doc["covariance"] = np.asarray(cal.covariance, dtype=float).tolist()
        if cal.extra.get("parameters") is not None:
            doc["parameters"] = [str(p) for p in cal.extra["parameters"]]
    if provenance is not None:
        doc["provenance"] = provenance
    if cal.arm is not None:
        doc["arm"] = arm_section(cal.arm)
    if p0 is not None:
        doc["p0"] = p0.to_doc()
    return yaml.safe_dump(doc, sort_keys=False, default_flow_style=None, width=120)


def _list(M: Any) -> list[Any] | None:
    return None if M is None else np.asarray(M, dtype=float).tolist()


def _raw(cal: Calibration) -> dict[str, Any]:
    """The solver's matrices by name (Z_probe only for QR24's separate Z of the probe)."""
    raw = {"X": cal.X_raw, "Y": cal.Y_raw, "Z": cal.Z_raw}
    if cal.Z_probe is not None:
        raw["Z_probe"] = cal.Z_probe_raw
    return raw


def _header(doc: Any, src: str) -> tuple[str, Applied, int]:
    if not isinstance(doc, dict):
        raise CalibrationError(f"{src}: not a tmscal calibration file (expected a mapping at "
                               f"the top level, got {type(doc).__name__})")
    if doc.get("format") != FORMAT:
        raise _bad(src, "format", f"expected {FORMAT!r}, got {doc.get('format')!r:.60} (a "
                   "file written by tmscal solve -o or tmscal export --format json)")
    if doc.get("version") != VERSION:
        raise _bad(src, "version", f"this tmscal reads version {VERSION}, got "
                   f"{doc.get('version')!r:.30}")
    method = doc.get("method")
    if not isinstance(method, str) or not method:
        raise _bad(src, "method", "expected the method's name")
    try:
        applied = Applied(doc.get("applied", "raw"))
    except ValueError:
        raise _bad(src, "applied", "expected 'raw' or 'orthonormal'") from None
    poses = _mapping(doc.get("poses"), src, "poses") or {}
    n = poses.get("solve", 0)
    if isinstance(n, bool) or not isinstance(n, int) or n < 0:
        raise _bad(src, "poses.solve", "expected the number of poses solved on (≥ 0)")
    return method, applied, n


def parse_calibration(doc: Any, src: str = "<calibration>") -> Calibration:
    """A :class:`Calibration` (X = flange_from_marker, Y = flange_from_probe, Z =
    base_from_tracker, 4×4 mm) from a parsed calibration document (a dict as the file holds
    it). Raises CalibrationError naming ``src`` and the key."""
    try:
        check_tree(doc, src)  # the rig config's bounds; its ConfigError becomes ours
    except ConfigError as e:
        raise CalibrationError(str(e)) from None
    method, applied, n = _header(doc, src)
    mats: dict[str, np.ndarray | None] = {}
    for k in _MATRICES:
        v = doc.get(k)
        if v is None and k in ("X", "Z"):
            raise _bad(src, k, f"missing: the {k} matrix is required")
        mats[k] = None if v is None else _matrix(v, src, k, rigid=True)
    raw_doc = _mapping(doc.get("raw"), src, "raw") or {}
    raw: dict[str, np.ndarray | None] = {}
    for k in _MATRICES:
        v = raw_doc.get(k)
        if v is None:
            raw[k] = mats[k]
            continue
        raw[k] = r = _matrix(v, src, f"raw.{k}", rigid=False)
        if mats[k] is None:
            if k == "Z_probe":  # files from before Z_probe was written: project it
                mats[k] = orthonormalize(r)
            else:
                raise _bad(src, k, f"missing, but raw.{k} is given")
    X, Z, X_raw, Z_raw = mats["X"], mats["Z"], raw["X"], raw["Z"]
    # X and Z are required above; a missing raw.X or raw.Z is the rigid one
    assert X is not None and Z is not None and X_raw is not None and Z_raw is not None
    cov = doc.get("covariance")
    cal = Calibration(method, n, X=X, Z=Z, X_raw=X_raw, Z_raw=Z_raw,
                      Y=mats["Y"], Y_raw=raw["Y"], Z_probe=mats["Z_probe"],
                      Z_probe_raw=raw["Z_probe"], applied=applied,
                      covariance=None if cov is None else _number_matrix(cov, src,
                                                                         "covariance", None),
                      uncertainty=_uncertainty(doc.get("uncertainty"), src),
                      distortion=_distortion(doc.get("distortion"), src))
    params = doc.get("parameters")
    if params is not None:
        if not isinstance(params, list) or not all(isinstance(p, str) for p in params):
            raise _bad(src, "parameters", "expected a list of parameter names")
        if cal.covariance is not None and len(params) != len(cal.covariance):
            raise _bad(src, "parameters", f"{len(params)} names for a "
                       f"{len(cal.covariance)}×{len(cal.covariance)} covariance")
        cal.extra["parameters"] = list(params)
    if doc.get("arm") is not None:
        cal.arm = parse_arm_section(doc["arm"], src)
    return cal


def read_calibration(path: str | Path) -> CalibrationFile:
    """Read a calibration file (YAML of ``tmscal solve -o`` or JSON of ``tmscal export
    --format json``): X = flange_from_marker, Y = flange_from_probe, Z = base_from_tracker,
    4×4 mm. Raises CalibrationError naming the file (and the key)."""
    p = Path(path)
    src = str(p)
    doc = _load_text(read_text_file(p, "calibration file", "calibration"), src)
    cal = parse_calibration(doc, src)
    if doc.get("noise_model") is not None:
        parse_noise_model(doc["noise_model"], src)
    if doc.get("p0") is not None:
        try:
            CalibratedP0.from_doc(doc["p0"])
        except ValueError as e:
            key, _, msg = str(e).partition(": ")
            raise _bad(src, key, msg) from None
    cal.extra.setdefault("source", src)
    return CalibrationFile(calibration=cal, path=p, doc=doc)


def load_calibration(path: str | Path) -> Calibration:
    """The :class:`tmscal.calib.Calibration` stored in a calibration file: the YAML ``tmscal
    solve -o`` writes or the JSON of ``tmscal export --format json`` (X, Y, Z, raw matrices,
    method, poses, applied, uncertainty, distortion, covariance and the identified arm
    (``Calibration.arm``) where present; 4×4 mm; see
    :func:`read_calibration`). Raises CalibrationError naming the file and the key for a file
    that is not a calibration."""
    return read_calibration(path).calibration


def calibration_p0(session: Any) -> CalibratedP0 | None:
    """Where a calibration solved on ``session`` (a ``tmscal.session.Session``) is made: the
    P0 its header's plan records and the extent of its recorded robot poses A
    (base_from_flange 4×4 mm); None for a session without a plan (a simulated one)."""
    plan = (session.header or {}).get("plan")
    if not isinstance(plan, dict) or "p0" not in plan:
        return None
    A = [r.A for r in session.poses if r.A is not None and r.skipped is None]
    try:
        return CalibratedP0.from_plan(plan, np.asarray(A) if A else None)
    except ValueError as e:
        key, _, msg = str(e).partition(": ")
        raise CalibrationError(f"{session.path}: header key '{key}': {msg}") from None


def provenance(header: dict[str, Any] | None = None) -> dict[str, Any]:
    """What a calibration file records of where it came from: the tmscal, Python and NumPy
    versions and, from a session ``header``, when the session was recorded, its config (the
    rig config it was acquired with, or the simulation's settings) and devices."""
    import platform

    from .. import __version__
    out: dict[str, Any] = {"versions": {"tmscal": __version__,
                                        "python": platform.python_version(),
                                        "numpy": np.__version__}}
    if header:
        out["session_created"] = header.get("created")
        out["config"] = header.get("config") or {}
        out["devices"] = header.get("devices") or {}
    return out


#: what an updated calibration does not inherit from its parent: figures of the parent's
#: solve that no longer describe the updated matrices
_NOT_INHERITED = ("created", "X", "Y", "Z", "Z_probe", "raw", "errors", "errors_sd",
                  "cross_validation", "outlier_poses", "truth_errors", "uncertainty",
                  "covariance", "parameters", "provenance")


def updated_calibration_yaml(parent: CalibrationFile, parent_sha256: str, cal: Calibration,
                             update: dict[str, Any], session_path: str, session_sha256: str,
                             n_poses: int, errors: dict[str, Any],
                             provenance: dict[str, Any] | None = None,
                             noise_model: dict[str, Any] | None = None) -> str:
    """The calibration YAML of a partial re-registration (``tmscal solve TODAY --calib CAL
    --update z -o NEW``, docs/lab-day.md): the parent's document with the updated matrices
    ``cal`` (4×4 mm, orthonormal at the top, raw under ``raw``), ``errors`` of the updated
    calibration on the update's session (in-sample: the poses it was fitted on), the
    ``update`` record (blocks, Δ sizes, σ, the predicted placement spread), and
    ``provenance.lineage``: the parent (path, SHA-256, what it was updated from) before the
    parent's own lineage. The parent's arm, distortion and method are kept, its noise model
    replaced by ``noise_model`` when given (the update's uncertainty added); its solver
    covariance and predicted uncertainty are dropped (they were of other matrices)."""
    doc = {k: v for k, v in parent.doc.items() if k not in _NOT_INHERITED}
    used = cal.exported()
    mats: dict[str, Any] = {k: np.asarray(v, dtype=float).tolist()
                            for k, v in used.items() if v is not None}
    raw = {"X": cal.X_raw, "Y": cal.Y_raw, "Z": cal.Z_raw, "Z_probe": cal.Z_probe_raw}
    pprov = parent.doc.get("provenance") or {}
    lineage = [{"path": str(parent.path), "sha256": parent_sha256,
                "created": parent.created, "method": parent.calibration.method,
                "session": parent.session}] + list(pprov.get("lineage") or [])
    prov = dict(provenance or {})
    prov["lineage"] = lineage
    out = {"format": FORMAT, "version": VERSION,
           "created": _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds"),
           **{k: v for k, v in doc.items() if k not in ("format", "version")}}
    out.update(mats)
    out["raw"] = {k: np.asarray(v, dtype=float).tolist() for k, v in raw.items()
                  if v is not None}
    out["session"] = {"path": session_path, "sha256": session_sha256}
    out["poses"] = {"solve": int(parent.calibration.n_poses), "test": int(n_poses),
                    "errors_on": f"in-sample (the {n_poses} poses of the update)"}
    out["errors"] = errors
    if noise_model is not None:
        out["noise_model"] = noise_model
    out["update"] = update
    out["provenance"] = prov
    return yaml.safe_dump(out, sort_keys=False, default_flow_style=None, width=120)
