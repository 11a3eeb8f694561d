"""PLUS toolkit device set (``tmscal export --format plus``): a ``PlusConfiguration`` holding
an NDITracker ``Device`` block and the ``CoordinateDefinitions`` of the calibration.

PLUS names a transform ``<From>To<To>``; it maps point coordinates of frame From into frame To
(4×4, mm, ``Matrix`` 16 numbers row by row). tmscal's transforms in PLUS' names:

* ``CoilMarkerToFlange`` = X = flange_from_marker
* ``CoilCentreToCoilMarker`` = X⁻¹ · Y = marker_from_coil (the coil's effective centre on
  the marker, ``Calibration.marker_from_coil``; none for a marker-only calibration)
* ``TrackerToRobotBase`` = Z = base_from_tracker

(orthonormal matrices). Y = flange_from_probe is CoilCentreToFlange, which PLUS' transform
repository computes through CoilMarker (X · X⁻¹ · Y): a definition of it too would close a
loop, which the repository refuses ("A transform path already exists"). ``Error`` is the
calibration's hold-out translation error in mm (the marker's for X, the total e_t for Z;
docs/methods.md; no hold-out error is defined for X⁻¹ · Y alone, so it has none), ``Date``
when the calibration was written (PLUS' "YYYY.MM.DD hh:mm:ss"). The NDITracker device lists
the tools as ``DataSource`` elements: the marker as ``CoilMarker``, so that PLUS chains the
tracked CoilMarkerToTracker with the definitions into CoilCentreToTracker (the coil from the
marker alone), and the probe, where the calibration has one, as ``Probe`` (ProbeToTracker, a
cross-check; a tool named CoilCentre would close a loop too). The ROM files, serial port and
baud rate come from the NDI driver's settings of the session's rig config when the
calibration file records it (``tmscal solve -o`` does), else placeholders to fill in. A
session on another tracker driver has no ROM files: its device block carries none, and its
device type is a placeholder (the file's comment says so).
"""

from __future__ import annotations

import datetime as _dt
from typing import Any

import numpy as np

from ..config import settings_class
from ..config.settings import TrackerSettings
from ..drivers.ndi.settings import NDISettings
from ..errors import ConfigError
from ..escape import xml_attr, xml_comment
from ..formats.calibfile import CalibrationFile

__all__ = ["FRAMES", "TOOL_IDS", "matrix_text", "render", "recorded_tracker", "rom_files"]

#: tmscal matrix → (PLUS From, PLUS To), in the order written: X, marker ← coil (X⁻¹ · Y),
#: Z. Y itself is not a definition: PLUS computes CoilCentreToFlange through CoilMarker
FRAMES = {"X": ("CoilMarker", "Flange"), "CoilToMarker": ("CoilCentre", "CoilMarker"),
          "Z": ("Tracker", "RobotBase")}
#: tmscal body → PLUS tool (DataSource) Id
TOOL_IDS = {"marker": "CoilMarker", "probe": "Probe"}


def matrix_text(M: np.ndarray) -> str:
    """A 4×4 as PLUS writes it: 16 numbers, row by row, separated by spaces."""
    return " ".join(repr(float(v)) for v in np.asarray(M, dtype=float).ravel())


def _date(created: str | None) -> str:
    try:
        t = _dt.datetime.fromisoformat(created) if created else None
    except ValueError:
        t = None
    return (t or _dt.datetime.now(_dt.UTC)).strftime("%Y.%m.%d %H:%M:%S")


def _error(doc: dict[str, Any], key: str) -> str:
    e = doc.get("errors") or {}
    v = {"X": (e.get("marker") or {}).get("trans_mm"), "Z": e.get("e_t_mm")}.get(key)
    return "" if v is None else f"{float(v):.4f}"


def recorded_tracker(cf: CalibrationFile) -> tuple[str | None, TrackerSettings | None]:
    """The tracker driver of the session's rig config and its settings, read by the driver's
    settings class with paths as the config wrote them (relative to its folder; files not
    checked, nor the wire log, which concerns the acquiring machine). (None, None) when the
    calibration file records no tracker; (driver, None) when its keys cannot be read here
    (a driver not installed, a config that no longer parses)."""
    cfg = (cf.doc.get("provenance") or {}).get("config") or {}
    tracker = cfg.get("tracker") if isinstance(cfg, dict) else None
    if not isinstance(tracker, dict):
        return None, None
    driver = tracker.get("driver", "ndi")
    if not isinstance(driver, str):
        return None, None
    section = {k: v for k, v in tracker.items() if k != "log_wire"}
    try:
        settings = settings_class("tracker", driver).parse(section, str(cf.path), None, False)
    except ConfigError:
        return driver, None
    return driver, settings if isinstance(settings, TrackerSettings) else None


def rom_files(cf: CalibrationFile) -> dict[str, str] | None:
    """The tools' ROM files {body: path} of the session's NDI tracker, as its rig config
    wrote them; {} when the file records none; None when the tracker is not an NDI (its
    driver has no ROM files)."""
    return _roms(*recorded_tracker(cf))


