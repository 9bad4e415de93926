"""Whole episodes scored by the official CrafText wrapper (1c518ae, run unmodified) and by our env
under the `official` success rule, game-over steps included.

    python -m benchmarks.official_wrapper [--difficulty medium|hard] [--worlds 4] [--steps 300]
        [--seed 0] [--dataset PATH]

Each world is one episode of Craftax with its default parameters (zombies and skeletons spawn, so
many worlds end in game over) played by a random player. Our env plays it once per goal of every
Medium (or Hard) split, under `official`; the official `InstructionWrapper.step` scores the same
steps, with the state before the step and what Craftax's auto-reset env returns, which on the
game-over step is the new world. Per (world, text) pair both give the step of the first success
(or none) and the step the episode ended; the script prints how many pairs agree, per split and
kind, and how many official successes fell on a game-over step. Exit 1 on any disagreement.

The wrapper needs `gym` and a text encoder, which scoring never uses: both are stubbed. Its inner
env is Craftax's `EnvironmentAutoReset.step` with one change, the key: Craftax steps with the
first half of the split key, our env with the step key itself (both reset from the second half),
so the inner env steps with the key itself and both play the same trajectory.
"""

from __future__ import annotations

import argparse
import functools
import importlib
import sys
import types
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[1]
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

from env.craftext_env import CrafTextEnv, EnvConfig, EpisodeState, make_task  # noqa: E402
from env.dataset import load_dataset  # noqa: E402
from env.goals import AnyGoal  # noqa: E402
from env.scenario_tasks import encode_goals  # noqa: E402
from env.termination import Termination  # noqa: E402
from env.variant import Variant  # noqa: E402

#: Our split name -> the official module under `craftext.dataset.scenarious.SMALL` and its dict.
SPLIT_MODULES = {
    "medium_train": ("instructions", "medium"),
    "medium_test_paraphrased": ("test", "medium_test_parafrased"),
    "medium_test_other_params": ("test", "medium_test_other_paramets"),
    "hard_train": ("instructions", "hard"),
}
DIFFICULTY_SPLITS = {
    "medium": ("medium_train", "medium_test_paraphrased", "medium_test_other_params"),
    "hard": ("hard_train",),
}


def official_modules(root: Path) -> Callable[[str], Any]:
    """`importlib.import_module` over the official repository at `root`, with the two modules
    the wrapper imports but scoring never runs stubbed: `gym` (its `Wrapper` base) and the
    DistilBERT encoder (transformers, a GPU)."""
    if str(root) not in sys.path:
        sys.path.insert(0, str(root))
    gym = types.ModuleType("gym")
    gym.Wrapper = type("Wrapper", (), {})  # type: ignore[attr-defined]
    sys.modules.setdefault("gym", gym)
    encoder = "craftext.environment.encoders.craftext_distilbert_model_encoder"
    stub = types.ModuleType(encoder)
    stub.DistilBertEncode = None  # type: ignore[attr-defined]
    sys.modules.setdefault(encoder, stub)
    return importlib.import_module


class _Stepped:
    """The wrapper's inner env for one step: returns what the auto-reset step produced (computed
    once per step, outside the per-goal vmap), whatever it is asked."""

    def __init__(self, after: Any, done: jax.Array):
        self.after, self.done = after, done

    def step(self, key: Any, state: Any, action: Any, params: Any) -> Any:
        return None, self.after, jnp.float32(0), self.done, {}


@dataclass
class Episode:
    """One world's trajectory, as the official wrapper sees it, stacked by step."""

    previous: Any
    after: Any
    done: np.ndarray
    actions: np.ndarray
    game_over: int | None
    """The 1-based step the game ended on, None if it ran all steps."""


@dataclass
class Outcome:
    """One goal in one world: the 1-based step of the first success (None: none) and of the
    episode's end (None: it ran all steps)."""

    success: int | None
    end: int | None


