"""The settings of the commands that talk to a model (`eval`, `plan`): declared once, as typed
fields with docstrings, and loaded from a YAML/TOML file overridden by flags.

Each field is declared here exactly once: its docstring is the flag's help text, its name with
dashes is the flag (`max_steps` -> `--max-steps`), and its name is the config-file key (nested
models such as `generation` are tables of their own). The resolved config, every default filled
in, is saved with the results.
"""

from __future__ import annotations

import difflib
import tomllib
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any, ClassVar, Self, TypeVar

import yaml
from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    PrivateAttr,
    ValidationError,
    field_validator,
    model_validator,
)

from env.dataset import CATEGORIES, PAPER_CATEGORIES, parse_categories
from env.device import EnvDevice
from env.errors import UserError
from env.goals import DEFAULT_DIFFICULTY, DIFFICULTIES, Difficulty, check_categories
from env.open_ended import Task
from env.rules import (
    DEFAULT_STEP_KEYS,
    DEFAULT_SUCCESS_RULE,
    OFFICIAL_WORLD_KEY,
    STEP_CAP,
    StepKeys,
    SuccessRule,
    WorldSeeding,
)
from env.variant import DEFAULT_VARIANT, Variant
from llm_agents.agents.answers.actions import action_names
from llm_agents.agents.loading import check_agent_name
from llm_agents.agents.registry import IMAGE_AGENTS, LETTER_AGENTS, ObservationMode
from llm_agents.backends import parse_model_spec, redact_secrets, redact_settings
from llm_agents.backends.base import (
    CHANGES_RESULTS,
    ChoiceRule,
    ChoiceScoring,
    GenerateConfig,
    result_values,
)
from llm_agents.backends.retry import RetryWaits
from llm_agents.evaluation.protocol import ProtocolName, apply_protocol, protocol_for
from llm_agents.run_data.store import RENAMED_SETTINGS, with_current_names
from textualizer import RENDERERS

if TYPE_CHECKING:
    from env import EnvConfig

#: Backend options that change how fast, where or how patiently a model runs, never what it
#: answers (the waits between retries included).
TRANSPORT_BACKEND_OPTIONS = frozenset(
    {"threads", "api_key_env", "health_interval_s", *RetryWaits.model_fields}
)


