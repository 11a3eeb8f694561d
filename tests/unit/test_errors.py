"""The error contract: ``str(DeviceError)`` names the device, the code and its name once, and
the fields survive pickling."""

import pickle

import pytest

from tmscal.errors import (
    ConfigError,
    DeviceError,
    DeviceTimeout,
    MissingExtraError,
    ProtocolError,
    RobotFault,
    format_code,
)


@pytest.mark.parametrize("err, text", [
    # the message already has the code and its name: only the device is added
    (RobotFault("b-CAP Robot_Move failed: 0x83500178 (not executable during emergency stop)",
                code=0x83500178, text="not executable during emergency stop", device="denso"),
     "denso: b-CAP Robot_Move failed: 0x83500178 (not executable during emergency stop)"),
    # NDI writes its codes as ERRORxx, and its messages start with the device
    (DeviceError("NDI BX answered ERROR0C (invalid frame)", code=0x0C, text="invalid frame",
                 device="ndi"),
     "NDI BX answered ERROR0C (invalid frame)"),
    # a code the message does not name is appended, with its name
    (DeviceTimeout("b-CAP Robot_Move: no reply", code=0x80000900, text="E_TIMEOUT",
                   device="denso"),
     "denso: b-CAP Robot_Move: no reply [0x80000900 (E_TIMEOUT)]"),
    (RobotFault("ur 127.0.0.3: moveL refused: robot in PROTECTIVE_STOP", code=3,
                text="PROTECTIVE_STOP", device="ur"),
     "ur 127.0.0.3: moveL refused: robot in PROTECTIVE_STOP [code 3]"),
    (ProtocolError("bad CRC", code="E_CRC", device="ndi"), "ndi: bad CRC [E_CRC]"),
    (DeviceError("plain"), "plain"),
])
def test_device_error_names_device_and_code_once(err, text):
    assert str(err) == text
    assert err.message in str(err)


def test_device_error_pickles_with_its_fields():
    e = pickle.loads(pickle.dumps(DeviceTimeout("no reply", code=0x80000900, text="E_TIMEOUT",
                                                device="denso")))
    assert isinstance(e, DeviceTimeout) and isinstance(e, TimeoutError)
    assert (e.message, e.code, e.text, e.device) == ("no reply", 0x80000900, "E_TIMEOUT",
                                                     "denso")
    m = pickle.loads(pickle.dumps(MissingExtraError("driver 'ur'", "ur", "no rtde")))
    assert str(m) == "driver 'ur' needs the optional extra 'ur' (no rtde): pip install 'tmscal[ur]'"


def test_missing_extra_is_a_config_error():
    assert issubclass(MissingExtraError, ConfigError)


@pytest.mark.parametrize("code, text", [(0x83500178, "0x83500178"), (-2147023170, "0x800706BE"),
                                        (12, "code 12"), ("E_FAIL", "E_FAIL")])
def test_format_code(code, text):
    assert format_code(code) == text
