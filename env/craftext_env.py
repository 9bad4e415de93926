"""The CrafText environment: Craftax plus every scenario's success checker.

`CrafTextEnv` is functional and JAX-pure (`reset`, `step`), so it can be jitted and vmapped like a
gymnax env. `VectorEnv` drives a fixed-size batch of episodes from the host: one compiled step
for all slots (or only the slots a mask names, the others left exactly as they were), finished
slots refilled in place, and everything the caller needs pulled to numpy once per step.

Determinism: an episode's randomness comes only from its episode key (see `episode_key`); step t
uses `fold_in(episode_key, t)`, so a trajectory does not depend on the batch size or on which slot
the episode runs in. A step spends its key as Craftax's auto-reset env does (`EnvConfig.step_keys`):
the game steps with the first half of its split, the world a game over starts comes from the second.

The step the game ends on is also checked in the world Craftax's auto-reset env would start next
(the official wrapper's verdict there, see `env.checker.scored_success`): that world is generated
only on such a step, and only for goals other than achievements.
"""

from __future__ import annotations

import hashlib
import weakref
from collections.abc import Sequence
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct
from pydantic import BaseModel, ConfigDict, Field

from env.achievements import NUM_ACHIEVEMENTS
from env.checker import goal_reached, scored_success
from env.device import EnvDevice, place_env
from env.jax_cache import enable_compilation_cache
from env.rules import DEFAULT_STEP_KEYS, DEFAULT_SUCCESS_RULE, STEP_CAP, StepKeys, SuccessRule
from env.scenario_checker import goal_met
from env.scenario_tasks import KIND_INDEX, NUM_PARAMS
from env.termination import Termination
from env.variant import DEFAULT_VARIANT, Variant

#: Each success is worth this much more than Craftax's own per-step reward, which is divided by it.
CRAFTAX_REWARD_SCALE = 50.0


class EnvConfig(BaseModel):
    """Settings of the CrafText environment."""

    model_config = ConfigDict(extra="forbid")

    variant: Variant = DEFAULT_VARIANT
    """Craftax variant: `full` (Craftax-Symbolic-v1, 43 actions) or `classic` (17 actions)."""
    max_steps: int = Field(STEP_CAP, ge=1)
    """Step cap per episode (`env.rules.STEP_CAP`, the official LLM baseline's)."""
    success_rule: SuccessRule = DEFAULT_SUCCESS_RULE
    """Whether a goal completed on the step the game ends counts (`game_over_counts`) or not
    (`official`); see `env.rules.SuccessRule`."""
    world_key: int | None = None
    """When set, every episode's world is generated from `jax.random.PRNGKey(world_key)` (the
    official loop uses 1) instead of its episode key; steps still draw from the episode key."""
    step_keys: StepKeys = DEFAULT_STEP_KEYS
    """How a step spends its key (`env.rules.StepKeys`): `auto_reset` as Craftax's auto-reset
    env, so that the game and the world a game over starts are the official wrapper's; `whole`
    as runs recorded before this setting played."""
    device: EnvDevice = "cpu"
    """Where JAX steps the worlds: `cpu` (the default: the accelerator stays the model's) or
    `default` (JAX's default device); see `env.device`."""


@struct.dataclass
class Task:
    """The goal of one episode in the checker's fixed shape (`env.scenario_tasks`): its kind,
    achievement masks over the 22 shared ids (achievements goals) and int32 parameters (the
    other kinds), so a batch can mix kinds."""

    required: jax.Array
    forbidden: jax.Array
    kind: jax.Array
    params: jax.Array


@struct.dataclass
class EpisodeState:
    """Craftax state plus CrafText bookkeeping for one episode (or a batch, with a leading axis)."""

    game: Any
    task: Task
    episode_key: jax.Array
    steps: jax.Array
    termination: jax.Array

    @property
    def done(self) -> jax.Array:
        return self.termination != Termination.RUNNING