class ModelSettings(BaseModel):
    """What every command that talks to a model shares."""

    model_config = ConfigDict(
        extra="forbid", validate_assignment=True, use_attribute_docstrings=True
    )
    renamed_settings: ClassVar[dict[str, str]] = {}
    """Old setting name -> current name, accepted in config files and recorded runs."""

    model: Annotated[str, CHANGES_RESULTS] = "hf:smollm2-135m"
    """Model spec: hf:NAME_OR_PATH, vllm:NAME_OR_PATH (a hub id, ORG/NAME or
    ORG/NAME:FILE.gguf, is downloaded on first use), openai:MODEL@URL or mock:SCRIPT. A URL's
    user info and query values are kept out of everything recorded or shown (`***`)."""
    generation: Annotated[GenerateConfig, CHANGES_RESULTS] = Field(default_factory=GenerateConfig)
    """Generation parameters passed to the backend."""
    backend_options: Annotated[dict[str, Any], CHANGES_RESULTS] = Field(default_factory=dict)
    """Backend option KEY=VALUE (repeatable; values read as JSON when they parse), e.g.
    threads=2, device=cuda, dtype=float32 (hf), enforce_eager=true (vllm), revision=v1.0 (a hub
    id's branch, tag or commit; hf, vllm), api_key_env=MY_KEY (openai). Secrets are kept out of
    everything recorded or shown (`***`): a URL's user info and query values, and the value of
    any option or `extra_body` field whose name says key, token, secret or password, or that is
    a header."""
    cache: str | None = None
    """SQLite file caching model responses, so a repeated run does not pay twice."""
    limit: int | None = Field(None, ge=1)
    """Do only the first N items of the schedule (episodes, or instructions to plan)."""
    templates_dir: str | None = None
    """Directory whose .j2 files override the packaged prompt templates of the same name."""
    dataset: str | None = None
    """Dataset source: an official CrafText clone, a craftext wheel or a dataset JSON written by
    this tool; unset: the official data (downloaded and cached on first use; the craftext 0.2.2
    wheel's, with a warning, when that fails)."""
    variant: Annotated[Variant, CHANGES_RESULTS] = DEFAULT_VARIANT
    """Craftax variant: full (43 actions) or classic (17 actions)."""
    probe: bool = True
    """Send one cheap request before any work to check that the model answers (a dead server,
    a wrong model name or a bad key then fails in seconds, before anything is written)."""

    @classmethod
    def with_presets(cls, settings: dict[str, Any]) -> dict[str, Any]:
        """The merged file and flag settings with any preset filled in under them."""
        return settings

    def result_settings(self) -> dict[str, Any]:
        """The settings that change results (marked `CHANGES_RESULTS`): what a resumed run must
        match. Of the backend options, those that only change how fast or where a model runs
        are left out."""
        settings = result_values(self)
        settings["backend_options"] = {
            key: value
            for key, value in settings["backend_options"].items()
            if key not in TRANSPORT_BACKEND_OPTIONS
        }
        return settings

    # The spec and the backend options as written, when they carry credentials: only the
    # backend is given them (they are never dumped, so no results file, card or page can carry
    # them).
    _written_model: str | None = PrivateAttr(None)
    _written_backend_options: dict[str, Any] | None = PrivateAttr(None)

    @field_validator("model")
    @classmethod
    def _known_backend(cls, value: str) -> str:
        parse_model_spec(value)
        return value

    @model_validator(mode="after")
    def _credentials_kept_apart(self) -> Self:
        # The one place a spec enters a run: from here on `model` is the redacted spec.
        shown = redact_secrets(self.model)
        if shown != self.model:
            self._written_model = self.model
            # Past validation: the spec was just validated, and assigning would validate again.
            self.__dict__["model"] = shown
        elif self._written_model is not None and redact_secrets(self._written_model) != shown:
            self._written_model = None  # another spec was assigned since
        options = redact_settings(self.backend_options)
        if options != self.backend_options:
            self._written_backend_options = self.backend_options
            self.__dict__["backend_options"] = options
        elif (
            self._written_backend_options is not None
            and redact_settings(self._written_backend_options) != options
        ):
            self._written_backend_options = None  # other options were assigned since
        return self

    @property
    def backend_spec(self) -> str:
        """The spec the backend is built from: `model` with its credentials, never recorded."""
        return self._written_model or self.model

    @property
    def backend_option_values(self) -> dict[str, Any]:
        """The backend options the backend is built with: `backend_options` with their
        secrets, never recorded."""
        return self._written_backend_options or self.backend_options

    @field_validator("templates_dir", "dataset", "cache", mode="before")
    @classmethod
    def _path_as_text(cls, value: Any) -> Any:
        return str(value) if isinstance(value, Path) else value

    @field_validator("templates_dir")
    @classmethod
    def _existing_templates_dir(cls, value: str | None) -> str | None:
        if value is not None and not Path(value).expanduser().is_dir():
            raise ValueError(f"templates directory {value!r} does not exist")
        return value


class TextSelection(ModelSettings):
    """What the commands that ask a model about instruction texts (`ground`, `plan`) share:
    which goals' texts, chosen as eval chooses its episodes' goals."""

    renamed_settings: ClassVar[dict[str, str]] = RENAMED_SETTINGS

    difficulty: Annotated[Difficulty, CHANGES_RESULTS] = DEFAULT_DIFFICULTY
    """CrafText difficulty: easy, medium or hard; --categories then picks its splits."""
    categories: Annotated[tuple[str, ...], CHANGES_RESULTS] = CATEGORIES
    """Instruction categories whose texts are used: easy's one, combo, paraphrased,
    new_objects; medium's and hard's train, paraphrased, new_objects (unset: every one of the
    difficulty's that the official data holds, Hard's train only; a config file's `splits`, this
    setting's name before, still means it)."""

    @classmethod
    def with_presets(cls, settings: dict[str, Any]) -> dict[str, Any]:
        """Categories, when unset, from the difficulty (an unknown one is left to validation)."""
        difficulty = settings.get("difficulty", DEFAULT_DIFFICULTY)
        if "categories" in settings or difficulty == "easy" or difficulty not in DIFFICULTIES:
            return settings
        default = protocol_for("default", difficulty).value("categories")
        return settings | {"categories": default}

    @field_validator("categories", mode="before")
    @classmethod
    def _known_categories(cls, value: Any) -> tuple[str, ...]:
        return tuple(parse_categories(value))

    @model_validator(mode="after")
    def _categories_of_the_difficulty(self) -> TextSelection:
        check_categories(self.categories, self.difficulty)
        return self


