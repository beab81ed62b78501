"""The particle filter's C random streams (the generator itself: :mod:`symmon.compile.rng`).

The compiled bootstrap recursion (:mod:`symmon.filters.particle._kernel`) draws its own numbers in
C, inside the loop that moves the particles, with the xoshiro256++ streams and the
256-layer ziggurat of :mod:`symmon.compile.rng`.

**Streams.**  Each run of a bank has its SeedSequence (child r of ``SeedSequence(seed)``,
:func:`symmon.filters.bank.run_streams`); stream c of the run is seeded by
words 4c … 4c + 3 of ``SeedSequence(entropy, spawn_key=run's key + (STREAM_TAG,))``
(:func:`symmon.compile.rng.xoshiro_states`).  Particles ``c·CHUNK … (c+1)·CHUNK − 1`` draw
from stream c, and one more stream draws the resampling uniforms, so the numbers of a seed
depend neither on the number of threads nor on the other runs.
"""

from __future__ import annotations

import numpy as np

from ...compile.rng import LANES, xoshiro_states

__all__ = ["CHUNK", "LANES", "LANE_TAG", "STREAM_TAG", "lane_states", "stream_states"]

#: Particles per random stream (a fixed split, so threads do not change the numbers); one
#: block of the kernel (:data:`~symmon.filters.particle._kernel.BLOCK`), so that 1000 particles are
#: four chunks, which two threads can share.
CHUNK = 256
#: The spawn-key entry that marks the particle filter's C streams among a run's children.
STREAM_TAG = 0x50465247  # "PFRG"
#: The spawn-key entry of the lanes that draw the moves' normals.
LANE_TAG = 0x5046524C  # "PFRL"


def stream_states(rng: np.random.Generator, streams: int) -> np.ndarray:
    """The xoshiro256++ states (streams, 4) of one run whose NumPy stream is ``rng`` (a
    child of the filter's SeedSequence, :func:`~symmon.filters.bank.run_streams`)."""
    return xoshiro_states(rng.bit_generator.seed_seq, streams, STREAM_TAG)


def lane_states(rng: np.random.Generator, chunks: int) -> np.ndarray:
    """The xoshiro256++ states (chunks, LANES, 4) of the lanes of one run's chunks (module
    notes; lane l of chunk c is stream c·LANES + l of the tag :data:`LANE_TAG`)."""
    return xoshiro_states(rng.bit_generator.seed_seq, chunks * LANES, LANE_TAG).reshape(chunks, LANES, 4)
