"""benchmarks/robustness_merge.py: robustness studies run in parts (one per GPU) written as
one study, the statistics over seeds recomputed; parts judged differently, a seed judged
twice and a user's files in --out refused; deploy_sweep.py --merge; robustness_pairs.py."""

from __future__ import annotations

import gzip
import json
import re

import pytest
from test_robustness import load_script

CONFIG = {"tasks": ["T"], "recipes": ["cli"], "seeds": 2, "seed_offset": 1000, "eval_seed": 1000,
          "draws": 1000, "bootstrap": 50, "out": "a", "work_dir": "", "parallel": 0}  # fmt: skip


def seed_row(seed: int, within_5: float) -> dict:
    return {"kind": "seed", "task": "T", "recipe": "cli", "seed": seed, "failed": within_5 < 0.99,
            "why": [], "command": f"python -m mara_mjx.train --seed {seed // 2 * 2}",
            "targets": {"within_5": within_5, "within_1": within_5,
                        "position_mm": {"mean": [0.1 * seed % 1, 0.2, 0.3]},
                        "episodes_colliding": 0.001}}  # fmt: skip


def write_part(folder, seeds, within, gz=False, **config):
    folder.mkdir()
    command = f"python -m mara_mjx.benchmark robustness {folder.name}"
    data = {"study": "robustness", "command": command,
            "device": {"device_kind": "NVIDIA H200", "platform": "gpu"}, "git_commit": "abc",
            "versions": {"jax": "0.11.2", "mujoco": "3.17.0"}, "date": "today",
            "config": {**CONFIG, **config},
            "records": [seed_row(s, w) for s, w in zip(seeds, within, strict=True)]
            + [{"kind": "metric", "stale": True}]}  # fmt: skip
    if gz:
        with gzip.open(folder / "robustness.json.gz", "wt") as f:
            json.dump(data, f)
    else:
        (folder / "robustness.json").write_text(json.dumps(data))
    return folder


def test_parts_merge_into_one_study_over_all_their_seeds(tmp_path, capsys):
    from mara_mjx.bench.robustness_report import summarise

    merge = load_script("robustness_merge")
    a = write_part(tmp_path / "a", [1000, 1001], [1.0, 0.98])
    b = write_part(tmp_path / "b", [1002, 1003], [0.995, 1.0], gz=True, seed_offset=1002, out="b")
    out = tmp_path / "merged"
    assert merge.main([str(a), str(b), "--out", str(out)]) == 0
    data = json.loads((out / "robustness.json").read_text())
    seeds = [r for r in data["records"] if r["kind"] == "seed"]
    metrics = [r for r in data["records"] if r["kind"] == "metric"]
    assert [r["seed"] for r in seeds] == [1000, 1001, 1002, 1003]
    assert not any(r.get("stale") for r in metrics)  # the parts' own statistics are dropped
    expected = summarise(seeds, type("C", (), {"bootstrap": 50}))
    assert metrics == json.loads(json.dumps(expected))
    within = next(r for r in metrics if r["metric"].startswith("poses within 5"))
    assert (
        within["seeds"] == 4 and within["failed_seeds"] == [1001] and within["worst_seed"] == 1001
    )
    assert data["config"]["seeds"] == 4 and [p["git_commit"] for p in data["parts"]] == ["abc"] * 2
    md = (out / "robustness.md").read_text()
    assert "robustness_merge.py" in md and "1 / 4" in md
    assert "--seed 1000" in md and "--seed 1002" in md  # each part's train command
    assert (out / "robustness.png").is_file()
    assert merge.main([str(a), str(b), "--out", str(out)]) == 0  # replaces its own output


