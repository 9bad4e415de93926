"""Tune a planner on the plans that worked when played: LoRA (peft) through TRL's SFTTrainer or
DPOTrainer, the merged model saved as a transformers folder that `plan --model hf:FOLDER` loads.

The loop (docs/guides/tuning-a-planner.md): `craftext-llm plan --candidates N` proposes plans,
`craftext-llm plan-score --export sft|dpo --out DATA` plays them and writes TRL's conversational
lines (`messages`, or `prompt` + `chosen` + `rejected` as message lists), this script tunes on
them, and
`plan` then `plan-score` measure the tuned model against the untuned one.

    python -m benchmarks.tune_planner train DATA/sft.jsonl --out TUNED
        [--model hf:qwen2.5-coder-0.5b] [--epochs 1] [--max-steps N] [--limit N]
        [--learning-rate 2e-4] [--lora-rank 16] [--batch-size 1] [--grad-accum 4] [--beta 0.1]
    python -m benchmarks.tune_planner compare BEFORE_DIR AFTER_DIR [--held-out]

An SFT conversation is handed to TRL as its prompt (the planner's messages) and its completion
(the answer), so the loss falls on the answer alone. Lines in the standard form earlier exports
wrote (`prompt` + `completion` strings) are read too: each prompt is put back into the chat the
planner sends (its system block, then its `Instruction: ...` user block; a bare instruction gets
the planner's own prompt around it). Either way the model is tuned on the very tokens `plan`
will show it, through its own chat template. The tuned folder holds a `tuning.json` sidecar
(base model, data file and its hash, settings, losses, seconds).

trl, peft, datasets and torch are imported here only: `pip install -e '.[tune]'`.
"""

from __future__ import annotations

import argparse
import hashlib
import importlib.util
import json
import shutil
import sys
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError

from env.errors import UserError
from env.variant import Variant
from llm_agents.backends import parse_model_spec
from llm_agents.backends.base import local_model_path
from llm_agents.planning.checks import PlanLimits
from llm_agents.planning.loop import planner_messages
from llm_agents.planning.records import PlanScore
from llm_agents.run_data.metrics import SuccessRate, clustered_rate

TUNE_PACKAGES = ("torch", "transformers", "peft", "trl", "datasets")
INSTALL_HINT = "pip install -e '.[tune]'"
SIDECAR = "tuning.json"
DEFAULT_MODEL = "hf:qwen2.5-coder-0.5b"

Method = Literal["sft", "dpo"]
#: The keys of each method's lines, as TRL reads them.
METHOD_KEYS: dict[Method, frozenset[str]] = {
    "sft": frozenset({"prompt", "completion"}),
    "dpo": frozenset({"prompt", "chosen", "rejected"}),
}
#: The keys of a conversational SFT line (what `plan-score --export sft` writes).
CONVERSATION_KEYS = frozenset({"messages"})
Chat = list[dict[str, str]]


class TuneSettings(BaseModel):
    """What a tuning run was asked to do."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    model: str = DEFAULT_MODEL
    """The base model, `hf:NAME` (a named model) or `hf:/path/to/folder`."""
    data: Path
    """An sft.jsonl or dpo.jsonl from `plan-score --export`."""
    out: Path
    """The folder the merged model is saved to (must not exist)."""
    epochs: float = Field(1.0, gt=0)
    max_steps: int | None = Field(None, ge=1)
    """Optimizer steps; None: as many as `epochs` take."""
    limit: int | None = Field(None, ge=1)
    """Only the data's first N lines."""
    learning_rate: float = Field(2e-4, gt=0)
    lora_rank: int = Field(16, ge=1)
    batch_size: int = Field(1, ge=1)
    grad_accum: int = Field(4, ge=1)
    beta: float = Field(0.1, gt=0)
    """DPO's strength of the pull towards the untuned model (TRL's `beta`); unused by SFT."""
    seed: int = 0
    variant: Variant = Variant.FULL
    """The variant whose names the planner's prompt lists (for bare-instruction prompts)."""
    templates_dir: str | None = None
    """The prompt templates the plans were asked with (None: the project's own)."""
    max_plan_steps: int = Field(PlanLimits().max_steps, ge=1)
    """The step limit the planner's prompt states, for the prompts this run builds."""
    reprompt: bool = False
    """Ask each line's instruction again with this run's prompt (`templates_dir`, `variant`,
    `max_plan_steps`) instead of the chat it was exported with: plans exported under one prompt
    tuned for another, as `plan --templates-dir` will ask."""


