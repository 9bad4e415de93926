"""Re-simulating recorded episodes and drawing them with Craftax's own pixel renderer.

An episode is replayed from the key its world was reset with and the action ids it took; the
replay reports what it reached (achievements, termination, steps, return) so the caller can check
it against the record. Episodes are replayed in fixed-size batches, stepped in fixed-length
chunks: the two compiled functions (reset, chunk) never see a new shape, so a run of any length
compiles once per process (and once per machine with the persistent compilation cache). A chunk
skips the steps past its batch's longest episode (a 2-step episode is not stepped and drawn 32
times).
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from env.achievements import ACHIEVEMENTS
from env.craftext_env import CrafTextEnv, EpisodeState, make_task
from env.scenario_checker import checker_trace, overworld
from env.scenario_tasks import NUM_PARAMS
from env.termination import Termination
from env.texture_cache import pixel_renderer
from env.variant import Variant

#: Pixels per map block: craftax's image size (16) for Classic; for the full game what its pixel
#: agents see (10), which makes a full-game report 2.5x smaller.
BLOCK_SIZES = {Variant.FULL: 10, Variant.CLASSIC: 16}


Carry = tuple[EpisodeState, jax.Array]
"""What the replay carries from step to step: the batch's states and the map each episode's
checker last read."""


@dataclass(frozen=True)
class ReplayInput:
    """What a replay needs from one recorded episode."""

    reset_key: np.ndarray
    """Raw PRNG key (two uint32 words) the world was reset with."""
    required: np.ndarray
    """Boolean mask over the 22 achievement ids: the goal's required achievements."""
    forbidden: np.ndarray
    """Boolean mask over the 22 achievement ids: the goal's forbidden achievements."""
    actions: Sequence[int]
    """Action ids taken, one per step, in order."""
    kind: int = 0
    """The goal's kind index (`env.scenario_tasks.KIND_INDEX`); 0, achievements, by default."""
    params: tuple[int, ...] = (0,) * NUM_PARAMS
    """The goal's checker parameters (`env.scenario_tasks.encode_goal`); zeros for achievements."""


@dataclass(frozen=True)
class Replay:
    """What re-simulating one episode produced."""

    frames: np.ndarray
    """uint8 RGB frames of shape (steps + 1, height, width, 3): the world before the first
    action, then after each action (1 by 1 black pixels from a `Replayer` that does not
    render)."""
    achievements: list[str]
    """Achievement names first unlocked during the replay, in order (within a step, by id)."""
    termination: str
    """`success`, `death` or `timeout` when the replay ended on its last action, else `running`;
    the first ending counts when the replay ended early."""
    ended_at: int | None
    """How many actions had been taken when the replay ended; None when it never did."""
    episode_return: float
    """Sum of rewards up to the end (or over every action when it never ended)."""
    trace: np.ndarray
    """int32 (steps + 1, 4): `env.scenario_checker.checker_trace` of each state, as `frames`."""
    end_map: np.ndarray
    """The block map the checker read when the episode ended (after its last action when it
    never did): the map a line, square or placement was found in."""
    goal_at_game_over: str | None = None
    """`death` or `timeout` (how the game ended) when the goal was met on the step the game
    ended, as the play loop records it; None otherwise."""
    goal_in_new_world: str | None = None
    """`death` or `timeout` when, on the step the game ended, the goal was met in the new
    world Craftax's automatic reset starts (the official rule's success); None otherwise."""


