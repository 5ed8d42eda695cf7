"""A workaround for slow MJX on the CPU, applied when mara_mjx is imported.

XLA's newer CPU fusion emitters compile the batched (vmapped) MJX kinematics of this arm
into far slower code than the older emitters: on a 2-core CPU with jaxlib 0.10.2, a
batched train-driver env step of 256 envs takes 0.22 s instead of 4-6 ms
(`benchmarks/cpu_step.py`, with and without the flag), and the whole PPO pipeline is
slowed the same way (benchmarks/NOTES.md section 10; a known class of XLA CPU
regression, cf. jax-ml/jax#33761).
`--xla_cpu_use_fusion_emitters=false` restores the old emitters for CPU code only (GPU
compilation ignores it) and leaves results unchanged. It is appended to XLA_FLAGS

* only if XLA_FLAGS does not mention the flag already (set it there to choose yourself),
* only for the jaxlib versions where the flag is known to exist (XLA aborts on unknown
  flags, and newer XLA plans to remove the old emitters),
* and it only takes effect if no JAX backend has started before mara_mjx is imported.
"""

from __future__ import annotations

import os

FLAG = "--xla_cpu_use_fusion_emitters=false"
JAXLIB_VERSIONS = ((0, 7), (0, 11))  # [first, end): 0.10.2 has the flag; 0.11.2 aborts on it


def _version(text: str) -> tuple[int, ...]:
    parts = []
    for p in text.split(".")[:2]:
        digits = "".join(c for c in p if c.isdigit())
        parts.append(int(digits or 0))
    return tuple(parts)


def apply_cpu_fusion_workaround() -> bool:
    """Append FLAG to XLA_FLAGS where appropriate (module docstring); True if appended."""
    flags = os.environ.get("XLA_FLAGS", "")
    if "xla_cpu_use_fusion_emitters" in flags:
        return False
    try:
        from importlib.metadata import version

        jaxlib = _version(version("jaxlib"))
    except Exception:  # not installed as a distribution: leave XLA alone
        return False
    first, end = JAXLIB_VERSIONS
    if not first <= jaxlib < end:
        return False
    os.environ["XLA_FLAGS"] = (flags + " " + FLAG).strip()
    return True


apply_cpu_fusion_workaround()