@struct.dataclass
class StepInfo:
    """What one step produced."""

    reward: jax.Array
    done: jax.Array
    termination: jax.Array
    craftax_reward: jax.Array
    new_achievements: jax.Array
    goal_at_game_over: jax.Array
    """True when the goal was completed on the step the game ended, whichever rule scored it."""
    goal_in_new_world: jax.Array
    """True when, on the step the game ended, the goal was met in the auto-reset world (what the
    official wrapper checks there, and `official` scores), whichever rule scored it."""


def make_task(required: Any, forbidden: Any, kind: Any = 0, params: Any = None) -> Task:
    """A task from boolean masks of length 22 (numpy or JAX), one episode's or a batch's (a
    leading axis); without `kind` and `params`, achievements goals. A scalar `kind` or a single
    `params` row is repeated over the batch, so callers never build a task of mixed shapes."""
    required = jnp.asarray(required, dtype=jnp.bool_)
    batch = required.shape[:-1]
    return Task(
        required=required,
        forbidden=jnp.asarray(forbidden, dtype=jnp.bool_),
        kind=jnp.broadcast_to(jnp.asarray(kind, dtype=jnp.int32), batch),
        params=jnp.broadcast_to(
            jnp.zeros(NUM_PARAMS, jnp.int32)
            if params is None
            else jnp.asarray(params, dtype=jnp.int32),
            (*batch, NUM_PARAMS),
        ),
    )