class TuneRecord(BaseModel):
    """The `tuning.json` sidecar of a tuned folder."""

    settings: TuneSettings
    method: Method
    base_folder: str
    data_sha256: str
    examples: int
    prompts_rebuilt: int
    """Lines given the planner's prompt around their instruction: bare instructions, and every
    line under `reprompt`."""
    steps: int
    first_loss: float | None
    last_loss: float | None
    seconds: float
    packages: dict[str, str]


def check_installed() -> None:
    """Refuse, in one line, when the `tune` extra is missing."""
    missing = [name for name in TUNE_PACKAGES if importlib.util.find_spec(name) is None]
    if missing:
        raise UserError(f"tuning needs {', '.join(missing)}: {INSTALL_HINT}")


# ---------------------------------------------------------------- data


def read_lines(path: Path, limit: int | None = None) -> tuple[Method, list[dict[str, Any]]]:
    """The lines of an exported file and the method their keys say (all lines alike)."""
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as error:
        raise UserError(f"cannot read {path}: {error.strerror}") from None
    rows: list[dict[str, Any]] = []
    for number, line in enumerate(text.splitlines(), start=1):
        if not line.strip():
            continue
        try:
            row = json.loads(line)
        except json.JSONDecodeError:
            raise UserError(f"{path}:{number} is not JSON") from None
        if not isinstance(row, dict):
            raise UserError(f"{path}:{number} is not a JSON object")
        rows.append(row)
    if not rows:
        raise UserError(f"{path} holds no examples")
    methods = [m for m, keys in METHOD_KEYS.items() if keys <= rows[0].keys()]
    conversation = "messages" in rows[0] and not methods
    if not methods and not conversation:
        raise UserError(
            f"{path}:1 has neither messages or prompt+completion (sft) nor "
            "prompt+chosen+rejected (dpo)"
        )
    method = "sft" if conversation else methods[-1]  # both shapes' keys: a preference pair
    keys = CONVERSATION_KEYS if conversation else METHOD_KEYS[method]
    for number, row in enumerate(rows, start=1):
        missing = keys - row.keys()
        if missing:
            raise UserError(f"{path}:{number} lacks {', '.join(sorted(missing))}")
    return method, rows[:limit] if limit else rows


class PlannerChats:
    """Turns an exported prompt back into the chat the planner sends."""

    _SENTINEL = "\x00instruction\x00"

    def __init__(
        self, variant: Variant, templates_dir: str | None, limits: PlanLimits | None = None
    ) -> None:
        self.variant, self.templates_dir, self.limits = variant, templates_dir, limits
        #: What the user block says before the instruction ("Instruction: "), in this run's
        #: prompt and in the project's own (the one `plan-score --export` writes by default).
        self.user_prefix = self._user_prefix(templates_dir)
        self.default_prefix = self._user_prefix(None)
        self.rebuilt = 0

    def _user_prefix(self, templates_dir: str | None) -> str:
        user = planner_messages(self._SENTINEL, None, self.variant, templates_dir)[-1].content
        return user.split(self._SENTINEL)[0]

    def chat(self, prompt: str | Chat) -> Chat:
        if isinstance(prompt, list):
            return prompt
        system, found, instruction = prompt.rpartition(self.user_prefix)
        if found and self.user_prefix:
            user = [{"role": "user", "content": f"{self.user_prefix}{instruction}".strip()}]
            head = [{"role": "system", "content": system.strip()}] if system.strip() else []
            return head + user
        return self.asked(prompt.strip())

    def asked(self, instruction: str) -> Chat:
        """The chat this run's planner prompt makes of a bare instruction."""
        self.rebuilt += 1
        messages = planner_messages(instruction, self.limits, self.variant, self.templates_dir)
        return [{"role": m.role, "content": m.content} for m in messages]

    def reprompted(self, prompt: str | Chat) -> Chat:
        """The chat this run's prompt makes of the instruction an exported prompt asked about."""
        if isinstance(prompt, str):
            user = prompt
        else:
            user = next((m["content"] for m in reversed(prompt) if m["role"] == "user"), "")
        for prefix in dict.fromkeys((self.user_prefix, self.default_prefix)):
            if prefix and prefix in user:
                return self.asked(user.rpartition(prefix)[2].strip())
        if isinstance(prompt, str):
            return self.asked(prompt.strip())
        raise UserError(
            f"--reprompt: a line's user message does not hold {self.user_prefix!r}, "
            "so its instruction cannot be found"
        )


def answer(text: str | Chat) -> Chat:
    return text if isinstance(text, list) else [{"role": "assistant", "content": text.strip()}]


