"""A pure step's state kept in one discrete state vector of a thin Drake system.

Every stateful stage is a pure ``step(state, inputs) -> state`` on a NamedTuple beside a thin
LeafSystem; the system keeps that state packed by a
:class:`~telesmooth.safety.state_codec.VectorCodec` in one discrete state vector, reads it
back for the step and for its outputs, and stores what the step returns. This class is that
plumbing, written once.
"""

from __future__ import annotations

import numpy as np

from telesmooth.safety.state_codec import VectorCodec

__all__ = ["CodecState"]


class CodecState:
    """The state of ``system``'s pure step: one discrete state vector holding a NamedTuple.

    Args:
        system: The LeafSystem (its constructor calls this).
        initial: The step's state before its first update (sets the layout).
        codec: What packs the state (``pack``, ``unpack``; ``field_slice`` for
            :meth:`output` by name); None: a VectorCodec of ``initial``'s layout.
    """

    def __init__(self, system, initial, codec=None):
        self._system = system
        self.codec = VectorCodec(initial) if codec is None else codec
        self.index = system.DeclareDiscreteState(self.codec.pack(initial))

    def vector(self, context) -> np.ndarray:
        """The packed state in ``context`` (the system's)."""
        return context.get_discrete_state(self.index).get_value()

    def get(self, context):
        """The step's state in ``context``, unpacked."""
        return self.codec.unpack(self.vector(context))

    def store(self, values, state) -> None:
        """Writes ``state`` into an update's ``values``: the DiscreteValues of a discrete
        update, or the State of an unrestricted one."""
        if hasattr(values, "get_mutable_discrete_state"):
            values = values.get_mutable_discrete_state()
        values.get_mutable_vector(self.index).SetFromVector(self.codec.pack(state))

    def set(self, context, state) -> None:
        """Writes ``state`` into ``context`` (the system's) outside an update."""
        context.SetDiscreteState(self.index, self.codec.pack(state))

    def output(self, name: str, where):
        """Declares output ``name`` as part of the state: ``where`` a field's name or a
        slice of the packed vector. It depends on the state only (no feedthrough)."""
        part = self.codec.field_slice(where) if isinstance(where, str) else where
        return self._system.DeclareVectorOutputPort(
            name, part.stop - part.start,
            lambda context, out: out.SetFromVector(self.vector(context)[part]),
            {self._system.xd_ticket()})
