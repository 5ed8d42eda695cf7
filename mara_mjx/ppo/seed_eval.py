"""The paper's evaluation over several seeds, and the summary across them.

`evaluate_seeds` runs the evaluation of `mara_mjx.ppo.evaluation` (the same episodes for
every seed) for a policy with a leading seed axis in one vmapped program; `summarise`
makes the summary a multi-seed run reports (`mara_mjx.cli.seeds`): per seed the mean per axis
of the final position (mm) and orientation (deg) errors, the episodes within the
tolerance, the collisions and the time to 5 mm and 1 mm; across the seeds the mean and
the worst seed per axis, the fewest episodes reached, the collisions and the median
times. `markdown` renders it as a table with the paper's numbers beside it.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from mara_mjx.ppo.evaluation import PAPER_RESULTS, EvalResult, make_evaluate
from mara_mjx.ppo.logger import ACCURACY_THRESHOLDS_MM, AXES
from mara_mjx.ppo.policy import Policy


def stack_policies(policies: list[Policy]) -> Policy:
    """One Policy with a leading seed axis (the first one's config: the seed is no part
    of what a policy computes)."""
    config = policies[0].config
    policies = [p.replace(config=config) for p in policies]
    return jax.tree.map(lambda *x: jnp.stack(x), *policies)


def evaluate_seeds(env: Any, policy: Policy, config: Any, n_seeds: int) -> list[EvalResult]:
    """The paper's evaluation (ppo.evaluation) of a seed-stacked policy, one vmapped
    program; every seed gets the same episodes."""
    out = jax.device_get(jax.jit(jax.vmap(make_evaluate(env, config)))(policy))
    return [EvalResult(**{k: np.asarray(v[i]) for k, v in out.items()}) for i in range(n_seeds)]


def seed_row(seed: int, result: EvalResult | None, records: dict[str, Any]) -> dict[str, Any]:
    row: dict[str, Any] = {"seed": seed}
    if result is not None:
        summary = result.summary()
        row.update(
            position_error_mm=summary["position_error_mm"]["mean"],
            orientation_error_deg=summary["orientation_error_deg"]["mean"],
            reached=summary["reached_tolerance"],
            episodes=summary["episodes"],
            collisions=summary["collisions"],
        )
    for mm in ACCURACY_THRESHOLDS_MM:
        row[f"time_to_{mm:g}mm_s"] = records.get(f"{mm:g}mm", {}).get("time_s")
        row[f"env_steps_to_{mm:g}mm"] = records.get(f"{mm:g}mm", {}).get("env_steps")
    return row


def summarise(
    env_name: str, orientation: bool, rows: list[dict[str, Any]], eval_config: dict
) -> dict[str, Any]:
    """The summary across seeds of `_row`s: mean and worst seed per axis, reached
    counts, collisions, median time to each accuracy."""
    across: dict[str, Any] = {}
    evaluated = all("reached" in r for r in rows)
    if evaluated:
        for key in ("position_error_mm", "orientation_error_deg"):
            a = np.array([r[key] for r in rows])  # (seeds, 3)
            across[key] = {
                "mean": a.mean(0).tolist(),
                "worst": a.max(0).tolist(),
                "worst_seed": [rows[j]["seed"] for j in a.argmax(0)],
            }
        reached = [r["reached"] for r in rows]
        across["reached"] = {"min": min(reached), "total": sum(reached),
                             "episodes_per_seed": rows[0]["episodes"]}  # fmt: skip
        collisions = [r["collisions"] for r in rows]
        across["collisions"] = {"mean": float(np.mean(collisions)), "max": max(collisions)}
    for mm in ACCURACY_THRESHOLDS_MM:
        key = f"time_to_{mm:g}mm_s"
        times = [r[key] for r in rows if r[key] is not None]
        median = float(np.median(times)) if times else None
        across[key] = {"median": median, "reached_by": len(times), "seeds": len(rows)}
    return {
        "env_name": env_name,
        "orientation": orientation,
        "seeds": [r["seed"] for r in rows],
        "eval": eval_config,
        "time_to_accuracy_metric": "wall-clock s from command start until the deterministic "
        "mean per-axis error (reach_error_mm with probe_reach_steps > 0, else det_error_mm) "
        "first drops below the threshold; median over "
        "the seeds that reached it. The seeds of one run train together, so each seed's "
        "time includes the others' work: compare env steps, or single runs, for speed",
        "per_seed": rows,
        "across_seeds": across,
        "paper": PAPER_RESULTS.get(env_name),
    }


def markdown(report: dict[str, Any]) -> str:
    """The summary as a markdown table: one row per seed, then mean, worst, paper."""
    rows, across = report["per_seed"], report["across_seeds"]
    evaluated = "position_error_mm" in across
    keys = ("position_error_mm",) + (("orientation_error_deg",) if report["orientation"] else ())
    header = ["seed"]
    if evaluated:
        header += [f"{a} (mm)" for a in AXES]
        header += [f"orientation {a} (deg)" for a in AXES] if len(keys) > 1 else []
        header += ["reached", "collisions"]
    header += [f"to {mm:g} mm (s)" for mm in ACCURACY_THRESHOLDS_MM]
    times = [f"time_to_{mm:g}mm_s" for mm in ACCURACY_THRESHOLDS_MM]
    fmt = lambda x: "-" if x is None else f"{x:.2f}"  # noqa: E731
    lines = []
    for r in rows:
        cells = [str(r["seed"])]
        if evaluated:
            cells += [fmt(v) for k in keys for v in r[k]]
            cells += [f"{r['reached']}/{r['episodes']}", str(r["collisions"])]
        lines.append(cells + [fmt(r[t]) for t in times])
    if evaluated:
        blank = ["", ""]
        mean = [fmt(v) for k in keys for v in across[k]["mean"]]
        lines.append(
            ["mean", *mean, *blank, *(f"median {fmt(across[t]['median'])}" for t in times)]
        )
        worst = [
            f"{v:.2f} (seed {s})"
            for k in keys
            for v, s in zip(across[k]["worst"], across[k]["worst_seed"], strict=True)
        ]
        reached = f"min {across['reached']['min']}/{across['reached']['episodes_per_seed']}"
        lines.append(["worst", *worst, reached, f"max {across['collisions']['max']}", "", ""])
        paper = report["paper"]
        if paper is not None:
            cells = [f"{m:.2f}" for m, _ in paper["position_mm"]]
            if len(keys) > 1:
                cells += [f"{m:.2f}" for m, _ in paper.get("orientation_deg", ((np.nan, 0),) * 3)]
            lines.append(["paper (mean of 10 runs)", *cells, *blank, "", ""])
    else:
        lines.append(["median", *(fmt(across[t]["median"]) for t in times)])
    e = report["eval"]
    title = (
        f"{report['env_name']}, {len(rows)} seeds: the paper's evaluation per seed "
        f"({e['episodes']} episodes, reset noise {e['noise']:g} rad, stop at "
        f"{e['tolerance_mm']:g} mm; mean per axis) and wall-clock time from command start "
        "to a deterministic mean per-axis error below 5 mm and 1 mm"
        if evaluated
        else f"{report['env_name']}, {len(rows)} seeds (not evaluated: --evaluate false; "
        "python -m mara_mjx.evaluate RUN evaluates them); time to 5 mm and 1 mm"
    )
    table = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    table += ["| " + " | ".join(cells) + " |" for cells in lines]
    return "\n".join([title, "", *table])
