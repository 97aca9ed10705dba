"""The onboard plant's vibration modes, linearised about a pose.

The flexible-joint arm (:mod:`telesmooth.arms.description`) has two coordinates per joint, the
motor angle and the link-side deflection. About a pose at rest, with the motor servo's
set-point held, small motions x (all motor and deflection angles) obey

    M ẍ + C ẋ + K x = 0,

with M the plant's mass matrix at the pose (links, rotor bodies and the reflected rotor
inertia gear_ratio²·rotor_inertia on each motor coordinate), K diagonal with the servo's
proportional gain kp on each motor coordinate and the spring stiffness k on each deflection,
and C diagonal with the servo's derivative gain kd and the spring's damping c. (Velocity
products vanish at rest; the servo's effort limit is not reached by small motions.)

Each pair of complex eigenvalues λ, λ̄ of the first-order form [[0, I], [−M⁻¹K, −M⁻¹C]] is a
vibration mode with natural frequency ω_n = |λ| (f_n = ω_n/2π) and damping ratio
ζ = −Re λ/|λ|; real eigenvalues are decays without oscillation (an overdamped servo) and are
not modes. The lowest mode decides how hard a command's acceleration and jerk ring the arm:
this is the paper's argument for smoothing them.

:func:`vibration_modes` is the numerics (numpy only); :func:`plant_modes` builds M from a
Drake MultibodyPlant of an arm description.
"""

from __future__ import annotations

import dataclasses
import functools

import numpy as np

__all__ = ["VibrationModes", "plant_modes", "vibration_modes"]

_OSCILLATION_RTOL = 1e-9
"""An eigenvalue whose imaginary part is below this share of its modulus is a real decay."""


@dataclasses.dataclass(frozen=True, eq=False)
class VibrationModes:
    """Vibration modes, lowest natural frequency first.

    Attributes:
        natural_frequency_hz: f_n = |λ|/2π of each mode, Hz, (m,), ascending.
        damping_ratio: ζ = −Re λ/|λ| of each mode, (m,), in [0, 1).
        num_decays: Eigenvalues that are real (decays without oscillation, e.g. a
            critically damped servo), counted, not listed.
    """

    natural_frequency_hz: np.ndarray
    damping_ratio: np.ndarray
    num_decays: int

    def as_dict(self, count: int | None = None) -> dict:
        """JSON-ready: the lowest ``count`` modes (all if None)."""
        keep = slice(None) if count is None else slice(0, count)
        return {"natural_frequency_hz": self.natural_frequency_hz[keep].tolist(),
                "damping_ratio": self.damping_ratio[keep].tolist(),
                "num_decays": self.num_decays}

    def describe(self, count: int = 3) -> str:
        """E.g. ``"0.84 Hz (ζ 0.021), 2.95 Hz (ζ 0.030), 6.10 Hz (ζ 0.049)"``."""
        parts = [f"{f:.3g} Hz (ζ {z:.3f})" for f, z in
                 zip(self.natural_frequency_hz[:count], self.damping_ratio[:count])]
        return ", ".join(parts) if parts else "no oscillatory mode"


