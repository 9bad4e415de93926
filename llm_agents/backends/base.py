"""The one interface every LLM backend implements.

A backend takes a batch of chat conversations and returns one `ModelOutput` per conversation,
in order. Backends never raise for a single bad generation: they return an output with
`finish_reason="error"` and the error text, so one failure never loses the rest of a batch.
"""

from __future__ import annotations

import abc
import base64
import difflib
import hashlib
import inspect
import io
import json
import logging
from collections.abc import Callable, Sequence, Sized
from pathlib import Path
from typing import Annotated, Any, ClassVar, Literal, NamedTuple, Self

import numpy as np
from jinja2 import TemplateError
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator

from env.errors import UserError
from llm_agents.backends.embedded import NAMED_MODELS, named_model_dir
from llm_agents.backends.endpoints import EndpointStats
from llm_agents.backends.hub import GGUF_SUFFIX, HubId, HubModel, fetch, parse_hub_id

logger = logging.getLogger(__name__)


Role = Literal["system", "user", "assistant"]
FinishReason = Literal["stop", "length", "choice", "error"]
#: How an answer is picked from a `ChoiceSet`: `loglik` ranks every option by its full
#: log-likelihood after the prompt; `guided` decodes greedily, constrained to the options.
#: The two can pick different options from the same prompt, so runs compare only under one rule.
ChoiceRule = Literal["loglik", "guided"]
#: How `loglik` turns an option's log-probabilities into its score (`choice_score`).
ChoiceScoring = Literal["sum", "mean", "bytes", "pmi", "letters"]
#: The user message of PMI's content-free prompt (Zhao et al. 2021's "N/A"): the options'
#: prior under the conversation's system message alone.
CONTENT_FREE_TEXT = "N/A"


class ImagePart(BaseModel):
    """One image of a message, as the PNG file every backend is handed."""

    model_config = ConfigDict(frozen=True)

    png_base64: str
    """The image as a PNG file, base64-encoded (what a data URL carries)."""

    @classmethod
    def from_frame(cls, frame: np.ndarray) -> ImagePart:
        """The PNG of a uint8 (height, width, 3) RGB frame, lossless."""
        from PIL import Image

        buffer = io.BytesIO()
        Image.fromarray(np.ascontiguousarray(frame, dtype=np.uint8), "RGB").save(buffer, "PNG")
        return cls(png_base64=base64.b64encode(buffer.getvalue()).decode("ascii"))

    @property
    def png(self) -> bytes:
        return base64.b64decode(self.png_base64)

    @property
    def data_url(self) -> str:
        """The image as an OpenAI-style `data:` URL."""
        return f"data:image/png;base64,{self.png_base64}"

    @property
    def sha256(self) -> str:
        return hashlib.sha256(self.png).hexdigest()

    def pil(self) -> Any:
        """The image as a PIL RGB image (what processors of image-text models take)."""
        from PIL import Image

        return Image.open(io.BytesIO(self.png)).convert("RGB")

    def array(self) -> np.ndarray:
        """The decoded uint8 (height, width, 3) pixels."""
        return np.asarray(self.pil(), dtype=np.uint8)


class ChatMessage(BaseModel):
    """One message of a chat conversation."""

    model_config = ConfigDict(frozen=True)

    role: Role
    """Who speaks: `system`, `user` or `assistant`."""
    content: str
    """The message text."""
    images: tuple[ImagePart, ...] = ()
    """Images sent with the text, shown before it, oldest first (`--observation image|both`)."""

    def key_data(self) -> dict[str, Any]:
        """The message as data for digests: a text message as it was before images existed,
        so the digests of text-only requests (cache keys) never change."""
        return self.model_dump(exclude=set() if self.images else {"images"})


def openai_message(message: ChatMessage) -> dict[str, Any]:
    """A message in the OpenAI chat format: its text alone, or with images, content parts (each
    image a PNG `data:` URL, then the text), as OpenAI-compatible servers and vLLM's `chat`
    take them."""
    if not message.images:
        return {"role": message.role, "content": message.content}
    parts: list[dict[str, Any]] = [
        {"type": "image_url", "image_url": {"url": image.data_url}} for image in message.images
    ]
    parts.append({"type": "text", "text": message.content})
    return {"role": message.role, "content": parts}


Conversation = Sequence[ChatMessage]