def conversational(
    rows: list[dict[str, Any]], method: Method, chats: PlannerChats, reprompt: bool = False
) -> list[dict]:
    """TRL's conversational lines: the prompt as the planner's chat, each plan as the answer
    (an SFT conversation split before its last message, the answer); under `reprompt` every
    prompt is this run's planner prompt around the line's instruction."""
    keys = METHOD_KEYS[method] - {"prompt"}
    ask = chats.reprompted if reprompt else chats.chat
    return [
        {"prompt": ask(row["messages"][:-1]), "completion": row["messages"][-1:]}
        if "messages" in row
        else {"prompt": ask(row["prompt"]), **{k: answer(row[k]) for k in keys}}
        for row in rows
    ]


# ---------------------------------------------------------------- training


def model_folder(spec: str) -> Path:
    """The local folder of an `hf:` model spec (a named model is fetched on first use)."""
    parsed = parse_model_spec(spec)
    if parsed.backend != "hf":
        raise UserError(f"tuning loads hf: models, not {spec!r}")
    folder = local_model_path("hf", parsed.name)
    if folder is None or not folder.is_dir():
        raise UserError(f"tuning needs a named model or a local model folder, not {spec!r}")
    return folder


def _sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def train(settings: TuneSettings) -> TuneRecord:
    """Tune `settings.model` on `settings.data` with LoRA, merge, save to `settings.out`."""
    check_installed()
    if settings.out.exists():
        raise UserError(f"{settings.out} exists; choose a new folder for the tuned model")
    method, rows = read_lines(settings.data, settings.limit)
    limits = PlanLimits(max_steps=settings.max_plan_steps)
    chats = PlannerChats(settings.variant, settings.templates_dir, limits)
    examples = conversational(rows, method, chats, settings.reprompt)
    folder = model_folder(settings.model)

    import datasets
    import peft
    import torch
    import transformers
    import trl

    started = time.monotonic()
    tokenizer = transformers.AutoTokenizer.from_pretrained(folder)
    model = transformers.AutoModelForCausalLM.from_pretrained(folder, dtype=torch.float32)
    lora = peft.LoraConfig(
        r=settings.lora_rank,
        lora_alpha=2 * settings.lora_rank,
        lora_dropout=0.05,
        target_modules="all-linear",
        task_type="CAUSAL_LM",
    )
    settings.out.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(
        dir=settings.out.parent, prefix=f".tuning-{settings.out.name}-"
    ) as scratch:
        common: dict[str, Any] = {
            "output_dir": str(Path(scratch) / "trainer"),
            "num_train_epochs": settings.epochs,
            "max_steps": settings.max_steps or -1,
            "per_device_train_batch_size": settings.batch_size,
            "gradient_accumulation_steps": settings.grad_accum,
            "learning_rate": settings.learning_rate,
            "seed": settings.seed,
            "logging_steps": 1,
            "save_strategy": "no",
            "report_to": "none",
            # The planner's prompt is long (its system block lists every Craftax name and action);
            # cutting it would tune the model on a prompt `plan` never sends.
            "max_length": None,
            # Recomputing activations saves memory a LoRA of a 0.5B model does not need, at a
            # third more compute.
            "gradient_checkpointing": False,
            # TRL asks for bfloat16 by default, which a CPU run refuses; a GPU that has it uses it.
            "bf16": torch.cuda.is_available() and torch.cuda.is_bf16_supported(),
        }
        dataset = datasets.Dataset.from_list(examples)
        trainer: Any
        if method == "sft":
            trainer = trl.SFTTrainer(
                model=model,
                args=trl.SFTConfig(**common, completion_only_loss=True),
                train_dataset=dataset,
                processing_class=tokenizer,
                peft_config=lora,
            )
        else:
            trainer = trl.DPOTrainer(
                model=model,
                args=trl.DPOConfig(**common, beta=settings.beta),
                train_dataset=dataset,
                processing_class=tokenizer,
                peft_config=lora,
            )
        result = trainer.train()
        losses = [entry["loss"] for entry in trainer.state.log_history if "loss" in entry]
        merged = trainer.model.merge_and_unload()
        staged = Path(scratch) / "model"
        merged.save_pretrained(staged)
        tokenizer.save_pretrained(staged)
        record = TuneRecord(
            settings=settings,
            method=method,
            base_folder=str(folder),
            data_sha256=_sha256(settings.data),
            examples=len(examples),
            prompts_rebuilt=chats.rebuilt,
            steps=result.global_step,
            first_loss=losses[0] if losses else None,
            last_loss=losses[-1] if losses else None,
            seconds=round(time.monotonic() - started, 1),
            packages={
                name: sys.modules[name].__version__
                for name in ("torch", "transformers", "peft", "trl")
            },
        )
        (staged / SIDECAR).write_text(record.model_dump_json(indent=2) + "\n")
        # Renamed into place only when complete: a folder that exists is a whole model.
        staged.rename(settings.out)
        shutil.rmtree(Path(scratch) / "trainer", ignore_errors=True)
    return record