class Harness:
    """Our env and the official wrapper for one variant and step count."""

    def __init__(self, official: Callable[[str], Any], variant: Variant, steps: int):
        self.variant, self.steps = variant, steps
        self.env = CrafTextEnv(EnvConfig(variant=variant, max_steps=steps, success_rule="official"))
        craftax, params = self.env.craftax, self.env.params
        self.reset = jax.jit(self.env.reset)
        self.batch_step = jax.jit(self.env.step_batch)

        def auto_reset_step(key: jax.Array, state: Any, action: jax.Array) -> Any:
            _, stepped, _, done, _ = craftax.step_env(key, state, action, params)
            _, world = craftax.reset_env(jax.random.split(key)[1], params)
            after = jax.tree.map(lambda x, y: jax.lax.select(done, x, y), world, stepped)
            return after, done

        self.auto_reset_step = jax.jit(auto_reset_step)
        wrapper = official("craftext.environment.craftext_wrapper")
        states = official(
            "craftext.environment.states.state"
            if variant is Variant.FULL
            else "craftext.environment.states.state_classic"
        )
        self.wrapper = wrapper
        self.game_data = states.GameData if variant is Variant.FULL else states.GameDataClassic

    @functools.cached_property
    def _official_step(self) -> Any:
        wrapper, game_data = self.wrapper, self.game_data

        def verdicts(
            targets: Any, checkers: jax.Array, previous: Any, after: Any, done: Any, action: Any
        ) -> tuple[jax.Array, jax.Array]:
            shim = types.SimpleNamespace(
                env=_Stepped(after, done), StateStructure=game_data, batched_ts=targets, steps=0
            )

            def one(index: jax.Array, checker: jax.Array) -> tuple[jax.Array, jax.Array]:
                text_state = wrapper.TextEnvState(
                    env_state=previous,
                    timestep=previous.timestep,
                    instruction=None,
                    idx=index,
                    success_rate=jnp.float32(0),
                    total_success_rate=jnp.float32(0),
                    environment_key=jnp.int32(0),
                    rng=jax.random.PRNGKey(0),
                    instruction_done=jnp.bool_(False),
                    checker_id=checker,
                )
                _, state, _, ended, _ = wrapper.InstructionWrapper.step(
                    shim, jax.random.PRNGKey(0), text_state, action, None
                )
                return state.instruction_done, ended

            return jax.vmap(one)(jnp.arange(checkers.shape[0]), checkers)

        return jax.jit(verdicts)

    def episode(
        self,
        key: np.ndarray,
        actions: np.ndarray,
        start: Any | None = None,
        kill_at: int | None = None,
    ) -> Episode:
        """Play `actions` from the world of episode `key` (or the game state `start`) until the
        game ends, with our env's step keys; with `kill_at`, the player is killed before that
        step (0-based), so it ends the game."""
        game = start if start is not None else self.start(key)
        previous, after, done, taken = [], [], [], []
        for step in range(self.steps):
            if step == kill_at:
                game = killed(game)
            step_key = jax.random.fold_in(jnp.asarray(key), step)
            action = jnp.int32(actions[step])
            next_game, ended = self.auto_reset_step(step_key, game, action)
            previous.append(game)
            after.append(next_game)
            done.append(bool(ended))
            taken.append(int(actions[step]))
            if done[-1]:
                break
            game = next_game
        stack = lambda states: jax.tree.map(lambda *leaves: jnp.stack(leaves), *states)  # noqa: E731
        return Episode(
            previous=stack(previous),
            after=stack(after),
            done=np.asarray(done),
            actions=np.asarray(taken, np.int32),
            game_over=len(done) if done[-1] else None,
        )

    def start(self, key: np.ndarray) -> Any:
        """The world our env starts episode `key` in."""
        task = make_task(np.zeros(22, bool), np.zeros(22, bool))
        return self.reset(jnp.asarray(key), task).game

    def official(self, episode: Episode, targets: Any, checkers: np.ndarray) -> list[Outcome]:
        """Each goal's outcome under the official wrapper, `targets` its stacked TargetStates."""
        met, ended = [], []
        for step in range(len(episode.actions)):
            pick = functools.partial(lambda leaf, step: leaf[step], step=step)
            done, over = self._official_step(
                targets,
                jnp.asarray(checkers),
                jax.tree.map(pick, episode.previous),
                jax.tree.map(pick, episode.after),
                jnp.bool_(episode.done[step]),
                jnp.int32(episode.actions[step]),
            )
            met.append(np.asarray(done))
            ended.append(np.asarray(over))
        return _outcomes(np.stack(met), np.stack(ended))

    def ours(
        self,
        key: np.ndarray,
        goals: Sequence[AnyGoal],
        episode: Episode,
        kill_at: int | None = None,
    ) -> list[Outcome]:
        """Each goal's outcome in our env, one row per goal, from the episode's first state (the
        player killed before step `kill_at`, as in `episode`)."""
        tasks = encode_goals(goals, self.variant)
        rows = len(goals)
        first = jax.tree.map(lambda leaf: leaf[0], episode.previous)
        state = EpisodeState(
            game=jax.tree.map(lambda leaf: jnp.broadcast_to(leaf, (rows, *leaf.shape)), first),
            task=make_task(tasks.required, tasks.forbidden, tasks.kind, tasks.params),
            episode_key=jnp.broadcast_to(jnp.asarray(key, jnp.uint32), (rows, 2)),
            steps=jnp.zeros(rows, jnp.int32),
            termination=jnp.full(rows, Termination.RUNNING, jnp.int32),
        )
        successes, ends = [], []
        for step in range(len(episode.actions)):
            if step == kill_at:
                state = EpisodeState(
                    game=killed(state.game),
                    task=state.task,
                    episode_key=state.episode_key,
                    steps=state.steps,
                    termination=state.termination,
                )
            state, info = self.batch_step(state, jnp.full(rows, episode.actions[step], jnp.int32))
            termination = np.asarray(info.termination)
            successes.append(termination == Termination.SUCCESS)
            ends.append(termination != Termination.RUNNING)
            if ends[-1].all():
                break
        met, ended = np.stack(successes), np.stack(ends)
        # The cap is ours (max_steps = steps): an episode that ran all steps did not end.
        if len(met) == self.steps:
            ended[-1] &= met[-1] | episode.done[-1]
        return _outcomes(met, ended)


