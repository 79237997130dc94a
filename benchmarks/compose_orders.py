"""Sub-tasks in an order never demonstrated, closed loop: `digail compose RUN --order` against a scripted expert.

    python benchmarks/compose_orders.py circle --runs runs/cw_s0 runs/cw_s1 runs/cw_s2 --flat runs/cw_flat_s0
    python benchmarks/compose_orders.py rooms --runs runs/frs_s0 --flat runs/fr_flat_s0

Each call measures one task and merges its entry into benchmarks/results/new-orders/compose_orders.json
(`--out`), with the command that made it. Every run folder is measured as trained (its model.pt) and as its VAE
alone (RUN/vae, when there), with the same episodes for every policy.

- circle: Circle-World reversed, the counter-clockwise circle first, then the clockwise one, no durations given.
  The order is the run's codes for labels 1, 0 (its segmentation.json mapping). Success is the env's own
  `order_reversed` (each half encloses at least half the circle's area with the new order's sign); beside it the
  radius and closure errors, and the mean distance per step to the reversed reference path
  (`reversed_reference_point`, divided by the radius). Reference: the scripted reversed expert
  (`circle_reversed_expert`). Rows: the closed-loop order with q alone (`--fallback none`), with the default
  fallback (the counter-clockwise code, which no demonstration leaves, runs its demonstrated length), the
  demonstrated order closed loop, the open-loop schedule with the true durations (60:60), and the flat policy.
- route: the landmark route in a new order (`--order`, default 3,2,1,0; demonstrated 0,2,1,3); success is the
  env's `is_success` for that order. Rows: the closed-loop order with q alone and with the fallback, the run's own
  macro-policy, and the flat policy. Reference: `route_expert` on the new order.
- rooms: Four Rooms, a route never demonstrated: start in room r, apple in the next room clockwise (r + 1), the
  long way round through corridors r - 1, r - 2, r - 3 (mod 4) and then the apple. The shortest-path expert
  passes at most two corridors, so no demonstration takes this route. 25 episodes per start room. The code of a
  corridor (or of the apple) is the one q gives most often to demonstration steps with that oracle label. Success:
  the corridors entered are exactly the route's (`corridor_entries`) and the episode ends at the apple within the
  64-step limit. Reference: `FourRoomsRouteExpert`. Rows: the closed-loop order (default fallback), the run's own
  macro-policy, and the flat policy.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from digail.algos.decode import hierarchical_act, segment_many
from digail.checkpoint import load_model, read_config
from digail.data.minari_io import load_dataset
from digail.envs import make_env
from digail.envs.actions import env_action_fn
from digail.envs.circle_world import reversed_reference_point
from digail.envs.episodes import Episode, play_batch, play_episodes
from digail.envs.four_rooms import APPLE_LABEL, ROOMS, corridor_entries
from digail.envs.landmark_route import ROUTE_ENV_ID
from digail.eval.composition import CodeSchedule, demonstrated_lengths, order_summary, parse_order, play_order
from digail.eval.returns import summarize
from digail.experts.scripted import FourRoomsRouteExpert, circle_reversed_expert, route_expert
from digail.fsio import write_json

CIRCLE = "digail/CircleWorld-v0"
ROOMS_ENV = "digail/FourRooms-v0"
SEED = 20_000
"""seed of the first episode, as `digail compose`'s default"""

TRAINING = {
    "circle": ["digail run digail/CircleWorld-v0 --seed S --out runs/cw_sS  # S = 0, 1, 2",
               "digail pretrain --demos digail/circleworld/expert-v0 --codes 1 --seed S --out runs/cw_flat_sS",
               "digail train --demos digail/circleworld/expert-v0 --vae runs/cw_flat_s0 --seed 0 "
               "--out runs/cw_flatgail_s0"],
    "rooms": ["digail run digail/FourRooms-v0 --preset four-rooms-subtasks --seed 0 --out runs/frs_s0",
              "digail pretrain --demos digail/fourrooms/expert-v0 --preset four-rooms-subtasks --seed S "
              "--out runs/frs_vae_sS  # S = 1, 2",
              "digail run digail/FourRooms-v0 --seed 0 --out runs/fr_s0",
              "digail pretrain --demos digail/fourrooms/expert-v0 --codes 1 --seed S --out runs/fr_flat_sS"],
}
"""how the run folders measured here were made (from the repository root, `PYTHONPATH=src`)"""
TRAINING["route"] = ["digail pretrain --demos digail/landmarkroute/expert-v0 --seed S --out runs/lr_vae_sS",
                     "digail pretrain --demos digail/landmarkroute/expert-v0 --codes 1 --seed 0 --out runs/lr_flat_s0"]


