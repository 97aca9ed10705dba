"""Seeded synthetic operator motion: joint-space test recordings and a Cartesian hand model.

Two generators live here, both pure numpy/scipy (no Drake):

* :func:`synthetic_joint_motion` -- the one joint-space generator of the package: per joint,
  a chain of minimum-jerk reaches of random size and duration with random pauses, plus white
  position noise. The test fixtures (``tests/core_fixtures.operator_recording``) and the
  benchmark (``scripts/bench_core.synthetic_operator``) are thin calls into it; its keyword
  options reproduce each of them bit for bit.
* :func:`synthetic_operator_session` -- a synthetic human operator for the planar air-bearing
  arm, configured by :class:`SyntheticOperatorConfig`: minimum-jerk hand reaches between
  random targets in a workspace box, with pauses, plus physiological tremor (band-limited
  noise, 8-12 Hz) and a slow bounded drift, sampled at the haptic rate and mapped to joint
  targets by the analytic 3R inverse kinematics. It returns the same
  :class:`~telesmooth.datasets.lasa.OperatorSession` record as the LASA loader, so the two
  are interchangeable downstream.
"""

from __future__ import annotations

import dataclasses
import math
import operator

import numpy as np
import scipy.signal

from telesmooth.arms.joint_vectors import check_positive_int, check_positive_scalar
from telesmooth.arms.planar import AIR_BEARING_ARM, PlanarArm
from telesmooth.datasets.lasa import OperatorSession, WorkspaceMapping, _operator_session_from_xy

__all__ = [
    "SYNTHETIC_SHAPE",
    "SyntheticOperatorConfig",
    "minimum_jerk",
    "synthetic_joint_motion",
    "synthetic_operator_session",
]

SYNTHETIC_SHAPE = "synthetic"
"""Value of ``OperatorSession.shape`` for sessions made by :func:`synthetic_operator_session`."""

# Order of the Butterworth filters (applied forwards and backwards, so the magnitude
# response is squared and the phase is zero).
_TREMOR_FILTER_ORDER = 4
_DRIFT_FILTER_ORDER = 2


def minimum_jerk(t, t0, duration, start, end):
    """Minimum-jerk point-to-point motion from ``start`` to ``end`` over [t0, t0 + duration].

    With the normalised time s = clip((t - t0) / duration, 0, 1),

        x(t) = start + (end - start) (10 s^3 - 15 s^4 + 6 s^5),

    so x = start before t0 and x = end after t0 + duration; velocity and acceleration are zero
    at both ends, the midpoint (s = 1/2) is (start + end) / 2 and the peak speed is
    1.875 |end - start| / duration.

    Args:
        t: Times, s; scalar or array of any shape T.
        t0: Start time of the motion, s.
        duration: Duration of the motion, s (> 0; not checked, for speed in inner loops).
        start: Start position; scalar or array of shape P (e.g. (2,) for a planar point).
        end: End position; scalar or array of shape P (broadcastable with ``start``).

    Returns:
        Positions, shape T + P (just T for scalar ``start``/``end``), in the units of
        ``start``; exactly ``start`` for t <= t0 and exactly ``end`` for t >= t0 + duration.
        In between, the expression is evaluated exactly as written above, which the bitwise
        equality with the frozen reference generators (``tests/test_synthetic.py``) relies
        on.
    """
    s = np.clip((np.asarray(t) - t0) / duration, 0.0, 1.0)
    start = np.asarray(start)
    end = np.asarray(end)
    point_ndim = np.broadcast(start, end).ndim
    if point_ndim:
        # Times along the leading axes, position coordinates along the trailing ones.
        s = s.reshape(s.shape + (1,) * point_ndim)
    position = start + (end - start) * (10 * s**3 - 15 * s**4 + 6 * s**5)
    # At s = 1 the expression can be an ulp off ``end``; return ``end`` exactly there. (For
    # start = 0 it is already exact, so the reference generators' sums are unchanged.)
    return np.where(s >= 1.0, end, position)