def killed(game: Any) -> Any:
    """`game` with the player at 0 health and no recovery: the next step ends the game."""
    return game.replace(
        player_health=game.player_health * 0, player_recover=game.player_recover * 0
    )


def _outcomes(met: np.ndarray, ended: np.ndarray) -> list[Outcome]:
    """(steps, goals) booleans -> per goal the first step each is true (1-based, None: never)."""

    def first(column: np.ndarray) -> int | None:
        hits = np.flatnonzero(column)
        return int(hits[0]) + 1 if len(hits) else None

    return [Outcome(first(met[:, g]), first(ended[:, g])) for g in range(met.shape[1])]


@dataclass
class Tally:
    pairs: int = 0
    agree: int = 0
    successes: int = 0
    game_over_successes: int = 0


def compare(
    harness: Harness,
    official: Callable[[str], Any],
    root: Path,
    splits: Sequence[str],
    worlds: Sequence[np.ndarray],
    actions: Sequence[np.ndarray],
    starts: Sequence[Any] | None = None,
    kills: Sequence[int | None] | None = None,
) -> tuple[dict[str, Tally], list[str]]:
    """Every (world, text) pair of `splits` scored by both; the tallies per split and kind, and
    a line per disagreeing (world, goal)."""
    dataset = load_dataset(root)
    tallies: dict[str, Tally] = {}
    differences: list[str] = []
    target_state = official("craftext.environment.scenarious.checkers.target_state").TargetState
    kills = kills if kills is not None else [None] * len(worlds)
    episodes = [
        harness.episode(key, acts, None if starts is None else starts[w], kills[w])
        for w, (key, acts) in enumerate(zip(worlds, actions, strict=True))
    ]
    for split in splits:
        module, variable = SPLIT_MODULES[split]
        entries = getattr(official(f"craftext.dataset.scenarious.SMALL.{module}"), variable)
        goals = dataset.split(split)
        targets = target_state.stack([entries[goal.id]["arguments"] for goal in goals])
        if harness.variant is Variant.FULL:
            count = episodes[0].previous.achievements.shape[-1]
            targets = _padded_achievements(targets, official, count)
        checkers = np.asarray([int(entries[goal.id]["scenario_checker"]) for goal in goals])
        for w, (key, episode) in enumerate(zip(worlds, episodes, strict=True)):
            theirs = harness.official(episode, targets, checkers)
            ours = harness.ours(key, goals, episode, kills[w])
            for goal, mine, official_outcome in zip(goals, ours, theirs, strict=True):
                texts = 1 + len(goal.paraphrases)
                tally = tallies.setdefault(f"{split}/{goal.kind}", Tally())
                tally.pairs += texts
                if official_outcome.success is not None:
                    tally.successes += texts
                    if official_outcome.success == episode.game_over:
                        tally.game_over_successes += texts
                if mine == official_outcome:
                    tally.agree += texts
                else:
                    differences.append(
                        f"{split}/{goal.id} world {w} (key {list(map(int, key))}): ours "
                        f"{mine}, official {official_outcome}, game over at {episode.game_over}"
                    )
    return tallies, differences


