"""Every HAL backend passes the same conformance script (core/hal_check.py).

To check a new backend, add a factory to BACKENDS: a callable that returns a fresh, unconnected
base. 
"""

import math

import pytest

from core.hal import HalError, Pose2D, RobotBase, VelocityCommand
from core.hal_check import check_base
from sim.config import SimConfig, SimConfigError
from sim.hal import SimLimo


def _sim_limo() -> RobotBase:
    # A small image keeps the script fast; the camera path is still exercised.
    return SimLimo(SimConfig(width_px=64, height_px=48))


def _sim_limo_in_hospital() -> RobotBase:
    """The same backend inside a textured world (the build_world hook, its floor and light)."""
    from sim.worlds import load_world

    world = load_world("hospital")
    (x0, y0), (x1, y1) = world.routes.walkthrough[:2]
    start = Pose2D(x0, y0, math.atan2(y1 - y0, x1 - x0))
    return SimLimo(SimConfig(width_px=64, height_px=48), start=start, world=world)


def _serial_limo_on_emulator() -> RobotBase:
    """The serial Limo backend talking real bytes to the base emulator over a pseudo-terminal."""
    from limo.config import LimoSerialConfig
    from limo.emulated import EmulatedSerialLimo

    return EmulatedSerialLimo(LimoSerialConfig(control_period_s=0.05))


def _serial_twin_in_hospital() -> RobotBase:
    """The serial backend over a pty to the emulator backed by the PyBullet Limo and sim camera."""
    from limo.config import LimoSerialConfig
    from sim.serial_twin import SerialTwinLimo
    from sim.worlds import load_world

    world = load_world("hospital")
    (x0, y0), (x1, y1) = world.routes.walkthrough[:2]
    return SerialTwinLimo(world, SimConfig(width_px=64, height_px=48),
                          Pose2D(x0, y0, math.atan2(y1 - y0, x1 - x0)),
                          serial_config=LimoSerialConfig(control_period_s=0.05))


BACKENDS = {
    "sim": _sim_limo,
    "sim-hospital": _sim_limo_in_hospital,
    "serial-emulated": _serial_limo_on_emulator,
    "serial-twin-hospital": _serial_twin_in_hospital,
}


#: backends that build a world in PyBullet or run a serial twin in real time: the slow lane
SLOW_BACKENDS = {"sim-hospital", "serial-twin-hospital"}


@pytest.mark.parametrize("make_base", [pytest.param(make, id=name, marks=pytest.mark.slow if name in SLOW_BACKENDS else ())
                                       for name, make in BACKENDS.items()])
def test_backend_conforms_to_hal(make_base):
    check_base(make_base)


class _NoClipBase(SimLimo):
    """A deliberately broken backend: apply() ignores the limits."""

    def apply(self, cmd):
        self._require("apply()")
        self._session.limo.set_command(cmd.v_mps, cmd.w_radps)
        return cmd


def test_checker_rejects_a_base_that_does_not_clip():
    with pytest.raises(AssertionError, match="clipped"):
        check_base(lambda: _NoClipBase(SimConfig(camera_enabled=False)))


@pytest.mark.parametrize("field,value", [
    ("physics_dt_s", 0.0),
    ("control_period_s", 0.105),          # not a whole number of physics steps
    ("width_px", 320.5),
    ("max_w_radps", -1.0),
    ("imu_yaw_rate_noise_radps", float("nan")),
    ("seed", -1),
    ("gui", "yes"),
])
def test_sim_config_errors_name_the_field(field, value):
    with pytest.raises(SimConfigError, match=f"SimConfig.{field}"):
        SimConfig(**{field: value})


def test_sim_reports_hal_errors_clearly():
    base = SimLimo(SimConfig(camera_enabled=False))
    with pytest.raises(HalError, match="not connected"):
        base.ground_truth.true_pose()
    with pytest.raises(HalError, match="not connected"):
        base.apply(VelocityCommand(0.1, 0.0))
