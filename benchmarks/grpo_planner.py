"""Tune a planner online against the game's verdict on its plans: GRPO (TRL's GRPOTrainer) with a
LoRA adapter (peft), every sampled plan rewarded by playing it; and the CPU baseline,
rejection-sampling rounds (sample plans, keep the ones that worked, SFT on them).

    python -m benchmarks.grpo_planner grpo --out TUNED [--model hf:qwen2.5-coder-0.5b]
        [--dataset D] [--splits easy_train] [--main-only] [--limit N] [--variant classic]
        [--max-steps N] [--max-minutes M] [--generations 4] [--prompts-per-step 2]
        [--worlds 2] [--selection-seed 0] [--learning-rate 5e-5] [--lora-rank 16]
        [--temperature 1.0] [--max-tokens 64] [--beta 0.0]
    python -m benchmarks.grpo_planner rs --out TUNED [--rounds 2] [--samples 8]
        [--threshold 0.5] [--sft-steps 8] [...the same...]

The reward of a plan is plan-score's verdict (`planning.scoring.PlanJudge`, its batched execution)
in `--worlds` of plan-score's selection worlds (`--selection-seed`, default plan-score's 0; their
keys are never eval's or the held-out worlds'): the share of worlds where the instruction's goal
was met, plus a shaped part that teaches where no sample succeeds: the share of the goal's required
achievements unlocked and the share of the plan's read skills that played. Success comes first: a
success in a world is worth 1 plus both shaped parts whole, so any success outweighs any failure. A
plan with a step that would earn a forbidden achievement, played or not, earns 0. The prompt is the
planner's request rendered from `benchmarks/short_planner/` (a few lines, not the full planner's
name lists), so a CPU step costs a short prompt; `plan --templates-dir benchmarks/short_planner`
asks the tuned model the same way.

The tuned folder is the merged model, loadable by `plan --model hf:FOLDER`, with a `tuning.json`
sidecar (settings, the reward of every step or round, seconds) and `reward_curve.png`.
trl, peft, datasets and torch are imported here only: `pip install -e '.[tune]'`.
"""

from __future__ import annotations

import argparse
import random
import shutil
import sys
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path
from statistics import fmean, pstdev
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError

from benchmarks.tune_planner import DEFAULT_MODEL, check_installed, model_folder, one_line_error
from env.dataset import load_dataset
from env.errors import UserError
from env.goals import AnyGoal
from env.variant import DEFAULT_VARIANT, Variant
from llm_agents.planning.checks import PlanLimits
from llm_agents.planning.execution import SKILL_STEPS
from llm_agents.planning.loop import planner_messages
from llm_agents.planning.scoring import PlanJudge

SIDECAR = "tuning.json"
CURVE = "reward_curve.png"
#: The planner request the online runs train and are asked with: a few lines.
SHORT_TEMPLATES = str(Path(__file__).with_name("short_planner"))
#: The seed of the selection worlds rewards are played in: plan-score's default, so a reward
#: is plan-score's verdict. Their keys are never those of eval's worlds or of plan-score's
#: held-out worlds, where a tuned planner is reported.
SELECTION_SEED = 0

Method = Literal["grpo", "rs"]
Chat = list[dict[str, str]]


