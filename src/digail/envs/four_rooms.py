"""Four Rooms: the discrete grid world of the paper (Sec. 5.1), with an oracle sub-task label.

Layout (15 wide x 11 tall including the outer walls; `#` wall, `.` floor, digits the four one-cell corridors
with their label)::

    x: 0         1
       012345678901234
    0  ###############
    1  #......#......#
    2  #......0......#
    3  #......#......#
    4  #......#......#
    5  ###3#######1###
    6  #......#......#
    7  #......#......#
    8  #......2......#
    9  #......#......#
    10 ###############

Coordinates are `(x, y)` with `x` the column (0..14, left to right) and `y` the row (0..10, top to bottom,
as in an image). Rooms are numbered clockwise from the top left (0 top-left, 1 top-right, 2 bottom-right,
3 bottom-left); corridor `i` joins room `i` and room `i + 1 (mod 4)`, so the corridor labels are
0 top, 1 right, 2 bottom, 3 left.

The oracle sub-task label of a state is where the expert's shortest path to the apple heads next: the label of
the next corridor cell on that path, not counting the cell the agent stands on, or `APPLE_LABEL` (4) when no
corridor is left before the apple. Shortest paths break ties by the fixed action order up, right, down, left,
so one state always gives the same action and the same label (`shortest_paths_to`).
"""

from __future__ import annotations

import functools
from collections import deque
from dataclasses import dataclass
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from digail.errors import UserError

GRID_WIDTH = 15
"""Grid width in cells, outer walls included."""
GRID_HEIGHT = 11
"""Grid height in cells, outer walls included."""
WALL_X = 7
"""Column of the vertical interior wall."""
WALL_Y = 5
"""Row of the horizontal interior wall."""

CORRIDORS: tuple[tuple[int, int], ...] = ((7, 2), (11, 5), (7, 8), (3, 5))
"""Doorway cells `(x, y)`, indexed by their label: 0 top, 1 right, 2 bottom, 3 left."""
APPLE_LABEL = 4
"""Sub-task label for "head straight to the apple" (no corridor left on the shortest path)."""
NUM_SUBTASKS = 5
"""Number of oracle labels: four corridors and the apple."""

ACTION_DELTAS: tuple[tuple[int, int], ...] = ((0, -1), (1, 0), (0, 1), (-1, 0))
"""`(dx, dy)` of each action: 0 up, 1 right, 2 down, 3 left (y grows downwards)."""

STEP_REWARD = -0.01
"""Reward of every step that does not reach the apple."""
APPLE_REWARD = 1.0
"""Reward of the step that reaches the apple (it replaces the step penalty)."""


def _build_walls() -> np.ndarray:
    walls = np.zeros((GRID_HEIGHT, GRID_WIDTH), dtype=bool)
    walls[[0, -1], :] = True
    walls[:, [0, -1]] = True
    walls[WALL_Y, :] = True
    walls[:, WALL_X] = True
    for x, y in CORRIDORS:
        walls[y, x] = False
    walls.setflags(write=False)
    return walls


WALLS = _build_walls()
"""Boolean (GRID_HEIGHT, GRID_WIDTH) array, True on wall cells; index it as `WALLS[y, x]`."""

ROOMS: tuple[tuple[tuple[int, int], ...], ...] = tuple(
    tuple((x, y) for y in ys for x in xs)
    for xs, ys in (
        (range(1, WALL_X), range(1, WALL_Y)),  # 0 top-left
        (range(WALL_X + 1, GRID_WIDTH - 1), range(1, WALL_Y)),  # 1 top-right
        (range(WALL_X + 1, GRID_WIDTH - 1), range(WALL_Y + 1, GRID_HEIGHT - 1)),  # 2 bottom-right
        (range(1, WALL_X), range(WALL_Y + 1, GRID_HEIGHT - 1)),  # 3 bottom-left
    )
)
"""Floor cells `(x, y)` of each room (corridors excluded), rooms numbered clockwise from the top left."""

FREE_CELLS: tuple[tuple[int, int], ...] = tuple(
    (x, y) for y in range(GRID_HEIGHT) for x in range(GRID_WIDTH) if not WALLS[y, x]
)
"""Every non-wall cell `(x, y)` (rooms and corridors), in row-major order."""

