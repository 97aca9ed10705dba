"""The best continuation (smoothing/foresight.py): against an independent dense QP, the lower
bound it is, the limits it keeps, validation; and `telesmooth foresight` end to end."""

import json

import numpy as np
import pytest
from core_fixtures import operator_recording
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from oracles import solve_dense_qp
from pydrake.solvers import ClarabelSolver, SolverOptions

from telesmooth.smoothing import foresight
from telesmooth.smoothing.foresight import best_continuation, foresight_sweep
from telesmooth.smoothing.online_hard import online_hard_run

DT = 0.25
A_MAX, J_MAX = 0.05, 0.1


def _dense_continuation(commands, reference, start, acc, jerk, vel=np.inf, rest=None):
    """The same problem per joint written out densely with loops: variables p_start …,
    the extended sequence [z_0 × 3, p_0 … p_{start−1}, x], every backward difference ending
    at a variable limited; solved by the dense Mehrotra oracle."""
    z = np.asarray(reference, dtype=float)
    num_samples, num_joints = z.shape
    n = num_samples - start
    out = np.array(commands, dtype=float)
    rest = z[0] if rest is None else np.asarray(rest, dtype=float)
    for j in range(num_joints):
        fixed = [rest[j]] * 3 + list(commands[:start, j])
        rows, bounds = [], []
        for order, limits in ((1, vel), (2, acc), (3, jerk)):
            limit = np.broadcast_to(limits, (num_joints,))[j]
            if not np.isfinite(limit):
                continue
            coefficients = {1: [-1, 1], 2: [1, -2, 1], 3: [-1, 3, -3, 1]}[order]
            for end in range(3 + start, 3 + num_samples):   # extended index of the last entry
                row, constant = np.zeros(n), 0.0
                for back, c in enumerate(reversed(coefficients)):
                    e = end - back
                    if e >= 3 + start:
                        row[e - 3 - start] += c
                    else:
                        constant += c * fixed[e]
                rows += [row, -row]
                bound = limit * DT**order
                bounds += [bound - constant, bound + constant]
        result = solve_dense_qp(np.eye(n), -z[start:, j], np.array(rows), np.array(bounds))
        out[start:, j] = result.x
    return out


def _stream(seed, num_samples=40, num_joints=2):
    """A noisy operator recording and the online-hard commands for it (within the limits)."""
    z = operator_recording(num_samples=num_samples, num_joints=num_joints, seed=seed,
                           noise=2e-3)
    commands = online_hard_run(z, DT, max_acceleration=A_MAX, max_jerk=J_MAX, q_start=z[0])
    return z, commands


@pytest.mark.parametrize("start", [0, 1, 7, 20, 39])
def test_matches_the_dense_oracle(start):
    z, commands = _stream(seed=3)
    dut = best_continuation(commands, z, start, DT, max_acceleration=A_MAX, max_jerk=J_MAX)
    assert dut.is_success.all(), dut.status
    expected = _dense_continuation(commands, z, start, A_MAX, J_MAX)
    # The objective is strongly convex, so near-optima are near each other; but a position
    # is a triple sum of the jerk differences, so a 1e-11 relative slack in the limit rows
    # moves it by ~1e-6 rad (both solvers' objectives agree to ~1e-11 rad²).
    np.testing.assert_allclose(dut.positions, expected, rtol=0, atol=2e-6)
    np.testing.assert_array_equal(dut.positions[:start], commands[:start])
    np.testing.assert_allclose(dut.squared_error,
                               np.sum((expected[start:] - z[start:]) ** 2, axis=0),
                               rtol=1e-7, atol=3e-11)


def test_a_velocity_limit_is_kept_and_matches_the_oracle():
    z, _ = _stream(seed=5)
    commands = online_hard_run(z, DT, max_acceleration=A_MAX, max_jerk=J_MAX,
                               max_velocity=0.02, q_start=z[0])
    dut = best_continuation(commands, z, 10, DT, max_acceleration=A_MAX, max_jerk=J_MAX,
                            max_velocity=0.02)
    expected = _dense_continuation(commands, z, 10, A_MAX, J_MAX, vel=0.02)
    np.testing.assert_allclose(dut.positions, expected, rtol=0, atol=2e-6)
    history = np.vstack([np.repeat(z[:1], 3, axis=0), dut.positions])
    assert np.abs(np.diff(history, axis=0)).max() / DT <= 0.02 * (1 + 1e-6)


def test_per_joint_limits_and_a_rest_pose_other_than_the_first_sample():
    z, _ = _stream(seed=8)
    rest = z[0] + np.array([0.01, -0.02])
    acc, jerk, vel = np.array([0.05, 0.08]), np.array([0.1, 0.2]), np.array([np.inf, 0.03])
    commands = online_hard_run(z, DT, max_acceleration=acc, max_jerk=jerk, max_velocity=vel,
                               q_start=rest)
    dut = best_continuation(commands, z, 12, DT, max_acceleration=acc, max_jerk=jerk,
                            max_velocity=vel, rest=rest)
    assert dut.is_success.all(), dut.status
    expected = _dense_continuation(commands, z, 12, acc, jerk, vel=vel, rest=rest)
    np.testing.assert_allclose(dut.positions, expected, rtol=0, atol=2e-6)


