"""The tta study's output (`mara_mjx.bench.tta`): the table's columns, the notes under it
(medians, the bit checks, the PPO's speed by XLA's GPU ops and with several seeds, the
roofline) and the figure."""

from __future__ import annotations

from typing import Any

from mara_mjx.viz.plots import finish_figure

CLI_DEFAULT = "cli default"
"""The xla_ops label of a run with the train CLI's own choice of XLA's GPU ops."""


def _cell(x: float | None, digits: int = 1) -> str:
    return "" if x is None else f"{x:.{digits}f}"


def mega(x: float | None) -> str:
    return "" if x is None else f"{x / 1e6:.3g} M"


def secs(x: float | None) -> str:
    return "not reached" if x is None else f"{x:.1f} s"


def _int(x: int | None) -> str:
    return "" if x is None else f"{x:,}"


def _notes(records: list[dict[str, Any]]) -> list[str]:
    lines = [
        "Times in seconds from command start (this process launching `python -m "
        "mara_mjx.train`; the CLI's own clock starts with its process, the offset is in "
        "the JSON), compile and start-up included; granularity one jitted call. env "
        "steps/s: median of the progress rows after the first (compiling) call. Full "
        "commands in the JSON (`command`)."
    ]
    medians = {r["cache"]: r for r in records if r["kind"] == "median"}
    if medians:
        parts = [
            f"{phase} 5 mm at {secs(m['to_5mm_s'])}, 1 mm at {secs(m['to_1mm_s'])}, "
            f"whole command {secs(m['command_s'])}"
            for phase, m in medians.items()
        ]
        seeds = ", ".join(str(s) for s in medians["cold"]["seeds"])
        lines += ["", f"Median of seeds {seeds}: " + "; ".join(parts) + "."]
        tta = [r for r in records if r["part"] == "tta"]
        same = [r["same_bits_as_cold"] for r in tta if "same_bits_as_cold" in r]
        lines += [f"Warm runs bit-identical to their cold run: {sum(same)} of {len(same)}."]
    rates = {r["xla_ops"]: r["env_steps_per_s"] for r in records if r["part"] == "xla_ops"}
    if "warm" in medians:
        rates[CLI_DEFAULT] = medians["warm"]["env_steps_per_s"]
    if rates:
        text = ", ".join(f"{k} {mega(v)}" for k, v in rates.items())
        lines += [
            "",
            f"PPO env steps/s by XLA's GPU ops: {text} (the CLI default: warm median of the "
            "tta runs; `--xla_gpu_deterministic_ops` only acts on GPUs).",
        ]
    groups = [r for r in records if r["part"] == "seeds" and r["cache"] == "warm"]
    if groups:
        text = "; ".join(
            f"{r['num_seeds']} seeds {mega(r['env_steps_per_s'])} env steps/s, bitwise as cold: "
            f"{'yes' if r['same_bits_as_cold'] else 'NO'}"
            for r in groups
        )
        lines += [
            "",
            f"Several seeds in one program (`--seeds N`, warm; env steps/s summed over the "
            f"seeds): {text}.",
        ]
    for r in (r for r in records if r["kind"] == "limit"):
        ppo = r["ppo_fraction_of_bound"]
        lines += [
            "",
            f"Roofline (`limit` study, {r['task']} train driver, {r['num_envs']:,} envs): one "
            f"env step {r['flops_per_env_step']:,.0f} FLOP and {r['bytes_per_env_step']:,.0f} "
            "bytes (XLA's cost analysis); ceilings measured here: float32 matmul "
            f"{r['f32_matmul_flops_per_s'] / 1e12:.2f} TFLOP/s, memory "
            f"{r['bytes_per_s'] / 1e9:.1f} GB/s; bound {mega(r['bound_env_steps_per_s'])} "
            f"env steps/s ({r['limited_by']}); the env step alone "
            f"{mega(r['env_steps_per_s'])} ({100 * r['fraction_of_bound']:.2f}% of it), "
            f"the PPO {mega(r['ppo_env_steps_per_s'])}"
            + (f" ({100 * ppo:.2f}% of it)." if ppo else "."),
        ]
    return lines + _peer_notes([r for r in records if r["kind"] == "peer"])


def _peer_notes(peers: list[dict[str, Any]]) -> list[str]:
    """The peers part: C MuJoCo against the MJX env step, brax's PPO against ours."""
    lines = []
    for r in (r for r in peers if "mjx_over_c" in r):
        ratio = r["mjx_over_c"]
        lines += [
            "",
            f"C peer ({r['impl']}, the train driver's work on {r['num_envs']:,} envs): "
            f"{mega(r['env_steps_per_s'])} env steps/s; MJX's env step (limit part) "
            f"{mega(r['mjx_env_steps_per_s'])}" + (f", {ratio:.3g}x C's." if ratio else "."),
        ]
    ppo = [r for r in peers if "curve" in r]  # the brax study's two runs
    if ppo:
        text = "; ".join(
            f"{r['impl']} {mega(r['env_steps_per_s'])} env steps/s, settled error below 5 mm "
            f"at {secs(r.get('settled_to_5mm_s'))} and 1 mm at "
            f"{secs(r.get('settled_to_1mm_s'))} of training"
            for r in ppo
        )
        lines += [
            "",
            f"PPO peers (`brax` study, preset default, {_int(ppo[0]['env_steps'])} env steps "
            f"each, compile excluded): {text}.",
        ]
    return lines


