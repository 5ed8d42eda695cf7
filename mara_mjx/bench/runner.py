"""The shared runner of the benchmark studies: configs, flags, output, provenance.

Every study (`mara_mjx.bench.<study>`) declares a `Study`: its config dataclass (a
`BenchConfig` subclass: one documented field per flag, validated in `__post_init__`,
with `QUICK` overrides for a CPU smoke run), its `run(config) -> records` and its table
spec. `main` (behind `python -m mara_mjx.benchmark STUDY`) generates each study's flags
from its config (`mara_mjx.cli.common`), configures JAX, runs the study and writes
`<study>.json` (settings, versions, device, the command, the records), `<study>.md` (the
table) and `<study>.png` into `--out`. Those three are checked before the study runs: an
existing file is replaced only if it is that study's earlier output (and a full run's
never by a --quick one), or with --overwrite; never a checkpoint or a run folder's file
(`mara_mjx.runtime.outputs.check_output`).
"""

from __future__ import annotations

import argparse
import dataclasses
import importlib
import json
import platform
import shlex
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, ClassVar, NamedTuple

import jax
import numpy as np

from mara_mjx.cli.common import UserError, configure_jax
from mara_mjx.config import ConfigMixin, check_int
from mara_mjx.runtime import files, outputs, runs
from mara_mjx.viz.plots import finish_figure

TASKS = ("MARA", "MARAOrient", "MARACollision", "MARACollisionOrient")


@dataclasses.dataclass(frozen=True)
class BenchConfig(ConfigMixin):
    """What every study shares."""

    tasks: tuple[str, ...] = TASKS
    """Registered envs to measure (peers and scaling use the first)."""
    out: str = "runs/benchmarks"
    """Results folder, relative to the working directory (the recorded results are in
    benchmarks/results/; a --quick run never replaces a full one)."""
    quick: bool = False
    """Tiny sizes: a CPU smoke run (the study's QUICK settings; flags given win)."""
    deterministic: bool = False
    """Deterministic XLA GPU ops (reproducible, about half the PPO speed); off by default,
    for speed; matmuls are float32 at HIGHEST precision either way."""
    overwrite: bool = False
    """Replace <study>.json, .md and .png in --out even if they are not this study's
    earlier output (never a checkpoint or a run folder's own file)."""

    QUICK: ClassVar[dict[str, Any]] = {}
    POSITIVE: ClassVar[tuple[str, ...]] = ()
    """Int fields (or tuples of ints) that must be >= 1."""
    CHOICES: ClassVar[dict[str, tuple[str, ...]]] = {}
    """Tuple fields -> the values allowed in them (and not empty)."""
    SHARES_DEVICE: ClassVar[bool] = False
    """The study starts other JAX processes (users' commands) while its own backend is
    up: its process leaves JAX's GPU memory preallocation off, so that they get the
    memory (`configure`)."""

    def __post_init__(self):
        from mara_mjx.envs import registered

        unknown = sorted(set(self.tasks) - set(registered()))
        if unknown or not self.tasks:
            raise ValueError(f"unknown task(s) {unknown}; registered: {list(registered())}")
        for name in self.POSITIVE:
            value = getattr(self, name)
            for v in value if isinstance(value, tuple) else (value,):
                check_int(name, v, minimum=1)
        for name, valid in self.CHOICES.items():
            values = getattr(self, name)
            if not values or any(v not in valid for v in values):
                raise ValueError(
                    f"{name}={list(values)} is not valid; choose among {', '.join(valid)}"
                )


class Study(NamedTuple):
    """One benchmark study."""

    name: str
    config: type[BenchConfig]
    run: Callable[[Any], list[dict[str, Any]]]
    table: dict[str, Any]
    """Title, markdown columns (header, record -> text), optional rows (records -> the
    records shown as table rows; default all), optional notes (records -> lines under
    the table), and either plot(records, title, path) or, for the default plot of env
    steps/s vs env count, series (record -> label) and style (record -> line style)."""
    summary: str


# name -> "module:attribute" of its Study; imported on use (brax only for the brax study)
STUDIES = {
    "env": "mara_mjx.bench.env:STUDY",
    "peers": "mara_mjx.bench.peers:STUDY",
    "train": "mara_mjx.bench.ppo:TRAIN",
    "brax": "mara_mjx.bench.ppo:BRAX",
    "limit": "mara_mjx.bench.limit:STUDY",
    "scaling": "mara_mjx.bench.scaling:STUDY",
    "tta": "mara_mjx.bench.tta:STUDY",
    "robustness": "mara_mjx.bench.robustness:STUDY",
}


def command_line(argv: Sequence[str]) -> str:
    """The study's command as a shell reads it back: an argument with spaces (a recipe
    with flags, `--recipes "cli --randomize"`) quoted, so a copy of it runs the same study."""
    return shlex.join(["python", "-m", "mara_mjx.benchmark", *argv])


def load_study(name: str) -> Study:
    module, attribute = STUDIES[name].split(":")
    return getattr(importlib.import_module(module), attribute)


