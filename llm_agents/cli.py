"""`craftext-llm`: evaluate LLM agents on CrafText, report runs, generate plans.

A thin layer over the library: flags are generated from the library's settings classes, a
`--config` file fills in what flags leave out, and every user mistake becomes one line on stderr
with a non-zero exit code.
"""

from __future__ import annotations

import argparse
import contextlib
import logging
import sys
from collections import Counter
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from env.errors import UserError
from llm_agents.cli_flags import FlagTarget, add_settings_flags, given_settings
from llm_agents.evaluation.config import EvalConfig, ModelSettings, build_settings, load_config_file

#: A results card that its run's records do not give (`card --verify`, `leaderboard`).
EXIT_VERIFY_FAILED = 1
EXIT_USER_ERROR = 2
EXIT_BACKEND_FAILURE = 3
EXIT_INTERRUPTED = 130


class _Parser(argparse.ArgumentParser):
    """Usage errors as one line (argparse prints the whole usage block by default)."""

    def error(self, message: str) -> Any:
        self.exit(EXIT_USER_ERROR, f"{self.prog}: error: {message} (see --help)\n")


def _settings_command(
    commands: Any, name: str, settings: type[ModelSettings], **kwargs: Any
) -> argparse.ArgumentParser:
    command: argparse.ArgumentParser = commands.add_parser(name, **kwargs)
    command.add_argument(
        "--config", help="YAML or TOML file of settings; keys are the flag names with underscores"
    )
    command.add_argument("--no-progress", action="store_true", help="hide the progress bar")
    targets = add_settings_flags(command, settings)
    command.set_defaults(settings_class=settings, flag_targets=targets)
    return command