def carries_images(conversations: Sequence[Conversation]) -> bool:
    """Whether any message of the conversations has an image."""
    return any(message.images for conversation in conversations for message in conversation)


class ChoiceSet(BaseModel):
    """The options an answer must be one of, and the rule that picks it."""

    model_config = ConfigDict(frozen=True)

    options: tuple[str, ...] = Field(min_length=1)
    """The candidate answers, e.g. the action names."""
    rule: ChoiceRule
    """`loglik`: the option with the highest log-likelihood; `guided`: constrained greedy decoding."""
    scoring: ChoiceScoring = "sum"
    """`loglik` only: how an option's log-probabilities make its score (`choice_score`)."""


class OutputSchema(BaseModel):
    """A JSON schema every answer to a request must follow: the one structured-output spec each
    backend hands its engine in its own form (vLLM's structured outputs, an OpenAI-compatible
    server's `response_format`, hf's grammar-constrained decoding, the mock's check)."""

    model_config = ConfigDict(frozen=True)

    name: str = Field(pattern=r"^[A-Za-z0-9_-]{1,64}$")
    """What the answers are (`goal_reading`, `action`): the name `response_format` carries."""
    json_schema: str
    """The schema as compact JSON text: hashable, so requests group by it. Keys keep the order
    they were built in, since an object's properties are decoded in the order listed."""

    @classmethod
    def of(cls, name: str, schema: dict[str, Any]) -> OutputSchema:
        """The spec of a schema given as data."""
        return cls(name=name, json_schema=json.dumps(schema, separators=(",", ":")))

    def as_data(self) -> dict[str, Any]:
        """The schema as data."""
        loaded: dict[str, Any] = json.loads(self.json_schema)
        return loaded

    @property
    def digest(self) -> str:
        """SHA-256 of the canonical schema: what a run records of the spec it asked under."""
        return hashlib.sha256(self.json_schema.encode()).hexdigest()


class OptionLoglik(NamedTuple):
    """One option's log-probabilities after one prompt, what every `loglik` rule is made of."""

    option: float
    """Summed log-probability of the option's own tokens."""
    end: float
    """Log-probability of the end-of-turn token after the option: that the answer stops there."""


def choice_score(
    scoring: ChoiceScoring,
    option: str,
    tokens: int,
    score: OptionLoglik,
    content_free: OptionLoglik | None = None,
) -> float:
    """An option's score under a `loglik` rule.

    `sum`: its tokens' summed log-probability, without the end of turn (the rule before the
    others existed, kept so older runs resume as they played: it favours the shortest name, and
    a name that is a token prefix of another never scores lower). The others count the end of
    turn, so a prefix pays for stopping early: `mean` per token (the option's `tokens` and the
    end), `bytes` per UTF-8 byte of the option (lm-evaluation-harness's `acc_norm`), `pmi` minus
    the same after the content-free prompt (`content_free`: the option's prior).

    `letters`: the options are one-character labels of a list the prompt shows
    (`agents.lettered`), each one token, scored by that token's log-probability, the next-token
    distribution at the end of the prompt. With every option one token long, no option is
    another's prefix and none pays for more tokens, so the end of turn adds nothing but noise
    and is left out (`needs_end`); what a label's own prior adds (models favour `A`) the agent
    spreads by permuting the list per step.
    """
    whole = score.option + score.end
    if scoring in ("sum", "letters"):
        return score.option
    if scoring == "mean":
        return whole / (tokens + 1)
    if scoring == "bytes":
        return whole / len(option.encode())
    if content_free is None:
        raise ValueError("pmi needs the options' scores after the content-free prompt")
    return whole - (content_free.option + content_free.end)


def needs_end(scoring: ChoiceScoring) -> bool:
    """Whether `scoring` reads the end-of-turn token after an option (`OptionLoglik.end`): a
    backend that scores only the option's own tokens under the others (hf: one pass over the
    prompt for one-token options) gives the same scores."""
    return scoring not in ("sum", "letters")


def content_free_conversation(conversation: Conversation) -> list[ChatMessage]:
    """PMI's content-free prompt for `conversation`: its system messages, then a user message
    that says nothing (`CONTENT_FREE_TEXT`). An agent's system message is the same at every
    step, so a run asks for one such prompt's scores (`ContentFreeScores` keeps them)."""
    system = [message for message in conversation if message.role == "system"]
    return [*system, ChatMessage(role="user", content=CONTENT_FREE_TEXT)]


