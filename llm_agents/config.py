"""The evaluation run's configuration: defaults, file loading (YAML or TOML) and validation.

The resolved config (every default filled in) is saved with the results, so a run can be
reproduced and resumed from its output directory alone.
"""

from __future__ import annotations

import tomllib
from pathlib import Path
from typing import Any

import yaml
from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    ValidationError,
    field_validator,
    model_validator,
)

from env.dataset import parse_categories
from env.errors import UserError
from env.variant import Variant
from llm_agents.backends.base import GenerateConfig

#: The paper's zero-shot EASY table: Achievements one / combo, and New objects.
DEFAULT_CATEGORIES: tuple[str, ...] = ("one", "combo", "new_objects")


class EvalConfig(BaseModel):
    """Everything that defines an evaluation run."""

    model_config = ConfigDict(extra="forbid", validate_assignment=True)

    model: str = "hf:smollm2-135m"
    """Model spec: `hf:NAME_OR_PATH`, `vllm:NAME_OR_PATH`, `openai:MODEL@URL` or `mock:SCRIPT`."""
    generation: GenerateConfig = Field(default_factory=GenerateConfig)
    """Generation parameters passed to the backend."""
    backend_options: dict[str, Any] = Field(default_factory=dict)
    """Keyword options for the backend, e.g. `threads` or `device` (hf), `enforce_eager` or
    `max_model_len` (vllm), `api_key_env` (openai)."""
    choice: bool = False
    """Constrain each answer to one action name (the backend's choice mode) instead of free text."""
    variant: Variant = Variant.FULL
    """Craftax variant: `full` (43 actions) or `classic` (17 actions)."""
    splits: tuple[str, ...] = DEFAULT_CATEGORIES
    """Instruction categories to run: `one`, `combo`, `paraphrased`, `new_objects`."""
    dataset: str | None = None
    """Dataset source: None for the craftext 0.2.2 wheel's data, else an official repository
    clone, a craftext wheel or a dataset JSON written by this tool."""
    paraphrases: bool = True
    """Run every paraphrase of each goal as well as its original instruction."""
    episodes_per_instruction: int = Field(1, ge=1)
    """Episodes (distinct worlds) per instruction text."""
    max_steps: int = Field(250, ge=1)
    """Step cap per episode (250 in the official LLM baseline)."""
    seed: int = 0
    """Run seed; each episode's world derives from (seed, goal, instruction variant, episode)."""
    batch_size: int = Field(8, ge=1)
    """Episodes played in lockstep, one batched model call per step."""
    lanes: int = Field(1, ge=1)
    """Split the batch into this many lanes whose model calls overlap the other lanes' env and
    text work: worth 2 with a server backend (openai, large batches), not with a local model."""
    renderer: str = "objects"
    """Observation text format: `objects`, `grid` or `table` (the official baseline's)."""
    history_length: int = Field(5, ge=0)
    """Recent actions (with outcomes) shown in each prompt."""
    templates_dir: str | None = None
    """Directory whose `.j2` files override the packaged prompt templates."""
    plans: str | None = None
    """JSON file mapping instruction text -> plan text, added to the step prompt."""
    output_dir: str = "runs/latest"
    """Where steps, episodes and results are written; rerunning on it resumes the run."""
    limit: int | None = Field(None, ge=1)
    """Run only the first N scheduled episodes (quick runs)."""
    fallback_action: str = "NOOP"
    """Action taken when the model's answer cannot be parsed (counted as invalid)."""
    cache: str | None = None
    """SQLite file caching model responses, so a repeated run does not pay twice."""
    record_steps: bool = True
    """Write one JSON line per agent step (observation, raw output, parsed action, ...)."""
    agent: str = "zero-shot"
    """Agent strategy: `zero-shot`, `cot` (keeps its recent reasoning), `few-shot` (expert
    demonstrations first) or `expert` (scripted, no model)."""
    cot_steps: int = Field(3, ge=1)
    """cot: how many of the model's last replies stay in the conversation."""
    cot_max_tokens: int = Field(384, ge=1)
    """cot: the kept replies' total size cap, in tokens (estimated as 4 characters each)."""
    few_shot_steps: int = Field(8, ge=1)
    """few-shot: demonstration steps shown before each episode."""
    demos: str | None = None
    """few-shot: a run directory of the `expert` agent on training goals (`one`, `combo`) with
    the same renderer, whose successful episodes give the demonstrations."""

    @field_validator("agent")
    @classmethod
    def _known_agent(cls, value: str) -> str:
        from llm_agents.agents import AGENTS

        if value not in AGENTS:
            raise ValueError(f"unknown agent {value!r}; choose from {', '.join(AGENTS)}")
        return value

    @model_validator(mode="after")
    def _few_shot_has_demos(self) -> EvalConfig:
        if self.agent == "few-shot" and self.demos is None:
            raise ValueError("the few-shot agent needs demos: the run directory of an expert run")
        return self

    @field_validator("splits", mode="before")
    @classmethod
    def _known_splits(cls, value: Any) -> tuple[str, ...]:
        return tuple(parse_categories(value))

    @field_validator("model")
    @classmethod
    def _known_backend(cls, value: str) -> str:
        from llm_agents.backends import parse_model_spec

        parse_model_spec(value)
        return value

    @field_validator("renderer")
    @classmethod
    def _known_renderer(cls, value: str) -> str:
        from textualizer import RENDERERS

        if value not in RENDERERS:
            raise ValueError(f"unknown renderer {value!r}; choose from {', '.join(RENDERERS)}")
        return value

    def run_identity(self) -> dict[str, Any]:
        """The settings that must match for a run directory to be resumed."""
        return self.model_dump(
            mode="json",
            exclude={
                "output_dir",
                "limit",
                "batch_size",
                "lanes",
                "cache",
                "generation",
                "backend_options",
            },
        ) | {
            "generation": self.generation.model_dump(
                mode="json", exclude={"max_concurrency", "timeout_s", "max_retries"}
            )
        }