def build_parser() -> argparse.ArgumentParser:
    from llm_agents.evaluation.grounding_run import GroundConfig
    from llm_agents.planning import PlannerConfig

    parser = _Parser(
        prog="craftext-llm",
        description="Zero-shot LLM agents on the CrafText benchmark (Craftax).",
    )
    parser.add_argument("-v", "--verbose", action="store_true", help="log debug messages")
    commands = parser.add_subparsers(
        dest="command", required=True, metavar="COMMAND", parser_class=_Parser
    )
    _settings_command(
        commands,
        "eval",
        EvalConfig,
        help="run an evaluation (resumes when the output directory holds an unfinished run)",
        description="Play CrafText episodes with an LLM agent and score them. Flags override "
        "the --config file; the resolved config is saved with the results.",
    )
    report = commands.add_parser(
        "report", help="print the table and redraw the chart of a finished or partial run"
    )
    report.add_argument("run_dir", help="a run's output directory")
    report.add_argument(
        "--success-rule",
        choices=["game_over_counts", "official"],
        help="re-score the run: does a goal completed on the step the game ends count? "
        "(default: the rule the run was played under)",
    )
    report.add_argument(
        "--compare",
        metavar="OTHER_RUN",
        action="append",
        help="another run (e.g. the expert's) shown beside it; repeat for more",
    )
    _goal_status_flags(report)

    data = commands.add_parser(
        "data",
        help="show, fetch or export the CrafText dataset the cache holds",
        description="show: what the cache holds; fetch: download the official data at the pinned "
        "commit into the cache (again with --refresh); export PATH: write a dataset (the default "
        "source, or --dataset) as JSON, usable later with --dataset PATH.",
    )
    data.add_argument("action", choices=["show", "fetch", "export"])
    data.add_argument("path", nargs="?", help="export: the JSON file to write")
    data.add_argument("--dataset", help="export: official CrafText clone, craftext wheel or JSON")
    data.add_argument("--refresh", action="store_true", help="fetch: download even when cached")

    export = commands.add_parser(
        "export",
        help="write a run in another benchmark's submission format",
        description="--format balrog: a complete --protocol balrog run as a submission folder "
        "of BALROG's leaderboard repository (per-episode files, crafter_summary.json, "
        "summary.json, metadata.yaml).",
    )
    export.add_argument("run_dir", help="a run's output directory")
    export.add_argument("out", help="the submission folder to write (absent or empty)")
    export.add_argument("--format", choices=["balrog"], required=True, help="the target format")

    card = commands.add_parser(
        "card",
        help="write a complete run's results card (card.json, card.md), or --verify one",
        description="Write RUN_DIR/card.json and card.md: what the run was (model, agent, "
        "protocol and departures, digests, code, hardware) and every figure its records give, "
        "once the records replay: the episodes its protocol gives, each re-simulated from its "
        "world key and actions, its answers parsed again (exit 1 naming the episode and field "
        "that differ, nothing written). With --verify CARD, replay RUN_DIR again, recompute each "
        "figure and name those that differ (exit 1).",
    )
    card.add_argument("run_dir", help="a complete run's output directory")
    card.add_argument("--no-progress", action="store_true", help="hide the progress bar")
    card.add_argument("--verify", metavar="CARD", help="check this card.json against RUN_DIR")
    card.add_argument("--out", metavar="DIR", help="write the card here (default: RUN_DIR)")
    card.add_argument(
        "--goal-flags",
        action="store_true",
        help="also record the goals doing nothing meets or no agent can (plays the do-nothing "
        "worlds once, cached)",
    )
    card.add_argument(
        "--do-nothing-worlds",
        type=int,
        default=8,
        metavar="N",
        help="--goal-flags: seeded worlds per goal the do-nothing agent plays (default 8)",
    )
    card.add_argument(
        "--reask",
        type=int,
        metavar="K",
        help="--verify of a greedy run: also ask the run's model again for K of its answered "
        "steps (a seeded choice), each prompt rebuilt from the records, and print how many "
        "answers are the recorded ones (a figure: rounding on other hardware can flip a token)",
    )
    card.add_argument(
        "--reask-seed",
        type=int,
        default=0,
        metavar="S",
        help="--reask: the seed of the choice of steps (default 0)",
    )

    leaderboard = commands.add_parser(
        "leaderboard",
        help="write a static leaderboard site from results cards (and a Markdown table)",
        description="Set cards beside each other and beside the published numbers (the "
        "CrafText paper's, BALROG's): one offline HTML page, a sortable table per difficulty "
        "and protocol, and Markdown tables. Give each card as CARD=RUN_DIR: its run is "
        "replayed and every figure of the card recomputed, and only cards so checked are "
        "ranked. A card given alone proves nothing, whatever replay it records: it needs "
        "--unverified and goes in a table headed as not replayed here.",
    )
    leaderboard.add_argument(
        "cards",
        nargs="+",
        metavar="CARD[=RUN_DIR]",
        help="card.json files (each once), each with the run directory it was written from",
    )
    leaderboard.add_argument(
        "--out",
        metavar="DIR",
        help="the site's folder (absent, empty, or an earlier leaderboard, replaced whole)",
    )
    leaderboard.add_argument(
        "--markdown", metavar="FILE", help="also write the cards as a Markdown table"
    )
    leaderboard.add_argument(
        "--unverified",
        action="store_true",
        help="also show cards given without a run to replay (whatever replay a card records), "
        "in tables of their own headed as not replayed here, never ranked",
    )

    view = commands.add_parser(
        "view",
        help="write a run's HTML report with episode replays (RUN_DIR/report/index.html)",
        description="Replay every episode of a run with Craftax's pixel renderer and write a "
        "static, offline HTML report: results, charts, and a frame-by-frame page per episode. "
        "With --episode and --gif, export one episode as an animation instead.",
    )
    view.add_argument("run_dir", help="a run's output directory")
    view.add_argument(
        "--episode",
        help="an episode id (or index): render its page alone, or export it with --gif",
    )
    view.add_argument(
        "--gif",
        metavar="OUT",
        help="write --episode as an animated GIF (.gif) or MP4 (.mp4, ffmpeg)",
    )
    view.add_argument(
        "--compare",
        metavar="OTHER_RUN",
        action="append",
        help="another run (e.g. the expert's) whose row is shown beside this run's; repeat for "
        "more",
    )
    view.add_argument(
        "--sample",
        type=int,
        metavar="N",
        help="render N episodes drawn at random (--seed) from those the filters keep; the run "
        "page lists the rest without a replay",
    )
    view.add_argument("--seed", type=int, default=0, help="the --sample draw's seed (0)")
    view.add_argument(
        "--categories",
        action="append",
        help="render only episodes of these goal sets (comma-separated or repeated)",
    )
    view.add_argument(
        "--class",
        dest="classes",
        action="append",
        help="render only episodes of these scenario classes (Achievements, Conditional, "
        "Localization, Build; comma-separated or repeated)",
    )
    view.add_argument(
        "--outcome",
        action="append",
        help="render only episodes that ended so (success, timeout, death, not_started; "
        "comma-separated or repeated)",
    )
    view.add_argument("--no-progress", action="store_true", help="hide the progress bar")
    _goal_status_flags(view)

    _settings_command(
        commands,
        "plan",
        PlannerConfig,
        help="generate step-by-step plans for instructions (the input of PPO-T+)",
        description="Ask a planner model for a plan of at most --max-steps numbered steps for "
        "every instruction and paraphrase of the chosen categories. Resumes by default.",
    )
    _plan_score_parser(commands)
    _settings_command(
        commands,
        "ground",
        GroundConfig,
        help="ask the model for the goal of every instruction text and score its readings",
        description="Ask the model for every instruction text's goal as JSON (required and "
        "forbidden achievements) and score the answers against the dataset: exact match, "
        "per-field precision and recall, confusions. Resumes like eval; `report` prints it.",
    )
    return parser


