"""ZeroShotAgent with mock backends: prompts per slot, parsing and fallback, history outcomes."""

import hashlib
import json
from collections.abc import Sequence

import pytest
from agent_steps import play_step
from pydantic import BaseModel, Field

from env.errors import UserError
from env.variant import Variant
from llm_agents.agents.strategies.zero_shot import ZeroShotAgent, describe_outcome
from llm_agents.agents.types import Decision, EpisodeStart, messages_hash
from llm_agents.backends import get_model
from llm_agents.backends.base import ChatMessage, ChoiceRule
from llm_agents.backends.mock import MockModel


class FakePosition(BaseModel):
    x: int
    y: int


class FakeInventory(BaseModel):
    materials: dict[str, int] = Field(default_factory=dict)
    tools: list[str] = Field(default_factory=list)


class FakeVitals(BaseModel):
    health: float = 9.0


class FakeObservation(BaseModel):
    """Stands in for textualizer's Observation, with the fields outcomes are read from."""

    position: FakePosition = FakePosition(x=10, y=10)
    floor: int | None = None
    inventory: FakeInventory = FakeInventory()
    achievements: list[str] = Field(default_factory=list)
    vitals: FakeVitals = FakeVitals()
    label: str = "grass around"


def fake(
    x: int = 10,
    y: int = 10,
    materials: dict[str, int] | None = None,
    tools: tuple[str, ...] = (),
    achievements: tuple[str, ...] = (),
    health: float = 9,
    floor: int | None = None,
) -> FakeObservation:
    return FakeObservation(
        position=FakePosition(x=x, y=y),
        floor=floor,
        inventory=FakeInventory(materials=materials or {}, tools=list(tools)),
        achievements=list(achievements),
        vitals=FakeVitals(health=health),
    )


def render_fake(observation: FakeObservation) -> str:
    return (
        f"You stand at ({observation.position.x}, {observation.position.y}); {observation.label}."
    )


def make_agent(**options: object) -> ZeroShotAgent:
    return ZeroShotAgent(Variant.CLASSIC, renderer=render_fake, **options)  # type: ignore[arg-type]


def user_text(conversation: Sequence[ChatMessage]) -> str:
    return conversation[-1].content


def test_each_slot_gets_its_own_step_message_under_a_shared_system_prompt() -> None:
    model = get_model("mock:cycle:LEFT|DO|MAKE_WOOD_PICKAXE")
    assert isinstance(model, MockModel)
    agent = make_agent()
    for slot in range(3):
        agent.start_episode(slot, EpisodeStart(f"goal number {slot}"))
    observations = [FakeObservation(label=f"slot {slot}") for slot in range(3)]
    first = play_step(agent, model, [0, 1, 2], observations)
    second = play_step(agent, model, [0, 1, 2], observations)
    assert [d.name for d in first + second] == ["LEFT", "DO", "MAKE_WOOD_PICKAXE"] * 2
    assert [d.action for d in first] == [1, 5, 11]
    assert len(model.requests) == 6
    systems = {conversation[0].content for conversation, _ in model.requests}
    assert len(systems) == 1 and "MAKE_WOOD_PICKAXE" in systems.pop()
    for slot, (conversation, choices) in enumerate(model.requests[:3]):
        assert [m.role for m in conversation] == ["system", "user"]
        assert f"goal number {slot}" in user_text(conversation)
        assert f"slot {slot}" in user_text(conversation)
        assert choices is None


def test_unparseable_answers_fall_back_and_are_flagged() -> None:
    def answer(conversation: Sequence[ChatMessage]) -> str:
        return "I refuse." if "bad" in user_text(conversation) else "<think>x</think>ACTION: SLEEP"

    agent = make_agent(fallback_action="do")
    agent.start_episode(0, EpisodeStart("bad slot"))
    agent.start_episode(1, EpisodeStart("good slot"))
    decisions = play_step(agent, MockModel(outputs=answer), [0, 1], [FakeObservation()] * 2)
    bad, good = decisions
    assert (bad.name, bad.action, bad.fallback_used, bad.parse.stage) == ("DO", 5, True, "invalid")
    assert (good.name, good.fallback_used, good.parse.stage) == ("SLEEP", False, "field")
    assert good.output.text == "<think>x</think>ACTION: SLEEP"


@pytest.mark.parametrize("report", [True, False])
def test_an_invalid_answer_is_reported_on_the_next_step_when_asked(report: bool) -> None:
    script = iter(["I refuse.", "ACTION: LEFT", "ACTION: LEFT"])
    model = MockModel(outputs=lambda conversation: next(script))
    agent = make_agent(report_invalid=report)
    agent.start_episode(0, EpisodeStart("collect wood"))
    for observation in (fake(x=10), fake(x=10), fake(x=9)):
        play_step(agent, model, [0], [observation])
    second, third = (user_text(request[0]) for request in model.requests[1:])
    reported = "step 0: NOOP (your answer named no valid action; NOOP was played)"
    assert (reported in second) is report
    assert "step 0: NOOP" in second
    # A valid answer is shown as before, whichever the setting.
    assert "step 1: LEFT: moved west" in third


def test_echoed_prompt_is_not_taken_as_an_answer() -> None:
    agent = make_agent()
    agent.start_episode(0, EpisodeStart("place a table near the water"))
    decision = play_step(
        agent,
        MockModel(outputs=lambda conversation: user_text(conversation)),
        [0],
        [FakeObservation()],
    )[0]
    assert decision.fallback_used and decision.name == "NOOP"


