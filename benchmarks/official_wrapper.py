"""Whole episodes scored by the official CrafText wrapper (1c518ae, run unmodified) and by our env
under the `official` success rule, game-over steps included.

    python -m benchmarks.official_wrapper [--difficulty medium|hard] [--worlds 4] [--steps 300]
        [--seed 0] [--dataset PATH]
    python -m benchmarks.official_wrapper --case CASE.jsonl --case-goal SPLIT/GOAL_ID

Each world is one episode of Craftax with its default parameters (zombies and skeletons spawn, so
many worlds end in game over) played by a random player. Our env plays it once per goal of every
Medium (or Hard) split, under `official`; the official `InstructionWrapper.step` scores the same
steps, with the state before the step and what Craftax's auto-reset env returns, which on the
game-over step is the new world. Per (world, text) pair both give the step of the first success
(or none) and the step the episode ended; the script prints how many pairs agree, per split and
kind, and how many official successes fell on a game-over step. Exit 1 on any disagreement.

The wrapper needs `gym` and a text encoder, which scoring never uses: both are stubbed. Its inner
env is Craftax's `EnvironmentAutoReset.step`, unmodified, called with our env's step keys: both
step the game with the first half of the key's split and make a game over's new world from the
second.

`--case` replays one recorded episode instead (a JSON line: `world_key`, `actions`, from the
official wrapper's `reset(world_key)` world), the real wrapper and its real auto-reset inner env
stepped beside our env with the same key each step (`fold_in(world_key, t)` split in two, the
second half: `case_step_key`), and prints every step where the two differ in the game, the end
or the verdict. Exit 1 if any does.
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
from typing import Any, Literal, NoReturn

REPO = Path(__file__).resolve().parents[1]
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
from pydantic import BaseModel, ConfigDict, Field, ValidationError  # noqa: E402

from env.craftext_env import CrafTextEnv, EnvConfig, EpisodeState, make_task  # noqa: E402
from env.dataset import load_dataset  # noqa: E402
from env.goals import AnyGoal  # noqa: E402
from env.rules import DEFAULT_STEP_KEYS, StepKeys  # noqa: E402
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


def auto_reset_env(variant: Variant) -> Any:
    """Craftax's own auto-reset env of `variant`: the official wrapper's inner env."""
    from craftax.craftax_env import make_craftax_env_from_name

    return make_craftax_env_from_name(variant.craftax_name, auto_reset=True)


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
        params = self.env.params
        self.reset = jax.jit(self.env.reset)
        self.batch_step = jax.jit(self.env.step_batch)
        self.inner = auto_reset_env(variant)

        def auto_reset_step(key: jax.Array, state: Any, action: jax.Array) -> Any:
            _, after, _, done, _ = self.inner.step(key, state, action, params)
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
    episodes: Sequence[Episode] | None = None,
) -> tuple[dict[str, Tally], list[str]]:
    """Every (world, text) pair of `splits` scored by both; the tallies per split and kind, and
    a line per disagreeing (world, goal). `episodes`: the worlds already played (`play`)."""
    dataset = load_dataset(root)
    tallies: dict[str, Tally] = {}
    differences: list[str] = []
    target_state = official("craftext.environment.scenarious.checkers.target_state").TargetState
    kills = kills if kills is not None else [None] * len(worlds)
    if episodes is None:
        episodes = play(harness, worlds, actions, starts, kills)
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


def play(
    harness: Harness,
    worlds: Sequence[np.ndarray],
    actions: Sequence[np.ndarray],
    starts: Sequence[Any] | None = None,
    kills: Sequence[int | None] | None = None,
) -> list[Episode]:
    """Each world's episode, as the official wrapper sees it (`Harness.episode`)."""
    kills = kills if kills is not None else [None] * len(worlds)
    return [
        harness.episode(key, acts, None if starts is None else starts[w], kills[w])
        for w, (key, acts) in enumerate(zip(worlds, actions, strict=True))
    ]


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


class GameOverCase(BaseModel):
    """One recorded episode (a line of a case file): the official wrapper's `reset(world_key)`
    world, played with `actions` under Craftax-Classic's default parameters."""

    model_config = ConfigDict(extra="ignore")

    world_key: tuple[int, int]
    actions: list[int] = Field(min_length=1)
    game_over_step: int | None = None
    """The 1-based step the game ended on, as recorded (compared, not trusted)."""
    peaceful: Literal[False] = False
    """Only Craftax's default parameters (mobs spawn) are replayed."""


