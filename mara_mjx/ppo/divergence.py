"""Stop a training run whose loss or parameters stop being finite.

A diverged PPO run (NaN or inf parameters) trains on silently: its actions are NaN, the
env replaces non-finite actions by holding the pose (spec section 3), so rewards,
evaluation tables and checkpoints all look ordinary. The train CLI's host loops
(`mara_mjx.cli.train.train_loop`, `mara_mjx.cli.seeds._loop`) call `check_finite` on every
jitted call's result, after it returns and before anything of it is logged or saved:
the run then ends with one message and exit status 1 (`Diverged`, a SystemExit), and
the run folder's newest checkpoint, written from a state that passed this check, is the
last finite one (`--resume` continues from it; lower the learning rate first).

The check reads the call's loss metrics (already on the host) and the state's
parameters and observation statistics (a few thousand floats) from the device: no
program is added to the jitted update. Inside the jitted scan nothing can stop, so a
call of several updates is checked once, at its end.
"""

from __future__ import annotations

from typing import Any

import jax
import numpy as np

LOSS_KEYS = ("loss", "policy_loss", "value_loss")
"""The metrics checked (others, e.g. an episode mean with no finished episode, may be
NaN by design)."""


class Diverged(SystemExit):
    """Training stopped: its loss or parameters are not finite. A SystemExit whose code
    is the one-line message (Python prints it on stderr and exits with status 1)."""


def _host(x: Any) -> np.ndarray:
    """x on the host; a replicated array of a multi-process run: this process's copy."""
    if isinstance(x, jax.Array) and not x.is_fully_addressable:
        x = x.addressable_data(0)
    return np.asarray(x)


def nonfinite(tree: Any, prefix: str) -> list[str]:
    """Names (prefix + key path) of the floating leaves of `tree` holding NaN or inf."""
    bad = []
    for path, leaf in jax.tree_util.tree_flatten_with_path(tree)[0]:
        value = _host(leaf)
        if np.issubdtype(value.dtype, np.inexact) and not np.all(np.isfinite(value)):
            bad.append(prefix + jax.tree_util.keystr(path))
    return bad


def _finite(x: np.ndarray, valid: np.ndarray | None) -> bool:
    """Every entry of x finite, in the rows `valid` marks (its shape leads x's: seeds and
    updates; x may add members)."""
    if valid is None:
        return bool(np.all(np.isfinite(x)))
    valid = valid.reshape(valid.shape + (1,) * (x.ndim - valid.ndim))
    return bool(np.all(np.isfinite(x) | ~valid))


def check_finite(
    state: Any, metrics: dict[str, Any], done: int, n: int, prog: str = "mara_mjx.train"
) -> None:
    """Raise `Diverged` when the loss metrics of the call that took the run from update
    `done` to `done + n`, or `state`'s params / obs_stats, are not finite. A population
    (CurriculumConfig.population: `state.fitness` set) stops only when all the members (of a
    seed) diverged: its exploit step replaces a diverged member by a copy of a good one
    (a member whose params are not finite ranks last), and its metrics are member 0's
    alone."""
    if getattr(state, "fitness", None) is not None:
        if not _population_diverged(state):
            return
        bad = ["every member's params or obs_stats"]
    else:
        # rows of the iterations a call skips (fewer updates than updates_per_call: the
        # run's last call) are NaN by construction (ppo.train's `skip`), marked not valid
        valid = _host(metrics["valid"]).astype(bool) if "valid" in metrics else None
        bad = [k for k in LOSS_KEYS if k in metrics and not _finite(_host(metrics[k]), valid)]
        bad += nonfinite(getattr(state, "params", None), "params")
        bad += nonfinite(getattr(state, "obs_stats", None), "obs_stats")
    if not bad:
        return
    shown = ", ".join(bad[:3]) + (f" and {len(bad) - 3} more" if len(bad) > 3 else "")
    raise Diverged(
        f"{prog}: error: training diverged in updates {done + 1}-{done + n}: {shown} not "
        "finite (NaN or inf); stopped without saving that state. The run folder's newest "
        "checkpoint is the last finite one: --resume continues from it (lower "
        "--learning_rate or --max_grad_norm first)"
    )


def _population_diverged(state: Any) -> bool:
    """Whether, for some seed, no member's params and obs stats are all finite (the
    member axis is the fitness' last; leaves lead with (seeds,) members)."""
    axis = np.ndim(_host(state.fitness)) - 1
    finite = None
    for leaf in jax.tree.leaves((state.params, state.obs_stats)):
        value = _host(leaf)
        if not np.issubdtype(value.dtype, np.inexact):
            continue
        ok = np.isfinite(value).all(axis=tuple(range(axis + 1, value.ndim)))
        finite = ok if finite is None else finite & ok
    return finite is not None and bool((~finite).all(axis=-1).any())