class CrafTextEnv:
    """Craftax with a CrafText instruction's success checker. Create one per process and reuse it:
    jit caches compiled functions per env instance."""

    def __init__(self, config: EnvConfig | None = None, *, compilation_cache: bool = True):
        self.config = config or EnvConfig()
        place_env(self.config.device)
        if compilation_cache:
            enable_compilation_cache()
        from craftax.craftax_env import make_craftax_env_from_name

        self.craftax = make_craftax_env_from_name(
            self.config.variant.craftax_name, auto_reset=False
        )
        self.params = self.craftax.default_params
        # Compiled once per env and shared by every VectorEnv over it: a fresh jax.jit wrapper
        # would trace and lower the whole game again (seconds) even with a warm compile cache.
        self.batched_step = jax.jit(self.masked_batch_step)
        # Donated like place_episode: only the stepped slots' rows are written back.
        self.slots_step = jax.jit(self.step_slots, donate_argnums=0)
        self.jitted_reset = jax.jit(self.reset)
        # Donates the batch state (VectorEnv never reads it again), so XLA writes the new world
        # in place instead of copying every slot's (5x faster on CPU). The masked step is not
        # donated: measured, it then ran slower (10.6 ms vs 6.0 ms for 32 full-Craftax slots).
        self.place_episode = jax.jit(_place_episode, donate_argnums=0)

    @property
    def variant(self) -> Variant:
        return self.config.variant

    @property
    def num_actions(self) -> int:
        return self.variant.num_actions

    def reset(self, key: jax.Array, task: Task) -> EpisodeState:
        """A fresh world for `task`; `key` is the episode key."""
        # The craftax symbolic observation is computed by reset_env/step_env but never returned
        # from our jitted functions, so XLA drops it: we textualize from the state instead.
        world_key = (
            jax.random.fold_in(key, 0x7E5E7)
            if self.config.world_key is None
            else jax.random.PRNGKey(self.config.world_key)
        )
        _, game = self.craftax.reset_env(world_key, self.params)
        # Craftax's reset leaves some leaves weakly typed while step returns them strongly typed;
        # matching types keeps the first step from compiling twice.
        game = jax.tree.map(lambda leaf: jnp.asarray(leaf).astype(jnp.asarray(leaf).dtype), game)
        return EpisodeState(
            game=game,
            task=task,
            episode_key=key,
            steps=jnp.int32(0),
            termination=jnp.int32(Termination.RUNNING),
        )

    def step(
        self, key: jax.Array, state: EpisodeState, action: jax.Array
    ) -> tuple[EpisodeState, StepInfo]:
        """One step of one episode with `key`. A finished episode keeps its step count and
        termination and earns nothing."""
        keys, states, actions = jax.tree.map(
            lambda leaf: jnp.expand_dims(leaf, 0), (key, state, action)
        )
        stepped = self._step_rows(keys, states, actions, jnp.ones(1, jnp.bool_))
        result: tuple[EpisodeState, StepInfo] = jax.tree.map(lambda leaf: leaf[0], stepped)
        return result

    def step_from_episode_key(
        self, state: EpisodeState, action: jax.Array
    ) -> tuple[EpisodeState, StepInfo]:
        """`step` with the key derived from the episode key and step index (deterministic replay)."""
        return self.step(jax.random.fold_in(state.episode_key, state.steps), state, action)

    def step_batch(self, state: EpisodeState, actions: jax.Array) -> tuple[EpisodeState, StepInfo]:
        """Step every episode of a batch (a leading axis), each with the key of its episode and
        step index: what vmapping `step_from_episode_key` would give, at the cost of one
        episode's step per row (a vmapped step would generate a new world in every row)."""
        return self._step_rows(_step_keys(state), state, actions, jnp.ones_like(state.done))

    def masked_batch_step(
        self, state: EpisodeState, actions: jax.Array, active: jax.Array
    ) -> tuple[EpisodeState, StepInfo]:
        """Step the slots where `active` is true; the others keep their state bit for bit.

        Frozen slots also keep their step index, so their next step draws the same key it would
        have drawn now: a trajectory does not depend on when its slot was stepped.
        """
        return self._step_rows(_step_keys(state), state, actions, active)

    def step_slots(
        self, state: EpisodeState, slots: jax.Array, actions: jax.Array, valid: jax.Array
    ) -> tuple[EpisodeState, StepInfo]:
        """Step only the listed slots of a batch (rows where `valid` is false are written back
        unchanged); the info has one row per listed slot.

        The cost follows the number of slots listed, not the batch size. `slots` must not repeat
        a slot: scattered rows would race.
        """
        current = jax.tree.map(lambda leaf: leaf[slots], state)
        stepped, info = self._step_rows(_step_keys(current), current, actions, valid)
        next_state: EpisodeState = jax.tree.map(
            lambda batch, rows: batch.at[slots].set(rows), state, stepped
        )
        return next_state, info

    def new_world(self, key: jax.Array) -> Any:
        """The Craftax state the auto-reset env starts when a step with `key` ends the game:
        craftax's `EnvironmentAutoReset.step` splits its key into (step, reset) and resets from
        the second."""
        _, world = self.craftax.reset_env(jax.random.split(key)[1], self.params)
        return world

    def game_key(self, key: jax.Array) -> jax.Array:
        """The key the game steps with on a step with `key`: the first half of its split, as
        craftax's `EnvironmentAutoReset.step` steps (under `step_keys="whole"`, `key` itself)."""
        return jax.random.split(key)[0] if self.config.step_keys == "auto_reset" else key

    def _step_rows(
        self, keys: jax.Array, state: EpisodeState, actions: jax.Array, active: jax.Array
    ) -> tuple[EpisodeState, StepInfo]:
        """Step the rows of a batch where `active` is true, with their `keys`; the others keep
        their state bit for bit and their info says nothing happened."""
        game, craftax_reward, ended, reached = jax.vmap(self._advance)(keys, state, actions)
        was_done = state.done
        # Rows that end their game now: a finished episode's game keeps stepping (see below),
        # and a dead player would end it again at every step.
        ending = active & ~was_done & ended
        in_new_world = self._met_in_new_world(keys, state, ending)
        steps = state.steps + 1
        success = scored_success(reached, in_new_world, ended, self.config.success_rule)
        # The step cap is ours, not a game end: a goal reached on the last capped step counts.
        termination = jnp.select(
            [success, game.player_health <= 0, ended | (steps >= self.config.max_steps)],
            [Termination.SUCCESS, Termination.DEATH, Termination.TIMEOUT],
            Termination.RUNNING,
        ).astype(jnp.int32)
        # A finished episode is masked, not frozen: its game keeps stepping (nobody reads it
        # until the slot is refilled), which spares copying the whole Craftax state every step.
        stepped = EpisodeState(
            game=game,
            task=state.task,
            episode_key=state.episode_key,
            steps=jnp.where(was_done, state.steps, steps),
            termination=jnp.where(was_done, state.termination, termination),
        )

        def keep_inactive(new: jax.Array, old: jax.Array) -> jax.Array:
            return jnp.where(active.reshape(active.shape + (1,) * (new.ndim - 1)), new, old)

        next_state: EpisodeState = jax.tree.map(keep_inactive, stepped, state)
        earning = active & ~was_done
        craftax_reward = jnp.where(earning, craftax_reward, 0.0).astype(jnp.float32)
        reward = jnp.where(earning, success.astype(jnp.float32), 0.0) + (
            craftax_reward / CRAFTAX_REWARD_SCALE
        )
        previous = state.game.achievements[:, :NUM_ACHIEVEMENTS]
        unlocked = game.achievements[:, :NUM_ACHIEVEMENTS]
        return next_state, StepInfo(
            reward=reward,
            done=next_state.done,
            termination=next_state.termination,
            craftax_reward=craftax_reward,
            new_achievements=earning[:, None] & unlocked & ~previous,
            goal_at_game_over=ending & reached,
            goal_in_new_world=ending & in_new_world,
        )

    def _advance(
        self, key: jax.Array, state: EpisodeState, action: jax.Array
    ) -> tuple[Any, jax.Array, jax.Array, jax.Array]:
        """One episode's Craftax step and its goal's verdict on the state after it: (game,
        Craftax's reward, whether the game ended, whether the goal is met)."""
        _, game, craftax_reward, game_over, _ = self.craftax.step_env(
            self.game_key(key), state.game, action, self.params
        )
        task = state.task
        reached = goal_met(
            state.game,
            game,
            task.kind,
            task.required,
            task.forbidden,
            task.params,
            self.variant,
        )
        return game, craftax_reward, game_over | (game.player_health <= 0), reached

    def _met_in_new_world(
        self, keys: jax.Array, state: EpisodeState, ending: jax.Array
    ) -> jax.Array:
        """Per row where `ending`: whether the goal is met checking, as the official wrapper
        does, the step from the state before it to the new world (`new_world`); False elsewhere."""
        task = state.task
        achievements = task.kind == KIND_INDEX["achievements"]
        # A new world has nothing unlocked, so achievements goals need none generated.
        met_unlocking_none = goal_reached(
            jnp.zeros_like(task.required), task.required, task.forbidden
        )
        generate = ending & ~achievements

        def one_row(row: tuple[jax.Array, Any, Task, jax.Array]) -> jax.Array:
            key, previous, row_task, wanted = row

            def check() -> jax.Array:
                return goal_met(
                    previous,
                    self.new_world(key),
                    row_task.kind,
                    row_task.required,
                    row_task.forbidden,
                    row_task.params,
                    self.variant,
                )

            return jax.lax.cond(wanted, check, lambda: jnp.bool_(False))

        # Row by row (`lax.map`), each behind its own `cond`: vmapped, a cond runs both branches
        # in every row, and Craftax's world generation, vectorised, makes other worlds in some
        # lanes (see `VectorEnv.reset`). The outer cond skips the loop on the usual step.
        in_world = jax.lax.cond(
            jnp.any(generate),
            lambda: jax.lax.map(one_row, (keys, state.game, task, generate)),
            lambda: jnp.zeros_like(generate),
        )
        return ending & jnp.where(achievements, met_unlocking_none, in_world)


