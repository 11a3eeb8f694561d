"""A serial arm from a URDF (the ROS robot description; docs/kinematics.md, "Arm files"): the
chain of joints from a base link to a flange link (by default ``base_link`` and ``tool0``, as
ROS-Industrial names them), read into the one arm model :class:`tmscal.calib.kinematics.Arm`.

What is read, per joint on the chain (``<joint>``; metres and radians in the file, mm and rad
in the arm): ``type`` revolute, continuous, prismatic or fixed; ``<origin xyz rpy>`` (parent
link ← joint frame, Trans(xyz) · Rz(yaw) Ry(pitch) Rx(roll), default identity); ``<axis xyz>``
(the joint's axis in the joint frame, default (1, 0, 0) as the URDF specification says);
``<limit lower upper>`` (required for revolute and prismatic; a continuous joint turns ±2π
here); ``<mimic joint multiplier offset>`` (a passive joint that follows another: a row of the
arm's joint map without a joint of its own). Links and joints off the chain are not read
beyond their names (a gripper's floating or planar joints do no harm), nor are visuals,
collisions, inertias, transmissions or meshes.

The chain becomes standard DH rows (Denavit and Hartenberg 1955) exactly: at q = 0, DH frame
0 lies on the first joint's axis (``Arm.root`` = base link ← DH frame 0), frame i on the
common normal of axes i and i + 1 (where two axes are parallel, the normal through the next
joint's origin), the last row runs along the last joint's own axis to the point nearest the
flange link's origin (α = 0: well conditioned whatever the flange's orientation), and
``Arm.flange`` = last DH frame ← flange link. Each joint's axis becomes its DH z
axis, so q keeps the URDF's sign; a joint's q = 0 is the URDF's zero. A prismatic joint's row
adds q (mm) to d.

Why no URDF library: the chain needs only the ``<joint>`` elements' attributes, which the
standard library's XML parser reads; yourdfpy and urchin (PyPI) would add lxml and trimesh (a
mesh library) for that and reject or accept a file by their own rules, with messages that
name neither the file nor, always, the element; pinocchio (a dependency of the Franka mock's
``franky-sim`` only, not of tmscal) builds a dynamics model whose joints would still have to be
turned into DH rows. Every problem here is one :class:`~tmscal.errors.CalibrationError`
naming the file and the element (``"arm.urdf: <joint name='elbow'>: …"``).
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import CalibrationError
from .textfile import read_text_file

__all__ = ["URDF_BASE", "URDF_FLANGE", "UrdfJoint", "parse_urdf", "read_urdf", "chain_joints",
           "dh_from_axes"]

#: the default base and flange link names (ROS-Industrial's)
URDF_BASE = "base_link"
URDF_FLANGE = "tool0"
#: joint types on the chain that the arm model takes (continuous: revolute without limits)
_MOVING = ("revolute", "continuous", "prismatic")
_KNOWN = _MOVING + ("fixed", "floating", "planar")
_MAX_ELEMENTS = 10_000
#: the sine below which two joint axes count as parallel, the distance (mm) below which they
#: intersect. Nearly parallel axes (a sine of 1e-3 and less) put the common normal far out
#: (≈ distance / sine): the rows stay exact in exact arithmetic but lose digits, as DH does
#: there (Hayati and Mirmirani 1985)
_PARALLEL = 1e-10
_MEET_MM = 1e-9


def _bad(src: str, what: str, msg: str) -> CalibrationError:
    return CalibrationError(f"{src}: {what}: {msg}")


@dataclass(frozen=True)
class UrdfJoint:
    """One ``<joint>`` as read: ``name``, ``type``, ``parent`` and ``child`` link names,
    ``origin`` (4×4 mm, parent link ← joint frame), ``axis`` (unit 3-vector, joint frame),
    ``limits`` ((lower, upper): rad, or mm for a prismatic joint; None: none given) and
    ``mimic`` ((joint name, multiplier, offset rad or mm) or None)."""

    name: str
    type: str
    parent: str
    child: str
    origin: np.ndarray
    axis: np.ndarray
    limits: tuple[float, float] | None
    mimic: tuple[str, float, float] | None


def _floats(text: str | None, n: int, default: list[float], src: str, what: str,
            attr: str) -> list[float]:
    if text is None:
        return list(default)
    parts = text.split()
    try:
        vals = [float(p) for p in parts]
    except ValueError:
        vals = []
    if len(vals) != n or not all(math.isfinite(v) for v in vals):
        raise _bad(src, what, f"{attr}={text[:60]!r}: expected {n} finite numbers")
    return vals


def _pose(xyz_m: list[float], rpy: list[float]) -> np.ndarray:
    from ..calib.kinematics.model import pose_from_rpy

    return pose_from_rpy(rpy, [1000.0 * v for v in xyz_m])


def _number(el: ET.Element, attr: str, src: str, what: str, default: float | None) -> float:
    v = el.get(attr)
    if v is None:
        if default is None:
            raise _bad(src, what, f"<{el.tag}> has no {attr}")
        return default
    try:
        x = float(v)
    except ValueError:
        raise _bad(src, what, f"<{el.tag} {attr}={v[:40]!r}>: not a number") from None
    if not math.isfinite(x):
        raise _bad(src, what, f"<{el.tag} {attr}={v[:40]!r}>: not a finite number")
    return x


def _joint(el: ET.Element, src: str) -> UrdfJoint:
    name = el.get("name")
    if not name:
        raise _bad(src, "<joint>", "a joint without a name")
    what = f"<joint name={name!r}>"
    jtype = el.get("type")
    if jtype not in _KNOWN:
        raise _bad(src, what, f"unknown joint type {jtype!r:.40}; a URDF joint is one of: "
                   f"{', '.join(_KNOWN)}")
    links = []
    for tag in ("parent", "child"):
        e = el.find(tag)
        if e is None or not e.get("link"):
            raise _bad(src, what, f"has no <{tag} link=…>")
        links.append(str(e.get("link")))
    o = el.find("origin")
    origin = np.eye(4) if o is None else _pose(
        _floats(o.get("xyz"), 3, [0.0] * 3, src, what, "origin xyz"),
        _floats(o.get("rpy"), 3, [0.0] * 3, src, what, "origin rpy"))
    a = el.find("axis")
    axis = np.array(_floats(None if a is None else a.get("xyz"), 3, [1.0, 0.0, 0.0], src, what,
                            "axis xyz"))
    norm = float(np.linalg.norm(axis))
    if jtype in _MOVING and not norm > 1e-12:
        raise _bad(src, what, "the axis is zero")
    scale = 1000.0 if jtype == "prismatic" else 1.0
    limits = None
    lim = el.find("limit")
    if jtype in ("revolute", "prismatic"):
        if lim is None:
            raise _bad(src, what, f"a {jtype} joint needs <limit lower=… upper=…>")
        lo = _number(lim, "lower", src, what, 0.0) * scale
        hi = _number(lim, "upper", src, what, 0.0) * scale
        if not lo < hi:
            raise _bad(src, what, f"<limit>: lower {lo / scale:g} is not below upper "
                       f"{hi / scale:g}")
        limits = (lo, hi)
    mimic = None
    mi = el.find("mimic")
    if mi is not None and jtype in _MOVING:
        other = mi.get("joint")
        if not other:
            raise _bad(src, what, "<mimic> names no joint")
        mimic = (str(other), _number(mi, "multiplier", src, what, 1.0),
                 _number(mi, "offset", src, what, 0.0) * scale)
    return UrdfJoint(name=name, type=str(jtype), parent=links[0], child=links[1],
                     origin=origin, axis=axis / norm if norm > 0 else axis, limits=limits,
                     mimic=mimic)


def chain_joints(text: str, src: str, base_link: str = URDF_BASE,
                 flange_link: str = URDF_FLANGE) -> tuple[str, list[UrdfJoint]]:
    """The robot's name and the joints from ``base_link`` down to ``flange_link``, in chain
    order. CalibrationError naming ``src`` and the element: not a URDF, a link named twice or
    not declared, a link that is the child of two joints or its own ancestor (a closed loop,
    which a URDF cannot describe), a flange that is not below the base."""
    try:
        root = ET.fromstring(text)
    except ET.ParseError as e:
        raise CalibrationError(f"{src}: not a readable URDF (XML: {e})") from None
    if root.tag != "robot":
        raise _bad(src, f"<{root.tag[:40]}>", "a URDF's top element is <robot>")
    name = root.get("name") or Path(src).stem
    if sum(1 for _ in root.iter()) > _MAX_ELEMENTS:
        raise CalibrationError(f"{src}: more than {_MAX_ELEMENTS} XML elements")
    links: set[str] = set()
    for el in root.findall("link"):
        ln = el.get("name")
        if not ln:
            raise _bad(src, "<link>", "a link without a name")
        if ln in links:
            raise _bad(src, f"<link name={ln!r}>", "declared twice")
        links.add(ln)
    joints: dict[str, UrdfJoint] = {}
    parent_of: dict[str, UrdfJoint] = {}
    for el in root.findall("joint"):
        j = _joint(el, src)
        if j.name in joints:
            raise _bad(src, f"<joint name={j.name!r}>", "declared twice")
        for ln in (j.parent, j.child):
            if ln not in links:
                raise _bad(src, f"<joint name={j.name!r}>", f"link {ln!r:.60} is not declared "
                           "(no <link name=…> of that name)")
        if j.child in parent_of:
            raise _bad(src, f"<joint name={j.name!r}>",
                       f"link {j.child!r} is already the child of joint "
                       f"{parent_of[j.child].name!r}: a closed loop (a link with two parents), "
                       "which a serial arm cannot have")
        joints[j.name] = j
        parent_of[j.child] = j
    for ln, role, opt in ((base_link, "base", "--urdf-base"),
                          (flange_link, "flange", "--urdf-flange")):
        if ln not in links:
            shown = ", ".join(sorted(links)[:12]) + (", …" if len(links) > 12 else "")
            raise _bad(src, f"<link name={ln!r}>", f"no such link (the {role} link; name "
                       f"another with {opt}; the file's links: {shown})")
    chain: list[UrdfJoint] = []
    seen = {flange_link}
    at = flange_link
    while at != base_link:
        up = parent_of.get(at)
        if up is None:
            raise _bad(src, f"<link name={flange_link!r}>",
                       f"the chain does not connect the flange link {flange_link!r} to the base "
                       f"link {base_link!r}: going up from the flange it ends at the root link "
                       f"{at!r}")
        j = up
        if j.parent in seen:
            raise _bad(src, f"<joint name={j.name!r}>", f"link {j.parent!r} is its own "
                       "ancestor: a closed loop")
        seen.add(j.parent)
        chain.append(j)
        at = j.parent
    chain.reverse()
    for j in chain:
        if j.type not in _MOVING + ("fixed",):
            raise _bad(src, f"<joint name={j.name!r}>", f"a {j.type} joint on the chain from "
                       f"{base_link!r} to {flange_link!r}: a serial arm's joints are revolute, "
                       "continuous, prismatic or fixed")
    return name, chain


def dh_from_axes(points: np.ndarray, axes: np.ndarray, flange: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(dh (m, 4), root 4×4, flange 4×4): standard DH rows [θ0 rad, d mm, a mm, α rad] whose
    chain, at zero joint values, puts joint i's axis (z of DH frame i − 1) on the line through
    ``points[i]`` (mm) along the unit ``axes[i]`` (both in the base frame), with ``root`` =
    base ← DH frame 0 and ``flange`` = last DH frame ← the given flange pose (base ← flange,
    4×4 mm) (module docstring)."""
    m = len(axes)
    z = axes[0] / np.linalg.norm(axes[0])
    o = points[0] + (-points[0] @ z) * z           # the axis point nearest the base origin
    x = np.array([1.0, 0.0, 0.0]) - z[0] * z
    if np.linalg.norm(x) < 1e-6:
        x = np.array([0.0, 1.0, 0.0]) - z[1] * z
    x = x / np.linalg.norm(x)
    root = _frame(o, x, z)
    lines: list[tuple[np.ndarray, np.ndarray | None]] = [
        (points[i], axes[i] / np.linalg.norm(axes[i])) for i in range(1, m)]
    lines.append((flange[:3, 3], None))     # the last row: along its own axis to the flange
    dh = np.empty((m, 4))
    for i, (p, w_next) in enumerate(lines):
        w = z if w_next is None else w_next
        c = np.cross(z, w)
        r = p - o
        if np.linalg.norm(c) > _PARALLEL:
            b = z @ w
            den = float(c @ c)                       # 1 − b², without its cancellation
            s = ((z @ r) - b * (w @ r)) / den
            t = (b * (z @ r) - (w @ r)) / den
            foot, o_next = o + s * z, p + t * w
        else:                                       # parallel: the normal through p
            foot, o_next = o + (r @ z) * z, p
        diff = o_next - foot
        diff = diff - (diff @ z) * z
        dist = float(np.linalg.norm(diff))
        if np.linalg.norm(c) > _PARALLEL:       # the common normal: along z × w exactly
            x_next = c / np.linalg.norm(c)
            if diff @ x_next < 0 and dist > _MEET_MM:
                x_next = -x_next
            dist = float(diff @ x_next) if dist > _MEET_MM else 0.0
        elif dist > _MEET_MM:
            x_next = diff / dist
        else:
            x_next = x
        z_next = w - (w @ x_next) * x_next
        z_next = z_next / np.linalg.norm(z_next)
        theta = math.atan2(float(np.cross(x, x_next) @ z), float(x @ x_next))
        alpha = math.atan2(float(np.cross(z, z_next) @ x_next), float(z @ z_next))
        dh[i] = [theta, float((foot - o) @ z), dist, alpha]
        # the frame the row reaches (built from the row, so that the chain is exactly it)
        o = foot + dist * x_next
        x, z = x_next, z_next
    last = _frame(o, x, z)
    return dh, root, np.linalg.inv(last) @ flange


