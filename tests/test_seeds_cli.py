"""Several seeds through the CLIs, as a user runs them (subprocesses, tiny settings): a
--seeds run is its seeds' single runs, evaluates, resumes and feeds the robustness study.
Split from test_train_cli.py (which trains the population and Orient-default runs) so that
the suite's workers share the subprocess trainings."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
from test_train_cli import CKPT1, CKPT2, TINY, read_rows, run_module

from mara_mjx.cli import pick
from mara_mjx.cli import train as train_cli
from mara_mjx.cli.common import run_cli
from mara_mjx.ppo import checkpoint as ckpt

# ------------------------------------------------------------------ several seeds
# TINY (seed 0) with --seeds 2: seeds 0 and 1 vmapped in one program; seed 0 must match
# a single run. With the CLI's own preset for MARA (ik_finish: the IK step in the vmapped
# program), as a user runs it. These programs used to deadlock XLA:CPU now and then (NOTES
# sections 15 and 28; they ran the `default` preset for that): batched LAPACK calls (the
# IK step's LU, the vmapped orthogonal init's QR) blocking every thread of XLA's CPU
# pool. Since NOTES section 30 a CPU program makes none
# (test_ik_finish.py::test_cpu_training_programs_hold_no_batched_lapack_call...), so these
# processes compile at the suite's LLVM O0 flags (cli_env) like every other CLI test (they
# ran without them, as users compile, while the hang was blamed on O0: 2-3x the compile).
SEEDS = [*TINY, "--seeds", "2", "--tensorboard", "false"]


@pytest.fixture(scope="session")
def seeds_run(cli_env, tmp_path_factory):
    """(run folder, completed process) of the tiny two-seed run."""
    out = tmp_path_factory.mktemp("seeds") / "run"
    proc = run_module(cli_env, "mara_mjx.train", *SEEDS, "--out", str(out))
    assert proc.returncode == 0, proc.stderr[-4000:]
    return out, proc


@pytest.fixture(scope="session")
def single_run(cli_env, tmp_path_factory):
    """TINY, seed 0, compiled like seeds_run, for their comparison (of the checkpoints:
    no final evaluation, plots or TensorBoard, which only cost compiles and imports)."""
    out = tmp_path_factory.mktemp("single") / "run"
    quiet = ["--evaluate", "false", "--plots", "false", "--tensorboard", "false"]
    proc = run_module(cli_env, "mara_mjx.train", *TINY, *quiet, "--out", str(out))
    assert proc.returncode == 0, proc.stderr[-4000:]
    return out, proc


def test_a_seeds_run_is_read_for_its_driver(seeds_run):
    """Resuming or evaluating a multi-seed run chooses the XLA flags of its driver (the
    train driver's, as the run was trained), not the real driver's careful default."""
    import argparse

    from mara_mjx.cli.common import uses_real_driver

    out, _ = seeds_run
    assert uses_real_driver(argparse.Namespace(), str(out)) is False
    assert uses_real_driver(argparse.Namespace(), str(out / "no_such_run")) is True


def test_robustness_study_judges_a_seeds_run(seeds_run, cli_env, tmp_path):
    """`python -m mara_mjx.benchmark robustness` on the tiny two-seed run (its training
    reused through the study's work folder, as a rerun with the same --work_dir finds
    it): every seed judged (the paper's evaluation and the hold), the summary across
    seeds per metric, JSON, markdown and figure."""
    from mara_mjx.bench.robustness import RobustnessConfig, make_jobs

    out, _ = seeds_run
    work, results = tmp_path / "work", tmp_path / "results"
    flags = ["--tasks", "MARA", "--seeds", "2", "--seed_offset", "0", "--episodes", "2"]
    flags += ["--bootstrap", "50", "--work_dir", str(work), "--out", str(results)]
    (job,) = make_jobs(
        RobustnessConfig(tasks=("MARA",), seeds=2, seed_offset=0, episodes=2, bootstrap=50),
        work,
    )
    shutil.copytree(out, job.out)
    timing = {"command_s": 1.0, "launch_offset_s": 0.0}
    job.log.with_suffix(".done").write_text(json.dumps({"command": job.command, "timing": timing}))
    proc = run_module(cli_env, "mara_mjx.benchmark", "robustness", *flags)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert "reusing the finished run of python -m mara_mjx.train --env MARA --seed 0" in proc.stdout
    data = json.loads((results / "robustness.json").read_text())
    seeds = [r for r in data["records"] if r["kind"] == "seed"]
    metrics = {r["metric"]: r for r in data["records"] if r["kind"] == "metric"}
    assert [(r["task"], r["recipe"], r["preset"], r["seed"]) for r in seeds] == [
        ("MARA", "cli", "ik_finish", 0),
        ("MARA", "cli", "ik_finish", 1),
    ]
    assert set(metrics) == {"paper position", "hold position", "hold collisions/episode"}
    for r in seeds:  # 64 env steps learn nothing: every seed misses the paper's bar
        assert r["paper"]["episodes"] == 2 and len(r["paper"]["position_mm"]) == 3
        assert r["failed"] and any("over the paper's mean" in w for w in r["why"])
    paper = metrics["paper position"]
    assert paper["failed_seeds"] == [0, 1] and paper["train_reused"] is True
    values = np.array([r["paper"]["position_mm"] for r in seeds])
    assert paper["mean"] == pytest.approx(values.mean(0).tolist())
    worst = int(np.argmax(values.max(1)))
    assert paper["worst_seed"] == worst and paper["worst"] == values[worst].tolist()
    for iqm, (lo, hi) in zip(paper["iqm"], paper["iqm_ci95"], strict=True):
        assert lo - 1e-9 <= iqm <= hi + 1e-9
    text = (results / "robustness.md").read_text()
    assert "| MARA | `cli` | paper position (mm) | 2 / 2 |" in text and "seed 1:" in text
    assert (results / "robustness.png").read_bytes()[:4] == b"\x89PNG"


def test_each_seed_of_a_seeds_run_is_the_single_run_of_that_seed(single_run, seeds_run):
    single, _ = single_run
    out, proc = seeds_run
    assert "Traceback" not in proc.stderr and "det_mm_median" in proc.stderr  # one bar
    for s in (0, 1):
        folder = out / f"seed_{s}"
        config = json.loads((folder / "config.json").read_text())
        assert config["ppo"]["seed"] == s and config["run"]["seeds"] == 1
        assert config["run"]["out"] == str(folder)
        assert [int(r["update"]) for r in read_rows(folder / "progress.csv")] == [1, 2]
        assert (folder / CKPT1).exists() and (folder / CKPT2).exists()
        assert len(json.loads((folder / "eval.json").read_text())["episodes"]) == 10
        assert (folder / "summary.json").exists() and (folder / "plots" / "error.png").exists()
    expected, _ = ckpt.load_checkpoint(single / CKPT2)
    seed0, meta = ckpt.load_checkpoint(out / "seed_0" / CKPT2)
    seed1, _ = ckpt.load_checkpoint(out / "seed_1" / CKPT2)
    assert meta["progress"]["update"] == 2 and expected.keys() == seed0.keys()
    for name in expected:
        np.testing.assert_allclose(seed0[name], expected[name], atol=1e-5, err_msg=name)
    kernel = "params/params/actor/Dense_0/kernel"
    assert not np.allclose(seed1[kernel], seed0[kernel], atol=1e-3)  # seeds differ

    report = json.loads((out / "seeds.json").read_text())
    assert report["seeds"] == [0, 1] and [r["seed"] for r in report["per_seed"]] == [0, 1]
    per_seed = np.array([r["position_error_mm"] for r in report["per_seed"]])
    across = report["across_seeds"]["position_error_mm"]
    np.testing.assert_allclose(across["mean"], per_seed.mean(0))
    np.testing.assert_allclose(across["worst"], per_seed.max(0))
    eval0 = json.loads((out / "seed_0" / "eval.json").read_text())["summary"]
    np.testing.assert_allclose(per_seed[0], eval0["position_error_mm"]["mean"])
    table = (out / "seeds.md").read_text()
    assert "| mean |" in table and "| worst |" in table and "| MARA" not in table
    assert table.split("\n| ")[0] in proc.stdout  # printed at the end


def test_evaluate_cli_on_a_seeds_run(seeds_run, cli_env, tmp_path):
    out, _ = seeds_run
    report_path = tmp_path / "seeds-eval.json"
    proc = run_module(cli_env, "mara_mjx.evaluate", str(out), "--json", str(report_path))
    assert proc.returncode == 0, proc.stderr[-4000:]
    assert "| mean |" in proc.stdout and "| worst |" in proc.stdout
    report = json.loads(report_path.read_text())
    during_training = json.loads((out / "seeds.json").read_text())
    assert report["per_seed"] == during_training["per_seed"]  # same policies, same episodes
    assert [c["checkpoint"] for c in report["checkpoints"]] == [
        str(out / f"seed_{s}" / CKPT2) for s in (0, 1)
    ]
    assert report_path.with_suffix(".md").read_text().startswith("MARA, 2 seeds")


def test_a_seeds_run_resumes_from_its_newest_common_checkpoint(seeds_run, cli_env, tmp_path):
    out, _ = seeds_run
    copy = tmp_path / "resumed"
    shutil.copytree(out, copy)
    (copy / "seed_1" / CKPT2).unlink()  # seed 0 has update 2, seed 1 only update 1
    quiet = ["--progress", "false", "--evaluate", "false", "--plots", "false"]
    proc = run_module(cli_env, "mara_mjx.train", "--resume", str(copy), *quiet)
    assert proc.returncode == 0, proc.stderr[-4000:]
    for s in (0, 1):
        original, _ = ckpt.load_checkpoint(out / f"seed_{s}" / CKPT2)
        resumed, meta = ckpt.load_checkpoint(copy / f"seed_{s}" / CKPT2)
        assert meta["progress"]["update"] == 2 and meta["ppo"]["seed"] == s
        for name in original:
            np.testing.assert_allclose(resumed[name], original[name], atol=1e-6, err_msg=name)
        rows = read_rows(copy / f"seed_{s}" / "progress.csv")
        assert [int(r["update"]) for r in rows] == [1, 2]


def test_pick_cli_ranks_the_seeds_on_the_real_driver(seeds_run, cli_env, tmp_path, capsys):
    """`python -m mara_mjx.pick RUN_OF_SEEDS` as the sim-to-real recipe runs it (tiny:
    2 draws at one speed): every seed judged on the real driver with randomised physics,
    ranked by the study's selection_score, the first named as the one to deploy; its own
    ranking is recognised (a rerun replaces it), a file it did not write is refused,
    untouched, and a one-seed folder is refused with the reason."""
    from mara_mjx.bench.robustness_judge import selection_score

    out, _ = seeds_run
    report_path = tmp_path / "rank.json"
    flags = ["--velocities", "0.3", "--draws", "2", "--seed", "3", "--json", str(report_path)]
    proc = run_module(cli_env, "mara_mjx.pick", str(out), *flags)
    assert proc.returncode == 0, proc.stderr[-4000:]
    report = json.loads(report_path.read_text())
    ranking = report["ranking"]
    assert sorted(r["seed"] for r in ranking) == [0, 1]
    scores = [selection_score(r) for r in ranking]
    assert scores == sorted(scores)
    assert report["chosen"] == ranking[0]["seed"]
    assert report["chosen_folder"] == str(out / f"seed_{report['chosen']}")
    for r in ranking:
        real = r["real"]["0.3"]
        assert set(r["velocities"]) == {"0.3"} and 0.0 <= real["within_5"] <= 1.0
        assert r["velocities"]["0.3"]["colliding"] == real["episodes_colliding"]
    assert report["settings"]["draws"] == 2 and report["settings"]["eval_seed"] == 3
    text = report_path.with_suffix(".md").read_text()
    assert f"chosen: seed {report['chosen']}, {out}/seed_{report['chosen']}" in text
    assert text.splitlines()[0] in proc.stdout

    # a rerun replaces its own ranking
    assert pick.is_ranking(report_path) and not pick.is_ranking(out / "seeds.json")

    # refusals, in-process (before anything is compiled)
    mine = tmp_path / "mine.json"
    mine.write_text('{"keep": 1}')
    assert run_cli(pick.main, pick.PROG, [str(out), "--json", str(mine)]) == 2
    assert "exists and was not written by" in capsys.readouterr().err
    assert mine.read_text() == '{"keep": 1}'
    assert run_cli(pick.main, pick.PROG, [str(out / "seed_0")]) == 2
    assert "not the folder of a several-seed run" in capsys.readouterr().err


def test_a_distill_run_learns_each_seed_from_the_same_seed_of_its_teacher(
    seeds_run, cli_env, tmp_path, capsys, compiled
):
    """--preset distill --teacher RUN --seeds 2: student seed s holds teacher seed s (the
    tiny two-seed run, MARA's CLI default with its IK finish) in its checkpoints, records
    the teacher's absolute path, and exports as the learnt network alone (.npz, no IK);
    a teacher without the student's seeds, of another task, or none are clear errors."""
    teacher, _ = seeds_run
    student = tmp_path / "student"
    quiet = ["--evaluate", "false", "--plots", "false", "--progress", "false"]
    base = [*SEEDS, "--preset", "distill", *quiet]
    proc = run_module(
        cli_env, "mara_mjx.train", *base, "--teacher", str(teacher), "--out", str(student)
    )
    assert proc.returncode == 0, proc.stderr[-4000:]
    for s in (0, 1):
        arrays, meta = ckpt.load_checkpoint(student / f"seed_{s}" / CKPT2)
        assert meta["curriculum"]["teacher"] == str(teacher.resolve())
        assert meta["policy"]["ik_finish"] == 0.0  # the student deploys no IK step
        own, _ = ckpt.load_checkpoint(teacher / f"seed_{s}" / CKPT2)
        other, _ = ckpt.load_checkpoint(teacher / f"seed_{1 - s}" / CKPT2)
        names = [n for n in own if n.startswith("params/params/actor/")]
        assert names
        for n in names:
            np.testing.assert_array_equal(arrays["teacher/" + n], own[n], err_msg=n)
        assert any(not np.array_equal(arrays["teacher/" + n], other[n]) for n in names)
    npz = tmp_path / "student.npz"
    proc = run_module(cli_env, "mara_mjx.export", str(student / "seed_1"), str(npz))
    assert proc.returncode == 0, proc.stderr[-4000:]

    bad = [
        (["--teacher", str(teacher), "--seed", "1"], "no seed folder for student seed(s) [2]"),
        (
            ["--teacher", str(teacher), "--env", "MARACollision"],
            "trained on MARA, not MARACollision",
        ),
        ([], "give --teacher RUN"),
    ]
    for extra, message in bad:  # in-process (the CLI refuses before it compiles anything)
        argv = [*base, *extra, "--out", str(tmp_path / "x")]
        compiled.clear()
        code = run_cli(train_cli.main, train_cli.PROG, argv)
        err = capsys.readouterr().err
        assert code == 2 and message in err and "Traceback" not in err, (extra, err[-2000:])
        assert not (tmp_path / "x").exists()  # nothing written for a refused command
        assert not [n for n in compiled if n in ("jit(run)", "jit(init)")], extra