def _check_range(field: str, value, *, allow_zero_low: bool) -> tuple[float, float]:
    """Returns ``value`` as a (low, high) float pair with 0 <(=) low <= high < inf.

    Raises:
        ValueError: naming ``field`` and the value, if the pair is malformed.
    """
    try:
        low, high = (float(v) for v in value)
    except (TypeError, ValueError):
        raise ValueError(f"{field} = {value!r} must be a pair (low, high) of numbers") from None
    low_ok = low >= 0.0 if allow_zero_low else low > 0.0
    if not (math.isfinite(low) and math.isfinite(high) and low_ok and low <= high):
        rule = "0 <= low <= high" if allow_zero_low else "0 < low <= high"
        raise ValueError(f"{field} = {value!r} must be finite with {rule}")
    return low, high


def synthetic_joint_motion(
    num_samples: int,
    num_joints: int,
    *,
    dt_s: float = 0.25,
    noise_rad: float = 1e-3,
    seed: int = 0,
    reach_rad: float = 0.4,
    reach_duration_range_s: tuple[float, float] = (2.0, 6.0),
    pause_range_s: tuple[float, float] = (0.0, 2.0),
    joint_offset_step_rad: float = 0.0,
    position_limit_rad: float | None = None,
) -> np.ndarray:
    """Operator-like joint recordings: chained minimum-jerk reaches per joint plus white noise.

    On the grid t_k = k dt_s, joint j starts at p = j * joint_offset_step_rad and, from
    t0 = 0 while t0 < t_{K-1}, repeats: draw a duration D ~ U(reach_duration_range_s) and a
    target p' = p + U(-reach_rad, reach_rad) (clipped to +-position_limit_rad if given), add
    the minimum-jerk step ``minimum_jerk(t, t0, D, 0, p' - p)``, then p = p' and
    t0 += D + U(pause_range_s). Finally N(0, noise_rad^2) noise is added to every entry.
    Each step is evaluated only on the samples its reach moves (it is exactly 0 before and
    exactly p' - p after, with the same sums bit for bit), so the cost is O(num_samples *
    num_joints), plus a constant per reach.

    Random numbers come from one ``np.random.default_rng(seed)`` in this order: for joint 0,
    (duration, target offset, pause) per reach; then joint 1, ...; then the noise array of
    shape (num_samples, num_joints) in one call. Keep this order: the test fixtures and the
    benchmark data depend on it bit for bit.

    Reproduces (bitwise):

    * ``tests/core_fixtures.operator_recording(n, J, dt, noise, seed)`` with
      ``joint_offset_step_rad=0.1`` and no position limit;
    * ``scripts/bench_core.synthetic_operator(n, J, dt_s=dt, seed=seed)`` with
      ``position_limit_rad=1.5``, no joint offset and ``noise_rad=1e-3``.

    Args:
        num_samples: Number of samples K (>= 1).
        num_joints: Number of joints J (>= 1).
        dt_s: Sample period, s (> 0).
        noise_rad: Standard deviation of the white position noise, rad (>= 0).
        seed: Seed of the random generator.
        reach_rad: Largest target offset of one reach, rad (>= 0).
        reach_duration_range_s: (low, high) of the uniform reach duration, s; 0 < low <= high.
        pause_range_s: (low, high) of the uniform pause after each reach, s; 0 <= low <= high.
        joint_offset_step_rad: Start position of joint j is j times this, rad.
        position_limit_rad: If given, every target is clipped to [-limit, +limit], rad (> 0).

    Returns:
        Joint positions, rad; shape (num_samples, num_joints).

    Raises:
        ValueError: If an argument is out of range; the message names it and its value.
    """
    num_samples = check_positive_int("num_samples", num_samples)
    num_joints = check_positive_int("num_joints", num_joints)
    dt_s = check_positive_scalar("dt_s", dt_s)
    for field, value in (("noise_rad", noise_rad), ("reach_rad", reach_rad)):
        if not (math.isfinite(value) and value >= 0.0):
            raise ValueError(f"{field} = {value!r} must be finite and >= 0")
    if not math.isfinite(joint_offset_step_rad):
        raise ValueError(f"joint_offset_step_rad = {joint_offset_step_rad!r} must be finite")
    if position_limit_rad is not None:
        check_positive_scalar("position_limit_rad", position_limit_rad)
    duration_low, duration_high = _check_range(
        "reach_duration_range_s", reach_duration_range_s, allow_zero_low=False
    )
    pause_low, pause_high = _check_range("pause_range_s", pause_range_s, allow_zero_low=True)

    rng = np.random.default_rng(seed)
    t = np.arange(num_samples) * dt_s
    q = np.zeros((num_samples, num_joints))
    for j in range(num_joints):
        # Bitwise the same as adding every reach's step to every sample, in order
        # (q[:, j] += minimum_jerk(t, t0, D, 0.0, step) per reach, as the generators this
        # replaces did), but evaluating each step only where it can be neither 0 nor ``step``:
        # * at t_k <= t0 a step is exactly +0.0 (s = 0), and adding +0.0 changes nothing but
        #   the sign of a -0.0;
        # * once s >= 1 it is exactly ``step``; and s >= 1 at every t_k > t0_next, since
        #   t0_next >= t0 + D rounded (the pause is >= 0);
        # so sample k holds ``prefix`` (the start value plus the steps of the reaches before
        # the last one with t0 < t_k, added in the same order), plus that reach's step at t_k,
        # plus +0.0 if a later reach exists.
        column = q[:, j]
        position, t0 = joint_offset_step_rad * j, 0.0
        column[:] = position
        prefix, last_start = position, None
        while t0 < t[-1]:
            duration = rng.uniform(duration_low, duration_high)
            target = position + rng.uniform(-reach_rad, reach_rad)
            if position_limit_rad is not None:
                target = np.clip(target, -position_limit_rad, position_limit_rad)
            step = target - position
            position, t0_next = target, t0 + duration + rng.uniform(pause_low, pause_high)
            # This reach is the last one started before t_k for start <= k < end, i.e.
            # t0 < t_k <= t0_next (for the last reach: every t_k > t0, as t0_next >= t[-1]).
            start = int(np.searchsorted(t, t0, side="right"))
            end = int(np.searchsorted(t, t0_next, side="right"))
            # Evaluate the step on start <= k < stop, where sample stop - 1 already has s >= 1
            # (or stop = end); s is nondecreasing in t_k, so it is exactly ``step`` after that.
            # The first t_k > t0 + D (rounded) has s >= 1, so the loop is only a safeguard.
            first_at_end = int(np.searchsorted(t, t0 + duration, side="left"))
            stop = min(max(first_at_end + 2, start + 1), end)
            while stop < end and not (t[stop - 1] - t0) / duration >= 1.0:  # minimum_jerk's s
                stop += 1
            if start < stop:
                column[start:stop] = prefix + minimum_jerk(t[start:stop], t0, duration, 0.0, step)
            prefix = prefix + step
            column[stop:end] = prefix
            last_start, t0 = start, t0_next
        if last_start is not None:
            # The later reaches' +0.0 steps at the samples before the last reach's start.
            column[:last_start] += 0.0
    return q + noise_rad * rng.standard_normal(q.shape)


