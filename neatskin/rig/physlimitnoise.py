"""The reading noise of one press's dR per pair in a dry run: the simulated DAQ's estimator spread, averaged over the
estimates the recorder's press values actually average (neatskin.acquisition.pressvalues.sweeps_used).

`rig.physlimit` (the electronics-only bound and the floors) and `rig.simcampaign.pair_noise_std_ohm` (the simulated
campaigns, the paper-pairing fit) both take it from here. A press's dR is the mean of its pressed estimates minus the
mean of its baseline estimates, every one an independent draw, so its variance is var_baseline / n_baseline +
var_pressed / n_pressed per pair, with the counts the selection gives on the press's nominal marks (the plan's
typical phase durations, as the simulated printer's clock places them). The counts are per pair: each pair's live
window inside the hold counts, whether or not its whole sweep does (paper.toml: 6 baseline, 3 or 4 pressed).
"""

from __future__ import annotations

import numpy as np

from neatskin.acquisition.pressvalues import sweeps_used
from neatskin.rig.plan import Plan
from neatskin.rig.protocol import CampaignProtocol
from neatskin.sim.daq import SimulatedDAQ
from neatskin.skin.model import SkinModel

# draws of one sweep's estimate per state: the std of a pair's estimate comes from DRAWS - 1 degrees of freedom,
# +-2.2 % (1 / sqrt(2 (DRAWS - 1))); the former 64 draws left +-8.9 % per pair, which was most of the
# spread over pairs the docs quoted (1.07 to 1.50 ohm where the estimator's own std varies by a few %)
DRAWS = 1024
CHUNK = 256  # draws per DAQ call: a state the features path cannot read exactly goes to the waveforms (~30 MB a chunk)


def typical_phases_s(plan: Plan) -> np.ndarray:
    """The median printer time of each phase [travel, descend, press, lift] over the campaign's presses (the
    plan's gcode.motion.phase_durations_s, computed once when the plan was built)."""
    return np.median(plan.phase_s, axis=0)


def nominal_marks(plan: Plan) -> dict[str, int]:
    """A typical press's marks in samples from the recorder's first sample (taken after the travel's M400): the
    descent ends at the surface (`contact`), the press phase at depth (`hold_start`), the dwell after hold_s
    (`hold_end`), each rounded from the cumulative time as the dry run's recorder rounds its clock."""
    phases, rate = typical_phases_s(plan), plan.sweep.rate_hz
    contact_s = float(phases[1])
    hold_start_s = contact_s + float(phases[2])
    hold_end_s = hold_start_s + float(plan.hold_s)
    return {
        "contact": int(round(contact_s * rate)),
        "hold_start": int(round(hold_start_s * rate)),
        "hold_end": int(round(hold_end_s * rate)),
    }


def press_windows(plan: Plan) -> np.ndarray:
    """The live windows of a press's recording (plan.n_sweeps sweeps from its first sample), (sweeps, pairs, 2)."""
    sweep = plan.sweep
    return np.arange(plan.n_sweeps)[:, None, None] * sweep.n_samples + np.asarray(sweep.live_windows)[None]


def press_estimate_counts(plan: Plan) -> tuple[np.ndarray, np.ndarray]:
    """Per pair, how many estimates a typical press's baseline and pressed values average, (pairs,) int each."""
    baseline, pressed = sweeps_used(press_windows(plan), nominal_marks(plan))
    return baseline.sum(axis=0), pressed.sum(axis=0)


def estimate_var_ohm2(
    daq: SimulatedDAQ, plan: Plan, states_ohm: np.ndarray, seed: int, method: str, window: int
) -> np.ndarray:
    """Variance of one sweep's estimate per state and pair, (states, pairs), from DRAWS draws of the DAQ's features
    path at each constant state (NaN where the pair is cut off: an infinite R_eq has no variance). Each state has
    its own random streams (seed, 10**6, k, chunk), so a state's figure does not depend on how many states there
    are."""
    states = np.atleast_2d(np.asarray(states_ohm, float))
    var = np.empty_like(states)
    for k, state in enumerate(states):

        def constant(t: np.ndarray, s: np.ndarray = state) -> np.ndarray:
            return np.broadcast_to(s, (len(t), s.size))

        at_state = SimulatedDAQ(daq.config, constant, noise=daq.noise)
        draws = np.vstack(
            [
                at_state.estimate_sweep(
                    plan.sweep,
                    np.random.default_rng([seed, 10**6, k, chunk]),
                    0.0,
                    method=method,
                    window=window,
                    n_sweeps=CHUNK,
                ).resistance_ohm
                for chunk in range(DRAWS // CHUNK)
            ]
        )
        with np.errstate(invalid="ignore"):  # a pair cut off (R_eq infinite): NaN, no information
            var[k] = draws.var(axis=0, ddof=1)
    return var


def dr_noise_std_ohm(
    protocol: CampaignProtocol,
    plan: Plan,
    skin: SkinModel,
    daq: SimulatedDAQ,
    x: np.ndarray,
    y: np.ndarray,
    depth: np.ndarray,
    pressed_ohm: np.ndarray | None = None,
) -> np.ndarray:
    """Std of one press's dR per pair (positions, pairs) at the positions: sqrt(var_baseline / n_baseline +
    var_pressed / n_pressed), the unpressed skin's estimator variance over the baseline estimates and each
    position's pressed state's over the pressed ones, with the counts of `press_estimate_counts` (+inf for a pair
    a press averages no estimate of, NaN for one cut off). pressed_ohm:
    the skin's pair R_eq at the positions when the caller has them (positions, pairs), else computed here."""
    if pressed_ohm is None:
        pressed_ohm = np.asarray(skin.pair_resistance_ohm(x, y, depth), float).reshape(len(np.atleast_1d(x)), -1)
    states = np.vstack([np.asarray(skin.baseline_pair_resistance_ohm, float)[None], pressed_ohm])
    acq = protocol.acquisition
    var = estimate_var_ohm2(daq, plan, states, protocol.seed, acq.demodulation, acq.window)
    n_baseline, n_pressed = press_estimate_counts(plan)
    # a pair with no baseline (a descent shorter than its place in the sweep) or no pressed estimate records no dR
    # (pressvalues: NaN): an infinite std, no information, as a pair cut off
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.sqrt(var[0] / n_baseline + var[1:] / n_pressed)
