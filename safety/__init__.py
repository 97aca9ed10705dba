"""The onboard and ground safety core: pure functions over immutable parameters and states.

No Drake systems here (numpy, and numba for the limiter's compiled tick): the hard limiter
(:mod:`~telesmooth.safety.limiter`, ``limiter_step``), the jerk-limited stop planner
(:mod:`~telesmooth.safety.stop`, ``plan_stop``) and the onboard link guard's state machine
(:mod:`~telesmooth.safety.guard`, ``guard_step``). The Drake systems that use them
(``LinkGuard``, ``ReducedQSmoother``, ``DelayFifo``) keep the states in their Context
(:mod:`~telesmooth.safety.state_codec`).
"""