def test_prompt_hash_is_sha256_of_the_messages_sent() -> None:
    model = MockModel(outputs=["NOOP"])
    agent = make_agent()
    agent.start_episode(0, EpisodeStart("eat a cow"))
    agent.start_episode(1, EpisodeStart("eat a cow"))
    same = play_step(agent, model, [0, 1], [FakeObservation(), FakeObservation()])
    sent = model.requests[0][0]
    payload = json.dumps([[m.role, m.content] for m in sent], ensure_ascii=False)
    assert same[0].prompt_hash == hashlib.sha256(payload.encode()).hexdigest()
    assert same[0].prompt_hash == same[1].prompt_hash
    other = play_step(agent, model, [0], [FakeObservation(label="a cow 1 north")])[0]
    assert other.prompt_hash != same[0].prompt_hash
    assert other.observation_text == "You stand at (10, 10); a cow 1 north."


@pytest.mark.parametrize("count", [0, 1, 3])
def test_prompt_hash_is_of_the_json_of_the_messages_whatever_their_text(count: int) -> None:
    # The hash encodes a message at a time (the shared system prompt once): it must still be
    # the hash of the whole list's JSON, escapes and non-ASCII text included, at every call.
    texts = ['Sé "quoted" \\ back\nslash\t\u2028 \U0001f600', "", "plain"]
    roles = ["system", "user", "assistant"]
    messages = [ChatMessage(role=roles[i], content=texts[i]) for i in range(count)]  # type: ignore[arg-type]
    payload = json.dumps([[m.role, m.content] for m in messages], ensure_ascii=False)
    for _ in range(2):
        assert messages_hash(messages) == hashlib.sha256(payload.encode()).hexdigest()


def test_history_records_outcomes_from_consecutive_observations() -> None:
    script = iter(["LEFT", "UP", "DO", "MAKE_WOOD_PICKAXE", "NOOP", "NOOP"])
    model = MockModel(outputs=lambda conversation: next(script))
    agent = make_agent(history_length=3)
    agent.start_episode(0, EpisodeStart("make a wood pickaxe"))
    observations = [
        fake(x=10),
        fake(x=9),  # LEFT moved west
        fake(x=9),  # UP blocked
        fake(x=9, materials={"wood": 1}, health=7),
        fake(x=9, tools=("wood_pickaxe",), achievements=("MAKE_WOOD_PICKAXE",), health=7),
        fake(x=9, tools=("wood_pickaxe",), achievements=("MAKE_WOOD_PICKAXE",), health=7),
    ]
    decisions: list[Decision] = []
    for observation in observations:
        decisions += play_step(agent, model, [0], [observation])
    outcomes = [(entry.step, entry.action, entry.outcome) for entry in agent.history(0)]
    assert outcomes == [
        (0, "LEFT", "moved west"),
        (1, "UP", "blocked, now facing north"),
        (2, "DO", "gained 1 wood, lost 2 health"),
        (
            3,
            "MAKE_WOOD_PICKAXE",
            "spent 1 wood, gained 1 wood pickaxe, achievement make wood pickaxe",
        ),
        (4, "NOOP", "no visible effect"),
    ]
    last_prompt = user_text(model.requests[-1][0])
    assert "step 1: UP: blocked, now facing north" not in last_prompt  # only the last 3 are shown
    assert "step 2: DO: gained 1 wood, lost 2 health" in last_prompt
    assert "step 4: NOOP: no visible effect" in last_prompt
    assert "first step" in user_text(model.requests[0][0])


def test_new_episode_in_a_slot_starts_a_fresh_history_and_plan() -> None:
    model = MockModel(outputs=["RIGHT"])
    agent = make_agent()
    agent.start_episode(0, EpisodeStart("old goal"))
    play_step(agent, model, [0], [FakeObservation()])
    play_step(agent, model, [0], [fake(x=11)])
    assert len(agent.history(0)) == 1
    agent.start_episode(0, EpisodeStart("new goal", plan="1. find water\n2. drink"))
    play_step(agent, model, [0], [FakeObservation()])
    prompt = user_text(model.requests[-1][0])
    assert agent.history(0) == []
    assert "new goal" in prompt and "old goal" not in prompt
    assert "1. find water" in prompt and "step 0" not in prompt


@pytest.mark.parametrize("rule", ["loglik", "guided"])
def test_choice_mode_passes_the_variant_action_names_and_the_rule(rule: ChoiceRule) -> None:
    model = MockModel(outputs=["not a name"])
    agent = ZeroShotAgent(Variant.FULL, renderer=render_fake, choice_rule=rule)
    agent.start_episode(0, EpisodeStart("descend"))
    decision = play_step(agent, model, [0], [FakeObservation()])[0]
    choices = model.requests[0][1]
    assert choices is not None and choices.rule == rule
    assert len(choices.options) == 43 and choices.options[18] == "DESCEND"
    assert decision.name == "NOOP" and decision.parse.stage == "exact"  # mock picks choices[0]
    assert "ACTION:" not in user_text(model.requests[0][0])


def test_user_mistakes_raise_user_error() -> None:
    with pytest.raises(UserError, match="MAKE_DIAMOND_SWORD"):
        make_agent(fallback_action="MAKE_DIAMOND_SWORD")
    with pytest.raises(UserError, match="history_length"):
        make_agent(history_length=-1)
    agent = make_agent()
    with pytest.raises(UserError, match="slot 3"):
        play_step(agent, MockModel(), [3], [FakeObservation()])


def test_describe_outcome_of_a_non_move_action_ignores_position() -> None:
    after = fake(x=2, achievements=("COLLECT_DRINK",))
    assert describe_outcome("DO", fake(x=1), after) == "achievement collect drink"
    assert describe_outcome("DESCEND", fake(floor=0), fake(floor=1, x=3)) == "changed floor"