def _frame(o: np.ndarray, x: np.ndarray, z: np.ndarray) -> np.ndarray:
    T = np.eye(4)
    T[:3, 0], T[:3, 1], T[:3, 2], T[:3, 3] = x, np.cross(z, x), z, o
    return T


def _rot(axis: np.ndarray, angle: float) -> np.ndarray:
    """Rotation (4×4) about the unit ``axis`` by ``angle`` rad (Rodrigues)."""
    K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    T = np.eye(4)
    T[:3, :3] = np.eye(3) + math.sin(angle) * K + (1 - math.cos(angle)) * (K @ K)
    return T


def _frozen(j: UrdfJoint) -> UrdfJoint:
    """A joint that mimics another with multiplier 0 is fixed at its offset."""
    from dataclasses import replace

    offset = j.mimic[2] if j.mimic is not None else 0.0
    if j.type == "prismatic":
        motion = np.eye(4)
        motion[:3, 3] = j.axis * offset
    else:
        motion = _rot(j.axis, offset)
    return replace(j, type="fixed", origin=j.origin @ motion, mimic=None)


def parse_urdf(text: str, src: str = "<urdf>", base_link: str = URDF_BASE,
               flange_link: str = URDF_FLANGE, name: str | None = None) -> Any:
    """The :class:`~tmscal.calib.kinematics.Arm` (mm, rad; ``base`` = identity: the world is
    the base link) of the chain from ``base_link`` to ``flange_link`` of a URDF's text
    (module docstring); its name is ``name``, else the robot's. CalibrationError naming
    ``src`` and the element."""
    from ..calib.kinematics.model import Arm

    robot, chain = chain_joints(text, src, base_link, flange_link)
    chain = [_frozen(j) if j.mimic is not None and j.mimic[1] == 0.0 else j for j in chain]
    moving = [j for j in chain if j.type in _MOVING]
    if not moving:
        raise _bad(src, f"<link name={flange_link!r}>", f"no revolute, continuous or prismatic "
                   f"joint between {base_link!r} and {flange_link!r}")
    actuated = [j.name for j in moving if j.mimic is None]
    if not actuated:
        raise _bad(src, f"<joint name={moving[0].name!r}>", "every joint on the chain mimics "
                   "another: none moves the arm")
    T = np.eye(4)
    points, axes = [], []
    for j in chain:                                   # base ← each joint frame at q = 0
        T = T @ j.origin
        if j.type in _MOVING:
            points.append(T[:3, 3].copy())
            axes.append(T[:3, :3] @ j.axis)
    dh, root, flange = dh_from_axes(np.array(points), np.array(axes), T)
    M = np.zeros((len(moving), len(actuated)))
    types, limits = [], []
    for i, j in enumerate(moving):
        types.append("prismatic" if j.type == "prismatic" else "revolute")
        if j.mimic is None:
            M[i, actuated.index(j.name)] = 1.0
            limits.append(list(j.limits) if j.limits is not None else
                          [-2 * math.pi, 2 * math.pi])
            continue
        other, mult, offset = j.mimic
        what = f"<joint name={j.name!r}>"
        if other not in actuated:
            why = ("mimics a joint that mimics another" if other in [k.name for k in moving]
                   else f"mimics joint {other!r:.60}, which is not on the chain from "
                   f"{base_link!r} to {flange_link!r}")
            raise _bad(src, what, f"<mimic>: {why}")
        k = actuated.index(other)
        if (moving[[mv.name for mv in moving].index(other)].type == "prismatic") != \
                (j.type == "prismatic"):
            raise _bad(src, what, "<mimic>: couples a revolute and a prismatic joint")
        M[i, k] = mult
        dh[i, 1 if j.type == "prismatic" else 0] += offset
    try:
        return Arm(name=name or robot, dh=dh, root=root, flange=flange,
                   joint_limits_rad=np.array(limits), joint_types=tuple(types),
                   joint_map=M)
    except ValueError as e:
        raise CalibrationError(f"{src}: not a valid arm ({e})") from None


def read_urdf(path: str | Path, base_link: str = URDF_BASE, flange_link: str = URDF_FLANGE,
              name: str | None = None) -> Any:
    """The arm of a URDF file (:func:`parse_urdf`). CalibrationError naming the file."""
    p = Path(path)
    return parse_urdf(read_text_file(p, "URDF", "urdf"), str(p), base_link, flange_link, name)
