"""Hostile config structures: mixed key types, non-string keys, huge and non-finite numbers,
non-JSON values, deep nesting and self-reference. ``parse_config`` and ``load_config`` raise
ConfigError naming the file (and a key), or accept a config whose raw data is plain JSON; never
TypeError, ValueError, OverflowError or RecursionError."""

from __future__ import annotations

import datetime
import json
import math

import yaml
from hypothesis import given
from hypothesis import strategies as st

from tests.fuzz import fuzz_settings
from tmscal.config import load_config, parse_config
from tmscal.errors import ConfigError

SECTIONS = ["robot", "tracker", "plan", "sampling", "safety", "run", "mock", "name",
            "description"]
FIELDS = ["driver", "host", "port", "speed_mm_s", "accel_mm_s2", "options", "tools", "baud",
          "reply", "frame_rate_hz", "kind", "poses", "radius_mm", "rotation_deg", "seed",
          "start", "samples", "settle_s", "min_share", "robot_reads", "max_offset_mm",
          "max_rotation_deg", "workspace_min_mm", "workspace_max_mm", "max_speed_mm_s",
          "max_accel_mm_s2", "tool_points_mm", "retries", "reconnect_wait_s", "clock", "truth",
          "noise", "faults", "volume", "envelope", "upload_script"]

hostile_scalars = st.one_of(
    st.none(), st.booleans(), st.integers(-10**6, 10**6),
    st.sampled_from([10**30, 10**400, -(10**400), 2**63, -(2**63) - 1, -0.0, 1e308, 5e-324]),
    st.floats(allow_nan=True, allow_infinity=True), st.text(max_size=8),
    st.sampled_from(["current", "eq14", "ur", "denso", "ndi", "bx", "tms", "fast",
                     "spy://x?file=/tmp/y", "socket://127.0.0.1:1", "loop://", "/dev/null"]),
    st.binary(max_size=4), st.just(datetime.date(2024, 1, 1)), st.just({1, 2}))
keys = st.one_of(st.sampled_from(FIELDS), st.text(max_size=6), st.integers(-3, 3), st.none(),
                 st.booleans(), st.floats(allow_nan=False))
values = st.recursive(hostile_scalars,
                      lambda c: st.one_of(st.lists(c, max_size=4),
                                          st.dictionaries(keys, c, max_size=4)),
                      max_leaves=16)
documents = st.dictionaries(st.one_of(st.sampled_from(SECTIONS), keys),
                            st.one_of(st.dictionaries(st.sampled_from(FIELDS), values,
                                                      max_size=6), values), max_size=6)


def _accepts_or_names(data, src="fuzz.yaml"):
    try:
        cfg = parse_config(data, src)
    except ConfigError as e:
        assert str(e).startswith(src) and "\n" not in str(e), e
        return None
    json.dumps(cfg.raw, allow_nan=False)  # plain data, ready for a session header
    return cfg


@fuzz_settings(300)
@given(documents)
def test_hostile_mappings(data):
    _accepts_or_names(data)


@fuzz_settings(100)
@given(documents, st.integers(1, 200), st.sampled_from(["list", "dict"]))
def test_deep_and_self_referencing(data, depth, kind):
    v: object = 1
    for _ in range(depth):
        v = [v] if kind == "list" else {"x": v}
    deep = {**data, "mock": {"tracker": {"x": v}}}
    cfg = _accepts_or_names(deep)
    assert cfg is None or depth <= 32
    loop: list = [1]
    loop.append(loop)
    assert _accepts_or_names({**data, "mock": {"robot": {"x": loop}}}) is None


@fuzz_settings(150)
@given(documents)
def test_yaml_round_trip(tmp_path_factory, data):
    """The same documents as YAML text (where PyYAML can write them) through load_config."""
    try:
        text = yaml.dump(data, allow_unicode=True)
    except (yaml.YAMLError, TypeError, ValueError, RecursionError):
        return
    p = tmp_path_factory.mktemp("fuzz") / "rig.yaml"
    p.write_text(text, encoding="utf-8")
    try:
        cfg = load_config(p)
    except ConfigError as e:
        assert str(e).startswith(str(p)) and "\n" not in str(e), e
        return
    json.dumps(cfg.raw, allow_nan=False)
    for k in ("max_offset_mm", "max_rotation_deg", "max_speed_mm_s", "max_accel_mm_s2"):
        v = getattr(cfg.safety, k)
        assert math.isfinite(v) and v > 0