def _plan_score_parser(commands: Any) -> None:
    score = commands.add_parser(
        "plan-score",
        help="score plans by playing them: each step read into a skill, the skills played in "
        "seeded worlds, the instruction's checker scoring each episode",
        description="Read a plans file ({text: plan}) or a candidates file ({text: [plan, "
        "...]}), read each step into the skills catalogue's skills, play them in order, "
        "strictly, in --worlds seeded worlds per text, and write OUT/scores.json (per plan: "
        "success with its interval, steps read and unread, first failures; per split) and "
        "OUT/best.json (each text's best plan). Resumes by default.",
    )
    score.add_argument("plans", help="the plans or candidates JSON file")
    score.add_argument("--out", required=True, metavar="DIR", help="the folder to write")
    score.add_argument(
        "--worlds",
        type=int,
        default=4,
        metavar="K",
        help="selection worlds per plan, where each text's best plan is chosen (4)",
    )
    score.add_argument(
        "--held-out-worlds",
        type=int,
        default=4,
        metavar="H",
        help="worlds, apart from the selection worlds and eval's, where each text's first and "
        "best plans are played again (4; 0: none)",
    )
    score.add_argument(
        "--eval-worlds",
        action="store_true",
        help="choose in eval's worlds (the seed's) instead of plan-score's selection worlds",
    )
    score.add_argument("--seed", type=int, default=0, help="the worlds' seed (0)")
    score.add_argument("--dataset", help="dataset source (as eval's --dataset)")
    score.add_argument(
        "--variant", choices=["full", "classic"], default=None, help="Craftax variant (full)"
    )
    score.add_argument(
        "--splits",
        action="append",
        help="score only texts of these dataset splits (comma-separated or repeated)",
    )
    score.add_argument("--limit", type=int, metavar="N", help="score only the first N texts")
    score.add_argument(
        "--skip-unknown-texts",
        action="store_true",
        help="skip texts the dataset does not have instead of refusing the file",
    )
    score.add_argument(
        "--batch-size", type=int, default=32, metavar="N", help="episodes in flight (32)"
    )
    score.add_argument(
        "--skill-steps",
        type=int,
        default=None,
        metavar="N",
        help="steps one skill may take before it fails (60)",
    )
    score.add_argument(
        "--export",
        action="append",
        choices=["sft", "dpo"],
        help="also write OUT/sft.jsonl (plans at or above --threshold) or OUT/dpo.jsonl "
        "(better against worse candidates by --margin); repeatable",
    )
    score.add_argument("--threshold", type=float, default=0.5, help="sft: least success rate (0.5)")
    score.add_argument(
        "--margin", type=float, default=0.25, help="dpo: least difference of success (0.25)"
    )
    score.add_argument(
        "--pairs-per-text",
        type=int,
        default=4,
        metavar="N",
        help="dpo: the most pairs one text gives, widest margins first (4)",
    )
    score.add_argument("--restart", action="store_true", help="discard OUT's journal")
    score.add_argument("--no-progress", action="store_true", help="hide the progress bar")


def _settings(args: argparse.Namespace) -> Any:
    targets: list[FlagTarget] = args.flag_targets
    base = load_config_file(args.config) if args.config else {}
    return build_settings(args.settings_class, base, given_settings(args, targets))


def _progress_bar(enabled: bool, unit: str = "episode") -> Any:
    if not enabled:
        return None
    from tqdm import tqdm

    def factory(total: int, initial: int) -> Any:
        return tqdm(total=total, initial=initial, unit=unit, dynamic_ncols=True)

    return factory