class GroundingSettings(BaseModel):
    """How a model is asked for an instruction's goal: `ground`, and the `guided` agent."""

    model_config = ConfigDict(
        extra="forbid", validate_assignment=True, use_attribute_docstrings=True
    )

    grounding_shots: Annotated[int, CHANGES_RESULTS] = Field(0, ge=0, le=16)
    """Worked examples shown before each instruction is read (ground, guided): instructions of
    the difficulty's training goals answered with their goals' JSON, never the answer of the
    text being read (no example phrasing its goal or reading as its goal, in any wording); 0:
    none, only the prompt's own example."""


class FailureSettings(BaseModel):
    """When a command that asks a model many times gives up on a failing backend: `eval`,
    `ground`."""

    model_config = ConfigDict(
        extra="forbid", validate_assignment=True, use_attribute_docstrings=True
    )

    max_consecutive_failures: int = Field(8, ge=1)
    """Stop the run (keeping what finished) after this many failed model answers in a row."""


class ChoiceSettings(ModelSettings):
    """How an answer is picked among given options: `eval` (an action name) and `ground` (one
    of the dataset's goals, as JSON) share it."""

    predated_settings: ClassVar[dict[str, Any]] = {"choice_scoring": "sum"}
    """Settings added after runs were recorded whose default is not how those runs played:
    the value such a run played with (`predated`; eval's `recorded`)."""
    predated_context: ClassVar[tuple[str, ...]] = ("choice",)
    """The recorded settings that decide whether a predated setting counts (`result_settings`
    leaves a setting out where it changes nothing)."""

    choice: Annotated[ChoiceRule | None, CHANGES_RESULTS] = None
    """Answer with one option (eval: an action name; the skills agent: loglik picks among the
    skills valid now, guided holds the answer to the catalogue's skills and parameters; ground:
    one of the chosen categories' goals, as JSON), picked by this rule: loglik (the option the
    model finds likeliest after the prompt; hf, vllm) or guided (constrained decoding: the
    model's own answer held to the options; hf, vllm, openai with structured outputs); unset:
    free text."""
    choice_scoring: Annotated[ChoiceScoring, CHANGES_RESULTS] = "pmi"
    """--choice loglik: how an option's log-probabilities make its score: sum (its tokens'
    total, no end of turn: favours the shortest option; runs recorded before this setting
    played it), mean (per token, the end of turn included), bytes (per byte,
    lm-evaluation-harness's acc_norm), pmi (minus the same after a content-free prompt) or
    letters (eval's zero-shot and few-shot agents: the actions listed under the letters A-Z,
    a-z in an order drawn per step from the seed, episode and step, and the model's next-token
    probability of each letter; the order is recorded per step). See docs/agents/choice-scoring.md."""

    structured_output: Annotated[bool, CHANGES_RESULTS] = False
    """Hold every answer to a JSON schema with the backend's structured outputs (hf through
    llguidance, vllm, openai-compatible servers' response_format, mock): guided and ground read a
    goal into its typed fields over the variant's names, so every reading parses; zero-shot
    answers {"action": NAME} over the variant's actions, cot {"reasoning": ..., "action": NAME}.
    Off: free text, as the paper's protocol asks (there, on is a declared departure). See
    docs/agents/structured-output.md."""

    @model_validator(mode="after")
    def _options_or_schema(self) -> ChoiceSettings:
        if self.structured_output and self.choice is not None:
            raise ValueError(
                f"--structured-output holds answers to a JSON schema, --choice {self.choice} to "
                "options: a run asks under one of them"
            )
        return self

    @model_validator(mode="after")
    def _scoring_with_loglik(self) -> ChoiceSettings:
        if (
            "choice_scoring" in self.model_fields_set
            and self.choice != "loglik"
            and self.choice_scoring != type(self).model_fields["choice_scoring"].default
        ):
            raise ValueError(
                f"choice_scoring {self.choice_scoring!r} scores --choice loglik only; this run's "
                f"choice is {self.choice or 'free text'} (leave --choice-scoring out)"
            )
        return self

    def result_settings(self) -> dict[str, Any]:
        """As `ModelSettings.result_settings`; the choice scoring only where it scores
        (`--choice loglik`), so other runs never differ by it."""
        settings = super().result_settings()
        if self.choice != "loglik":
            settings["choice_scoring"] = None
        return settings

    @classmethod
    def predated(cls, recorded: dict[str, Any]) -> dict[str, Any]:
        """The result settings a run that recorded `recorded` (its identity's settings) played
        with: the defaults, except `predated_settings` where it predates them."""
        context = {key: recorded[key] for key in cls.predated_context if key in recorded}
        return cls.model_construct(**{**cls.predated_settings, **context}).result_settings()


