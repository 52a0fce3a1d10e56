"""One seed, split per component: a run repeats bit for bit from its seed."""

from __future__ import annotations

import zlib

import numpy as np


def component_rng(seed: int, component: str) -> np.random.Generator:
    """An independent generator for ``component``, derived from the run seed.

    Keyed by name rather than by spawn order so that adding a component does not change the
    random streams of the others.
    """
    key = zlib.crc32(component.encode("utf-8"))
    return np.random.default_rng(np.random.SeedSequence([seed, key]))
