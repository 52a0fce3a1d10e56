"""Traffic-light state estimation (aUToronto 6.4.3): HMM filtering and duty-cycle flashing detection.

HMM: the hidden state is the light's true :class:`LightState`. The transition prior follows the
signal sequence green -> yellow -> red -> green: over a step of ``dt`` a lit state is left with
probability ``1 - exp(-dt / dwell_s)`` (its mean dwell time), and of that leaving mass
``1 - p_out_of_sequence`` goes to the state that comes next in the sequence, the rest spread over the
others (off included: power cuts, flashing). A dark light comes back to any colour alike. The
emission model is the detector's confusion matrix ``C[true, detected]``; a detection's confidence
``s`` mixes it with an uninformative likelihood, ``s * C[:, j] + (1 - s) / 4``, so a low-score box moves
the belief less. The forward filter is normalised at every step; with no detection the belief is only
predicted (the map keeps the track alive through occlusions).

Flashing: over the last N observed states of a track, the fraction of lit states (on ratio) and of
dark states (off ratio) are compared with the band of the US MUTCD [section 4D.?] that the paper cites:
"predicted to be flashing only if both the on and off state ratios are within this threshold",
with the threshold (1/2, 2/3). See :func:`duty_cycle` for how we read that wording.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from lastmile.core.traffic_light_messages import N_LIGHT_STATES, LightState

# The signal sequence: the state each one normally turns into.
NEXT_STATE = {
    LightState.GREEN: LightState.YELLOW,
    LightState.YELLOW: LightState.RED,
    LightState.RED: LightState.GREEN,
}


def transition_matrix(dt_s: float, dwell_s: np.ndarray, p_out_of_sequence: float) -> np.ndarray:
    """(4, 4) row-stochastic ``T[from, to]`` for a step of ``dt_s`` seconds.

    Args:
        dt_s: time step (s, >= 0); 0 gives the identity.
        dwell_s: (4,) mean time in each state (s, > 0), in :class:`LightState` order.
        p_out_of_sequence: share of the leaving probability that goes against the signal sequence.
    """
    leave = 1.0 - np.exp(-dt_s / dwell_s)
    t = np.zeros((N_LIGHT_STATES, N_LIGHT_STATES))
    for state in LightState:
        i = int(state)
        t[i, i] = 1.0 - leave[i]
        others = [int(s) for s in LightState if s is not state]
        if state is LightState.OFF:
            t[i, others] = leave[i] / len(others)
            continue
        nxt = int(NEXT_STATE[state])
        t[i, nxt] = leave[i] * (1.0 - p_out_of_sequence)
        rest = [j for j in others if j != nxt]
        t[i, rest] = leave[i] * p_out_of_sequence / len(rest)
    return t


def hmm_predict(prob: np.ndarray, transition: np.ndarray) -> np.ndarray:
    """Belief (4,) after one transition step."""
    return np.asarray(prob @ transition)


def hmm_update(prob: np.ndarray, detected: int, score: float, confusion: np.ndarray) -> np.ndarray:
    """Belief (4,) after a detection of state ``detected`` with confidence ``score`` (normalised)."""
    like = score * confusion[:, detected] + (1.0 - score) / N_LIGHT_STATES
    post = prob * like
    return np.asarray(post / post.sum())


def duty_cycle(history: Sequence[int], lower: float, upper: float) -> tuple[bool, LightState]:
    """Flashing test over a window of observed states, and the flashing colour.

    The paper's wording is that the on ratio and the off ratio must both lie within (1/2, 2/3). Read
    as two fractions of the same window they sum to one, so both cannot exceed 1/2; the cited rule
    (MUTCD: the illuminated period is not less than half and not more than two-thirds of the flash
    cycle) bounds the on ratio by [1/2, 2/3], hence the off ratio by [1/3, 1/2]. We test both ratios
    against that band (each against its own side of it), so both must hold, as the paper says, and a
    window with states the test cannot use (none here: every entry is lit or off) could not pass on
    one ratio alone. The ends are included: a 50 % flash sampled over an even window lands exactly on
    1/2, and the MUTCD's bounds are inclusive.

    Args:
        history: the last N observed states (ints of :class:`LightState`), oldest first.
        lower, upper: the band of the on ratio (1/2 and 2/3 by default in the tracker).

    Returns:
        (flashing, colour): colour is the most frequent lit state in the window (``OFF`` if none).
    """
    n = len(history)
    if n == 0:
        return False, LightState.OFF
    counts = np.bincount(np.asarray(history, dtype=np.int64), minlength=N_LIGHT_STATES)
    off = int(counts[int(LightState.OFF)])
    on = n - off
    on_ratio, off_ratio = on / n, off / n
    eps = 1e-12
    flashing = (lower - eps <= on_ratio <= upper + eps) and (
        1.0 - upper - eps <= off_ratio <= 1.0 - lower + eps
    )
    lit = counts[: int(LightState.OFF)]
    colour = LightState(int(np.argmax(lit))) if on else LightState.OFF
    return bool(flashing), colour
