"""SkinModel: the simulated skin the rest of the rig uses — press in, channel and pair resistances,
probe force and position Jacobian out — plus the optional skin-side rig effects (docs/skin.md, the scene's variability sources).

Fidelities:
- "deformation": each channel's resistance is the integral of rho / A(s) along it under the
  pinch profile of `deformation.py` (Gauss-Legendre, `PinchParams.nodes_per_panel`).
- "network": a closed-form factor per channel (the pinch at the channel point nearest the probe,
  applied over one probe diameter: `deformation.nearest_point_factor`). About 6x cheaper per
  channel; its error against the deformation model is measured in tests/test_skin_model.py and
  stated in docs/skin.md (rms 6 % of the largest change, worst ~50 %).

Rig effects, each off by default: fluid resistivity drift with temperature (`temperature_c`),
probe placement error (`placement_sigma_mm`, applied by the runner through
`placement_error_mm`), silicone hysteresis (`hysteresis_fraction`: on unloading the skin lags
behind the probe). Everything random takes an explicit numpy Generator.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import cached_property
from typing import TYPE_CHECKING

import numpy as np

from neatskin.layout import Layout
from neatskin.skin.deformation import (
    PinchParams,
    factor_and_length_fraction,
    nearest_point_factor,
    pinched_length_fraction,
    resistance_factor,
)
from neatskin.skin.network import equivalent_resistance

if TYPE_CHECKING:  # the kernel module imports the FE solver (scipy): only a model that has a kernel loads it
    from neatskin.skin.kernel import PinchKernel

FIDELITIES = ("deformation", "network")
DEFORMATIONS = ("parametric", "fe-kernel")


@dataclass(frozen=True)
class SkinModel:
    """A simulated skin: a layout, a probe and the model choices. Frozen; nothing computed at construction.

    youngs_modulus_pa / poisson_ratio: EcoFlex 00-30 (E ~ 70 kPa, nearly incompressible).
    temperature_c: fluid temperature; None = no drift. Resistivity follows
        rho(T) = rho_layout * (1 + resistivity_tempco_per_k * (T - reference_temperature_c)),
        with -2 %/K for saline (its conductivity rises ~2 %/K).
    hysteresis_fraction: 0 = elastic. On unloading (depth below the press's peak depth) the skin
        recovers only partly: it pinches as at depth + h * (peak - depth), and pushes back with
        (1 - h) times the loading force.
    placement_sigma_mm: standard deviation of the probe placement error per axis (the runner draws
        it with `placement_error_mm`).
    channel_height_factor: per channel, its height over the layout's (fabrication spread; None =
        as drawn). R0 scales by 1 / h, and a press takes the same absolute height off every
        channel, so the pinch fraction scales by 1 / h (`skin.variability.fabrication_heights`).
    displaced_fluid_fraction: the sealed network keeps this share of the fluid a press displaces
        in its channels, which widen uniformly by 1 + e so that the fluid volume is conserved
        (0 = off: the displaced fluid goes elsewhere, e.g. into the electrode wells). A press then
        lowers the resistance of the channels it does not pinch: a negative dR on far pairs.
    """

    layout: Layout
    fidelity: str = "deformation"
    probe_radius_mm: float = 2.75
    pinch: PinchParams = field(default_factory=PinchParams)
    youngs_modulus_pa: float = 70e3
    poisson_ratio: float = 0.49
    temperature_c: float | None = None
    reference_temperature_c: float = 25.0
    resistivity_tempco_per_k: float = -0.02
    hysteresis_fraction: float = 0.0
    placement_sigma_mm: float = 0.0
    channel_height_factor: tuple[float, ...] | None = None
    displaced_fluid_fraction: float = 0.0
    kernel: PinchKernel | None = field(default=None, compare=False)

    def __post_init__(self) -> None:
        if self.fidelity not in FIDELITIES:
            raise ValueError(f"fidelity must be one of {FIDELITIES}, got {self.fidelity!r}")
        for name in ("probe_radius_mm", "youngs_modulus_pa"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be a positive number, got {value!r}")
        if not 0 <= self.poisson_ratio < 0.5:
            raise ValueError(f"poisson_ratio must be in [0, 0.5), got {self.poisson_ratio!r}")
        if not 0 <= self.hysteresis_fraction < 1:
            raise ValueError(f"hysteresis_fraction must be in [0, 1), got {self.hysteresis_fraction!r}")
        if not (math.isfinite(self.placement_sigma_mm) and self.placement_sigma_mm >= 0):
            raise ValueError(f"placement_sigma_mm must be >= 0, got {self.placement_sigma_mm!r}")
        if not 0 <= self.displaced_fluid_fraction <= 1:
            raise ValueError(f"displaced_fluid_fraction must be in [0, 1], got {self.displaced_fluid_fraction!r}")
        if self.channel_height_factor is not None:
            heights = np.asarray(self.channel_height_factor, float)
            if heights.shape != (self.layout.n_channels,) or not np.all(np.isfinite(heights) & (heights > 0)):
                raise ValueError(
                    f"channel_height_factor must be {self.layout.n_channels} positive numbers (one per channel "
                    f"of layout '{self.layout.name}'), got {self.channel_height_factor!r}"
                )
        if self.temperature_c is not None and self.resistivity_factor(self.temperature_c) <= 0:
            raise ValueError(
                f"temperature_c = {self.temperature_c} drives the resistivity to <= 0; "
                "check resistivity_tempco_per_k and reference_temperature_c"
            )

    # ---- resistances -----------------------------------------------------------------------

    def resistivity_factor(self, temperature_c) -> np.ndarray | float:
        """rho(T) / rho_layout (linear temperature coefficient)."""
        return 1.0 + self.resistivity_tempco_per_k * (np.asarray(temperature_c, float) - self.reference_temperature_c)

    @property
    def deformation(self) -> str:
        """'fe-kernel' with a pinch kernel (finite-element A/A0, skin/kernel.py), else 'parametric' (PinchParams)."""
        return "parametric" if self.kernel is None else "fe-kernel"

    def _kernel_pass(self, x, y, depth) -> tuple[np.ndarray, np.ndarray]:
        assert self.kernel is not None
        from neatskin.skin.kernelpinch import kernel_factor_and_share

        return kernel_factor_and_share(self.layout, self.kernel, x, y, depth)

    @cached_property
    def _heights(self) -> np.ndarray | None:
        return None if self.channel_height_factor is None else np.asarray(self.channel_height_factor, float)

    @property
    def _pinch_scale(self) -> np.ndarray | None:
        return None if self._heights is None else 1.0 / self._heights

    @cached_property
    def channel_baseline_ohm(self) -> np.ndarray:
        """Undeformed resistance of every channel, (channels,): the layout's, over the fabricated heights."""
        base = self.layout.channel_resistance_ohm
        return base if self._heights is None else base / self._heights

    @cached_property
    def channel_volume_mm3(self) -> np.ndarray:
        """Undeformed fluid volume of every channel, (channels,)."""
        volume = np.array([c.length_mm * c.area_mm2 for c in self.layout.channels])
        return volume if self._heights is None else volume * self._heights

    def channel_resistance_ohm(
        self,
        x_mm,
        y_mm,
        depth_mm,
        peak_depth_mm=None,
        temperature_c=None,
        *,
        resistivity_factor=None,
        extra_factor=None,
    ) -> np.ndarray:
        """Resistance of every channel for every press, (n, channels); inf for a channel pinched shut.

        depth_mm <= 0 means not touching (baseline). peak_depth_mm (unloading branch) only matters
        with hysteresis; temperature_c (per press or scalar) overrides the model's temperature.
        resistivity_factor (per press or scalar) multiplies rho (drift); extra_factor (n or 1,
        channels) is added to every channel's R / R0 (a residual dent from earlier presses)."""
        x, y, depth = _as_presses(x_mm, y_mm, depth_mm)
        depth = self.effective_depth_mm(depth, peak_depth_mm)
        widening = None
        if self.kernel is not None and self.fidelity == "deformation":
            factor, share = self._kernel_pass(x, y, depth)
            if self.displaced_fluid_fraction > 0:
                widening = self._widening(share * self.channel_volume_mm3)
        elif self.displaced_fluid_fraction > 0 and self.fidelity == "deformation":  # one quadrature for both
            factor, share = factor_and_length_fraction(
                self.layout, x, y, depth, self.probe_radius_mm, self.pinch, self._pinch_scale
            )
            widening = self._widening(share * self.channel_volume_mm3)
        else:
            factor = self.pinch_factor(x, y, depth)
        if extra_factor is not None:
            factor = factor + np.asarray(extra_factor, float)
        if self.displaced_fluid_fraction > 0:
            if widening is None:
                widening = self.fluid_widening(x, y, depth)
            factor = factor / widening[:, None]
        resistance = factor * self.channel_baseline_ohm
        temperature = self.temperature_c if temperature_c is None else temperature_c
        if temperature is not None:
            resistance = resistance * np.reshape(self.resistivity_factor(temperature), (-1, 1))
        if resistivity_factor is not None:
            resistance = resistance * np.reshape(np.asarray(resistivity_factor, float), (-1, 1))
        return resistance

    def pinch_factor(self, x_mm, y_mm, depth_mm) -> np.ndarray:
        """R / R0 of every channel from the pinch alone (no fluid widening, drift or dents), (n, channels)."""
        x, y, depth = _as_presses(x_mm, y_mm, depth_mm)
        if self.kernel is not None and self.fidelity == "deformation":
            return self._kernel_pass(x, y, depth)[0]
        args = (self.layout, x, y, depth, self.probe_radius_mm, self.pinch)
        scale = None if self._heights is None else 1.0 / self._heights
        if self.fidelity == "deformation":
            return resistance_factor(*args, pinch_scale=scale)
        return nearest_point_factor(*args, pinch_scale=scale)

    def pinched_volume_mm3(self, x_mm, y_mm, depth_mm) -> np.ndarray:
        """Fluid volume each press takes out of each channel under the probe, (n, channels)."""
        x, y, depth = _as_presses(x_mm, y_mm, depth_mm)
        if self.kernel is not None and self.fidelity == "deformation":
            return self._kernel_pass(x, y, depth)[1] * self.channel_volume_mm3
        scale = None if self._heights is None else 1.0 / self._heights
        share = pinched_length_fraction(self.layout, x, y, depth, self.probe_radius_mm, self.pinch, scale)
        return share * self.channel_volume_mm3

    def fluid_widening(self, x_mm, y_mm, depth_mm) -> np.ndarray:
        """1 + e per press, (n,): the uniform widening of every channel's cross-section that keeps the
        share `displaced_fluid_fraction` of the displaced volume dV in the network,
        (1 + e) (V - dV) = V - dV + f dV."""
        return self._widening(self.pinched_volume_mm3(x_mm, y_mm, depth_mm))

    def _widening(self, pinched_volume_mm3: np.ndarray) -> np.ndarray:
        lost = pinched_volume_mm3.sum(axis=1)
        total = float(self.channel_volume_mm3.sum())
        with np.errstate(divide="ignore", invalid="ignore"):
            return 1.0 + self.displaced_fluid_fraction * lost / np.maximum(total - lost, 0.0)

    def channel_fluid_volume_mm3(self, x_mm, y_mm, depth_mm) -> np.ndarray:
        """Fluid volume of every channel under each press, (n, channels): pinched, then widened."""
        lost = self.pinched_volume_mm3(x_mm, y_mm, depth_mm)
        widening = self.fluid_widening(x_mm, y_mm, depth_mm) if self.displaced_fluid_fraction > 0 else 1.0
        return (self.channel_volume_mm3 - lost) * np.reshape(widening, (-1, 1))

    def pair_resistance_ohm(
        self,
        x_mm,
        y_mm,
        depth_mm,
        peak_depth_mm=None,
        temperature_c=None,
        *,
        resistivity_factor=None,
        extra_factor=None,
    ) -> np.ndarray:
        """Equivalent resistance of every electrode pair (layout.pairs order), (n, pairs); inf if cut apart."""
        resistance = self.channel_resistance_ohm(
            x_mm,
            y_mm,
            depth_mm,
            peak_depth_mm,
            temperature_c,
            resistivity_factor=resistivity_factor,
            extra_factor=extra_factor,
        )
        with np.errstate(divide="ignore"):
            return equivalent_resistance(self.layout, 1.0 / resistance)

    @property
    def has_analytic_jacobian(self) -> bool:
        """Whether `pair_resistance_and_jacobian_ohm` applies: the parametric pinch with the "deformation" fidelity, no
        fluid widening and no temperature drift (skin/modelgrad.py differentiates that model only)."""
        return (
            self.fidelity == "deformation"
            and self.kernel is None
            and self.displaced_fluid_fraction == 0
            and self.temperature_c is None
        )

    def pair_resistance_and_jacobian_ohm(self, x_mm, y_mm, depth_mm) -> tuple[np.ndarray, np.ndarray]:
        """`pair_resistance_ohm` (to rounding: ~1e-15 relative) and its derivatives in (x, y, depth), ohm/mm,
        (n, pairs) and (n, pairs, 3), from one pass (skin/modelgrad.py); NaN where a channel is shut. Only where
        `has_analytic_jacobian` (ValueError otherwise)."""
        if not self.has_analytic_jacobian:
            raise ValueError(
                "pair_resistance_and_jacobian_ohm differentiates the parametric pinch with the 'deformation' fidelity "
                "and no fluid widening or temperature drift; difference pair_resistance_ohm for this skin"
            )
        from neatskin.skin.modelgrad import factor_and_gradient, pair_resistance_and_gradient

        x, y, depth = _as_presses(x_mm, y_mm, depth_mm)
        factor, grad = factor_and_gradient(
            self.layout, x, y, depth, self.probe_radius_mm, self.pinch, self._pinch_scale
        )
        return pair_resistance_and_gradient(self.layout, factor, grad, self.channel_baseline_ohm)

    @cached_property
    def baseline_pair_resistance_ohm(self) -> np.ndarray:
        """R_eq of every pair with nothing pressing (at the model's temperature), (pairs,)."""
        return self.pair_resistance_ohm(0.0, 0.0, 0.0)[0]

    def jacobian_mm(self, x_mm, y_mm, depth_mm, step_mm: float = 0.01) -> np.ndarray:
        """d R_eq / d(x, y) in ohm/mm by central differences, (n, pairs, 2); NaN where R_eq is inf."""
        x, y, depth = _as_presses(x_mm, y_mm, depth_mm)
        n = x.shape[0]
        xs = np.concatenate([x + step_mm, x - step_mm, x, x])
        ys = np.concatenate([y, y, y + step_mm, y - step_mm])
        r = self.pair_resistance_ohm(xs, ys, np.tile(depth, 4)).reshape(4, n, -1)
        with np.errstate(invalid="ignore"):
            jac = np.stack([r[0] - r[1], r[2] - r[3]], axis=-1) / (2.0 * step_mm)
        jac[~np.isfinite(jac)] = np.nan
        return jac

    # ---- mechanics -------------------------------------------------------------------------

    def effective_depth_mm(self, depth_mm, peak_depth_mm=None) -> np.ndarray:
        """The depth the channels feel: the probe depth, or on unloading with hysteresis,
        depth + h * (peak - depth)."""
        depth = np.asarray(depth_mm, float)
        if peak_depth_mm is None or self.hysteresis_fraction == 0:
            return depth
        peak = np.maximum(np.asarray(peak_depth_mm, float), depth)
        lagged = depth + self.hysteresis_fraction * (peak - depth)
        return np.where(depth > 0, lagged, depth)

    def contact_force_n(self, depth_mm, loading: bool = True) -> np.ndarray:
        """Force (N) on the flat probe at each depth, (n,); 0 where not touching.

        Sneddon's flat circular punch on an elastic half-space, F = 2 a E d / (1 - nu^2), times a
        bonded-layer correction kappa(a/T) = 1 + 1.33 (a/T) + 1.33 (a/T)^3 that interpolates between
        the half-space (kappa -> 1) and the thin incompressible layer (kappa ~ (a/T)^3) limits; the
        coefficients are this model's choice, not a fit to published tables (Hayes et al. 1972).
        Linear elasticity at strains up to d/T ~ 0.6 and an approximate kappa: take it as +-30 %.
        For the paper's press (a = 2.75 mm, T = 5.5 mm, d = 3.5 mm, E = 70 kPa) F ~ 3.2 N.
        With hysteresis, the unloading branch (loading=False) is (1 - h) times the loading one."""
        depth_m = np.maximum(np.atleast_1d(np.asarray(depth_mm, float)), 0.0) * 1e-3
        a_m = self.probe_radius_mm * 1e-3
        ratio = self.probe_radius_mm / self.layout.thickness_mm
        kappa = 1.0 + 1.33 * ratio + 1.33 * ratio**3
        force = 2.0 * a_m * self.youngs_modulus_pa * depth_m / (1.0 - self.poisson_ratio**2) * kappa
        return force if loading else force * (1.0 - self.hysteresis_fraction)

    def placement_error_mm(self, x_mm, y_mm, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        """Where the probe actually lands: the model's placement_sigma_mm applied (see the module function)."""
        return placement_error_mm(x_mm, y_mm, self.placement_sigma_mm, rng)


def placement_error_mm(x_mm, y_mm, sigma_mm: float, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Commanded (x, y) -> landed (x, y): independent Gaussian error of sigma_mm per axis.
    sigma_mm = 0 returns the inputs unchanged and draws nothing from rng."""
    x, y = np.asarray(x_mm, float), np.asarray(y_mm, float)
    if sigma_mm == 0:
        return x.copy(), y.copy()
    err = rng.normal(0.0, sigma_mm, size=(2,) + np.broadcast_shapes(x.shape, y.shape))
    return x + err[0], y + err[1]


def _as_presses(x_mm, y_mm, depth_mm) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    x, y, depth = np.broadcast_arrays(*(np.atleast_1d(np.asarray(v, float)) for v in (x_mm, y_mm, depth_mm)))
    if x.ndim != 1:
        raise ValueError(f"x_mm, y_mm, depth_mm must be scalars or 1-D arrays of presses, got shape {x.shape}")
    for name, value in (("x_mm", x), ("y_mm", y), ("depth_mm", depth)):
        if not np.all(np.isfinite(value)):
            bad = int(np.flatnonzero(~np.isfinite(value))[0])
            raise ValueError(f"{name} must be finite; press {bad} has {name} = {value[bad]}")
    return x, y, depth