def _is_real(value) -> bool:
    """True for int/float (numpy scalars included), False for bool, str and others."""
    return isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(
        value, (bool, np.bool_)
    )


def _pair(field: str, value) -> tuple[float, float]:
    """Returns ``value`` as a pair of finite floats; raises ValueError naming the field."""
    try:
        pair = tuple(float(v) for v in value)
    except (TypeError, ValueError):
        raise ValueError(f"{field} = {value!r} must be a pair of numbers") from None
    if len(pair) != 2:
        raise ValueError(f"{field} = {value!r} must have two entries")
    for i, entry in enumerate(pair):
        if not math.isfinite(entry):
            raise ValueError(f"{field}[{i}] = {entry!r} must be finite")
    return pair


@dataclasses.dataclass(frozen=True)
class SyntheticOperatorConfig:
    """A synthetic human operator moving the planar arm's end effector.

    The hand position is the sum of three parts, sampled at t_k = k / haptic_rate_hz,
    k = 0..K-1 with K = round(duration_s * haptic_rate_hz) + 1:

    1. intended motion: the hand rests at a random start point in the workspace box during
       [0, hold_start_s], then makes minimum-jerk reaches to uniformly random targets in the
       box, each lasting U(reach_duration_range_s) and followed by a pause U(pause_range_s);
       reaches are added while they end by duration_s - hold_end_s, so the intended position
       is constant for at least the last hold_end_s;
    2. tremor: zero-mean noise band-limited to tremor_band_hz (white noise through a
       Butterworth band-pass applied forwards and backwards), scaled so that each axis has
       exactly tremor_rms_m RMS over the session; it is present throughout, holds included,
       as in a real hand holding still;
    3. drift: per axis, a mean-reverting random walk (Ornstein-Uhlenbeck; diffusion
       drift_rate_m_per_sqrt_s, time constant drift_time_constant_s) starting at 0, smoothed by
       a zero-phase low-pass at drift_cutoff_hz (so it adds nothing in the tremor band) and
       bounded smoothly to +-drift_limit_m by d -> drift_limit_m tanh(d / drift_limit_m).

    Defaults are tuned for the air-bearing arm (``AIR_BEARING_ARM``) at
    end_effector_angle_rad = 0: over the box the wrist point stays at least 0.22 m inside
    both radii of the reachable annulus (far more than tremor and drift, millimetres, can
    use) and the elbow between 82 and 136 deg, away from both singular configurations.

    Attributes:
        duration_s: Session length, s (> 0).
        haptic_rate_hz: Sampling rate (the haptic device's rate), Hz (> 0).
        workspace_center_m: Centre (x, y) of the target box in the arm's base frame, m.
        workspace_half_extents_m: Half widths (x, y) of the target box, m (>= 0).
        reach_duration_range_s: (low, high) of the reach duration, s; 0 < low <= high.
        pause_range_s: (low, high) of the pause after each reach, s; 0 <= low <= high.
        tremor_rms_m: RMS of the tremor on each axis, m (>= 0). Physiological tremor is
            about 0.2 mm.
        tremor_band_hz: (low, high) edges of the tremor band, Hz;
            0 < low < high < haptic_rate_hz / 2.
        drift_rate_m_per_sqrt_s: Diffusion rate of the drift random walk, m/sqrt(s) (>= 0):
            over a time much shorter than the time constant the unfiltered drift's RMS
            change is drift_rate_m_per_sqrt_s * sqrt(time).
        drift_time_constant_s: Mean-reversion time constant of the drift, s (> 0).
        drift_cutoff_hz: Cut-off of the drift's low-pass, Hz; 0 < it < tremor_band_hz[0].
        drift_limit_m: Hard bound on the drift on each axis, m (> 0).
        hold_start_s: Time the hand rests at its start point before the first reach, s (>= 0).
        hold_end_s: Shortest rest at the last target before the session ends, s (>= 0).
        end_effector_angle_rad: Fixed orientation of the end effector, rad.
        seed: Seed of the random generators (>= 0); reaches, tremor and drift use
            independent streams spawned from it, so changing e.g. the tremor settings does
            not move the reach targets.

    Raises:
        ValueError: If a field is out of range, or duration_s leaves less than the shortest
            reach between the holds; the message names the field and its value.
    """

    duration_s: float = 60.0
    haptic_rate_hz: float = 100.0
    workspace_center_m: tuple[float, float] = (0.70, 0.0)
    workspace_half_extents_m: tuple[float, float] = (0.15, 0.20)
    reach_duration_range_s: tuple[float, float] = (1.5, 4.0)
    pause_range_s: tuple[float, float] = (0.3, 1.5)
    tremor_rms_m: float = 2e-4
    tremor_band_hz: tuple[float, float] = (8.0, 12.0)
    drift_rate_m_per_sqrt_s: float = 1e-3
    drift_time_constant_s: float = 10.0
    drift_cutoff_hz: float = 0.5
    drift_limit_m: float = 5e-3
    hold_start_s: float = 2.0
    hold_end_s: float = 4.0
    end_effector_angle_rad: float = 0.0
    seed: int = 0

    def __post_init__(self) -> None:
        for name in ("duration_s", "haptic_rate_hz", "drift_time_constant_s", "drift_limit_m"):
            check_positive_scalar(name, getattr(self, name))
        for name in ("tremor_rms_m", "drift_rate_m_per_sqrt_s", "hold_start_s", "hold_end_s"):
            value = getattr(self, name)
            if not (_is_real(value) and math.isfinite(value) and value >= 0.0):
                raise ValueError(f"{name} = {value!r} must be finite and >= 0")
        if not (_is_real(self.end_effector_angle_rad)
                and math.isfinite(self.end_effector_angle_rad)):
            raise ValueError(
                f"end_effector_angle_rad = {self.end_effector_angle_rad!r} must be finite"
            )
        object.__setattr__(
            self, "workspace_center_m", _pair("workspace_center_m", self.workspace_center_m)
        )
        extents = _pair("workspace_half_extents_m", self.workspace_half_extents_m)
        for i, extent in enumerate(extents):
            if extent < 0.0:
                raise ValueError(f"workspace_half_extents_m[{i}] = {extent!r} must be >= 0")
        object.__setattr__(self, "workspace_half_extents_m", extents)
        object.__setattr__(
            self,
            "reach_duration_range_s",
            _check_range("reach_duration_range_s", self.reach_duration_range_s,
                         allow_zero_low=False),
        )
        object.__setattr__(
            self,
            "pause_range_s",
            _check_range("pause_range_s", self.pause_range_s, allow_zero_low=True),
        )
        band = _pair("tremor_band_hz", self.tremor_band_hz)
        nyquist_hz = 0.5 * self.haptic_rate_hz
        if not 0.0 < band[0] < band[1] < nyquist_hz:
            raise ValueError(
                f"tremor_band_hz = {self.tremor_band_hz!r} must satisfy 0 < low < high < "
                f"haptic_rate_hz / 2 = {nyquist_hz!r}"
            )
        object.__setattr__(self, "tremor_band_hz", band)
        if not (_is_real(self.drift_cutoff_hz) and math.isfinite(self.drift_cutoff_hz)
                and 0.0 < self.drift_cutoff_hz < band[0]):
            raise ValueError(
                f"drift_cutoff_hz = {self.drift_cutoff_hz!r} must be > 0 and below "
                f"tremor_band_hz[0] = {band[0]!r}"
            )
        if isinstance(self.seed, bool):
            raise ValueError(f"seed = {self.seed!r} must be a non-negative integer")
        try:
            seed = operator.index(self.seed)
        except TypeError:
            raise ValueError(f"seed = {self.seed!r} must be a non-negative integer") from None
        if seed < 0:
            raise ValueError(f"seed = {self.seed!r} must be a non-negative integer")
        motion_window_s = self.duration_s - self.hold_start_s - self.hold_end_s
        if motion_window_s < self.reach_duration_range_s[0]:
            raise ValueError(
                f"duration_s = {self.duration_s!r} leaves {motion_window_s!r} s between "
                f"hold_start_s = {self.hold_start_s!r} and hold_end_s = {self.hold_end_s!r}, "
                f"less than the shortest reach reach_duration_range_s[0] = "
                f"{self.reach_duration_range_s[0]!r} s"
            )

    @property
    def num_samples(self) -> int:
        """Number of samples K = round(duration_s * haptic_rate_hz) + 1."""
        return int(round(self.duration_s * self.haptic_rate_hz)) + 1