@dataclass
class CaseStep:
    """What both sides made of one step of a case (1-based `step`)."""

    step: int
    game_over: bool
    """Whether Craftax ended the game on this step (in our env's game)."""
    games_equal: bool
    """Whether the worlds both check after the step are the same, leaf for leaf: the games, or
    on a game-over step the new world the wrapper's inner env started and the one our env
    makes (`CrafTextEnv.new_world`)."""
    official_ended: bool
    official_met: bool
    """The wrapper's `instruction_done`."""
    ours: Termination

    @property
    def agrees(self) -> bool:
        return (
            self.games_equal
            and self.official_ended == (self.ours is not Termination.RUNNING)
            and self.official_met == (self.ours is Termination.SUCCESS)
        )


def refuse(message: str) -> NoReturn:
    """A mistake in the script's arguments: one line on stderr, exit 2, nothing run."""
    print(f"error: {message}", file=sys.stderr)
    raise SystemExit(2)


def same_game(one: Any, other: Any) -> bool:
    """Whether two Craftax states are the same game: every leaf equal, floats to within a
    millionth. A new world made inside a compiled step and the same world made alone differ in
    the last bit of the light level (XLA compiles its cosine differently), never in anything a
    checker reads."""

    def equal(a: Any, b: Any) -> bool:
        a, b = np.asarray(a), np.asarray(b)
        if np.issubdtype(a.dtype, np.floating):
            return a.shape == b.shape and bool(np.allclose(a, b, rtol=1e-6, atol=0))
        return bool(np.array_equal(a, b))

    return all(
        equal(a, b) for a, b in zip(jax.tree.leaves(one), jax.tree.leaves(other), strict=True)
    )


def read_case(path: Path) -> GameOverCase:
    """The first line of a case file (refused in one line naming the file when it is not
    one)."""
    try:
        return GameOverCase.model_validate_json(path.read_text().splitlines()[0])
    except (OSError, IndexError, ValidationError) as error:
        reason = str(error).splitlines()[0]
        refuse(f"{path} is not a game-over case: {reason}")


def case_step_key(world_key: jax.Array, step: int) -> jax.Array:
    """The key both sides step with at `step` (0-based): the second half of the split of
    `fold_in(world_key, step)` (the first is the recording player's)."""
    return jax.random.split(jax.random.fold_in(world_key, step))[1]


def replay_case(
    official: Callable[[str], Any],
    root: Path,
    case: GameOverCase,
    split: str,
    goal_id: str,
    step_keys: StepKeys = DEFAULT_STEP_KEYS,
) -> list[CaseStep]:
    """Each step of `case` under the official wrapper (its real auto-reset inner env) and our
    Craftax-Classic env under `official`, until either side's episode ends. Our env steps with
    the wrapper's key; under `step_keys="whole"` with the half of it the wrapper's game steps
    with, so that the games are the same."""
    module, variable = SPLIT_MODULES[split]
    entries = getattr(official(f"craftext.dataset.scenarious.SMALL.{module}"), variable)
    if goal_id not in entries:
        refuse(f"no goal {goal_id!r} in {split}")
    wrapper = official("craftext.environment.craftext_wrapper")
    target_state = official("craftext.environment.scenarious.checkers.target_state").TargetState
    game_data = official("craftext.environment.states.state_classic").GameDataClassic
    inner = auto_reset_env(Variant.CLASSIC)
    params = inner.default_params
    shim = types.SimpleNamespace(
        env=inner,
        StateStructure=game_data,
        batched_ts=target_state.stack([entries[goal_id]["arguments"]]),
        steps=0,
    )
    world_key = jnp.asarray(case.world_key, jnp.uint32)
    _, game = inner.reset(world_key, params)
    theirs = wrapper.TextEnvState(
        env_state=game,
        timestep=game.timestep,
        instruction=None,
        idx=jnp.int32(0),
        success_rate=jnp.float32(0),
        total_success_rate=jnp.float32(0),
        environment_key=jnp.int32(0),
        rng=world_key,
        instruction_done=jnp.bool_(False),
        checker_id=jnp.int32(int(entries[goal_id]["scenario_checker"])),
    )
    official_step = jax.jit(
        lambda key, state, action: wrapper.InstructionWrapper.step(shim, key, state, action, params)
    )
    env = CrafTextEnv(
        EnvConfig(
            variant=Variant.CLASSIC,
            max_steps=len(case.actions) + 1,
            success_rule="official",
            step_keys=step_keys,
        )
    )
    [goal] = [g for g in load_dataset(root).split(split) if g.id == goal_id]
    task = encode_goals([goal], Variant.CLASSIC)
    ours = EpisodeState(
        game=game,
        task=make_task(task.required[0], task.forbidden[0], task.kind[0], task.params[0]),
        episode_key=world_key,
        steps=jnp.int32(0),
        termination=jnp.int32(Termination.RUNNING),
    )
    our_step, new_world = jax.jit(env.step), jax.jit(env.new_world)
    steps = []
    for t, action_id in enumerate(case.actions):
        key, action = case_step_key(world_key, t), jnp.int32(action_id)
        _, theirs, _, ended, _ = official_step(key, theirs, action)
        our_key = key if step_keys == "auto_reset" else jax.random.split(key)[0]
        ours, info = our_step(our_key, ours, action)
        game_over = bool(inner.is_terminal(ours.game, params))
        checked = new_world(our_key) if game_over else ours.game
        same = same_game(theirs.env_state, checked)
        steps.append(
            CaseStep(
                step=t + 1,
                game_over=game_over,
                games_equal=same,
                official_ended=bool(ended),
                official_met=bool(theirs.instruction_done),
                ours=Termination(int(info.termination)),
            )
        )
        if steps[-1].official_ended or steps[-1].ours is not Termination.RUNNING:
            break
    return steps


