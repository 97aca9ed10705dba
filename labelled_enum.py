"""Integer enumerations that name themselves in reports and logs."""

from __future__ import annotations

import enum

__all__ = ["LabelledEnum"]


class LabelledEnum(enum.IntEnum):
    """An IntEnum (its value is what a port or a message carries) whose :attr:`label` is the
    name reports and logs write: lower case, words joined by hyphens
    (``HOLD_NOT_STOPPABLE`` → ``"hold-not-stoppable"``)."""

    @property
    def label(self) -> str:
        return self.name.lower().replace("_", "-")
