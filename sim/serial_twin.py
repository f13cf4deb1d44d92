"""The serial twin: the simulated Limo behind the real serial backend, every command as bytes.

:class:`SerialTwinLimo` is a :class:`~limo.serial_base.LimoSerialBase` (so a
:class:`~core.hal.RobotBase`) whose ``connect()`` first brings up, in this process,

* a PyBullet world with the simulated Limo (:class:`PyBulletBaseModel`, a
  :class:`~sim.hal.SimLimo` underneath), which plays the emulator's
  :class:`~limo.emulator.models.BaseModel`: wheel odometry (0x311), gyro (0x322), euler yaw
  (0x323) and motion state (0x221) come from the simulated body;
* the base emulator (:class:`~limo.emulator.firmware.LimoEmulator`) on a pseudo-terminal, answering
  as the firmware with that model behind it;
* a camera source (:class:`SimCameraSource`) rendering the simulated camera of that same body
  with the world's light,

and then opens the pty like any serial port. Commands go controller -> ``apply()`` -> writer
thread -> pty bytes -> emulator parser -> physics; feedback comes back the same way. Truth for
metrics is :attr:`SerialTwinLimo.ground_truth` (a :class:`~core.hal.GroundTruth`), exactly as
with ``SimLimo``, so the run loop can swap one for the other::

    with SerialTwinLimo(world, SimConfig(), start, appearance_seed=0) as base:
        base.apply(VelocityCommand(0.3, 0.0)); base.tick(); frame = base.read()
        pose = base.ground_truth.true_pose()

Time: **real time**, not lock-step. The emulator thread advances the model by the wall-clock
time since its last feedback cycle (50 Hz, capped at ``EmulatorConfig.max_step_s``, 0.25 s here
so render stalls do not lose simulated time), and the model
steps the physics by exactly that much simulated time in whole ``physics_dt_s`` steps, carrying
the remainder (< one step) to the next call, so simulated time follows wall time. Physics costs
about 1-2 ms per 20 ms cycle on the 2-core dev machine (``python -m sim.serial_twin`` measures
it). Rendering is the expensive part and PyBullet holds the GIL while it renders, so every render
stalls the other threads (serial writer, reader, emulator) for its duration; the camera therefore
renders at ``camera_rate_hz`` (default 10, the controller's rate), not at the Dabai's 30 fps.

Threads: PyBullet is not thread-safe for one client, so every call into the client (physics
steps from the emulator thread, renders from the camera thread, ground truth from the caller)
goes through :class:`PyBulletBaseModel`, which serialises them with one lock.

Shutdown (``close()``, ``with``, an exception, Ctrl-C, interpreter exit): the serial backend
stops its writer and sends zero velocity, the camera thread is joined, the twin waits (up to
``stop_settle_s``, shorter than the firmware's own 0.5 s watchdog) until the emulator executes
the zero command, then stops the emulator (thread joined, pty closed) and disconnects PyBullet.
"""

from __future__ import annotations

import argparse
import math
import sys
import threading
import time
from dataclasses import dataclass, field, replace
from typing import Any, Callable, List, Optional

import numpy as np

from core.angles import wrap_angle
from core.cli import Parser, non_negative_int, positive_float
from core.hal import GroundTruth, HalError, Pose2D, VelocityCommand
from core.shutdown import exit_status, interrupted_by, stop_on_signals
from core.validate import check_positive
from limo.camera import CameraError, CameraFrame
from limo.config import LimoSerialConfig
from limo.emulator.firmware import EmulatorConfig, LimoEmulator
from limo.emulator.models import BaseState
from limo.geometry import WHEEL_RADIUS_M
from limo.serial_base import LimoSerialBase
from sim.bullet import p
from sim.camera import Camera, check_light
from sim.config import CameraSpec, SimConfig
from sim.hal import SimLimo

#: connect() fails when the simulated camera has rendered nothing by then
FIRST_IMAGE_TIMEOUT_S = 5.0


class SerialTwinError(ValueError):
    """A :class:`SerialTwinConfig` field is invalid; the message names the field."""


