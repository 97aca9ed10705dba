"""Loading our arm and workspace models into a Drake MultibodyPlant (no downloads, ever)."""

from __future__ import annotations

from pydrake.multibody.parsing import Parser
from pydrake.multibody.tree import ModelInstanceIndex

from telesmooth.arms.description import ArmDescription, arm_sdf, model_path
from telesmooth.arms.workspace import Workspace, workspace_sdf

__all__ = ["add_arm", "add_workspace"]


def add_arm(plant, arm: ArmDescription, *, flexible: bool) -> ModelInstanceIndex:
    """Adds the SDFormat model of ``arm`` (rigid or flexible) to ``plant``.

    The committed file under ``arms/models/`` is loaded when it is exactly the model of
    ``arm``; a modified description (e.g. ``dataclasses.replace`` of a link length) is
    loaded from its freshly generated text instead, so edits are never silently ignored.
    Call before ``plant.Finalize()``. Returns the model instance (named ``arm.name``).
    """
    text = arm_sdf(arm, flexible=flexible)
    path = model_path(arm, flexible=flexible)
    if path.is_file() and path.read_text() == text:
        (instance,) = Parser(plant).AddModels(str(path))
    else:
        (instance,) = Parser(plant).AddModelsFromString(text, "sdf")
    return instance


def add_workspace(plant, workspace: Workspace) -> ModelInstanceIndex | None:
    """Adds the static obstacle/wall model of ``workspace``; None if it has no boxes."""
    if not workspace.boxes():
        return None
    (instance,) = Parser(plant).AddModelsFromString(workspace_sdf(workspace), "sdf")
    return instance
