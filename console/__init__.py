"""The operator's console as pure Python: what the operator's input means (no Drake systems).

:mod:`telesmooth.console.input` turns the browser's controls (sliders moved by keys or the
mouse, the Enable and Stop buttons, a gamepad) and the page's connection into the hand pose,
the clutch and the stop the ground station receives: ``console_step(params, state, inputs)
-> (state, outputs)``. :class:`telesmooth.systems.operator_console.OperatorConsole` is the
thin Drake system that reads Meshcat's controls and calls it.
"""