def test_a_reference_within_the_limits_is_its_own_continuation():
    # A slow cosine (|a| ≤ 0.02, |j| ≤ 0.02 rad/s³) from rest: the unconstrained optimum is z.
    t = DT * np.arange(80)
    z = np.stack([0.3 * (1 - np.cos(0.25 * t)), -0.2 * (1 - np.cos(0.2 * t))], axis=1)
    z = np.vstack([np.zeros((8, 2)), z])   # at rest first: the ramp-in is within the limits
    dut = best_continuation(z, z, 30, DT, max_acceleration=A_MAX, max_jerk=J_MAX)
    np.testing.assert_allclose(dut.positions, z, rtol=0, atol=1e-8)
    assert np.all(dut.squared_error < 1e-14)


class _StopsShortBelow:
    """Clarabel, except that asked for a tolerance under ``floor`` it is given one iteration
    (and so stops short, as Clarabel itself may at 1e-12 on another CPU)."""

    def __init__(self, floor):
        self._solver, self.floor, self.asked = ClarabelSolver(), floor, []

    def id(self):
        return self._solver.id()

    def Solve(self, prog, guess, options):  # noqa: N802 (Drake's name)
        asked = dict(options.options[self.id().name()])
        self.asked.append(asked["tol_feas"])
        if asked["tol_feas"] < self.floor:
            options = SolverOptions()
            for name, value in {**asked, "max_iter": 1}.items():
                options.SetOption(self.id(), name, value)
        return self._solver.Solve(prog, guess, options)


def test_a_solve_that_stops_short_is_retried_at_a_looser_tolerance(monkeypatch):
    z, commands = _stream(seed=3)
    stub = _StopsShortBelow(1e-11)
    monkeypatch.setattr(foresight, "ClarabelSolver", lambda: stub)
    dut = best_continuation(commands, z, 7, DT, max_acceleration=A_MAX, max_jerk=J_MAX)
    assert stub.asked == [1e-12, 1e-10] * 2                # per joint: 1e-12 fails, 1e-10 holds
    assert dut.is_success.all()
    assert dut.status == ("SolutionResult.kSolutionFound at tolerance 1e-10",) * 2
    expected = _dense_continuation(commands, z, 7, A_MAX, J_MAX)
    np.testing.assert_allclose(dut.positions, expected, rtol=0, atol=2e-6)


def test_a_solve_that_stops_short_at_every_tolerance_is_a_failure(monkeypatch):
    z, commands = _stream(seed=3)
    stub = _StopsShortBelow(1.0)
    monkeypatch.setattr(foresight, "ClarabelSolver", lambda: stub)
    dut = best_continuation(commands, z, 7, DT, max_acceleration=A_MAX, max_jerk=J_MAX)
    assert stub.asked == [1e-12, 1e-10, 1e-8] * 2
    assert not dut.is_success.any() and np.isnan(dut.squared_error).all()
    assert np.isnan(dut.positions[7:]).all()
    np.testing.assert_array_equal(dut.positions[:7], commands[:7])
    assert all(status.endswith("at tolerance 1e-08") and "kSolutionFound" not in status
               for status in dut.status), dut.status


@settings(max_examples=12, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 10_000), step=st.integers(1, 9))
def test_a_lower_bound_within_the_limits_for_every_start(seed, step):
    """For every start s: the method's own remaining error ≥ the bound (the method is one of
    the continuations), Bound_s ≤ (p_s − z_s)² + Bound_{s+1} (fixing one more command can only
    cost), the prefix is kept bit for bit and the whole sequence is within the FD limits."""
    z, commands = _stream(seed=seed, num_samples=30, num_joints=2)
    starts = list(range(0, 30, step))
    sweep = foresight_sweep(commands, z, DT, starts=starts + [s + 1 for s in starts if s < 29],
                            max_acceleration=A_MAX, max_jerk=J_MAX)
    bound = dict(zip(sweep.starts.tolist(), sweep.bound_squared_error))
    for s, method, cont in zip(sweep.starts, sweep.method_squared_error, sweep.continuations):
        assert cont.is_success.all(), cont.status
        assert np.all(method >= cont.squared_error - 1e-9), (s, method, cont.squared_error)
        np.testing.assert_array_equal(cont.positions[:s], commands[:s])
        history = np.vstack([np.repeat(z[:1], 3, axis=0), cont.positions])
        assert np.abs(np.diff(history, 2, axis=0)).max() / DT**2 <= A_MAX * (1 + 1e-6)
        assert np.abs(np.diff(history, 3, axis=0)).max() / DT**3 <= J_MAX * (1 + 1e-6)
        if s + 1 in bound:
            assert np.all(bound[s] <= (commands[s] - z[s]) ** 2 + bound[s + 1] + 1e-9)