def cmd_eval(args: argparse.Namespace) -> int:
    from llm_agents.agents import NoModel, agent_class
    from llm_agents.evaluation.runner import execute_run, open_model, prepare_run
    from llm_agents.judging.report import report_run

    config: EvalConfig = _settings(args)
    prepared = prepare_run(config)
    needs_model = agent_class(config.agent).needs_model
    player = config.model if needs_model else "the scripted expert"
    where = f" on Ray ({config.ray_workers} workers)" if config.ray else ""
    banner = (
        f"evaluating {player} ({config.agent}) on {', '.join(config.categories)} "
        f"({config.variant.value} Craftax) -> {config.output_dir}{where}"
    )
    progress = _progress_bar(not args.no_progress)
    try:
        if config.ray:
            from llm_agents.evaluation.ray_runner import run_on_ray

            print(banner, file=sys.stderr)
            outcome = run_on_ray(prepared, progress=progress)
        else:
            commit = prepared.identity.model_revision
            with open_model(config, commit) if needs_model else NoModel() as model:
                print(banner, file=sys.stderr)
                outcome = execute_run(prepared, model, progress=progress)
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
    return 0 if outcome.results.status == "complete" else EXIT_BACKEND_FAILURE


def _print_report(run_dir: str | Path) -> None:
    from llm_agents.judging.report import report_run

    with contextlib.suppress(UserError):
        print(report_run(run_dir))


def cmd_ground(args: argparse.Namespace) -> int:
    from llm_agents.evaluation.grounding_run import execute_grounding, prepare_grounding
    from llm_agents.evaluation.runner import open_model
    from llm_agents.judging.grounding_report import report_grounding

    config = _settings(args)
    prepared = prepare_grounding(config)
    with open_model(config, prepared.identity.model_revision) as model:
        print(
            f"grounding {len(prepared.instructions)} instruction texts of "
            f"{', '.join(config.categories)} with {config.model} -> {config.output_dir}",
            file=sys.stderr,
        )
        try:
            results = execute_grounding(
                prepared, model, progress=_progress_bar(not args.no_progress, "text")
            )
        except KeyboardInterrupt:
            print(
                f"\ninterrupted: answers so far are in {config.output_dir}; "
                "rerun the same command to resume",
                file=sys.stderr,
            )
            return EXIT_INTERRUPTED
    print(report_grounding(config.output_dir))
    return 0 if results.status == "complete" else EXIT_BACKEND_FAILURE


def _goal_status_flags(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--goal-status",
        action="store_true",
        help="also show the tables without the goals a do-nothing agent meets or no agent can "
        "meet (with why), and the do-nothing agent's row (its worlds are played once, cached)",
    )
    parser.add_argument(
        "--do-nothing-worlds",
        type=int,
        default=8,
        metavar="N",
        help="--goal-status: seeded worlds per goal the do-nothing agent plays (default 8)",
    )


def _check_goal_status_flags(args: argparse.Namespace, *, gif: bool = False) -> None:
    if args.do_nothing_worlds < 1:
        raise UserError(f"--do-nothing-worlds must be at least 1, not {args.do_nothing_worlds}")
    if args.goal_status and (args.compare or gif):
        raise UserError(
            "--goal-status shows one run's goals: leave out " + ("--gif" if gif else "--compare")
        )


def cmd_report(args: argparse.Namespace) -> int:
    from llm_agents.judging.report import report_run
    from llm_agents.run_data.store import RESULTS_FILE, results_kind

    results_path = Path(args.run_dir) / RESULTS_FILE
    if results_path.is_file() and results_kind(results_path) == "ground":
        from llm_agents.judging.grounding_report import report_grounding

        if args.success_rule or args.compare or args.goal_status:
            raise UserError(
                "a grounding run has no episodes: --success-rule, --compare and --goal-status "
                "do not apply"
            )
        print(report_grounding(args.run_dir))
        return 0

    _check_goal_status_flags(args)
    if args.compare:
        from llm_agents.judging.comparison import compare_runs

        if args.success_rule:
            raise UserError(
                "--success-rule re-scores one run: leave out --compare, or compare runs as they "
                "were scored"
            )

        print(compare_runs(args.run_dir, *args.compare))
        return 0
    print(
        report_run(
            args.run_dir,
            success_rule=args.success_rule,
            goal_status=args.goal_status,
            worlds=args.do_nothing_worlds,
        )
    )
    return 0


