"""Step length from the gait signal: one walker-level scale, and the step-to-step changes of intensity.

``S_k = step_length_m · (R_k / SWING_REF_MPS2)^BETWEEN_EXPONENT · (A_k / R_k)^WITHIN_EXPONENT``, clipped to
[min_step_m, max_step_m], then shortened for steps that turn on the spot (:func:`turn_factor`), where

- ``A_k``: the peak-to-valley swing of the band-passed acceleration magnitude over step k's own interval
  (the period before its peak), Weinberg's ``a_max - a_min`` (H. Weinberg, "Using the ADXL202 in
  pedometer and personal navigation applications", Analog Devices AN-602, 2002);
- ``R_k``: the median swing of the steps around it (:data:`REF_STEPS` either side): the walker's current
  gait and way of carrying the phone.

Weinberg's single exponent 1/4 mixes two things that behave differently (measured on the ILC 2.0 and
IPIN 2023 walks, docs/notes/formats-real.md): *between* walkers and phones the swing says little about the
step (a phone swinging in a hand or held loosely swings far more for the same stride: exponent 0.1), while
*within* a walk a smaller swing means a slower, shorter step (exponent 0.4, near the inverted pendulum's
1/2). The per-walk scale error that remains is what the optimizer refines.
"""

from __future__ import annotations

import numpy as np

from rmbuild.config.pdr import PdrConfig

#: m/s²; the swing at which a step is ``step_length_m`` long
SWING_REF_MPS2 = 4.0
#: exponents of the walker-level swing and of a step's swing relative to it (docs/formats-real.md)
BETWEEN_EXPONENT = 0.1
WITHIN_EXPONENT = 0.4
#: steps either side whose median swing is a step's reference (a running median follows a change of gait
#: or of the way the phone is carried)
REF_STEPS = 15
#: rad per step; a step turning by less than TURN_FREE_RAD keeps its length, one turning by more than
#: TURN_PIVOT_RAD is a pivot on the spot and keeps TURN_FLOOR of it, linear in between
TURN_FREE_RAD = np.deg2rad(30.0)
TURN_PIVOT_RAD = np.deg2rad(90.0)
TURN_FLOOR = 0.25


def step_swings(step_t_s: np.ndarray, period_s: np.ndarray, grid_t_s: np.ndarray, s: np.ndarray) -> np.ndarray:
    """(k,) peak-to-valley swing of ``s`` (the band-passed magnitude on ``grid_t_s``) over each step's own
    interval, the period before its time."""
    t = np.asarray(step_t_s, dtype=np.float64)
    lo = np.searchsorted(grid_t_s, t - period_s, side="left")
    hi = np.searchsorted(grid_t_s, t, side="right")
    out = np.zeros(len(t))
    for i in range(len(t)):
        seg = s[lo[i]:max(hi[i], lo[i] + 1)]
        out[i] = float(seg.max() - seg.min()) if len(seg) else 0.0
    return out


def turn_factor(turn_rad: np.ndarray) -> np.ndarray:
    """Step length factor (k,) for steps turning by ``turn_rad`` (k,) over their stride: people turning on
    the spot take small pivot steps, not full ones."""
    x = (np.abs(np.asarray(turn_rad, dtype=np.float64)) - TURN_FREE_RAD) / (TURN_PIVOT_RAD - TURN_FREE_RAD)
    return 1.0 - (1.0 - TURN_FLOOR) * np.clip(x, 0.0, 1.0)


def step_lengths(swing_mps2: np.ndarray, turn_rad: np.ndarray, cfg: PdrConfig) -> np.ndarray:
    """(k,) step lengths in m from the steps' swings (m/s², :func:`step_swings`) and turns (rad)."""
    from scipy.ndimage import median_filter

    a = np.maximum(np.asarray(swing_mps2, dtype=np.float64), 1e-3)
    if len(a) == 0:
        return np.zeros(0)
    ref = median_filter(a, size=2 * REF_STEPS + 1, mode="nearest")
    s = cfg.step_length_m * (ref / SWING_REF_MPS2) ** BETWEEN_EXPONENT * (a / ref) ** WITHIN_EXPONENT
    return np.clip(s, cfg.min_step_m, cfg.max_step_m) * turn_factor(turn_rad)
