"""benchmarks/grpo_planner.py: plans judged by playing them (success first, a shaped part where
none succeeds), and a GRPO run end to end on the tiny model, rewarded by real executions."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import pytest
from tiny_llm import build_tiny_llm

from benchmarks import grpo_planner, tune_planner
from env.dataset import Dataset, DatasetSource, Goal
from env.variant import Variant

TUNE_MISSING = [n for n in tune_planner.TUNE_PACKAGES if importlib.util.find_spec(n) is None]
needs_tune = pytest.mark.skipif(
    bool(TUNE_MISSING),
    reason=f"the tune extra is not installed ({', '.join(TUNE_MISSING)}): pip install -e '.[tune]'",
)

WOOD, TABLE = "Collect wood.", "Place a crafting table."


def _dataset(tmp_path: Path) -> Path:
    goals = (
        Goal(
            id="wood",
            split="easy_train",
            category="one",
            instruction=WOOD,
            paraphrases=("Chop a tree.",),
            required=("COLLECT_WOOD",),
        ),
        Goal(
            id="table",
            split="easy_train",
            category="combo",
            instruction=TABLE,
            paraphrases=(),
            required=("COLLECT_WOOD", "PLACE_TABLE"),
            forbidden=("COLLECT_SAPLING",),
        ),
        Goal(
            id="sword",
            split="easy_test_paraphrased",
            category="paraphrased",
            instruction="Make a wooden sword.",
            paraphrases=(),
            required=("MAKE_WOOD_SWORD",),
        ),
    )
    source = DatasetSource(kind="json", path="test")
    return Dataset(source=source, goals=goals).save_json(tmp_path / "data.json")


def _settings(tmp_path: Path, **values: object) -> grpo_planner.OnlineSettings:
    return grpo_planner.OnlineSettings(
        out=tmp_path / "tuned",
        dataset=str(_dataset(tmp_path)),
        variant=Variant.CLASSIC,
        **values,
    )


def test_the_texts_are_the_selection_splits_own(tmp_path: Path) -> None:
    texts = grpo_planner.training_texts(_settings(tmp_path))
    assert {text: (goal.id, index) for text, (goal, index) in texts.items()} == {
        WOOD: ("wood", 0),
        "Chop a tree.": ("wood", 1),
        TABLE: ("table", 0),
    }
    main = grpo_planner.training_texts(_settings(tmp_path, main_only=True, limit=1))
    assert list(main) == [WOOD]
    with pytest.raises(grpo_planner.UserError, match="no split nope"):
        grpo_planner.training_texts(_settings(tmp_path, splits=("nope",)))


def test_the_short_prompt_is_the_planners_request_from_its_own_template(tmp_path: Path) -> None:
    chat = grpo_planner.prompt_chat(WOOD, _settings(tmp_path, max_plan_steps=3))
    assert [m["role"] for m in chat] == ["system", "user"]
    assert chat[1]["content"] == f"Instruction: {WOOD}"
    assert "at most 3 numbered steps" in chat[0]["content"]
    full = grpo_planner.prompt_chat(WOOD, _settings(tmp_path, templates_dir=None))
    # The full planner prompt lists every Craftax name; the short one a few lines.
    assert len(chat[0]["content"]) * 3 < len(full[0]["content"])


@pytest.mark.slow
def test_plans_are_judged_by_plan_score_in_its_selection_worlds_success_first(
    tmp_path: Path,
) -> None:
    from llm_agents.planning.scoring import SELECTION_WORLDS

    judge = grpo_planner.plan_judge(_settings(tmp_path, worlds=2))
    assert (judge.stream, judge.seed, judge.worlds) == (SELECTION_WORLDS, 0, 2)
    works = "1. Collect 2 wood.\n2. Place crafting table."
    plans = [
        (TABLE, works),
        # One wood, counted: the table is refused at step 2; wood, one of two achievements, is
        # reached. (An uncounted "Collect wood." gathers the 2 the table spends.)
        (TABLE, "1. Collect 1 wood.\n2. Place crafting table."),
        # Stone needs a pickaxe: the first step fails, nothing is reached.
        (TABLE, "1. Collect stone.\n2. Place crafting table."),
        (TABLE, "Sure! Here is a plan."),
        (TABLE, "1. Collect 2 wood.\n2. Dance a jig.\n3. Place crafting table."),
        # Met before its last step plays, which collects the sapling the text forbids.
        (TABLE, works + "\n3. Collect sapling."),
    ]
    verdicts = grpo_planner.judge_plans(judge, plans)
    good, short, stone, unread, partly, breaking = verdicts
    assert (good.success, good.achieved, good.played, good.episodes) == (1.0, 1.0, 1.0, 2)
    assert (short.success, short.achieved, short.played) == (0.0, 0.5, 0.5)
    assert (stone.success, stone.achieved, stone.played) == (0.0, 0.0, 0.0)
    assert (unread.success, unread.played, unread.episodes) == (0.0, 0.0, 0)
    # A world where the goal was met counts the shaped parts whole, unread steps or not.
    assert (partly.success, partly.achieved, partly.played) == (1.0, 1.0, 1.0)
    assert breaking.success == 1.0 and breaking.breaks
    rewards = [v.reward(0.3, 0.2) for v in verdicts]
    assert rewards[0] == rewards[4] == pytest.approx(1.5)
    assert rewards[1] == pytest.approx(0.25)
    assert rewards[0] > rewards[1] > rewards[2] == rewards[3] == rewards[5] == 0.0
    # The verdicts are plan-score's own, and played again in the same worlds they repeat.
    played = judge.score(plans[:2])
    assert [p.success for p in played] == [v.success for v in verdicts[:2]]
    assert grpo_planner.judge_plans(judge, plans[:2]) == verdicts[:2]


def _steered_generation(tokenizer_dir: Path) -> dict[str, object]:
    """Biases that make the random tiny model write bullet plans of `collect wood` and `collect
    stone` lines in random order: the only way its samples read as plans, and differ."""
    from transformers import AutoTokenizer

    tokenizer = AutoTokenizer.from_pretrained(tokenizer_dir)

    def one(text: str) -> int:
        (token,) = tokenizer.encode(text, add_special_tokens=False)
        return int(token)

    newline, dash, collect = one("\n"), one("-"), one(" collect")
    wood, stone, end = one(" wood"), one(" stone"), one("<|im_end|>")
    bias = {
        (newline, dash): 40.0,
        (dash, collect): 40.0,
        (collect, wood): 30.0,
        (collect, stone): 30.0,
        (wood, newline): 30.0,
        (wood, end): 30.0,
        (stone, newline): 30.0,
        (stone, end): 30.0,
    }
    return {"sequence_bias": {key: value for key, value in bias.items()}}


@needs_tune
@pytest.mark.slow
def test_grpo_tunes_the_adapter_on_rewards_from_real_executions(tmp_path: Path) -> None:
    import torch
    from safetensors.torch import load_file

    from llm_agents.backends.embedded import embedded_model_dir

    tokenizer_dir = embedded_model_dir()
    base = build_tiny_llm(tmp_path / "tiny", tokenizer_dir)
    settings = _settings(
        tmp_path,
        model=f"hf:{base}",
        splits=("easy_train",),
        main_only=True,
        max_steps=2,
        generations=4,
        prompts_per_step=2,
        worlds=1,
        max_tokens=12,
        learning_rate=5e-2,
        lora_rank=4,
    )
    judged: list[tuple[str, str]] = []
    real_judge = grpo_planner.judge_plans

    def spy(judge: grpo_planner.PlanJudge, plans: list[tuple[str, str]]) -> list:
        judged.extend(plans)
        return real_judge(judge, plans)

    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(grpo_planner, "judge_plans", spy)
        record = grpo_planner.tune_online(
            settings, generation_kwargs=_steered_generation(tokenizer_dir)
        )

    # Two steps, each judging 2 prompts x 4 samples, played in the env.
    assert record.steps == 2 and len(record.rewards) == 2
    assert len(judged) == 16 and {text for text, _ in judged} == {WOOD, TABLE}
    assert any("collect wood" in plan for _, plan in judged)
    assert record.episodes > 0
    assert all(step.plans == 8 for step in record.rewards)
    # The samples' rewards differed within a step, so GRPO had something to learn from.
    assert any(step.reward_std > 0 for step in record.rewards)

    out = settings.out
    assert sorted(p.name for p in tmp_path.iterdir()) == ["data.json", "tiny", "tuned"]
    sidecar = json.loads((out / grpo_planner.SIDECAR).read_text())
    assert sidecar["settings"]["method"] == "grpo" and len(sidecar["rewards"]) == 2
    # Every judged plan is kept with its verdict, in the order the reward saw them.
    logged = [(p["instruction"], p["plan"]) for s in sidecar["rewards"] for p in s["judged"]]
    assert logged == judged
    assert (out / grpo_planner.CURVE).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    # The merged weights differ from the base: the adapter learned and was merged in.
    before, after = load_file(base / "model.safetensors"), load_file(out / "model.safetensors")
    assert before.keys() == after.keys()
    changed = [k for k in before if not torch.equal(before[k], after[k])]
    assert any("proj" in key for key in changed)

    # The folder is what `plan --model hf:FOLDER` loads.
    from llm_agents.backends import get_model
    from llm_agents.backends.base import ChatMessage, GenerateConfig

    chat = [
        ChatMessage(role=m["role"], content=m["content"])
        for m in grpo_planner.prompt_chat(WOOD, settings)
    ]
    answer = get_model(f"hf:{out}", GenerateConfig(max_tokens=4)).generate([chat])[0]
    assert answer.error is None


@needs_tune
@pytest.mark.slow
def test_rejection_sampling_keeps_the_plans_that_worked_and_tunes_on_them(tmp_path: Path) -> None:
    import torch
    from safetensors.torch import load_file

    from llm_agents.backends.embedded import embedded_model_dir

    tokenizer_dir = embedded_model_dir()
    base = build_tiny_llm(tmp_path / "tiny", tokenizer_dir)
    settings = _settings(
        tmp_path,
        method="rs",
        model=f"hf:{base}",
        main_only=True,
        rounds=1,
        samples=6,
        worlds=1,
        max_tokens=12,
        sft_steps=2,
        learning_rate=5e-2,
        lora_rank=4,
    )
    record = grpo_planner.tune_online(
        settings, generation_kwargs=_steered_generation(tokenizer_dir)
    )
    (round_one,) = record.rewards
    assert record.steps == 1 and record.episodes > 0
    # Some samples start with `collect wood`, which meets the wood goal: those are kept.
    assert round_one.plans_succeeding > 0 and round_one.kept == round_one.plans_succeeding
    before = load_file(base / "model.safetensors")
    after = load_file(settings.out / "model.safetensors")
    assert any(not torch.equal(before[k], after[k]) for k in before if "proj" in k)
    assert json.loads((settings.out / grpo_planner.SIDECAR).read_text())["rewards"][0]["kept"]


def test_a_missing_model_is_one_line_and_exit_2(
    tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    out = tmp_path / "tuned"
    argv = ["grpo", "--out", str(out), "--model", f"hf:{tmp_path / 'no-model'}"]
    assert grpo_planner.main([*argv, "--dataset", str(_dataset(tmp_path))]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: ") and "\n" not in err and "no-model" in err
    assert not out.exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["data.json"]


def test_a_missing_tune_extra_is_one_line_and_exit_2(
    tmp_path: Path, capsys: pytest.CaptureFixture, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(
        tune_planner, "TUNE_PACKAGES", (*tune_planner.TUNE_PACKAGES, "no_such_trainer")
    )
    out = tmp_path / "tuned"
    assert grpo_planner.main(["rs", "--out", str(out), "--dataset", str(_dataset(tmp_path))]) == 2
    err = capsys.readouterr().err.strip()
    assert err == "error: tuning needs no_such_trainer: pip install -e '.[tune]'"
    assert not out.exists()


@pytest.mark.parametrize(
    ("argv", "message"),
    [(["--worlds", "0"], "--worlds"), (["--generations", "1"], "--generations")],
)
def test_bad_settings_are_one_line_and_exit_2(
    tmp_path: Path, capsys: pytest.CaptureFixture, argv: list[str], message: str
) -> None:
    out = tmp_path / "tuned"
    assert grpo_planner.main(["grpo", "--out", str(out), *argv]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"error: {message}") and "\n" not in err
    assert not out.exists()