# ---------------------------------------------------------------- before and after


def read_scores(path: Path) -> list[PlanScore]:
    """The plans of a `plan-score` folder's scores.json (or the file itself)."""
    path = path / "scores.json" if path.is_dir() else path
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
        return [PlanScore.model_validate(plan) for plan in data["plans"]]
    except OSError as error:
        raise UserError(f"cannot read {path}: {error.strerror}") from None
    except (json.JSONDecodeError, KeyError, TypeError, ValidationError):
        raise UserError(f"{path} is no plan-score scores.json") from None


class Difference(BaseModel):
    """After minus before over the texts both scored, with a 95% normal interval clustered by
    goal (the same worlds play both plans of a text, so the texts pair up)."""

    texts: int
    rate: float
    low: float
    high: float


def worlds_played(score: PlanScore, held_out: bool) -> SuccessRate:
    """A plan's success in plan-score's selection worlds, or in its held-out worlds."""
    if not held_out:
        return score.success
    if score.held_out is None:
        raise UserError(
            f"{score.instruction!r} was not played in held-out worlds: score it with "
            "plan-score --held-out-worlds H"
        )
    return score.held_out


def paired_difference(
    before: list[PlanScore], after: list[PlanScore], held_out: bool = False
) -> Difference | None:
    """The first candidates' success, after minus before, on the texts both files scored."""
    first_before = {s.instruction: s for s in before if s.candidate == 0}
    pairs = [
        (worlds_played(first_before[s.instruction], held_out), worlds_played(s, held_out), s)
        for s in after
        if s.candidate == 0 and s.instruction in first_before
    ]
    pairs = [(b, a, s) for b, a, s in pairs if b.episodes == a.episodes]
    if not pairs:
        return None
    goals: dict[str, list[int]] = {}
    for b, a, score in pairs:
        goal = goals.setdefault(score.goal_id, [0, 0])
        goal[0] += a.successes - b.successes
        goal[1] += a.episodes
    trials = sum(m for _, m in goals.values())
    rate = sum(d for d, _ in goals.values()) / trials
    variance = sum((d - rate * m) ** 2 for d, m in goals.values()) / trials**2
    half = 1.96 * variance**0.5 * (len(goals) / (len(goals) - 1) if len(goals) > 1 else 1) ** 0.5
    return Difference(texts=len(pairs), rate=rate, low=rate - half, high=rate + half)


def first_candidates(
    scores: list[PlanScore], split: str, held_out: bool = False
) -> SuccessRate | None:
    """Best-of-1: each text's first candidate, clustered by goal."""
    chosen = [
        (s.goal_id, worlds_played(s, held_out))
        for s in scores
        if s.split == split and s.candidate == 0
    ]
    if not chosen:
        return None
    return clustered_rate((goal, rate.successes, rate.episodes) for goal, rate in chosen)


def failure_reasons(scores: list[PlanScore], split: str, top: int = 4) -> list[str]:
    """The commonest first failures of the first candidates' episodes."""
    counts: dict[str, int] = {}
    for score in scores:
        if score.split == split and score.candidate == 0:
            for failure in score.failures:
                key = f"{failure.skill or '-'}: {failure.reason}"
                counts[key] = counts.get(key, 0) + failure.episodes
    ranked = sorted(counts.items(), key=lambda item: (-item[1], item[0]))[:top]
    return [f"{n} x {key}" for key, n in ranked]


def compare(before: Path, after: Path, held_out: bool = False) -> str:
    """Best-of-1 success per split, before and after, side by side, with the difference; in
    plan-score's selection worlds, or with `held_out` in its held-out worlds."""
    old, new = read_scores(before), read_scores(after)
    lines = ["| split | before | after | after - before |", "|---|---|---|---|"]
    reasons = []
    for split in sorted({s.split for s in old} | {s.split for s in new}):
        rates = [first_candidates(scores, split, held_out) for scores in (old, new)]
        cells = [rate.cell() if rate else "-" for rate in rates]
        diff = paired_difference(
            [s for s in old if s.split == split], [s for s in new if s.split == split], held_out
        )
        delta = (
            f"{diff.rate:+.2f} [{diff.low:+.2f}, {diff.high:+.2f}] n={diff.texts} texts"
            if diff
            else "-"
        )
        lines.append(f"| {split} | {cells[0]} | {cells[1]} | {delta} |")
        for label, scores in (("before", old), ("after", new)):
            reasons.append(f"{split} {label}: " + "; ".join(failure_reasons(scores, split)))
    unread = [sum(s.unread for s in scores if s.candidate == 0) for scores in (old, new)]
    steps = [sum(len(s.steps) for s in scores if s.candidate == 0) for scores in (old, new)]
    lines += [
        "",
        f"steps unread: before {unread[0]} of {steps[0]}, after {unread[1]} of {steps[1]}",
        "commonest first failures (episodes):",
        *(f"  {line}" for line in reasons),
        f"worlds: {'held-out' if held_out else 'selection'}",
        f"before: {before}\nafter: {after}",
    ]
    return "\n".join(lines)


