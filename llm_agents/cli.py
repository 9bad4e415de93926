"""`craftext-llm`: evaluate LLM agents on CrafText, report runs, generate plans.

A thin layer over the library: it parses flags into the library's configs, shows progress, and
turns user mistakes into one-line errors with a non-zero exit code.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import logging
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from env.errors import UserError

EXIT_USER_ERROR = 2
EXIT_INTERRUPTED = 130


def _backend_option(text: str) -> tuple[str, Any]:
    key, sep, value = text.partition("=")
    if not sep or not key.strip():
        raise argparse.ArgumentTypeError(f"expected KEY=VALUE, got {text!r}")
    try:
        parsed = json.loads(value)
    except json.JSONDecodeError:
        parsed = value
    return key.strip(), parsed


def _add_generation_flags(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--backend-option",
        dest="backend_options",
        type=_backend_option,
        action="append",
        metavar="KEY=VALUE",
        help="backend option, repeatable (values read as JSON when they parse): threads=2, "
        "device=cuda, enforce_eager=true, api_key_env=MY_KEY",
    )
    group = parser.add_argument_group("generation")
    group.add_argument("--max-tokens", type=int, help="most tokens per answer (default 256)")
    group.add_argument("--temperature", type=float, help="sampling temperature (default 0: greedy)")
    group.add_argument("--top-p", type=float, help="nucleus sampling mass (default 1)")
    group.add_argument("--gen-seed", type=int, dest="gen_seed", help="sampling seed (default 0)")
    group.add_argument(
        "--reasoning-budget", type=int, help="thinking tokens for reasoning models before answering"
    )
    group.add_argument("--timeout", type=float, dest="timeout_s", help="seconds per HTTP request")
    group.add_argument("--max-concurrency", type=int, help="HTTP requests in flight at once")


def _generation_overrides(args: argparse.Namespace) -> dict[str, Any]:
    return {
        "max_tokens": args.max_tokens,
        "temperature": args.temperature,
        "top_p": args.top_p,
        "seed": args.gen_seed,
        "reasoning_budget": args.reasoning_budget,
        "timeout_s": args.timeout_s,
        "max_concurrency": args.max_concurrency,
    }


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="craftext-llm",
        description="Zero-shot LLM agents on the CrafText benchmark (Craftax).",
    )
    parser.add_argument("-v", "--verbose", action="store_true", help="log debug messages")
    commands = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    run = commands.add_parser(
        "eval",
        help="run an evaluation (resumes when the output directory holds an unfinished run)",
        description="Play CrafText episodes with an LLM agent and score them. Flags override "
        "the --config file; the resolved config is saved with the results.",
    )
    run.add_argument("--config", help="YAML or TOML file of settings (flags override it)")
    run.add_argument(
        "--model", help="model spec: hf:NAME|PATH, vllm:PATH, openai:MODEL@URL, mock:SCRIPT"
    )
    run.add_argument(
        "--choice",
        action="store_true",
        default=None,
        help="constrain answers to action names (needed by small models)",
    )
    run.add_argument(
        "--variant", choices=["full", "classic"], help="Craftax variant (default full)"
    )
    run.add_argument(
        "--splits",
        nargs="+",
        help="categories: one combo paraphrased new_objects (default: one combo new_objects)",
    )
    run.add_argument("--dataset", help="official CrafText clone, craftext wheel or dataset JSON")
    run.add_argument(
        "--no-paraphrases",
        dest="paraphrases",
        action="store_false",
        default=None,
        help="run only each goal's original instruction",
    )
    run.add_argument(
        "--episodes-per-instruction", type=int, help="worlds per instruction (default 1)"
    )
    run.add_argument("--max-steps", type=int, help="step cap per episode (default 250)")
    run.add_argument("--seed", type=int, help="run seed (default 0)")
    run.add_argument("--batch-size", type=int, help="episodes in lockstep (default 8)")
    run.add_argument(
        "--lanes", type=int, help="overlap model calls with env work in N lanes (default 1)"
    )
    run.add_argument("--renderer", help="observation text: objects (default), grid, table")
    run.add_argument("--history-length", type=int, help="recent actions shown (default 5)")
    run.add_argument("--templates-dir", help="directory of .j2 files overriding the prompts")
    run.add_argument("--plans", help="JSON file: instruction -> plan, added to the prompt")
    run.add_argument("--output-dir", help="results directory (default runs/latest)")
    run.add_argument("--limit", type=int, help="run only the first N episodes")
    run.add_argument("--fallback-action", help="action for unparseable answers (default NOOP)")
    run.add_argument("--cache", help="SQLite file caching model responses")
    run.add_argument(
        "--no-step-log",
        dest="record_steps",
        action="store_false",
        default=None,
        help="do not write steps.jsonl",
    )
    run.add_argument("--no-progress", action="store_true", help="hide the progress bar")
    _add_generation_flags(run)

    report = commands.add_parser(
        "report", help="print the table and redraw the chart of a finished or partial run"
    )
    report.add_argument("run_dir", help="a run's output directory")
    report.add_argument(
        "--compare", metavar="OTHER_RUN", help="another run (e.g. the expert's) shown beside it"
    )

    plan = commands.add_parser(
        "plan",
        help="generate step-by-step plans for instructions (the input of PPO-T+)",
        description="Ask a planner model for a plan of at most --max-plan-steps numbered steps "
        "for every instruction and paraphrase of the chosen splits. Resumes by default.",
    )
    plan.add_argument("--model", required=True, help="planner model spec")
    plan.add_argument("--output", required=True, help="plans JSON to write (instruction -> plan)")
    plan.add_argument(
        "--splits",
        nargs="+",
        help="dataset splits (easy_train easy_test_paraphrased easy_test_other_params, the default) "
        "or eval's category names (one and combo plan the train split)",
    )
    plan.add_argument("--dataset", help="official CrafText clone, craftext wheel or dataset JSON")
    plan.add_argument("--variant", choices=["full", "classic"], help="vocabulary (default full)")
    plan.add_argument("--max-plan-steps", type=int, help="steps per plan (default 5)")
    plan.add_argument("--max-step-words", type=int, help="words per step (default 8)")
    plan.add_argument("--no-repair", action="store_true", help="do not ask to repair bad plans")
    plan.add_argument("--drop-failed", action="store_true", help="leave unrepaired plans out")
    plan.add_argument("--batch-size", type=int, help="conversations per backend call (default 32)")
    plan.add_argument("--restart", action="store_true", help="discard earlier progress")
    plan.add_argument("--templates-dir", help="directory of .j2 files overriding the prompts")
    plan.add_argument("--no-progress", action="store_true", help="hide the progress bar")
    _add_generation_flags(plan)
    return parser


def _progress_bar(enabled: bool) -> Any:
    if not enabled:
        return None
    from tqdm import tqdm

    def factory(total: int, initial: int) -> Any:
        return tqdm(total=total, initial=initial, unit="episode", dynamic_ncols=True)

    return factory


def _open_model(
    spec: str, generation: Any, cache: str | None, options: dict[str, Any] | None = None
) -> Any:
    from llm_agents.backends import get_model

    model = get_model(spec, generation, **(options or {}))
    if cache:
        from llm_agents.backends.cache import CachedModel

        model = CachedModel(model, cache)
    return model


def cmd_eval(args: argparse.Namespace) -> int:
    from llm_agents.config import build_config, load_config_file
    from llm_agents.report import report_run
    from llm_agents.runner import run_eval

    base = load_config_file(args.config) if args.config else {}
    flags = {
        name: getattr(args, name)
        for name in (
            "model",
            "choice",
            "variant",
            "splits",
            "dataset",
            "paraphrases",
            "episodes_per_instruction",
            "max_steps",
            "seed",
            "batch_size",
            "renderer",
            "history_length",
            "templates_dir",
            "plans",
            "output_dir",
            "limit",
            "fallback_action",
            "cache",
            "record_steps",
        )
    }
    if args.backend_options:
        flags["backend_options"] = {**base.get("backend_options", {}), **dict(args.backend_options)}
    config = build_config(base, flags, _generation_overrides(args))
    print(
        f"evaluating {config.model} on {', '.join(config.splits)} ({config.variant.value} Craftax)"
        f" -> {config.output_dir}",
        file=sys.stderr,
    )
    from llm_agents.agents import NoModel, agent_class

    opened = (
        _open_model(config.model, config.generation, config.cache, config.backend_options)
        if agent_class(config.agent).needs_model
        else NoModel()
    )
    with opened as model:
        try:
            outcome = run_eval(config, model, progress=_progress_bar(not args.no_progress))
        except KeyboardInterrupt:
            print(
                f"\ninterrupted: partial results are in {config.output_dir}; "
                "rerun the same command to resume",
                file=sys.stderr,
            )
            _print_report(config.output_dir)
            return EXIT_INTERRUPTED
    if outcome.missing_plans:
        print(
            f"note: {len(outcome.missing_plans)} instructions had no plan in {config.plans}",
            file=sys.stderr,
        )
    print(report_run(outcome.output_dir))
    return 0


def _print_report(run_dir: str | Path) -> None:
    from llm_agents.report import report_run

    with contextlib.suppress(UserError):
        print(report_run(run_dir))


def cmd_report(args: argparse.Namespace) -> int:
    from llm_agents.report import report_run

    if args.compare:
        from llm_agents.report import compare_runs

        print(compare_runs(args.run_dir, args.compare))
        return 0
    print(report_run(args.run_dir))
    return 0


def cmd_plan(args: argparse.Namespace) -> int:
    from pydantic import ValidationError

    from env.dataset import CATEGORY_SPLIT
    from llm_agents.backends.base import GenerateConfig
    from llm_agents.planner import PlanLimits, PlannerConfig, run_planner

    try:
        generation = GenerateConfig(
            **{k: v for k, v in _generation_overrides(args).items() if v is not None}
        )
        limits = PlanLimits(
            **{
                key: value
                for key, value in (
                    ("max_steps", args.max_plan_steps),
                    ("max_step_words", args.max_step_words),
                )
                if value is not None
            }
        )
        settings: dict[str, Any] = {
            "output": Path(args.output),
            "limits": limits,
            "repair": not args.no_repair,
            "drop_failed": args.drop_failed,
            "restart": args.restart,
            "progress": not args.no_progress,
        }
        for key in ("dataset", "variant", "batch_size", "templates_dir"):
            if getattr(args, key) is not None:
                settings[key] = getattr(args, key)
        if args.splits is not None:
            settings["splits"] = list(dict.fromkeys(CATEGORY_SPLIT.get(s, s) for s in args.splits))
        config = PlannerConfig(**settings)
    except ValidationError as err:
        raise UserError(
            f"invalid plan settings: {err.errors()[0]['loc']}: {err.errors()[0]['msg']}"
        ) from err
    with _open_model(args.model, generation, None, dict(args.backend_options or [])) as model:
        summary = run_planner(config, model)
    print(
        f"{summary.instructions} instructions: {summary.valid} valid, {summary.repaired} repaired, "
        f"{summary.failed} failed, {summary.errors} backend errors, {summary.resumed} resumed\n"
        f"plans: {summary.output}\nsidecar: {summary.sidecar}"
    )
    if summary.errors:
        print("some requests failed; rerun the same command to retry them", file=sys.stderr)
        return 1
    return 0


COMMANDS = {"eval": cmd_eval, "report": cmd_report, "plan": cmd_plan}


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    logging.basicConfig(
        level=logging.DEBUG if args.verbose else logging.WARNING,
        format="%(levelname)s %(name)s: %(message)s",
    )
    try:
        return COMMANDS[args.command](args)
    except UserError as err:
        print(f"craftext-llm: error: {err}", file=sys.stderr)
        return EXIT_USER_ERROR
    except KeyboardInterrupt:
        print("\ninterrupted", file=sys.stderr)
        return EXIT_INTERRUPTED


if __name__ == "__main__":
    sys.exit(main())
