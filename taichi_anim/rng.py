"""Counter-based random numbers for kernels: the same (seed, step, particle, draw) gives the same value
whatever the thread count, unlike Taichi's per-thread `ti.random()` (keeps runs deterministic per seed).

Hash: Chris Wellons' "lowbias32" integer finaliser (2018), chained over the counters.
"""

import taichi as ti

# The seed enters the hash as one u32: seeds must lie in [0, SEED_LIMIT). A larger seed would be cut to
# its low 32 bits and silently repeat a smaller seed's run, so Builder.finalize rejects it instead.
SEED_LIMIT = 2**32


@ti.func
def hash_u32(x: ti.u32) -> ti.u32:
    x ^= x >> 16
    x *= ti.u32(0x7FEB352D)
    x ^= x >> 15
    x *= ti.u32(0x846CA68B)
    x ^= x >> 16
    return x


@ti.func
def uniform(seed: ti.u32, a: ti.u32, b: ti.u32, c: ti.u32):
    """A float in [0, 1) from four counters (24 random bits, exact in f32)."""
    h = hash_u32(seed ^ hash_u32(a ^ hash_u32(b ^ hash_u32(c + ti.u32(0x9E3779B9)))))
    return ti.cast(h >> 8, float) * (1.0 / 16777216.0)
