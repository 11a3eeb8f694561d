"""A Polaris that takes as long as a real one (docs/devices.md): seconds to answer RESET
after a break (ndicapi waits up to 7 s), INIT / PINIT / TSTART taking seconds (PlusLib: "First
init can take up to 5 seconds"), and RESET arriving as the answer to a command after the
device reset. Our driver against the Polaris mock over a real pty, on the fast clock with
the mock's delay options: the mock really waits, so the driver's timeouts are exercised.
Each delay is well inside the driver's timeout for it and well beyond its general
``timeout_s``, so the outcome does not hinge on scheduling."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from tmscal.drivers.ndi.tracker import NDITracker
from tmscal.errors import ConnectionLost
from tmscal.mocks.clock import FAST
from tmscal.mocks.polaris import PolarisMock
from tmscal.sim.rig import TMS_RIG_P0, Noise, SimRig, tms_rig_truth

TOOLS_DIR = Path(__file__).resolve().parents[2] / "configs" / "tools"
ROMS = {"marker": str(TOOLS_DIR / "marker-8700340.rom"),
        "probe": str(TOOLS_DIR / "probe-8700340.rom")}


def make_mock(**delays: float) -> PolarisMock:
    rig = SimRig(tms_rig_truth(), noise=Noise.none(), rng=np.random.default_rng(1),
                 start=TMS_RIG_P0)
    return PolarisMock(rig, ROMS, clock=FAST, seed=3, **delays)


@pytest.fixture
def slow_reset() -> Iterator[PolarisMock]:
    with make_mock(reset_delay_s=1.5) as m:
        yield m


def test_slow_reset_after_a_break_is_waited_for(slow_reset: PolarisMock) -> None:
    """The break reached the device (a pty cannot carry one, so the mock is told); RESET
    comes 1.5 s later. The driver waits for it, then initialises: one INIT, answered."""
    path = slow_reset.start_pty()
    slow_reset.serial_break()
    with NDITracker(path, ROMS, reset=True) as tr:
        assert tr.read().tools["marker"].usable
        assert tr.identity()["model"] == "Polaris Spectra"
    assert slow_reset.commands[0] == "INIT:"
    assert slow_reset.commands.count("INIT:") == 1


def test_slow_init_pinit_tstart_are_sent_once() -> None:
    """INIT, PINIT and TSTART each take 1 s; the driver's general timeout is 0.4 s. Each is
    sent once and its own reply taken (not re-sent and the late reply taken for the next
    command)."""
    with make_mock(init_delay_s=1.0, pinit_delay_s=1.0, tstart_delay_s=1.0) as m, \
            NDITracker(m.start_pty(), ROMS, timeout_s=0.4, reset=False) as tr:
        assert tr.read().tools["probe"].usable
        assert tr.identity()["serial"] == "P6-00001"
        names = [c.split(":")[0] for c in m.commands]
        assert names.count("INIT") == 1
        assert names.count("PINIT") == 2
        assert names.count("TSTART") == 1
        assert sorted(tr.handles.values()) == [1, 2]


def test_reset_as_an_answer_is_an_error_naming_the_command() -> None:
    """The device resets while tracking (power dip, a break from elsewhere): the next
    command gets RESET. That is a ConnectionLost naming the command, not a reply."""
    with make_mock(reset_delay_s=0.3) as m, \
            NDITracker(m.start_pty(), ROMS, timeout_s=2.0, retries=0, reset=False,
                       reply="tx") as tr:
        assert tr.read().tools["marker"].usable
        m.serial_break()
        with pytest.raises(ConnectionLost, match="TX.*RESET"):
            tr.read()
