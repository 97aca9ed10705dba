"""The pre-simulator's collision checker: a latched collision flag for the 4 Hz delay FIFO.

The ground station shows the newest inverse-kinematics target in a pre-simulator 0.75 s
ahead of the robot (docs/method.md §5). This system checks that newest target, undelayed, against
the workspace and the arm itself at the IK rate (100 Hz) and reports a collision flag. The delay
FIFO reads the flag only at 4 Hz, so the flag it reads is latched: any collision among the
samples of the last ``latch_s`` seconds, long enough that a collision between two 4 Hz ticks is
never missed. On that flag the FIFO refills its queue with the command already sent and the
robot holds (docs/method.md §5.2). A thin Drake system around the pure step
:func:`telesmooth.safety.collision_latch.latch_step`, whose state lives in the Context as one
vector.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence

from pydrake.systems.framework import LeafSystem

from telesmooth.arms.collision import ArmCollisionModel
from telesmooth.arms.description import ArmDescription
from telesmooth.arms.workspace import Workspace
from telesmooth.safety.collision_latch import (
    LatchState,
    collision_detected,
    latch_initial_state,
    latch_step,
)
from telesmooth.systems.codec_state import CodecState
from telesmooth.systems.timing import check_period

__all__ = ["CollisionChecker", "CollisionCheckerConfig"]

# latch_s / period_s is rounded up after subtracting this, so 0.26 / 0.01 = 26.000000000000004
# gives 26 samples, not 27.
_RATIO_SLACK = 1e-9


@dataclasses.dataclass(frozen=True)
class CollisionCheckerConfig:
    """Settings of :class:`CollisionChecker`.

    Attributes:
        period_s: Sample period of the check, s (0.01 s = the 100 Hz IK rate).
        safety_margin_m: A sample is a collision when the smallest signed distance is below
            this, m (>= 0; 0 means contact only).
        distance_horizon_m: Pairs farther apart than this are not computed and the reported
            distance is at most this, m; must exceed ``safety_margin_m``.
        latch_s: Length of the latch window, s (>= ``period_s``): ``collision_detected`` is
            1 while any of the last N = ceil(latch_s / period_s) samples collided. 0.26 s
            = 26 samples covers one 0.25 s FIFO period plus one sample, so a reader at 4 Hz
            sees every sample whichever order co-timed events run in.

    Raises:
        ValueError: If a field is out of range; the message names the field and the value.
    """

    period_s: float = 0.01
    safety_margin_m: float = 0.02
    distance_horizon_m: float = 0.2
    latch_s: float = 0.26

    def __post_init__(self) -> None:
        check_period("CollisionCheckerConfig.period_s", self.period_s)
        for name in ("safety_margin_m", "distance_horizon_m", "latch_s"):
            value = getattr(self, name)
            if (isinstance(value, bool) or not isinstance(value, (int, float))
                    or not math.isfinite(value) or value < 0.0):
                raise ValueError(
                    f"CollisionCheckerConfig.{name} = {value!r} must be non-negative and finite"
                )
        if not self.distance_horizon_m > self.safety_margin_m:
            raise ValueError(
                f"CollisionCheckerConfig.distance_horizon_m = {self.distance_horizon_m!r} must "
                f"exceed safety_margin_m = {self.safety_margin_m!r} (else every sample would "
                "be a collision)"
            )
        if not self.latch_s >= self.period_s * (1.0 - _RATIO_SLACK):
            raise ValueError(
                f"CollisionCheckerConfig.latch_s = {self.latch_s!r} must be at least "
                f"period_s = {self.period_s!r}"
            )

    @property
    def latch_samples(self) -> int:
        """N = ceil(latch_s / period_s), the number of samples in the latch window (>= 1)."""
        return max(1, math.ceil(self.latch_s / self.period_s - _RATIO_SLACK))


class CollisionChecker(LeafSystem):
    r"""Signed distance of the newest joint target to the workspace, with a latched flag.

    .. pydrake_system::

        name: CollisionChecker
        input_ports:
        - q_target
        output_ports:
        - min_distance
        - in_collision
        - collision_detected

    Ports (n = number of joints):

    - ``q_target``: the newest, undelayed IK joint target, rad, (n,), ordered as
      ``arm.joint_names``.
    - ``min_distance``: d_k, the smallest signed distance between the rigid arm at the last
      sample and the workspace or itself, m, (1,); at most ``distance_horizon_m``; negative
      when penetrating.
    - ``in_collision``: c_k, 1.0 if the last sample collided (d_k < safety_margin_m), else
      0.0; (1,).
    - ``collision_detected``: 1.0 if any of the last N samples collided, else 0.0; (1,).
      This is what the 4 Hz FIFO reads.

    State (one discrete vector, :class:`~telesmooth.safety.collision_latch.LatchState`): d,
    the ring of the last N flags f = [c_{k−N+1}, …, c_k], oldest first (N =
    ``config.latch_samples`` = ceil(latch_s / period_s), 26 by default), and the target q_d
    whose distance d is (NaN before the first and after an invalid target).

    Update at t_k = k·period_s (offset 0), with q = q_target(t_k), h = distance_horizon_m,
    m = safety_margin_m:

        if q is finite:  d_k = min(h, min over checked pairs of signed distance(q))
                         (d_k = d_{k−1} without a query if q = q_d: the same target)
                         c_k = [d_k < m];  q_d ← q
        else:            d_k = 0,  c_k = 1      (a NaN/inf target counts as a collision)
        f ← [f_2, …, f_N, c_k]
        min_distance = d_k,  in_collision = f_N,  collision_detected = max(f)

    Latch semantics: a collision at sample k shows on ``collision_detected`` from the update
    at t_k until the update at t_{k+N} (N samples, N·period_s >= latch_s). Outputs are state,
    so an event at time t sees the samples up to the previous update (Drake's x⁻ convention);
    a 4 Hz reader at t_r therefore sees samples t_r − N·period_s … t_r − period_s, and two
    consecutive reads 0.25 s apart overlap by one sample with N = 26: every sample is seen by
    at least one read.

    A NaN/inf entry (or an unconnected input) is flagged as a collision, never raised at run
    time; a wrong-sized input cannot occur (Drake rejects it when the port is connected or
    fixed). Joint limits are not checked here (the IK never produces a target outside them).

    Before the first update (e.g. a fresh context): d = h, no collision, an empty latch.
    No output depends directly on the input.
    """

    def __init__(
        self,
        config: CollisionCheckerConfig = CollisionCheckerConfig(),
        *,
        arm: ArmDescription,
        workspace: Workspace,
        extra_filtered_pairs: Sequence[tuple[str, str]] = (),
    ) -> None:
        """Builds the collision model and declares ports, state and the periodic update.

        Args:
            config: Period, margin, horizon and latch window.
            arm: The arm (its rigid model is the pre-simulator's).
            workspace: Obstacles and walls.
            extra_filtered_pairs: Body-name pairs not to check, on top of the model's own
                filters (see :class:`~telesmooth.arms.collision.ArmCollisionModel`).

        Raises:
            ValueError: If ``config`` is not a CollisionCheckerConfig or the model cannot be
                built (unknown body in ``extra_filtered_pairs``, ...).
        """
        super().__init__()
        if not isinstance(config, CollisionCheckerConfig):
            raise ValueError(f"config = {config!r} must be a CollisionCheckerConfig")
        self._config = config
        # A kinematics-only plant and its context, fully overwritten by every query (the
        # STYLE §9.2 exception for scratch contexts): no simulation state lives on self.
        self._model = ArmCollisionModel(
            arm, workspace,
            distance_horizon_m=config.distance_horizon_m,
            extra_filtered_pairs=extra_filtered_pairs,
        )
        n = arm.num_joints

        self._q_target_input = self.DeclareVectorInputPort("q_target", n)
        self._state = CodecState(self, latch_initial_state(
            n, config.latch_samples, config.distance_horizon_m))
        self.DeclarePeriodicDiscreteUpdateEvent(config.period_s, 0.0, self._update)
        flags = self._state.codec.field_slice("flags")
        self._min_distance_output = self._state.output("min_distance", "distance_m")
        self._in_collision_output = self._state.output(
            "in_collision", slice(flags.stop - 1, flags.stop))
        self._collision_detected_output = self.DeclareVectorOutputPort(
            "collision_detected", 1,
            lambda context, out: out.SetAtIndex(0, collision_detected(self.latch_state(context))),
            {self.xd_ticket()})

    # -- accessors ------------------------------------------------------------------------

    @property
    def config(self) -> CollisionCheckerConfig:
        return self._config

    @property
    def latch_samples(self) -> int:
        """N, the number of samples in the latch window."""
        return self._config.latch_samples

    @property
    def collision_model(self) -> ArmCollisionModel:
        """The underlying collision model (for offline queries of the same scene)."""
        return self._model

    def get_q_target_input_port(self):
        return self._q_target_input

    def get_min_distance_output_port(self):
        return self._min_distance_output

    def get_in_collision_output_port(self):
        return self._in_collision_output

    def get_collision_detected_output_port(self):
        return self._collision_detected_output

    def latch_state(self, context) -> LatchState:
        """The latch, as :func:`~telesmooth.safety.collision_latch.latch_step` left it."""
        return self._state.get(context)

    # -- the update -----------------------------------------------------------------------

    def _query(self, q) -> tuple[float, bool]:
        result = self._model.query(q)
        return result.min_distance_m, result.in_collision(self._config.safety_margin_m)

    def _update(self, context, discrete_state) -> None:
        q = (self._q_target_input.Eval(context)
             if self._q_target_input.HasValue(context) else None)
        self._state.store(discrete_state, latch_step(
            self.latch_state(context), q, query=self._query,
            safety_margin_m=self._config.safety_margin_m))
