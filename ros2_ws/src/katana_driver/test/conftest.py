"""Shared fixtures of katana_driver's tests: emulators on loopback, ROS contexts."""

import os

os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "OFF")

import pytest  # noqa: E402
from katana_emulator.emulator import Faults, KatanaEmulator, KatanaModel  # noqa: E402


@pytest.fixture
def make_emulator():
    """Factory: a KatanaEmulator listening on 127.0.0.1, any free port; stopped afterwards."""
    made: list[KatanaEmulator] = []

    def make(
        time_scale: float = 1.0,
        calibration_s: float = 0.2,
        calibrated: bool = False,
        variant: str = "6M180",
        serial: bool = False,
        **faults,
    ) -> KatanaEmulator:
        model = KatanaModel(
            variant=variant,
            time_scale=time_scale,
            calibration_s=calibration_s,
            calibrated=calibrated,
        )
        emulator = KatanaEmulator(model, Faults(**faults))
        emulator.serve_tcp("127.0.0.1", 0)
        if serial:
            emulator.serve_pty()
        made.append(emulator)
        return emulator

    yield make
    for emulator in made:
        emulator.stop()
