"""Scenarios, the diagrams built from them, and the runs and studies on those diagrams.

A scenario (``scenario``, loaded from YAML through ``typed_yaml``; the built-in
``scenarios.yaml`` holds ``Defaults`` and ``OneOfEverything``) sets every stage of a run.
``teleoperation`` wires the systems of :mod:`telesmooth.systems` into the ground station, the
onboard robot and the whole chain in one process (or the two halves of the LCM split, with the
channel names of ``channels``); ``visualization`` draws a run in Meshcat and the diagram with
Graphviz. On top of these diagrams: headless runs and their metrics (``simulation``), the
offline plan/validate/playback mode (``offline``), every smoothing method through the same plant
(``comparison``, the paper's Table 2), and the experiment on the LASA demonstrations on Dask
(``experiment``) with its figures and claim verdicts (``claims``).
"""