@dataclass(frozen=True)
class SerialTwinConfig:
    """How the twin runs, beyond the simulator (``SimConfig``) and the serial link (``LimoSerialConfig``)."""

    #: renders per second of the simulated camera; each 320x240 render holds the GIL ~25-55 ms,
    #: so more than the controller's rate only slows the serial threads down
    camera_rate_hz: float = 10.0
    #: on close, wait at most this long for the emulator to execute the zero command; shorter
    #: than the firmware's 0.5 s watchdog, so a zero seen in time really came over the wire
    stop_settle_s: float = 0.3
    #: the emulated firmware (feedback rate, command watchdog, battery, injected faults); one
    #: model step may cover 0.25 s so that simulated time keeps up through render stalls
    emulator: EmulatorConfig = field(default_factory=lambda: EmulatorConfig(max_step_s=0.25))

    def __post_init__(self) -> None:
        for name in ("camera_rate_hz", "stop_settle_s"):
            check_positive(f"SerialTwinConfig.{name}", getattr(self, name), error=SerialTwinError)
        if not isinstance(self.emulator, EmulatorConfig):
            raise SerialTwinError(f"SerialTwinConfig.emulator must be an EmulatorConfig, got {self.emulator!r}")


@dataclass(frozen=True)
class ModelTiming:
    """What the emulator asked of the physics and what it cost (wall seconds of this process)."""

    steps: int                #: calls of step() by the emulator
    physics_steps: int        #: PyBullet steps taken
    requested_s: float        #: sum of the dt the emulator asked for
    sim_time_s: float         #: simulated time advanced (requested minus a remainder < one physics step)
    busy_s: float             #: wall time spent inside step(), lock waits included
    max_step_s: float         #: the slowest step()
    renders: int              #: camera renders through this model
    render_busy_s: float      #: wall time spent rendering
    max_render_s: float       #: the slowest render


def render_light_of(world: Any, appearance_seed: int) -> dict:
    """The ``getCameraImage`` light of ``world`` under ``appearance_seed`` (``{}`` for a plain floor),
    the same light :class:`~sim.hal.SimLimo` renders with."""
    if world is None:
        return {}
    from sim.appearance import apply_appearance  # noqa: PLC0415
    from sim.world import render_light_kwargs  # noqa: PLC0415 - a plain floor needs no world code

    return check_light(render_light_kwargs(apply_appearance(world, appearance_seed).light))


