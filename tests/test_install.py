"""A plain (non-editable) install, used from another folder, as a new user would.

`pip install --no-deps --no-build-isolation --target SITE COPY` of a copy of the tracked
sources, then subprocesses with `PYTHONPATH=SITE` and the working directory elsewhere:
the MJCF must come from the installed package data, every module must import, and
nothing may be written into the installed package folder.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]

CHECK = """
import importlib, pathlib, pkgutil, sys
import mara_mjx
from mara_mjx.envs.arm import XML_PATH
site = pathlib.Path(sys.argv[1]).resolve()
assert pathlib.Path(mara_mjx.__file__).resolve().is_relative_to(site), mara_mjx.__file__
assert XML_PATH.resolve().is_relative_to(site), XML_PATH
for info in pkgutil.walk_packages(mara_mjx.__path__, "mara_mjx."):
    importlib.import_module(info.name)
env = mara_mjx.make("MARA", check_target=False)
print("OK", env.observation_size, XML_PATH)
"""


def _can_build_wheels() -> bool:
    """setuptools >= 70.1 builds wheels itself; older ones need the `wheel` package."""
    import importlib.util

    import setuptools

    major, minor = (int(x) for x in setuptools.__version__.split(".")[:2])
    return (major, minor) >= (70, 1) or importlib.util.find_spec("wheel") is not None


# Only what a plain `pip install .` brings: every distribution outside the installed
# mara_mjx's declared dependencies (their closure, extras and markers followed, without
# mara_mjx's own extras) cannot be imported, as on a machine where pip installed nothing
# else. Then the train CLI's trace cache serializes a program (jax.export; it needs
# flatbuffers, which jax leaves optional: without it every train run printed "training
# program failed: Please install 'flatbuffers' ...").
PLAIN_DEPS_ONLY = """
import importlib.abc, importlib.metadata as md, pathlib, sys
from packaging.requirements import Requirement
from packaging.utils import canonicalize_name as canon
site = pathlib.Path(sys.argv[1]).resolve()
ours = next(
    d for d in md.distributions(path=[str(site)]) if canon(d.metadata["Name"]) == "mara-mjx"
)
allowed, todo = set(), [(r, "") for r in ours.requires or []]
while todo:
    text, extra = todo.pop()
    req = Requirement(text)
    if req.marker is not None and not req.marker.evaluate({"extra": extra}):
        continue
    name = canon(req.name)
    first = name not in allowed
    allowed.add(name)
    try:
        requires = md.distribution(req.name).requires or []
    except md.PackageNotFoundError:
        continue
    todo += [(r, e) for r in requires for e in ([""] if first else []) + sorted(req.extras)]
owners = md.packages_distributions()
blocked = set()

class PlainInstallOnly(importlib.abc.MetaPathFinder):
    def find_spec(self, fullname, path=None, target=None):
        top = fullname.partition(".")[0]
        dists = {canon(d) for d in owners.get(top, [])}
        if top == "mara_mjx" or not dists or dists & allowed:
            return None
        blocked.add(top)
        raise ModuleNotFoundError(f"No module named {top!r}", name=top)

sys.meta_path.insert(0, PlainInstallOnly())
import jax, jax.numpy as jnp
import mara_mjx, mara_mjx.train
from mara_mjx.ppo import trace_cache
exported = jax.export.export(jax.jit(lambda x: 2 * x))(jax.ShapeDtypeStruct((3,), jnp.float32))
loaded, _ = trace_cache._unpack(trace_cache._pack(exported, []))
assert loaded.call(jnp.ones(3, jnp.float32)).tolist() == [2.0, 2.0, 2.0]
mara_mjx.make("MARA", check_target=False)
print("OK; not importable in a plain install:", sorted(blocked))
"""

RESOLVE_ENV_STUDY = (
    "from mara_mjx.bench import runner; runner.resolve(runner.build_parser(''), ['env'])"
)


@pytest.fixture(scope="module")
def site(tmp_path_factory) -> Path:
    if not _can_build_wheels():
        pytest.skip("no offline wheel build: pip install 'setuptools>=70.1' or wheel ([dev])")
    src = tmp_path_factory.mktemp("src")
    files = subprocess.run(
        ["git", "ls-files", "pyproject.toml", "README.md", "mara_mjx", "assets"],
        cwd=REPO,
        capture_output=True,
        text=True,
        check=True,
    ).stdout.split()
    for name in files:
        (src / name).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(REPO / name, src / name)
    target = tmp_path_factory.mktemp("site")
    subprocess.run(
        [sys.executable, "-m", "pip", "install", "--quiet", "--no-deps", "--no-build-isolation"]
        + ["--no-index", "--target", str(target), str(src)],
        check=True,
        capture_output=True,
        text=True,
    )
    return target


def _snapshot(folder: Path) -> set[Path]:
    return {p.relative_to(folder) for p in folder.rglob("*") if "__pycache__" not in p.parts}


def test_plain_install_finds_its_model_and_imports_everything(site, tmp_path):
    assert (site / "mara_mjx" / "assets" / "mara.xml").is_file()
    env = {**os.environ, "PYTHONPATH": str(site), "JAX_PLATFORMS": "cpu"}
    before = _snapshot(site / "mara_mjx")
    out = subprocess.run(
        [sys.executable, "-c", CHECK, str(site)],
        cwd=tmp_path,
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert out.returncode == 0, out.stderr[-3000:]
    assert out.stdout.startswith("OK 12 ")
    # a benchmark's default output folder is under the working directory, not the package
    # (parse_args creates it and checks it is writable; the studies are test_benchmark's)
    bench = subprocess.run(
        [sys.executable, "-c", RESOLVE_ENV_STUDY],
        cwd=tmp_path,
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert bench.returncode == 0, bench.stderr[-3000:]
    assert _snapshot(site / "mara_mjx") == before
    assert not (site / "benchmarks").exists()
    assert (tmp_path / "runs" / "benchmarks").is_dir()


def test_plain_install_dependencies_cover_the_train_cli(site, tmp_path):
    """What the train CLI imports, its trace cache's serialization included, comes with a
    plain install's dependencies (fails without flatbuffers in pyproject.toml's)."""
    env = {**os.environ, "PYTHONPATH": str(site), "JAX_PLATFORMS": "cpu"}
    out = subprocess.run(
        [sys.executable, "-c", PLAIN_DEPS_ONLY, str(site)],
        cwd=tmp_path,
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert out.returncode == 0, out.stderr[-3000:]
    assert out.stdout.startswith("OK"), out.stdout
    assert "Please install" not in out.stdout + out.stderr
