"""Loading our arm and workspace models into a Drake MultibodyPlant (no downloads, ever)."""

from __future__ import annotations

from pydrake.multibody.parsing import Parser
from pydrake.multibody.tree import ModelInstanceIndex

from telesmooth.arms.description import ArmDescription, arm_sdf
from telesmooth.arms.workspace import Workspace, workspace_sdf

__all__ = ["add_arm", "add_workspace"]


def add_arm(plant, arm: ArmDescription, *, flexible: bool) -> ModelInstanceIndex:
    """Adds the SDFormat model of ``arm`` (rigid or flexible) to ``plant``.

    The model is parsed from its generated text (:func:`arm_sdf`): for the arms we ship, the
    text of the committed file under ``arms/models/`` (a test keeps the two equal); for a
    modified description (e.g. ``dataclasses.replace`` of a link length), its own model, so
    edits are never silently ignored. Parsing the text costs about 2.5 ms; parsing the same
    text from its file costs about 70 ms (measured with pydrake 1.51), which a playback per
    method paid on every run. Call before ``plant.Finalize()``. Returns the model instance
    (named ``arm.name``).
    """
    (instance,) = Parser(plant).AddModelsFromString(arm_sdf(arm, flexible=flexible), "sdf")
    return instance


def add_workspace(plant, workspace: Workspace) -> ModelInstanceIndex | None:
    """Adds the static obstacle/wall model of ``workspace``; None if it has no boxes."""
    if not workspace.boxes():
        return None
    (instance,) = Parser(plant).AddModelsFromString(workspace_sdf(workspace), "sdf")
    return instance