class PyBulletBaseModel:
    """The emulator's :class:`~limo.emulator.models.BaseModel` played by a simulated Limo in a world.

    Owns one :class:`~sim.hal.SimLimo` (its control period set to one physics step, camera off)
    and the lock that serialises every use of its PyBullet client. ``step(dt_s, v, w)`` applies
    the command (SimLimo clips it to ``sim_config``'s limits and ramps it at the Limo's
    acceleration limits) and steps the physics by ``dt_s`` of simulated time in whole physics
    steps, carrying the remainder. The reported :class:`~limo.emulator.models.BaseState`:

    * ``left_m``/``right_m``: wheel travel from the wheel joint angles (with ``SimConfig``'s slip
      noise, drawn per physics step here), counted from the last ``reset()``;
    * ``v_mps``: mean wheel speed over the step (keeps counting when a wall blocks the body);
    * ``w_radps``: the IMU yaw rate (true body rate plus ``SimConfig``'s gyro noise);
    * ``x_m, y_m, yaw_rad``: the body's true pose in the frame of ``start`` (the IMU's power-on
      frame), so the euler yaw (0x323) is the heading since start;
    * ``accel_mps2``: change of ``v_mps`` over the step.
    """

    def __init__(self, sim_config: SimConfig = SimConfig(), world: Any = None,
                 start: Pose2D = Pose2D(0.0, 0.0, 0.0), appearance_seed: int = 0) -> None:
        self.sim_config = sim_config
        self.world = world
        self.start = start
        self.appearance_seed = appearance_seed
        physics = replace(sim_config, control_period_s=sim_config.physics_dt_s, camera_enabled=False)
        self._sim = SimLimo(physics, start=start, world=world, appearance_seed=appearance_seed)
        self._lock = threading.RLock()
        self._light: dict = {}
        self._state = BaseState()
        self._wheel_origin = (0.0, 0.0)
        self._budget_s = 0.0
        self._counts = dict(steps=0, physics_steps=0, renders=0)
        self._times = dict(requested=0.0, busy=0.0, max_step=0.0, render=0.0, max_render=0.0)
        self.ground_truth = TwinGroundTruth(self)

    # -- life cycle ------------------------------------------------------------------------

    @property
    def connected(self) -> bool:
        return self._sim.connected

    def connect(self) -> None:
        """Start the PyBullet client and build the world (HalError if already connected)."""
        with self._lock:
            self._light = render_light_of(self.world, self.appearance_seed)
            self._sim.connect()
            self._reset_locked()

    def close(self) -> None:
        """Zero command, disconnect PyBullet. Safe to call more than once."""
        with self._lock:
            self._sim.close()

    # -- BaseModel -------------------------------------------------------------------------

    def reset(self) -> BaseState:
        """Back to ``start`` at rest, wheel counters at zero; returns that state."""
        with self._lock:
            self._sim.ground_truth.teleport(self.start)
            return self._reset_locked()

    def _reset_locked(self) -> BaseState:
        odo = self._sim.read().odometry
        self._wheel_origin = (odo.left_m, odo.right_m)
        self._budget_s = 0.0
        self._state = BaseState()
        return self._state

    def step(self, dt_s: float, v_cmd_mps: float, w_cmd_radps: float) -> BaseState:
        """Advance ``dt_s`` seconds of simulated time under the commanded body velocity."""
        t0 = time.perf_counter()
        with self._lock:
            if not self._sim.connected or dt_s <= 0:
                return self._state  # closed under a late emulator cycle: report the last state
            pdt = self.sim_config.physics_dt_s
            self._sim.apply(VelocityCommand(v_cmd_mps, w_cmd_radps))
            self._budget_s += dt_s
            # a tiny epsilon so 0.02 s of 1/250 s steps is 5 steps, not 4 by rounding
            n = int(self._budget_s / pdt + 1e-9)
            if n > 0:
                self._budget_s -= n * pdt
                for _ in range(n):
                    self._sim.tick()
                self._state = self._measure_locked(n * pdt)
            self._counts["steps"] += 1
            self._counts["physics_steps"] += n
            self._times["requested"] += dt_s
            state = self._state
        spent = time.perf_counter() - t0
        self._times["busy"] += spent
        self._times["max_step"] = max(self._times["max_step"], spent)
        return state

    def _measure_locked(self, elapsed_s: float) -> BaseState:
        frame = self._sim.read()
        odo = frame.odometry
        pose = self._sim.ground_truth.true_pose()
        prev = self._state
        left = odo.left_m - self._wheel_origin[0]
        right = odo.right_m - self._wheel_origin[1]
        v = ((left - prev.left_m) + (right - prev.right_m)) / 2.0 / elapsed_s
        c, s = math.cos(self.start.yaw_rad), math.sin(self.start.yaw_rad)
        dx, dy = pose.x_m - self.start.x_m, pose.y_m - self.start.y_m
        return BaseState(x_m=c * dx + s * dy, y_m=-s * dx + c * dy, yaw_rad=wrap_angle(pose.yaw_rad - self.start.yaw_rad),
                         v_mps=v, w_radps=float(frame.imu_yaw_rate_radps), left_m=left, right_m=right,
                         accel_mps2=(v - prev.v_mps) / elapsed_s)

    # -- what the camera and the metrics need ----------------------------------------------

    def render(self, camera: Camera) -> np.ndarray:
        """Render ``camera`` mounted on the Limo, with the world's light: (H, W, 3) uint8 RGB."""
        t0 = time.perf_counter()
        with self._lock:
            sim = self._require("render()")
            pos, orn = p.getBasePositionAndOrientation(sim.robot_id, physicsClientId=sim.client_id)
            rgb = camera.render(sim.client_id, pos, orn, **self._light)
            spent = time.perf_counter() - t0
            self._counts["renders"] += 1
            self._times["render"] += spent
            self._times["max_render"] = max(self._times["max_render"], spent)
        return rgb

    def _require(self, what: str) -> SimLimo:
        if not self._sim.connected:
            raise HalError(f"PyBulletBaseModel.{what}: not connected (the serial twin is closed or not started)")
        return self._sim

    @property
    def sim_time_s(self) -> float:
        with self._lock:
            return self._require("sim_time_s").sim_time_s

    @property
    def timing(self) -> ModelTiming:
        with self._lock:
            c, t = self._counts, self._times
            return ModelTiming(c["steps"], c["physics_steps"], t["requested"],
                               c["physics_steps"] * self.sim_config.physics_dt_s, t["busy"], t["max_step"],
                               c["renders"], t["render"], t["max_render"])

    def _truth(self, what: str):
        return self._require(what).ground_truth


