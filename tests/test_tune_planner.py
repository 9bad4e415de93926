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