#: An answer no chat template changes, rendered to find what closes an assistant turn.
_ANSWER_MARK = "ANSWER_MARK"


def end_of_turn_id(tokenizer: Any) -> int:
    """The token that closes an assistant turn under a transformers `tokenizer`'s chat template
    (`<|im_end|>` for Qwen and SmolLM2): what follows an answer in a rendered conversation, if
    that is a special token, else the tokenizer's end-of-sequence token. `loglik` scores it
    after each option: that the answer ends there."""
    try:
        text = str(
            tokenizer.apply_chat_template(
                [{"role": "user", "content": "?"}, {"role": "assistant", "content": _ANSWER_MARK}],
                tokenize=False,
            )
        )
    except (TemplateError, ValueError):
        # A template that refuses this conversation: the eos token below.
        text = ""
    after = text.partition(_ANSWER_MARK)[2]
    ids = list(tokenizer(after, add_special_tokens=False).input_ids) if after else []
    if ids and ids[0] in set(tokenizer.all_special_ids):
        return int(ids[0])
    if tokenizer.eos_token_id is None:
        raise UserError("the model's tokenizer has no end-of-turn token for loglik choices")
    return int(tokenizer.eos_token_id)


class ContentFreeScores:
    """The options' scores after content-free prompts, computed once per distinct prompt and
    option list and kept for the backend's life (a run)."""

    def __init__(self) -> None:
        self._kept: dict[tuple[tuple[int, ...], tuple[str, ...]], list[OptionLoglik]] = {}

    def rows(
        self,
        prompts: Sequence[Sequence[int]],
        options: Sequence[str],
        score: Callable[[list[list[int]]], list[list[OptionLoglik]]],
    ) -> list[list[OptionLoglik]]:
        """Each content-free prompt's (token ids) row of option scores; `score` computes the
        rows of prompts not seen before, all in one call."""
        keys = [(tuple(prompt), tuple(options)) for prompt in prompts]
        missing = list(dict.fromkeys(key for key in keys if key not in self._kept))
        if missing:
            rows = score([list(prompt) for prompt, _ in missing])
            self._kept.update(zip(missing, rows, strict=True))
        return [self._kept[key] for key in keys]


class _ChangesResults:
    """See `CHANGES_RESULTS`."""

    def __repr__(self) -> str:
        return "CHANGES_RESULTS"


#: Settings metadata, `name: Annotated[T, CHANGES_RESULTS]`: the setting can change what a run
#: answers or scores, so a run resumed in the same directory must match it. An unmarked setting
#: changes only speed, waiting, logging, or where things are read (paths, whose contents are
#: hashed instead) or written.
CHANGES_RESULTS = _ChangesResults()


def result_fields(settings: type[BaseModel]) -> tuple[str, ...]:
    """The fields of a settings class marked `CHANGES_RESULTS`, in declaration order."""
    return tuple(
        name
        for name, field in settings.model_fields.items()
        if any(mark is CHANGES_RESULTS for mark in field.metadata)
    )


def result_values(settings: BaseModel) -> dict[str, Any]:
    """The marked settings' values as JSON data, nested settings reduced to their own marked
    ones: the part of a run's identity its settings give."""
    values = {}
    for name in result_fields(type(settings)):
        value = getattr(settings, name)
        values[name] = (
            result_values(value)
            if isinstance(value, BaseModel)
            else settings.model_dump(mode="json", include={name})[name]
        )
    return values


