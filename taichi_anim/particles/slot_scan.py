"""An emitter's free-slot scan in parallel passes, for GPU backends.

The serial scan (`Emitter.scan`) walks the free bits 32 slots a word from a rotating cursor and takes
the first n free slots. On a GPU that walk runs on one thread at memory latency per word and per slot
(10^7 particles on an H200: 549 ms a frame of 10 steps, ~24 ms of it a host copy the benchmark made;
5.6 ms with the passes below, without that copy). The same slots come out of three parallel passes of
one launch:

1. every word of the emitter's range, in the scan's order (rotated to start at the cursor), counts its
   free bits;
2. an exclusive prefix sum of those counts (spatial/prefix_sum.py, Blelloch 1990) gives each word the
   rank of its first free slot;
3. each word whose first rank is below n writes its free slots, lowest bit first, at ranks rank,
   rank + 1, ... < n and clears their bits; the word holding rank n - 1 leaves the cursor on itself.

So the slots, their order, the bits and the cursor are the serial scan's exactly (tested bit for bit
against it on the CPU), and the work is N/32 word reads spread over the device.
"""

import taichi as ti

from .. import capacity
from ..runtime import data_oriented
from ..spatial.prefix_sum import PrefixSum


@ti.func
def bit_index(low: ti.u32) -> ti.i32:
    """Index of the single set bit of `low` (portable: clz of the sign bit differs on Vulkan)."""
    b = 0
    if low & ti.u32(0xFFFF0000):
        b += 16
    if low & ti.u32(0xFF00FF00):
        b += 8
    if low & ti.u32(0xF0F0F0F0):
        b += 4
    if low & ti.u32(0xCCCCCCCC):
        b += 2
    if low & ti.u32(0xAAAAAAAA):
        b += 1
    return b


@ti.func
def range_bits(state: ti.template(), w, word_lo, word_hi, mask_lo, mask_hi):
    """Word w's free bits that belong to the slot range [word_lo, word_hi] with its end masks."""
    mask = ti.u32(0xFFFFFFFF)
    if w == word_lo:
        mask &= mask_lo
    if w == word_hi:
        mask &= mask_hi
    return state.particle_free[w] & mask


@data_oriented
class ParallelSlotScan:
    """Scratch for one emitter of `slots` slots: a free count and a first rank per word."""

    def __init__(self, slots: int):
        # Under capacity buckets the sizes go by the bucket, so every size of it compiles one kernel.
        words = (capacity.bucket(slots) if capacity.enabled() else slots) // 32 + 2  # + both end words
        self.count = ti.field(ti.i32, words + 1)
        self.first = ti.field(ti.i32, words + 1)
        self.prefix = PrefixSum(words + 1)

    @ti.func
    def take(self, state: ti.template(), index, n, start, word_lo, word_hi, mask_lo, mask_hi):
        """The first n free slots of the range into state.emit_slot[start + k], their bits cleared, the
        cursor moved as the serial scan moves it, and state.emit_found[index] = how many were found.
        Call at the top level of a kernel (its loops are the parallel passes)."""
        words = word_hi - word_lo + 1
        cursor = state.emit_cursor[index]
        for r in range(words):
            w = word_lo + (cursor + r) % words
            self.count[r] = ti.math.popcnt(range_bits(state, w, word_lo, word_hi, mask_lo, mask_hi))
        self.prefix.exclusive(self.count, self.first, words)
        for r in range(words):
            rank = self.first[r]
            if rank < n and self.count[r] > 0:
                w = word_lo + (cursor + r) % words
                bits = range_bits(state, w, word_lo, word_hi, mask_lo, mask_hi)
                while bits != 0 and rank < n:
                    low = bits & (~bits + ti.u32(1))  # lowest set bit
                    state.emit_slot[start + rank] = w * 32 + bit_index(low)
                    state.particle_free[w] ^= low
                    rank += 1
                    bits ^= low
                if self.first[r] + self.count[r] >= n:  # slot n - 1 is here: the serial scan stops here
                    state.emit_cursor[index] = (cursor + r) % words
        ti.loop_config(serialize=True)
        for _ in range(1):  # fewer than n free: every word scanned, the cursor back where it was
            state.emit_found[index] = ti.min(n, self.first[words])
