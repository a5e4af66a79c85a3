"""stable-baselines3 callbacks of ``train`` (imports stable-baselines3: import it lazily)."""

from __future__ import annotations

import sys
import time

import numpy as np
import torch
from stable_baselines3.common.callbacks import BaseCallback

from .envs import final_powers


class ProgressCallback(BaseCallback):
    """Progress bar (tqdm) with mean return and final P_N/P_max; logs rollout/final_power."""

    def __init__(self, total: int, enabled: bool):
        super().__init__()
        self.total = total
        self.enabled = enabled
        self.bar = None
        self._last_post = 0.0
        self._last_log = 0
        self._seen = 0

    def _on_training_start(self) -> None:
        from tqdm import tqdm

        start = self.model.num_timesteps
        self.bar = tqdm(
            total=self.total,
            initial=start,
            unit="step",
            dynamic_ncols=True,
            disable=not self.enabled,
            smoothing=0.05,
            file=sys.stderr,
            mininterval=0.5,
        )
        self._seen = start

    def _on_step(self) -> bool:
        n = self.model.num_timesteps
        if self.bar is not None:
            self.bar.update(n - self._seen)
        self._seen = n
        now = time.monotonic()
        if now - self._last_post > 0.5:
            self._last_post = now
            self._post_summary()
        if n - self._last_log >= 1000:
            self._last_log = n
            powers = final_powers(self.model.ep_info_buffer or [])
            if powers.size:
                self.logger.record("rollout/final_power_mean", float(powers.mean()))
        return True

    def _post_summary(self) -> None:
        buf = self.model.ep_info_buffer
        if not buf or self.bar is None:
            return
        post = {"return": f"{float(np.mean([ep['r'] for ep in buf])):.2f}"}
        powers = final_powers(buf)
        if powers.size:
            post["P_N"] = f"{powers.mean():.3f}"
        self.bar.set_postfix(post, refresh=False)

    def _on_training_end(self) -> None:
        self.close()

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()


class WallClockLimit(BaseCallback):
    """Stops training (cleanly: the model is saved as after the last step) once ``seconds`` of
    wall time have passed since training started; ``reached`` says whether it did."""

    def __init__(self, seconds: float):
        super().__init__()
        self.seconds = float(seconds)
        self.reached = False
        self._t0 = 0.0

    def _on_training_start(self) -> None:
        self._t0 = time.monotonic()

    def _on_step(self) -> bool:
        if time.monotonic() - self._t0 >= self.seconds:
            self.reached = True
            return False
        return True


class WarmBuffer(BaseCallback):
    """No update until step ``until``: the model acts with its own policy and its transitions
    fill the replay buffer (a fine-tune's ``learning_starts``; SB3 would act at random). Its
    ``gradient_steps`` is 0 meanwhile; :meth:`restore` puts it back (also before a save)."""

    def __init__(self, until: int):
        super().__init__()
        self.until = int(until)
        self._kept: int | None = None

    def _on_training_start(self) -> None:
        if self.model.num_timesteps < self.until:
            self._kept = self.model.gradient_steps
            self.model.gradient_steps = 0

    def _on_step(self) -> bool:
        # (the update after a rollout comes after this: the step at ``until`` makes none)
        if self._kept is not None and self.num_timesteps > self.until:
            self.restore()
        return True

    def _on_training_end(self) -> None:
        self.restore()

    def restore(self) -> None:
        if self._kept is not None:
            self.model.gradient_steps, self._kept = self._kept, None