# ------------------------------------------------------------------------------------------ shared
def _models(run: Path) -> list[tuple[str, Any]]:
    """(name, model) of the run as trained and of its VAE alone (a `digail pretrain` folder: the VAE only)."""
    out = [("vae" if read_config(run).get("kind") == "vae" else "trained", load_model(run / "model.pt")[0])]
    if (run / "vae" / "model.pt").is_file():
        out.append(("vae", load_model(run / "vae" / "model.pt")[0]))
    return out


def _demo_codes(run: Path, model: Any) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """q's causal codes of the run's training demonstrations and their oracle labels."""
    trajs = load_dataset(read_config(run)["demos"]).trajs
    return segment_many(model, trajs), [np.asarray(t.subtasks[:len(t)]) for t in trajs]


def _play(model: Any, envs: list[gym.Env], episodes: int, seed: int, schedule: Any = None) -> list[Episode]:
    act = hierarchical_act(model, env_action_fn(envs[0]), deterministic=True, schedule=schedule)
    return play_batch(envs, act, episodes, seed, keep=episodes)


def _mean_sd(rows: list[dict[str, Any]], key: str) -> dict[str, float]:
    vals = [float(r[key]) for r in rows if isinstance(r.get(key), (int, float))]
    return {"mean": float(np.mean(vals)), "sd": float(np.std(vals)), "n": len(vals)} if vals else {}


# ------------------------------------------------------------------------------------------ Circle-World
def _circle_scores(eps: list[Episode]) -> dict[str, Any]:
    out = summarize(eps, CIRCLE)
    dist = []
    for e in eps:
        r, xy = float(e.reset_info["radius"]), np.asarray(e.obs, np.float64)
        ref = np.stack([reversed_reference_point(r, k) for k in range(len(xy))])
        dist.append(float(np.mean(np.linalg.norm(xy - ref, axis=1))) / r)
    out["success"] = out.get("order_reversed_rate", 0.0)
    out["reversed_reference_distance"] = float(np.mean(dist))
    return {k: v for k, v in out.items() if k in ("success", "order_correct_rate", "order_reversed_rate",
                                                   "radius_error", "closure_error", "reversed_reference_distance",
                                                   "episodes")}


def _circle_envs(n: int = 8) -> list[gym.Env]:
    return [make_env(CIRCLE) for _ in range(n)]


def _label_order(run: Path, labels: list[int]) -> list[int]:
    """The run's codes for the oracle sub-task `labels`, through the code -> label mapping its segmentation.json
    found on the demonstrations."""
    seg = json.loads((run / "segmentation.json").read_text())
    by_label = {int(lb): int(c) for c, lb in seg["mapping"].items()}
    return [by_label[lb] for lb in labels]