def load_config_file(path: str | Path) -> dict[str, Any]:
    """Read a YAML (.yaml/.yml) or TOML (.toml) config file into a dict."""
    file = Path(path)
    try:
        text = file.read_text(encoding="utf-8")
    except OSError as err:
        raise UserError(f"cannot read config file {file}: {err.strerror}") from err
    try:
        if file.suffix == ".toml":
            data = tomllib.loads(text)
        elif file.suffix in (".yaml", ".yml"):
            data = yaml.safe_load(text) or {}
        else:
            raise UserError(f"config file {file} must end in .toml, .yaml or .yml")
    except (tomllib.TOMLDecodeError, yaml.YAMLError) as err:
        raise UserError(f"config file {file} does not parse: {err}") from err
    if not isinstance(data, dict):
        raise UserError(f"config file {file} must hold a table of settings")
    return data


def build_config(
    base: dict[str, Any] | None = None,
    overrides: dict[str, Any] | None = None,
    generation_overrides: dict[str, Any] | None = None,
) -> EvalConfig:
    """An `EvalConfig` from file settings overridden by flags (None values are ignored)."""
    data = dict(base or {})
    generation = dict(data.pop("generation", None) or {})
    data.update({k: v for k, v in (overrides or {}).items() if v is not None})
    generation.update({k: v for k, v in (generation_overrides or {}).items() if v is not None})
    try:
        return EvalConfig(**data, generation=GenerateConfig(**generation))
    except ValidationError as err:
        raise UserError(f"invalid configuration: {_validation_message(err)}") from err


def _validation_message(err: ValidationError) -> str:
    parts = []
    for problem in err.errors():
        where = ".".join(str(p) for p in problem["loc"]) or "config"
        parts.append(f"{where}: {problem['msg']}")
    return "; ".join(parts)