class ActorFreeze(BaseCallback):
    """Keeps the actor's weights as they are until step ``until`` (``critic_warmup``): the
    critic's updates go on, the actor's loss reaches no weight of the actor. A fine-tune on
    another task (held decisions, another rig) starts with a critic that values the old one,
    and the actor's first updates follow that critic away from a good policy (the held `lab`
    fine-tune of models/n5_hard: its rollouts fell from 0.85 to 0.69 within 60,000 steps with a
    warm buffer and a tenth of the learning rate)."""

    def __init__(self, until: int):
        super().__init__()
        self.until = int(until)
        self.frozen = False
        self._log_ent_coef = None

    def _set(self, frozen: bool) -> None:
        for param in self.model.actor.parameters():
            param.requires_grad_(not frozen)
        self.frozen = frozen
        # SAC's entropy coefficient is the actor's too: left to learn against a frozen actor
        # it grew tenfold (0.0085 -> 0.091 in 200,000 steps) and, released, drove the actor to
        # a random policy (0.83 -> 0.13 at the next evaluation). It is held with the actor.
        log_ent_coef = getattr(self.model, "log_ent_coef", None)
        self._log_ent_coef = (
            log_ent_coef.detach().clone() if frozen and log_ent_coef is not None else None
        )

    def _hold_entropy(self) -> None:
        if self._log_ent_coef is not None:
            with torch.no_grad():
                self.model.log_ent_coef.copy_(self._log_ent_coef)

    def _on_training_start(self) -> None:
        if self.model.num_timesteps < self.until:
            self._set(True)
            print(
                f"[train] critic warm-up: the actor stays as it is until step {self.until}",
                flush=True,
            )

    def _on_step(self) -> bool:
        self._hold_entropy()  # (the update after the last rollout moved it)
        if self.frozen and self.num_timesteps >= self.until:
            self._set(False)
            print(f"[train] critic warm-up done at step {self.num_timesteps}", flush=True)
        return True

    def _on_training_end(self) -> None:
        self.restore()

    def restore(self) -> None:
        if self.frozen:
            self._hold_entropy()
            self._set(False)


class BestModelCallback(BaseCallback):
    """Every ``every`` calls (vector steps), ``evaluate(model) -> final P_N/P_max`` of the
    deterministic policy; logs ``eval/final_power`` and calls ``save_best(model, power)`` when it
    is the best so far. Its time is not training time: a :class:`WallClockLimit` is told.
    ``at_start``: evaluate once before the first step too (a fine-tuned model: its starting
    figure, and DIR/best never worse than where it started)."""

    def __init__(
        self,
        every: int,
        evaluate,
        save_best,
        limit: WallClockLimit | None = None,
        at_start: bool = False,
    ):
        super().__init__()
        self.every = max(int(every), 1)
        self.evaluate = evaluate
        self.save_best = save_best
        self.limit = limit
        self.at_start = at_start
        self.best = float("-inf")
        self.results: list[tuple[int, float]] = []

    def _on_training_start(self) -> None:
        if self.at_start:
            self._evaluate()

    def _on_step(self) -> bool:
        if self.n_calls % self.every:
            return True
        self._evaluate()
        return True

    def _evaluate(self) -> None:
        t0 = time.monotonic()
        power = float(self.evaluate(self.model))
        steps = int(self.model.num_timesteps)
        self.results.append((steps, power))
        # Written at once, at its own step: left to SB3's next dump, the row would carry a later
        # step count (the evaluation at the start of a fine-tune read one rollout late), and a
        # second evaluation before that dump would replace the first.
        self.logger.record("eval/final_power", power)
        self.logger.record("time/total_timesteps", steps, exclude="tensorboard")
        self.logger.dump(step=steps)
        if power > self.best:
            self.best = power
            self.save_best(self.model, power)
        if self.limit is not None:
            self.limit._t0 += time.monotonic() - t0


def training_callbacks(
    total: int,
    progress: bool,
    checkpoint_every: int,
    out,
    normalize: bool,
    max_seconds: float | None = None,
    best: tuple | None = None,
    best_at_start: bool = False,
):
    """The progress bar, the checkpoints (``out/checkpoints/model_<steps>_steps.zip``), with
    ``best = (every, evaluate, save_best)`` a :class:`BestModelCallback` and, with
    ``max_seconds``, a :class:`WallClockLimit` (last)."""
    from stable_baselines3.common.callbacks import CallbackList, CheckpointCallback

    (out / "checkpoints").mkdir(exist_ok=True)
    wall = WallClockLimit(max_seconds) if max_seconds else None
    limit = [wall] if wall else []
    if best is not None:
        limit.insert(0, BestModelCallback(*best, limit=wall, at_start=best_at_start))
    return CallbackList(
        [
            ProgressCallback(total, enabled=progress),
            CheckpointCallback(
                checkpoint_every,
                str(out / "checkpoints"),
                name_prefix="model",
                save_vecnormalize=normalize,
            ),
            *limit,
        ]
    )