def _intended_motion(config: SyntheticOperatorConfig, t_s: np.ndarray, rng) -> np.ndarray:
    """Minimum-jerk reaches between random targets in the box; shape (K, 2), m."""
    low = np.subtract(config.workspace_center_m, config.workspace_half_extents_m)
    high = np.add(config.workspace_center_m, config.workspace_half_extents_m)
    position = rng.uniform(low, high)
    xy = np.broadcast_to(position, (t_s.size, 2)).copy()
    t0 = config.hold_start_s
    motion_end_s = config.duration_s - config.hold_end_s
    while True:
        duration = rng.uniform(*config.reach_duration_range_s)
        if t0 + duration > motion_end_s:
            break
        target = rng.uniform(low, high)
        xy += minimum_jerk(t_s, t0, duration, np.zeros(2), target - position)
        position = target
        t0 += duration + rng.uniform(*config.pause_range_s)
    return xy


def _tremor(config: SyntheticOperatorConfig, num_samples: int, rng) -> np.ndarray:
    """Band-limited noise with exactly ``tremor_rms_m`` RMS per axis; shape (K, 2), m."""
    if config.tremor_rms_m == 0.0:
        return np.zeros((num_samples, 2))
    sos = scipy.signal.butter(
        _TREMOR_FILTER_ORDER, config.tremor_band_hz, btype="bandpass",
        output="sos", fs=config.haptic_rate_hz,
    )
    # Filter a longer stretch of noise and keep its middle, so that the filter's start-up
    # transients (a few periods of the band's lower edge) never reach the session.
    margin = int(math.ceil(10.0 * config.haptic_rate_hz / config.tremor_band_hz[0]))
    white = rng.standard_normal((num_samples + 2 * margin, 2))
    band = scipy.signal.sosfiltfilt(sos, white, axis=0)[margin:margin + num_samples]
    rms = np.sqrt(np.mean(band**2, axis=0))
    return band * (config.tremor_rms_m / rms)