def _padded_achievements(targets: Any, official: Callable[[str], Any], count: int) -> Any:
    """`targets` with their achievement masks padded (`NOT_MATTER`) to full Craftax's `count`.

    The wrapper's `lax.switch` traces every checker, and the achievements checker compares its
    22-entry mask with the state's achievements, which fails to trace on full Craftax: no Hard
    goal is an achievements goal, so the branch is traced but never taken, and padding its
    mask changes no verdict."""
    checkers = official("craftext.environment.scenarious.checkers.target_state")
    mask = tuple(targets.achievements.achievement_mask)
    fill = jnp.full_like(mask[0], int(checkers.AchievementState.NOT_MATTER))
    padded = mask + (fill,) * (count - len(mask))
    return targets.replace(achievements=targets.achievements.replace(achievement_mask=padded))


def world_keys(seed: int, count: int) -> list[np.ndarray]:
    return [np.asarray(jax.random.key_data(k), np.uint32) for k in _split(seed, count)]


def _split(seed: int, count: int) -> Any:
    return jax.random.split(jax.random.key(seed), count)


def add_repository_arguments(parser: argparse.ArgumentParser) -> None:
    """`--dataset` (the official repository) and `--out` (where it is unpacked otherwise)."""
    parser.add_argument("--dataset", type=Path, help="the official repository (default: unpacked)")
    parser.add_argument("--out", type=Path, default=Path("/tmp/official_wrapper"))


def repository_root(parser: argparse.ArgumentParser, args: argparse.Namespace) -> Path:
    """The official repository `--dataset` names, else the reference archive unpacked."""
    from benchmarks.official_clone import official_clone

    root = args.dataset or official_clone(args.out)
    if root is None:
        parser.error("no official repository: pass --dataset")
    return Path(root)


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--difficulty", choices=sorted(DIFFICULTY_SPLITS), default="medium")
    parser.add_argument("--worlds", type=int, default=4)
    parser.add_argument("--steps", type=int, default=300)
    parser.add_argument("--seed", type=int, default=0)
    add_repository_arguments(parser)
    args = parser.parse_args(argv)
    root = repository_root(parser, args)
    official = official_modules(root)
    variant = Variant.FULL if args.difficulty == "hard" else Variant.CLASSIC
    harness = Harness(official, variant, args.steps)
    rng = np.random.default_rng(args.seed)
    keys = world_keys(args.seed, args.worlds)
    actions = [rng.integers(variant.num_actions, size=args.steps) for _ in keys]
    tallies, differences = compare(
        harness, official, root, DIFFICULTY_SPLITS[args.difficulty], keys, actions
    )
    print(
        f"{args.difficulty}, {variant.value}, {args.worlds} worlds x {args.steps} steps, seed "
        f"{args.seed}: (world, text) pairs, agreeing, official successes (on the game-over step)"
    )
    for name, t in sorted(tallies.items()):
        print(f"  {name}: {t.pairs}, {t.agree}, {t.successes} ({t.game_over_successes})")
    total = Tally(*(sum(getattr(t, f) for t in tallies.values()) for f in Tally.__annotations__))
    print(f"  all: {total.pairs}, {total.agree}, {total.successes} ({total.game_over_successes})")
    for line in differences:
        print("  differs:", line)
    return 1 if differences else 0


if __name__ == "__main__":
    raise SystemExit(main())