def test_a_prefix_that_breaks_a_limit_has_no_continuation():
    z, _ = _stream(seed=1)
    commands = z.copy()                  # the raw samples: joint 0 breaks the jerk limit
    commands[:, 1] = z[0, 1]             # joint 1 rests: within every limit
    dut = best_continuation(commands, z, 20, DT, max_acceleration=A_MAX, max_jerk=J_MAX,
                            joint_names=("shoulder", "elbow"))
    assert dut.is_success.tolist() == [False, True]
    assert np.all(np.isnan(dut.positions[20:, 0])) and np.isnan(dut.squared_error[0])
    assert "already break a limit of joint 0 ('shoulder')" in dut.status[0]


@pytest.mark.parametrize("change, message", [
    (dict(start=40), r"start = 40 must be an integer in \[0, 40\)"),
    (dict(start=-1), r"start = -1 must be"),
    (dict(start=2.0), r"start = 2.0 must be an integer"),
    (dict(dt_s=0.0), r"dt_s = 0.0 must be a positive"),
    (dict(max_jerk=-1.0), r"max_jerk_rad_per_s3"),
    (dict(rest=[0.0, float("nan")]), r"rest\[1\] = nan for joint 1 must be finite$"),
])
def test_bad_input_names_the_field(change, message):
    z, commands = _stream(seed=2)
    arguments = dict(commands=commands, reference=z, start=3, dt_s=DT,
                     max_acceleration=A_MAX, max_jerk=J_MAX) | change
    with pytest.raises(ValueError, match=message):
        best_continuation(**arguments)


def test_shapes_and_non_finite_samples_are_refused():
    z, commands = _stream(seed=2)
    with pytest.raises(ValueError, match=r"commands has shape \(39, 2\) but reference"):
        best_continuation(commands[:-1], z, 3, DT, max_acceleration=A_MAX, max_jerk=J_MAX)
    bad = z.copy()
    bad[5, 1] = np.nan
    with pytest.raises(ValueError, match="reference"):
        best_continuation(commands, bad, 3, DT, max_acceleration=A_MAX, max_jerk=J_MAX)
    with pytest.raises(ValueError, match="step = 0 must be"):
        foresight_sweep(commands, z, DT, step=0, max_acceleration=A_MAX, max_jerk=J_MAX)


def test_the_foresight_command_writes_its_report(tmp_path):
    from telesmooth.scripts.cli import main

    text = ("{haptic: {source: synthetic, synthetic: {duration_s: 12.0, seed: 4}}, "
            "settle_s: 2.0}")
    assert main(["foresight", "--scenario-text", text, "--step", "3",
                 "--out", str(tmp_path)]) == 0
    study = json.loads((tmp_path / "foresight.json").read_text())
    assert (tmp_path / "foresight.png").stat().st_size > 10_000
    report = (tmp_path / "report.md").read_text()
    assert "# Foresight: online-hard" in report and "foresight.png" in report
    rows = study["rows"]
    assert [row["start"] for row in rows] == list(range(0, study["scenario"]["num_samples"], 3))
    for row in rows:          # online-hard is within the limits: every start continues
        assert all(row["is_success"]), row["status"]
        assert all(m >= b - 1e-9 for m, b in zip(row["method_squared_error_rad2"],
                                                  row["bound_squared_error_rad2"]))
    assert set(study["commitment"]) == {"0.5", "0.8"}
    method_e_def = study["method"]["e_def_m"]
    for share, first in study["commitment"].items():
        if first is None:
            assert all(row["e_def_m"] < float(share) * method_e_def for row in rows)
            continue
        before = [row for row in rows if row["start"] < first["start"]]
        assert first["e_def_m"] >= float(share) * method_e_def
        assert all(row["e_def_m"] < float(share) * method_e_def for row in before)
    for row in rows:
        assert 0.0 <= row["bound_share"] <= 1.0 + 1e-9 or row["bound_share"] != row["bound_share"]
    assert study["method"]["first_limit_violation_sample"] is None


def test_a_method_that_breaks_the_limits_is_reported_and_not_continued(tmp_path):
    from telesmooth.scripts.cli import main

    text = "{haptic: {source: synthetic, synthetic: {duration_s: 12.0, seed: 4}}}"
    assert main(["foresight", "--scenario-text", text, "--method", "original",
                 "--out", str(tmp_path)]) == 0
    study = json.loads((tmp_path / "foresight.json").read_text())
    first = study["method"]["first_limit_violation_sample"]
    assert isinstance(first, int) and study["commitment"] == {}
    for row in study["rows"]:
        assert all(row["is_success"]) == (row["start"] <= first), (row["start"], first)
    assert (f"original's commands break the FD limits (first at sample {first})"
            in (tmp_path / "report.md").read_text())


def test_the_foresight_command_refuses_a_bad_step(capsys, tmp_path):
    from telesmooth.scripts.cli import main

    assert main(["foresight", "--step", "0", "--out", str(tmp_path / "never")]) == 2
    assert "step = 0 must be an integer >= 1" in capsys.readouterr().err
    assert not (tmp_path / "never").exists()