class GenerateConfig(BaseModel):
    """Generation parameters shared by all backends."""

    model_config = ConfigDict(extra="forbid", use_attribute_docstrings=True)

    max_tokens: Annotated[int, CHANGES_RESULTS] = Field(256, ge=1)
    """Most tokens generated for the answer (thinking included unless `reasoning_budget` is set)."""
    temperature: Annotated[float, CHANGES_RESULTS] = Field(0.0, ge=0.0)
    """Sampling temperature; 0 means greedy decoding."""
    top_p: Annotated[float, CHANGES_RESULTS] = Field(1.0, gt=0.0, le=1.0)
    """Nucleus sampling mass."""
    sampling_seed: Annotated[int | None, CHANGES_RESULTS] = 0
    """Sampling seed where the backend supports one; None leaves it to the backend."""
    stop: Annotated[list[str], CHANGES_RESULTS] = Field(default_factory=list)
    """Strings that end generation."""
    reasoning_budget: Annotated[int | None, CHANGES_RESULTS] = Field(None, ge=1)
    """Tokens a reasoning model may spend thinking before it must answer; None: no separate budget."""
    timeout_s: float = Field(120.0, gt=0)
    """Seconds one request may take before it counts as failed (HTTP backends)."""
    max_concurrency: int = Field(16, ge=1)
    """Requests in flight at once (HTTP backends)."""
    max_retries: int = Field(6, ge=0)
    """Retries of a transient failure (HTTP backends), after the first attempt."""


#: Generation parameters that shape the answer itself.
ANSWER_FIELDS = frozenset(result_fields(GenerateConfig))
#: Generation parameters that cannot change an answer: they only bound waiting and retrying.
TRANSPORT_FIELDS = frozenset(GenerateConfig.model_fields) - ANSWER_FIELDS
#: Longest a probe request may take: a dead server must fail the start within seconds.
PROBE_TIMEOUT_S = 10.0
#: Longest error text an output keeps; server bodies and tracebacks can be megabytes.
ERROR_CHARS = 1000


class ModelOutput(BaseModel):
    """What a backend returns for one conversation."""

    text: str
    """The answer, with any reasoning removed."""
    reasoning: str | None = None
    """The model's reasoning (thinking) text, kept for logs; never parsed as the answer."""
    prompt_tokens: int = 0
    """Tokens in the prompt."""
    computed_prompt_tokens: int | None = None
    """Prompt tokens the backend computed for this answer, the rest taken from its prefix
    cache (0 for an answer from the response cache); None where the backend does not say."""
    completion_tokens: int = 0
    """Tokens generated, reasoning included."""
    latency_s: float = 0.0
    """Wall time spent on this conversation (for a batch: the batch's time)."""
    finish_reason: FinishReason = "stop"
    """`stop`: natural end; `length`: hit max_tokens; `choice`: picked from the given choices; `error`: failed."""
    followups: int = 0
    """Extra requests made for this answer (e.g. an "answer only" follow-up after truncated thinking)."""
    cached: bool = False
    """True when the answer came from the response cache: no request was made now; tokens and followups are the original generation's."""
    error: str | None = None
    """Why the generation failed (one line, secrets removed), when finish_reason is `error`."""

    @field_validator("error")
    @classmethod
    def _one_line(cls, error: str | None) -> str | None:
        # Every backend's error lands in one line of steps.jsonl and of the run's summary; a
        # backend redacts its own secrets before this (only it knows them).
        if error is None:
            return None
        line = " ".join(error.split())
        return line if len(line) <= ERROR_CHARS else line[:ERROR_CHARS] + "..."


def scored_choices(
    choices: ChoiceSet,
    candidates: Sequence[Sized],
    scores: Sequence[Sequence[OptionLoglik]],
    content_free: Sequence[Sequence[OptionLoglik]] | None = None,
) -> list[list[float]]:
    """Each prompt's row of option scores under `choices.scoring` (`choice_score`); the one
    place a backend's log-probabilities become scores, so every backend ranks alike.
    `candidates`: each option's tokens; `content_free`: each prompt's row after its content-free
    prompt (`pmi` only)."""
    priors = content_free if content_free is not None else [None] * len(scores)
    return [
        [
            choice_score(
                choices.scoring,
                option,
                len(ids),
                score,
                prior[index] if prior is not None else None,
            )
            for index, (option, ids, score) in enumerate(
                zip(choices.options, candidates, row, strict=True)
            )
        ]
        for row, prior in zip(scores, priors, strict=True)
    ]


def ranked_choices(
    choices: ChoiceSet,
    prompts: Sequence[Sized],
    candidates: Sequence[Sized],
    scores: Sequence[Sequence[OptionLoglik]],
    latency_s: float,
    content_free: Sequence[Sequence[OptionLoglik]] | None = None,
) -> list[ModelOutput]:
    """One `choice` output per prompt: the option that scores highest in that prompt's row
    under `choices.scoring` (`scored_choices`)."""
    options = choices.options
    outputs = []
    for prompt, row in zip(
        prompts, scored_choices(choices, candidates, scores, content_free), strict=True
    ):
        best = max(range(len(options)), key=row.__getitem__)
        outputs.append(
            ModelOutput(
                text=options[best],
                prompt_tokens=len(prompt),
                completion_tokens=len(candidates[best]),
                latency_s=latency_s,
                finish_reason="choice",
            )
        )
    return outputs