def cmd_data(args: argparse.Namespace) -> int:
    from env.dataset import cache_status, load_dataset, load_official, official_splits
    from env.downloads import cache_root

    def counts(goals: dict[str, int]) -> str:
        return ", ".join(f"{category} {count}" for category, count in goals.items())

    def all_counts(dataset: Any) -> str:
        """EASY's categories, then each Medium and Hard split the dataset holds."""
        later = Counter(g.split for g in dataset.goals if not g.split.startswith("easy_"))
        return counts({**dataset.category_goals(), **later})

    if args.action == "show":
        print(f"cache: {cache_root()}")
        for entry in cache_status():
            if not entry.present or entry.source is None:
                print(f"{entry.name}: not cached ({entry.path})")
                continue
            official = ", ".join(entry.official_splits) or "none"
            print(
                f"{entry.name}: {entry.path}\n  from {entry.source.kind} {entry.source.path}"
                f" (version {entry.source.version})\n  goals: {counts(entry.goals)}"
                f"\n  splits equal to the official data: {official}"
            )
        return 0
    if args.action == "fetch":
        dataset = load_official(refresh=args.refresh)
        print(
            f"official data at {dataset.source.version} from {dataset.source.path}\n"
            f"goals: {all_counts(dataset)}"
        )
        return 0
    if not args.path:
        raise UserError("data export needs the JSON file to write: craftext-llm data export PATH")
    dataset = load_dataset(args.dataset)
    target = dataset.save_json(args.path)
    print(
        f"wrote {target}: goals {all_counts(dataset)} "
        f"from {dataset.source.kind} {dataset.source.path}; splits equal to the official data: "
        f"{', '.join(official_splits(dataset)) or 'none'}"
    )
    return 0


def cmd_export(args: argparse.Namespace) -> int:
    from llm_agents.judging.balrog_export import export_balrog

    print(export_balrog(args.run_dir, args.out))
    return 0


def cmd_card(args: argparse.Namespace) -> int:
    from llm_agents.judging.replay_check import RunDoesNotReplay

    try:
        return _card(args)
    except RunDoesNotReplay as refused:
        print(f"craftext-llm: error: {refused}", file=sys.stderr)
        return EXIT_VERIFY_FAILED


def _reask_checks(args: argparse.Namespace) -> None:
    """Refuse `--reask` where it cannot run, before the (long) replay."""
    from llm_agents.evaluation.run_view import read_run
    from llm_agents.judging.reask import check_reask

    check_reask(read_run(args.run_dir), args.reask)


def _print_reask(args: argparse.Namespace) -> None:
    from llm_agents.evaluation.run_view import read_run
    from llm_agents.judging.reask import reask

    found = reask(
        read_run(args.run_dir), args.reask, seed=args.reask_seed, progress=not args.no_progress
    )
    print(
        f"asked the model again for {found.asked} answered steps (seed {args.reask_seed}): "
        f"{found.same} of {found.asked} answers are the recorded ones ({found.seconds:.0f} s)"
    )
    for line in found.differing:
        print(f"  differs: {line}")
    for line in found.not_rebuilt:
        print(f"  not asked: {line}")


def _card(args: argparse.Namespace) -> int:
    from llm_agents.judging.card import build_card, read_card, verify_card, write_card

    if args.do_nothing_worlds < 1:
        raise UserError(f"--do-nothing-worlds must be at least 1, not {args.do_nothing_worlds}")
    if args.reask is not None and args.verify is None:
        raise UserError("--reask asks a verified run's model again: give it with --verify CARD")
    if args.verify is not None:
        if args.out or args.goal_flags:
            raise UserError("--verify checks a card: leave out --out and --goal-flags")
        if args.reask is not None:
            _reask_checks(args)
        differences = verify_card(
            read_card(args.verify), args.run_dir, progress=not args.no_progress
        )
        if differences:
            print(
                f"{args.verify} does NOT match the run in {args.run_dir}: "
                f"{len(differences)} figures differ",
                file=sys.stderr,
            )
            for difference in differences:
                print(f"  {difference}", file=sys.stderr)
            return EXIT_VERIFY_FAILED
        print(
            f"{args.verify} matches the run in {args.run_dir}: its records replay, every "
            "figure recomputed"
        )
        if args.reask is not None:
            _print_reask(args)
        return 0
    if args.out and not Path(args.out).is_dir():
        # Checked before the replay, which can take minutes: a mistyped --out must not cost them.
        raise UserError(f"{args.out} is not a directory to write the card into")
    card = build_card(
        args.run_dir,
        goal_flags_worlds=args.do_nothing_worlds if args.goal_flags else None,
        progress=not args.no_progress,
    )
    json_path, md_path = write_card(card, args.out or args.run_dir)
    figures = card.figures
    print(
        f"wrote {json_path} and {md_path}: success {figures.success.cell()}, "
        f"progression {figures.scores.progression:.1f}"
    )
    return 0


