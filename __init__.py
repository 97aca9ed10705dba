"""telesmooth: acceleration/jerk-limited Kalman smoothing for delayed haptic teleoperation.

Subpackages (each a top-level folder of the repository):

* ``telesmooth.smoothing``: the pure numerical core (jerk model, Kalman filter, RTS,
  fixed-lag smoothers, reduced-Q, Offline-CKS, metrics, trajectory I/O). No Drake systems.
* ``telesmooth.arms``: arm models and their kinematics.
* ``telesmooth.datasets``: real human demonstrations (LASA) mapped to operator sessions.
* ``telesmooth.systems``: one Drake LeafSystem per stage of the teleoperation chain.
* ``telesmooth.diagrams``: builder functions wiring the systems into diagrams.
* ``telesmooth.lcm_types``: LCM message definitions for the ground/onboard link.
* ``telesmooth.scripts``: the ``telesmooth`` command line.
"""

__version__ = "0.1.0"
