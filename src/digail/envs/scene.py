"""Where an env's observation holds the end-effector, the object and the goal (or several landmarks), and which
actions move the end-effector: what `digail generate` needs to move a demonstrated path into a new scene and track
it there.

An env states this once, in its registry entry (`EnvSpec.scene`); a user's env gives the same by flags
(`digail generate --ee 0:3 --object 3:6 ...`, parsed by `parse_columns`).
"""

from __future__ import annotations

from dataclasses import dataclass

from digail.errors import UserError


@dataclass(frozen=True)
class SceneColumns:
    """The columns of a flat observation and action that locate the scene's parts (positions in metres, world
    frame), and how far one unit of a move action moves the end-effector."""

    ee: slice
    """end-effector position (3 columns, or 2 in a planar env)"""
    object: slice | None
    """position of the object the task acts on (as many columns as `ee`); None: the scene has landmarks instead"""
    goal: slice | None
    """position of the goal (as many columns as `ee`); None: the env observes no goal"""
    move_actions: slice
    """the action columns that move the end-effector by a displacement (one per position column)"""
    gripper_action: int | None
    """the action column that opens and closes the gripper (kept from the source demonstration); None: none"""
    action_scale: float
    """metres the end-effector's target moves per unit of a move action"""
    integrating: bool = False
    """the move actions displace a target that accumulates them (Meta-World's mocap, which the hand follows with a
    lag), rather than one placed relative to the end-effector at every step (Fetch's): paths are then tracked on
    that target, dead-reckoned from the actions, so that the hand lags as it lagged in the source"""
    landmarks: tuple[slice, ...] = ()
    """positions of further things a sub-task can head for (the landmark route's four landmarks): frames
    `landmark0`, `landmark1`, ... in this order"""

    @property
    def dim(self) -> int:
        """numbers per position (3, or 2 in a planar env)"""
        return len(range(self.ee.stop or 0)[self.ee])

    def check(self, obs_dim: int, act_dim: int) -> None:
        """Refuse, in one sentence, columns outside an observation of `obs_dim` numbers or actions of `act_dim`."""
        named = [("--ee", self.ee), ("--object", self.object), ("--goal", self.goal),
                 *((f"landmark {i}", c) for i, c in enumerate(self.landmarks))]
        for name, cols in named:
            if cols is None:
                continue
            if len(range(obs_dim)[cols]) != self.dim or (cols.stop or 0) > obs_dim:
                raise UserError(f"{name} {_text(cols)} must name {self.dim} columns of the {obs_dim}-number "
                                "observation; pass e.g. 0:3.")
        if len(range(act_dim)[self.move_actions]) != self.dim or (self.move_actions.stop or 0) > act_dim:
            raise UserError(f"--move-actions {_text(self.move_actions)} must name {self.dim} columns of the "
                            f"{act_dim}-number action; pass e.g. 0:3.")
        if self.gripper_action is not None and not 0 <= self.gripper_action < act_dim:
            raise UserError(f"--gripper-action {self.gripper_action} is not a column of the {act_dim}-number action;"
                            f" pass one of 0-{act_dim - 1}.")
        if not self.action_scale > 0:
            raise UserError(f"--action-scale must be positive (metres per action unit), not {self.action_scale}.")


def _text(cols: slice) -> str:
    return f"{cols.start}:{cols.stop}"


def parse_columns(text: str, flag: str) -> slice:
    """'3:6' -> slice(3, 6), refusing anything else in one sentence."""
    start, sep, stop = text.partition(":")
    try:
        if not sep:
            raise ValueError
        cols = slice(int(start), int(stop))
    except ValueError:
        raise UserError(f"{flag} {text!r} is not a column range; pass START:STOP, e.g. 0:3.") from None
    if cols.start < 0 or cols.stop - cols.start != 3:
        raise UserError(f"{flag} {text} must name 3 columns (a position), e.g. 0:3.")
    return cols


FETCH = SceneColumns(ee=slice(0, 3), object=slice(3, 6), goal=slice(25, 28), move_actions=slice(0, 3),
                     gripper_action=3, action_scale=0.05)
"""digail/FetchPickAndPlace-v4 (`digail.envs.fetch`): gripper, cube and goal; one action unit moves the mocap
target 5 cm"""
METAWORLD = SceneColumns(ee=slice(0, 3), object=slice(4, 7), goal=slice(36, 39), move_actions=slice(0, 3),
                         gripper_action=3, action_scale=0.01, integrating=True)
"""every Meta-World v3 task (`digail.envs.metaworld`): the hand, the first object and the goal; one action unit moves
the mocap 1 cm (Meta-World's `action_scale`)"""
LANDMARK_ROUTE = SceneColumns(ee=slice(0, 2), object=None, goal=None, move_actions=slice(0, 2), gripper_action=None,
                              action_scale=0.05, landmarks=(slice(2, 4), slice(4, 6), slice(6, 8), slice(8, 10)))
"""digail/LandmarkRoute-v0 (`digail.envs.landmark_route`): the point and the four landmarks in label order, in the
plane; one action unit moves the point `SPEED` (0.05)"""
