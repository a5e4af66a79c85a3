"""``ops-bench recipes``: the learning recipes trained side by side on this machine, then compared.

Each recipe (``ops_experiments/yaml/recipes.yaml``, or ``--recipes-file``) is the command line
that trains a model folder from scratch with a periodic test evaluation: ``distill`` (a
student of the privileged oracle; it writes ``learning.csv``) or ``train`` (SAC, PPO, ...;
``learning.csv`` is made from its evaluations in ``logs/``, as ``ops-bench ship-model`` does).
For each recipe named, one after the other, this runs ``ros2 run ops_gym_bridge COMMAND ...
--mode MODE --seed SEED --max-minutes MINUTES --out OUT/NAME`` in a process of its own, its
output shown line by line under the recipe's name, and then draws every stored run with ``ops-bench
learning-curves``: P_N / P_max of the test evaluation against wall minutes and against
environment steps, the paper's TD3 budget (300,000 steps) marked, and a table of the first
minute and step where each reached 0.95.

Resumable: a recipe whose folder holds a finished run (``metadata.json`` not marked
interrupted, and ``learning.csv``) is not trained again; a folder left by a failed or
interrupted run is trained afresh. Ctrl-C stops the run under way (it saves what it has) and
the bench. Wall minutes depend on the machine's load: run it alone, and read
``load_average`` in ``runs.json``.

    ops-bench recipes --mode hard --minutes 20   # runs in runs/recipes/hard; the figure
    # docs/figures/recipes_hard.png, the table docs/results/learned_recipes/side_by_side_hard
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import signal
import subprocess
import sys
from pathlib import Path

from . import REPO, learning_curves
from .processes import executable
from .ship_model import learning_curve

RECIPES = REPO / "ops_experiments" / "ops_experiments" / "yaml" / "recipes.yaml"


def read_recipes(path: Path) -> dict[str, list[str]]:
    """name -> the command line after ``ros2 run ops_gym_bridge`` (its first word distill or
    train), as the YAML file lists them."""
    import yaml

    data = yaml.safe_load(Path(path).read_text()) or {}
    if not isinstance(data, dict):
        raise ValueError(f"{path}: expected a mapping of recipe name -> command line")
    recipes = {}
    for name, command in data.items():
        if not isinstance(command, list) or not command or command[0] not in ("distill", "train"):
            raise ValueError(
                f"{path}: recipe {name!r} must be a list starting with distill or train "
                f"(got {command!r})"
            )
        recipes[str(name)] = [str(word) for word in command]
    return recipes


def finished(folder: Path) -> bool:
    """Whether ``folder`` holds a run that ended by itself (not interrupted, not failed)."""
    meta = folder / "metadata.json"
    if not meta.exists() or not (folder / "learning.csv").exists():
        return False
    return not json.loads(meta.read_text()).get("interrupted", False)


def command_of(recipe: list[str], args, folder: Path) -> list[str]:
    """The recipe's full command line for this bench's mode, seed, minutes and folder."""
    return [
        *executable("ops_gym_bridge", recipe[0]),
        *recipe[1:],
        *("--stage", str(args.stage), "--mode", args.mode, "--seed", str(args.seed)),
        *("--max-minutes", f"{args.minutes:g}", "--out", str(folder)),
    ]


def train_recipe(name: str, command: list[str], folder: Path) -> int:
    """Run one recipe's command afresh in ``folder``, its output prefixed with the name."""
    if folder.exists():
        shutil.rmtree(folder)
    folder.parent.mkdir(parents=True, exist_ok=True)
    print(f"[recipes] {name}: {' '.join(command)}", flush=True)
    proc = subprocess.Popen(
        command,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        stdin=subprocess.DEVNULL,
        start_new_session=True,  # Ctrl-C reaches it once, from this process
    )
    try:
        for line in proc.stdout:
            print(f"[recipes {name}] {line.rstrip()}", flush=True)
        code = proc.wait()
    except KeyboardInterrupt:
        os.killpg(proc.pid, signal.SIGINT)  # the run saves what it has
        proc.wait()
        raise
    if code == 0 and not (folder / "learning.csv").exists() and (folder / "logs").is_dir():
        learning_curve(folder / "logs", folder / "learning.csv")  # train's evaluations
    return code


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="ops-bench recipes",
        description=__doc__.split("\n\n")[0],
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    p.add_argument("--recipes", nargs="+", metavar="NAME", help="recipes to run (default: all)")
    p.add_argument("--recipes-file", type=Path, default=RECIPES, help="the recipes (YAML)")
    p.add_argument("--stage", type=int, default=5)
    p.add_argument("--mode", default="hard", choices=("easy", "medium", "hard", "extreme"))
    p.add_argument("--minutes", type=float, default=20.0, help="wall minutes per recipe")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", type=Path, help="the runs (default: runs/recipes/MODE)")
    p.add_argument("--figure", help="default: docs/figures/recipes_MODE.png")
    p.add_argument(
        "--results", help="its table.md (default: docs/results/learned_recipes/side_by_side_MODE)"
    )
    p.add_argument("--list", action="store_true", help="print the recipes and exit")
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        recipes = read_recipes(args.recipes_file)
    except (OSError, ValueError) as exc:
        print(f"ops-bench recipes: {exc}", file=sys.stderr)
        return 2
    unknown = sorted(set(args.recipes or ()) - set(recipes))
    if unknown or args.minutes <= 0:
        why = f"unknown recipe(s) {unknown}" if unknown else "--minutes must be > 0"
        print(f"ops-bench recipes: {why}; recipes: {', '.join(recipes)}", file=sys.stderr)
        return 2
    if args.list:
        for name, command in recipes.items():
            print(f"{name}: ros2 run ops_gym_bridge {' '.join(command)}")
        return 0
    out = args.out or REPO / "runs" / "recipes" / args.mode
    failed = []
    for name in args.recipes or recipes:
        folder = out / name
        if finished(folder):
            print(f"[recipes] {name}: stored in {folder}", flush=True)
            continue
        code = train_recipe(name, command_of(recipes[name], args, folder), folder)
        if code != 0 or not finished(folder):
            failed.append(name)
            print(f"[recipes] {name}: failed (exit {code})", file=sys.stderr, flush=True)
    runs = [name for name in recipes if finished(out / name)]
    out.mkdir(parents=True, exist_ok=True)
    record = {"mode": args.mode, "minutes": args.minutes, "runs": runs}
    record["load_average"] = os.getloadavg()
    (out / "runs.json").write_text(json.dumps(record, indent=2))
    if runs:
        learning_curves.main(
            [arg for name in runs for arg in ("--run", f"{name}={out / name}")]
            + ["--figure", args.figure or f"docs/figures/recipes_{args.mode}.png"]
            + [
                "--results",
                args.results or f"docs/results/learned_recipes/side_by_side_{args.mode}",
            ]
        )
    return 1 if failed else 0


if __name__ == "__main__":
    raise SystemExit(main())
