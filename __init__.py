"""telesmooth: acceleration/jerk-limited Kalman smoothing for delayed haptic teleoperation.

Subpackages (each a top-level folder of the repository; docs/architecture.md has the layout):

* ``telesmooth.smoothing``: the pure numerical core (the joint model driven by white jounce,
  Kalman filter, RTS, fixed-lag smoothers, reduced-Q, Offline-CKS, the banded interior point,
  the hard-limited and peer methods, foresight, metrics, trajectory I/O). No Drake systems.
* ``telesmooth.safety``: the safety core as pure functions (hard limiter, jerk-limited stop,
  the onboard link guard's state machine). No Drake systems.
* ``telesmooth.link``: the ground-to-robot link (fault model, HMAC authentication, epochs and
  sessions, the fault relay, a counting UDP multicast receiver).
* ``telesmooth.arms``: arm models and their kinematics.
* ``telesmooth.datasets``: real human demonstrations (LASA) mapped to operator sessions.
* ``telesmooth.systems``: one Drake LeafSystem per stage of the teleoperation chain.
* ``telesmooth.diagrams``: scenarios, the builders wiring the systems into diagrams, and the
  runs built on them (simulation, comparison, experiment, offline playback).
* ``telesmooth.lcm_types``: LCM message definitions for the ground/onboard link.
* ``telesmooth.scripts``: the ``telesmooth`` command line, its reports and the benchmark.
"""

__version__ = "0.1.0"