_SHARED: weakref.WeakValueDictionary[str, CrafTextEnv] = weakref.WeakValueDictionary()


def shared_env(config: EnvConfig) -> CrafTextEnv:
    """The process's `CrafTextEnv` for `config`: the one made earlier while anything still
    holds it (a run in progress, a caller's reference), else a new one.

    Each new env traces and lowers the game again on its first step (seconds, even when the
    persistent cache then skips compiling), so runs, replays and do-nothing checks of the same
    settings share one. Held weakly: an env nobody holds frees its compiled functions.
    """
    key = config.model_dump_json()
    env = _SHARED.get(key)
    if env is None:
        env = CrafTextEnv(config)
        _SHARED[key] = env
    return env


def _step_keys(state: EpisodeState) -> jax.Array:
    """Each row's step key: its episode key folded with its step index."""
    return jax.vmap(jax.random.fold_in)(state.episode_key, state.steps)


def episode_key(
    seed: int, goal_id: str, instruction_index: int, episode_index: int, stream: str = ""
) -> np.ndarray:
    """The raw PRNG key (two uint32 words) of one episode.

    Derived by hashing, so the world of (seed, goal, instruction variant, episode) is the same in
    every run, whatever else the run contains or in which order it schedules episodes. A
    non-empty `stream` names another family of worlds (`plan-score`'s selection and held-out
    worlds): its hashed text can never equal an unnamed (eval's) one, so the families share no
    key short of a 64-bit hash collision.
    """
    text = f"{seed}\x1f{goal_id}\x1f{instruction_index}\x1f{episode_index}"
    if stream:
        text = f"{stream}\x1e{text}"
    digest = hashlib.blake2b(text.encode(), digest_size=8).digest()
    return np.frombuffer(digest, dtype=np.uint32).copy()


