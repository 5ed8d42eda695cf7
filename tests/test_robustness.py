"""The robustness study's parts that need no training: recipes, the failure rule, the
statistics across seeds, the selection (and `pick`'s checks of its input, and
deploy_sweep's numbers); the study itself runs with --quick in test_benchmark.py."""

from __future__ import annotations

import re

import numpy as np
import pytest

from mara_mjx.bench.robustness import RobustnessConfig, make_jobs, split_recipe
from mara_mjx.bench.robustness_judge import failure
from mara_mjx.bench.robustness_report import iqm, iqm_interval, summarise


def test_recipes_name_a_preset_or_the_cli_choice():
    assert split_recipe("cli") == ("", "")
    assert split_recipe("default --population 4") == ("default", "--population 4")
    with pytest.raises(ValueError, match="unknown preset 'nope'.*'cli'"):
        split_recipe("nope --randomize")


@pytest.mark.parametrize(
    "recipes, message",
    [
        (("default --seeds 4",), "the study sets --seeds"),
        (("cli --no_such_flag 1",), "no_such_flag"),
        (("cli", "cli"), "distinct"),
        (("bogus",), "unknown preset"),
    ],
)
def test_bad_recipes_are_refused(recipes, message):
    with pytest.raises(ValueError, match=message):
        RobustnessConfig(tasks=("MARA",), recipes=recipes)


def test_jobs_are_the_users_seeds_command(tmp_path):
    config = RobustnessConfig(
        tasks=("MARA", "MARAOrient"), recipes=("cli", "default --randomize"), seeds=3
    )
    jobs = make_jobs(config, tmp_path)
    assert [(j.task, j.recipe, j.preset) for j in jobs] == [
        ("MARA", "cli", "ik_finish"),
        ("MARA", "default --randomize", "default"),
        ("MARAOrient", "cli", "orient_first"),
        ("MARAOrient", "default --randomize", "default"),
    ]
    assert len({j.out for j in jobs}) == 4
    cmd = jobs[1].command
    assert cmd.startswith("python -m mara_mjx.train --env MARA --seed 1000 --seeds 3 ")
    assert "--preset default --randomize " in cmd and cmd.endswith(str(jobs[1].out))
    assert "--preset" not in jobs[0].command  # the CLI's own choice, as a user types it


def test_iqm_is_the_mean_of_the_middle_half():
    x = np.array([100.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, -50.0])  # middle half: 2, 3, 4, 5
    assert iqm(x) == pytest.approx(3.5)
    lo, hi = iqm_interval(x, 500)
    assert lo <= 3.5 <= hi and hi > lo
    assert iqm_interval(np.full(16, 2.0), 200) == (2.0, 2.0)


def _row(position, reached=10, orientation=None, within=None):
    row = {"paper": {"position_mm": position, "reached": reached, "episodes": 10}}
    if orientation is not None:
        row["paper"]["orientation_deg"] = orientation
    if within is not None:
        row["real"] = {"0.3": {"within_5": within}}
    return row


def test_a_seed_fails_below_the_papers_bar():
    config = RobustnessConfig(tasks=("MARA",))
    assert failure(_row([1.0, 1.0, 1.0]), "MARA", config) == []
    assert failure(_row([1.0, 1.0, 1.0], reached=9), "MARA", config) == ["reached 9/10"]
    (why,) = failure(_row([1.0, 7.0, 1.0]), "MARA", config)  # paper's y mean: 6.78 mm
    assert "position over the paper's mean" in why and "7.00>6.78" in why
    orient = _row([1.0, 1.0, 1.0], orientation=[0.1, 1.7, 0.1])  # pitch: paper 1.61 deg
    (why,) = failure(orient, "MARAOrient", config)
    assert why.startswith("orientation over") and "1.70>1.61" in why
    (why,) = failure(_row([1.0, 1.0, 1.0], within=0.985), "MARA", config)
    assert why == "real 0.3 rad/s: 98.5% within 5 mm/deg"


