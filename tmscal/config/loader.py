"""Loading a rig config: the YAML text, the document's bounds and sections, and each section
through the module that owns it. Every problem is a ConfigError naming the file, the key and
(for ``load_config``) the line, raised before any device is opened."""

from __future__ import annotations

import json
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import yaml

from ..errors import ConfigError
from ..filekind import read_kind
from .devices import parse_ft, parse_robot, parse_tracker
from .mock import parse_mock
from .plan import parse_plan
from .run import parse_adaptive, parse_run, parse_sampling
from .safety import check_robot_caps, parse_safety, warn_without_tool_points
from .sections import RigConfig
from .values import MAX_CONFIG_BYTES, check_tree, err, show, with_line

__all__ = ["SECTIONS", "parse_config", "load_config"]

#: the top-level keys of a config
SECTIONS = ("robot", "tracker", "plan", "sampling", "safety", "run", "mock", "adaptive", "ft",
            "name", "description")


def _check_top_level(data: Any, src: str) -> None:
    """A mapping of plain data with known sections; name and description are strings."""
    if not isinstance(data, Mapping):
        raise ConfigError(f"{src}: expected a YAML mapping at the top level")
    check_tree(data, src)
    unknown = sorted(k for k in data if k not in SECTIONS)
    if unknown:
        raise err(src, unknown[0], f"unknown section; expected: {', '.join(sorted(SECTIONS))}")
    for k in ("name", "description"):
        if data.get(k) is not None and not isinstance(data[k], str):
            raise err(src, k, f"expected a string, got {show(data[k])}")


def parse_config(data: Any, src: str = "<config>", base_dir: Path | None = None,
                 check_files: bool = True) -> RigConfig:
    """Validate a config mapping (as loaded from YAML) into a ``RigConfig``. Raises
    ConfigError naming ``src`` and the key (``tmscal.config``'s docstring lists the rules).
    ``base_dir`` is the folder relative paths in the config are resolved against (None: as
    given). ``check_files=False`` skips the check that files named in the config exist, such
    as an NDI tracker's ROM files (``tmscal robot`` needs only the robot; building the
    driver checks them before it opens)."""
    _check_top_level(data, src)
    robot = parse_robot(data.get("robot"), src, base_dir, check_files)
    tracker = parse_tracker(data.get("tracker"), src, base_dir, check_files)
    plan = parse_plan(data.get("plan"), src)
    sampling = parse_sampling(data.get("sampling"), src)
    safety = parse_safety(data, src, robot is not None)
    run = parse_run(data.get("run"), src)
    mock = parse_mock(data.get("mock"), src)
    adaptive = parse_adaptive(data.get("adaptive"), src)
    ft = parse_ft(data.get("ft"), src, base_dir, check_files)
    check_robot_caps(robot, safety, src)
    try:  # the resolved config goes into the session header as JSON
        json.dumps(data, allow_nan=False)
    except (TypeError, ValueError, OverflowError, RecursionError) as e:
        raise ConfigError(f"{src}: the config is not plain data ({e})") from None
    warn_without_tool_points(robot, safety, src)
    return RigConfig(path=None, robot=robot, tracker=tracker, plan=plan, sampling=sampling,
                     safety=safety, run=run, mock=mock, raw=dict(data), adaptive=adaptive,
                     ft=ft)


def load_config(path: str | os.PathLike[str], *, check_files: bool = True) -> RigConfig:
    """Load and validate a YAML rig config. Raises ConfigError naming the file, the line and
    the key; nothing is opened or written. ``check_files=False``: see ``parse_config``."""
    p = Path(path)
    text = read_kind(p, "config", "config", MAX_CONFIG_BYTES, ConfigError)
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as e:
        mark = getattr(e, "problem_mark", None)
        where = f", line {mark.line + 1}" if mark is not None else ""
        raise ConfigError(f"{p}{where}: invalid YAML ({getattr(e, 'problem', e)})") from None
    except RecursionError:
        raise ConfigError(f"{p}: invalid YAML (nested too deeply)") from None
    except (ValueError, OverflowError, TypeError) as e:  # e.g. an int beyond the digit limit
        raise ConfigError(f"{p}: invalid YAML ({show(str(e), 120)})") from None
    try:
        cfg = parse_config(data, str(p), p.parent, check_files)
    except ConfigError as e:
        raise with_line(e, str(p), text) from None
    cfg.path = p
    return cfg