# ---------------------------------------------------------------- command line


def _train_settings(args: argparse.Namespace) -> TuneSettings:
    return TuneSettings(
        model=args.model,
        data=args.data,
        out=args.out,
        epochs=args.epochs,
        max_steps=args.max_steps,
        limit=args.limit,
        learning_rate=args.learning_rate,
        lora_rank=args.lora_rank,
        batch_size=args.batch_size,
        grad_accum=args.grad_accum,
        beta=args.beta,
        seed=args.seed,
        variant=Variant(args.variant),
        templates_dir=args.templates_dir,
        max_plan_steps=args.max_plan_steps,
        reprompt=args.reprompt,
    )


def one_line_error(error: ValidationError | UserError) -> int:
    """A user mistake as one line on stderr (a bad setting named by its flag); exit code 2."""
    if isinstance(error, ValidationError):
        first = error.errors()[0]
        flag = "-".join(map(str, first["loc"])).replace("_", "-")
        print(f"error: --{flag}: {first['msg']}", file=sys.stderr)
    else:
        print(f"error: {error}", file=sys.stderr)
    return 2


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    commands = parser.add_subparsers(dest="command", required=True)
    tune = commands.add_parser("train", help="tune a model on an exported sft/dpo file")
    defaults = TuneSettings(data=Path("-"), out=Path("-"))
    tune.add_argument("data", type=Path, help="sft.jsonl or dpo.jsonl from plan-score --export")
    tune.add_argument("--out", type=Path, required=True, help="new folder for the tuned model")
    tune.add_argument("--model", default=defaults.model)
    tune.add_argument("--epochs", type=float, default=defaults.epochs)
    tune.add_argument("--max-steps", type=int, default=None)
    tune.add_argument("--limit", type=int, default=None, help="only the first N lines")
    tune.add_argument("--learning-rate", type=float, default=defaults.learning_rate)
    tune.add_argument("--lora-rank", type=int, default=defaults.lora_rank)
    tune.add_argument("--batch-size", type=int, default=defaults.batch_size)
    tune.add_argument("--grad-accum", type=int, default=defaults.grad_accum)
    tune.add_argument("--beta", type=float, default=defaults.beta, help="DPO only")
    tune.add_argument("--seed", type=int, default=defaults.seed)
    tune.add_argument(
        "--variant", default=defaults.variant.value, choices=[v.value for v in Variant]
    )
    tune.add_argument("--templates-dir", default=None)
    tune.add_argument(
        "--max-plan-steps",
        type=int,
        default=defaults.max_plan_steps,
        help="the step limit the prompts this run builds state (plan's --max-steps)",
    )
    tune.add_argument(
        "--reprompt",
        action="store_true",
        help="ask each line's instruction again with this run's prompt (--templates-dir, "
        "--variant, --max-plan-steps) instead of the chat it was exported with",
    )
    side = commands.add_parser(
        "compare", help="best-of-1 success of two plan-score folders, side by side"
    )
    side.add_argument("before", type=Path, help="plan-score folder of the untuned model's plans")
    side.add_argument("after", type=Path, help="plan-score folder of the tuned model's plans")
    side.add_argument(
        "--held-out",
        action="store_true",
        help="the plans' held-out worlds (plan-score --held-out-worlds) instead of its selection "
        "worlds",
    )
    args = parser.parse_args(argv)
    try:
        if args.command == "train":
            record = train(_train_settings(args))
            print(
                f"tuned {args.model} ({record.method}, {record.examples} examples, "
                f"{record.steps} steps, loss {record.first_loss} -> {record.last_loss}, "
                f"{record.seconds:.0f} s)\nmodel: {args.out} (plan with --model hf:{args.out})"
            )
        else:
            print(compare(args.before, args.after, args.held_out))
    except (ValidationError, UserError) as error:
        return one_line_error(error)
    return 0


if __name__ == "__main__":
    sys.exit(main())