class TwinGroundTruth(GroundTruth):
    """Simulator truth of the twin's body, for metrics only (never for a controller).

    ``teleport`` places the body (at rest) without telling the firmware: wheel counters carry
    on as on a real robot carried by hand, while the euler yaw jumps to the new heading.
    """

    def __init__(self, model: PyBulletBaseModel) -> None:
        self._model = model

    def true_pose(self) -> Pose2D:
        with self._model._lock:
            return self._model._truth("ground_truth.true_pose()").true_pose()

    def collision_count(self) -> int:
        with self._model._lock:
            return self._model._truth("ground_truth.collision_count()").collision_count()

    def teleport(self, pose: Pose2D) -> None:
        with self._model._lock:
            self._model._truth("ground_truth.teleport()").teleport(pose)

    def toppled(self) -> bool:
        with self._model._lock:
            return self._model._truth("ground_truth.toppled()").toppled()


class SimCameraSource:
    """The simulated camera as a camera source for :class:`~limo.serial_base.LimoSerialBase`.

    Same use as :class:`limo.camera.CameraSource`: ``start()`` renders in a background
    thread every ``1 / rate_hz`` s, ``latest()`` returns the newest :class:`CameraFrame` without
    waiting (``None`` before the first), ``close()`` joins the thread; ``read()`` renders one
    frame now. ``stamp_s`` is ``clock()`` (the serial backend's monotonic clock) when the pose
    was taken for the render.
    """

    def __init__(self, model: PyBulletBaseModel, spec: CameraSpec, rate_hz: float = 10.0,
                 clock: Callable[[], float] = time.monotonic) -> None:
        if not rate_hz > 0:
            raise CameraError(f"simulated camera rate_hz must be > 0, got {rate_hz!r}")
        self.spec = spec
        self.rate_hz = rate_hz
        self._model = model
        self._camera = Camera(spec, base_height_m=WHEEL_RADIUS_M)
        self._clock = clock
        self._lock = threading.Lock()
        self._latest: Optional[CameraFrame] = None
        self._error: Optional[str] = None
        self._index = 0
        self._stop = threading.Event()
        self._thread: Optional[threading.Thread] = None

    def read(self) -> CameraFrame:
        """Render one frame now (blocks for the render); raises :class:`CameraError` when the sim is gone."""
        stamp = self._clock()
        try:
            rgb = self._model.render(self._camera)
        except (HalError, p.error) as exc:
            raise CameraError(f"simulated camera: {exc}") from exc
        with self._lock:
            frame = CameraFrame(stamp_s=stamp, rgb=rgb, index=self._index)
            self._index += 1
            self._latest = frame
        return frame

    def start(self) -> None:
        """Render in the background from now on (a no-op when already running)."""
        if self._thread is not None:
            return
        with self._lock:  # a frame or error of an earlier connection must not show in this one
            self._latest, self._error = None, None
        self._stop.clear()
        self._thread = threading.Thread(target=self._render_loop, name="sim-camera", daemon=True)
        self._thread.start()

    def _render_loop(self) -> None:
        period = 1.0 / self.rate_hz
        next_due = time.monotonic()
        while not self._stop.is_set():
            try:
                self.read()
            except CameraError as exc:
                with self._lock:
                    self._error = str(exc)
                return
            # a slow render does not make the next ones come in a burst
            next_due = max(next_due + period, time.monotonic())
            self._stop.wait(max(0.0, next_due - time.monotonic()))

    def wait_for_frame(self, timeout_s: float) -> CameraFrame:
        """Block until the render thread has a frame (as :meth:`limo.camera.CameraSource.wait_for_frame`)."""
        deadline = time.monotonic() + timeout_s
        while (frame := self.latest()) is None:
            if time.monotonic() >= deadline:
                raise CameraError(f"simulated camera delivered no frame within {timeout_s:g} s")
            time.sleep(0.005)
        return frame

    def latest(self) -> Optional[CameraFrame]:
        """The newest frame (``None`` before the first); raises :class:`CameraError` if rendering failed."""
        with self._lock:
            if self._error is not None:
                raise CameraError(self._error)
            return self._latest

    def close(self) -> None:
        """Stop and join the render thread. Safe to call more than once."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
            self._thread = None


class SerialTwinLimo(LimoSerialBase):
    """The serial backend driving the simulated Limo through the emulator on a pseudo-terminal.

    ``world`` (a :class:`~sim.world_spec.WorldSpec` or ``None`` for a plain floor), ``sim_config``,
    ``start`` and ``appearance_seed`` mean what they mean for :class:`~sim.hal.SimLimo`;
    ``serial_config`` configures the serial backend (its ``port`` and ``camera`` are replaced by
    the pty and the simulated camera); ``twin_config`` the rest. ``__init__`` only stores;
    ``connect()`` starts PyBullet, the emulator and the camera, then opens the port; ``close()``
    undoes it in reverse (module docstring). While connected: :attr:`ground_truth`,
    :attr:`emulator` (its ``commanded``, ``stats``, fault injection), :attr:`model` (timing).
    """

    def __init__(self, world: Any = None, sim_config: SimConfig = SimConfig(),
                 start: Pose2D = Pose2D(0.0, 0.0, 0.0), appearance_seed: int = 0,
                 serial_config: LimoSerialConfig = LimoSerialConfig(),
                 twin_config: SerialTwinConfig = SerialTwinConfig(),
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.model = PyBulletBaseModel(sim_config, world=world, start=start, appearance_seed=appearance_seed)
        #: the simulated camera feeding SensorFrame.rgb (None when ``sim_config.camera_enabled`` is off)
        self.camera_source = (SimCameraSource(self.model, sim_config.camera, twin_config.camera_rate_hz, clock=clock)
                              if sim_config.camera_enabled else None)
        # the port is the emulator's pty, known only once it runs; "twin" is a placeholder
        super().__init__(replace(serial_config, port="twin", camera=None), camera=self.camera_source, clock=clock)
        self.twin_config = twin_config
        self.emulator: Optional[LimoEmulator] = None

    @property
    def ground_truth(self) -> GroundTruth:
        """Simulator truth of the body behind the serial link (raises HalError when not connected)."""
        return self.model.ground_truth

    def connect(self) -> None:
        if self.emulator is not None or self.model.connected:
            raise HalError("SerialTwinLimo is already connected")
        self.model.connect()
        try:
            self.emulator = LimoEmulator(self.model, self.twin_config.emulator)
            self.config = replace(self.config, port=self.emulator.start())
            super().connect()
            self._wait_for_first_image()
        except BaseException:
            self.close()
            raise

    def _wait_for_first_image(self) -> None:
        # as with SimLimo, the first read() after connect has an image (a render takes ~25-70 ms)
        if self.camera_source is None:
            return
        deadline = time.monotonic() + FIRST_IMAGE_TIMEOUT_S
        while self.camera_source.latest() is None:
            if time.monotonic() > deadline:
                raise HalError(f"the simulated camera rendered no image within {FIRST_IMAGE_TIMEOUT_S} s")
            time.sleep(0.005)

    def close(self) -> None:
        """Zero velocity over the wire, then port, camera, emulator and PyBullet. Safe to call twice."""
        try:
            super().close()
        finally:
            self._stop_twin()

    def _stop_twin(self) -> None:
        emulator = self.emulator
        try:
            if emulator is not None:
                deadline = time.monotonic() + self.twin_config.stop_settle_s
                while not emulator.commanded.is_zero and time.monotonic() < deadline:
                    time.sleep(0.005)
                emulator.stop()
        finally:
            self.emulator = None
            self.model.close()


# ---------------------------------------------------------------------------------- measurement


def _measure(args: argparse.Namespace) -> int:
    from sim.worlds import load_world  # noqa: PLC0415

    world = load_world(args.world) if args.world != "none" else None
    start = Pose2D(0.0, 0.0, 0.0)
    if world is not None:
        (x0, y0), (x1, y1) = world.routes.walkthrough[:2]
        start = Pose2D(x0, y0, math.atan2(y1 - y0, x1 - x0))
    camera = args.width > 0 and args.height > 0
    sim_config = SimConfig(width_px=args.width, height_px=args.height) if camera else SimConfig(camera_enabled=False)
    serial_config = LimoSerialConfig(control_period_s=0.1)
    twin = SerialTwinLimo(world, sim_config, start, serial_config=serial_config,
                          twin_config=SerialTwinConfig(camera_rate_hz=args.camera_hz))
    wall0 = time.monotonic()
    with twin as base:
        connected_s = time.monotonic() - wall0
        emu = base.emulator
        stats0, link0, timing0 = emu.stats, base.link_stats(), base.model.timing
        t0 = time.monotonic()
        images = 0
        tick_ends: List[float] = []
        last_image = None
        while time.monotonic() - t0 < args.seconds:
            phase = (time.monotonic() - t0) % 4.0
            base.apply(VelocityCommand(0.3, 0.0) if phase < 2.0 else VelocityCommand(0.0, 0.6))
            base.tick()
            frame = base.read()
            if frame.rgb is not None and frame.rgb is not last_image:
                images += 1
                last_image = frame.rgb
            tick_ends.append(time.monotonic())
        elapsed = time.monotonic() - t0
        stats, link, timing = emu.stats, base.link_stats(), base.model.timing
        truth = base.ground_truth.true_pose()
    ticks = np.diff(tick_ends) if len(tick_ends) > 1 else np.zeros(1)
    steps = timing.steps - timing0.steps
    renders = timing.renders - timing0.renders
    camera_text = f"camera {args.width}x{args.height} at {args.camera_hz} Hz" if camera else "camera off"
    print(f"serial twin, world {args.world}, {camera_text}, {elapsed:.1f} s driven (connect {connected_s:.2f} s)")
    print(f"  emulator steps     {steps / elapsed:6.1f} Hz  (nominal {twin.twin_config.emulator.feedback_rate_hz:.0f})")
    physics_steps = timing.physics_steps - timing0.physics_steps
    print(f"  physics per step   {1e3 * (timing.busy_s - timing0.busy_s) / max(steps, 1):6.2f} ms mean, "
          f"{1e3 * timing.max_step_s:.2f} ms max  ({physics_steps / max(steps, 1):.2f} physics steps of "
          f"{1e3 * sim_config.physics_dt_s:.2f} ms)")
    print(f"  render             {1e3 * (timing.render_busy_s - timing0.render_busy_s) / max(renders, 1):6.2f} ms mean, "
          f"{1e3 * timing.max_render_s:.2f} ms max, {renders / elapsed:.1f} renders/s, "
          f"{images / elapsed:.1f} new images/s at read()")
    print(f"  commands received  {(stats.motion_commands - stats0.motion_commands) / elapsed:6.1f} Hz "
          f"(backend sends at {serial_config.command_rate_hz:.0f} Hz + one per apply)")
    print(f"  feedback received  {(link.feedback_frames - link0.feedback_frames) / 6 / elapsed:6.1f} cycles/s, "
          f"{link.bad_checksums} bad checksums")
    print(f"  control tick       {1e3 * float(np.mean(ticks)):6.1f} ms mean, {1e3 * float(np.max(ticks)):.1f} ms max "
          f"(period {1e3 * serial_config.control_period_s:.0f} ms)")
    print(f"  simulated time     {timing.sim_time_s - timing0.sim_time_s:.3f} s advanced while driving "
          f"{elapsed:.3f} s wall ({timing.requested_s - timing0.requested_s:.3f} s requested by the emulator)")
    print(f"  true pose at end   x={truth.x_m:.2f} y={truth.y_m:.2f} yaw={truth.yaw_rad:.2f}")
    return 0


def main(argv: Optional[List[str]] = None) -> int:
    parser = Parser(
        prog="python -m sim.serial_twin",
        description="Drive the serial twin (the simulated Limo behind the base emulator on a pseudo-terminal) "
                    "forward and turning, and print what each emulator step and render costs, the command "
                    "and feedback rates achieved over the link, and simulated vs wall time.")
    parser.add_argument("--world", default="hospital", help="world name or YAML path; 'none' for a plain floor")
    parser.add_argument("--seconds", type=positive_float, default=8.0, help="how long to drive (default 8)")
    parser.add_argument("--width", type=non_negative_int, default=320, help="camera width in pixels (0: no camera)")
    parser.add_argument("--height", type=non_negative_int, default=240, help="camera height in pixels")
    parser.add_argument("--camera-hz", type=positive_float, default=10.0, help="renders per second (default 10)")
    args = parser.parse_args(argv)
    stop_on_signals()
    from core.configfile import ConfigError  # noqa: PLC0415

    try:
        return _measure(args)
    except (ConfigError, HalError, ValueError) as exc:
        print(f"serial_twin: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt as exc:
        print(f"serial_twin: {interrupted_by(exc)}", file=sys.stderr)
        return exit_status(exc)


if __name__ == "__main__":
    sys.exit(main())
