"""Random config structures: the validator raises ConfigError (naming a key) or accepts, never
anything else."""

from hypothesis import given, settings
from hypothesis import strategies as st

from tmscal.config import parse_config
from tmscal.errors import ConfigError

scalars = st.one_of(st.none(), st.booleans(), st.integers(-10**6, 10**6),
                    st.floats(allow_nan=True, allow_infinity=True), st.text(max_size=12))
values = st.recursive(scalars, lambda c: st.one_of(st.lists(c, max_size=4),
                                                   st.dictionaries(st.text(max_size=8), c,
                                                                   max_size=4)), max_leaves=12)
keys = st.sampled_from(["robot", "tracker", "plan", "sampling", "safety", "run", "mock", "name",
                        "bogus"])
fields = st.sampled_from(["driver", "host", "port", "speed_mm_s", "accel_mm_s2", "options",
                          "tools", "baud", "reply", "kind", "poses", "radius_mm", "start",
                          "samples", "settle_s", "min_share", "max_offset_mm",
                          "workspace_min_mm", "workspace_max_mm", "clock", "truth", "noise",
                          "retries", "x"])
sections = st.dictionaries(fields, values, max_size=6)


@settings(max_examples=300, deadline=None)
@given(st.one_of(values, st.dictionaries(keys, st.one_of(sections, values), max_size=5)))
def test_parse_config_only_config_errors(data):
    try:
        parse_config(data, "fuzz.yaml")
    except ConfigError as e:
        assert str(e).startswith("fuzz.yaml")