def plot_tta(records: list[dict[str, Any]], title: str, path: Any) -> None:
    """Left: time to 5 mm, 1 mm and the whole command, cold and warm (bars: median over
    seeds; dots: seeds). Right: PPO env steps/s by XLA's GPU-op choice, and of the seeds
    part's warm runs (summed over their seeds)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (left, right) = plt.subplots(1, 2, figsize=(10, 4.5), width_ratios=(3, 2))
    keys = (("to_5mm_s", "5 mm"), ("to_1mm_s", "1 mm"), ("command_s", "command"))
    for j, phase in enumerate(("cold", "warm")):
        m = next((r for r in records if r["kind"] == "median" and r["cache"] == phase), None)
        runs = [r for r in records if r["kind"] == "run" and r["part"] == "tta"]
        runs = [r for r in runs if r["cache"] == phase]
        xs = [i + 0.38 * (j - 0.5) for i in range(len(keys))]
        heights = [(m or {}).get(k) or 0.0 for k, _ in keys]
        left.bar(xs, heights, width=0.36, color=f"C{j}", alpha=0.7, label=f"{phase} (median)")
        for x, h, (k, _) in zip(xs, heights, keys, strict=True):
            ys = [r[k] for r in runs if r[k] is not None]
            left.plot([x] * len(ys), ys, "k.", markersize=5)
            if m is not None and not h:
                left.text(x, 0, "not\nreached", ha="center", va="bottom", fontsize=7)
    left.set_xticks(range(len(keys)), [label for _, label in keys])
    left.set_ylabel("seconds from command start")
    left.set_title("time to accuracy (dots: seeds)")
    left.grid(True, axis="y", alpha=0.3)
    left.legend(fontsize=8)
    rates = [(r["xla_ops"], r["env_steps_per_s"]) for r in records if r["part"] == "xla_ops"]
    warm = [r for r in records if r["kind"] == "median" and r["cache"] == "warm"]
    rates += [(CLI_DEFAULT, r["env_steps_per_s"]) for r in warm]
    seeds = [r for r in records if r["part"] == "seeds" and r["cache"] == "warm"]
    rates += [(f"{r['num_seeds']} seeds, warm", r["env_steps_per_s"]) for r in seeds]
    rates = [(k, v) for k, v in rates if v]
    for i, (k, v) in enumerate(rates):
        right.bar(i, v, color=f"C{i + 2}", label=k)
    right.set_xticks(range(len(rates)), [k.replace(" ", "\n") for k, _ in rates], fontsize=7)
    fig.suptitle(title)
    xlabel = "XLA GPU ops; seeds in one program"
    finish_figure(fig, right, path, "PPO speed", xlabel, "env steps / s")


def _seed_cell(r: dict[str, Any]) -> str:
    if "seed" not in r:  # a median: its seeds
        return ",".join(map(str, r["seeds"]))
    n = r.get("num_seeds", 1)
    return str(r["seed"]) if n == 1 else f"{r['seed']}-{r['seed'] + n - 1}"


TTA_TABLE: dict[str, Any] = {
    "title": "tta study: time to accuracy from command start (the train CLI as users run it)",
    "columns": [
        ("part", lambda r: r["part"] if r["kind"] == "run" else "median"),
        ("seed", _seed_cell),
        ("cache", lambda r: r["cache"]),
        ("XLA GPU ops", lambda r: r["xla_ops"]),
        ("5 mm at (s)", lambda r: _cell(r["to_5mm_s"])),
        ("1 mm at (s)", lambda r: _cell(r["to_1mm_s"])),
        ("env steps to 1 mm", lambda r: _int(r["to_1mm_env_steps"])),
        ("first call done (s)", lambda r: _cell(r["first_call_s"])),
        ("command (s)", lambda r: _cell(r["command_s"])),
        ("env steps/s", lambda r: mega(r["env_steps_per_s"])),
        ("final det error (mm)", lambda r: _cell(r.get("final_det_error_mm"), 3)),
        ("state hash", lambda r: r.get("state_hash") or ""),
        ("training hash", lambda r: r.get("training_hash") or ""),
    ],
    "rows": lambda records: [r for r in records if r["kind"] in ("run", "median")],
    "notes": _notes,
    "plot": plot_tta,
}
