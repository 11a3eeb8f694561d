"""PLUS toolkit device set (``tmscal export --format plus``): a ``PlusConfiguration`` holding
an NDITracker ``Device`` block and the ``CoordinateDefinitions`` of the calibration.

PLUS names a transform ``<From>To<To>``; it maps point coordinates of frame From into frame To
(4×4, mm, ``Matrix`` 16 numbers row by row). tmscal's transforms in PLUS' names:

* ``CoilMarkerToFlange`` = X = flange_from_marker
* ``CoilCentreToFlange`` = Y = flange_from_probe (the probe marks the coil's centre)
* ``TrackerToRobotBase`` = Z = base_from_tracker

(orthonormal matrices). ``Error`` is the calibration's hold-out translation error in mm (the
marker's for X, the probe's for Y, the total e_t for Z; docs/methods.md), ``Date`` when the
calibration was written (PLUS' "YYYY.MM.DD hh:mm:ss"). The NDITracker device lists the tools
as ``DataSource`` elements whose ``Id`` are the frames above (CoilMarker, CoilCentre), so
PLUS' transform repository chains CoilMarkerToTracker with the definitions; the ROM files,
serial port and baud rate come from the session's rig config when the calibration file
records it (``tmscal solve -o`` does), else placeholders to fill in.
"""

from __future__ import annotations

import datetime as _dt
from typing import Any

import numpy as np

from .calibfile import CalibrationFile
from .escape import xml_attr, xml_comment

__all__ = ["FRAMES", "TOOL_IDS", "matrix_text", "render"]

#: tmscal matrix → (PLUS From, PLUS To)
FRAMES = {"X": ("CoilMarker", "Flange"), "Y": ("CoilCentre", "Flange"),
          "Z": ("Tracker", "RobotBase")}
#: tmscal body → PLUS tool (DataSource) Id
TOOL_IDS = {"marker": "CoilMarker", "probe": "CoilCentre"}


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
    v = {"X": (e.get("marker") or {}).get("trans_mm"),
         "Y": (e.get("probe") or {}).get("trans_mm"), "Z": e.get("e_t_mm")}[key]
    return "" if v is None else f"{float(v):.4f}"


def _port_attrs(tracker: dict[str, Any]) -> list[str]:
    port = tracker.get("port")
    if isinstance(port, str) and port.startswith("socket://"):
        host, _, num = port.removeprefix("socket://").rpartition(":")
        return [f"NetworkHostname={xml_attr(host)}", f"NetworkPort={xml_attr(num)}"]
    out = [f"SerialPort={xml_attr(str(port) if port else 'CHECK: the tracker port')}"]
    if tracker.get("baud"):
        out.append(f"BaudRate={xml_attr(str(tracker['baud']))}")
    return out


def _device(cf: CalibrationFile) -> list[str]:
    cfg = (cf.doc.get("provenance") or {}).get("config") or {}
    tracker = cfg.get("tracker") if isinstance(cfg.get("tracker"), dict) else {}
    tools = cf.tools
    bodies = ["marker", "probe"] if cf.calibration.Y is not None else ["marker"]
    attrs = ['Id="TrackerDevice"', 'Type="NDITracker"', *_port_attrs(tracker),
             'ToolReferenceFrame="Tracker"']
    if tracker.get("frame_rate_hz"):
        attrs.insert(2, f"AcquisitionRate={xml_attr(str(tracker['frame_rate_hz']))}")
    lines = ["    <Device " + "\n      ".join(attrs) + " >", "      <DataSources>"]
    for b in bodies:
        rom = tools.get(b) or f"CHECK: the {b} tool's ROM file"
        lines.append(f'        <DataSource Type="Tool" Id="{TOOL_IDS[b]}" '
                     f"RomFile={xml_attr(rom)} />")
    lines += ["      </DataSources>", "      <OutputChannels>",
              '        <OutputChannel Id="TrackerStream" >']
    lines += [f'          <DataSource Id="{TOOL_IDS[b]}" />' for b in bodies]
    lines += ["        </OutputChannel>", "      </OutputChannels>", "    </Device>"]
    return lines


def render(cf: CalibrationFile) -> str:
    """The device-set XML text (comments name the frames and units)."""
    cal = cf.calibration
    date = _date(cf.created)
    known = ("as the session's rig config wrote them (relative to its folder)" if cf.tools
             else "placeholders: fill in CHECK")
    note = (f"tmscal {cal.method} calibration {cf.path.name}: transforms in mm, 16 numbers "
            "row by row; AToB maps A coordinates into B. CoilMarkerToFlange = X "
            "(flange_from_marker), CoilCentreToFlange = Y (flange_from_probe), "
            "TrackerToRobotBase = Z (base_from_tracker). Error: hold-out translation error, "
            f"mm. Tool ROM files and port: {known}.")
    lines = ['<?xml version="1.0" encoding="UTF-8"?>', f"<!-- {xml_comment(note)} -->",
             '<PlusConfiguration version="2.1">',
             '  <DataCollection StartupDelaySec="1.0" >',
             '    <DeviceSet Name="tmscal: NDI tracker and the robot calibration" '
             'Description="CoilMarker and CoilCentre tracked; the calibration in '
             'CoordinateDefinitions" />',
             *_device(cf), "  </DataCollection>", "  <CoordinateDefinitions>"]
    for k, (a, b) in FRAMES.items():
        M = getattr(cal, k)
        if M is None:
            continue
        lines.append(f'    <Transform From="{a}" To="{b}" Matrix="{matrix_text(M)}" '
                     f'Error={xml_attr(_error(cf.doc, k))} Date={xml_attr(date)} />')
    lines += ["  </CoordinateDefinitions>", "</PlusConfiguration>", ""]
    return "\n".join(lines)