def test_parts_judged_differently_or_overlapping_are_refused(tmp_path, capsys):
    merge = load_script("robustness_merge")
    a = write_part(tmp_path / "a", [1000, 1001], [1.0, 1.0])
    other_eval = write_part(tmp_path / "b", [1002, 1003], [1.0, 1.0], eval_seed=7)
    overlap = write_part(tmp_path / "c", [1001, 1002], [1.0, 1.0])
    out = tmp_path / "m"
    with pytest.raises(SystemExit, match=r"differ in eval_seed \(1000 vs 7\)"):
        merge.main([str(a), str(other_eval), "--out", str(out)])
    with pytest.raises(SystemExit, match="seed 1001 of T / cli is judged in two parts"):
        merge.main([str(a), str(overlap), "--out", str(out)])
    with pytest.raises(SystemExit) as e:
        merge.main([str(a), str(tmp_path / "a"), "--out", str(out)])
    assert e.value.code == 2 and "given twice" in capsys.readouterr().err
    with pytest.raises(SystemExit, match="holds no robustness.json"):
        merge.main([str(a), str(tmp_path), "--out", str(out)])
    assert not out.exists() or not list(out.iterdir())  # nothing written by a refused merge
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "robustness.md").write_text("my notes")
    with pytest.raises(SystemExit) as e:
        merge.main([str(a), "--out", str(mine)])
    assert e.value.code == 2 and "was not written" in capsys.readouterr().err
    assert (mine / "robustness.md").read_text() == "my notes"


def test_deploy_sweeps_merge_into_one_with_flat_parts(tmp_path, monkeypatch):
    """deploy_sweep.py --merge: complete one-cell sweeps as one sweep (each row its own
    command); a merged sweep merged again keeps one flat list of the original parts; an
    incomplete sweep, a folder given twice and sweeps of several tasks are refused."""
    sweep = load_script("deploy_sweep")
    task = {"p0.onnx": "T", "p1.onnx": "T", "p2.onnx": "T", "q.onnx": "U"}

    def fake(policy, velocity, flags, args, tmp):
        ep = {"position_error_mm": [0.5, 0.1, 0.1], "collisions": 0}
        return f"evaluate {policy} {velocity}", 1.0, {"env_name": task[policy], "episodes": [ep],
                                                      "versions": {"jax": policy}}  # fmt: skip

    monkeypatch.setattr(sweep, "evaluate", fake)
    cell = ["--latencies", "--calibrations"]
    for name in task:
        assert sweep.main([name, "--out", str(tmp_path / name), "--velocities", "0.3", *cell]) == 0
    ab = tmp_path / "ab"
    assert sweep.main(["--merge", str(tmp_path / "p0.onnx"), str(tmp_path / "p1.onnx"),
                       "--out", str(ab), "--label", "x"]) == 0  # fmt: skip
    abc = tmp_path / "abc"
    assert sweep.main(["--merge", str(ab), str(tmp_path / "p2.onnx"), "--out", str(abc)]) == 0
    data = json.loads((abc / "deploy_sweep.json").read_text())
    assert [r["command"] for r in data["rows"]] == [f"evaluate p{i}.onnx 0.3" for i in range(3)]
    assert [p["versions"] for p in data["parts"]] == [{"jax": f"p{i}.onnx"} for i in range(3)]
    assert data["complete"] is True and (abc / "deploy_sweep.png").is_file()
    data["complete"] = False
    (tmp_path / "p2.onnx" / "deploy_sweep.json").write_text(json.dumps(data))
    for parts, message in (
        (["p2.onnx"], "an incomplete deploy_sweep.json"),
        (["p0.onnx", "p0.onnx"], "is given twice"),
        (["p0.onnx", "q.onnx"], "several tasks (T, U)"),
    ):
        with pytest.raises(SystemExit, match=re.escape(message)):
            sweep.main(
                ["--merge", *[str(tmp_path / p) for p in parts], "--out", str(tmp_path / "m")]
            )


def test_pairs_prints_each_seed_both_ways_and_names_the_seeds_short(tmp_path, capsys):
    """benchmarks/robustness_pairs.py: two judgements of the same seeds side by side."""
    pairs = load_script("robustness_pairs")
    a = write_part(tmp_path / "a", [1000, 1001], [1.0, 0.98])
    b = write_part(tmp_path / "b", [1000, 1001], [1.0, 0.995], gz=True)
    assert pairs.main([str(a), str(b), "--label_b", "restarts"]) == 0
    out = capsys.readouterr().out
    assert "| 1001 | 98.0 -> 99.5% | 0.1 -> 0.1% |" in out
    assert "as trained: 1 of 2 seeds miss a bar (1001)" in out
    assert "restarts: 0 of 2 seeds miss a bar" in out
    c = write_part(tmp_path / "c", [1000, 1002], [1.0, 1.0])
    assert pairs.main([str(a), str(c)]) == 2  # other seeds: refused
    assert "judge different seeds" in capsys.readouterr().err