_CORRIDOR_LABEL = {cell: label for label, cell in enumerate(CORRIDORS)}
_FREE_SET = frozenset(FREE_CELLS)
_ROOM_SET = frozenset(cell for room in ROOMS for cell in room)


def move(cell: tuple[int, int], action: int) -> tuple[int, int]:
    """Cell reached from `cell` by `action`; moving into a wall keeps the position."""
    dx, dy = ACTION_DELTAS[action]
    x, y = cell[0] + dx, cell[1] + dy
    if WALLS[y, x]:
        return cell
    return (x, y)


def room_of(cell: tuple[int, int]) -> int | None:
    """Room index (0..3) of a floor cell, or None for a corridor or wall cell."""
    if cell not in _ROOM_SET:
        return None
    x, y = cell
    return (0 if y < WALL_Y else 3) if x < WALL_X else (1 if y < WALL_Y else 2)


@dataclass(frozen=True)
class ShortestPaths:
    """Shortest-path tables towards one apple cell, each a read-only (GRID_HEIGHT, GRID_WIDTH) int64 array
    indexed `[y, x]`; wall cells hold -1."""

    distance: np.ndarray
    """BFS distance (number of steps) from each cell to the apple."""
    action: np.ndarray
    """Expert action: the first of up, right, down, left that lowers the distance (0 at the apple)."""
    subtask: np.ndarray
    """Oracle label: the next corridor (0..3) the expert's path passes, or `APPLE_LABEL`."""


@functools.lru_cache(maxsize=len(FREE_CELLS))
def shortest_paths_to(apple: tuple[int, int]) -> ShortestPaths:
    """BFS distances, expert actions and oracle sub-task labels for every cell, towards `apple`.

    Ties between equally short paths go to the first action in the order up, right, down, left, and the label
    follows that same path, so the label always agrees with the action the expert takes.

    Args:
        apple: goal cell `(x, y)`; must be a free cell.

    Returns:
        The cached, read-only tables for this apple.
    """
    apple = (int(apple[0]), int(apple[1]))
    if apple not in _FREE_SET:
        raise UserError(
            f"Apple cell {apple} is not a free cell of the Four Rooms grid; pick one of FREE_CELLS."
        )
    distance = np.full((GRID_HEIGHT, GRID_WIDTH), -1, dtype=np.int64)
    distance[apple[1], apple[0]] = 0
    order = [apple]
    queue = deque(order)
    while queue:
        cell = queue.popleft()
        for a in range(len(ACTION_DELTAS)):
            nxt = move(cell, a)
            if distance[nxt[1], nxt[0]] < 0:
                distance[nxt[1], nxt[0]] = distance[cell[1], cell[0]] + 1
                order.append(nxt)
                queue.append(nxt)

    action = np.full_like(distance, -1)
    subtask = np.full_like(distance, -1)
    action[apple[1], apple[0]] = 0
    subtask[apple[1], apple[0]] = APPLE_LABEL
    # BFS order visits cells by increasing distance, so the successor's label is always known already.
    for cell in order[1:]:
        x, y = cell
        for a in range(len(ACTION_DELTAS)):
            nxt = move(cell, a)
            if distance[nxt[1], nxt[0]] == distance[y, x] - 1:
                action[y, x] = a
                subtask[y, x] = _CORRIDOR_LABEL.get(nxt, subtask[nxt[1], nxt[0]])
                break
    for table in (distance, action, subtask):
        table.setflags(write=False)
    return ShortestPaths(distance=distance, action=action, subtask=subtask)


def encode_observation(agent: tuple[int, int], apple: tuple[int, int]) -> np.ndarray:
    """The 52-dim observation: `onehot(agent_x, 15) ++ onehot(agent_y, 11) ++ onehot(apple_x, 15) ++
    onehot(apple_y, 11)`, float32."""
    obs = np.zeros(2 * (GRID_WIDTH + GRID_HEIGHT), dtype=np.float32)
    obs[agent[0]] = 1.0
    obs[GRID_WIDTH + agent[1]] = 1.0
    obs[GRID_WIDTH + GRID_HEIGHT + apple[0]] = 1.0
    obs[2 * GRID_WIDTH + GRID_HEIGHT + apple[1]] = 1.0
    return obs


