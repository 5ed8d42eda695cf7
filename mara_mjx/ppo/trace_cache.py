"""Skip tracing the training program on a warm start: `trainer.run` kept as a `jax.export`.

JAX's persistent compilation cache (mara_mjx.runtime.jax_cache) turns a warm start's XLA compile
into a file read, but the program is still traced and lowered first: Python running the
env, the networks and the PPO update through JAX, about 5 s for an `orient_first` run on
a GPU host, most of what a warm start has left (benchmarks/NOTES.md sections 13 and 29).
Where that cache is on, the train CLI also keeps `trainer.run` as a serialized
`jax.export.Exported` (StableHLO) in `<cache folder>/mara_mjx_export/<key>.bin`:

* cold (no file for the key): `jax.export` traces and lowers `run` (what `jax.jit` would
  do), the file is written (a temporary file renamed into place, so processes sharing
  the folder read a whole file or none), and training runs that exported program;
* warm: the file is read (milliseconds) and training runs it; nothing is traced.

Both paths run the same exported program, so a warm run repeats its cold run bit for
bit, as with the compilation cache alone (tests/test_trace_cache.py also checks it equals
plain `trainer.run` on the CPU). The key is a hash of what the traced program depends on:
the resolved PPO config (its seed aside: the seed enters through the state), the env's
type, task, config, driver settings, MuJoCo model and default params, the batched env, the
state's shapes and dtypes, the updates per call, a teacher's config (imitation), the
versions of python, jax, jaxlib, mujoco, flax, optax and numpy, the backend and device
kind, JAX's numeric settings, and the source of the installed mara_mjx package (an edited
mara_mjx never loads a stale program). Something else that changes the program without
changing any of these (a patched dependency, say) needs the folder deleted or
MARA_MJX_TRACE_CACHE=0.

A file is not trusted by its name: it carries the full key material (the JSON the key
hashes) in its header, and a loaded file whose material differs from the run's (a stale
entry, one copied or renamed from another configuration's, a hash collision) is ignored
with one line on stderr, traced again and replaced; its program's inputs and outputs are
also checked against the state's shapes and dtypes. Only for one device (as
ppo.warmup) and one seed; anything that fails falls back to plain `trainer.run` with one
line on stderr, and a file that cannot be written costs only the next warm start.
"""

from __future__ import annotations

import functools
import hashlib
import json
import os
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp

from mara_mjx.runtime import files

FOLDER = "mara_mjx_export"
FORMAT = 2  # 2: the key material in the header


@functools.lru_cache(maxsize=1)
def source_hash() -> str:
    """sha256 of the mara_mjx package's Python sources (paths and bytes)."""
    root = Path(__file__).resolve().parents[1]
    h = hashlib.sha256()
    for path in sorted(root.rglob("*.py")):
        if "__pycache__" in path.parts:
            continue
        h.update(str(path.relative_to(root)).encode())
        h.update(path.read_bytes())
    return h.hexdigest()


ENV_VAR = "MARA_MJX_TRACE_CACHE"


def cache_folder(enabled: bool | None = None, folder: str | None = None) -> Path | None:
    """`<JAX's compilation-cache folder>/mara_mjx_export` when that cache is on (None:
    JAX's settings), else None; also None when the environment variable
    MARA_MJX_TRACE_CACHE is 0 / false / no / off."""
    if os.environ.get(ENV_VAR, "").strip().lower() in ("0", "false", "no", "off"):
        return None
    enabled = jax.config.jax_enable_compilation_cache if enabled is None else enabled
    folder = jax.config.jax_compilation_cache_dir if folder is None else folder
    return Path(folder) / FOLDER if enabled and folder else None


def cache_key(trainer: Any, state: Any, program: str = "run") -> str:
    """The file name's hash of `key_material`."""
    return _hash_name(key_material(trainer, state, program))


def _hash_name(material: str) -> str:
    return hashlib.sha256(material.encode()).hexdigest()[:32]