def circle(args: argparse.Namespace) -> dict[str, Any]:
    envs = _circle_envs()
    expert = _circle_scores(play_episodes(envs[0], lambda env, obs: circle_reversed_expert(env), args.episodes,
                                          SEED, keep=True))
    rows: list[dict[str, Any]] = []
    for run in args.runs:
        order = _label_order(run, [1, 0])
        for name, model in _models(run):
            codes, _ = _demo_codes(run, model)
            lengths = demonstrated_lengths(codes)
            row: dict[str, Any] = {"run": str(run), "model": name, "order": order, "demonstrated_lengths": lengths}
            for variant, lens in (("order_q_only", {}), ("order", lengths)):
                eps, sw = play_order(model, envs, order, args.episodes, SEED, hold=args.hold,
                                     lengths={c: n for c, n in lens.items() if c in order[:-1]},
                                     keep_obs=args.episodes)
                summ = order_summary(sw)
                row[variant] = {**_circle_scores(eps), "order_completed_rate": summ["order_completed_rate"],
                                "mean_switch_steps": summ["mean_switch_steps"]}
            eps, sw = play_order(model, envs, order[::-1], args.episodes, SEED, hold=args.hold, keep_obs=0)
            row["demonstrated_order"] = {**{k: v for k, v in summarize(eps, CIRCLE).items()
                                            if k in ("order_correct_rate", "radius_error")},
                                         "order_completed_rate": order_summary(sw)["order_completed_rate"],
                                         "mean_switch_steps": order_summary(sw)["mean_switch_steps"]}
            sched = CodeSchedule([(order[0], 60), (order[1], 60)])
            row["schedule_60_60"] = _circle_scores(_play(model, envs, args.episodes, SEED, sched))
            rows.append(row)
    flat = []
    for run in args.flat:
        model = load_model(run / "model.pt")[0]
        flat.append({"run": str(run), "codes": model.codes,
                     "closed_loop": _circle_scores(_play(model, envs, args.episodes, SEED))})
    for env in envs:
        env.close()
    summary = {m: {v: {k: _mean_sd([r[v] for r in rows if r["model"] == m], k)
                       for k in ("success", "radius_error", "reversed_reference_distance")}
                   for v in ("order", "order_q_only", "schedule_60_60")}
               for m in ("trained", "vae") if any(r["model"] == m for r in rows)}
    return {"task": "Circle-World reversed: counter-clockwise first, then clockwise", "episodes": args.episodes,
            "seed": SEED, "hold": args.hold, "expert": expert, "runs": rows, "flat": flat, "summary": summary,
            "success_vs_expert": {f"{m}:{v}": summary[m][v]["success"].get("mean", 0.0) / max(expert["success"], 1e-9)
                                  for m in summary for v in summary[m]}}


# ------------------------------------------------------------------------------------------ Four Rooms
class RouteStarts(gym.Wrapper):
    """Four Rooms episodes for the route task of start room `room`: the agent on a random cell of that room, the
    apple on a random cell of the next room clockwise, both drawn from the reset's seed."""

    def __init__(self, env: gym.Env, room: int) -> None:
        super().__init__(env)
        self.room = room

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> Any:
        rng = np.random.default_rng(seed)
        start, goal = ROOMS[self.room], ROOMS[(self.room + 1) % 4]
        agent, apple = start[int(rng.integers(len(start)))], goal[int(rng.integers(len(goal)))]
        return self.env.reset(seed=seed, options={"agent": agent, "apple": apple})


def route_of(room: int) -> list[int]:
    """The long way round from `room` to the next room clockwise: corridors room - 1, room - 2, room - 3."""
    return [(room - k) % 4 for k in (1, 2, 3)]


def _route_scores(eps: list[Episode], route: list[int]) -> dict[str, float]:
    followed = [corridor_entries(np.asarray(e.obs)) == route for e in eps]
    apple = [bool(e.final_info.get("is_success")) for e in eps]
    return {"success": float(np.mean([f and a for f, a in zip(followed, apple, strict=True)])),
            "route_followed": float(np.mean(followed)), "apple_reached": float(np.mean(apple)),
            "mean_length": float(np.mean([e.length for e in eps])),
            "shortest_route": float(np.mean([len(corridor_entries(np.asarray(e.obs))) <= 1 and a
                                             for e, a in zip(eps, apple, strict=True)]))}


def _pool(parts: list[dict[str, float]]) -> dict[str, float]:
    """Means over the start rooms of the scores every part has."""
    return {k: float(np.mean([p[k] for p in parts])) for k in parts[0] if all(k in p for p in parts)}


