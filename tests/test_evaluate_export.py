"""An exported policy file in evaluate's closed loop (mara_mjx.deploy.in_the_loop): the
.onnx and the .npz export of a checkpoint give the checkpoint's table on the same episodes."""

from __future__ import annotations

import json

import numpy as np
import pytest
from test_export_plots import make_run

from mara_mjx.cli.common import UserError
from mara_mjx.cli.evaluate import main as evaluate_main
from mara_mjx.cli.export import export_policy
from mara_mjx.deploy import in_the_loop
from mara_mjx.ppo import make_policy
from mara_mjx.ppo.config import EvalConfig
from mara_mjx.ppo.evaluation import evaluate

pytest.importorskip("onnx")
pytest.importorskip("onnxruntime")

# an untrained policy: a wide reset noise and tolerance so that the episodes differ, some
# stop at the tolerance (2 of 4, at different steps) and some at the horizon
CONFIG = EvalConfig(episodes=4, noise=0.5, tolerance_mm=750.0)


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    """A tiny MARA run (relative actions: the arm moves toward the target's side) and its
    .onnx and .npz exports."""
    folder = tmp_path_factory.mktemp("loop")
    path = make_run(folder / "run", "MARA", True, relative=True, max_joint_step=0.05)
    return path, export_policy(path, folder / "p.onnx"), export_policy(path, folder / "p.npz")


def test_export_matches_checkpoint_on_the_same_episodes(exported):
    path, onnx_path, npz_path = exported
    policy = make_policy(path)
    first = in_the_loop.load(onnx_path)
    env = in_the_loop.make_env(first, max_episode_steps=12)
    ours = evaluate(env, policy, CONFIG)
    for export in (first, in_the_loop.load(npz_path)):
        got = evaluate(env, export.policy, CONFIG)
        assert got.reached.sum() == ours.reached.sum()
        np.testing.assert_array_equal(got.steps, ours.steps)
        np.testing.assert_allclose(
            got.position_error_mm.mean(0), ours.position_error_mm.mean(0), atol=0.01
        )
        np.testing.assert_allclose(
            got.orientation_error_deg.mean(0), ours.orientation_error_deg.mean(0), atol=0.01
        )
    assert 0 < ours.reached.sum() < CONFIG.episodes and len(set(ours.steps.tolist())) > 1


def test_layout_mismatch_is_refused(exported):
    export = in_the_loop.load(exported[1])
    with pytest.raises(in_the_loop.InTheLoopError, match="observes"):
        in_the_loop.make_env(export, "MARAOrient")


def test_cli_reports_the_file(exported, tmp_path, capsys):
    _, onnx_path, _ = exported
    out = tmp_path / "r.json"
    argv = [str(onnx_path), "--episodes", "2", "--max_episode_steps", "4", "--json", str(out)]
    assert evaluate_main(argv) == 0
    report = json.loads(out.read_text())
    assert report["exported_policy"]["path"] == str(onnx_path)
    assert len(report["exported_policy"]["sha256"]) == 64
    assert "checkpoint" not in report and report["env_name"] == "MARA"
    assert f"exported policy: {onnx_path}" in capsys.readouterr().out
    with pytest.raises(UserError, match="--env is for an exported file"):
        evaluate_main([str(exported[0]), "--env", "MARA", "--json", str(out)])
