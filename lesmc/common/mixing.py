"""64-bit mixers for hashing arrays of words: splitmix64's and murmur3's finalisers.

A mixer is a bijection of 64-bit words that spreads every input bit over the
output. The unfolder's state hashes (lesmc/unfold/hashing.py) use lane 0, the joint
tracker's 128-bit digests (lesmc/tracking/joint.py) one lane per half.
"""

from __future__ import annotations

import numpy as np

#: (shift, multiplier, shift, multiplier, shift) of each lane: splitmix64's, murmur3's.
MIXERS = (
    (30, 0xBF58476D1CE4E5B9, 27, 0x94D049BB133111EB, 31),
    (33, 0xFF51AFD7ED558CCD, 33, 0xC4CEB9FE1A85EC53, 33),
)


def mix(x: np.ndarray, lane: int = 0) -> np.ndarray:
    """``x`` (a uint64 array) through lane ``lane``'s finaliser, as a new array (products
    wrap modulo 2^64; numpy does not warn for arrays)."""
    s1, m1, s2, m2, s3 = _CONSTANTS[lane]
    x = x ^ (x >> s1)
    x *= m1
    x ^= x >> s2
    x *= m2
    x ^= x >> s3
    return x


_CONSTANTS = tuple(tuple(np.uint64(c) for c in lane) for lane in MIXERS)