def _drift(config: SyntheticOperatorConfig, num_samples: int, rng) -> np.ndarray:
    """Smoothed, bounded Ornstein-Uhlenbeck drift starting at 0; shape (K, 2), m."""
    if config.drift_rate_m_per_sqrt_s == 0.0:
        return np.zeros((num_samples, 2))
    dt_s = 1.0 / config.haptic_rate_hz
    tau_s = config.drift_time_constant_s
    # Exact discretisation of dd = -d / tau dt + rate dW:
    #   d[k+1] = a d[k] + rate sqrt(tau (1 - a^2) / 2) w[k],  a = exp(-dt / tau).
    decay = math.exp(-dt_s / tau_s)
    step_std_m = config.drift_rate_m_per_sqrt_s * math.sqrt(0.5 * tau_s * (1.0 - decay**2))
    increments = step_std_m * rng.standard_normal((num_samples - 1, 2))
    raw = np.zeros((num_samples, 2))
    raw[1:] = scipy.signal.lfilter([1.0], [1.0, -decay], increments, axis=0)
    sos = scipy.signal.butter(
        _DRIFT_FILTER_ORDER, config.drift_cutoff_hz, btype="lowpass",
        output="sos", fs=config.haptic_rate_hz,
    )
    # Odd extension at the edges keeps the smoothed drift at ~0 at t = 0.
    smooth = scipy.signal.sosfiltfilt(sos, raw, axis=0, padlen=min(num_samples - 1, 300))
    return config.drift_limit_m * np.tanh(smooth / config.drift_limit_m)


