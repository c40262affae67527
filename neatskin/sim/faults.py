"""The faults a real serial line and a real printer inflict, as a validated value and a text spec.

Rates are probabilities per line (received, or replied). `FaultConfig.parse("corrupt=0.01,drop_ok=0.005")`
reads the CLI's `--faults` spec; the presets `realistic` and `extreme` name the rates the
fault-injection tests run at (lost lines and `ok`s among them, which only a host with lost-ok recovery,
as ours, survives); `noisy` keeps the faults third-party hosts recover from (corrupted lines, busy storms).
"""

from __future__ import annotations

from dataclasses import dataclass, fields, replace

from neatskin.errors import ConfigError

_RATES = ("corrupt", "drop_line", "drop_ok", "duplicate", "busy_storm")


@dataclass(frozen=True)
class FaultConfig:
    corrupt: float = 0.0  # a received line has one byte changed (checksum or line-number error)
    drop_line: float = 0.0  # a received line never arrives
    drop_ok: float = 0.0  # an `ok` is never sent
    duplicate: float = 0.0  # a reply line is sent twice, back to back
    busy_storm: float = 0.0  # a command answers with a burst of `echo:busy: processing` first
    reset_after: int | None = None  # reboot (`start`) after this many executed lines
    dead_after: int | None = None  # stop answering after this many executed lines
    dead_closes: bool = False  # ... and close the port (the host reads EIO) instead of going silent

    def __post_init__(self) -> None:
        for name in _RATES:
            value = getattr(self, name)
            if not 0.0 <= value <= 1.0:
                raise ConfigError(
                    f"fault rate {name}={value!r} is not a probability",
                    field=name,
                    fix="give a number between 0 and 1, e.g. corrupt=0.01",
                )
        for name in ("reset_after", "dead_after"):
            value = getattr(self, name)
            if value is not None and value < 1:
                raise ConfigError(
                    f"{name}={value!r} must be a positive line count",
                    field=name,
                    fix=f"give {name}=N with N >= 1, or leave it out",
                )

    @property
    def any(self) -> bool:
        return any(getattr(self, f.name) for f in fields(self))

    @classmethod
    def preset(cls, name: str) -> FaultConfig:
        if name == "none":
            return cls()
        if name == "noisy":  # what a third-party host (Printrun, OctoPrint) recovers from: no line or `ok` is lost
            return cls(corrupt=0.003, busy_storm=0.002)
        if name == "realistic":  # a noisy USB line: about one fault per few hundred lines
            return cls(corrupt=0.003, drop_line=0.001, drop_ok=0.002, duplicate=0.002, busy_storm=0.002)
        if name == "extreme":
            return cls(corrupt=0.08, drop_line=0.04, drop_ok=0.05, duplicate=0.05, busy_storm=0.03)
        raise ConfigError(f"unknown fault preset {name!r}", field="faults", fix="use none, noisy, realistic or extreme")

    @classmethod
    def parse(cls, spec: str | None) -> FaultConfig:
        """`realistic`, `extreme`, `none`, or `key=value,...` (optionally after a preset: `realistic,reset_after=500`)."""
        if not spec:
            return cls()
        config = cls()
        names = {f.name for f in fields(cls)}
        for part in (p.strip() for p in spec.split(",") if p.strip()):
            if "=" not in part:
                config = replace(
                    cls.preset(part),
                    **{k: getattr(config, k) for k in names if getattr(config, k) != getattr(cls(), k)},
                )
                continue
            key, _, value = part.partition("=")
            key = key.strip().replace("-", "_")
            if key not in names:
                raise ConfigError(
                    f"unknown fault {key!r} in {spec!r}", field="faults", fix=f"use one of {', '.join(sorted(names))}"
                )
            try:
                if key in _RATES:
                    parsed: object = float(value)
                elif key == "dead_closes":
                    parsed = value.strip().lower() in ("1", "true", "yes", "on")
                else:
                    parsed = int(value)
            except ValueError:
                raise ConfigError(
                    f"fault {key}={value!r} is not a number", field="faults", fix=f"write {key}=<number>"
                ) from None
            config = replace(config, **{key: parsed})  # type: ignore[arg-type]  # typed per key above
        return config