def _code_dependence(run: Path, model: Any) -> float:
    """Share of the demonstrations' states at which pi's most likely action is not the same under every code: 0
    means the code changes nothing pi does, so no code order can steer it."""
    import torch

    trajs = load_dataset(read_config(run)["demos"]).trajs
    obs = torch.as_tensor(np.concatenate([np.asarray(t.obs[:len(t)], np.float32) for t in trajs]))
    with torch.no_grad():
        obs_n = model.normalizer(obs)
        acts = torch.stack([model.pi.mode(obs_n, torch.eye(model.codes)[[k] * len(obs_n)])
                            for k in range(model.codes)])
    return float((acts != acts[:1]).any(0).float().mean())


def rooms(args: argparse.Namespace) -> dict[str, Any]:
    per_room = max(args.episodes // 4, 1)
    envs_of = {r: [RouteStarts(make_env(ROOMS_ENV), r) for _ in range(8)] for r in range(4)}
    expert_parts: list[dict[str, float]] = []
    room0: dict[str, list[Episode]] = {}
    for r in range(4):
        ex = FourRoomsRouteExpert(route_of(r))
        eps = play_episodes(envs_of[r][0], lambda env, obs, ex=ex: ex(env), per_room, SEED, keep=True,
                            on_episode=lambda e, ex=ex: ex.reset())
        expert_parts.append(_route_scores(eps, route_of(r)))
        room0.setdefault("scripted route expert", eps)
    rows: list[dict[str, Any]] = []
    for run in args.runs:
        for name, model in _models(run):
            codes, labels = _demo_codes(run, model)
            flat_codes, flat_labels = np.concatenate(codes), np.concatenate(labels)
            code_of = {lb: int(np.bincount(flat_codes[flat_labels == lb], minlength=model.codes).argmax())
                       for lb in range(APPLE_LABEL + 1) if np.any(flat_labels == lb)}
            lengths = demonstrated_lengths(codes)
            row: dict[str, Any] = {"run": str(run), "model": name, "code_of_label": code_of,
                                   "demonstrated_lengths": lengths, "orders": {},
                                   "pi_code_dependence": _code_dependence(run, model)}
            composed, own = [], []
            for r in range(4):
                route = route_of(r)
                own.append(_route_scores(_play(model, envs_of[r], per_room, SEED), route))
                order_codes = [code_of[c] for c in [*route, APPLE_LABEL]]
                try:
                    order = parse_order(",".join(map(str, order_codes)), model.codes)
                except Exception as exc:  # a code order with a repeat cannot say this route
                    row["orders"][str(r)] = {"codes": order_codes, "error": str(exc)}
                    composed.append({"success": 0.0, "route_followed": 0.0})
                    continue
                eps, sw = play_order(model, envs_of[r], order, per_room, SEED, hold=args.hold,
                                     lengths={c: n for c, n in lengths.items() if c in order[:-1]},
                                     keep_obs=per_room)
                scores = _route_scores(eps, route)
                row["orders"][str(r)] = {"route": route, "codes": order, **scores,
                                         "order_completed_rate": order_summary(sw)["order_completed_rate"]}
                composed.append(scores)
                if r == 0:
                    room0.setdefault(f"{run.name} ({name}), order {','.join(map(str, order))}", eps)
            row["order"], row["own_macro_policy"] = _pool(composed), _pool(own)
            rows.append(row)
    flat = []
    for run in args.flat:
        model = load_model(run / "model.pt")[0]
        parts = [_play(model, envs_of[r], per_room, SEED) for r in range(4)]
        room0.setdefault(f"{run.name} (one code)", parts[0])
        flat.append({"run": str(run), "codes": model.codes,
                     "closed_loop": _pool([_route_scores(e, route_of(r)) for r, e in enumerate(parts)])})
    for envs in envs_of.values():
        for env in envs:
            env.close()
    expert = _pool(expert_parts)
    if args.figure is not None:
        from digail.viz.figures import four_rooms_trajectories

        four_rooms_trajectories({k: [(np.asarray(e.obs), np.asarray(e.codes or [0] * e.length)) for e in v]
                                 for k, v in room0.items()}, args.figure)
    return {"task": "Four Rooms, the long way round: start room r, apple in room r + 1, corridors r - 1, r - 2, "
                    "r - 3, then the apple", "episodes": per_room * 4, "seed": SEED, "hold": args.hold,
            "expert": expert, "runs": rows, "flat": flat,
            "success_vs_expert": {f"{r['run']}:{r['model']}": r["order"]["success"] / max(expert["success"], 1e-9)
                                  for r in rows}}


# ------------------------------------------------------------------------------------------ landmark route
def _route_env_scores(eps: list[Episode]) -> dict[str, Any]:
    out = summarize(eps, ROUTE_ENV_ID)
    return {k: out[k] for k in ("episodes", "success_rate", "legs_done", "wrong_visits") if k in out}


def landmark_route(args: argparse.Namespace) -> dict[str, Any]:
    """The landmarks in the order `args.order` (default 3,2,1,0, never demonstrated; demonstrated: 0,2,1,3): a
    landmark's code is the one the run's segmentation matched to its oracle label. Success is the env's own
    `is_success` for that order (every leg in turn, no landmark touched out of turn)."""
    new = [int(x) for x in args.order.split(",")]
    envs = [make_env(ROUTE_ENV_ID, order=new) for _ in range(8)]
    demo_envs = [make_env(ROUTE_ENV_ID) for _ in range(8)]
    expert = _route_env_scores(play_episodes(envs[0], lambda env, obs: route_expert(env), args.episodes, SEED,
                                             keep=True))
    rows: list[dict[str, Any]] = []
    for run in args.runs:
        order = _label_order(run, new)
        for name, model in _models(run):
            codes, _ = _demo_codes(run, model)
            lengths = demonstrated_lengths(codes)
            row: dict[str, Any] = {"run": str(run), "model": name, "codes": order, "demonstrated_lengths": lengths}
            for variant, lens in (("order_q_only", {}), ("order", lengths)):
                eps, sw = play_order(model, envs, order, args.episodes, SEED, hold=args.hold,
                                     lengths={c: n for c, n in lens.items() if c in order[:-1]}, keep_obs=0)
                row[variant] = {**_route_env_scores(eps),
                                "order_completed_rate": order_summary(sw)["order_completed_rate"]}
            row["own_macro_policy"] = _route_env_scores(_play(model, envs, args.episodes, SEED))
            # the same policy on the demonstrated route, its own q choosing: how well the sub-task policies drive
            row["demonstrated_route"] = _route_env_scores(_play(model, demo_envs, args.episodes, SEED))
            rows.append(row)
    flat = [{"run": str(run), "codes": 1, "closed_loop": _route_env_scores(
        _play(load_model(run / "model.pt")[0], envs, args.episodes, SEED))} for run in args.flat]
    for env in envs + demo_envs:
        env.close()
    return {"task": f"Landmark route in the order {args.order} (demonstrated: 0,2,1,3)", "episodes": args.episodes,
            "seed": SEED, "hold": args.hold, "expert": expert, "runs": rows, "flat": flat,
            "success_vs_expert": {f"{r['run']}:{r['model']}": r["order"]["success_rate"] / max(
                expert["success_rate"], 1e-9) for r in rows}}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("task", choices=("circle", "rooms", "route"))
    ap.add_argument("--order", default="3,2,1,0", help="route: the landmarks' new order")
    ap.add_argument("--runs", type=Path, nargs="*", default=[], help="run folders of the hierarchical policy")
    ap.add_argument("--flat", type=Path, nargs="*", default=[], help="run folders of one-code (flat) policies")
    ap.add_argument("--episodes", type=int, default=100)
    ap.add_argument("--hold", type=int, default=1)
    ap.add_argument("--figure", type=Path, default=None, help="rooms: paths from room 0, one panel per policy")
    ap.add_argument("--out", type=Path, default=Path("benchmarks/results/new-orders/compose_orders.json"))
    args = ap.parse_args()
    result = {"circle": circle, "rooms": rooms, "route": landmark_route}[args.task](args)
    result["command"] = "python " + " ".join(sys.argv)
    result["training_commands"] = TRAINING[args.task]
    data = json.loads(args.out.read_text()) if args.out.is_file() else {}
    data[args.task] = result
    write_json(args.out, data)
    print(json.dumps({k: result[k] for k in ("expert", "success_vs_expert")}, indent=1))


if __name__ == "__main__":
    main()