def synthetic_operator_session(
    config: SyntheticOperatorConfig = SyntheticOperatorConfig(),
    *,
    arm: PlanarArm = AIR_BEARING_ARM,
) -> OperatorSession:
    """A synthetic operator session for a planar 3R arm (see :class:`SyntheticOperatorConfig`).

    The joint targets come from :func:`planar_3r_inverse_kinematics` at
    ``config.end_effector_angle_rad`` with elbow branch +1, or -1 if +1 cannot reach every
    sample (as for LASA sessions).

    Args:
        config: The operator model and its seed.
        arm: The arm; must have three joints.

    Returns:
        An :class:`OperatorSession` with ``shape = "synthetic"``, ``demo_index =
        config.seed`` and a ``mapping`` that records the haptic rate, the holds, the
        end-effector angle and the box centre; its ``scale_m_per_unit`` and ``time_scale``
        are 1 (the synthetic positions and times are already in m and s).

    Raises:
        ValueError: If the arm does not have three joints or some sample is unreachable on
            both elbow branches; the message names the first unreachable sample and the
            configuration.
    """
    if arm.num_joints != 3:
        raise ValueError(
            f"arm.num_joints = {arm.num_joints} (joint_names = {arm.joint_names!r}); "
            "a synthetic operator session needs a three-joint planar arm"
        )
    reach_rng, tremor_rng, drift_rng = (
        np.random.default_rng(child) for child in np.random.SeedSequence(config.seed).spawn(3)
    )
    num_samples = config.num_samples
    t_s = np.arange(num_samples) / config.haptic_rate_hz
    xy_m = (
        _intended_motion(config, t_s, reach_rng)
        + _tremor(config, num_samples, tremor_rng)
        + _drift(config, num_samples, drift_rng)
    )
    mapping = WorkspaceMapping(
        scale_m_per_unit=1.0,
        time_scale=1.0,
        center_m=config.workspace_center_m,
        end_effector_angle_rad=config.end_effector_angle_rad,
        hold_start_s=config.hold_start_s,
        hold_end_s=config.hold_end_s,
        haptic_rate_hz=config.haptic_rate_hz,
    )
    return _operator_session_from_xy(
        t_s,
        xy_m,
        config.end_effector_angle_rad,
        arm,
        shape=SYNTHETIC_SHAPE,
        demo_index=int(config.seed),
        mapping=mapping,
        describe="the synthetic operator session",
        advice=(
            f"; move or shrink workspace_center_m = {config.workspace_center_m!r} / "
            f"workspace_half_extents_m = {config.workspace_half_extents_m!r} ({config!r})"
        ),
    )
