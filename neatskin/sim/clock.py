"""The simulated printer's clocks: virtual seconds that jump to what it waits for, or real time scaled."""

from __future__ import annotations

import time

from neatskin.errors import ConfigError


class VirtualClock:
    """Simulated seconds that jump forward to whatever the printer waits for."""

    def __init__(self) -> None:
        self.t_s = 0.0

    def now(self) -> float:
        return self.t_s

    def wait_until(self, t_s: float) -> float:
        self.t_s = max(self.t_s, t_s)
        return 0.0


class ScaledClock:
    """Real time, `speed` times faster (speed=1: wall clock)."""

    def __init__(self, speed: float = 1.0) -> None:
        if speed <= 0:
            raise ConfigError(f"time speed {speed!r} must be > 0", field="speed", fix="use e.g. 1 or 10")
        self.speed = speed
        self._t0 = time.monotonic()

    def now(self) -> float:
        return (time.monotonic() - self._t0) * self.speed

    def wait_until(self, t_s: float) -> float:
        return max(0.0, (t_s - self.now()) / self.speed)
