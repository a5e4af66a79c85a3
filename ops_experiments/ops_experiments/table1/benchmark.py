"""``ros2 run ops_gym_bridge benchmark``: the paper's benchmark (section 3, Table 1, Figures 7-11
and 17), as a set of independent runs, in parallel, resumable.

Profiles (``--profile``; ``ops_experiments/ops_experiments/yaml/profiles.yaml``):

* ``paper``: N = 5, easy / medium / hard, PPO / TD3 / SAC with the paper's hyper-parameters
  (``yaml/*.yaml``) and 300,000 training steps, 10 seeds; hard mode at N = 1...6 for TD3
  and SAC (Figures 9 and 10). Hundreds of core-hours: use ``--ray-address`` on a cluster.
* ``quick``: the same protocol with 3 seeds and the budgets this 2-core machine finishes in a few
  hours; Figures 9 / 10 with one seed per extra N.
* ``smoke``: seconds, for the tests (N = 2, tiny budgets and networks).

Every profile also evaluates each no-training controller of
:data:`ops_controller_ros.controllers.CONTROLLERS` (SPGD-PID, ...) in the same protocol.

Each run executes in its own process (``python -m ops_experiments.table1.bench_worker``, torch
on one thread): ``--jobs`` at once on this machine (default: one per core), or as Ray tasks of one
CPU each with ``--ray-address`` (``auto``, ``HOST:PORT`` or ``local``: a local Ray instance), as
many as the cluster has CPUs, the project shipped to the nodes (:mod:`.ray_pool`). A finished run
is stored at once and atomically in ``OUT/runs/<id>/``; ``OUT/work/<id>/`` holds runs in progress.
Running the same command again skips every stored run and resumes the others from their last save.
SIGINT (Ctrl-C) or SIGTERM stops every run in progress, each saving its model, and exits with 130.
``ros2 run ops_gym_bridge report OUT --out DIR`` turns stored runs into Table 1 and the figures.
"""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ops_contract.config import DETECTORS, MODES
from ops_contract.observation import OBSERVATION_SETS
from ops_controller_ros.controllers import BENCHMARK_PARAMS, CONTROLLERS

from .. import cli_args
from ..hyperparams import ALGOS, BENCHMARK_SETS, profiles
from .bench_worker import EXIT_INTERRUPTED, read_json, write_json
from .ray_pool import RayAddressError, RayPool, check_address

PAPER_MODES = ("easy", "medium", "hard")

#: The profiles (``yaml/profiles.yaml``): ``timesteps`` per algorithm;
#: ``stage_runs``: the extra hard-mode stages of Figures 9 and 10 (algorithms, stages, seeds);
#: ``traces``: the (algo, mode) runs whose testing episode traces are kept (Figure 17).
PROFILES: dict[str, dict[str, Any]] = profiles()
#: Rough seconds per training step at N = 5 on one core (measured, torch 2.13, SB3 2.7), for the
#: time-left estimate until this session has measured its own.
PRIOR_S_PER_STEP = {"ppo": 0.0012, "td3": 0.009, "sac": 0.014}


def run_id(kind: str, name: str, stage: int, mode: str, seed: int | None) -> str:
    return f"n{stage}_{mode}_{name}" + ("" if seed is None else f"_s{seed}")


