"""Playback of a planned joint path: the source that feeds a validated 4 Hz plan to the uplink.

The offline mode (:mod:`telesmooth.diagrams.offline_planning`) plans a whole recorded session
with Offline-CKS and validates every sample; playback
(:mod:`telesmooth.diagrams.offline_playback`) then replays the plan through the same 4 Hz
:class:`~telesmooth.systems.uplink.Uplink` as the online chain. This system is the first stage of
that playback: it holds row k of the plan over [t_k, t_{k+1}) and the last row afterwards.
"""

from __future__ import annotations

import math

import numpy as np
from pydrake.systems.framework import LeafSystem

__all__ = ["PlannedPathSource"]

# Added to t / Δt before flooring, so that a tick time computed as k·Δt selects row k.
_ROW_INDEX_EPSILON = 1e-9


class PlannedPathSource(LeafSystem):
    r"""Replays a planned 4 Hz path: row k on [t_k, t_{k+1}), the last row afterwards.

    .. pydrake_system::

        name: PlannedPathSource
        output_ports:
        - q_planned
        - state_planned

    Ports (J = number of joints, N = samples):

    - ``q_planned``: q_planned[k(t)], rad, (J,), with k(t) = clamp(floor(t/Δt + 1e-9), 0, N−1);
      the 1e-9 makes a tick time computed as k·Δt select row k.
    - ``state_planned``: the smoothed state of the same row in the Uplink's layout
      [q (J), q̇ (J), q̈ (J), q⃛ (J)], rad, rad/s, rad/s², rad/s³, (4J,); zero derivatives
      when no states were given, and zero derivatives after the last row (the plan rests).

    Stateless; outputs depend on time only.
    """

    def __init__(self, positions, *, period_s: float, states=None):
        """Args:
            positions: q_planned, rad, (N, J), finite.
            period_s: Δt, s.
            states: Optional smoothed states (N, J, 4).

        Raises:
            ValueError: On a shape mismatch or a non-finite entry.
        """
        super().__init__()
        q = np.asarray(positions, dtype=float)
        if q.ndim != 2 or q.shape[0] < 1 or not np.all(np.isfinite(q)):
            raise ValueError(f"positions must be finite with shape (N, J); got {q.shape}")
        num_samples, n = q.shape
        if states is None:
            derivatives = np.zeros((num_samples, 3 * n))
        else:
            states = np.asarray(states, dtype=float)
            if states.shape != (num_samples, n, 4) or not np.all(np.isfinite(states)):
                raise ValueError(f"states must be finite with shape {(num_samples, n, 4)}; "
                                 f"got {states.shape}")
            # (N, J, 4) → [q̇ (J), q̈ (J), q⃛ (J)] per row.
            derivatives = states[:, :, 1:].transpose(0, 2, 1).reshape(num_samples, 3 * n)
        self._q = q
        self._state = np.hstack([q, derivatives])
        self._rest = np.concatenate([q[-1], np.zeros(3 * n)])
        self._period_s = float(period_s)
        time_only = {self.time_ticket()}
        self._q_output = self.DeclareVectorOutputPort(
            "q_planned", n, self._calc_q, prerequisites_of_calc=time_only)
        self._state_output = self.DeclareVectorOutputPort(
            "state_planned", 4 * n, self._calc_state, prerequisites_of_calc=time_only)

    def get_q_planned_output_port(self):
        return self._q_output

    def get_state_planned_output_port(self):
        return self._state_output

    def _row(self, context) -> int:
        return math.floor(context.get_time() / self._period_s + _ROW_INDEX_EPSILON)

    def _calc_q(self, context, output) -> None:
        output.SetFromVector(self._q[min(max(self._row(context), 0), self._q.shape[0] - 1)])

    def _calc_state(self, context, output) -> None:
        row = self._row(context)
        output.SetFromVector(self._rest if row >= self._q.shape[0]
                             else self._state[max(row, 0)])
