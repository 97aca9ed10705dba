"""Scenarios, the diagrams built from them, and the runs on those diagrams.

A scenario (``scenario``, loaded from YAML through ``typed_yaml``; the built-in
``scenarios.yaml`` holds ``Defaults`` and ``OneOfEverything``) sets every stage of a run.
``teleoperation`` wires the systems of :mod:`telesmooth.systems` into the ground station, the
onboard robot and the whole chain in one process (or the two halves of the LCM split, with the
channel names of :mod:`telesmooth.lcm_types.channels`); ``visualization`` draws a run in
Meshcat and the diagram with Graphviz. On top of these diagrams: headless runs and their metrics
(``simulation``), a recorded session sampled at the uplink rate (``session_sampling``), and the
offline mode: the plan of a recorded session (``offline_planning``), the check of every sample
of a path (``offline_validation``) and the playback of a valid plan (``offline_playback``).
The studies that run every method through the same plant and the LASA experiment are in
:mod:`telesmooth.studies`.
"""