class HostBatch(struct.PyTreeNode):
    """Everything the host needs after a reset or step, as numpy arrays with a leading slot axis."""

    game: Any
    reward: np.ndarray
    done: np.ndarray
    termination: np.ndarray
    steps: np.ndarray
    achievements: np.ndarray
    new_achievements: np.ndarray
    goal_at_game_over: np.ndarray
    goal_in_new_world: np.ndarray


#: Slots stepped per call when only a few of a large batch are ready (see `VectorEnv.step`).
SLOT_GROUP = 8


class VectorEnv:
    """A fixed batch of episodes stepped with one compiled function, all of them or a masked
    subset.

    Shapes never change (finished slots are masked until refilled), so nothing recompiles
    after the first step.
    """

    def __init__(self, env: CrafTextEnv, batch_size: int):
        if batch_size < 1:
            raise ValueError("batch_size must be at least 1")
        self.env = env
        self.batch_size = batch_size
        self._reset_one = env.jitted_reset
        self._step = env.batched_step
        self._step_slots = env.slots_step
        # Continuous scheduling steps a few ready slots at a time: stepping all of a large batch
        # for them costs the whole batch (full Craftax, 32 slots, CPU: 10.4 ms), a group of 8
        # listed slots 2.8 ms. Small batches, or most slots ready, take the one masked step.
        self._group = min(batch_size, SLOT_GROUP)
        self._place = env.place_episode
        self._state: EpisodeState | None = None

    @property
    def variant(self) -> Variant:
        return self.env.variant

    def reset(
        self,
        keys: np.ndarray,
        required: np.ndarray,
        forbidden: np.ndarray,
        kind: np.ndarray | None = None,
        params: np.ndarray | None = None,
    ) -> HostBatch:
        """Start a new episode in every slot. Without `kind` and `params` (rows of
        `env.scenario_tasks.EncodedTasks`) every goal is an achievements goal."""
        # One world at a time, with the function refills use: XLA's vectorised world generation
        # gives slots past the eighth other worlds than generating them alone (measured on CPU),
        # so a batched reset would make an episode's world depend on the batch size.
        worlds = [
            jax.device_get(self._reset_one(key, task))
            for key, task in _episode_tasks(
                self.batch_size, keys, required, forbidden, kind, params
            )
        ]
        self._state = jax.tree.map(lambda *leaves: jnp.asarray(np.stack(leaves)), *worlds)
        return self._fresh_host()

    def refill(
        self,
        slots: Sequence[int],
        keys: np.ndarray,
        required: np.ndarray,
        forbidden: np.ndarray,
        kind: np.ndarray | None = None,
        params: np.ndarray | None = None,
    ) -> HostBatch:
        """Start new episodes in the given slots; the other slots are untouched.

        `keys`, `required`, `forbidden` (and `kind`, `params`, as in `reset`) hold one row per
        refilled slot, in the order of `slots`.
        """
        state = self._require_state()
        tasks = _episode_tasks(len(slots), keys, required, forbidden, kind, params)
        for slot, (key, task) in zip(slots, tasks, strict=True):
            state = self._place(state, self._reset_one(key, task), jnp.int32(slot))
        self._state = state
        return self._fresh_host()

    def step(self, actions: np.ndarray, active: np.ndarray | None = None) -> HostBatch:
        """Step every slot, or only those where `active` is true (the others stay exactly as
        they were, earning nothing); finished slots earn nothing and keep their termination."""
        state = self._require_state()
        actions = np.asarray(actions, dtype=np.int32).reshape(self.batch_size)
        if active is None:
            active = np.ones(self.batch_size, dtype=bool)
        active = np.asarray(active, dtype=bool).reshape(self.batch_size)
        ready = np.flatnonzero(active)
        if self._group == self.batch_size or 2 * len(ready) > self.batch_size:
            self._state, info = self._step(state, jnp.asarray(actions), jnp.asarray(active))
            return self._to_host(self._state, _row_outputs(info))
        idle = np.flatnonzero(~active)
        groups, infos = [], []
        for start in range(0, len(ready), self._group):
            group = ready[start : start + self._group]
            # Padding rows name distinct idle slots, which are written back as they were.
            slots = np.concatenate([group, idle[: self._group - len(group)]]).astype(np.int32)
            valid = np.arange(self._group) < len(group)
            state, info = self._step_slots(
                state, jnp.asarray(slots), jnp.asarray(actions[slots]), jnp.asarray(valid)
            )
            groups.append(group)
            infos.append(_row_outputs(info))
        self._state = state
        outputs = _no_outputs(self.batch_size)
        # One transfer for the round's groups, with the state's: each sync stalls the host.
        game, termination, steps, fetched = jax.device_get(
            (state.game, state.termination, state.steps, infos)
        )
        for group, rows in zip(groups, fetched, strict=True):
            for output, row_values in zip(outputs, rows, strict=True):
                output[group] = row_values[: len(group)]
        return _host_batch(game, termination, steps, outputs)

    def frames(self, slots: Sequence[int]) -> np.ndarray:
        """uint8 frames (`env.frames`: what the variant's Pixels env shows) of the listed
        slots' current worlds, in their order."""
        from env.frames import frame_renderer

        state = self._require_state()
        renderer = frame_renderer(self.variant)
        rows = np.asarray(slots, np.int32)
        drawn = []
        # Groups of a fixed size (the last padded with its own first slot), so the renderer
        # compiles once whatever the number of ready slots.
        for start in range(0, len(rows), self._group):
            group = rows[start : start + self._group]
            padded = jnp.asarray(
                np.concatenate([group, np.full(self._group - len(group), group[0])])
            )
            games = jax.tree.map(lambda leaf, rows=padded: leaf[rows], state.game)
            drawn.append(renderer.render(games)[: len(group)])
        return np.concatenate(drawn)

    def step_terminations(self, actions: np.ndarray, active: np.ndarray) -> np.ndarray:
        """`step` every slot where `active` is true, pulling only each slot's termination code
        to the host, not its world: for players that never look (the do-nothing agent)."""
        state = self._require_state()
        self._state, _ = self._step(
            state,
            jnp.asarray(np.asarray(actions, np.int32).reshape(self.batch_size)),
            jnp.asarray(np.asarray(active, bool).reshape(self.batch_size)),
        )
        return np.asarray(jax.device_get(self._state.termination))

    def _fresh_host(self) -> HostBatch:
        # numpy zeros: an eager jnp.zeros would be one more compile on an accelerator.
        return self._to_host(self._require_state(), _no_outputs(self.batch_size))

    def _require_state(self) -> EpisodeState:
        if self._state is None:
            raise RuntimeError("call reset() before step() or refill()")
        return self._state

    @staticmethod
    def _to_host(state: EpisodeState, outputs: tuple[Any, ...]) -> HostBatch:
        game, termination, steps, fetched = jax.device_get(
            (state.game, state.termination, state.steps, outputs)
        )
        return _host_batch(game, termination, steps, fetched)


