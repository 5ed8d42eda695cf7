"""The command-line plumbing every CLI shares: flags generated from config dataclasses
(no flag is written by hand), user errors as one line and exit status 2, JAX setup.

Every field of a section gets `--section.field`; it also gets the short `--field` when no
earlier section (in the order given) has a field of that name, so `--gamma` is the PPO
discount and the reward's gamma is `--env.gamma`. The help text is the field's
docstring. Flags default to "not given": only what the user typed becomes an override.
"""

from __future__ import annotations

import argparse
import dataclasses
import re
import types
import typing
from collections.abc import Sequence
from pathlib import Path
from typing import Any, Literal

from mara_mjx.config import field_docs


@dataclasses.dataclass(frozen=True)
class Section:
    """The fields of `cls` (minus `exclude`) as flags under `--{name}.`."""

    name: str
    cls: type
    defaults: Any = None
    """An instance whose values the help shows as defaults (None: the class defaults)."""
    exclude: tuple[str, ...] = ()
    dotted: bool = True
    """Also offer `--{name}.field` (False: only `--field`, e.g. a subcommand's own flags)."""
    brief: tuple[str, ...] | None = None
    """Fields whose flags a short --help shows, with the first sentence of their
    docstring (None: all, in full). The others still parse; a full help lists them."""

    def field_names(self) -> list[str]:
        return [f.name for f in dataclasses.fields(self.cls) if f.name not in self.exclude]


def parse_bool(text: str) -> bool:
    value = text.strip().lower()
    if value in ("true", "1", "yes", "on"):
        return True
    if value in ("false", "0", "no", "off"):
        return False
    raise argparse.ArgumentTypeError(f"expected true or false, got {text!r}")


def _argparse_kwargs(hint: Any) -> dict[str, Any]:
    """type / nargs / choices / metavar for a field's type hint."""
    origin, args = typing.get_origin(hint), typing.get_args(hint)
    if hint is bool:  # `--flag` alone means true
        return {"type": parse_bool, "metavar": "{true,false}", "nargs": "?", "const": True}
    if hint in (int, float, str):
        return {"type": hint}
    if origin is Literal:
        return {"type": type(args[0]), "choices": list(args)}
    if origin is tuple:
        item = {k: v for k, v in _argparse_kwargs(args[0]).items() if k in ("type", "choices")}
        if len(args) == 2 and args[1] is Ellipsis:
            return {**item, "nargs": "+"}
        return {**item, "nargs": len(args)}
    if origin in (typing.Union, types.UnionType):
        for simple in (float, int, str):  # e.g. `jax.Array | float`
            if simple in args:
                return {"type": simple}
    raise TypeError(f"no command-line flag for a field of type {hint!r}")


def add_flags(parser: argparse.ArgumentParser, sections: Sequence[Section]) -> None:
    """Add `--section.field` (and `--field` where unambiguous) for every section field."""
    taken = {s for action in parser._actions for s in action.option_strings}
    for section in sections:
        hints = typing.get_type_hints(section.cls)
        docs = field_docs(section.cls)
        defaults = section.defaults
        if defaults is None:
            defaults = section.cls()
        group = parser.add_argument_group(f"{section.name} options ({section.cls.__name__})")
        for name in section.field_names():
            flags = [f"--{section.name}.{name}"] if section.dotted else []
            if f"--{name}" not in taken:
                flags.insert(0, f"--{name}")
            if not flags:
                raise ValueError(f"flag --{name} of section {section.name} is taken twice")
            taken.update(flags)
            default = getattr(defaults, name)
            shown = " ".join(map(str, default)) if isinstance(default, tuple) else default
            doc = docs.get(name, "").replace("%", "%%")
            if section.brief is not None:
                doc = _first_sentence(doc)
            kwargs = _argparse_kwargs(hints[name])
            if "choices" not in kwargs:
                kwargs.setdefault("metavar", name.upper())
            hidden = section.brief is not None and name not in section.brief
            group.add_argument(
                *flags,
                dest=f"{section.name}.{name}",
                default=argparse.SUPPRESS,
                help=argparse.SUPPRESS if hidden else f"{doc} (default: {shown})",
                **kwargs,
            )


