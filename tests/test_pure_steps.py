"""Every stateful Drake system of ``telesmooth.systems`` is ports and a codec around a pure step.

Read from the sources (no Drake needed): a class is *stateful* when its methods declare a
state (``Declare…State(`` or ``CodecState(``). Each one is in :data:`PURE_STEPS`: the system
calls the named pure function, imported from a module that imports no pydrake, and its own
callbacks stay short (the logic is in the step). A new stateful system fails here until it
is built so and listed.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

SYSTEMS = Path(__file__).resolve().parents[1] / "systems"

PURE_STEPS = {
    "collision_checker.CollisionChecker": ("telesmooth.safety.collision_latch", "latch_step"),
    "command_interpolator.CommandGate": ("telesmooth.safety.command_gate", "gate_step"),
    "delay_fifo.DelayFifo": ("telesmooth.safety.fifo", "fifo_step"),
    "haptic_command_receiver.HapticCommandReceiver": ("telesmooth.link.haptic", "haptic_step"),
    "inverse_kinematics.InverseKinematicsSystem": ("telesmooth.arms.ik_step", "ik_step"),
    "joint_command_receiver.JointCommandReceiver": ("telesmooth.link.receiver",
                                                    "receiver_step"),
    "laser_tracker.LaserTracker": ("telesmooth.arms.tracker", "tracker_step"),
    "lcm_safe_subscriber.LcmSafeSubscriber": ("telesmooth.link.inbox", "inbox_step"),
    "link_channel.LinkChannel": ("telesmooth.link.channel", "channel_step"),
    "link_guard.LinkGuard": ("telesmooth.safety.guard", "guard_step"),
    "link_monitor.LinkMonitor": ("telesmooth.link.monitor", "monitor_step"),
    "operator_console.OperatorConsole": ("telesmooth.console.input", "console_step"),
    "period_mean.PeriodMean": ("telesmooth.smoothing.period_mean", "period_mean_step"),
    "reduced_q_smoother.ReducedQSmoother": ("telesmooth.smoothing.smoother_step",
                                            "smoother_step"),
    "robot_predictor.RobotPredictor": ("telesmooth.link.prediction", "receive_step"),
    "uplink.Uplink": ("telesmooth.link.uplink", "uplink_step"),
}
"""System → (module, function) of its pure step."""

MAX_CALLBACK_LINES = 40
"""A thin system's longest method body, lines (ports, codec and the call: no logic)."""


def _classes():
    for path in sorted(SYSTEMS.glob("*.py")):
        tree = ast.parse(path.read_text())
        for node in tree.body:
            if isinstance(node, ast.ClassDef):
                yield f"{path.stem}.{node.name}", node, tree


def _declares_state(cls: ast.ClassDef) -> bool:
    """The class declares Context state: ``self.Declare…State(…)``, or its pure step's state
    through ``CodecState(self, …)``."""
    def declares(call):
        func = call.func
        if isinstance(func, ast.Name):
            return func.id == "CodecState"
        return (isinstance(func, ast.Attribute) and isinstance(func.value, ast.Name)
                and func.value.id == "self" and func.attr.startswith("Declare")
                and func.attr.endswith("State"))
    return any(isinstance(call, ast.Call) and declares(call) for call in ast.walk(cls))


STATEFUL = {name: (cls, tree) for name, cls, tree in _classes() if _declares_state(cls)}


def test_every_stateful_system_is_a_pure_step():
    assert set(STATEFUL) == set(PURE_STEPS), (
        f"unlisted: {sorted(set(STATEFUL) - set(PURE_STEPS))}; "
        f"listed but not stateful: {sorted(set(PURE_STEPS) - set(STATEFUL))}")


@pytest.mark.parametrize("name", sorted(PURE_STEPS))
def test_a_thin_system_calls_its_pure_step_and_keeps_no_logic(name):
    cls, tree = STATEFUL[name]
    module, function = PURE_STEPS[name]
    imported = {alias.name for node in ast.walk(tree) if isinstance(node, ast.ImportFrom)
                and node.module == module for alias in node.names}
    assert function in imported, f"{name} does not import {function} from {module}"
    called = {node.func.id for node in ast.walk(cls) if isinstance(node, ast.Call)
              and isinstance(node.func, ast.Name)}
    assert function in called, f"{name} never calls {function}"
    for method in cls.body:
        if isinstance(method, ast.FunctionDef) and method.name != "__init__":
            body = method.body[1:] if ast.get_docstring(method) else method.body
            lines = body[-1].end_lineno - body[0].lineno + 1
            assert lines <= MAX_CALLBACK_LINES, f"{name}.{method.name}: {lines} lines"


@pytest.mark.parametrize("module", sorted({module for module, _ in PURE_STEPS.values()}))
def test_the_pure_steps_live_outside_drake(module):
    path = Path(__file__).resolve().parents[1].joinpath(
        *module.split(".")[1:]).with_suffix(".py")
    tree = ast.parse(path.read_text())
    for node in ast.walk(tree):
        if isinstance(node, (ast.Import, ast.ImportFrom)):
            names = [node.module] if isinstance(node, ast.ImportFrom) else [
                alias.name for alias in node.names]
            assert not any(str(n).startswith("pydrake") for n in names), (module, names)
