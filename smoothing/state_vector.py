"""Flat-vector form of the Online-CKS state, for fixed-size discrete state in a Drake Context.

Drake discrete state is a vector; the smoother's state is a small record of arrays
(:class:`~telesmooth.smoothing.reduced_q.OnlineCksState`). :class:`OnlineCksStateVector`
packs it into one float vector of fixed size and back, exactly (every value is stored as a
float64 and read back bit for bit).

Layout (all float64), for J joints, lag L, B = L + 1 blocks:

    [ steps (1) | blocks_scaled (J·B·4) | covariance (J·C) | sigma (J) | sent (3·J)
      | window_count (1) | window slots (B × (1 + J·B·4 + J·C + J)) ]

with C = B·16 for the recursion (cross covariances (B, 4, 4)) and C = (4B)² for the
superstate method. The window slots are used only by variant B2: each holds
(steps, blocks_scaled, covariance, z) of one checkpoint; unused slots are zero.
"""

from __future__ import annotations

import numpy as np

from telesmooth.smoothing.fixed_lag import FixedLagState
from telesmooth.smoothing.model import STATE_SIZE
from telesmooth.smoothing.reduced_q import OnlineCks, OnlineCksState

__all__ = ["OnlineCksStateVector"]


class OnlineCksStateVector:
    """Packs/unpacks the state of one :class:`OnlineCks` instance (its sizes fix the layout)."""

    def __init__(self, online: OnlineCks):
        self._online = online
        self._num_joints = online.model.num_joints
        self._num_blocks = online.lag + 1
        blocks = self._num_blocks
        if online.smoother.method == "superstate":
            self._cov_shape = (self._num_joints, STATE_SIZE * blocks, STATE_SIZE * blocks)
        else:
            self._cov_shape = (self._num_joints, blocks, STATE_SIZE, STATE_SIZE)
        self._means_shape = (self._num_joints, blocks, STATE_SIZE)
        self._means_size = int(np.prod(self._means_shape))
        self._cov_size = int(np.prod(self._cov_shape))
        self._smoother_size = 1 + self._means_size + self._cov_size
        self._slot_size = self._smoother_size + self._num_joints
        self._window_slots = blocks if online.config.variant == "B2" else 0
        self.size = (
            self._smoother_size + 4 * self._num_joints + 1 + self._window_slots * self._slot_size
        )

    def _pack_smoother(self, state: FixedLagState) -> list[np.ndarray]:
        return [
            np.array([float(state.steps)]),
            np.asarray(state.blocks_scaled, dtype=float).ravel(),
            np.asarray(state.covariance, dtype=float).ravel(),
        ]

    def _unpack_smoother(self, vector: np.ndarray, start: int) -> tuple[FixedLagState, int]:
        steps = int(round(vector[start]))
        start += 1
        means = vector[start:start + self._means_size].reshape(self._means_shape).copy()
        start += self._means_size
        cov = vector[start:start + self._cov_size].reshape(self._cov_shape).copy()
        start += self._cov_size
        return FixedLagState(blocks_scaled=means, covariance=cov, steps=steps), start

    def pack(self, state: OnlineCksState) -> np.ndarray:
        """The state as a vector of length :attr:`size`."""
        parts = self._pack_smoother(state.smoother)
        parts += [
            np.asarray(state.sigma, dtype=float).ravel(),
            np.asarray(state.sent_positions, dtype=float).ravel(),
            np.array([float(len(state.window))]),
        ]
        for checkpoint, z in state.window:
            parts += self._pack_smoother(checkpoint)
            parts.append(np.asarray(z, dtype=float).ravel())
        vector = np.zeros(self.size)
        packed = np.concatenate(parts)
        if packed.size > self.size:
            raise ValueError(
                f"Online-CKS state of size {packed.size} does not fit the layout ({self.size}); "
                f"window has {len(state.window)} checkpoints, at most {self._window_slots}"
            )
        vector[:packed.size] = packed
        return vector

    def unpack(self, vector) -> OnlineCksState:
        """Inverse of :meth:`pack`."""
        vector = np.asarray(vector, dtype=float)
        if vector.shape != (self.size,):
            raise ValueError(
                f"Online-CKS state vector has shape {vector.shape}; expected ({self.size},)"
            )
        smoother, start = self._unpack_smoother(vector, 0)
        n = self._num_joints
        sigma = vector[start:start + n].copy()
        start += n
        sent = vector[start:start + 3 * n].reshape(3, n).copy()
        start += 3 * n
        count = int(round(vector[start]))
        start += 1
        window = []
        for _ in range(count):
            checkpoint, start = self._unpack_smoother(vector, start)
            window.append((checkpoint, vector[start:start + n].copy()))
            start += n
        return OnlineCksState(
            smoother=smoother, sigma=sigma, sent_positions=sent, window=tuple(window)
        )
