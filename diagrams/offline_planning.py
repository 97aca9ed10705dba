"""The offline mode's plan: a recorded session smoothed with Offline-CKS and validated.

Pipeline (docs/method.md §2.5/§2.6 for the smoother, §5.1 for the 4 Hz sampling):

    recorded operator session (make_haptic_recording)
      └─▶ inverse kinematics at the haptic rate (the ground station's own IK system)
            └─▶ one joint sample per uplink tick t_k = k·Δt (the latest IK target, or the
                period mean when ``scenario.period_mean``) ─────────────────▶ q_raw (N, J)
                  └─▶ Offline-CKS over the whole session (Drake MathematicalProgram),
                      committed history = the robot's start pose, rest at the end ─▶ q_planned
                        └─▶ validation of EVERY sample against the pre-simulator's scene:
                            finite values, joint limits, collision (safety margin), and the
                            finite-difference velocity/acceleration/jerk limits
                              └─▶ playback (only if valid): 4 Hz source → Uplink → robot

:func:`plan_offline` runs the first four stages and returns an :class:`OfflinePlan`. The
sampling is :mod:`~telesmooth.diagrams.session_sampling`, the check
:mod:`~telesmooth.diagrams.offline_validation`, and the playback of a valid plan
:mod:`~telesmooth.diagrams.offline_playback`.
"""

from __future__ import annotations

import dataclasses
import time

import numpy as np

from telesmooth.arms.joint_vectors import as_per_joint
from telesmooth.diagrams.offline_validation import (
    ValidationReport,
    describe_violations,
    validation_report,
)
from telesmooth.diagrams.scenario import Scenario
from telesmooth.diagrams.session_sampling import joint_targets_at_uplink_rate
from telesmooth.diagrams.teleoperation import scenario_smoother_config
from telesmooth.smoothing.kalman import start_prior
from telesmooth.smoothing.model import JerkModel
from telesmooth.smoothing.offline import (
    OFFLINE_CONSTRAINTS,
    OfflineCksResult,
    solve_offline_cks,
)

__all__ = ["OfflinePlan", "plan_offline"]


@dataclasses.dataclass(frozen=True, eq=False)
class OfflinePlan:
    """A smoothed, validated plan of a recorded session, sampled at the uplink period.

    Attributes:
        scenario: The scenario it was planned (and validated) for.
        joint_names: Joint order of every array, (J,).
        period_s: Δt, the uplink period, s.
        t_s: t_k = k·Δt, s, (N,).
        q_start: The robot's pose before the plan (the solver's committed history), rad, (J,).
        q_raw: The unsmoothed joint samples z_k (IK targets as the FIFO would sample them),
            rad, (N, J).
        q_planned: The smoothed positions to send, rad, (N, J); NaN if the solve failed.
        states_planned: The smoothed states [q, q̇, q̈, q⃛] per joint, (N, J, 4).
        ik_failures: Haptic samples at which the IK rejected the command and held, count.
        solver: What the Offline-CKS solve returned
            (:class:`~telesmooth.smoothing.offline.OfflineCksResult`: success, results, solver,
            objective, times, tolerances; its ``states`` are ``states_planned``).
        constraint: The solve's constraint mode (``"state"`` or ``"trajectory"``); always with
            the rest at the end.
        max_velocity_rad_per_s: The velocity limit per joint of the solve, rad/s (J,) or None.
        validation: The check of every sample of ``q_planned``.
        timings_s: Wall-clock time of each planning stage, s ("inverse_kinematics", "solve",
            "validation", "total").
    """

    scenario: Scenario
    joint_names: tuple
    period_s: float
    t_s: np.ndarray
    q_start: np.ndarray
    q_raw: np.ndarray
    q_planned: np.ndarray
    states_planned: np.ndarray
    ik_failures: int
    solver: OfflineCksResult
    constraint: str
    max_velocity_rad_per_s: np.ndarray | None
    validation: ValidationReport
    timings_s: dict

    @property
    def is_valid(self) -> bool:
        """True when the solve succeeded and every sample passed validation."""
        return self.solver.is_success and self.validation.passed

    @property
    def violations(self) -> tuple:
        return self.validation.violations

    @property
    def reason(self) -> str:
        """Why the plan is not valid ("" when it is)."""
        if not self.solver.is_success:
            failed = [f"{name!r}: {result}" + (f" (violated: {list(names)})" if names else "")
                      for name, result, names in zip(self.joint_names,
                                                     self.solver.solution_results,
                                                     self.solver.infeasible_constraints)
                      if result != "kSolutionFound"]
            return "Offline-CKS failed for joint " + "; ".join(failed)
        return describe_violations(self.validation.violations)


