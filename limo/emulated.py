"""The serial Limo backend wired to its own in-process emulator: every command crosses a real
pseudo-terminal as bytes, no hardware needed."""

from __future__ import annotations

from dataclasses import replace
from typing import Optional

from core.hal import HalError
from limo.camera import CameraSource
from limo.config import LimoSerialConfig
from limo.emulator.firmware import EmulatorConfig, LimoEmulator
from limo.emulator.models import BaseModel
from limo.serial_base import LimoSerialBase


class EmulatedSerialLimo(LimoSerialBase):
    """The serial backend wired to its own in-process emulator: every command crosses a real
    pseudo-terminal as bytes. ``connect()`` starts the emulator and points the backend at it;
    ``close()`` stops the base, closes the port, then stops the emulator. ``config.port`` is
    ignored. Useful for the HAL conformance test and for driving the stack without hardware.
    """

    def __init__(self, config: LimoSerialConfig = LimoSerialConfig(), camera: Optional[CameraSource] = None,
                 model: Optional[BaseModel] = None, emulator_config: EmulatorConfig = EmulatorConfig()) -> None:
        super().__init__(config, camera=camera)
        self._model_for_emulator = model
        self._emulator_config = emulator_config
        self.emulator: Optional[LimoEmulator] = None

    def connect(self) -> None:
        if self.emulator is not None:
            raise HalError("EmulatedSerialLimo is already connected")
        self.emulator = LimoEmulator(self._model_for_emulator, self._emulator_config)
        try:
            self.config = replace(self.config, port=self.emulator.start())
            super().connect()
        except BaseException:
            if self.emulator is not None:  # super().connect() may have closed it already
                self.emulator.stop()
                self.emulator = None
            raise

    def close(self) -> None:
        try:
            super().close()
        finally:
            if self.emulator is not None:
                self.emulator.stop()
                self.emulator = None