class OnlineSettings(BaseModel):
    """What an online tuning run was asked to do."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    method: Method = "grpo"
    model: str = DEFAULT_MODEL
    """The base model, `hf:NAME` (a named model) or `hf:/path/to/folder`."""
    out: Path
    """The folder the merged model is saved to (must not exist)."""
    dataset: str | None = None
    """Where the instruction texts come from (`load_dataset`)."""
    splits: tuple[str, ...] = ("easy_train",)
    """The dataset splits whose texts are trained on."""
    main_only: bool = False
    """Each goal's main instruction only, not its paraphrases."""
    limit: int | None = Field(None, ge=1)
    """Only the first N texts."""
    variant: Variant = DEFAULT_VARIANT
    worlds: int = Field(2, ge=1)
    """Selection worlds each sampled plan is played in."""
    selection_seed: int = SELECTION_SEED
    skill_steps: int = Field(SKILL_STEPS, ge=1)
    templates_dir: str | None = SHORT_TEMPLATES
    """The planner prompt's templates (None: the project's full planner prompt)."""
    max_plan_steps: int = Field(PlanLimits().max_steps, ge=1)
    achieved_weight: float = Field(0.3, ge=0)
    """Reward per world for the share of the goal's required achievements unlocked."""
    played_weight: float = Field(0.2, ge=0)
    """Reward per world for the share of the plan's read skills that played."""
    temperature: float = Field(1.0, gt=0)
    max_tokens: int = Field(64, ge=1)
    """Tokens a sampled plan may take."""
    learning_rate: float = Field(5e-5, gt=0)
    lora_rank: int = Field(16, ge=1)
    seed: int = 0
    max_minutes: float | None = Field(None, gt=0)
    """Stop training (GRPO: after the step that crosses it; rs: before a round) once this much
    wall time has passed."""
    # GRPO
    max_steps: int = Field(20, ge=1)
    """GRPO optimizer steps."""
    generations: int = Field(4, ge=2)
    """Plans sampled per prompt: GRPO's group, whose rewards are compared."""
    prompts_per_step: int = Field(2, ge=1)
    beta: float = Field(0.0, ge=0)
    """GRPO's pull towards the untuned model (TRL's `beta`; 0: none, no reference model)."""
    # rejection sampling
    rounds: int = Field(2, ge=1)
    samples: int = Field(8, ge=1)
    """rs: plans sampled per text and round."""
    threshold: float = Field(0.5, gt=0, le=1)
    """rs: the least share of worlds a kept plan succeeds in."""
    sft_steps: int = Field(8, ge=1)
    """rs: SFT optimizer steps per round (on two plans each)."""


# ---------------------------------------------------------------- the game's verdict


class PlanVerdict(BaseModel):
    """One plan played in the selection worlds."""

    model_config = ConfigDict(frozen=True)

    success: float
    """Share of worlds where the goal was met."""
    achieved: float
    """Share of the goal's required achievements unlocked, averaged over worlds (a placing
    goal: its success)."""
    played: float
    """Share of the plan's read skills that finished, averaged over worlds."""
    episodes: int
    """Episodes played on the env (0 when no step was read)."""
    breaks: tuple[str, ...] = ()
    """Steps that earn an achievement the instruction forbids, played or not."""

    def reward(self, achieved_weight: float, played_weight: float) -> float:
        if self.breaks:
            # A plan that would break its instruction earns nothing, even where its episodes
            # ended at success before the breaking step: plan-score keeps it out of every export.
            return 0.0
        # A world that succeeded counts both shaped parts whole (1 + both weights), a failed
        # one at most both weights: success comes first.
        return self.success + achieved_weight * self.achieved + played_weight * self.played


def plan_judge(settings: OnlineSettings) -> PlanJudge:
    """plan-score's judge over the run's dataset, playing in its selection worlds."""
    return PlanJudge(
        dataset=settings.dataset,
        variant=settings.variant,
        worlds=settings.worlds,
        seed=settings.selection_seed,
        skill_steps=settings.skill_steps,
    )


def judge_plans(judge: PlanJudge, plans: Sequence[tuple[str, str]]) -> list[PlanVerdict]:
    """The game's verdict on each (instruction text, plan text): the one place plans are
    played, by plan-score's batched execution in its selection worlds."""
    return [
        PlanVerdict(
            success=played.success,
            achieved=played.goal_reached,
            played=played.played,
            episodes=0 if played.empty else judge.worlds,
            breaks=played.breaks,
        )
        for played in judge.score(plans)
    ]


# ---------------------------------------------------------------- texts and prompts


