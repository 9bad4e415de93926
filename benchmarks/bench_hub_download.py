"""A hub id's first use, as a user meets it: `craftext-llm eval --model hf:ORG/NAME` from an
empty hub cache, the model downloaded from a hub served on loopback (`tests/hub_server.py`,
the real `huggingface_hub` client talking to it through `HF_ENDPOINT`), then the eval run; and
the same command again with the model cached; and, apart, the download alone (resolve and
fetch into another empty cache, in a fresh process). Prints the wall time of each and the
download's progress bar as stderr showed it.

The model is the tests' tiny Llama (`tests/tiny_llm.py`: random weights, the embedded model's
tokenizer), or any local model folder (`--model-dir`), served as `bench-org/NAME`.

    python benchmarks/bench_hub_download.py [--model-dir DIR] [--episodes 1] [--max-steps 2]
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "tests"))

from hub_server import HubServer  # noqa: E402
from tiny_llm import build_tiny_llm, folder_files  # noqa: E402

#: Resolves and downloads a model spec's hub id, as `eval` does before its run.
FETCH = (
    "import sys; from llm_agents.backends import model_revision, parse_model_spec; "
    "from llm_agents.backends.base import locate_model; spec = sys.argv[1]; "
    "model_revision(spec, {}); locate_model('hf', parse_model_spec(spec).name, None)"
)


def eval_command(model: str, out: Path, episodes: int, max_steps: int) -> list[str]:
    return [
        sys.executable, "-m", "llm_agents.cli", "eval", "--model", model,
        "--variant", "classic", "--categories", "combo", "--max-steps", str(max_steps),
        "--limit", str(episodes), "--batch-size", "1", "--max-tokens", "4",
        "--backend-option", "threads=1", "--output-dir", str(out), "--no-progress",
    ]  # fmt: skip


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--model-dir", type=Path, help="a model folder to serve (default: tiny)")
    parser.add_argument("--episodes", type=int, default=1)
    parser.add_argument("--max-steps", type=int, default=2)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix="bench-hub-") as scratch:
        root = Path(scratch)
        folder = args.model_dir
        if folder is None:
            from llm_agents.backends.embedded import embedded_model_dir

            folder = build_tiny_llm(root / "tiny", embedded_model_dir())
        hub = HubServer()
        repo_id = f"bench-org/{folder.name}"
        commit = hub.commit(repo_id, folder_files(folder))
        size = sum(len(data) for data in folder_files(folder).values())
        env = {
            **os.environ,
            "HF_HOME": str(root / "hf-home"),
            "HF_ENDPOINT": hub.url,
            "PYTHONPATH": str(REPO),
        }
        env.pop("HF_HUB_OFFLINE", None)
        print(f"serving {repo_id} ({size / 1e6:.1f} MB, commit {commit[:12]}) at {hub.url}")
        with hub.running():
            for label, out in (("empty hub cache", "first"), ("model cached", "second")):
                command = eval_command(f"hf:{repo_id}", root / out, args.episodes, args.max_steps)
                start = time.perf_counter()
                done = subprocess.run(command, env=env, capture_output=True, text=True, cwd=REPO)
                wall = time.perf_counter() - start
                if done.returncode != 0:
                    sys.exit(f"eval failed ({done.returncode}):\n{done.stderr}")
                print(f"\n== {label}: download + eval wall time {wall:.1f} s")
                bar = [
                    line
                    for line in done.stderr.replace("\r", "\n").splitlines()
                    if line.startswith("downloading ")
                ]
                print("progress bar, as stderr showed it:" if bar else "no download")
                for line in bar:
                    print(f"  {line}")
            fetch = [sys.executable, "-c", FETCH, f"hf:{repo_id}"]
            start = time.perf_counter()
            alone = {**env, "HF_HOME": str(root / "hf-home-alone")}
            done = subprocess.run(fetch, env=alone, capture_output=True, text=True, cwd=REPO)
            wall = time.perf_counter() - start
            if done.returncode != 0:
                sys.exit(f"the download failed ({done.returncode}):\n{done.stderr}")
            print(f"\n== the download alone (a fresh process, imports included): {wall:.1f} s")
        print(f"\ncommand: {' '.join(command[1:])} (with HF_ENDPOINT={hub.url}, empty HF_HOME)")


if __name__ == "__main__":
    main()