def _roms(driver: str | None, settings: TrackerSettings | None) -> dict[str, str] | None:
    if driver is not None and driver != "ndi":
        return None
    if not isinstance(settings, NDISettings):
        return {}
    return {k: v for k, v in settings.tools.items() if isinstance(v, str)}


def _port_attrs(settings: NDISettings | None) -> list[str]:
    port = settings.port if settings is not None else ""
    if port.startswith("socket://"):
        host, _, num = port.removeprefix("socket://").rpartition(":")
        return [f"NetworkHostname={xml_attr(host)}", f"NetworkPort={xml_attr(num)}"]
    out = [f"SerialPort={xml_attr(port or 'CHECK: the tracker port')}"]
    if settings is not None:
        out.append(f"BaudRate={xml_attr(str(settings.baud))}")
    return out


def _device(cf: CalibrationFile, driver: str | None,
            settings: TrackerSettings | None) -> list[str]:
    cfg = (cf.doc.get("provenance") or {}).get("config") or {}
    tracker = cfg.get("tracker")
    if not isinstance(tracker, dict):
        tracker = {}
    roms = _roms(driver, settings)
    bodies = ["marker", "probe"] if cf.calibration.Y is not None else ["marker"]
    if roms is None:
        kind = [f"Type={xml_attr(f'CHECK: the PLUS device of tracker driver {driver!r}')}"]
    else:
        ndi = settings if isinstance(settings, NDISettings) else None
        kind = ['Type="NDITracker"', *_port_attrs(ndi)]
    attrs = ['Id="TrackerDevice"', *kind, 'ToolReferenceFrame="Tracker"']
    if tracker.get("frame_rate_hz"):
        attrs.insert(2, f"AcquisitionRate={xml_attr(str(tracker['frame_rate_hz']))}")
    lines = ["    <Device " + "\n      ".join(attrs) + " >", "      <DataSources>"]
    for b in bodies:
        rom = "" if roms is None else " RomFile=" + xml_attr(
            roms.get(b) or f"CHECK: the {b} tool's ROM file")
        lines.append(f'        <DataSource Type="Tool" Id="{TOOL_IDS[b]}"{rom} />')
    lines += ["      </DataSources>", "      <OutputChannels>",
              '        <OutputChannel Id="TrackerStream" >']
    lines += [f'          <DataSource Id="{TOOL_IDS[b]}" />' for b in bodies]
    lines += ["        </OutputChannel>", "      </OutputChannels>", "    </Device>"]
    return lines


def render(cf: CalibrationFile) -> str:
    """The device-set XML text (comments name the frames and units)."""
    cal = cf.calibration
    date = _date(cf.created)
    driver, settings = recorded_tracker(cf)
    roms = _roms(driver, settings)
    known = ("as the session's rig config wrote them (relative to its folder)" if roms
             else "placeholders: fill in CHECK" if roms is not None
             else f"none: the session's tracker (driver {driver!r}) is not an NDI and has no "
                  "ROM files; set its PLUS device and tool sources (CHECK)")
    note = (f"tmscal {cal.method} calibration {cf.path.name}: transforms in mm, 16 numbers "
            "row by row; AToB maps A coordinates into B. CoilMarkerToFlange = X "
            "(flange_from_marker), CoilCentreToCoilMarker = X⁻¹·Y (marker_from_coil: the "
            "coil centre on the marker, so CoilCentreToTracker follows from the tracked "
            "CoilMarker alone, and CoilCentreToFlange = Y through it), TrackerToRobotBase = Z "
            "(base_from_tracker). Tool Probe: the calibration probe, a cross-check (remove it "
            "when the probe is gone). Error: hold-out translation error, mm. Tool ROM files "
            f"and port: {known}.")
    lines = ['<?xml version="1.0" encoding="UTF-8"?>', f"<!-- {xml_comment(note)} -->",
             '<PlusConfiguration version="2.1">',
             '  <DataCollection StartupDelaySec="1.0" >',
             '    <DeviceSet Name="tmscal: NDI tracker and the robot calibration" '
             'Description="CoilMarker (and the calibration Probe) tracked; the calibration in '
             'CoordinateDefinitions" />',
             *_device(cf, driver, settings), "  </DataCollection>", "  <CoordinateDefinitions>"]
    e = cal.exported()  # rigid, as every export (docs/exports.md)
    exported = {"X": e["X"], "Z": e["Z"],
                "CoilToMarker": cal.marker_from_coil() if cal.Y is not None else None}
    for k, (a, b) in FRAMES.items():
        M = exported[k]
        if M is None:
            continue
        err = "" if k == "CoilToMarker" else f"Error={xml_attr(_error(cf.doc, k))} "
        lines.append(f'    <Transform From="{a}" To="{b}" Matrix="{matrix_text(M)}" '
                     f'{err}Date={xml_attr(date)} />')
    lines += ["  </CoordinateDefinitions>", "</PlusConfiguration>", ""]
    return "\n".join(lines)