def _first_sentence(doc: str) -> str:
    """A docstring's first sentence (up to a '. ' before a capital letter, so that "..",
    "e.g. " and numbers do not end it), on one line."""
    text = " ".join(doc.split())
    end = re.search(r"\.\s+(?=[A-Z])", text)
    return text if end is None else text[: end.start() + 1]


def add_checkpoint_argument(parser: argparse.ArgumentParser) -> None:
    """The positional CHECKPOINT of the CLIs that load a policy (evaluate, play)."""
    parser.add_argument(
        "checkpoint",
        metavar="CHECKPOINT",
        help="checkpoint file (.npz) or run folder (its newest checkpoint)",
    )


def overrides(namespace: argparse.Namespace, section: str) -> dict[str, Any]:
    """{field: value} of the flags given for `section` (lists become tuples)."""
    prefix = f"{section}."
    return {
        k[len(prefix) :]: tuple(v) if isinstance(v, list) else v
        for k, v in vars(namespace).items()
        if k.startswith(prefix)
    }


def add_deprecated_alias(parser: argparse.ArgumentParser, old: str, new: str, prog: str) -> None:
    """Accept the flag `old` (a store_true flag's earlier spelling) as `new`, with a note
    on stderr; hidden from --help. Every flag is spelled with underscores."""
    import sys

    dest = new.lstrip("-")

    class Deprecated(argparse.Action):
        def __call__(self, parser, namespace, values, option_string=None):
            print(f"{prog}: note: {old} is deprecated; use {new}", file=sys.stderr)
            setattr(namespace, dest, True)

    parser.add_argument(old, nargs=0, action=Deprecated, help=argparse.SUPPRESS)


class UserError(Exception):
    """Bad input from the user: reported as `prog: error: message`, exit status 2."""


def add_cache_argument(parser: argparse.ArgumentParser, default: str = "true") -> None:
    """`--compilation_cache {true,false,PATH}` (mara_mjx.runtime.jax_cache)."""
    parser.add_argument(
        "--compilation_cache",
        metavar="{true,false,PATH}",
        help="JAX's persistent compilation cache: true (the per-user folder "
        "$XDG_CACHE_HOME/mara_mjx/jax or ~/.cache/mara_mjx/jax, or JAX_COMPILATION_CACHE_DIR "
        "if set), false (off), or a folder; the environment variable "
        f"MARA_MJX_COMPILATION_CACHE takes the same values (default: {default})",
    )


def configure_jax(
    compilation_cache: str | bool | None = None, real_driver: bool = True
) -> Path | None:
    """Full-precision float32 matmuls, bitwise reproducible GPU programs and the persistent
    compilation cache, before anything compiles.

    * On GPUs JAX's default matmul precision may be TF32, which silently degrades the MJX
      kinematics and training. JAX_DEFAULT_MATMUL_PRECISION, if set, wins.
    * Reproducibility: PPO amplifies last-bit differences into different policies (the
      same seed gave 116 mm and 4.9 mm final errors on an H200, benchmarks/NOTES.md
      section 5). Measured on an H100 (NOTES section 14): a compiled train-driver program
      repeats itself bit for bit; what differed between processes was the kernels that
      XLA's autotuner picked at compile time. So `--xla_gpu_autotune_level=0` (the same
      kernels in every compile) makes runs reproducible at 96% of the fastest speed,
      where `--xla_gpu_deterministic_ops=true` costs half of it (it also serialises
      scatters XLA cannot prove free of races: MJX kinematics'). MJX's dynamics
      (`mjx.step`, which a real-driver run may use: real_contacts='physical' or
      kinematics='mjx'; the default plain-jnp dynamics have none) do sum floats with
      scatter-adds, which GPUs run with atomics: with `real_driver` (the callers' worst
      case when the driver is not known yet), `--xla_gpu_deterministic_ops=true` is added
      as before. Nothing is added when XLA_FLAGS already names either flag.
    * JAX's persistent compilation cache, on unless `compilation_cache` (the
      `--compilation_cache` flag; None: not given) or MARA_MJX_COMPILATION_CACHE turns it
      off (`mara_mjx.runtime.jax_cache`). Returns the cache folder in use, or None.
    """
    import os

    import jax

    from mara_mjx.runtime import jax_cache

    folder = jax_cache.configure(compilation_cache)

    if "JAX_DEFAULT_MATMUL_PRECISION" not in os.environ:
        jax.config.update("jax_default_matmul_precision", "highest")
    flags = os.environ.get("XLA_FLAGS", "")
    if "xla_gpu_deterministic_ops" not in flags and "xla_gpu_autotune_level" not in flags:
        os.environ["XLA_FLAGS"] = (flags + " " + reproducible_gpu_flags(real_driver)).strip()
    return folder