#: The backends that load hub ids (`hub.py`): the others name models of their own servers.
HUB_BACKENDS = frozenset({"hf", "vllm"})
#: The `ModelAPI.info` key of the hub commit a hub-id model was loaded at.
HUB_REVISION_KEY = "revision"


def local_model_path(backend: str, model_name: str) -> Path | None:
    """The local folder (or GGUF file) a model name means, or None for a hub id (`hub_id_of`).

    A name of `embedded.NAMED_MODELS` (`smollm2-135m`, the embedded default, and the
    Qwen2.5-Coder models) is fetched and converted on first use; an existing
    folder is itself, and so is an existing `.gguf` file; a name written as a path (starting
    with `.`, `/` or `~`) that is neither is a `UserError` rather than a hub lookup.
    """
    if model_name in NAMED_MODELS:
        return named_model_dir(model_name)
    path = Path(model_name).expanduser()
    if path.is_dir() or (path.is_file() and path.suffix == GGUF_SUFFIX):
        return path
    if model_name.startswith((".", "/", "~")):
        raise UserError(f"{backend} model folder {model_name!r} does not exist")
    if _hub_id(backend, model_name) is None:
        raise UserError(
            f"{backend} model {model_name!r} is no named model, local folder or hub id "
            f"(ORG/NAME, or ORG/NAME:FILE{GGUF_SUFFIX})"
        )
    return None


def hub_id_of(backend: str, model_name: str) -> HubId | None:
    """The hub id a backend's model name spells (downloaded on first use, `hub.fetch`), or None
    for a named model, a local path, or a backend that loads no hub ids. Touches no network."""
    if backend not in HUB_BACKENDS or model_name in NAMED_MODELS:
        return None
    path = Path(model_name).expanduser()
    if path.is_dir() or path.is_file():
        return None
    return _hub_id(backend, model_name)


def _hub_id(backend: str, model_name: str) -> HubId | None:
    """`parse_hub_id`, refusing a misspelled named model rather than asking the hub for it."""
    hub_id = parse_hub_id(model_name)
    if hub_id is not None and "/" not in hub_id.repo_id:
        close = difflib.get_close_matches(hub_id.repo_id, NAMED_MODELS, n=1, cutoff=0.8)
        if close:
            raise UserError(
                f"{backend}:{model_name} is no named model; did you mean {backend}:{close[0]}? "
                "(a hub id is ORG/NAME)"
            )
    return hub_id


class ModelLocation(NamedTuple):
    """Where a hf or vllm model's files are, and the hub commit they are of."""

    path: Path
    """A model folder, or a GGUF file."""
    hub_model: HubModel | None
    """The hub id and commit it was resolved to; None for a named model or a local path."""


def locate_model(backend: str, model_name: str, revision: str | None) -> ModelLocation:
    """The local files of a model name: a named model or local path as `local_model_path`
    finds it, a hub id downloaded at `revision` into the hub cache on first use (`hub.fetch`).
    A revision is refused for anything but a hub id."""
    path = local_model_path(backend, model_name)
    if path is not None:
        if revision is not None:
            raise UserError(
                f"revision={revision!r} pins a hub id's commit; {backend}:{model_name} is no "
                "hub id (leave the revision option out)"
            )
        return ModelLocation(path, None)
    hub_id = _hub_id(backend, model_name)
    assert hub_id is not None  # local_model_path refused every other name
    fetched = fetch(hub_id, revision)
    assert fetched.path is not None
    return ModelLocation(fetched.path, fetched)


def hub_info(location: ModelLocation) -> dict[str, str]:
    """What `ModelAPI.info` records of a hub model: its repository and the commit it played
    (`HUB_REVISION_KEY`); nothing for a named model or a local path."""
    model = location.hub_model
    if model is None:
        return {}
    return {"hub_repo": model.hub_id.spec, HUB_REVISION_KEY: model.commit}