def plan_offline(scenario: Scenario, *, constraint: str = "trajectory", max_velocity=None,
                 num_ticks: int | None = None) -> OfflinePlan:
    """Plans a recorded session: IK → 4 Hz samples → Offline-CKS → validation of every sample.

    Offline-CKS uses the scenario's smoother σ (per joint allowed), r (divided by the samples
    per period when ``scenario.period_mean``), a_max and j_max, the robot's start pose as the
    committed history, and rest at the end. Finite-difference excesses count as violations in
    the "trajectory" and "both" modes (the solver promises those limits); in "state" and "none"
    they are reported in ``validation.fd_limits`` only (the paper's limits are on the state).
    The online smoother's ``method`` and reduced-Q settings do not apply offline.

    Args:
        scenario: The session, arm, workspace, smoother limits and periods.
        constraint: Offline-CKS constraint mode: "trajectory" (default), "state", "both",
            "none".
        max_velocity: v_max per joint, rad/s (scalar or per joint), or None.
        num_ticks: Samples to plan; default covers the recording (see
            :func:`joint_targets_at_uplink_rate`).

    Returns:
        The plan. A failed solve or a failed check is an expected outcome: ``is_valid`` is then
        False and ``reason`` says why; nothing is raised.

    Raises:
        ValueError: Invalid input only: an unknown ``constraint``, a bad ``max_velocity``, a
            scenario without a recording.
    """
    start = time.perf_counter()
    if constraint not in OFFLINE_CONSTRAINTS:
        raise ValueError(f"constraint = {constraint!r} must be one of {OFFLINE_CONSTRAINTS}")
    arm = scenario.arm_description
    names = arm.joint_names
    n = arm.num_joints
    velocity = None if max_velocity is None else as_per_joint(
        "max_velocity_rad_per_s", max_velocity, n, names, allow_inf=True)

    # Stage 1: the operator's session through the ground station's IK, sampled at 4 Hz.
    t_s, z, q_start, ik_failures = joint_targets_at_uplink_rate(scenario, num_ticks=num_ticks)
    after_ik = time.perf_counter()

    # Stage 2: Offline-CKS over the whole session (docs/method.md §2.5/§2.6).
    smoother = scenario_smoother_config(scenario)
    model = JerkModel.make(scenario.uplink.period_s, smoother.sigma, smoother.r, num_joints=n,
                           joint_names=names)
    result = solve_offline_cks(
        z, model, max_acceleration=smoother.max_acceleration_rad_per_s2,
        max_jerk=smoother.max_jerk_rad_per_s3, max_velocity=velocity, constraint=constraint,
        rest_at_end=True, start_position=q_start, joint_names=names,
        prior=start_prior(smoother.start_prior, q_start, model))
    after_solve = time.perf_counter()

    # Stage 3: the pre-simulator's check of every planned sample.
    q_planned = result.states[:, :, 0].copy()
    if result.is_success:
        report = validation_report(q_planned, t_s, scenario, start_position=q_start,
                                   check_fd_limits=constraint in ("trajectory", "both"),
                                   max_velocity=velocity)
    else:
        report = ValidationReport(checked=False, violations=(),
                                  min_distance_m=np.full(len(t_s), np.nan),
                                  closest_pairs=(), fd_limits={}, fd_limits_enforced=False)
    end = time.perf_counter()
    return OfflinePlan(
        scenario=scenario, joint_names=names, period_s=scenario.uplink.period_s, t_s=t_s,
        q_start=q_start, q_raw=z, q_planned=q_planned, states_planned=result.states,
        ik_failures=ik_failures, solver=result, constraint=constraint,
        max_velocity_rad_per_s=velocity, validation=report,
        timings_s={"inverse_kinematics": after_ik - start, "solve": after_solve - after_ik,
                   "validation": end - after_solve, "total": end - start})