def cmd_leaderboard(args: argparse.Namespace) -> int:
    from llm_agents.viewer.leaderboard import CardsRefused, build_leaderboard, parse_entries

    if not args.out and not args.markdown:
        raise UserError("leaderboard writes --out DIR, --markdown FILE or both: give one")
    try:
        outcome = build_leaderboard(
            parse_entries(args.cards),
            out=args.out,
            markdown=args.markdown,
            unverified=args.unverified,
        )
    except CardsRefused as refused:
        print(f"craftext-llm: error: {refused}", file=sys.stderr)
        for line in refused.details:
            print(f"  {line}", file=sys.stderr)
        return EXIT_VERIFY_FAILED
    for line in outcome:
        print(line)
    return 0


def cmd_view(args: argparse.Namespace) -> int:
    from llm_agents.viewer import build_view, export_episode

    if args.gif is not None and args.episode is None:
        raise UserError("--gif writes one episode: give it with --episode")
    if args.gif is not None and args.compare:
        raise UserError("--compare adds a row to the HTML report: it does not go with --gif")
    _check_goal_status_flags(args, gif=args.gif is not None)
    selection = view_selection(args)
    if args.gif is not None:
        status = export_episode(args.run_dir, args.episode, args.gif)
        print(f"wrote {args.gif} ({status.frames} frames)")
        problems = {args.episode: status} if status.state == "mismatch" else {}
    else:
        outcome = build_view(
            args.run_dir,
            progress=not args.no_progress,
            compare=args.compare or [],
            goal_status=args.goal_status,
            worlds=args.do_nothing_worlds,
            selection=selection,
        )
        listed = f", {outcome.listed} more listed" if outcome.listed else ""
        print(
            f"wrote {outcome.index} ({len(outcome.statuses)} episodes{listed}, "
            f"{outcome.frames} frames, {outcome.size_bytes / 1e6:.1f} MB)"
        )
        problems = outcome.mismatches
    if problems:
        print(
            f"WARNING: {len(problems)} replays do NOT reproduce their recorded episodes "
            "(a bug, or a Craftax / craftext-llm version other than the run's):",
            file=sys.stderr,
        )
        for episode, status in problems.items():
            print(f"  {episode}: {'; '.join(status.problems)}", file=sys.stderr)
        return 1
    return 0


def view_selection(args: argparse.Namespace) -> Any:
    """`view`'s filters and sample as a `Selection`, each name checked."""
    from env.goals import SCENARIO_CLASSES, parse_categories
    from llm_agents.run_data.records import EPISODE_ENDS
    from llm_agents.viewer import Selection

    def names(values: list[str] | None, known: tuple[str, ...], flag: str) -> tuple[str, ...]:
        chosen = tuple(
            part.strip() for value in values or [] for part in value.split(",") if part.strip()
        )
        for name in chosen:
            if name not in known:
                raise UserError(f"unknown {flag} {name!r}; known: {', '.join(known)}")
        return chosen

    filtered = args.sample is not None or args.categories or args.classes or args.outcome
    if args.episode is not None and filtered:
        raise UserError("--episode renders one episode: it does not go with --sample or filters")
    return Selection(
        sample=args.sample,
        seed=args.seed,
        categories=parse_categories(args.categories) if args.categories else (),
        classes=names(args.classes, SCENARIO_CLASSES, "--class"),
        outcomes=names(args.outcome, EPISODE_ENDS, "--outcome"),
        episode=args.episode if args.gif is None else None,
    )


def _planner_tokens(summary: Any) -> str:
    line = f"prompt tokens: {summary.prompt_tokens}"
    if summary.computed_prompt_tokens is not None and summary.prompt_tokens:
        share = summary.computed_prompt_tokens / summary.prompt_tokens
        line += f" ({summary.computed_prompt_tokens} computed, {share:.0%})"
    return line + f"; completion tokens: {summary.completion_tokens}"