def test_summary_names_the_worst_seed_per_metric():
    config = RobustnessConfig(tasks=("MARA",), bootstrap=100)
    rows = []
    for seed, pos, within in [
        (1000, [1, 2, 3], 1.0),
        (1001, [9, 1, 1], 0.9),
        (1002, [2, 2, 2], 1.0),
    ]:
        row = {"seed": seed, "task": "MARA", "recipe": "cli", **_row(pos, within=within)}
        rows.append({**row, "failed": bool(failure(row, "MARA", config))})
    summary = {r["metric"]: r for r in summarise(rows, config)}
    paper = summary["paper position"]
    assert paper["worst_seed"] == 1001 and paper["worst"] == [9, 1, 1]
    assert paper["mean"] == pytest.approx([4.0, 5 / 3, 2.0])
    assert paper["median"] == [2.0, 2.0, 2.0]
    assert paper["failed_seeds"] == [1001]  # 9 mm > 5.74 and 90% within 5 mm
    within = summary["real 0.3 rad/s within 5 mm(/deg)"]
    assert within["worst_seed"] == 1001 and within["worst"] == [0.9]  # smaller is worse


def test_an_unfinished_run_is_continued_and_an_empty_one_started_again(tmp_path):
    from mara_mjx.bench.robustness import continue_argv
    from mara_mjx.ppo.checkpoint import CHECKPOINT_DIR, checkpoint_name

    config = RobustnessConfig(tasks=("MARA",), seeds=2)
    (job,) = make_jobs(config, tmp_path)
    assert continue_argv(config, job) == list(job.argv)  # nothing there yet
    job.out.mkdir(parents=True)
    (job.out / "progress.csv").write_text("update\n")  # stopped before any checkpoint
    assert continue_argv(config, job) == list(job.argv) and not job.out.exists()
    folder = job.out / "seed_1000" / CHECKPOINT_DIR
    folder.mkdir(parents=True)
    (folder / checkpoint_name(3)).write_bytes(b"")
    argv = continue_argv(config, job)
    assert argv[1:5] == ["-m", "mara_mjx.train", "--resume", str(job.out)]
    assert "--preset" not in argv and "--seeds" not in argv  # the run keeps its config


def test_pose_summary_keeps_the_worst_episodes_to_replay():
    from types import SimpleNamespace

    from mara_mjx.bench.robustness_judge import WORST_EPISODES, pose_summary

    rng = np.random.default_rng(0)
    pos = rng.uniform(0.0, 0.5, (40, 3))
    pos[7] = [0.1, 9.0, 0.2]  # misses by 9 mm in y
    ori = rng.uniform(0.0, 0.5, (40, 3))
    ori[12, 2] = 3.0  # 3 deg in yaw: within 5, not within 1
    collisions = np.zeros(40, int)
    collisions[[7, 30]] = [4, 1]
    result = SimpleNamespace(
        position_error_mm=pos, orientation_error_deg=ori, collisions=collisions
    )
    targets = SimpleNamespace(pos=rng.uniform(size=(40, 3)), quat=rng.uniform(size=(40, 4)))
    out = pose_summary(result, True, targets)
    assert out["within_5"] == pytest.approx(39 / 40) and out["within_1"] == pytest.approx(38 / 40)
    assert out["within_5mm_2deg"] == pytest.approx(38 / 40)  # the 3 deg yaw misses this bar
    assert out["episodes_colliding"] == pytest.approx(2 / 40)
    worst = out["worst_episodes"]
    assert len(worst) == WORST_EPISODES and [w["episode"] for w in worst[:2]] == [7, 12]
    assert worst[0]["collisions"] == 4 and worst[0]["target_pos"] == targets.pos[7].tolist()
    assert out["position_mm"]["max"] == pytest.approx(pos.max(0).tolist())


def test_gpu_slots_name_the_users_visible_gpus(monkeypatch):
    """With CUDA_VISIBLE_DEVICES=2,3 JAX numbers the two GPUs 0 and 1: the train commands
    must get 2 and 3."""
    import jax

    from mara_mjx.bench import robustness

    class Gpu:
        platform = "gpu"

    monkeypatch.setattr(jax, "devices", lambda: [Gpu(), Gpu()])
    assert robustness.gpu_slots(0, "2,3") == ["2", "3"]
    assert robustness.gpu_slots(1, "2,3") == [None]  # one at a time, as the user set it
    assert robustness.gpu_slots(0, "") == ["0", "1"]
    monkeypatch.setattr(jax, "devices", lambda: [Gpu()])
    assert robustness.gpu_slots(0, "5") == [None]