def versions() -> dict[str, str]:
    import flax
    import mujoco
    import optax

    import mara_mjx

    return {
        "python": platform.python_version(),
        "jax": jax.__version__,
        "jaxlib": jax.lib.__version__ if hasattr(jax.lib, "__version__") else "",
        "mujoco": mujoco.__version__,
        "flax": flax.__version__,
        "optax": optax.__version__,
        "mara_mjx": mara_mjx.__version__,
    }


def device_info() -> dict[str, Any]:
    dev = jax.devices()[0]
    return {
        "platform": dev.platform,
        "device_kind": dev.device_kind,
        "device_count": jax.device_count(),
        "host": platform.node(),
    }


def peak_memory() -> int | None:
    stats = jax.devices()[0].memory_stats() or {}
    return stats.get("peak_bytes_in_use")


def fmt_m(x: float | None) -> str:
    """Millions with two decimals, or '' for None."""
    return "" if x is None else f"{x / 1e6:.2f} M"


def write_results(
    study: str, records: list[dict[str, Any]], out: Path, meta: dict[str, Any]
) -> list[Path]:
    """Write `<study>.json` (meta + records; NaN and infinities as null, so strict JSON),
    `<study>.md` (table and notes) and `<study>.png` (the study's plot; by default env
    steps/s vs environments, log-log) into `out`. Returns the written paths."""
    spec = load_study(study).table
    out.mkdir(parents=True, exist_ok=True)
    paths = [out / f"{study}.{ext}" for ext in ("json", "md", "png")]
    data = _json_safe({**meta, "records": records})
    files.write_atomic(paths[0], json.dumps(data, indent=2, allow_nan=False))
    headers = [h for h, _ in spec["columns"]]
    lines = [
        f"# {spec['title']}",
        "",
        f"Device: {meta['device']['device_kind']} ({meta['device']['platform']}); "
        f"versions: jax {meta['versions']['jax']}, mujoco {meta['versions']['mujoco']}.",
        "",
        f"Command: `{meta['command']}`",
        "",
        "| " + " | ".join(headers) + " |",
        "|" + "|".join("---" for _ in headers) + "|",
    ]
    for r in spec.get("rows", list)(records):
        lines.append("| " + " | ".join(f(r) for _, f in spec["columns"]) + " |")
    if "notes" in spec:
        lines += ["", *spec["notes"](records)]
    files.write_atomic(paths[1], "\n".join(lines) + "\n")
    title = f"{study}: {meta['device']['device_kind']}"
    if "plot" in spec:
        spec["plot"](records, title, paths[2])
    else:
        plot_throughput(records, spec, title, paths[2])
    return paths


def _json_safe(x: Any) -> Any:
    """x with non-finite floats replaced by None (recursively through dicts and lists)."""
    if isinstance(x, dict):
        return {k: _json_safe(v) for k, v in x.items()}
    if isinstance(x, list | tuple):
        return [_json_safe(v) for v in x]
    if isinstance(x, float | np.floating):
        return float(x) if np.isfinite(x) else None
    if isinstance(x, np.integer):
        return int(x)
    return x