def add_repository_arguments(parser: argparse.ArgumentParser) -> None:
    """`--dataset` (the official repository) and `--out` (where it is unpacked otherwise)."""
    parser.add_argument("--dataset", type=Path, help="the official repository (default: unpacked)")
    parser.add_argument("--out", type=Path, default=Path("/tmp/official_wrapper"))


def repository_root(args: argparse.Namespace) -> Path:
    """The official repository `--dataset` names, else the reference archive unpacked."""
    from benchmarks.official_clone import official_clone

    root = args.dataset or official_clone(args.out)
    if root is None:
        refuse("no official repository (no reference archive beside the checkout): pass --dataset")
    if not (Path(root) / "craftext" / "environment" / "craftext_wrapper.py").is_file():
        refuse(f"{root} is not the official CrafText repository (no craftext/environment)")
    return Path(root)


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--difficulty", choices=sorted(DIFFICULTY_SPLITS), default="medium")
    parser.add_argument("--worlds", type=int, default=4)
    parser.add_argument("--steps", type=int, default=300)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--case", type=Path, help="replay this recorded episode instead")
    parser.add_argument(
        "--case-goal",
        default="medium_train/INSTRUCTION_PLACE_STONE_IRON_2_2",
        help="SPLIT/GOAL_ID the case is scored on",
    )
    add_repository_arguments(parser)
    args = parser.parse_args(argv)
    root = repository_root(args)
    official = official_modules(root)
    if args.case is not None:
        return print_case(official, root, read_case(args.case), args.case_goal)
    variant = Variant.FULL if args.difficulty == "hard" else Variant.CLASSIC
    harness = Harness(official, variant, args.steps)
    rng = np.random.default_rng(args.seed)
    keys = world_keys(args.seed, args.worlds)
    actions = [rng.integers(variant.num_actions, size=args.steps) for _ in keys]
    episodes = play(harness, keys, actions)
    tallies, differences = compare(
        harness,
        official,
        root,
        DIFFICULTY_SPLITS[args.difficulty],
        keys,
        actions,
        episodes=episodes,
    )
    ended = [e.game_over for e in episodes if e.game_over is not None]
    print(
        f"{args.difficulty}, {variant.value}, {args.worlds} worlds x {args.steps} steps, seed "
        f"{args.seed}: {len(ended)} worlds end in game over (at steps {sorted(ended)})"
    )
    print("  (world, text) pairs, agreeing, official successes (on the game-over step)")
    for name, t in sorted(tallies.items()):
        print(f"  {name}: {t.pairs}, {t.agree}, {t.successes} ({t.game_over_successes})")
    total = Tally(*(sum(getattr(t, f) for t in tallies.values()) for f in Tally.__annotations__))
    print(f"  all: {total.pairs}, {total.agree}, {total.successes} ({total.game_over_successes})")
    for line in differences:
        print("  differs:", line)
    return 1 if differences else 0


def print_case(official: Callable[[str], Any], root: Path, case: GameOverCase, goal: str) -> int:
    """Replay `case` scored on `goal` (SPLIT/GOAL_ID); print where both sides differ."""
    split, _, goal_id = goal.partition("/")
    if split not in SPLIT_MODULES or split.startswith("hard"):
        refuse(f"--case-goal {goal!r} is not SPLIT/GOAL_ID of a Medium split")
    steps = replay_case(official, root, case, split, goal_id)
    last = steps[-1]
    print(
        f"case {list(case.world_key)} on {goal}: {len(steps)} steps (recorded game over: "
        f"{case.game_over_step}); last step: game over {last.game_over}, official ended "
        f"{last.official_ended} met {last.official_met}, ours {last.ours.name.lower()}"
    )
    differing = [s for s in steps if not s.agrees]
    for step in differing:
        print("  differs:", step)
    print(f"  {len(steps) - len(differing)} of {len(steps)} steps agree")
    return 1 if differing else 0


if __name__ == "__main__":
    raise SystemExit(main())