def test_a_rerun_with_other_flags_gets_its_own_run_folder(tmp_path):
    """The run folder is named by the whole command: the same task and recipe with other
    seeds or train flags in the same work folder never continues or judges another
    command's run."""
    base = RobustnessConfig(tasks=("MARA",), seeds=2)
    (a,) = make_jobs(base, tmp_path)
    (b,) = make_jobs(base.replace(seeds=3), tmp_path)
    (c,) = make_jobs(base.replace(train_args="--num_envs 8"), tmp_path)
    (again,) = make_jobs(base, tmp_path)
    assert len({a.out, b.out, c.out}) == 3 and again.out == a.out
    assert a.out.name.startswith("MARA-cli-")


def test_select_trains_k_seeds_per_judged_seed_and_keeps_the_one_that_transfers(tmp_path):
    from mara_mjx.bench.robustness_judge import select_seeds

    config = RobustnessConfig(tasks=("MARA",), recipes=("default",), seeds=2, select=3)
    assert " --seeds 6 " in make_jobs(config, tmp_path)[0].command
    assert config.selection_seed == 1001  # never the judged episodes
    with pytest.raises(ValueError, match="select_seed=1000 is eval_seed"):
        RobustnessConfig(tasks=("MARA",), select=2, select_seed=1000)

    def row(w3, w5, err, colliding=0.0):
        runs = {"0.3": w3, "0.5": w5}
        return {"real": {v: {"within_5": w, "position_mm": {"mean": [err] * 3},
                             "episodes_colliding": colliding}
                         for v, w in runs.items()}}  # fmt: skip

    rows = [
        row(1.0, 0.5, 1.0),
        row(0.9, 0.9, 9.0),
        row(0.9, 0.9, 2.0),  # group 1: index 2
        row(0.0, 0.0, 1.0),
        row(1.0, 1.0, 0.5),
        row(1.0, 1.0, 0.4),  # group 2: index 5
        row(1.0, 1.0, 0.1, 0.3),
        row(1.0, 1.0, 0.9, 0.01),
        row(1.0, 0.9, 0.1),
    ]  # 3: 7
    picks, records = select_seeds(list(range(10, 19)), rows, 3)
    # the highest worst-velocity fraction, then the fewest collisions, then the lowest error
    assert picks == [2, 5, 7]
    assert records[0]["group"] == [10, 11, 12]
    assert records[1]["candidates"][13]["0.3"] == {
        "within_5": 0.0,
        "colliding": 0.0,
        "error_mm": 1.0,
    }
    # on a task with an orientation, the ranking's bar is 5 mm and 2 deg
    a, b = row(1.0, 1.0, 0.5), row(1.0, 1.0, 0.9)
    for r in a["real"].values():
        r["within_5mm_2deg"] = 0.8  # within 5 deg, not within 2
    for r in b["real"].values():
        r["within_5mm_2deg"] = 1.0
    assert select_seeds([1, 2], [a, b], 2)[0] == [1]

    # on a random-target task the train driver's poses count too: servo ties (100%, no
    # collision) broken by the fraction within 1 mm, then by its collisions
    def train(within_1, colliding=0.0):
        return {"targets": {"within_1": within_1, "episodes_colliding": colliding,
                            "position_mm": {"mean": [0.2] * 3}}}  # fmt: skip

    tied = [
        {**row(1.0, 1.0, 0.3), **train(0.998)},
        {**row(1.0, 1.0, 0.9), **train(1.0)},
        {**row(1.0, 1.0, 0.1), **train(1.0, 0.002)},
        {**row(0.99, 1.0, 0.1), **train(1.0)},
    ]
    picks, records = select_seeds([5, 6, 7, 8], tied, 4)
    assert picks == [1] and records[0]["train"][5]["within_1"] == 0.998
    assert "train" not in select_seeds([1, 2], [a, b], 2)[1][0]  # servos alone: no record


