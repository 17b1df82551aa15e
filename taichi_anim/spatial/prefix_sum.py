"""Exclusive prefix sum on any Taichi backend, callable inside a kernel (a `@ti.func` whose loops stay
top-level, so they run as separate parallel passes of that one launch).

Taichi's `PrefixSumExecutor` runs on CUDA and Vulkan only. This is the classic three-pass block scan
(Blelloch, "Prefix Sums and Their Applications", 1990, sec. 1.4): scan each block of B counts serially
(blocks in parallel), scan the block totals serially, add each block's offset. Work O(n), two parallel
passes and one serial pass over n / B totals.
"""

import taichi as ti

from ..runtime import data_oriented

BLOCK = 1024


@data_oriented
class PrefixSum:
    """Scratch for scanning up to `capacity` integers; serial=True runs every pass on one thread (for
    small, launch-bound scans on the CPU)."""

    def __init__(self, capacity: int, serial: bool = False, make=None):
        """make(owner, role, dtype, shape, dims): the allocator (a model's pool under capacity buckets;
        default: a new field)."""
        self.capacity = capacity
        self.serial = serial
        self.block_count = (capacity + BLOCK - 1) // BLOCK
        if make is None:
            self.block_total = ti.field(ti.i32, self.block_count + 1)
        else:
            self.block_total = make(self, "prefix_block_total", ti.i32, self.block_count + 1)

    @ti.func
    def exclusive(self, counts: ti.template(), starts: ti.template(), n):
        """starts[c] = sum(counts[:c]) for c in [0, n]; n <= capacity. Call at the top level of a kernel."""
        blocks = (n + BLOCK - 1) // BLOCK
        ti.loop_config(serialize=self.serial)
        for b in range(blocks):
            acc = 0
            for c in range(b * BLOCK, ti.min(n, (b + 1) * BLOCK)):
                starts[c] = acc
                acc += counts[c]
            self.block_total[b] = acc
        ti.loop_config(serialize=True)
        for _ in range(1):
            acc = 0
            for b in range(blocks):
                t = self.block_total[b]
                self.block_total[b] = acc
                acc += t
            starts[n] = acc
        ti.loop_config(serialize=self.serial)
        for c in range(n):
            starts[c] += self.block_total[c // BLOCK]