class EvalConfig(ChoiceSettings, GroundingSettings, FailureSettings):
    """Everything that defines an evaluation run (`craftext-llm eval`)."""

    predated_settings: ClassVar[dict[str, Any]] = {
        **ChoiceSettings.predated_settings,
        "stuck_after": 0,
        "step_keys": "whole",
    }
    predated_context: ClassVar[tuple[str, ...]] = ("choice", "agent")

    renamed_settings: ClassVar[dict[str, str]] = RENAMED_SETTINGS

    difficulty: Annotated[Difficulty, CHANGES_RESULTS] = DEFAULT_DIFFICULTY
    """CrafText difficulty: easy, medium (Craftax-Classic in the official configs) or hard
    (full Craftax); --categories then picks its splits."""
    categories: Annotated[tuple[str, ...], CHANGES_RESULTS] = PAPER_CATEGORIES
    """Instruction categories to run: easy's one, combo, paraphrased, new_objects; medium's and
    hard's train, paraphrased, new_objects (a config file's `splits`, this setting's name
    before, still means it)."""
    paraphrases: Annotated[bool, CHANGES_RESULTS] = True
    """Run every paraphrase of each goal as well as its original instruction."""
    episodes_per_instruction: Annotated[int, CHANGES_RESULTS] = Field(1, ge=1)
    """Episodes (distinct worlds) per instruction text."""
    max_steps: Annotated[int, CHANGES_RESULTS] = Field(STEP_CAP, ge=1)
    """Step cap per episode (250 in the official LLM baseline)."""
    seed: Annotated[int, CHANGES_RESULTS] = 0
    """Run seed; each episode's world derives from (seed, goal, instruction variant, episode)."""
    batch_size: int = Field(8, ge=1)
    """Episodes in flight at once: each steps as soon as its own answer arrives, and a finished
    one's slot is refilled at once. With a server backend, match --max-concurrency to it."""
    renderer: Annotated[str, CHANGES_RESULTS] = "objects"
    """Observation text format: objects, grid or table (the official baseline's)."""
    history_length: Annotated[int, CHANGES_RESULTS] = Field(5, ge=0)
    """Recent actions (with outcomes) shown in each prompt."""
    observation: Annotated[ObservationMode, CHANGES_RESULTS] = "text"
    """What the model is shown of the world each step: text (the renderer's), image (the frame
    Craftax's pixel renderer draws, as its Pixels environment shows it, sent as a PNG image) or
    both (the text, and the image)."""
    frame_history: Annotated[int, CHANGES_RESULTS] = Field(0, ge=0)
    """--observation image|both: frames of past steps sent before the current one, oldest
    first (0: the current frame alone)."""
    report_invalid_answers: Annotated[bool, CHANGES_RESULTS] = False
    """Say in the next prompt's history that an answer named no valid action and the fallback
    action was played instead (BALROG's harness does; `--protocol balrog` sets it)."""
    task: Annotated[Task, CHANGES_RESULTS] = "craftext"
    """`craftext`: the dataset's instructions, judged by their checkers; `open_ended`: BALROG's
    Crafter task, one goal of our own asking for as many achievements as possible (no dataset),
    judged by the achievement scores (`--protocol balrog` sets it)."""
    plans: str | None = None
    """JSON file mapping instruction text to plan text, added to the step prompt."""
    output_dir: str = "runs/latest"
    """Where steps, episodes and results are written; rerunning on it resumes the run."""
    fallback_action: Annotated[str, CHANGES_RESULTS] = "NOOP"
    """Action taken when the model's answer cannot be parsed (counted as invalid)."""
    record_steps: bool = True
    """Write one JSON line per agent step (observation, raw output, parsed action, ...)."""
    protocol: Annotated[ProtocolName, CHANGES_RESULTS] = "default"
    """Evaluation protocol whose settings fill in those not set explicitly: `default` (ours),
    `paper` (the official CrafText evaluation: Classic, official success rule and world, 0.7
    temperature, 10 tokens, 4 actions shown) or `balrog` (BALROG's open-ended Crafter task); see
    docs/protocols/index.md."""
    protocol_overrides: Annotated[tuple[str, ...], CHANGES_RESULTS] = Field(
        (), json_schema_extra={"flag": False}
    )
    """Settings given explicitly that depart from the protocol's (filled in from the protocol,
    never set by hand)."""
    success_rule: Annotated[SuccessRule, CHANGES_RESULTS] = DEFAULT_SUCCESS_RULE
    """How the step the game ends on is scored: `game_over_counts` (a goal completed then is a
    success) or `official` (as the official CrafText wrapper: the goal is checked on the
    auto-reset world, where no achievements goal is met but a placing or building goal can be)."""
    world_seeding: Annotated[WorldSeeding, CHANGES_RESULTS] = "per_episode"
    """`per_episode`: a world per episode from (seed, goal, variant, episode); `official`: every
    episode in the one world of reset key PRNGKey(1), as the official loop plays."""
    step_keys: Annotated[StepKeys, CHANGES_RESULTS] = DEFAULT_STEP_KEYS
    """How the env spends each step's key: `auto_reset` (as Craftax's auto-reset env, the
    official wrapper's inner env: the game and a game over's new world are the ones the official
    wrapper would check) or `whole` (how runs recorded before this setting played; resume such a
    run with it)."""
    env_device: EnvDevice = "cpu"
    """Where JAX steps the worlds: `cpu` (the accelerator stays the model's, and JAX claims none
    of its memory) or `default` (JAX's default device)."""

    ray: bool = False
    """Play the episodes on a Ray cluster (the one RAY_ADDRESS names, else a local one started
    for the run): workers with their own env and model each, results written here as usual."""
    ray_workers: int = Field(2, ge=1)
    """--ray: worker actors, spread over the nodes, each playing --batch-size episodes at once."""
    ray_worker_gpus: float = Field(0.0, ge=0.0)
    """--ray: GPUs each worker reserves (1 for an in-process vllm: engine per GPU)."""

    @classmethod
    def with_presets(cls, settings: dict[str, Any]) -> dict[str, Any]:
        """The settings over their protocol's choices; explicit departures are recorded."""
        generation = settings.get("generation") or {}
        explicit = (set(settings) - {"generation"}) | {f"generation.{key}" for key in generation}
        if "protocol_overrides" in explicit:
            raise UserError("protocol_overrides is recorded by the run, not a setting")
        completed, departures = apply_protocol(settings | {"generation": generation}, explicit)
        completed["protocol_overrides"] = tuple(departures)
        return completed

    agent: Annotated[str, CHANGES_RESULTS] = "zero-shot"
    """Agent strategy: `zero-shot`, `cot` (keeps its recent reasoning), `few-shot` (expert
    demonstrations first), `expert` (scripted, no model), `guided` (the model grounds the
    instruction into a goal once, the expert plays that goal), `noop` (`NOOP` at every step,
    no model: the do-nothing floor), `skills`; or an agent of your own: `package.module:Class`,
    or the name an installed package registers under the `craftext_llm.agents` entry points
    (see docs/writing-an-agent.md)."""
    cot_steps: Annotated[int, CHANGES_RESULTS] = Field(3, ge=1)
    """cot: how many of the model's last replies stay in the conversation."""
    cot_max_tokens: Annotated[int, CHANGES_RESULTS] = Field(384, ge=1)
    """cot: the kept replies' total size cap, in tokens (estimated as 4 characters each)."""
    few_shot_steps: Annotated[int, CHANGES_RESULTS] = Field(8, ge=1)
    """few-shot: demonstration steps shown before each episode."""
    demos: Annotated[str | None, CHANGES_RESULTS] = None
    """few-shot: a run directory of the `expert` agent on training goals (`one`, `combo`) with
    the same renderer, whose successful episodes give the demonstrations."""
    skill_steps: Annotated[int, CHANGES_RESULTS] = Field(60, ge=1, le=250)
    """skills: the step budget of one skill; one that has not finished by then ends
    `out_of_steps` and the model chooses again."""
    stuck_after: Annotated[int, CHANGES_RESULTS] = Field(3, ge=0)
    """skills: once the model has chosen the same skill this many times, each ending before its
    first step (it failed, or had nothing to do) and no skill taking a step in between, the
    agent asks nothing more and the episode plays NOOP to
    its end, a failure with the reason recorded (0: never; runs recorded before this setting
    never stopped)."""

    skill_demos: Annotated[int, CHANGES_RESULTS] = Field(0, ge=0)
    """skills: worked skill sequences shown before the instruction in each request: how the
    expert's planner chained skills for the difficulty's training goals, in the catalogue's
    words, never for the evaluated text's goal (no demonstration phrasing its goal or reading
    as its goal); 0: none."""

    def result_settings(self) -> dict[str, Any]:
        """As `ChoiceSettings.result_settings`; `stuck_after` only for the skills agent, so
        runs of other agents, recorded before it or not, never differ by it."""
        settings = super().result_settings()
        if self.agent != "skills":
            settings["stuck_after"] = None
        return settings

    @field_validator("agent")
    @classmethod
    def _known_agent(cls, value: str) -> str:
        # A name or the form of a path only: the class is imported, and checked, by the run.
        check_agent_name(value)
        return value

    @model_validator(mode="after")
    def _letters_where_listed(self) -> EvalConfig:
        lettered = self.choice == "loglik" and self.choice_scoring == "letters"
        if lettered and self.agent not in LETTER_AGENTS:
            raise ValueError(
                f"choice_scoring letters letters the actions of a step message; the "
                f"{self.agent} agent shows none (letters works with: "
                f"{', '.join(LETTER_AGENTS)})"
            )
        return self

    @model_validator(mode="after")
    def _few_shot_has_demos(self) -> EvalConfig:
        if self.agent == "few-shot" and self.demos is None:
            raise ValueError("the few-shot agent needs demos: the run directory of an expert run")
        if self.grounding_shots and self.agent != "guided":
            raise ValueError(
                f"grounding_shots are shown to the guided agent's grounding request; the "
                f"{self.agent} agent asks for none (leave --grounding-shots out)"
            )
        if self.skill_demos and self.agent != "skills":
            raise ValueError(
                f"skill_demos are shown to the skills agent; the {self.agent} agent chooses no "
                "skills (leave --skill-demos out)"
            )
        return self

    @model_validator(mode="after")
    def _images_where_they_go(self) -> EvalConfig:
        if self.observation == "text":
            if self.frame_history:
                raise ValueError(
                    "frame_history counts the frames of an image observation; this run's "
                    "observation is text (add --observation image or both)"
                )
            return self
        if self.agent not in IMAGE_AGENTS:
            raise ValueError(
                f"the {self.agent} agent shows a model no observation image; --observation "
                f"{self.observation} needs one of: {', '.join(IMAGE_AGENTS)}"
            )
        if self.choice == "loglik":
            raise ValueError(
                "--choice loglik scores text prompts only; with --observation "
                f"{self.observation} answer in free text or with --choice guided"
            )
        return self

    @field_validator("categories", mode="before")
    @classmethod
    def _known_categories(cls, value: Any) -> tuple[str, ...]:
        return tuple(parse_categories(value))

    @model_validator(mode="after")
    def _categories_of_the_difficulty(self) -> EvalConfig:
        check_categories(self.categories, self.difficulty)
        return self

    @field_validator("renderer")
    @classmethod
    def _known_renderer(cls, value: str) -> str:
        if value not in RENDERERS:
            raise ValueError(f"unknown renderer {value!r}; choose from {', '.join(RENDERERS)}")
        return value

    @field_validator("fallback_action")
    @classmethod
    def _known_action(cls, value: str) -> str:
        # The variant is validated after this field, so accept a name of either variant here;
        # the agent checks it against the run's variant before anything is written.
        names = set(action_names(Variant.FULL)) | set(action_names(Variant.CLASSIC))
        if value.strip().upper() not in names:
            close = difflib.get_close_matches(value.strip().upper(), sorted(names), n=1)
            hint = f"; did you mean {close[0]}?" if close else ""
            raise ValueError(f"unknown action {value!r}{hint}")
        return value

    @classmethod
    def recorded(cls, settings: dict[str, Any]) -> EvalConfig:
        """The config a run recorded (`RunResults.config`), as it was: not validated again (the
        paths it names may not exist here), and for the settings the run predates the value it
        played with (`predated_settings`, else the default)."""
        current = {**cls.predated_settings, **with_current_names(settings)}
        return cls.model_construct(**{k: v for k, v in current.items() if k in cls.model_fields})

    def env_config(self) -> EnvConfig:
        """The `EnvConfig` of the env this run's episodes are played (and replayed) in."""
        from env import EnvConfig

        return EnvConfig(
            variant=self.variant,
            max_steps=self.max_steps,
            success_rule=self.success_rule,
            world_key=OFFICIAL_WORLD_KEY if self.world_seeding == "official" else None,
            step_keys=self.step_keys,
            device=self.env_device,
        )