def training_texts(settings: OnlineSettings) -> dict[str, tuple[AnyGoal, int]]:
    """The texts trained on, in the dataset's order, each with its goal and phrasing index."""
    dataset = load_dataset(settings.dataset)
    known = {goal.split for goal in dataset.goals}
    unknown = [split for split in settings.splits if split not in known]
    if unknown:
        raise UserError(
            f"the dataset has no split {', '.join(unknown)}; it has {', '.join(sorted(known))}"
        )
    texts: dict[str, tuple[AnyGoal, int]] = {}
    for goal in dataset.goals:
        if goal.split in settings.splits:
            phrasings = goal.texts[:1] if settings.main_only else goal.texts
            for index, text in enumerate(phrasings):
                texts.setdefault(text, (goal, index))
    chosen = dict(list(texts.items())[: settings.limit])
    if not chosen:
        raise UserError(f"the splits {', '.join(settings.splits)} hold no text")
    return chosen


def prompt_chat(text: str, settings: OnlineSettings) -> Chat:
    limits = PlanLimits(max_steps=settings.max_plan_steps)
    messages = planner_messages(text, limits, settings.variant, settings.templates_dir)
    return [{"role": m.role, "content": m.content} for m in messages]


def completion_text(completion: Any) -> str:
    """A completion as TRL hands it: a string, or a conversational answer's messages."""
    if isinstance(completion, str):
        return completion
    return "".join(m.get("content", "") for m in completion if m.get("role") == "assistant")


# ---------------------------------------------------------------- records


class JudgedPlan(BaseModel):
    """One sampled plan and the game's verdict on it."""

    instruction: str
    plan: str
    reward: float
    verdict: PlanVerdict


class StepRewards(BaseModel):
    """The plans of one GRPO step or one rejection-sampling round, as judged."""

    step: int
    plans: int
    reward_mean: float
    reward_std: float
    success_mean: float
    achieved_mean: float
    played_mean: float
    plans_succeeding: int
    """Plans that met the goal in at least one world."""
    seconds: float
    """Wall seconds since the run started, at the end of judging."""
    kept: int | None = None
    """rs: plans kept for SFT."""
    judged: list[JudgedPlan] = Field(default_factory=list)
    """Every plan judged, what the model wrote and what it earned."""


class OnlineRecord(BaseModel):
    """The `tuning.json` sidecar of an online-tuned folder."""

    settings: OnlineSettings
    base_folder: str
    texts: int
    steps: int
    """GRPO optimizer steps, or rs rounds, taken."""
    stopped_by_time: bool
    rewards: list[StepRewards]
    episodes: int
    """Plan episodes played on the env for rewards."""
    seconds: float
    packages: dict[str, str]


class PlanReward:
    """GRPO's reward function: the game's verdict on each sampled plan, every call recorded."""

    __name__ = "plan_verdict"

    def __init__(self, judge: PlanJudge, settings: OnlineSettings, started: float):
        self.judge, self.settings, self.started = judge, settings, started
        self.steps: list[StepRewards] = []

    def __call__(
        self, prompts: list[Any], completions: list[Any], instruction: list[str], **_: Any
    ) -> list[float | None]:
        plans = [completion_text(c) for c in completions]
        verdicts = judge_plans(self.judge, list(zip(instruction, plans, strict=True)))
        judged = list(zip(instruction, plans, strict=True))
        self.steps.append(
            _summary(len(self.steps) + 1, judged, verdicts, self.settings, self.started)
        )
        return [
            v.reward(self.settings.achieved_weight, self.settings.played_weight) for v in verdicts
        ]


def _summary(
    step: int,
    plans: list[tuple[str, str]],
    verdicts: list[PlanVerdict],
    settings: OnlineSettings,
    started: float,
) -> StepRewards:
    rewards = [v.reward(settings.achieved_weight, settings.played_weight) for v in verdicts]
    return StepRewards(
        step=step,
        plans=len(verdicts),
        reward_mean=fmean(rewards),
        reward_std=pstdev(rewards),
        success_mean=fmean(v.success for v in verdicts),
        achieved_mean=fmean(v.achieved for v in verdicts),
        played_mean=fmean(v.played for v in verdicts),
        plans_succeeding=sum(v.success > 0 for v in verdicts),
        seconds=round(time.monotonic() - started, 1),
        judged=[
            JudgedPlan(instruction=text, plan=plan, reward=reward, verdict=verdict)
            for (text, plan), reward, verdict in zip(plans, rewards, verdicts, strict=True)
        ],
    )


