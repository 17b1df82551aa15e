"""A force term's stiffness K = -df/dx and damping C = -df/dv in NumPy, as parts the stability estimate
(stability.py: Lanczos on M^-1/2 K M^-1/2 and a block Gershgorin bound) applies and bounds: springs in
their compact rank-two form, any element term as dense per-element blocks."""

import numpy as np


def _scatter(ids, values, n):
    """(n, 3) sums of values (E, 3) by particle ids (E,) (bincount: no float atomics, fixed order)."""
    return np.stack([np.bincount(ids, weights=values[:, c], minlength=n) for c in range(3)], axis=1)


class SpringPart:
    """Springs (terms/springs.py) in their compact form: K_s = k [n n^T + t (I - n n^T)],
    t = max(1 - L/l, 0), C_s = c n n^T, acting on p_i - p_j (+ at i, - at j)."""

    def __init__(self, springs, x):
        self.pairs = springs.pairs
        d = x[self.pairs[:, 0]] - x[self.pairs[:, 1]]
        length = np.maximum(np.linalg.norm(d, axis=1), 1e-12)
        self.n = d / length[:, None]
        self.t = np.maximum(1.0 - springs.rest_length / length, 0.0)
        self.k = springs.stiffness
        self.c = springs.damping

    def apply(self, p, damping: bool):
        """K p (or C p with damping) for p (N,3)."""
        i, j = self.pairs[:, 0], self.pairs[:, 1]
        d = p[i] - p[j]
        nd = np.einsum("ec,ec->e", self.n, d)[:, None]
        if damping:
            f = self.c[:, None] * nd * self.n
        else:
            f = self.k[:, None] * ((1.0 - self.t)[:, None] * nd * self.n + self.t[:, None] * d)
        return _scatter(i, f, len(p)) - _scatter(j, f, len(p))

    def gershgorin(self, diag, off, s):
        """Add its diagonal blocks to diag (N,3,3) and its off-diagonal block norms, scaled by s = m^-1/2,
        to off (N,)."""
        i, j = self.pairs[:, 0], self.pairs[:, 1]
        nn = self.n[:, :, None] * self.n[:, None, :]
        blk = self.k[:, None, None] * (nn + self.t[:, None, None] * (np.eye(3) - nn))
        np.add.at(diag, i, blk)
        np.add.at(diag, j, blk)
        norm = self.k * np.maximum(1.0, self.t) * s[i] * s[j]  # eigenvalues of the block: k and k t
        off += np.bincount(i, weights=norm, minlength=len(off))
        off += np.bincount(j, weights=norm, minlength=len(off))


class BlockPart:
    """Element blocks: ids (E, a) particle indices, K and C (E, 3a, 3a)."""

    def __init__(self, ids, k, c):
        self.ids, self.k, self.c = ids, k, c
        self.dofs = (3 * ids[:, :, None] + np.arange(3)).reshape(len(ids), -1)

    def apply(self, p, damping: bool):
        """K p (or C p with damping) for p (N,3)."""
        y = np.einsum("eij,ej->ei", self.c if damping else self.k, p.reshape(-1)[self.dofs])
        return np.bincount(self.dofs.ravel(), weights=y.ravel(), minlength=p.size).reshape(-1, 3)

    def gershgorin(self, diag, off, s):
        """Add its diagonal blocks to diag (N,3,3) and its off-diagonal block norms, scaled by s = m^-1/2,
        to off (N,)."""
        ids, k = self.ids, self.k
        for a in range(ids.shape[1]):
            ra = slice(3 * a, 3 * a + 3)
            np.add.at(diag, ids[:, a], k[:, ra, ra])
            for b in range(ids.shape[1]):
                if b != a:
                    # The Frobenius norm bounds the spectral norm (equal for rank-one blocks).
                    blk = k[:, ra, 3 * b : 3 * b + 3]
                    norm = np.sqrt(np.einsum("eij,eij->e", blk, blk)) * s[ids[:, a]] * s[ids[:, b]]
                    off += np.bincount(ids[:, a], weights=norm, minlength=len(off))
