"""``mock.changes`` and ``mock.events`` (docs/configs.md, ``mock``): a valid schedule with one
value made bad is a ConfigError naming that key, whatever the bad value; any value at all is
either accepted (finite, in bounds) or a ConfigError naming a key under ``mock.changes`` or
``mock.events``, never another exception."""

from __future__ import annotations

import math
import re

from hypothesis import given, settings
from hypothesis import strategies as st

from tmscal.config import parse_config
from tmscal.errors import ConfigError

MOVES = ["tracker", "marker", "coil", "coil_centre"]
SRC = "fuzz.yaml"

small = st.floats(-100, 100, allow_nan=False)
triple = st.lists(small, min_size=3, max_size=3)
rot = st.lists(st.floats(-90, 90, allow_nan=False), min_size=3, max_size=3)  # ‖deg‖ < 180
change = st.fixed_dictionaries({}, optional={"mm": triple, "deg": rot})
event = st.fixed_dictionaries({"at_s": st.floats(0, 1e6, allow_nan=False),
                               "move": st.sampled_from(MOVES)},
                              optional={"mm": triple, "deg": rot})
changes = st.dictionaries(st.sampled_from(MOVES), change, min_size=1)
events = st.lists(event, min_size=1, max_size=5)

junk = st.one_of(st.none(), st.booleans(), st.text(max_size=6),
                 st.dictionaries(st.text(max_size=4), st.integers(), max_size=2))
bad_number = st.one_of(junk, st.just(math.nan), st.just(math.inf), st.just(-math.inf),
                       st.lists(small, max_size=3), st.integers(2**63, 2**70))


def bad_vector(bound: float) -> st.SearchStrategy:
    """Anything that is not three finite numbers within ±bound."""
    out = st.one_of(st.floats(bound * 1.0001, 1e300), st.floats(-1e300, -bound * 1.0001),
                    bad_number)
    spoilt = st.tuples(triple, st.integers(0, 2), out).map(
        lambda t: [*t[0][:t[1]], t[2], *t[0][t[1] + 1:]])  # one entry of three made bad
    wrong_len = st.one_of(st.lists(small, max_size=2), st.lists(small, min_size=4, max_size=6))
    return st.one_of(junk, small, wrong_len, spoilt)


too_far = st.floats(150, 180).map(lambda v: [v, v, 0.0])  # each in bounds, ‖deg‖ > 180
bad_at = st.one_of(st.floats(-1e300, -1e-9), st.floats(1e6 * 1.0001, 1e300), bad_number,
                   st.lists(small, min_size=1, max_size=2))
bad_move = st.one_of(st.text(max_size=12).filter(lambda s: s not in MOVES), st.integers(),
                     st.none(), st.booleans(), st.lists(st.sampled_from(MOVES), max_size=2))
word = st.text("abcdefghijklmnopqrstuvwxyz_", min_size=1, max_size=10)


def key_of(e: ConfigError) -> str:
    m = re.match(rf"{re.escape(SRC)}(, line \d+)?: key '([^']*)'", str(e))
    assert m, str(e)
    return m.group(2)


def refused(mock: dict) -> str:
    """The key a ConfigError names for this mock section (fails when it is accepted)."""
    try:
        parse_config({"mock": mock}, SRC)
    except ConfigError as e:
        return key_of(e)
    raise AssertionError(f"accepted: {mock!r}")


@settings(max_examples=300, deadline=None)
@given(events, st.data())
def test_one_bad_event_value_is_a_config_error_naming_it(evs, data):
    i = data.draw(st.integers(0, len(evs) - 1))
    what = data.draw(st.sampled_from(["at_s", "move", "mm", "deg", "deg_norm", "unknown",
                                      "missing_at_s", "not_a_mapping"]))
    e = dict(evs[i])
    key = f"mock.events[{i}]"
    if what == "at_s":
        e["at_s"] = data.draw(bad_at)
        key += ".at_s"
    elif what == "move":
        e["move"] = data.draw(bad_move)
        key += ".move"
    elif what in ("mm", "deg"):
        e[what] = data.draw(bad_vector(1000.0 if what == "mm" else 180.0))
        key += f".{what}"
    elif what == "deg_norm":
        e["deg"] = data.draw(too_far)
        key += ".deg"
    elif what == "unknown":
        k = data.draw(word.filter(lambda k: k not in ("at_s", "move", "mm", "deg")))
        e[k] = data.draw(st.one_of(junk, small))
        key += f".{k}"
    elif what == "missing_at_s":
        del e["at_s"]
        key += ".at_s"
    else:
        e = data.draw(st.one_of(junk.filter(lambda v: not isinstance(v, dict)), triple))
    evs = [*evs[:i], e, *evs[i + 1:]]
    assert refused({"events": evs}).startswith(key)


@settings(max_examples=300, deadline=None)
@given(changes, st.data())
def test_one_bad_change_value_is_a_config_error_naming_it(chs, data):
    move = data.draw(st.sampled_from(sorted(chs)))
    what = data.draw(st.sampled_from(["mm", "deg", "deg_norm", "unknown", "unknown_move",
                                      "not_a_mapping"]))
    c = dict(chs[move])
    chs = dict(chs)
    key = f"mock.changes.{move}"
    if what in ("mm", "deg"):
        c[what] = data.draw(bad_vector(1000.0 if what == "mm" else 180.0))
        key += f".{what}"
    elif what == "deg_norm":
        c["deg"] = data.draw(too_far)
        key += ".deg"
    elif what == "unknown":
        k = data.draw(word.filter(lambda k: k not in ("mm", "deg")))
        c[k] = data.draw(st.one_of(junk, small))
        key += f".{k}"
    elif what == "unknown_move":
        k = data.draw(word.filter(lambda k: k not in MOVES))
        chs[k] = c
        key = f"mock.changes.{k}"
    else:
        c = data.draw(st.one_of(junk.filter(lambda v: not isinstance(v, dict)), triple))
    if what != "unknown_move":
        chs[move] = c
    assert refused({"changes": chs}).startswith(key)


anything = st.recursive(
    st.one_of(st.none(), st.booleans(), st.integers(-10**20, 10**20), st.floats(),
              st.text(max_size=8), st.sampled_from(MOVES + ["at_s", "mm", "deg", "move"])),
    lambda c: st.one_of(st.lists(c, max_size=4),
                        st.dictionaries(st.one_of(st.sampled_from(MOVES + ["at_s", "mm",
                                                                           "deg", "move"]),
                                                  st.text(max_size=6)), c, max_size=4)),
    max_leaves=16)


@settings(max_examples=400, deadline=None)
@given(st.sampled_from(["changes", "events"]), anything)
def test_any_value_is_accepted_in_bounds_or_a_config_error_under_its_key(name, value):
    try:
        cfg = parse_config({"mock": {name: value}}, SRC)
    except ConfigError as e:
        assert key_of(e).startswith(f"mock.{name}"), str(e)
        return
    m = cfg.mock
    assert m is not None
    entries = list(m.changes.values()) if name == "changes" else list(m.events)
    for c in entries:
        assert all(math.isfinite(v) and abs(v) <= 1000 for v in c["mm"])
        assert all(math.isfinite(v) and abs(v) <= 180 for v in c["deg"])
        assert math.hypot(*c["deg"]) <= 180
    for e in m.events:
        assert 0 <= e["at_s"] <= 1e6 and e["move"] in MOVES