Settings = TypeVar("Settings", bound=ModelSettings)


def load_config_file(path: str | Path) -> dict[str, Any]:
    """Read a YAML (.yaml/.yml) or TOML (.toml) config file into a dict."""
    file = Path(path)
    try:
        text = file.read_text(encoding="utf-8")
    except OSError as err:
        raise UserError(f"cannot read config file {file}: {err.strerror}") from err
    except UnicodeDecodeError as err:
        raise UserError(f"config file {file} is not UTF-8 text") from err
    try:
        if file.suffix == ".toml":
            data = tomllib.loads(text)
        elif file.suffix in (".yaml", ".yml"):
            data = yaml.safe_load(text) or {}
        else:
            raise UserError(f"config file {file} must end in .toml, .yaml or .yml")
    except (tomllib.TOMLDecodeError, yaml.YAMLError) as err:
        first_line = str(err).strip().splitlines()[0]
        raise UserError(f"config file {file} does not parse: {first_line}") from err
    if not isinstance(data, dict):
        raise UserError(f"config file {file} must hold a table of settings")
    return data


def build_settings(
    cls: type[Settings],
    base: dict[str, Any] | None = None,
    overrides: dict[str, Any] | None = None,
) -> Settings:
    """Settings of type `cls` from file settings (`base`) overridden by flags.

    Nested tables (`generation`, `backend_options`, ...) are merged key by key, so a flag
    changes one generation setting without dropping the file's others.
    """
    current = with_current_names(dict(base or {}), cls.renamed_settings)
    merged = _merge(current, overrides or {}, cls)
    unknown = sorted(set(merged) - set(cls.model_fields))
    if not unknown:
        merged = cls.with_presets(merged)
    if unknown:
        close = difflib.get_close_matches(unknown[0], list(cls.model_fields), n=1)
        hint = f" (did you mean {close[0]!r}?)" if close else ""
        raise UserError(f"unknown setting {unknown[0]!r}{hint}")
    try:
        return cls(**merged)
    except ValidationError as err:
        raise UserError(f"invalid setting {validation_message(err)}") from err