def reproducible_gpu_flags(real_driver: bool) -> str:
    """The XLA flags `configure_jax` adds for bitwise reproducible GPU runs."""
    if real_driver:
        return "--xla_gpu_deterministic_ops=true"
    return "--xla_gpu_autotune_level=0"


def check_rate_limit(evaluation: Any, driver: str) -> None:
    """UserError when EvalConfig.rate_limit is asked for an env that is not on the real
    driver (the servo speed it limits the policy's steps to)."""
    if getattr(evaluation, "rate_limit", False) and driver != "real":
        raise UserError(
            f"--rate_limit true limits the policy's steps to the real driver's servo speed, "
            f"but the env's driver is {driver!r}; add --driver real, or drop --rate_limit"
        )


def uses_real_driver(namespace: argparse.Namespace, checkpoint: str | None = None) -> bool:
    """Whether a CLI run may step the real driver: its `--driver` flag, else the driver of
    `checkpoint`'s env (a file or run folder; True when it cannot be read: the error is
    reported later, where the checkpoint is loaded for real)."""
    given = overrides(namespace, "env").get("driver")
    if given is not None:
        return given == "real"
    if checkpoint is None:
        return False
    import json

    from mara_mjx.ppo import checkpoint as ckpt

    try:
        path = Path(checkpoint)
        if (path / "seeds.json").is_file():  # a multi-seed run: its seeds share the env
            path = path / f"seed_{int(json.loads((path / 'seeds.json').read_text())['seeds'][0])}"
        _, meta = ckpt.load_checkpoint(ckpt.find_checkpoint(path))
        return meta["env_config"].get("driver", "train") == "real"
    except Exception:  # unreadable: the careful choice
        return True


def run_cli(main: typing.Callable[[list[str] | None], int], prog: str, argv=None) -> int:
    """Run a CLI main; user errors (UserError, CheckpointError) print one line on stderr
    and return 2 instead of a traceback."""
    import sys

    from mara_mjx.ppo.checkpoint import CheckpointError

    try:
        return main(argv)
    except (UserError, CheckpointError) as e:
        print(f"{prog}: error: {e}", file=sys.stderr)
        return 2
    except (MemoryError, RuntimeError) as e:  # JaxRuntimeError is a RuntimeError
        if not is_out_of_memory(e):
            raise
        what = (str(e).strip().splitlines() or [type(e).__name__])[0]
        print(
            f"{prog}: error: out of memory: {what} (fewer --num_envs, --num_steps or "
            "--episodes need less)",
            file=sys.stderr,
        )
        return 1


def is_out_of_memory(error: BaseException) -> bool:
    """Python's MemoryError, or XLA's RESOURCE_EXHAUSTED (host or device memory)."""
    return isinstance(error, MemoryError) or "RESOURCE_EXHAUSTED" in str(error)[:200]


def env_overrides(namespace: argparse.Namespace) -> dict[str, Any]:
    """The EnvConfig overrides of the flags: the `env` section's, plus the `randomization`
    section's fields as `randomization={field: value}` (applied on top of the env's own
    ranges by `EnvConfig.replace`)."""
    flags = overrides(namespace, "env")
    randomization = overrides(namespace, "randomization")
    if randomization:
        flags["randomization"] = randomization
    return flags
