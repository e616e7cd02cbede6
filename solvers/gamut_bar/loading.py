"""Load protocols of seed sec. 4.1 and what is read off them.

Monotonic: F_0 = 0.01 N, ×1.01 per static step until failure. Cyclic: an incremental-step
test, amplitude levels σ_a geometrically spaced from low·σ_y to high·σ_y; each level is run
``repeats`` times; each half-cycle goes in force increments of 1 % of the level's peak force
and reverses when |σ| reaches the level's amplitude.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


def monotonic_forces(f0, growth, f_cap):
    """F_k = F_0·growth^k up to the first force ≥ f_cap (inclusive)."""
    count = int(math.ceil(math.log(f_cap / f0) / math.log(growth))) + 1
    return f0 * growth ** np.arange(max(count, 1), dtype=float)


@dataclass(frozen=True)
class CyclicPlan:
    """Step counts of the cyclic protocol; fixed per scene so every run has the same steps."""

    levels: int
    repeats: int
    per_half: int                 # steps from +F_a to −F_a (2 / increment)
    ramps: tuple[int, ...]        # steps to reach each level's +F_a from the previous peak

    @property
    def steps(self) -> int:       # recorded states, the unloaded start included
        return 1 + sum(self.ramps) + self.levels * self.repeats * 2 * self.per_half

    @property
    def cycles(self) -> int:      # loops in all: every level, each repeat
        return self.levels * self.repeats

    def cycle_of_step(self, step: int) -> int:
        """The cycle (1 .. ``cycles``) that load step ``step`` (an index of ``forces``; 0 is
        the unloaded start) belongs to. A level's ramp from the previous peak belongs to its
        first cycle: the cycle that loads the bar to the new amplitude."""
        end = 1                   # one past the last step of the part reached so far
        for level, ramp in enumerate(self.ramps):
            end += ramp
            if step < end:
                return level * self.repeats + 1
            for repeat in range(self.repeats):
                end += 2 * self.per_half
                if step < end:
                    return level * self.repeats + repeat + 1
        raise ValueError(f"step {step} is past the {self.steps} steps of the protocol")

    @classmethod
    def for_amplitudes(cls, amplitudes, repeats, increment):
        per_half = int(round(2.0 / increment))
        first = int(round(1.0 / increment))
        ramps = [first] + [max(1, int(math.ceil((1.0 - a0 / a1) / increment - 1e-9)))
                           for a0, a1 in zip(amplitudes[:-1], amplitudes[1:])]
        return cls(len(amplitudes), repeats, per_half, tuple(ramps))

    def forces(self, peaks):
        """Force of every step (the unloaded start first) and, per level and repeat, the index
        of the step that starts its loop (+F_a); a loop spans 2·per_half steps."""
        out = [np.zeros(1)]
        starts = np.empty((self.levels, self.repeats), dtype=np.int64)
        pos, prev = 1, 0.0
        down = np.arange(1, self.per_half + 1) / self.per_half   # 1 step .. full range
        for lvl, (peak, ramp) in enumerate(zip(peaks, self.ramps)):
            out.append(prev + (peak - prev) * np.arange(1, ramp + 1) / ramp)
            pos += ramp
            for rep in range(self.repeats):
                starts[lvl, rep] = pos - 1
                out.append(peak - 2.0 * peak * down)
                out.append(-peak + 2.0 * peak * down)
                pos += 2 * self.per_half
            prev = peak
        return np.concatenate(out), starts


def loop_amplitudes(strain, stress, starts, span, E):
    """Per loop (rows of ``starts``, last repeat): σ_a = (σ_max − σ_min)/2, ε_a = half the
    strain range, ε_pa = ε_a − σ_a/E."""
    idx = starts[:, -1][:, None] + np.arange(span + 1)[None, :]
    s, e = stress[idx], strain[idx]
    sig_a = 0.5 * (s.max(axis=1) - s.min(axis=1))
    eps_a = 0.5 * (e.max(axis=1) - e.min(axis=1))
    return sig_a, eps_a, eps_a - sig_a / E


def fit_cyclic(sig_a, eps_pa, eps_a):
    """n′, K′ of σ_a = K′ ε_pa^n′ by least squares of log σ_a on log ε_pa (the seed's "poly1"),
    over the loops with ε_pa > 1e-6·ε_a. NaN if fewer than two such loops."""
    use = eps_pa > 1e-6 * eps_a
    if np.count_nonzero(use) < 2:
        return math.nan, math.nan, int(np.count_nonzero(use))
    slope, intercept = np.polyfit(np.log(eps_pa[use]), np.log(sig_a[use]), 1)
    return float(slope), float(math.exp(intercept)), int(np.count_nonzero(use))


def resample_path(strain, stress, eps_ref, sig_ref, points):
    """``points`` states equally spaced in normalised arc length of the (ε/ε_ref, σ/σ_ref)
    path, first and last state included (linear between converged states)."""
    a = np.asarray(strain) / eps_ref
    b = np.asarray(stress) / sig_ref
    s = np.concatenate([[0.0], np.cumsum(np.hypot(np.diff(a), np.diff(b)))])
    t = np.linspace(0.0, s[-1], points)
    t[-1] = s[-1]
    return np.interp(t, s, strain), np.interp(t, s, stress)