def _merge(data: dict[str, Any], overrides: dict[str, Any], cls: type[BaseModel]) -> dict[str, Any]:
    for key, value in overrides.items():
        field = cls.model_fields.get(key)
        table = field is not None and _is_table(field.annotation)
        if table and key in data and not isinstance(data[key], dict):
            raise UserError(f"setting {key!r} must be a table of settings, not {data[key]!r}")
        if table and isinstance(value, dict):
            data[key] = {**data.get(key, {}), **value}
        else:
            data[key] = value
    for key, value in data.items():
        field = cls.model_fields.get(key)
        if field is not None and _is_table(field.annotation) and not isinstance(value, dict):
            raise UserError(f"setting {key!r} must be a table of settings, not {value!r}")
    return data


def _is_table(annotation: Any) -> bool:
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        return True
    return getattr(annotation, "__origin__", None) is dict


def validation_message(err: ValidationError) -> str:
    """One line naming each invalid setting and why."""
    parts = []
    for problem in err.errors():
        where = ".".join(str(p) for p in problem["loc"]) or "config"
        message = problem["msg"].removeprefix("Value error, ")
        parts.append(f"{where}: {message}")
    return "; ".join(parts)


def build_config(
    base: dict[str, Any] | None = None, overrides: dict[str, Any] | None = None
) -> EvalConfig:
    """An `EvalConfig` from file settings overridden by flags (`build_settings` for eval)."""
    return build_settings(EvalConfig, base, overrides)
