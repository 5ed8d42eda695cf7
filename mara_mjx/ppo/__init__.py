"""PPO (OpenAI baselines ppo2 semantics) for the MARA tasks, many environments per device.

Pure pieces:        gae, ppo_loss, ActorCritic, gaussian_log_prob, gaussian_entropy,
                    RunningStats, update_stats, normalize
Training:           make_train(env, TrainConfig or PPOConfig, updates_per_call) -> Trainer;
                    with CurriculumConfig.teacher, imitation of a trained policy (teacher.py)
Config:             TrainConfig(ppo=PPOConfig, policy=PolicyConfig, curriculum=CurriculumConfig),
                    RunConfig, EvalConfig, PRESETS ("default", "paper", "ros2learn", ...)
Policy artefact:    make_policy(checkpoint_or_params, config) -> Policy (fn(obs) -> action),
                    load_policy(checkpoint file or run folder)
Checkpoints:        save_checkpoint, load_checkpoint, find_checkpoint
Evaluation:         evaluate(env, policy, EvalConfig) -> EvalResult, format_table

CLIs: `python -m mara_mjx.train --env MARA`, `python -m mara_mjx.evaluate CHECKPOINT`.
"""

from mara_mjx.ppo.checkpoint import (
    CheckpointError,
    find_checkpoint,
    load_checkpoint,
    save_checkpoint,
)
from mara_mjx.ppo.config import (
    CurriculumConfig,
    EvalConfig,
    PolicyConfig,
    PPOConfig,
    RunConfig,
    TrainConfig,
)
from mara_mjx.ppo.evaluation import PAPER_RESULTS, EvalResult, evaluate, format_table
from mara_mjx.ppo.losses import LossInfo, gae, ppo_loss
from mara_mjx.ppo.networks import (
    MLP,
    ActorCritic,
    RunningStats,
    gaussian_entropy,
    gaussian_log_prob,
    normalize,
    update_stats,
)
from mara_mjx.ppo.optim import make_lr_schedule
from mara_mjx.ppo.policy import Policy, load_policy, make_policy
from mara_mjx.ppo.presets import PRESETS
from mara_mjx.ppo.train import RunnerState, Trainer, make_train

__all__ = [
    "MLP",
    "PAPER_RESULTS",
    "PRESETS",
    "ActorCritic",
    "CheckpointError",
    "CurriculumConfig",
    "EvalConfig",
    "EvalResult",
    "LossInfo",
    "PPOConfig",
    "Policy",
    "PolicyConfig",
    "RunConfig",
    "RunnerState",
    "RunningStats",
    "TrainConfig",
    "Trainer",
    "evaluate",
    "find_checkpoint",
    "format_table",
    "gae",
    "gaussian_entropy",
    "gaussian_log_prob",
    "load_checkpoint",
    "load_policy",
    "make_lr_schedule",
    "make_policy",
    "make_train",
    "normalize",
    "ppo_loss",
    "save_checkpoint",
    "update_stats",
]