def cmd_plan(args: argparse.Namespace) -> int:
    from llm_agents.evaluation.runner import open_model
    from llm_agents.planning import PlannerConfig, plan_instructions, planned_instructions

    config: PlannerConfig = _settings(args)
    instructions, provenance = planned_instructions(config)
    with open_model(config) as model:
        summary = plan_instructions(
            instructions, model, config, provenance, progress=not args.no_progress
        )
    print(
        f"{summary.instructions} instructions: {summary.valid} valid, {summary.repaired} repaired, "
        f"{summary.failed} failed, {summary.errors} backend errors, {summary.resumed} resumed"
        + (
            f"; {config.candidates} samples each, {summary.duplicates} duplicates not kept\n"
            if config.candidates
            else "\n"
        )
        + f"{_planner_tokens(summary)}\n"
        f"plans: {summary.output}\nsidecar: {summary.sidecar}"
    )
    if summary.errors:
        print("some requests failed; rerun the same command to retry them", file=sys.stderr)
        return EXIT_BACKEND_FAILURE
    return 0


def cmd_plan_score(args: argparse.Namespace) -> int:
    from llm_agents.planning.scoring import score_plans

    config = score_config(args)
    summary = score_plans(config, progress=_progress_bar(not args.no_progress))
    exports = "".join(f"\n{kind}: {lines} lines" for kind, lines in summary.exports.items())
    if summary.exports:
        exports += "\nkept out of the exports: " + ", ".join(
            f"{why} {count}" for why, count in summary.kept_out.items()
        )
    print(
        f"{summary.texts} texts, {summary.plans} plans, {summary.episodes} episodes "
        f"({summary.resumed} resumed) in {summary.wall_s:.1f} s\n"
        f"scores: {summary.scores}\nbest: {summary.best}{exports}"
    )
    return 0


def score_config(args: argparse.Namespace) -> Any:
    """`plan-score`'s settings from its parsed flags (a bad value: one `UserError` line)."""
    from pydantic import ValidationError

    from llm_agents.planning.scoring import ScoreConfig

    given = {
        "plans": Path(args.plans),
        "out": Path(args.out),
        "worlds": args.worlds,
        "held_out_worlds": args.held_out_worlds,
        "eval_worlds": args.eval_worlds,
        "seed": args.seed,
        "dataset": args.dataset,
        "splits": tuple(
            part.strip() for value in args.splits or [] for part in value.split(",") if part.strip()
        ),
        "limit": args.limit,
        "skip_unknown_texts": args.skip_unknown_texts,
        "batch_size": args.batch_size,
        "export": tuple(dict.fromkeys(args.export or [])),
        "threshold": args.threshold,
        "margin": args.margin,
        "pairs_per_text": args.pairs_per_text,
        "restart": args.restart,
    }
    if args.variant is not None:
        given["variant"] = args.variant
    if args.skill_steps is not None:
        given["skill_steps"] = args.skill_steps
    try:
        config = ScoreConfig.model_validate(given)
    except ValidationError as err:
        first = err.errors()[0]
        where = "--" + "-".join(str(part) for part in first["loc"]).replace("_", "-")
        raise UserError(f"{where}: {first['msg']}") from None
    return config


COMMANDS = {
    "eval": cmd_eval,
    "report": cmd_report,
    "view": cmd_view,
    "plan": cmd_plan,
    "plan-score": cmd_plan_score,
    "ground": cmd_ground,
    "data": cmd_data,
    "export": cmd_export,
    "card": cmd_card,
    "leaderboard": cmd_leaderboard,
}


def main(argv: Sequence[str] | None = None) -> int:
    from llm_agents.evaluation.runner import BackendFailure

    args = build_parser().parse_args(argv)
    logging.basicConfig(
        level=logging.DEBUG if args.verbose else logging.WARNING,
        format="%(levelname)s %(name)s: %(message)s",
    )
    try:
        return COMMANDS[args.command](args)
    except BackendFailure as err:
        print(f"craftext-llm: error: {err}", file=sys.stderr)
        return EXIT_BACKEND_FAILURE
    except UserError as err:
        print(f"craftext-llm: error: {err}", file=sys.stderr)
        return EXIT_USER_ERROR
    except KeyboardInterrupt:
        print("\ninterrupted", file=sys.stderr)
        return EXIT_INTERRUPTED


if __name__ == "__main__":
    sys.exit(main())