def key_material(trainer: Any, state: Any, program: str = "run") -> str:
    """JSON of everything the traced program (`run`, or the reach probe kept apart from
    it: `probe`) depends on (module docstring)."""
    from mara_mjx.runtime import runs  # here, not at the top: runs imports ppo.checkpoint

    leaves, treedef = jax.tree.flatten(state)
    batched = trainer.env
    env = getattr(batched, "env", batched)
    parts = {
        "format": FORMAT,
        "program": [program, getattr(trainer, "probe", None) is not None],  # run: probe in it?
        "versions": runs.versions(),  # packages, backend, devices: as every run records
        "jax_config": [
            str(jax.config.jax_default_matmul_precision),
            bool(jax.config.jax_enable_x64),
            str(jax.config.jax_default_prng_impl),
            bool(jax.config.jax_threefry_partitionable),
            str(jax.config.jax_numpy_dtype_promotion),
            int(getattr(jax.config, "jax_random_seed_offset", 0)),
        ],
        "source": source_hash(),
        **trainer.config.to_dict(),  # "ppo", "policy", "curriculum"; the seed is not compiled in
        "ppo": {k: v for k, v in trainer.config.ppo.to_dict().items() if k != "seed"},
        "env": env_fingerprint(env),
        "batched": [getattr(batched, "reset_strategy", None), getattr(batched, "num_envs", None)],
        "updates_per_call": trainer.updates_per_call,
        "teacher": None
        if getattr(trainer, "teacher", None) is None
        else [
            trainer.teacher.config.to_dict(),  # its deployed rules are traced into the program
            trainer.teacher.action_size,
        ],
        "state": [str(treedef), [(tuple(x.shape), str(x.dtype)) for x in leaves]],
    }
    return json.dumps(parts, sort_keys=True, default=str)


def env_fingerprint(env: Any) -> list:
    """What the traced env step closes over: its type, task, config, driver settings, the
    MuJoCo model (its binary form) and the default params (their bytes). A user's own
    variant (mara_mjx.register) with another task or model gets another key."""
    import mujoco
    import numpy as np

    model = ""
    arm = getattr(env, "arm", None)
    if arm is not None and hasattr(arm, "mj_model"):
        buf = np.empty(mujoco.mj_sizeModel(arm.mj_model), np.uint8)
        mujoco.mj_saveModel(arm.mj_model, None, buf)
        model = hashlib.sha256(buf.tobytes()).hexdigest()
    params = hashlib.sha256()
    for x in jax.tree.leaves(getattr(env, "default_params", None)):
        params.update(np.asarray(x).tobytes())
    return [
        f"{type(env).__module__}.{type(env).__qualname__}",
        repr(getattr(env, "task", None)),
        env.config.to_dict() if hasattr(env, "config") else repr(env),
        [getattr(env, "kinematics", None), getattr(env, "n_substeps", None)],
        model,
        params.hexdigest(),
    ]


def _pack(exported: Any, metric_keys: list[str], material: str = "") -> bytes:
    header = json.dumps({"format": FORMAT, "metrics": metric_keys, "key": material}).encode()
    return len(header).to_bytes(8, "little") + header + bytes(exported.serialize())


def _unpack(blob: bytes, material: str | None = None) -> tuple[Any, list[str]]:
    """(exported, metric keys); ValueError unless the header's format and, unless None,
    key material are this run's (compared before the program is deserialized)."""
    n = int.from_bytes(blob[:8], "little")
    header = json.loads(blob[8 : 8 + n])
    if header.get("format") != FORMAT:
        raise ValueError(f"format {header.get('format')!r}, expected {FORMAT}")
    if material is not None and header.get("key") != material:
        raise ValueError(
            "it was exported for another configuration (its key material differs from this "
            f"run's{_first_difference(header.get('key'), material)}: a stale or renamed entry)"
        )
    return jax.export.deserialize(bytearray(blob[8 + n :])), list(header["metrics"])


def _first_difference(stored: Any, material: str) -> str:
    """', first at <part>' naming the first top-level part of the key that differs."""
    try:
        old, new = json.loads(stored), json.loads(material)
        part = next(k for k in sorted(set(old) | set(new)) if old.get(k) != new.get(k))
    except (TypeError, ValueError, AttributeError, StopIteration):
        return ""
    return f", first at {part!r}"