def room_visits(obs: np.ndarray) -> np.ndarray:
    """The room visit of each of a demonstration's (T, 52) observations, numbered 0, 1, ... in time: a new visit
    begins where the agent steps onto a corridor cell. The pieces `--vae.init-pieces env` gives one code each:
    a sub-task of the paper's Four Rooms (heading for a corridor or for the apple) can only change there."""
    agent, _ = decode_observations(obs)
    on_corridor = np.array([(int(x), int(y)) in _CORRIDOR_LABEL for x, y in agent], dtype=bool)
    return np.cumsum(np.r_[False, on_corridor[1:] & ~on_corridor[:-1]]).astype(np.int64)


def corridor_entries(obs: np.ndarray) -> list[int]:
    """The corridors (labels 0..3) a path of (T, 52) observations steps onto, in order: one entry each time the
    agent moves onto a corridor cell from a room cell (standing on it counts once). A route is followed when
    these are exactly its corridors."""
    agent, _ = decode_observations(obs)
    labels = [_CORRIDOR_LABEL.get((int(x), int(y)), -1) for x, y in agent]
    return [lb for prev, lb in zip([-1, *labels[:-1]], labels, strict=True) if lb >= 0 and prev < 0]


def decode_observations(obs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """`encode_observation` undone for a batch: (T, 52) observations -> (T, 2) agent cells and (T, 2) apple cells,
    each (x, y) as int64."""
    w, h = GRID_WIDTH, GRID_HEIGHT
    o = np.asarray(obs).reshape(-1, 2 * (w + h))
    agent = np.column_stack([o[:, :w].argmax(1), o[:, w:w + h].argmax(1)])
    apple = np.column_stack([o[:, w + h:2 * w + h].argmax(1), o[:, 2 * w + h:].argmax(1)])
    return agent, apple


class FourRoomsEnv(gym.Env[np.ndarray, np.int64]):
    """Reach the apple in a four-room grid world (Directed-Info GAIL, Sec. 5.1).

    - **Reset**: the apple goes on a uniformly random cell of a uniformly random room (never a corridor), the
      agent on a uniformly random free cell (rooms or corridors) other than the apple. `options` may fix
      either: `{"agent": (x, y), "apple": (x, y)}`.
    - **Observation**: `Box(0, 1, (52,), float32)`, the concatenation `onehot(agent_x, 15)`,
      `onehot(agent_y, 11)`, `onehot(apple_x, 15)`, `onehot(apple_y, 11)` (see `encode_observation`).
    - **Actions**: `Discrete(4)`: 0 up, 1 right, 2 down, 3 left; moving into a wall keeps the position.
    - **Reward**: `APPLE_REWARD` (+1) on the step that reaches the apple, `STEP_REWARD` (-0.01) on every
      other step.
    - **Termination**: at the apple. The time limit (truncation) comes from the registration (64 steps, well
      above the longest shortest path, 20 steps).
    - **info** (same keys at reset and every step): `subtask` (int, oracle label of the current state, see the
      module docstring), `shortest_path_length` (int, BFS distance from the current cell to the apple) and
      `is_success` (bool, the agent is on the apple).

    Attributes:
        agent: current agent cell `(x, y)`.
        apple: apple cell `(x, y)`.
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 8}

    CELL_PIXELS = 16
    """Side of one grid cell in rendered images."""

    def __init__(self, render_mode: str | None = None) -> None:
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise UserError(
                f"Unsupported render_mode {render_mode!r} for FourRooms; use 'rgb_array' or None."
            )
        self.render_mode = render_mode
        self.observation_space = spaces.Box(
            0.0, 1.0, shape=(2 * (GRID_WIDTH + GRID_HEIGHT),), dtype=np.float32
        )
        self.action_space = spaces.Discrete(len(ACTION_DELTAS))
        self.agent: tuple[int, int] = FREE_CELLS[0]
        self.apple: tuple[int, int] = ROOMS[0][0]

    def _info(self) -> dict[str, Any]:
        paths = shortest_paths_to(self.apple)
        x, y = self.agent
        return {
            "subtask": int(paths.subtask[y, x]),
            "shortest_path_length": int(paths.distance[y, x]),
            "is_success": self.agent == self.apple,
        }

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        super().reset(seed=seed)
        options = options or {}
        if "apple" in options:
            apple = (int(options["apple"][0]), int(options["apple"][1]))
            if apple not in _ROOM_SET:
                raise UserError(f"options['apple'] {apple} is not a room cell; pick a cell from ROOMS.")
        else:
            room = ROOMS[int(self.np_random.integers(len(ROOMS)))]
            apple = room[int(self.np_random.integers(len(room)))]
        if "agent" in options:
            agent = (int(options["agent"][0]), int(options["agent"][1]))
            if agent not in _FREE_SET or agent == apple:
                raise UserError(f"options['agent'] {agent} must be a free cell other than the apple {apple}.")
        else:
            starts = [cell for cell in FREE_CELLS if cell != apple]
            agent = starts[int(self.np_random.integers(len(starts)))]
        self.agent, self.apple = agent, apple
        return encode_observation(self.agent, self.apple), self._info()

    def step(self, action: Any) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        a = int(action)
        if not 0 <= a < len(ACTION_DELTAS):
            raise ValueError(f"FourRooms action must be an integer in [0, 4), got {action!r}.")
        self.agent = move(self.agent, a)
        reached = self.agent == self.apple
        reward = APPLE_REWARD if reached else STEP_REWARD
        return encode_observation(self.agent, self.apple), reward, reached, False, self._info()

    def render(self) -> np.ndarray | None:  # type: ignore[override]
        """An RGB image (uint8, 176 x 240 x 3): walls dark, corridors light grey, apple red, agent blue."""
        if self.render_mode != "rgb_array":
            return None
        cell_rgb = np.full((GRID_HEIGHT, GRID_WIDTH, 3), 255, dtype=np.uint8)
        cell_rgb[WALLS] = (60, 60, 60)
        for x, y in CORRIDORS:
            cell_rgb[y, x] = (215, 215, 215)
        image = np.repeat(np.repeat(cell_rgb, self.CELL_PIXELS, axis=0), self.CELL_PIXELS, axis=1)
        # Faint grid lines make individual cells countable.
        image[:: self.CELL_PIXELS, :] = np.minimum(image[:: self.CELL_PIXELS, :], 230)
        image[:, :: self.CELL_PIXELS] = np.minimum(image[:, :: self.CELL_PIXELS], 230)
        self._draw_disc(image, self.apple, (220, 30, 30))
        self._draw_disc(image, self.agent, (30, 80, 220))
        return image

    def _draw_disc(self, image: np.ndarray, cell: tuple[int, int], rgb: tuple[int, int, int]) -> None:
        size = self.CELL_PIXELS
        yy, xx = np.mgrid[0:size, 0:size]
        centre = (size - 1) / 2
        disc = (xx - centre) ** 2 + (yy - centre) ** 2 <= (0.38 * size) ** 2
        patch = image[cell[1] * size : (cell[1] + 1) * size, cell[0] * size : (cell[0] + 1) * size]
        patch[disc] = rgb


class FourRoomsVecEnv:
    """N Four Rooms envs stepped together as arrays: the training rollouts' `sync` backend for this env.

    Follows `digail.envs.vector.VectorEnv` (same-step autoreset, `final` observations and infos of the envs that
    ended) and gives the numbers of N wrapped `FourRoomsEnv`s in `digail.envs.vector.VecEnv` bit for bit
    (tests/test_vector.py): each env keeps its own Gymnasium RNG and draws its resets exactly as
    `FourRoomsEnv.reset` does; a step moves every agent at once and counts the time limit as Gymnasium's
    `TimeLimit` does. Why: the grid's step is a table lookup under tens of microseconds of per-env Python.

    Args:
        env_id: the registered id (its time limit and keyword arguments apply, e.g. `max_episode_steps`).
        num_envs: N.
        **kwargs: passed to `gym.make`.
    """

    def __init__(self, env_id: str, num_envs: int, **kwargs: Any) -> None:
        # made through the registry's entry, which names this class: the id is registered by then
        self._probe = gym.make(env_id, **kwargs)
        if not isinstance(self._probe.unwrapped, FourRoomsEnv):
            raise UserError(f"FourRoomsVecEnv steps Four Rooms only, not {env_id!r}.")
        spec = self._probe.spec
        self.limit = spec.max_episode_steps if spec is not None else None
        self.num_envs = num_envs
        self.single_action_space = self._probe.action_space
        self._rngs: list[np.random.Generator | None] = [None] * num_envs
        self.agent = np.zeros((num_envs, 2), dtype=np.int64)
        self.apple = np.zeros((num_envs, 2), dtype=np.int64)
        self.elapsed = np.zeros(num_envs, dtype=np.int64)
        self._deltas = np.array(ACTION_DELTAS, dtype=np.int64)

    @property
    def probe(self) -> gym.Env:
        return self._probe

    def _info(self, i: int) -> dict[str, Any]:
        paths = shortest_paths_to((int(self.apple[i, 0]), int(self.apple[i, 1])))
        x, y = int(self.agent[i, 0]), int(self.agent[i, 1])
        return {"subtask": int(paths.subtask[y, x]), "shortest_path_length": int(paths.distance[y, x]),
                "is_success": bool(x == self.apple[i, 0] and y == self.apple[i, 1])}

    def _reset_one(self, i: int, seed: int | None) -> dict[str, Any]:
        from gymnasium.utils import seeding

        if seed is not None or self._rngs[i] is None:  # gym.Env.reset(seed=...) and its lazy unseeded RNG
            self._rngs[i], _ = seeding.np_random(seed)
        rng = self._rngs[i]
        assert rng is not None
        room = ROOMS[int(rng.integers(len(ROOMS)))]
        apple = room[int(rng.integers(len(room)))]
        starts = [cell for cell in FREE_CELLS if cell != apple]
        self.agent[i] = starts[int(rng.integers(len(starts)))]
        self.apple[i] = apple
        self.elapsed[i] = 0
        return self._info(i)

    def _obs(self) -> np.ndarray:
        obs = np.zeros((self.num_envs, 2 * (GRID_WIDTH + GRID_HEIGHT)), dtype=np.float32)
        rows = np.arange(self.num_envs)
        for offset, column in ((0, self.agent[:, 0]), (GRID_WIDTH, self.agent[:, 1]),
                               (GRID_WIDTH + GRID_HEIGHT, self.apple[:, 0]),
                               (2 * GRID_WIDTH + GRID_HEIGHT, self.apple[:, 1])):
            obs[rows, offset + column] = 1.0  # encode_observation, row by row
        return obs

    def reset(self, seeds: Any) -> tuple[np.ndarray, list[dict[str, Any]]]:
        infos = [self._reset_one(i, s) for i, s in enumerate(seeds)]
        return self._obs(), infos

    def step(self, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray,
                                                 list[dict[str, Any]], dict[int, tuple[np.ndarray, dict[str, Any]]]]:
        a = np.asarray(actions).reshape(self.num_envs).astype(np.int64)
        if np.any((a < 0) | (a >= len(ACTION_DELTAS))):
            raise ValueError(f"FourRooms actions must be integers in [0, 4), got {actions!r}.")
        target = self.agent + self._deltas[a]
        blocked = WALLS[target[:, 1], target[:, 0]]  # `move`: a wall keeps the position
        self.agent = np.where(blocked[:, None], self.agent, target)
        reached = np.all(self.agent == self.apple, axis=1)
        rews = np.where(reached, APPLE_REWARD, STEP_REWARD).astype(np.float32)
        self.elapsed += 1
        truncs = self.elapsed >= self.limit if self.limit is not None else np.zeros(self.num_envs, dtype=bool)
        obs = self._obs()
        infos = [self._info(i) for i in range(self.num_envs)]
        final: dict[int, tuple[np.ndarray, dict[str, Any]]] = {}
        for i in np.flatnonzero(reached | truncs):
            final[int(i)] = (obs[i].copy(), infos[i])
            infos[i] = self._reset_one(int(i), None)
        if final:
            ended = np.fromiter(final, dtype=np.int64, count=len(final))
            obs[ended] = self._obs()[ended]
        return obs, rews, reached, truncs, infos, final

    def close(self) -> None:
        self._probe.close()