def plan(args) -> list[dict[str, Any]]:
    """The runs of the benchmark, cheapest and most informative first: the controllers, then
    every (mode, algo) cell for seed 0, then seed 1, ...; the extra stages last."""
    prof = PROFILES[args.profile]
    evaluation = dict(prof["eval"])
    if args.eval_seeds:
        evaluation["seeds"] = list(args.eval_seeds)
    if args.eval_episodes:
        evaluation["episodes"] = int(args.eval_episodes)
    common = {
        "detector": args.detector,
        "observation": args.observation,
        "episode_steps": prof["episode_steps"],
        "eval": evaluation,
        "save_every": args.save_every,
    }
    if args.hyperparams_set != "paper":  # (runs stored before the option hold no key)
        common["hyperparams_set"] = args.hyperparams_set
    rig = cli_args.resolve_rig(args.realism, args.rig)  # (checked by run first)
    if rig:  # (nor before the rig)
        common["rig"] = rig
    modes = args.modes or prof["modes"]
    algos = args.algos or prof["algos"]
    seeds = prof["seeds"] if args.seeds is None else args.seeds
    stage = args.stage or prof["stage"]
    specs: list[dict[str, Any]] = []
    for name in args.controllers if args.controllers is not None else CONTROLLERS:
        for mode in modes:
            specs.append(
                {
                    **common,
                    "id": run_id("controller", name, stage, mode, None),
                    "kind": "controller",
                    "controller": name,
                    "controller_params": dict(BENCHMARK_PARAMS.get(name, {})),
                    "stage": stage,
                    "mode": mode,
                    "seed": None,
                    "transfer_modes": list(modes),
                }
            )

    def train_spec(algo, st, mode, seed, traces):
        steps = args.timesteps or prof["timesteps"].get(algo, max(prof["timesteps"].values()))
        return {
            **common,
            "id": run_id("train", algo, st, mode, seed),
            "kind": "train",
            "algo": algo,
            "stage": st,
            "mode": mode,
            "seed": seed,
            "timesteps": int(steps),
            "hyperparams": list(prof["hyperparams"].get(algo, [])) + list(args.hyperparams),
            # Figure 11 needs every mode of the profile, also when --modes runs a few of them.
            "transfer_modes": list(dict.fromkeys([*prof["modes"], *modes])) if st == stage else [],
            "traces": traces,
        }

    for seed in seeds:
        for mode in modes:
            for algo in sorted(algos, key=lambda a: PRIOR_S_PER_STEP.get(a, 0.01)):
                traces = (algo, mode) in [tuple(t) for t in prof["traces"]]
                specs.append(train_spec(algo, stage, mode, seed, traces))
    extra = prof["stage_runs"]
    stages = extra["stages"] if args.extra_stages is None else args.extra_stages
    if "hard" in modes:
        for seed in extra["seeds"] if args.seeds is None else args.seeds:
            for st in stages:
                for algo in extra["algos"]:
                    if algo in algos and st != stage:
                        specs.append(train_spec(algo, st, "hard", seed, False))
    return specs


# ------------------------------------------------------------------------------ execution
def worker_command(spec_path: Path, out: Path) -> list[str]:
    return [sys.executable, "-m", "ops_experiments.table1.bench_worker", str(spec_path), str(out)]


@dataclass
class Progress:
    """Runs done / total and an estimate of the time left."""

    total: int
    jobs: int
    done: int = 0
    t0: float = field(default_factory=time.monotonic)
    rates: dict[str, list[float]] = field(default_factory=dict)

    def cost(self, spec: dict, out: Path) -> float:
        if spec["kind"] != "train":
            return 5.0
        algo = spec["algo"]
        r = self.rates.get(algo)
        per_step = (sum(r) / len(r)) if r else PRIOR_S_PER_STEP.get(algo, 0.01)
        per_step *= max(spec["stage"], 1) / 5 if not r else 1.0
        prog = read_json(out / "work" / spec["id"] / "progress.json") or {}
        left = spec["timesteps"] - int(prog.get("timesteps", 0))
        return per_step * max(left, 0) + 10.0

    def learn(self, record: dict) -> None:
        spec = record["spec"]
        if spec["kind"] == "train" and record.get("train_wall_s") and spec["stage"] == 5:
            self.rates.setdefault(spec["algo"], []).append(
                record["train_wall_s"] / max(record["timesteps"], 1)
            )

    def line(self, remaining: list[dict], out: Path) -> str:
        left = sum(self.cost(s, out) for s in remaining) / max(self.jobs, 1)
        el = time.monotonic() - self.t0
        return (
            f"[benchmark] {self.done}/{self.total} runs done; elapsed {_hms(el)}; "
            f"time left ~{_hms(left)}"
        )


_ERROR_LINE = re.compile(r"^(\w+(?:\.\w+)*(?:Error|Exception|Interrupt)\b.*)$", re.M)


def last_error(log: Path) -> str | None:
    """The last exception line of a run's log (``ImportError: ...``), so that a failure's
    cause is on the benchmark's own output and not only in the log."""
    try:
        found = _ERROR_LINE.findall(log.read_text(errors="replace"))
    except OSError:
        return None
    return found[-1].strip()[:200] if found else None


def failure_text(code: int, log: Path) -> str:
    """``exit N`` and, where the log has one, its last exception: ``exit 1: ImportError: ...``."""
    cause = last_error(log)
    return f"exit {code}: {cause}" if cause else f"exit {code}"