def plot_throughput(
    records: list[dict[str, Any]], spec: dict[str, Any], title: str, path: Path
) -> None:
    """env steps/s vs environments (log-log), one line per spec["series"] label."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4.5))
    for label in sorted({spec["series"](r) for r in records}):
        rs = [r for r in records if spec["series"](r) == label]
        ax.plot(
            [r["num_envs"] for r in rs],
            [r["env_steps_per_s"] for r in rs],
            marker="o",
            linestyle=spec["style"](rs[0]),
            label=label,
        )
    ax.set_xscale("log")
    ax.set_yscale("log")
    finish_figure(fig, ax, path, title, "environments", "env steps / s")


# The variables `configure` may change, as they were before it did: the environment of a
# study's subprocesses, which run users' commands (mara_mjx.bench.train_command.child_env).
USER_ENV: dict[str, str | None] = {}


def configure(
    deterministic: bool, compilation_cache: str | None = None, preallocate: bool = True
) -> dict[str, str]:
    """Before the backend starts: float32 matmuls at HIGHEST precision (unless
    JAX_DEFAULT_MATMUL_PRECISION says otherwise) and, unless `deterministic` or XLA_FLAGS
    says otherwise, XLA's faster non-deterministic GPU ops (the training CLI's default is
    the reverse; `configure_jax` is shared). The persistent compilation cache is off
    unless `compilation_cache` (the flag), MARA_MJX_COMPILATION_CACHE or
    JAX_COMPILATION_CACHE_DIR turns it on: the studies report compile (cold start)
    times. Without `preallocate`, XLA_PYTHON_CLIENT_PREALLOCATE=false (unless set).
    Returns what is in effect, for the JSON; the variables' earlier values go to
    `USER_ENV`."""
    import os

    from mara_mjx.runtime import jax_cache

    for name in ("XLA_FLAGS", "XLA_PYTHON_CLIENT_PREALLOCATE"):
        USER_ENV[name] = os.environ.get(name)
    if not preallocate and "XLA_PYTHON_CLIENT_PREALLOCATE" not in os.environ:
        os.environ["XLA_PYTHON_CLIENT_PREALLOCATE"] = "false"
    flags = os.environ.get("XLA_FLAGS", "")
    if not deterministic and "xla_gpu_deterministic_ops" not in flags:
        os.environ["XLA_FLAGS"] = (flags + " --xla_gpu_deterministic_ops=false").strip()
    user_set = os.environ.get(jax_cache.ENV_VAR) or os.environ.get("JAX_COMPILATION_CACHE_DIR")
    if compilation_cache is None and not user_set:
        compilation_cache = "false"
    folder = configure_jax(compilation_cache)
    return {
        "XLA_FLAGS": os.environ.get("XLA_FLAGS", ""),
        "XLA_PYTHON_CLIENT_PREALLOCATE": os.environ.get("XLA_PYTHON_CLIENT_PREALLOCATE", ""),
        "matmul_precision": str(jax.config.jax_default_matmul_precision),
        "compilation_cache": str(folder),
    }


def recorded_quick(path: Path) -> bool:
    """True if `path` (a study's JSON) does not exist or was itself a --quick run."""
    if not path.exists():
        return True
    try:
        return bool(json.loads(path.read_text()).get("config", {}).get("quick"))
    except (OSError, ValueError, AttributeError):
        return False


def build_parser(description: str) -> argparse.ArgumentParser:
    """`STUDY [flags]`: one subcommand per study, flags generated from its config."""
    from mara_mjx.cli.common import Section, add_cache_argument, add_flags

    parser = argparse.ArgumentParser(
        prog="python -m mara_mjx.benchmark",
        description=description,
        formatter_class=argparse.RawDescriptionHelpFormatter,
        allow_abbrev=False,
    )
    sub = parser.add_subparsers(dest="study", required=True, metavar="STUDY")
    for name in STUDIES:
        study = load_study(name)
        p = sub.add_parser(name, help=study.summary, description=study.summary, allow_abbrev=False)
        add_flags(p, [Section(name, study.config, dotted=False)])
        add_cache_argument(p, default="false: the studies time compiles")
    return parser


def resolve(parser: argparse.ArgumentParser, argv: Sequence[str] | None) -> BenchConfig:
    """The study's config: defaults, then QUICK if --quick, then the flags given; the
    output folder checked. Bad input exits 2 with one line (argparse's error)."""
    from mara_mjx.cli.common import overrides

    args = parser.parse_args(argv)
    study = load_study(args.study)
    given = overrides(args, args.study)
    try:
        config = study.config()
        if given.get("quick"):
            config = config.replace(quick=True, **study.config.QUICK)
        config = config.replace(**given)
    except (TypeError, ValueError) as e:
        parser.error(f"{args.study}: {e}")
    out = Path(config.out)
    try:
        files.check_writable(out)  # several studies may check one folder at once
    except OSError as e:
        parser.error(f"output folder {out} is not writable: {e}")
    if config.quick and not recorded_quick(out / f"{args.study}.json"):
        parser.error(
            f"{out / (args.study + '.json')} holds a full (not --quick) run; a --quick "
            "smoke run does not replace it: choose another --out"
        )
    ours = recorded_study(out / f"{args.study}.json", args.study)
    for path in [out / f"{args.study}.{ext}" for ext in ("json", "md", "png")]:
        try:
            outputs.check_output(path, f"{args.study} output", lambda _: ours, config.overwrite)
        except UserError as e:
            parser.error(str(e))
    return config


def recorded_study(path: Path, study: str) -> bool:
    """True if `path` is the JSON record of an earlier run of `study` (write_results)."""
    record = outputs.read_json(path)
    return isinstance(record, dict) and record.get("study") == study and "records" in record


def main(argv: Sequence[str] | None = None, description: str = "") -> None:
    parser = build_parser(description)
    config = resolve(parser, argv)
    name = next(n for n in STUDIES if load_study(n).config is type(config))
    study = load_study(name)
    cache = parser.parse_args(argv).compilation_cache
    settings = configure(config.deterministic, cache, preallocate=not config.SHARES_DEVICE)
    if hasattr(config, "check_devices"):  # needs the backend, so after configure
        try:
            config.check_devices()
        except ValueError as e:
            parser.error(f"{name}: {e}")
    meta = {
        "study": name,
        "command": command_line(sys.argv[1:] if argv is None else argv),
        "versions": versions(),
        "git_commit": runs.git_commit(),
        "device": device_info(),
        "settings": settings,
        "config": config.to_dict(),
        "date": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
    }
    records = study.run(config)
    try:
        paths = write_results(name, records, Path(config.out), meta)
    except files.WriteError as e:  # e.g. a full disk: one line, as bad input is
        parser.exit(2, f"{parser.prog}: error: cannot write {e.filename!r}: {e.strerror}\n")
    print(paths[1].read_text())
    print("wrote " + ", ".join(str(p) for p in paths))
