"""``ros2 run ops_gym_bridge distill``: a student that sees only the rig's observation, taught by
a privileged teacher with DAgger (Ross et al., 2011) on the batched simulator.

The teacher (:mod:`.oracle`, recipe ``dagger-oracle``) reads the simulator's true delay errors and
cancels them; the student is the actor of a stable-baselines3 SAC model (deterministic: tanh of
its mean) on the rig's observation with memory (``--obs-history k``). Each round runs
``--envs`` environments of :class:`~ops_sim_ros.vec_env.OpsVectorEnv` for one episode
(``--episode-steps``; the test evaluation's episodes keep 200 steps): at each
step every environment takes the teacher's action with probability beta (1 in the first round,
then ``--beta-decay`` times the last) and the student's otherwise, and every visited state is
stored with the teacher's label; the actor is then fitted to all stored pairs (mean squared
error of its deterministic action, ``--grad-steps`` Adam steps a round). So the student learns the
teacher's answer on the states it reaches itself.

Every ``--eval-every`` rounds the student runs 100 deterministic test-split episodes (seed
``--eval-seed``); ``learning.csv`` records minutes, environment steps (every simulated step of
collection; the oracle takes none) and the mean and worst final P_N / P_max. The model kept is
the best of those evaluations (no episode below 0.8 first, then the mean), saved as a SAC model
directory (``model.zip``, ``metadata.json`` as ``train`` writes it, with ``recipe`` and
``training_wall_s``: wall seconds of the whole run) that ``evaluate``, the policy node and
``train --init-from`` (an RL fine-tune) take unchanged.
"""

from __future__ import annotations

import argparse
import csv
import sys
import time
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from ops_contract.heap import freeze_after_heavy_imports

from . import cli_args
from .envs import EPISODE_STEPS
from .oracle import privileged_dim, privileged_features, teacher_labels

RECIPES = ("dagger-oracle",)
EVAL_EPISODES = 100
#: The saved actor's log std (its stochastic policy, unused by the deterministic student): exp
#: of it, 0.1, is the exploration an RL fine-tune from the student starts with.
INITIAL_LOG_STD = -2.3


@dataclass
class Dataset:
    """The aggregated (observation, label, auxiliary target) rows, a ring of ``capacity``;
    ``aux_dim`` 0: no auxiliary targets."""

    capacity: int
    obs_dim: int
    act_dim: int
    aux_dim: int = 0
    size: int = 0
    head: int = 0
    obs: np.ndarray = field(init=False)
    labels: np.ndarray = field(init=False)
    aux: np.ndarray = field(init=False)

    def __post_init__(self) -> None:
        self.obs = np.zeros((self.capacity, self.obs_dim), dtype=np.float32)
        self.labels = np.zeros((self.capacity, self.act_dim), dtype=np.float32)
        self.aux = np.zeros((self.capacity, self.aux_dim), dtype=np.float32)

    def add(self, obs: np.ndarray, labels: np.ndarray, aux: np.ndarray | None = None) -> None:
        n = obs.shape[0]
        idx = (self.head + np.arange(n)) % self.capacity
        self.obs[idx] = obs
        self.labels[idx] = labels
        if self.aux_dim:
            self.aux[idx] = aux
        self.head = int((self.head + n) % self.capacity)
        self.size = min(self.size + n, self.capacity)

    def sample(self, rng: np.random.Generator, batch: int):
        """(observations, labels, auxiliary targets) of ``batch`` rows drawn with replacement."""
        idx = rng.integers(0, self.size, size=batch)
        return self.obs[idx], self.labels[idx], self.aux[idx]


class Standardizer:
    """The observation's per-value mean and std (of the first round's states): the student
    learns on standardized inputs, and :meth:`folded` writes the standardization into the
    actor's first layer for saving, so the saved SAC model takes the raw observation."""

    def __init__(self, obs: np.ndarray) -> None:
        self.mean = obs.mean(axis=0).astype(np.float32)
        self.std = np.maximum(obs.std(axis=0), 1e-4).astype(np.float32)

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        return ((obs - self.mean) / self.std).astype(np.float32)

    @contextmanager
    def folded(self, actor):
        """Within: the actor's first layer is W / std, b - W (mean / std) (raw inputs)."""
        import torch

        first = actor.latent_pi[0]
        w, b = first.weight.data.clone(), first.bias.data.clone()
        inv = torch.as_tensor(1.0 / self.std)
        first.weight.data = w * inv
        first.bias.data = b - (w * inv) @ torch.as_tensor(self.mean)
        try:
            yield
        finally:
            first.weight.data, first.bias.data = w, b