def _row_outputs(info: StepInfo) -> tuple[jax.Array, ...]:
    """What the host reads of a step's info, one row per stepped slot (`_host_batch`'s order)."""
    return (info.reward, info.new_achievements, info.goal_at_game_over, info.goal_in_new_world)


def _no_outputs(rows: int) -> tuple[np.ndarray, ...]:
    """`_row_outputs` of rows that did nothing."""
    return (
        np.zeros(rows, np.float32),
        np.zeros((rows, NUM_ACHIEVEMENTS), bool),
        np.zeros(rows, bool),
        np.zeros(rows, bool),
    )


def _episode_tasks(
    rows: int,
    keys: np.ndarray,
    required: np.ndarray,
    forbidden: np.ndarray,
    kind: np.ndarray | None,
    params: np.ndarray | None,
) -> list[tuple[jax.Array, Task]]:
    """Each row's reset key and task, from host rows (achievements goals where `kind` and
    `params` are not given)."""
    keys = np.asarray(keys, dtype=np.uint32).reshape(rows, 2)
    required = np.asarray(required, dtype=bool).reshape(rows, NUM_ACHIEVEMENTS)
    forbidden = np.asarray(forbidden, dtype=bool).reshape(rows, NUM_ACHIEVEMENTS)
    kind = np.zeros(rows, np.int32) if kind is None else np.asarray(kind, np.int32).reshape(rows)
    params = (
        np.zeros((rows, NUM_PARAMS), np.int32)
        if params is None
        else np.asarray(params, np.int32).reshape(rows, NUM_PARAMS)
    )
    # numpy leaves, as `make_task` would make them: its eager jnp calls cost ~0.5 ms a row on
    # CPU, and the jitted functions these go to take numpy as they take JAX arrays.
    return [
        (
            keys[row],
            Task(
                required=required[row],
                forbidden=forbidden[row],
                kind=kind[row],
                params=params[row],
            ),
        )
        for row in range(rows)
    ]


def _host_batch(
    game: Any, termination: np.ndarray, steps: np.ndarray, outputs: tuple[np.ndarray, ...]
) -> HostBatch:
    reward, new, goal_at_game_over, goal_in_new_world = outputs
    return HostBatch(
        game=game,
        reward=reward,
        done=termination != Termination.RUNNING,
        termination=termination,
        steps=steps,
        achievements=np.asarray(game.achievements)[:, :NUM_ACHIEVEMENTS],
        new_achievements=new,
        goal_at_game_over=goal_at_game_over,
        goal_in_new_world=goal_in_new_world,
    )


def _place_episode(state: EpisodeState, episode: EpisodeState, slot: jax.Array) -> EpisodeState:
    result: EpisodeState = jax.tree.map(lambda batch, one: batch.at[slot].set(one), state, episode)
    return result