def _hms(s: float) -> str:
    s = int(s)
    return f"{s // 3600}h{(s % 3600) // 60:02d}m{s % 60:02d}s"


class Stop(Exception):
    """SIGINT / SIGTERM reached the benchmark."""

    def __init__(self, signum: int):
        super().__init__(signal.Signals(signum).name)
        self.signum = signum


def _raise_stop(signum, frame):
    raise Stop(signum)


class LocalPool:
    """``jobs`` worker processes at a time, each in its own session (the benchmark forwards the
    stop signal itself, exactly once)."""

    def __init__(self, jobs: int, out: Path, log_dir: Path):
        self.jobs, self.out, self.log_dir = jobs, out, log_dir
        self.running: dict[str, tuple[subprocess.Popen, Any]] = {}

    def free(self) -> bool:
        return len(self.running) < self.jobs

    def submit(self, spec: dict, spec_path: Path) -> None:
        log = open(self.log_dir / f"{spec['id']}.log", "a")  # noqa: SIM115 (closed in poll)
        env = {**os.environ, "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
        proc = subprocess.Popen(
            worker_command(spec_path, self.out),
            stdin=subprocess.DEVNULL,
            stdout=log,
            stderr=subprocess.STDOUT,
            start_new_session=True,
            env=env,
        )
        self.running[spec["id"]] = (proc, log)

    def poll(self, timeout: float) -> list[tuple[str, int]]:
        deadline = time.monotonic() + timeout
        while True:
            finished = []
            for rid, (proc, log) in list(self.running.items()):
                code = proc.poll()
                if code is not None:
                    log.close()
                    del self.running[rid]
                    finished.append((rid, code))
            if finished or time.monotonic() >= deadline or not self.running:
                return finished
            time.sleep(0.2)

    def stop(self, grace_s: float) -> None:
        for proc, _ in self.running.values():
            if proc.poll() is None:
                proc.send_signal(signal.SIGTERM)
        deadline = time.monotonic() + grace_s
        for proc, log in self.running.values():
            try:
                proc.wait(max(deadline - time.monotonic(), 0.1))
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
            log.close()
        self.running.clear()


class _Scheduler:
    """The run loop of :func:`execute`: starts runs while the pool has room, collects finished
    ones, tries a failed run again after a delay (``--retries``), prints progress."""

    def __init__(self, args, specs: list[dict], todo: list[dict], out: Path, pool, prog):
        self.args, self.out, self.pool, self.prog = args, out, pool, prog
        self.by_id = {s["id"]: s for s in specs}
        self.queue = list(todo)
        self.failed: list[str] = []
        self.attempts: dict[str, int] = {}
        self.retry_at: dict[str, float] = {}
        self.last_line = time.monotonic()

    def busy(self) -> bool:
        return bool(self.queue or self.pool.running or self.retry_at)

    def start_ready(self) -> None:
        for rid, at in list(self.retry_at.items()):
            if time.monotonic() >= at:
                del self.retry_at[rid]
                self.queue.append(self.by_id[rid])
        while self.queue and self.pool.free():
            spec = self.queue.pop(0)
            path = self.out / "specs" / f"{spec['id']}.json"
            write_json(path, spec)
            resumed = (self.out / "work" / spec["id"] / "model.zip").exists()
            print(
                f"[benchmark] start {spec['id']}" + (" (resuming)" if resumed else ""), flush=True
            )
            self.pool.submit(spec, path)
        if not self.pool.running:  # only retries left: wait for them
            time.sleep(1.0)

    def collect(self) -> None:
        for rid, code in self.pool.poll(timeout=1.0):
            self._finished(rid, code)
            self._status()
        if time.monotonic() - self.last_line > self.args.status_every:
            self._status()

    def _finished(self, rid: str, code: int) -> None:
        args, log = self.args, self.out / "logs" / f"{rid}.log"
        rec = read_json(self.out / "runs" / rid / "run.json")
        if code == 0 and rec:
            self.prog.done += 1
            self.prog.learn(rec)
            fp = rec["final_power"]
            print(
                f"[benchmark] done {rid}: final P_N/P_max train {fp['train']:.4f}, "
                f"test {fp['test']:.4f} ({rec['wall_s']:.0f} s)",
                flush=True,
            )
        elif self.attempts.get(rid, 0) < args.retries:
            # e.g. a package being edited under a long benchmark: try again later (what the run
            # had trained is in its work directory).
            self.attempts[rid] = self.attempts.get(rid, 0) + 1
            self.retry_at[rid] = time.monotonic() + args.retry_delay
            print(
                f"[benchmark] run {rid} failed ({failure_text(code, log)}); "
                f"retry {self.attempts[rid]}/{args.retries} in {args.retry_delay:.0f} s; "
                f"see {log}",
                file=sys.stderr,
                flush=True,
            )
        else:
            self.failed.append(rid)
            print(
                f"[benchmark] FAILED {rid} ({failure_text(code, log)}); see {log}",
                file=sys.stderr,
                flush=True,
            )

    def _status(self) -> None:
        remaining = self.queue + [self.by_id[r] for r in _running_ids(self.pool)]
        self.prog.jobs = self.pool.jobs  # a Ray cluster's CPUs come and go
        print(self.prog.line(remaining, self.out), flush=True)
        self.last_line = time.monotonic()

    def stop(self, reason) -> None:
        running = list(_running_ids(self.pool))
        print(
            f"\n[benchmark] {reason}: stopping {len(running)} run(s) in progress "
            f"({', '.join(running) or 'none'}); each saves its model",
            file=sys.stderr,
            flush=True,
        )
        self.pool.stop(self.args.grace)
        print(
            f"[benchmark] stopped with {self.prog.done}/{self.prog.total} runs stored; run the "
            "same command again to resume",
            file=sys.stderr,
            flush=True,
        )


def execute(args, specs: list[dict], out: Path) -> int:
    (out / "specs").mkdir(parents=True, exist_ok=True)
    (out / "logs").mkdir(exist_ok=True)
    stored = {s["id"] for s in specs if (out / "runs" / s["id"] / "run.json").exists()}
    todo = [s for s in specs if s["id"] not in stored]
    if args.ray_address:
        pool = RayPool(args.ray_address, args.jobs, out, out / "logs")
    else:
        pool = LocalPool(args.jobs, out, out / "logs")
    prog = Progress(total=len(specs), jobs=pool.jobs, done=len(stored))
    for rid in sorted(stored):
        rec = read_json(out / "runs" / rid / "run.json")
        if rec:
            prog.learn(rec)
    print(
        f"[benchmark] {len(specs)} runs in the plan, {len(stored)} already stored in "
        f"{out / 'runs'}; {len(todo)} to run, "
        + (
            f"one per CPU of the Ray cluster ({args.ray_address}, {pool.jobs} now)"
            if args.ray_address
            else f"{pool.jobs} at a time"
        ),
        flush=True,
    )
    scheduler = _Scheduler(args, specs, todo, out, pool, prog)
    old = {s: signal.signal(s, _raise_stop) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        while scheduler.busy():
            scheduler.start_ready()
            scheduler.collect()
    except Stop as stop:
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        signal.signal(signal.SIGTERM, signal.SIG_IGN)
        scheduler.stop(stop)
        return EXIT_INTERRUPTED
    finally:
        for s, h in old.items():
            signal.signal(s, h)
    if args.ray_address:
        pool.ray.shutdown()
    print(f"[benchmark] finished: {prog.done}/{prog.total} runs stored in {out / 'runs'}")
    if scheduler.failed:
        failed = scheduler.failed
        print(f"[benchmark] {len(failed)} run(s) failed: {', '.join(failed)}", file=sys.stderr)
        return 1
    return 0


def _running_ids(pool) -> list[str]:
    if isinstance(pool, LocalPool):
        return list(pool.running)
    return list(pool.running.values())


# ------------------------------------------------------------------------------ CLI
def build_parser():
    p = cli_args.make_parser(
        "benchmark", "The paper's benchmark (Table 1, Figures 7-11, 17): runs, stored, resumable."
    )
    p.add_argument("--profile", choices=tuple(PROFILES), default="quick", help="protocol size")
    cli_args.add_env_arguments(
        p,
        defaults={"detector": "polarizer", "mode": list(PAPER_MODES)},
        several=("mode",),
        include=("mode", "detector"),
    )
    p.add_argument(
        "--observation",
        choices=OBSERVATION_SETS,
        default="rig",
        help="observation set of the trained agents: rig (what a real stacker measures) or "
        "authors (the authors' CPS_env, with the actual delay-line lengths: the paper's Table 1)",
    )
    cli_args.add_rig_arguments(p, "every controller and training run")
    p.add_argument(
        "--stage", type=cli_args.stage_type, help="stages N of Table 1 (default: the profile's)"
    )
    p.add_argument("--algos", nargs="+", choices=ALGOS, help="(default: the profile's)")
    p.add_argument("--seeds", type=int, nargs="+", help="training seeds (default: the profile's)")
    p.add_argument(
        "--controllers",
        nargs="*",
        choices=CONTROLLERS,
        help="no-training controllers to evaluate (default: every registered one)",
    )
    p.add_argument(
        "--extra-stages",
        type=int,
        nargs="*",
        help="hard-mode stages besides the profile's for Figures 9/10 (default: the profile's)",
    )
    p.add_argument("--timesteps", type=int, help="training steps of every run (overrides)")
    p.add_argument("--eval-seeds", type=int, nargs="+", help="evaluation seeds (overrides)")
    p.add_argument("--eval-episodes", type=int, help="episodes per evaluation seed (overrides)")
    p.add_argument(
        "--hyperparams-set",
        choices=BENCHMARK_SETS,
        default="paper",
        help="hyper-parameters of the training runs: paper (the paper's tables) or authors (the "
        "authors' code, which made the paper's Table 1)",
    )
    cli_args.add_key_value_argument(
        p, "--hyperparams", help="overrides passed to every training run"
    )
    p.add_argument("--jobs", type=int, default=os.cpu_count() or 1, help="runs at once")
    p.add_argument(
        "--ray-address",
        help="run on Ray: auto, HOST:PORT, or local (start a local instance with --jobs CPUs)",
    )
    p.add_argument("--out", default="runs/benchmark", help="directory of the stored runs")
    p.add_argument("--save-every", type=int, default=10_000, help="steps between saves of a run")
    p.add_argument("--status-every", type=float, default=300.0, help="seconds between lines")
    p.add_argument("--retries", type=int, default=3, help="tries again of a failed run")
    p.add_argument("--retry-delay", type=float, default=300.0, help="seconds before a retry")
    p.add_argument("--grace", type=float, default=120.0, help="seconds a stopped run may save")
    p.add_argument("--list", action="store_true", help="print the plan and exit")
    return p


def run(argv: list[str] | None = None) -> int:
    args = cli_args.parse_args(build_parser(), argv)
    if args.modes and any(m not in MODES for m in args.modes):
        return 2
    assert args.detector in DETECTORS
    out = Path(args.out)
    try:
        args.rig_config = cli_args.resolve_rig(args.realism, args.rig)
    except ValueError as exc:
        print(f"[benchmark] error: {exc}", file=sys.stderr)
        return 2
    if args.ray_address and not args.list:
        try:  # before anything is written
            check_address(args.ray_address)
        except RayAddressError as exc:
            print(f"[benchmark] error: {exc}", file=sys.stderr)
            return 2
    out.mkdir(parents=True, exist_ok=True)
    specs = plan(args)
    if args.list:
        for s in specs:
            steps = f" {s['timesteps']} steps" if s["kind"] == "train" else ""
            print(f"{s['id']}{steps}")
        return 0
    settings = {
        "profile": args.profile,
        "detector": args.detector,
        "observation": args.observation,
        "hyperparams_set": args.hyperparams_set,
        "rig": args.rig_config,
        "profile_settings": PROFILES[args.profile],
        "command_line": ["ros2", "run", "ops_gym_bridge", "benchmark", *(argv or sys.argv[1:])],
    }
    previous = read_json(out / "benchmark.json")
    # A folder holds one protocol: runs with another observation, hyper-parameter set or
    # detector go to another --out (None: every stored folder has the key).
    for key, default in (
        ("observation", "rig"),
        ("hyperparams_set", "paper"),
        ("detector", None),
        ("rig", {}),
    ):
        given = settings[key]
        stored = previous.get(key, default) if previous else given
        if stored != given:
            flag = "--" + key.replace("_", "-")
            print(f"[benchmark] error: {out} holds runs with {flag} {stored}", file=sys.stderr)
            return 2
    write_json(out / "benchmark.json", settings)
    return execute(args, specs, out)


def main(argv: list[str] | None = None) -> None:
    try:
        code = run(argv)
    except KeyboardInterrupt:
        code = EXIT_INTERRUPTED
    sys.exit(code)


if __name__ == "__main__":
    main()