class Replayer:
    """Replays episodes of one `CrafTextEnv` (its variant and step cap) and renders their frames.

    Create one per process and reuse it: its compiled functions are cached per instance. With
    `render=False` it draws nothing (checking a run's records needs no frames).
    """

    def __init__(
        self, env: CrafTextEnv, *, batch_size: int = 8, chunk: int = 32, render: bool = True
    ):
        self.env = env
        self.batch_size = batch_size
        self.chunk = chunk
        if render:
            pixels = _pixel_renderer(env)

            def draw(game: Any) -> jax.Array:
                return jnp.clip(jnp.round(pixels(game)), 0, 255).astype(jnp.uint8)

        else:
            # Checking a run needs no pixels: drawing is most of a replay's cost.
            def draw(game: Any) -> jax.Array:
                return jnp.zeros((1, 1, 3), jnp.uint8)

        variant = env.variant

        def trace(state: EpisodeState) -> jax.Array:
            return jax.vmap(
                lambda game, task: checker_trace(game, task.kind, task.params, variant)
            )(state.game, state.task)

        def reset(keys: jax.Array, task: Any) -> tuple[Carry, jax.Array, jax.Array]:
            # One world at a time, as `env.jitted_reset` makes it: vectorized over a batch,
            # Craftax's world generation rounds differently in some lanes (seen from lane 8 of
            # 12 or more on an AVX-512 CPU), and the world would depend on where it was made.
            state = jax.lax.map(lambda inputs: env.reset(*inputs), (keys, task))
            end_map = jax.vmap(lambda game: overworld(game, variant))(state.game)
            return (state, end_map), jax.vmap(draw)(state.game), trace(state)

        def step(carry: Carry, action: jax.Array, acting: jax.Array) -> tuple[Carry, Any]:
            state, end_map = carry
            # The map the checker read last stays once the episode ended or took its last
            # action (the game goes on stepping after either, for rows that are still acting).
            frozen = state.done | ~acting
            state, info = env.step_batch(state, action)
            now = jax.vmap(lambda game: overworld(game, variant))(state.game)
            end_map = jnp.where(frozen[:, None, None], end_map, now)
            return (state, end_map), (
                jax.vmap(draw)(state.game),
                info.reward,
                info.done,
                info.termination,
                info.new_achievements,
                trace(state),
                info.goal_at_game_over,
                info.goal_in_new_world,
                state.game.player_health <= 0,
            )

        def advance(carry: Carry, actions: jax.Array, lengths: jax.Array) -> tuple[Carry, Any]:
            """Each row's first `lengths` steps of the chunk; outputs past a row's length are
            never read, and the steps past every row's, drawing included, are skipped (a
            chunk keeps one shape, so a shorter one never recompiles)."""
            skipped = jax.tree.map(
                lambda out: jnp.zeros(out.shape, out.dtype),
                jax.eval_shape(step, carry, actions[:, 0], lengths > 0)[1],
            )
            taken = jnp.max(lengths)

            def one_step(carry: Carry, inputs: tuple[jax.Array, jax.Array]) -> tuple[Carry, Any]:
                action, index = inputs
                return jax.lax.cond(
                    index < taken,
                    lambda: step(carry, action, index < lengths),
                    lambda: (carry, skipped),
                )

            # Scan over time with the batch inside: outputs come back time-major.
            return jax.lax.scan(
                one_step, carry, (actions.T, jnp.arange(actions.shape[1], dtype=jnp.int32))
            )

        self._reset = jax.jit(reset)
        self._advance = jax.jit(advance)

    def replay(self, episodes: Sequence[ReplayInput], *, workers: int = 2) -> Iterator[Replay]:
        """Replays of `episodes`, in order, computed a batch at a time (memory stays bounded).

        `workers` batches are computed at once, each from its own thread: XLA runs them in
        parallel (one batch keeps about one core busy), and the caller handles finished
        replays meanwhile.
        """
        batches = [
            list(episodes[start : start + self.batch_size])
            for start in range(0, len(episodes), self.batch_size)
        ]
        with ThreadPoolExecutor(max(1, workers), thread_name_prefix="replay") as pool:
            pending: deque[Future[list[Replay]]] = deque()
            for index, batch in enumerate(batches):
                if index == 0:
                    # The first batch is launched from this thread, so the two functions are
                    # compiled (or loaded from the persistent cache) once, before any worker
                    # calls them: a test process once died (SIGSEGV in XLA's executable
                    # deserialization) while two replay threads loaded the same executable.
                    pending.append(pool.submit(self._collect, batch, self._launch(batch)))
                else:
                    pending.append(pool.submit(self._compute, batch))
                if len(pending) > max(1, workers):
                    yield from pending.popleft().result()
            while pending:
                yield from pending.popleft().result()

    def _compute(self, batch: list[ReplayInput]) -> list[Replay]:
        return self._collect(batch, self._launch(batch))

    def _launch(self, batch: list[ReplayInput]) -> tuple[Any, list[Any]]:
        """Start the batch's computation; returns its (not yet computed) outputs."""
        # Padding slots repeat the last episode; their output is dropped.
        padded = batch + [batch[-1]] * (self.batch_size - len(batch))
        keys = jnp.asarray(np.stack([np.asarray(e.reset_key, np.uint32) for e in padded]))
        task = make_task(
            np.stack([e.required for e in padded]),
            np.stack([e.forbidden for e in padded]),
            np.array([e.kind for e in padded], np.int32),
            np.array([e.params for e in padded], np.int32),
        )
        lengths = np.array([len(e.actions) for e in padded], np.int32)
        longest = int(lengths.max())
        actions = np.zeros(
            (self.batch_size, max(1, -(-longest // self.chunk)) * self.chunk), np.int32
        )
        for row, episode in enumerate(padded):
            actions[row, : len(episode.actions)] = episode.actions
        carry, first, first_trace = self._reset(keys, task)
        chunks = []
        # At least one chunk, so even a batch of empty episodes has step outputs to slice.
        for offset in range(0, max(longest, 1), self.chunk):
            carry, outputs = self._advance(
                carry,
                jnp.asarray(actions[:, offset : offset + self.chunk]),
                jnp.asarray(np.clip(lengths - offset, 0, self.chunk)),
            )
            chunks.append(outputs)
        return (first, first_trace, carry[1]), chunks

    def _collect(self, batch: list[ReplayInput], launched: tuple[Any, list[Any]]) -> list[Replay]:
        (first, first_trace, end_maps), chunks = jax.device_get(launched)
        # Chunk outputs are time-major: (chunk, batch, ...). Frames, the bulk, are copied once,
        # straight from the chunks into each episode's array.
        reward, done, termination, unlocked, traces, at_game_over, in_new_world, dead = (
            np.concatenate([chunk[field] for chunk in chunks]) for field in range(1, 9)
        )
        replays = []
        for row, episode in enumerate(batch):
            length = len(episode.actions)
            frames = np.empty((length + 1, *first.shape[1:]), np.uint8)
            frames[0] = first[row]
            for number, chunk in enumerate(chunks):
                start = number * self.chunk
                if start >= length:
                    break
                frames[1 + start : 1 + min(length, start + self.chunk)] = chunk[0][
                    : length - start, row
                ]
            replays.append(
                _summarize(
                    frames,
                    reward[:length, row],
                    done[:length, row],
                    termination[:length, row],
                    unlocked[:length, row],
                    np.concatenate([first_trace[row : row + 1], traces[:length, row]]),
                    np.asarray(end_maps[row]),
                    (at_game_over[:length, row], in_new_world[:length, row], dead[:length, row]),
                )
            )
        return replays


def _summarize(
    frames: np.ndarray,
    rewards: np.ndarray,
    dones: np.ndarray,
    terminations: np.ndarray,
    unlocked: np.ndarray,
    trace: np.ndarray,
    end_map: np.ndarray,
    game_over: tuple[np.ndarray, np.ndarray, np.ndarray],
) -> Replay:
    ended = np.flatnonzero(dones)
    last = int(ended[0]) + 1 if ended.size else len(dones)
    achievements = [ACHIEVEMENTS[i] for step in unlocked[:last] for i in np.flatnonzero(step)]
    termination = Termination(int(terminations[last - 1])).label if ended.size else "running"
    at_game_over, in_new_world, dead = game_over
    # Set only on the step that ends the game, named as the play loop names it.
    ending = "death" if ended.size and dead[last - 1] else "timeout"
    return Replay(
        frames=frames,
        achievements=achievements,
        termination=termination,
        ended_at=last if ended.size else None,
        episode_return=float(rewards[:last].sum()),
        trace=trace,
        end_map=end_map,
        goal_at_game_over=ending if ended.size and at_game_over[last - 1] else None,
        goal_in_new_world=ending if ended.size and in_new_world[last - 1] else None,
    )


def _pixel_renderer(env: CrafTextEnv) -> Callable[[Any], jax.Array]:
    # Night drawn as an even darkening instead of random static in the full game: the same
    # scene, but a 64-episode report of 250-step episodes is 2.5x smaller (night frames
    # compress). Classic's renderer has no such option: its nights keep their static.
    return pixel_renderer(
        env.variant, BLOCK_SIZES[env.variant], night_noise=env.variant is not Variant.FULL
    )