def bad_options(backend: str, err: ValidationError) -> UserError:
    """One line naming each option a backend's options model refused, and why."""
    problems = "; ".join(
        f"{'.'.join(str(part) for part in problem['loc']) or 'options'}: {problem['msg']}"
        for problem in err.errors()
    )
    return UserError(f"bad option for the {backend} backend: {problems}")


class ModelAPI(abc.ABC):
    """Base class of every backend. Subclasses are registered in `llm_agents.backends`.

    Each backend declares what it honours, so that nothing a user sets is silently ignored:
    `options_model` (or, without one, the keyword-only parameters of `__init__`) lists the backend
    options `get_model` accepts, and `honoured_config` the `GenerateConfig` fields it reads.
    `check_settings` refuses an unknown option and an answer-shaping field the backend would
    ignore, and warns about an ignored transport field (a timeout cannot change an answer).
    """

    #: The registry name, e.g. "hf"; set by each subclass.
    backend_name: str = ""
    #: The pydantic model of this backend's options, when it has one.
    options_model: ClassVar[type[BaseModel] | None] = None
    #: The `GenerateConfig` fields this backend reads; any other must stay at its default.
    honoured_config: ClassVar[frozenset[str]] = ANSWER_FIELDS - {"reasoning_budget"}
    #: The choice rules `generate` accepts; set by each subclass.
    choice_rules: ClassVar[frozenset[ChoiceRule]] = frozenset()
    #: Why a rule outside `choice_rules` is missing, told to the user who asks for it.
    choice_rule_gaps: ClassVar[dict[ChoiceRule, str]] = {}
    #: How the runner should feed the backend. True: many concurrent one-conversation
    #: `generate` calls (up to `max_concurrency`, from threads), for servers that batch requests
    #: themselves. False: one call at a time with every conversation that is ready, for
    #: in-process engines that batch what they are given.
    concurrent_requests: bool = False

    def __init__(self, model_name: str, config: GenerateConfig | None = None, **options: Any):
        self.model_name = model_name
        self.config = config or GenerateConfig()
        self.options = options

    def generate(
        self,
        conversations: Sequence[Conversation],
        choices: ChoiceSet | None = None,
        schema: OutputSchema | None = None,
    ) -> list[ModelOutput]:
        """Answer every conversation; with `choices`, each answer is exactly one of its options,
        picked by its rule (a rule the backend lacks raises `UserError`, checked here for every
        backend before it answers); with `schema`, each answer is JSON that follows it, decoded
        under the backend's structured outputs (a backend without them raises `UserError`)."""
        if choices is not None and schema is not None:
            raise ValueError("a request holds its answer to options or to a schema, not both")
        if choices is not None:
            self.check_choice_rule(choices.rule)
        if schema is not None:
            return self._generate_structured(conversations, schema)
        return self._generate(conversations, choices)

    @abc.abstractmethod
    def _generate(
        self, conversations: Sequence[Conversation], choices: ChoiceSet | None
    ) -> list[ModelOutput]:
        """`generate` for this backend, `choices`' rule already checked."""

    def _generate_structured(
        self, conversations: Sequence[Conversation], schema: OutputSchema
    ) -> list[ModelOutput]:
        """`generate` under `schema`; a backend with structured outputs overrides this."""
        raise UserError(self.no_structured_outputs())

    def no_structured_outputs(self) -> str:
        """The one line that refuses a schema to this backend."""
        return (
            f"the {self.backend_name} backend cannot hold answers to a JSON schema "
            "(--structured-output needs the hf, vllm, openai or mock backend)"
        )

    def check_schema(self, schema: OutputSchema) -> None:
        """Raise `UserError` (one line naming the backend and what to install or change) unless
        answers can be held to `schema`; called before a run writes anything. The default
        refuses: only a backend that overrides `_generate_structured` takes schemas."""
        if type(self)._generate_structured is ModelAPI._generate_structured:
            raise UserError(self.no_structured_outputs())

    def check_choice_rule(self, rule: ChoiceRule) -> None:
        """Raise `UserError` unless this backend can pick answers by `rule`."""
        if rule in self.choice_rules:
            return
        supported = ", ".join(sorted(self.choice_rules)) or "none"
        why = self.choice_rule_gaps.get(rule)
        raise UserError(
            f"the {self.backend_name} backend cannot choose by {rule!r} (it supports: {supported})"
            + (f": {why}" if why else "")
        )

    @classmethod
    def accepted_options(cls) -> list[str]:
        """Names of the backend options (`get_model` keyword arguments) this backend accepts."""
        if cls.options_model is not None:
            return list(cls.options_model.model_fields)
        parameters = inspect.signature(cls.__init__).parameters.values()
        return [p.name for p in parameters if p.kind is inspect.Parameter.KEYWORD_ONLY]

    @classmethod
    def check_settings(cls, config: GenerateConfig | None, options: dict[str, Any]) -> None:
        """Refuse what this backend would silently ignore; warn where results cannot differ.

        An unknown option is a `UserError` naming it, with a did-you-mean and the accepted ones.
        A `GenerateConfig` field the backend does not read, set away from its default, is refused
        when it shapes answers (the run would not be what was asked for) and logged as a warning
        when it only bounds waiting (`TRANSPORT_FIELDS`).
        """
        accepted = cls.accepted_options()
        for name in options:
            if name not in accepted:
                close = difflib.get_close_matches(name, accepted, n=1)
                hint = f"; did you mean {close[0]!r}?" if close else ""
                listed = ", ".join(accepted) if accepted else "none"
                raise UserError(
                    f"the {cls.backend_name} backend has no option {name!r}{hint} (accepted: {listed})"
                )
        if config is None:
            return
        defaults = GenerateConfig()
        ignored = [
            field
            for field in GenerateConfig.model_fields
            if field not in cls.honoured_config
            and getattr(config, field) != getattr(defaults, field)
        ]
        refused = [field for field in ignored if field not in TRANSPORT_FIELDS]
        if refused:
            raise UserError(
                f"the {cls.backend_name} backend cannot honour {', '.join(refused)}; leave "
                f"{'it' if len(refused) == 1 else 'them'} unset (it honours: "
                f"{', '.join(sorted(cls.honoured_config)) or 'no generation settings'})"
            )
        for field in ignored:
            logger.warning(
                "the %s backend ignores %s=%r (no answer depends on it, so the run goes on)",
                cls.backend_name,
                field,
                getattr(config, field),
            )

    def check_images(self) -> None:
        """Raise `UserError` unless this backend and model take images (`--observation image`
        or `both`); called before anything runs."""
        raise UserError(
            f"the {self.backend_name} backend takes no images; use --observation text, or an "
            "image-text model through hf, vllm or an openai-compatible server"
        )

    def probe(self) -> None:
        """Check that the model answers at all, cheaply, before a run starts.

        The default generates a one-token answer with no retries and a short timeout, so that a
        backend that cannot answer fails in seconds with a `UserError` naming the cause.
        Backends with a cheaper check override this.
        """
        self.answers_quickly(
            [ChatMessage(role="user", content="Say OK.")], "does not answer a one-token request"
        )

    def answers_quickly(self, conversation: Conversation, failure: str) -> None:
        """Generate a one-token answer with no retries and a short timeout; a `UserError`
        saying the model `failure` where it fails (probes)."""
        quick = self.config.model_copy(
            update={
                "max_tokens": 1,
                "max_retries": 0,
                "reasoning_budget": None,
                "timeout_s": min(self.config.timeout_s, PROBE_TIMEOUT_S),
            }
        )
        saved, self.config = self.config, quick
        try:
            [output] = self.generate([conversation])
        finally:
            self.config = saved
        if output.finish_reason == "error":
            raise UserError(
                f"{self.backend_name}:{self.model_name} {failure}: "
                f"{output.error or 'no error given'}"
            )

    def cannot_sample(self) -> str | None:
        """Why this backend cannot draw different answers to one prompt (`plan --candidates`),
        or None when it can: with a temperature above 0, each sampling seed draws anew."""
        if {"temperature", "sampling_seed"} <= self.honoured_config:
            return None
        return f"the {self.backend_name} backend does not honour temperature and sampling_seed"

    def info(self) -> dict[str, str]:
        """Backend, model and library versions, recorded in results."""
        return {"backend": self.backend_name, "model": self.model_name}

    def endpoint_stats(self) -> list[EndpointStats]:
        """Per-server counts of a backend that talks to servers (recorded in results); none here."""
        return []

    def close(self) -> None:
        """Release resources (processes, GPU memory, connections)."""
        return None

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
