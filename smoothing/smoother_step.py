"""The ground's online smoother, one uplink tick as a pure step.

:class:`~telesmooth.systems.reduced_q_smoother.ReducedQSmoother` is the thin Drake system
around :func:`smoother_step`. A tick takes the FIFO's newest sample z_k and returns the
smoothed estimate of the sample leaving the FIFO, x̂_{k−L|k} (docs/method.md §3.2, §4.2):

1. a non-finite z_k is replaced by the last smoothed position, and the tick resets (the FIFO
   never passes one; a user who wires one in gets a hold, not NaN);
2. on a reset (the FIFO refilled at this tick: the collision hold) the smoother restarts at
   rest at z_k, keeping σ, and the raw window is refilled with z_k;
3. the Online-CKS step (reduced-Q: σ lowered for the joints whose command broke a_max or
   j_max), or BMFLS with infinite limits (σ never changes);
4. ``pass-through``: the output is the raw sample leaving the window, at rest;
5. ``online-hard``: the output goes through the hard limiter (reset with the smoother), and
   its jerk is the third difference of the last four sent positions.

The state is :class:`SmootherStepState`; :class:`SmootherStepStateVector` packs it into one
float vector (the Online-CKS record by
:class:`~telesmooth.smoothing.state_vector.OnlineCksStateVector`, the rest by
:class:`~telesmooth.safety.state_codec.VectorCodec`).
"""

from __future__ import annotations

import dataclasses
from typing import NamedTuple

import numpy as np

from telesmooth.safety.finite_differences import fd_jerk
from telesmooth.safety.limiter import (
    LimiterParams,
    LimiterState,
    limiter_rest_state,
    limiter_step,
)
from telesmooth.safety.state_codec import VectorCodec
from telesmooth.smoothing.model import STATE_SIZE
from telesmooth.smoothing.reduced_q import OnlineCks, OnlineCksState
from telesmooth.smoothing.state_vector import OnlineCksStateVector

__all__ = [
    "SmootherStepParams",
    "SmootherStepState",
    "SmootherStepStateVector",
    "SmootherTick",
    "smoother_initial_state",
    "smoother_step",
]


@dataclasses.dataclass(frozen=True)
class SmootherStepParams:
    """What a tick needs besides its state (immutable).

    Attributes:
        online: The Online-CKS core (its model, limits, lag and variant); BMFLS is Online-CKS
            with infinite limits.
        pass_through: Send the raw sample leaving the window instead of the estimate.
        limiter: The hard limiter's parameters (``online-hard``), or None.
        period_s: Δt, the tick period, s (the sent jerk's finite difference).
    """

    online: OnlineCks
    pass_through: bool = False
    limiter: LimiterParams | None = None
    period_s: float = 0.25

    @property
    def lag(self) -> int:
        return self.online.lag


class SmootherStepState(NamedTuple):
    """The smoother between ticks."""

    online: OnlineCksState       # the Online-CKS record (means, covariances, σ, sent, window)
    raw: np.ndarray              # (L+1, J) the last L+1 samples, oldest first
    limiter: LimiterState | None  # the hard limiter's state (``online-hard``), or None


class SmootherTick(NamedTuple):
    """What one tick returns."""

    state: SmootherStepState     # the state after the tick
    output: np.ndarray           # (J, 4) x̂_{k−L|k} as [q, q̇, q̈, q⃛] per joint
    triggered: np.ndarray        # (J,) bool: this tick's command broke a limit


def smoother_initial_state(params: SmootherStepParams, q0, sigma0=None) -> SmootherStepState:
    """At rest at ``q0`` (J,), σ = ``sigma0`` (None: the model's)."""
    q0 = np.asarray(q0, dtype=float)
    return SmootherStepState(
        online=params.online.initial_state(q0, sigma0),
        raw=np.tile(q0, (params.lag + 1, 1)),
        limiter=None if params.limiter is None else limiter_rest_state(params.limiter, q0))


def smoother_step(params: SmootherStepParams, state: SmootherStepState, z,
                  reset: bool) -> SmootherTick:
    """One tick: sample ``z`` (J,) enters; ``reset`` when the FIFO was refilled at this tick."""
    online = params.online
    z = np.array(z, dtype=float)
    core = state.online
    raw = state.raw
    if not np.all(np.isfinite(z)):
        z = online.smoother.output(core.smoother)[:, 0]
        reset = True
    if reset:
        core = online.initial_state(z, core.sigma)
        raw = np.tile(z, (params.lag + 1, 1))
    new_core, output, triggered = online.step(core, z)
    new_raw = np.vstack([raw[1:], z[None, :]])
    if params.pass_through:
        output = np.zeros((z.size, STATE_SIZE))
        output[:, 0] = new_raw[0]
    limiter = state.limiter
    if params.limiter is not None:
        if reset:
            limiter = limiter_rest_state(params.limiter, z)
        limiter, _ = limiter_step(params.limiter, limiter, output[:, 0])
        sent = limiter.sent
        output = np.stack([limiter.position, limiter.velocity, limiter.acceleration,
                           fd_jerk(sent[-4], sent[-3], sent[-2], sent[-1], params.period_s)],
                          axis=1)
    return SmootherTick(SmootherStepState(online=new_core, raw=new_raw, limiter=limiter),
                        output, triggered)


class SmootherStepStateVector:
    """Packs a :class:`SmootherStepState` into one float vector and back, exactly:
    [Online-CKS record | raw window (row-major) | limiter state (if any)].

    Args:
        params: The smoother's parameters (they fix the layout).
        example: A state of the layout (e.g. :func:`smoother_initial_state`'s).
    """

    def __init__(self, params: SmootherStepParams, example: SmootherStepState):
        self._online = OnlineCksStateVector(params.online)
        self._raw_shape = example.raw.shape
        self._limiter = None if example.limiter is None else VectorCodec(example.limiter)
        raw_size = int(np.prod(self._raw_shape))
        self._raw = slice(self._online.size, self._online.size + raw_size)
        self.size = self._raw.stop + (0 if self._limiter is None else self._limiter.size)

    def pack(self, state: SmootherStepState) -> np.ndarray:
        parts = [self._online.pack(state.online), np.asarray(state.raw, dtype=float).ravel()]
        if self._limiter is not None:
            parts.append(self._limiter.pack(state.limiter))
        return np.concatenate(parts)

    def unpack(self, vector) -> SmootherStepState:
        vector = np.asarray(vector, dtype=float)
        if vector.shape != (self.size,):
            raise ValueError(
                f"smoother state vector has shape {vector.shape}; expected ({self.size},)")
        return SmootherStepState(
            online=self._online.unpack(vector[:self._raw.start]),
            raw=vector[self._raw].reshape(self._raw_shape).copy(),
            limiter=(None if self._limiter is None
                     else self._limiter.unpack(vector[self._raw.stop:])))
