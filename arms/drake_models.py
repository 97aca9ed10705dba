"""Loading our arm and workspace models into a Drake MultibodyPlant (no downloads, ever)."""

from __future__ import annotations

from pydrake.multibody.parsing import Parser
from pydrake.multibody.tree import ModelInstanceIndex

from telesmooth.arms.description import ArmDescription, model_path
from telesmooth.arms.workspace import Workspace, workspace_sdf

__all__ = ["add_arm", "add_workspace"]


def add_arm(plant, arm: ArmDescription, *, flexible: bool) -> ModelInstanceIndex:
    """Adds the committed SDFormat model of ``arm`` (rigid or flexible) to ``plant``.

    Call before ``plant.Finalize()``. Returns the model instance (named ``arm.name``).
    """
    path = model_path(arm, flexible=flexible)
    if not path.is_file():
        raise FileNotFoundError(
            f"arm model {path} is missing; regenerate it with "
            "`python -m telesmooth.arms.description`"
        )
    (instance,) = Parser(plant).AddModels(str(path))
    return instance


def add_workspace(plant, workspace: Workspace) -> ModelInstanceIndex | None:
    """Adds the static obstacle/wall model of ``workspace``; None if it has no boxes."""
    if not workspace.boxes():
        return None
    (instance,) = Parser(plant).AddModelsFromString(workspace_sdf(workspace), "sdf")
    return instance