def vibration_modes(mass_matrix, stiffness, damping) -> VibrationModes:
    """Modes of M ẍ + C ẋ + K x = 0.

    Args:
        mass_matrix: M, symmetric positive definite, (d, d).
        stiffness: K, (d, d), or its diagonal, (d,).
        damping: C, (d, d), or its diagonal, (d,).

    Returns:
        The oscillatory modes (one per complex-conjugate pair), lowest first.

    Raises:
        ValueError: if the shapes disagree or an entry is not finite.
    """
    mass = np.asarray(mass_matrix, dtype=float)
    if mass.ndim != 2 or mass.shape[0] != mass.shape[1] or mass.shape[0] == 0:
        raise ValueError(f"mass_matrix has shape {mass.shape}; expected (d, d), d >= 1")
    size = mass.shape[0]

    def square(name, value):
        matrix = np.asarray(value, dtype=float)
        matrix = np.diag(matrix) if matrix.ndim == 1 else matrix
        if matrix.shape != (size, size):
            raise ValueError(f"{name} has shape {np.shape(value)}; expected ({size},) or "
                             f"({size}, {size})")
        return matrix

    k, c = square("stiffness", stiffness), square("damping", damping)
    if not all(np.all(np.isfinite(m)) for m in (mass, k, c)):
        raise ValueError("mass_matrix, stiffness and damping must be finite")
    # First-order form: [ẋ; ẍ] = [[0, I], [−M⁻¹K, −M⁻¹C]] [x; ẋ].
    m_inv_k = np.linalg.solve(mass, k)
    m_inv_c = np.linalg.solve(mass, c)
    state_matrix = np.block([[np.zeros((size, size)), np.eye(size)],
                             [-m_inv_k, -m_inv_c]])
    eigenvalues = np.linalg.eigvals(state_matrix)
    modulus = np.abs(eigenvalues)
    oscillatory = eigenvalues.imag > _OSCILLATION_RTOL * np.maximum(modulus, 1e-300)
    pairs = eigenvalues[oscillatory]
    order = np.argsort(np.abs(pairs))
    pairs = pairs[order]
    omega = np.abs(pairs)
    real = np.abs(eigenvalues.imag) <= _OSCILLATION_RTOL * np.maximum(modulus, 1e-300)
    return VibrationModes(natural_frequency_hz=omega / (2.0 * np.pi),
                          damping_ratio=-pairs.real / omega,
                          num_decays=int(np.count_nonzero(real)))


@functools.lru_cache(maxsize=8)
def _flexible_plant(arm):
    """A continuous MultibodyPlant of ``arm``'s flexible model and, per state coordinate, the
    stiffness and damping of its drive (built once per description: parsing costs ~0.3 s)."""
    from pydrake.multibody.plant import MultibodyPlant

    from telesmooth.arms.drake_models import add_arm

    plant = MultibodyPlant(0.0)     # no SceneGraph: the mass matrix needs no geometry
    instance = add_arm(plant, arm, flexible=True)
    plant.Finalize()
    size = plant.num_velocities()
    stiffness, damping = np.zeros(size), np.zeros(size)
    motors = []
    for joint in arm.joints:
        motor = plant.GetJointByName(f"{joint.name}_motor", instance)
        deflection = plant.GetJointByName(f"{joint.name}_deflection", instance)
        motors.append(motor)
        stiffness[motor.velocity_start()] = joint.motor_kp_n_m_per_rad
        damping[motor.velocity_start()] = joint.motor_kd_n_m_s_per_rad
        stiffness[deflection.velocity_start()] = joint.stiffness_n_m_per_rad
        damping[deflection.velocity_start()] = joint.damping_n_m_s_per_rad
    return plant, tuple(motors), stiffness, damping


def plant_modes(arm, positions_rad) -> VibrationModes:
    """The vibration modes of ``arm``'s flexible model at rest at ``positions_rad``.

    Args:
        arm: An :class:`~telesmooth.arms.description.ArmDescription` (its joints' drive
            parameters: stiffness, damping, rotor inertia, gear ratio, servo gains).
        positions_rad: Joint angles of the pose (motors; no deflection), rad, (n,).

    Raises:
        ValueError: if ``positions_rad`` does not have one finite value per joint.
    """
    q = np.asarray(positions_rad, dtype=float)
    if q.shape != (arm.num_joints,) or not np.all(np.isfinite(q)):
        raise ValueError(f"positions_rad = {positions_rad!r} must be {arm.num_joints} finite "
                         f"angles (joints {arm.joint_names})")
    plant, motors, stiffness, damping = _flexible_plant(arm)
    context = plant.CreateDefaultContext()
    for motor, angle in zip(motors, q):
        motor.set_angle(context, angle)
    return vibration_modes(plant.CalcMassMatrix(context), stiffness, damping)