def load_script(name: str):
    """A benchmarks/ script as a module."""
    import importlib.util
    from pathlib import Path

    path = Path(__file__).resolve().parents[1] / "benchmarks" / f"{name}.py"
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_deploy_sweep_reads_an_evaluate_report():
    """benchmarks/deploy_sweep.py's numbers from a report's episodes: the two bars (mm and,
    on an Orient task, deg together), per-axis mean / p95 / worst, colliding episodes."""
    sweep = load_script("deploy_sweep")

    def episode(mm, deg, collisions=0):
        return {"position_error_mm": [mm, 0.1, 0.1], "orientation_error_deg": [deg, 0, 0],
                "collisions": collisions}  # fmt: skip

    eps = [episode(0.5, 0.5), episode(3.0, 0.5, 2), episode(3.0, 3.0), episode(9.0, 0.1)]
    m = sweep.metrics({"env_name": "MARACollisionOrientRandomTarget", "episodes": eps})
    assert m["within_5mm_2deg"] == 0.5  # 3.0 deg and 9.0 mm miss
    assert m["within_1mm_1deg"] == 0.25
    assert m["position_mm"]["worst"] == [9.0, 0.1, 0.1] and m["colliding"] == 0.25
    assert m["position_mm"]["mean"][0] == pytest.approx(3.875)
    plain = sweep.metrics({"env_name": "MARACollision", "episodes": eps})
    assert plain["within_5mm"] == 0.75 and "orientation_deg" not in plain


def test_deploy_sweep_keeps_what_ran_and_a_users_files(tmp_path, monkeypatch, capsys):
    """deploy_sweep.py writes its JSON after every cell (a sweep cut off keeps the cells
    that ran), replaces an earlier sweep's files, and refuses, before running anything, an
    --out whose deploy_sweep.* a user wrote, or an --out that is a file."""
    import json

    sweep = load_script("deploy_sweep")
    calls = []

    def fake(policy, velocity, flags, args, tmp):
        calls.append(flags)
        if len(calls) == 3:
            raise KeyboardInterrupt  # the machine taken back mid-sweep
        ep = {"position_error_mm": [0.5, 0.1, 0.1], "collisions": 0}
        return "python -m mara_mjx.evaluate ...", 1.0, {"env_name": "MARA", "episodes": [ep]}

    monkeypatch.setattr(sweep, "evaluate", fake)
    out = tmp_path / "sweep"
    argv = ["p.onnx", "--out", str(out), "--velocities", "0.3", "--calibrations"]
    with pytest.raises(KeyboardInterrupt):
        sweep.main(argv)  # randomised, latency 0, latency 1 (cut), ...
    data = json.loads((out / "deploy_sweep.json").read_text())
    assert data["complete"] is False and [r["condition"] for r in data["rows"]] == [
        "randomised", "latency 0"]  # fmt: skip
    calls.clear()
    assert sweep.main([*argv[:-1], "--latencies", "--calibrations"]) == 0  # replaces its own
    data = json.loads((out / "deploy_sweep.json").read_text())
    assert data["complete"] is True and len(data["rows"]) == 1
    assert (out / "deploy_sweep.png").is_file()
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "deploy_sweep.md").write_text("my notes")
    calls.clear()
    for bad, message in (
        (mine, "exists and was not written"),
        (mine / "deploy_sweep.md", "is a file"),
    ):
        with pytest.raises(SystemExit) as e:
            sweep.main(["p.onnx", "--out", str(bad)])
        assert e.value.code == 2 and message in capsys.readouterr().err
    assert calls == [] and (mine / "deploy_sweep.md").read_text() == "my notes"
    check = load_script("deploy_check")
    (mine / "deploy_check.json").write_text("{}")
    monkeypatch.setattr("sys.argv", ["deploy_check.py", "seed", "--out", str(mine), "--label", "x"])
    with pytest.raises(SystemExit) as e:
        check.main()
    assert e.value.code == 2 and "deploy_check.json" in capsys.readouterr().err


@pytest.mark.parametrize(
    "flags, message",
    [
        (["--draws", "0"], "--draws must be at least 1"),
        (["--velocities", "0.3", "11"], "--velocities must be in (0, 10]"),
        (["--velocities", "0.3", "0.3"], "--velocities must be distinct"),
        (["--seed", "-1"], "--seed must be >= 0"),
        (["--collision_guard_mm", "-2"], "--collision_guard_mm must be -1 or >= 0"),
    ],
)
def test_pick_cli_names_bad_input(tmp_path, flags, message):
    """`python -m mara_mjx.pick` refuses bad settings by name before loading anything."""
    from mara_mjx.cli import pick
    from mara_mjx.cli.common import UserError

    with pytest.raises(UserError, match=re.escape(message)):
        pick.main([str(tmp_path), *flags])
    assert not list(tmp_path.iterdir())  # nothing written