def student_actions(actor, obs: np.ndarray, norm=None) -> np.ndarray:
    """The actor's deterministic actions (tanh of its mean) for a batch of observations
    (standardized by ``norm`` first, while the actor learns on standardized inputs)."""
    import torch

    x = obs if norm is None else norm(obs)
    with torch.no_grad():
        mean, _, _ = actor.get_action_dist_params(torch.as_tensor(x))
        return torch.tanh(mean).numpy().astype(np.float64)


def fit(actor, optimizer, data: Dataset, rng, steps: int, batch: int, norm, aux=None) -> float:
    """``steps`` Adam steps of the actor's deterministic action toward the labels; the mean
    loss (of the actions alone) of the last tenth. ``aux`` (head, weight): a linear head on the
    actor's last hidden layer fitted to the auxiliary targets as well, the weighted mean squared
    error added to the loss (the head is not part of the saved actor)."""
    import torch

    losses = []
    for _ in range(steps):
        x, y, z = data.sample(rng, batch)
        features = actor.extract_features(torch.as_tensor(norm(x)), actor.features_extractor)
        latent = actor.latent_pi(features)
        loss = torch.mean((torch.tanh(actor.mu(latent)) - torch.as_tensor(y)) ** 2)
        total = loss
        if aux is not None:
            head, weight = aux
            total = loss + weight * torch.mean((head(latent) - torch.as_tensor(z)) ** 2)
        optimizer.zero_grad()
        total.backward()
        optimizer.step()
        losses.append(float(loss.detach()))
    tail = losses[-max(1, steps // 10) :]
    return float(np.mean(tail)) if tail else float("nan")


def evaluate_student(actor, env_kwargs: dict, seed: int, norm=None, episodes=EVAL_EPISODES):
    """Final P_N / P_max of ``episodes`` deterministic test-split episodes (one batch)."""
    from ops_sim_ros.vec_env import OpsVectorEnv

    venv = OpsVectorEnv(num_envs=episodes, split="test", seed=seed, **env_kwargs)
    obs, _ = venv.reset(seed=seed)
    final = None
    for _ in range(venv.config.episode_steps):
        obs, _, _, trunc, info = venv.step(student_actions(actor, obs, norm))
        if trunc.all():
            final = np.asarray(info["final_info"]["power"], dtype=np.float64)
    return final


class Collector:
    """The training environments (one episode per round, a rig drawn per round with
    ``--rig-randomize``) and the teacher's labels of the states they visit."""

    def __init__(self, args, env_kwargs: dict, rig_ranges) -> None:
        from ops_sim_ros.vec_env import OpsVectorEnv

        self.venv = OpsVectorEnv(
            num_envs=args.envs,
            split="train",
            seed=args.seed,
            continue_prob=args.continue_prob,
            **env_kwargs,
        )
        self.fresh = True  # the next round starts every env afresh
        self.venv.reset(seed=args.seed)
        self.base_config = self.venv.sim.config
        self.rig_ranges = rig_ranges
        self.rng = np.random.default_rng(args.seed + 1)
        self.probe_steps = args.probe_steps
        self.noise = args.action_noise
        self.steps = 0

    def round(self, actor, data: Dataset, beta: float, norm) -> float:
        """One episode of every env; returns the mean final power of the round."""
        sim = self.venv.sim
        if self.rig_ranges:
            sim.use_rig(self.base_config.replace(**self.rig_ranges.draw(self.rng)))
        if self.fresh or self.rig_ranges or not self.venv.continue_prob:
            obs, _ = self.venv.reset()
            self.age = np.zeros(self.venv.num_envs, dtype=np.int64)
        else:  # with --continue-prob the envs' own ends of episodes started or continued them
            obs = self.last_obs
        self.fresh = False
        final = np.nan
        for _ in range(self.base_config.episode_steps):
            labels = teacher_labels(sim, self.probe_steps, self.age)
            data.add(obs, labels, privileged_features(sim) if data.aux_dim else None)
            if beta >= 1.0:
                act = labels
            else:
                act = student_actions(actor, obs, norm)
                if self.noise > 0:
                    act = np.clip(act + self.rng.normal(0.0, self.noise, act.shape), -1, 1)
                teach = self.rng.random(act.shape[0]) < beta
                act[teach] = labels[teach]
            obs, _, _, trunc, info = self.venv.step(act)
            self.steps += act.shape[0]
            self.age += 1
            if trunc.any():  # fresh runs start at set-points 0; continued ones moved away
                self.age[trunc & np.all(sim.setpoints_fs == 0.0, axis=1)] = 0
            if trunc.all():
                final = float(np.mean(info["final_info"]["power"]))
        self.last_obs = obs
        return final


def build_student(args, out: Path):
    """The SAC model (the student is its actor) built as ``train`` builds it."""
    from .build import build_model

    options = [
        "--algo", "sac", "--hyperparams-set", "fast", "--stage", str(args.stage),
        "--mode", args.mode, "--detector", args.detector, "--obs-history", str(args.obs_history),
        "--seed", str(args.seed), "--torch-threads", str(args.torch_threads), "--n-envs", "1",
        "--hyperparams", f"net_arch=[{args.width},{args.width}]",
    ]  # fmt: skip
    if args.episode_steps != EPISODE_STEPS:
        options += ["--episode-steps", str(args.episode_steps)]
    if args.setpoint_window:
        options += ["--setpoint-window", str(args.setpoint_window)]
    if args.continue_prob:
        options += ["--continue-prob", str(args.continue_prob)]
    if args.realism:
        options += ["--realism", args.realism]
    if args.rig_randomize:
        options += ["--rig-randomize", *args.rig_randomize]
    return build_model(options, out)


def env_kwargs_of(run, episode_steps: int | None = None) -> dict:
    """The batched envs' arguments for the run's task (stage, mode, detector, observation, rig;
    episodes of ``episode_steps``, default the run's training episodes)."""
    from .training_run import observation_options

    a = run.args
    return dict(
        stage=a.stage,
        mode=a.mode,
        detector=a.detector,
        max_episode_steps=a.episode_steps if episode_steps is None else episode_steps,
        observation_options=observation_options(a),
        **a.rig_config,
    )


def save_student(run, out: Path, argv: list[str], t0: float, extra: dict) -> None:
    """The model directory (model.zip, metadata.json with recipe and training_wall_s)."""
    from .learn import _save

    wall = time.perf_counter() - t0
    extra = {**extra, "training_wall_s": round(wall, 1)}
    _save(out, run.args, run.params, run.model, run.venv, argv, wall, False, None, False, extra)


def _score(mean: float, worst: float) -> tuple[bool, float]:
    return (worst >= 0.8, mean)


def train_loop(args, run, out: Path, argv: list[str], t0: float) -> dict:
    """The DAgger rounds; returns the best evaluation's figures."""
    import torch

    actor = run.model.actor
    actor.set_training_mode(True)
    with torch.no_grad():  # a near-deterministic start for an RL fine-tune (train --init-from)
        actor.log_std.weight.zero_()
        actor.log_std.bias.fill_(INITIAL_LOG_STD)
    aux = None
    params = list(actor.parameters())
    if args.aux_weight > 0:  # the privileged values as auxiliary targets of the last hidden layer
        head = torch.nn.Linear(actor.mu.in_features, privileged_dim(args.stage))
        aux = (head, args.aux_weight)
        params += list(head.parameters())
    optimizer = torch.optim.Adam(params, lr=args.lr)
    env_kwargs = env_kwargs_of(run)
    test_kwargs = env_kwargs_of(run, EPISODE_STEPS)  # the test's episodes, whatever training's
    collector = Collector(args, env_kwargs, run.args.rig_ranges)
    obs_dim = int(np.prod(run.model.observation_space.shape))
    data = Dataset(args.capacity, obs_dim, args.stage, privileged_dim(args.stage) if aux else 0)
    rng = np.random.default_rng(args.seed)
    best: dict = {}
    norm = None
    curve = out / "learning.csv"
    with curve.open("w", newline="") as fh:
        writer = csv.writer(fh)
        writer.writerow(["minutes", "env_steps", "test_final_power", "test_worst", "beta"])
        for r in range(args.rounds):
            beta = args.beta0 * args.beta_decay ** (r - 1) if r > 0 else 1.0
            train_power = collector.round(actor, data, beta, norm)
            if norm is None:
                norm = Standardizer(data.obs[: data.size])
            loss = fit(actor, optimizer, data, rng, args.grad_steps, args.batch, norm, aux)
            if (r + 1) % args.eval_every and r + 1 < args.rounds:
                continue
            final = evaluate_student(actor, test_kwargs, args.eval_seed, norm)
            mean, worst = float(final.mean()), float(final.min())
            minutes = (time.perf_counter() - t0) / 60.0
            row = (f"{minutes:.2f}", collector.steps, f"{mean:.4f}", f"{worst:.4f}", f"{beta:.3f}")
            writer.writerow(row)
            fh.flush()
            print(f"[distill] round {r + 1} steps {collector.steps} beta {beta:.3f} loss "
                  f"{loss:.4f} train {train_power:.3f} test {mean:.4f} worst {worst:.4f} "
                  f"({minutes:.1f} min)", flush=True)  # fmt: skip
            if not best or _score(mean, worst) > _score(best["mean"], best["worst"]):
                best = dict(mean=mean, worst=worst, round=r + 1, env_steps=collector.steps)
                run.model.num_timesteps = collector.steps
                with norm.folded(actor):
                    save_student(run, out, argv, t0, _extra(args, best, collector.steps))
            if minutes > args.max_minutes:
                break
    best["total_env_steps"] = collector.steps
    return best


def _extra(args, best: dict, steps: int) -> dict:
    return {
        "recipe": args.recipe,
        "eval_final_power": best["mean"],
        "eval_worst_final_power": best["worst"],
        "eval_episodes": EVAL_EPISODES,
        "dagger": {
            "round": best["round"],
            "env_steps": steps,
            **{k: getattr(args, k) for k in DAGGER_KEYS},
        },
    }


DAGGER_KEYS = (
    "envs", "rounds", "beta0", "beta_decay", "grad_steps", "batch", "lr", "capacity",
    "probe_steps", "action_noise", "width", "eval_seed", "setpoint_window", "continue_prob",
    "episode_steps", "aux_weight",
)  # fmt: skip


def build_parser() -> argparse.ArgumentParser:
    p = cli_args.make_parser("distill", __doc__.split("\n\n")[0])
    p.add_argument("--recipe", choices=RECIPES, default="dagger-oracle")
    p.add_argument("--stage", type=int, default=5)
    p.add_argument("--mode", choices=("easy", "medium", "hard", "extreme"), default="hard")
    p.add_argument("--detector", choices=("polarizer", "total"), default="polarizer")
    p.add_argument("--obs-history", type=int, default=8, help="memory k of the observation")
    p.add_argument(
        "--setpoint-window",
        type=float,
        default=0.0,
        help="set-points observed re-centred by whole cycles (as train's)",
    )
    p.add_argument(
        "--continue-prob",
        type=float,
        default=0.0,
        help="an ended episode carries the run on with this probability (as train's)",
    )
    p.add_argument(
        "--episode-steps",
        type=int,
        default=EPISODE_STEPS,
        help="steps of a training episode (a round is one); the test evaluation's episodes "
        f"keep {EPISODE_STEPS}: shorter ones start more runs afresh per environment step",
    )
    p.add_argument("--realism", choices=("ideal", "lab"), default=None)
    p.add_argument("--rig-randomize", nargs="+", default=None, metavar="KEY=LOW:HIGH",
                   help="a rig drawn per round (all envs share it), as train's")  # fmt: skip
    p.add_argument("--envs", type=int, default=256, help="batched environments")
    p.add_argument("--rounds", type=int, default=200, help="DAgger rounds (one episode each)")
    p.add_argument("--beta0", type=float, default=0.5, help="teacher share of round 2")
    p.add_argument("--beta-decay", type=float, default=0.7, help="beta's factor per round")
    p.add_argument("--grad-steps", type=int, default=1000, help="Adam steps per round")
    p.add_argument("--batch", type=int, default=512)
    p.add_argument("--lr", type=float, default=1e-3)
    p.add_argument("--capacity", type=int, default=1_000_000, help="stored pairs (a ring)")
    p.add_argument("--probe-steps", type=int, default=6, help="steps of the fixed probe")
    p.add_argument("--action-noise", type=float, default=0.1, help="std on student actions")
    p.add_argument("--width", type=int, default=256, help="hidden units (two layers)")
    p.add_argument(
        "--aux-weight",
        type=float,
        default=0.0,
        help="weight of auxiliary targets: a linear head on the student's last hidden layer "
        "also fits what only the simulator knows (each line's true error as cos and sin of its "
        "phase, the drift's slope; oracle.privileged_features), which the labels, clipped to "
        "the actuator's step, do not tell far from the optimum; the head is not saved (0: none)",
    )
    p.add_argument("--eval-every", type=int, default=3, help="rounds between evaluations")
    p.add_argument("--eval-seed", type=int, default=1000)
    p.add_argument("--max-minutes", type=float, default=60.0)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--torch-threads", type=int, default=1)
    p.add_argument("--out", required=True, help="the model directory")
    return p


def main(argv: list[str] | None = None) -> int:
    freeze_after_heavy_imports()
    raw = cli_args.strip_ros_args(list(sys.argv[1:] if argv is None else argv))
    args = build_parser().parse_args(raw)
    t0 = time.perf_counter()
    out = Path(args.out).expanduser().resolve()
    run = build_student(args, out)
    command = ["ros2", "run", "ops_gym_bridge", "distill", *raw]
    best = train_loop(args, run, out, command, t0)
    wall = time.perf_counter() - t0
    print(f"[distill] best: round {best.get('round')} test {best.get('mean', float('nan')):.4f} "
          f"worst {best.get('worst', float('nan')):.4f}; {best['total_env_steps']} env steps, "
          f"{wall / 60:.1f} min -> {out}", flush=True)  # fmt: skip
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
