"""benchmarks/tune_planner.py: exported lines read back into the planner's chat, and a LoRA tuning
run end to end on the embedded model, whose saved folder `plan`'s backend loads."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import pytest

from benchmarks import tune_planner
from env.errors import UserError
from env.variant import Variant
from llm_agents.planning.loop import planner_messages
from llm_agents.run_data.metrics import SuccessRate

TUNE_MISSING = [n for n in tune_planner.TUNE_PACKAGES if importlib.util.find_spec(n) is None]
needs_tune = pytest.mark.skipif(
    bool(TUNE_MISSING),
    reason=f"the tune extra is not installed ({', '.join(TUNE_MISSING)}): pip install -e '.[tune]'",
)


def _write(path: Path, rows: list[dict]) -> Path:
    path.write_text("".join(json.dumps(row) + "\n" for row in rows))
    return path


def test_a_conversation_is_tuned_on_its_answer_alone(tmp_path: Path) -> None:
    chat = [
        {"role": "system", "content": "Write a plan."},
        {"role": "user", "content": "Instruction: Get wood."},
        {"role": "assistant", "content": "1. Collect wood."},
    ]
    sft = _write(tmp_path / "sft.jsonl", [{"messages": chat}])
    method, rows = tune_planner.read_lines(sft)
    assert method == "sft"
    chats = tune_planner.PlannerChats(Variant.CLASSIC, None)
    assert tune_planner.conversational(rows, method, chats) == [
        {"prompt": chat[:2], "completion": chat[2:]}
    ]
    assert chats.rebuilt == 0


def test_method_follows_the_keys(tmp_path: Path) -> None:
    sft = _write(tmp_path / "sft.jsonl", [{"prompt": "a", "completion": "1. b"}] * 3)
    dpo = _write(tmp_path / "dpo.jsonl", [{"prompt": "a", "chosen": "1. b", "rejected": "1. c"}])
    assert tune_planner.read_lines(sft) == ("sft", [{"prompt": "a", "completion": "1. b"}] * 3)
    assert tune_planner.read_lines(sft, limit=2)[1] == [{"prompt": "a", "completion": "1. b"}] * 2
    assert tune_planner.read_lines(dpo)[0] == "dpo"


@pytest.mark.parametrize(
    ("lines", "message"),
    [
        (["{not json"], ":1 is not JSON"),
        (["[1, 2]"], "1 is not a JSON object"),
        ([json.dumps({"prompt": "a", "plan": "b"})], r"neither messages or prompt\+completion"),
        (
            [json.dumps({"prompt": "a", "completion": "b"}), json.dumps({"prompt": "a"})],
            "2 lacks completion",
        ),
        ([""], "holds no examples"),
    ],
)
def test_bad_files_are_refused(tmp_path: Path, lines: list[str], message: str) -> None:
    path = tmp_path / "data.jsonl"
    path.write_text("\n".join(lines))
    with pytest.raises(UserError, match=message):
        tune_planner.read_lines(path)


def test_the_planner_prompt_is_put_back_into_its_chat() -> None:
    planner = planner_messages("Make a wooden pickaxe.", None, Variant.CLASSIC)
    system, user = (m.content for m in planner)
    chats = tune_planner.PlannerChats(Variant.CLASSIC, None)
    # As earlier plan-score exports wrote it: one string, the blocks joined.
    assert chats.chat(f"{system}\n\n{user}\n") == [
        {"role": "system", "content": system},
        {"role": "user", "content": user},
    ]
    # A bare instruction gets the planner's whole prompt around it, and is counted.
    assert chats.chat("Make a wooden pickaxe.") == [
        {"role": "system", "content": system},
        {"role": "user", "content": user},
    ]
    assert chats.rebuilt == 1
    conversation = [{"role": "user", "content": "x"}]
    assert chats.chat(conversation) is conversation


SHORT_PLANNER = Path(__file__).parents[1] / "benchmarks" / "short_planner"


def test_reprompt_asks_each_exported_instruction_with_this_runs_prompt(tmp_path: Path) -> None:
    # Exported under the project's prompt (plan-score's default), tuned for the short one.
    exported = [
        {"role": m.role, "content": m.content}
        for m in planner_messages("Make a wooden pickaxe.", None, Variant.CLASSIC)
    ]
    plan = [{"role": "assistant", "content": "1. collect wood 3"}]
    rows = [
        {"messages": exported + plan},
        {"prompt": exported, "chosen": plan, "rejected": plan},
    ]
    limits = tune_planner.PlanLimits(max_steps=12)
    chats = tune_planner.PlannerChats(Variant.CLASSIC, str(SHORT_PLANNER), limits)
    short = [
        {"role": m.role, "content": m.content}
        for m in planner_messages("Make a wooden pickaxe.", limits, Variant.CLASSIC, SHORT_PLANNER)
    ]
    assert short != exported and "at most 12 numbered steps" in short[0]["content"]
    assert tune_planner.conversational(rows[:1], "sft", chats, reprompt=True) == [
        {"prompt": short, "completion": plan}
    ]
    assert tune_planner.conversational(rows[1:], "dpo", chats, reprompt=True)[0]["prompt"] == short
    assert chats.rebuilt == 2
    # Without it the exported chat is kept as it was.
    assert tune_planner.conversational(rows[:1], "sft", chats) == [
        {"prompt": exported, "completion": plan}
    ]
    # A chat whose user message names no instruction the way a planner prompt does.
    with pytest.raises(UserError, match="--reprompt"):
        chats.reprompted([{"role": "user", "content": "Get wood."}])


def test_a_bad_file_is_one_line_and_exit_2(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    data = _write(tmp_path / "data.jsonl", [{"prompt": "a"}])
    assert tune_planner.main(["train", str(data), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: ") and "\n" not in err
    assert not (tmp_path / "out").exists()


# Short prompts in the planner's shape (a system block, then "Instruction: ..."), so a few
# optimizer steps take seconds; the completions are plans the untuned model does not write.
TRAIN = [
    {"prompt": "Write a plan.\n\nInstruction: Get wood.", "completion": "1. Collect wood."},
    {"prompt": "Write a plan.\n\nInstruction: Get stone.", "completion": "1. Collect stone."},
]


@needs_tune
@pytest.mark.slow
def test_tuning_runs_and_the_saved_model_plans_differently(tmp_path: Path) -> None:
    from llm_agents.backends import get_model
    from llm_agents.backends.base import ChatMessage, GenerateConfig

    data = _write(tmp_path / "sft.jsonl", TRAIN)
    out = tmp_path / "tuned"
    record = tune_planner.train(
        tune_planner.TuneSettings(
            model="hf:smollm2-135m",
            data=data,
            out=out,
            max_steps=12,
            learning_rate=2e-3,
            batch_size=2,
            grad_accum=1,
        )
    )
    assert record.method == "sft" and record.examples == 2 and record.steps == 12
    assert record.prompts_rebuilt == 0
    assert record.last_loss is not None and record.first_loss is not None
    assert record.last_loss < record.first_loss
    sidecar = json.loads((out / tune_planner.SIDECAR).read_text())
    assert sidecar["data_sha256"] == tune_planner._sha256(data)
    # No scratch folder left beside the model.
    assert sorted(p.name for p in tmp_path.iterdir()) == ["sft.jsonl", "tuned"]

    chat = [
        ChatMessage(role="system", content="Write a plan."),
        ChatMessage(role="user", content="Instruction: Get wood."),
    ]
    config = GenerateConfig(max_tokens=12)
    before = get_model("hf:smollm2-135m", config).generate([chat])[0].text
    after = get_model(f"hf:{out}", config).generate([chat])[0].text
    assert after != before
    assert after.strip().startswith("1. Collect wood.")


@needs_tune
def test_an_existing_output_folder_is_refused(tmp_path: Path) -> None:
    data = _write(tmp_path / "sft.jsonl", TRAIN)
    (tmp_path / "tuned").mkdir()
    settings = tune_planner.TuneSettings(model="hf:smollm2-135m", data=data, out=tmp_path / "tuned")
    with pytest.raises(UserError, match="exists"):
        tune_planner.train(settings)


def _score(text: str, goal: str, hits: int, worlds: int = 4, candidate: int = 0) -> dict:
    return {
        "instruction": text,
        "candidate": candidate,
        "plan": "1. Collect wood.",
        "steps": [{"number": 1, "text": "Collect wood.", "skills": ["collect wood"]}],
        "goal_id": goal,
        "split": "easy_test_other_params",
        "success": SuccessRate.of(hits, worlds).model_dump(mode="json"),
        "env_steps": 10,
        "failures": (
            [{"step": 1, "skill": "collect wood", "reason": "no tree", "episodes": worlds - hits}]
            if hits < worlds
            else []
        ),
    }


def _scores_dir(path: Path, plans: list[dict]) -> Path:
    path.mkdir()
    (path / "scores.json").write_text(json.dumps({"settings": {}, "splits": {}, "plans": plans}))
    return path


def test_compare_puts_best_of_one_side_by_side(tmp_path: Path) -> None:
    before = _scores_dir(
        tmp_path / "before",
        [
            _score("a", "g1", 0),
            _score("b", "g1", 1),
            _score("c", "g2", 0),
            _score("a", "g1", 4, candidate=1),
        ],
    )
    after = _scores_dir(
        tmp_path / "after", [_score("a", "g1", 4), _score("b", "g1", 3), _score("c", "g2", 0)]
    )
    old, new = tune_planner.read_scores(before), tune_planner.read_scores(after)
    # Only first candidates count: best-of-1.
    first = tune_planner.first_candidates(old, "easy_test_other_params")
    assert first is not None and (first.successes, first.episodes, first.clusters) == (1, 12, 2)
    diff = tune_planner.paired_difference(old, new)
    assert diff is not None and diff.texts == 3
    assert diff.rate == pytest.approx((4 + 3 - 1) / 12)
    assert diff.low < diff.rate < diff.high
    table = tune_planner.compare(before, after)
    assert "| easy_test_other_params | 0.08 " in table and "| 0.58 " in table
    assert "+0.50" in table
    # The failed episodes of the first candidates: before 4 + 3 + 4, after 0 + 1 + 4.
    assert "easy_test_other_params before: 11 x collect wood: no tree" in table
    assert "easy_test_other_params after: 5 x collect wood: no tree" in table
    assert tune_planner.main(["compare", str(before), str(tmp_path / "missing")]) == 2
    assert "worlds: selection" in table
    # Without held-out worlds in the files, --held-out is refused in one line.
    with pytest.raises(UserError, match="--held-out-worlds"):
        tune_planner.compare(before, after, held_out=True)


def test_compare_reads_the_held_out_worlds_on_request(tmp_path: Path) -> None:
    def held_out(score: dict, hits: int) -> dict:
        return score | {"held_out": SuccessRate.of(hits, 4).model_dump(mode="json")}

    before = _scores_dir(
        tmp_path / "before",
        [
            held_out(_score("a", "g1", 0), 1),
            held_out(_score("b", "g2", 1), 0),
            _score("x", "g1", 4, candidate=1),
        ],
    )
    after = _scores_dir(
        tmp_path / "after",
        # "c" was scored after only: it has no pair and is left out of the difference.
        [
            held_out(_score("a", "g1", 0), 4),
            held_out(_score("b", "g2", 1), 2),
            held_out(_score("c", "g3", 0), 0),
        ],
    )
    old, new = tune_planner.read_scores(before), tune_planner.read_scores(after)
    first = tune_planner.first_candidates(new, "easy_test_other_params", held_out=True)
    assert first is not None and (first.successes, first.episodes) == (6, 12)
    diff = tune_planner.paired_difference(old, new, held_out=True)
    assert diff is not None and diff.texts == 2 and diff.rate == pytest.approx((3 + 2) / 8)
    table = tune_planner.compare(before, after, held_out=True)
    assert "worlds: held-out" in table and "+0.62" in table