def draw_curve(rewards: list[StepRewards], method: Method, path: Path) -> None:
    """The mean reward and success share per step (or round) as a PNG."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import MaxNLocator

    steps = [r.step for r in rewards]
    figure, axis = plt.subplots(figsize=(6, 3.5), dpi=100)
    axis.plot(steps, [r.reward_mean for r in rewards], marker="o", label="mean reward")
    axis.plot(steps, [r.success_mean for r in rewards], marker="s", label="success share")
    axis.plot(steps, [r.achieved_mean for r in rewards], linestyle="--", label="achievements")
    axis.set_xlabel("GRPO step" if method == "grpo" else "rejection-sampling round")
    axis.set_ylabel("per sampled plan")
    axis.set_ylim(bottom=0)
    axis.xaxis.set_major_locator(MaxNLocator(integer=True))
    axis.grid(alpha=0.3)
    axis.legend(fontsize=8)
    figure.tight_layout()
    figure.savefig(path)
    plt.close(figure)


# ---------------------------------------------------------------- training


def _lora(settings: OnlineSettings) -> Any:
    import peft

    return peft.LoraConfig(
        r=settings.lora_rank,
        lora_alpha=2 * settings.lora_rank,
        lora_dropout=0.0,
        target_modules="all-linear",
        task_type="CAUSAL_LM",
    )


def _common_args(settings: OnlineSettings, scratch: Path) -> dict[str, Any]:
    import torch

    return {
        "output_dir": str(scratch / "trainer"),
        "learning_rate": settings.learning_rate,
        "seed": settings.seed,
        "logging_steps": 1,
        "save_strategy": "no",
        "report_to": "none",
        "gradient_checkpointing": False,
        "bf16": torch.cuda.is_available() and torch.cuda.is_bf16_supported(),
    }


def _deadline_callback(settings: OnlineSettings, started: float) -> Any:
    import transformers

    class Deadline(transformers.TrainerCallback):
        stopped = False

        def on_step_end(self, args: Any, state: Any, control: Any, **kwargs: Any) -> Any:
            minutes = (time.monotonic() - started) / 60
            if settings.max_minutes is not None and minutes >= settings.max_minutes:
                Deadline.stopped = True
                control.should_training_stop = True
            return control

    return Deadline()


def _grpo(
    settings: OnlineSettings,
    texts: dict[str, tuple[AnyGoal, int]],
    model: Any,
    tokenizer: Any,
    judge: PlanJudge,
    scratch: Path,
    started: float,
    generation_kwargs: dict[str, Any] | None,
) -> tuple[Any, list[StepRewards], int, bool]:
    import datasets
    import trl

    batch = settings.generations * settings.prompts_per_step
    args = trl.GRPOConfig(
        **_common_args(settings, scratch),
        max_steps=settings.max_steps,
        per_device_train_batch_size=batch,
        gradient_accumulation_steps=1,
        num_generations=settings.generations,
        max_completion_length=settings.max_tokens,
        temperature=settings.temperature,
        beta=settings.beta,
        generation_kwargs=generation_kwargs,
    )
    rows = [{"prompt": prompt_chat(text, settings), "instruction": text} for text in texts]
    reward = PlanReward(judge, settings, started)
    deadline = _deadline_callback(settings, started)
    trainer = trl.GRPOTrainer(
        model=model,
        reward_funcs=[reward],
        args=args,
        train_dataset=datasets.Dataset.from_list(rows),
        processing_class=tokenizer,
        peft_config=_lora(settings),
        callbacks=[deadline],
    )
    result = trainer.train()
    tuned: Any = trainer.model
    return tuned, reward.steps, result.global_step, type(deadline).stopped


def sample_plans(
    model: Any,
    tokenizer: Any,
    chat: Chat,
    settings: OnlineSettings,
    count: int,
    generation_kwargs: dict[str, Any] | None = None,
) -> list[str]:
    """`count` plans sampled for one prompt, as `plan --candidates` would ask."""
    import torch

    ids = tokenizer.apply_chat_template(
        chat, add_generation_prompt=True, return_tensors="pt", return_dict=True
    )
    with torch.no_grad():
        out = model.generate(
            **ids,
            do_sample=True,
            temperature=settings.temperature,
            max_new_tokens=settings.max_tokens,
            num_return_sequences=count,
            pad_token_id=tokenizer.pad_token_id or tokenizer.eos_token_id,
            **(generation_kwargs or {}),
        )
    prompt_length = ids["input_ids"].shape[1]
    return [tokenizer.decode(row[prompt_length:], skip_special_tokens=True).strip() for row in out]


def _rejection_sampling(
    settings: OnlineSettings,
    texts: dict[str, tuple[AnyGoal, int]],
    model: Any,
    tokenizer: Any,
    judge: PlanJudge,
    scratch: Path,
    started: float,
    generation_kwargs: dict[str, Any] | None,
) -> tuple[Any, list[StepRewards], int, bool]:
    import datasets
    import torch
    import trl

    torch.manual_seed(settings.seed)
    rounds: list[StepRewards] = []
    kept_all: list[dict[str, Any]] = []
    for number in range(1, settings.rounds + 1):
        if settings.max_minutes and (time.monotonic() - started) / 60 >= settings.max_minutes:
            return model, rounds, len(rounds), True
        model.eval()
        pairs: list[tuple[str, str]] = []
        for text in texts:
            chat = prompt_chat(text, settings)
            plans = sample_plans(
                model, tokenizer, chat, settings, settings.samples, generation_kwargs
            )
            pairs += [(text, plan) for plan in dict.fromkeys(plans)]
        verdicts = judge_plans(judge, pairs)
        kept = {
            (text, plan)
            for (text, plan), verdict in zip(pairs, verdicts, strict=True)
            if verdict.success >= settings.threshold
        }
        kept_all += [
            {
                "prompt": prompt_chat(text, settings),
                "completion": [{"role": "assistant", "content": plan}],
            }
            for text, plan in sorted(kept)
        ]
        summary = _summary(number, pairs, verdicts, settings, started)
        rounds.append(summary.model_copy(update={"kept": len(kept)}))
        if not kept_all:
            continue
        # Every plan kept so far, so a round that finds nothing new still rehearses the old.
        random.Random(settings.seed + number).shuffle(kept_all)
        trainer = trl.SFTTrainer(
            model=model,
            args=trl.SFTConfig(
                **_common_args(settings, scratch),
                max_steps=settings.sft_steps,
                per_device_train_batch_size=2,
                gradient_accumulation_steps=1,
                completion_only_loss=True,
                max_length=None,
            ),
            train_dataset=datasets.Dataset.from_list(kept_all),
            processing_class=tokenizer,
            peft_config=_lora(settings),
        )
        trainer.train()
        adapted: Any = trainer.model
        model = adapted.merge_and_unload()
    return model, rounds, len(rounds), False


def tune_online(
    settings: OnlineSettings, *, generation_kwargs: dict[str, Any] | None = None
) -> OnlineRecord:
    """Tune `settings.model` against the game's verdict, merge, save to `settings.out`.

    `generation_kwargs` reach the sampling unchanged (transformers' `generate` arguments)."""
    check_installed()
    if settings.out.exists():
        raise UserError(f"{settings.out} exists; choose a new folder for the tuned model")
    folder = model_folder(settings.model)
    texts = training_texts(settings)

    import torch
    import transformers

    started = time.monotonic()
    torch.manual_seed(settings.seed)
    tokenizer = transformers.AutoTokenizer.from_pretrained(folder)
    if tokenizer.pad_token is None:
        tokenizer.pad_token = tokenizer.eos_token
    model = transformers.AutoModelForCausalLM.from_pretrained(folder, dtype=torch.float32)
    judge = plan_judge(settings)
    settings.out.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(
        dir=settings.out.parent, prefix=f".tuning-{settings.out.name}-"
    ) as scratch_name:
        scratch = Path(scratch_name)
        if settings.method == "grpo":
            tuned, rewards, steps, stopped = _grpo(
                settings, texts, model, tokenizer, judge, scratch, started, generation_kwargs
            )
            merged = tuned.merge_and_unload()
        else:
            merged, rewards, steps, stopped = _rejection_sampling(
                settings, texts, model, tokenizer, judge, scratch, started, generation_kwargs
            )
        staged = scratch / "model"
        merged.save_pretrained(staged)
        tokenizer.save_pretrained(staged)
        record = OnlineRecord(
            settings=settings,
            base_folder=str(folder),
            texts=len(texts),
            steps=steps,
            stopped_by_time=stopped,
            rewards=rewards,
            episodes=sum(plan.verdict.episodes for step in rewards for plan in step.judged),
            seconds=round(time.monotonic() - started, 1),
            packages={
                name: sys.modules[name].__version__
                for name in ("torch", "transformers", "peft", "trl")
            },
        )
        (staged / SIDECAR).write_text(record.model_dump_json(indent=2) + "\n")
        if rewards:
            draw_curve(rewards, settings.method, staged / CURVE)
        # Renamed into place only when complete: a folder that exists is a whole model.
        staged.rename(settings.out)
        shutil.rmtree(scratch / "trainer", ignore_errors=True)
    return record


# ---------------------------------------------------------------- command line


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    commands = parser.add_subparsers(dest="method", required=True)
    defaults = OnlineSettings(out=Path("-"))
    for method, help_text in (
        ("grpo", "online GRPO against the game's verdict, LoRA"),
        ("rs", "rejection-sampling rounds: sample, keep the plans that work, SFT"),
    ):
        sub = commands.add_parser(method, help=help_text)
        sub.add_argument("--out", type=Path, required=True, help="new folder for the tuned model")
        sub.add_argument("--model", default=defaults.model)
        sub.add_argument("--dataset", default=None)
        sub.add_argument("--splits", default=",".join(defaults.splits))
        sub.add_argument("--main-only", action="store_true")
        sub.add_argument("--limit", type=int, default=None)
        sub.add_argument(
            "--variant", default=defaults.variant.value, choices=[v.value for v in Variant]
        )
        sub.add_argument("--templates-dir", default=defaults.templates_dir)
        for name in (
            "worlds", "selection_seed", "skill_steps", "max_plan_steps", "max_tokens",
            "lora_rank", "seed", "max_steps", "generations", "prompts_per_step", "rounds",
            "samples", "sft_steps",
        ):  # fmt: skip
            sub.add_argument(
                f"--{name.replace('_', '-')}", type=int, default=getattr(defaults, name)
            )
        for name in (
            "achieved_weight", "played_weight", "temperature", "learning_rate", "beta",
            "threshold", "max_minutes",
        ):  # fmt: skip
            sub.add_argument(
                f"--{name.replace('_', '-')}", type=float, default=getattr(defaults, name)
            )
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    values = vars(args)
    try:
        settings = OnlineSettings(
            **{
                **values,
                "splits": tuple(s for s in args.splits.split(",") if s),
                "variant": Variant(args.variant),
            }
        )
        record = tune_online(settings)
    except (ValidationError, UserError) as error:
        return one_line_error(error)
    last = record.rewards[-1] if record.rewards else None
    print(
        f"tuned {settings.model} ({settings.method}, {record.texts} texts, {record.steps} "
        f"{'steps' if settings.method == 'grpo' else 'rounds'}, {record.episodes} episodes, "
        f"{record.seconds:.0f} s"
        + (f", last mean reward {last.reward_mean:.3f}" if last else "")
        + f")\nmodel: {settings.out} (plan with --model hf:{settings.out} "
        f"--templates-dir {settings.templates_dir or 'the default'})"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