def test_pick_warns_when_even_the_chosen_seed_misses_draws():
    """`pick`'s warning: none when the chosen seed ends every draw within the bar; when it
    misses some (the any-pose pick that missed 2 of 200 held 98.4% on other draws), the
    warning names the misses per speed, and the markdown carries it under the choice."""
    from mara_mjx.cli.pick import markdown, warning

    clean = {"0.3": {"within_5": 1.0, "colliding": 0.005, "error_mm": 0.3},
             "0.5": {"within_5": 1.0, "colliding": 0.0, "error_mm": 0.3}}  # fmt: skip
    assert warning(clean, 200, "5 mm") is None  # a collision alone is no miss
    missed = {**clean, "0.5": {"within_5": 0.99, "colliding": 0.0, "error_mm": 2.1}}
    text = warning(missed, 200, "5 mm and 2 deg")
    assert "misses 2 of 200 draws at 0.5 rad/s outside 5 mm and 2 deg:" in text
    assert "0.3 rad/s" not in text
    exact = {"within_1": 1.0, "colliding": 0.0, "error_mm": 0.1}
    assert warning(clean, 200, "5 mm", exact, 1000) is None
    inexact = warning(clean, 200, "5 mm", {**exact, "within_1": 0.997}, 1000)
    assert "misses 3 of 1000 train-driver poses outside 1 mm:" in inexact
    report = {"env_name": "T", "run": "r", "orientation": True, "chosen": 7, "chosen_folder": "f",
              "settings": {"draws": 200, "eval_seed": 1}, "warning": text,
              "ranking": [{"seed": 7, "velocities": missed}]}  # fmt: skip
    assert markdown(report).splitlines()[-2:] == ["chosen: seed 7, f", f"warning: {text}"]
    assert "warning" not in markdown({**report, "warning": None})


@pytest.mark.parametrize("task, poses", [("MARAOrientRandomTarget", 8), ("MARA", 0)])
def test_pick_ranks_random_target_seeds_on_the_train_driver_too(tmp_path, monkeypatch, task, poses):
    """`pick` on a random-target run judges every seed on --poses train-driver poses drawn
    from --seed as well as on the servos, and ranks by both (a seed exact on the servos'
    few draws but not on the poses loses to one exact on both); on a fixed-target run it
    asks for no poses. (The judgements are faked here: the real ones run in
    test_seeds_cli's pick test and, on a random-target run, NOTES section 45.)"""
    import json

    from mara_mjx.bench import robustness_judge
    from mara_mjx.cli import pick
    from mara_mjx.envs import make
    from mara_mjx.ppo import seed_eval

    env = make(task)
    meta = {"env_name": task, "env_config": {}, "observation_size": env.observation_size}
    (tmp_path / "seeds.json").write_text(json.dumps({"env_name": task, "seeds": [3, 4]}))
    asked = []

    def real(meta, policy, n, settings, orientation):
        asked.append(("real", settings.eval_seed, settings.draws))
        summary = {"within_5": 1.0, "within_5mm_2deg": 1.0, "episodes_colliding": 0.0,
                   "position_mm": {"mean": [0.3] * 3}}  # fmt: skip
        return [{"real": {"0.3": dict(summary)}} for _ in range(n)]

    def targets(env, policy, n, settings, orientation):
        asked.append(("train", settings.eval_seed, settings.poses))
        mean = {"mean": [0.2] * 3}
        return [{"targets": {"within_1": w, "episodes_colliding": 0.0, "position_mm": mean}}
                for w in (0.875, 1.0)]  # fmt: skip

    monkeypatch.setattr(robustness_judge, "load_seeds", lambda top, s: ([None, None], meta, []))
    monkeypatch.setattr(robustness_judge, "judge_real", real)
    monkeypatch.setattr(robustness_judge, "judge_targets", targets)
    monkeypatch.setattr(seed_eval, "stack_policies", lambda p: p)
    argv = [str(tmp_path), "--velocities", "0.3", "--draws", "4", "--seed", "5", "--poses", "8"]
    assert pick.main(argv) == 0
    report = json.loads((tmp_path / pick.REPORT).read_text())
    if poses:
        assert asked == [("real", 5, 4), ("train", 5, 8)]
        assert report["chosen"] == 4 and report["ranking"][1]["train"]["within_1"] == 0.875
        assert report["warning"] is None  # the chosen seed missed nothing
        assert "train driver: within 1 mm and 1 deg" in (tmp_path / "pick-real.md").read_text()
    else:
        assert asked == [("real", 5, 4)] and "train" not in report["ranking"][0]
        assert report["settings"]["poses"] == 0
