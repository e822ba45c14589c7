"""The training loop of `TrafficGP`: minibatch steps, evaluations, early stopping, the anneal.

Every `eval_every` steps the loop records the ELBO on a fixed sample of the training rows
(`elbo_`, at `eval_steps_`) and, given held-out rows (the most recent days, see `validation`),
their mean negative log predictive density (`validation_loss_`). When the held-out loss has not
improved for `patience` evaluations after the warm-up, the step-size anneal (both step sizes
lowered tenfold over ANNEAL_SHARE of the steps) starts there if it has not started yet
(`anneal_start_`: at full step size the minibatch jitter hides slow progress), and training
stops at the first such plateau once the anneal is over. The state of the best evaluation is
kept (`best_step_`; of evaluations within TIE_SHARE of the best loss, the latest).
"""
import logging
import time
from typing import Optional

import numpy as np
from tqdm import tqdm

import traffic_gp.gp_parts as gp_parts
from traffic_gp.observations import Observations

log = logging.getLogger(__name__)

WARMUP_STEPS = 100
ADAM_WARMUP_STEPS = 50      # a new optimiser's (after fit or load) step size ramps up over these
EVAL_ROWS = 20000           # rows of the fixed ELBO sample and at most of the held-out set
COMPILE_STEPS = 60          # a first training of fewer steps runs eagerly (tracing costs more)
TIE_SHARE = 1e-3            # held-out losses this close to the best count as ties
ANNEAL_SHARE = 0.4


class Training:
    """Mixin of `TrafficGP`: `_train` and the step-size schedule."""

    def prepare_training(self) -> None:
        """Get ready to train for a long time in short chunks (a node learning online): a
        compiled step, traced now. Without this, a first training of fewer than COMPILE_STEPS
        steps makes an eager step (quicker for a few dozen steps, about 7x the CPU per step
        after that), kept for the model's life. Call outside any lock the model's readers take:
        tracing takes seconds, and nothing is trained."""
        if self._trainer is not None and self._trainer.compiled:
            return
        self._trainer = gp_parts.Trainer(self.model_, learning_rate=self.learning_rate,
                                         gamma=self.natgrad_gamma, compiled=True)
        self._trainer_used, self._trainer_steps = False, 0
        start = time.perf_counter()
        self._trainer.trace()
        self.compile_seconds_ += time.perf_counter() - start

    def _train(self, data: Observations, n_steps: int, *, anneal: bool = False,
               held_out: Optional[Observations] = None, rate_scale: float = 1.0):
        """Train `n_steps` minibatch steps on `data`; with `held_out` rows, stop early on them
        (see the module); `anneal` lowers the step sizes over the last steps; `rate_scale`
        multiplies both step sizes (folding rows into a converged model: 0.1)."""
        if self._trainer is None:
            self._trainer = gp_parts.Trainer(self.model_, learning_rate=self.learning_rate,
                                             gamma=self.natgrad_gamma,
                                             compiled=n_steps >= COMPILE_STEPS)
            self._trainer_used, self._trainer_steps = False, 0
        inputs, targets = self._obs_inputs(data), self._targets(data)
        eval_rows = np.random.default_rng(self.random_state).permutation(len(data))[:EVAL_ROWS]
        eval_inputs, eval_targets = inputs[eval_rows], targets[eval_rows]
        early = held_out is not None and len(held_out) > 0
        if early:
            if len(held_out) > EVAL_ROWS:
                keep = np.sort(np.random.default_rng(self.random_state).permutation(
                    len(held_out))[:EVAL_ROWS])
                held_out = held_out.subset(keep)
            val_inputs, val_targets = self._obs_inputs(held_out), self._targets(held_out)
        size = min(self.batch_size, len(data))
        steps = range(n_steps)
        if self.progress and n_steps:
            steps = tqdm(steps, desc="training crowd GP", unit="step", mininterval=1.0)
        start = time.perf_counter()
        fresh = not self._trainer_used
        if fresh and n_steps:     # tracing the compiled functions takes seconds: timed apart
            self._trainer.elbo(inputs[:2], targets[:2])
        best, best_loss, done, improved_at = None, np.inf, 0, 0
        anneal_steps = max(int(round(ANNEAL_SHARE * n_steps)), 1)
        anneal_start = n_steps - anneal_steps if anneal else None
        for step in steps:
            annealed = 0.0
            if anneal_start is not None:
                annealed = min(max((step - anneal_start) / anneal_steps, 0.0), 1.0)
            self._set_rates(self.n_steps_ + step, annealed, rate_scale)
            batch = self._rng.integers(0, len(data), size)
            self._trainer.step(inputs[batch], targets[batch])
            self._trainer_steps += 1
            done = step + 1
            if fresh:
                self.compile_seconds_ += time.perf_counter() - start
                self._trainer_used, fresh = True, False
            if done % self.eval_every and step != n_steps - 1:
                continue
            self.eval_steps_.append(self.n_steps_ + done)
            self.elbo_.append(float(self._trainer.elbo(eval_inputs, eval_targets))
                              * len(data) / len(eval_rows))
            if not early:
                continue
            loss = -float(np.mean(self._trainer.log_density(val_inputs, val_targets)))
            self.validation_loss_.append(loss)
            if loss < best_loss:
                best_loss, improved_at = loss, self.n_steps_ + done
            if loss <= best_loss + TIE_SHARE * abs(best_loss):    # ties: the later state
                best = gp_parts.parameter_values(self.model_)
                self.best_step_ = self.n_steps_ + done
            elif (self.n_steps_ + done > WARMUP_STEPS
                  and self.n_steps_ + done - improved_at >= self.patience * self.eval_every):
                if anneal_start is not None and done < anneal_start:    # plateau: anneal now
                    anneal_start = done
                    anneal_steps = max(min(anneal_steps, n_steps - done), 1)
                elif anneal_start is None or done >= anneal_start + anneal_steps:
                    self.stopped_early_ = True
                    break
        if hasattr(steps, "close"):
            steps.close()
        if anneal_start is not None and anneal_start < done:
            self.anneal_start_ = self.n_steps_ + anneal_start
        self.n_steps_ += done
        if best is not None:
            gp_parts.assign_parameter_values(self.model_, best)
        self.train_seconds_ += time.perf_counter() - start
        if self.elbo_ and not np.isfinite(self.elbo_[-1]):
            log.warning("the ELBO is not finite after %d steps: lower learning_rate or "
                        "natgrad_gamma", self.n_steps_)
        return self

    def _set_rates(self, done: int, annealed: float, rate_scale: float = 1.0) -> None:
        """Natural-gradient steps grow 100x over the first WARMUP_STEPS of training; both step
        sizes also grow linearly over the first ADAM_WARMUP_STEPS of a new optimiser (after
        `load`: a fresh Adam's first steps have the full step size in every direction whatever
        the gradient, and full natural-gradient steps on a minibatch would shake the model);
        over a fit's anneal (`annealed` goes from 0 to 1) both step sizes shrink 10x (less
        minibatch jitter)."""
        warm = 10.0 ** (-2.0 * (1.0 - done / WARMUP_STEPS)) if done < WARMUP_STEPS else 1.0
        adam_warm = min(1.0, (self._trainer_steps + 1) / ADAM_WARMUP_STEPS)
        warm = min(warm, adam_warm)         # a loaded model's first natural-gradient steps too
        anneal = 10.0 ** -annealed * rate_scale
        self._trainer.gamma.assign(self.natgrad_gamma * warm * anneal)
        self._trainer.adam.learning_rate.assign(self.learning_rate * anneal * adam_warm)
