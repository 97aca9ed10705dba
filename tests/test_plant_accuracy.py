"""The default plant is accurate: what the chain reports does not depend on how the plant is
integrated.

The default onboard plant is continuous (``FlexibleArmConfig.time_step_s = 0``), integrated by
the scenario's error-controlled integrator (``onboard.integration_scheme`` at
``onboard.integration_accuracy``: Bogacki–Shampine 3(2) at 1e-3 by default). Oracle: the same
runs integrated by a different scheme 1000× more accurately (third-order Runge–Kutta at 1e-6,
itself within 0.01 % of fifth-order Runge–Kutta at 1e-8). On Defaults and on the lightweight
drive preset, the figures of the paper's table, e (each method's mean response error), P
(Online-CKS against the original), E_def (Cartesian deformation) and the largest link
deflection, must agree within 1 %.

(A fixed plant step is a different matter: a discrete plant sees each command from the first
step after it was sent, so the set-point stalls for up to one step per command and e grows
with the step; docs/numerics.md, "Simulation speed and accuracy", gives the measured convergence.)
"""

import dataclasses

import numpy as np
import pytest
from pydrake.systems.analysis import ResetIntegratorFromFlags, RungeKutta3Integrator, Simulator
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import Integrator, Sine

from telesmooth.diagrams.scenario import LoadScenario
from telesmooth.studies.comparison import prepare_comparison, run_method, set_improvement_ratios
from telesmooth.systems.flexible_arm import FlexibleArmConfig, MakeSimulator

REFERENCE_SCHEME, REFERENCE_ACCURACY = "runge_kutta3", 1e-6


def _figures(scenario) -> dict:
    setup = prepare_comparison(scenario)
    runs = {method: run_method(setup, method) for method in ("original", "online-cks")}
    set_improvement_ratios(runs)
    figures = {f"e_{method}": run.metrics["response_error_m"]["mean"]
               for method, run in runs.items()}
    figures["P"] = runs["online-cks"].metrics["improvement_ratio_percent"]
    figures["E_def"] = runs["online-cks"].metrics["cartesian_deformation_m"]["mean"]
    for method, run in runs.items():
        figures[f"deflection_{method}"] = float(np.max(run.metrics["link_deflection_max_abs_rad"]))
    return figures


@pytest.mark.parametrize("text", ["{}", "{onboard: {drive: {preset: lightweight}}}"],
                         ids=["Defaults", "lightweight"])
def test_the_default_plant_agrees_with_a_much_more_accurate_integration(text):
    scenario = LoadScenario(scenario_text=text)
    assert scenario.onboard.time_step_s == 0.0
    assert (scenario.onboard.integration_scheme, scenario.onboard.integration_accuracy) == (
        "bogacki_shampine3", 1e-3)
    default = _figures(scenario)

    reference_onboard = dataclasses.replace(
        scenario.onboard, integration_scheme=REFERENCE_SCHEME,
        integration_accuracy=REFERENCE_ACCURACY)
    reference = _figures(dataclasses.replace(scenario, onboard=reference_onboard))
    assert default.keys() == reference.keys()
    for name, value in default.items():
        assert value == pytest.approx(reference[name], rel=0.01), name
    # The check bites: the figures are not all equal to the last bit (the integration differs).
    assert any(default[name] != reference[name] for name in default)


def _sine_integral():
    """x' = sin(3 t), x(0) = 0: a diagram an error-controlled integrator has to work on."""
    builder = DiagramBuilder()
    source = builder.AddSystem(Sine(1.0, 3.0, 0.0, 1, is_time_based=True))
    integral = builder.AddSystem(Integrator(1))
    builder.Connect(source.get_output_port(0), integral.get_input_port())
    return builder.Build()


def _run(simulator) -> tuple[float, int]:
    simulator.AdvanceTo(2.0)
    x = simulator.get_context().get_continuous_state_vector().CopyToVector()[0]
    return float(x), simulator.get_integrator().get_num_derivative_evaluations()


def test_make_simulator_applies_the_configured_integrator():
    diagram = _sine_integral()
    default = MakeSimulator(diagram, FlexibleArmConfig())
    assert default.get_integrator().get_target_accuracy() == 1e-3
    # Steps of at most 10 ms, the tracker's period (a playback's steps are not ended by it).
    assert default.get_integrator().get_maximum_step_size() == 0.01
    # The same run as an independently configured Bogacki–Shampine integrator, step for step.
    by_hand = Simulator(diagram)
    ResetIntegratorFromFlags(by_hand, "bogacki_shampine3", 0.01).set_target_accuracy(1e-3)
    x, evaluations = _run(default)
    assert (x, evaluations) == _run(by_hand)
    assert x == pytest.approx((1.0 - np.cos(6.0)) / 3.0, rel=1e-2)     # the closed form
    # drake's own default (third-order Runge–Kutta at 1e-4) is not what the helper gives.
    assert _run(Simulator(diagram)) != (x, evaluations)
    other = MakeSimulator(diagram, FlexibleArmConfig(integration_scheme="runge_kutta3",
                                                      integration_accuracy=1e-6))
    assert isinstance(other.get_integrator(), RungeKutta3Integrator)
    assert other.get_integrator().get_target_accuracy() == 1e-6
    assert _run(other)[0] == pytest.approx((1.0 - np.cos(6.0)) / 3.0, rel=1e-5)


@pytest.mark.parametrize("field, value, message", [
    ("integration_scheme", "runge_kutta2", "integration_scheme = 'runge_kutta2' must be one of"),
    ("integration_scheme", "rk4", "integration_scheme = 'rk4' must be one of"),
    ("integration_accuracy", 0.0, "integration_accuracy = 0.0 must be > 0 and < 1"),
    ("integration_accuracy", float("nan"), "integration_accuracy = nan must be > 0 and < 1"),
    ("integration_accuracy", 1.0, "integration_accuracy = 1.0 must be > 0 and < 1"),
    ("integration_accuracy", True, "integration_accuracy = True must be > 0 and < 1"),
])
def test_a_bad_integrator_setting_is_refused_naming_the_field(field, value, message):
    with pytest.raises(ValueError, match=f"FlexibleArmConfig.{message}"):
        FlexibleArmConfig(**{field: value})