def exported_run(trainer: Any, state: Any, folder: Path | None) -> tuple[Callable, str]:
    """(run, status): a jitted `run(state, n)` executing `trainer.run`'s exported program
    (module docstring) for states shaped like `state` (arrays or ShapeDtypeStructs), and
    'loaded <file>', 'exported <file>', or why plain `trainer.run` is returned instead
    ('off: ...' or 'failed: ...')."""
    leaves, treedef = jax.tree.flatten(state)
    metric_keys: list[str] = []

    def flat_run(flat: list[jax.Array], n: jax.Array) -> list[jax.Array]:
        new_state, metrics = trainer.run(jax.tree.unflatten(treedef, flat), n)
        if not all(isinstance(v, jax.Array) for v in metrics.values()):
            raise TypeError("metrics must be a flat dict of arrays")
        metric_keys[:] = sorted(metrics)
        return [*jax.tree.leaves(new_state), *(metrics[k] for k in metric_keys)]

    exported, status = _load_or_export(trainer, state, folder, "run", flat_run, metric_keys)
    if exported is None:
        return trainer.run, status
    count = len(leaves)

    def run(state: Any, num_updates: Any) -> tuple[Any, dict[str, jax.Array]]:
        out = exported.call(jax.tree.leaves(state), jnp.asarray(num_updates, jnp.int32))
        metrics = dict(zip(metric_keys, out[count:], strict=True))
        return jax.tree.unflatten(treedef, out[:count]), metrics

    # An exported call's results are committed to the device, so the state is declared
    # on it in and out: one compile for init's state and for run's own (see `traced`).
    donate = () if jax.default_backend() == "cpu" else (0,)  # as make_train's run
    on = device_sharding()
    return jax.jit(run, in_shardings=(on, None), out_shardings=on, donate_argnums=donate), status


def exported_probe(trainer: Any, state: Any, folder: Path | None) -> tuple[Callable, str]:
    """(probe, status): `trainer.probe` (the reach probe kept apart from `run`, make_train's
    probe_apart) as `exported_run` keeps `run`: a warm start traces neither."""
    treedef = jax.tree.structure(state)

    def flat_probe(flat: list[jax.Array], n: jax.Array) -> list[jax.Array]:
        return [trainer.probe(jax.tree.unflatten(treedef, flat), n)]

    exported, status = _load_or_export(trainer, state, folder, "probe", flat_probe, ["reach"])
    if exported is None:
        return trainer.probe, status

    def probe(state: Any, num_updates: Any) -> jax.Array:
        return exported.call(jax.tree.leaves(state), jnp.asarray(num_updates, jnp.int32))[0]

    return jax.jit(probe, in_shardings=(device_sharding(), None)), status


def _load_or_export(
    trainer: Any, state: Any, folder: Path | None, program: str, flat: Callable, names: list
) -> tuple[Any, str]:
    """(the exported `flat(state leaves, n)` read from or written to the cache file of
    `program`, status), or (None, why not). `names` (the outputs after the state's, as
    `flat` fills it when traced) is filled from the file when loaded."""
    if folder is None:
        return None, "off: no compilation cache"
    if trainer.env.mesh is not None or jax.device_count() != 1:
        return None, "off: several devices"
    try:
        leaves = jax.tree.leaves(state)
        material = key_material(trainer, state, program)
        path = Path(folder) / f"{_hash_name(material)}.bin"
        try:
            exported, stored = _unpack(path.read_bytes(), material)
            _check(exported, leaves, stored, program)
            names[:] = stored
            return exported, f"loaded {path}"
        except FileNotFoundError:
            pass
        except Exception as e:  # a damaged or foreign file: export again, replace it
            print(f"mara_mjx: ignoring {path}: {e}", file=sys.stderr)
        n = jax.ShapeDtypeStruct((), jnp.int32)
        shapes = [jax.ShapeDtypeStruct(x.shape, x.dtype) for x in leaves]
        exported = jax.export.export(jax.jit(flat))(shapes, n)
        status = f"exported {path}"
        try:
            files.write_atomic(path, _pack(exported, names, material))
        except OSError as e:  # train with the program all the same
            print(f"mara_mjx: cannot write {path}: {e}", file=sys.stderr)
            status = f"exported (not saved: {e})"
        return exported, status
    except Exception as e:  # never stop training over a cache
        print(f"mara_mjx: {program} program not cached ({e})", file=sys.stderr)
        return None, f"failed: {e}"


def _check(exported: Any, leaves: list, names: list, program: str) -> None:
    """ValueError unless `exported` takes these state leaves and the step count, and
    returns (run) the state's leaves and one output per name, or (probe) one per name."""
    want = [(tuple(x.shape), x.dtype) for x in leaves] + [((), jnp.dtype(jnp.int32))]
    got = [(tuple(a.shape), a.dtype) for a in exported.in_avals]
    if got != want:
        raise ValueError("its inputs do not match the training state's shapes and dtypes")
    if len(exported.out_avals) != (len(leaves) if program == "run" else 0) + len(names):
        raise ValueError(f"its outputs do not match the {program} program's")


def device_sharding() -> jax.sharding.Sharding:
    return jax.sharding.SingleDeviceSharding(jax.devices()[0])
