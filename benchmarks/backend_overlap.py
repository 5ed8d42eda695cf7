"""Would starting the JAX backend beside the package's imports shorten the train CLI's start?

The train CLI imports jax, then the rest of the package (mujoco, MJX, flax, optax,
gymnasium, mara_mjx), then starts the backend at its first jnp operation (on a GPU host
the CUDA client: 1-2 s, benchmarks/NOTES.md section 14). jaxlib releases the GIL while it
creates the client, so a thread could start it while the main thread imports the rest.
Before the CLI's imports are rebuilt for that, this measures what it would save. Each
mode in fresh processes (`--repeat` each, alternating), times from the process start:

* `serial`: import jax; jax.devices() (the backend); import mara_mjx.cli.train;
* `overlap`: import jax; jax.devices() in a thread; import mara_mjx.cli.train; join.

    python benchmarks/backend_overlap.py --repeat 3 [--json out.jsonl]

One JSON line per process: the mode, seconds to `import jax` done, to the backend up
(`backend_s`: that call's own length), to the rest imported, and to both done.
"""

from __future__ import annotations

import argparse
import subprocess
import sys

CHILD = r"""
import json, os, sys, threading, time
def since_start():  # mara_mjx.cli.train's _command_start, inlined: importing it would
    # import the package before the clock's first reading
    with open("/proc/self/stat") as f:
        ticks = int(f.read().rsplit(")", 1)[1].split()[19])
    with open("/proc/uptime") as f:
        up = float(f.read().split()[0])
    return up - ticks / os.sysconf("SC_CLK_TCK")
t0 = time.monotonic() - since_start()
at = lambda: round(time.monotonic() - t0, 3)
mode, out = sys.argv[1], {"mode": sys.argv[1]}
import jax
out["jax_imported_s"] = at()
def backend():
    s = time.monotonic()
    out["devices"] = [d.device_kind for d in jax.devices()]
    out["backend_s"] = round(time.monotonic() - s, 3)
    out["backend_up_s"] = at()
if mode == "overlap":
    thread = threading.Thread(target=backend)
    thread.start()
else:
    backend()
import mara_mjx.cli.train  # noqa: F401
out["rest_imported_s"] = at()
if mode == "overlap":
    thread.join()
out["both_done_s"] = at()
print(json.dumps(out))
"""


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--json", help="also append the lines to this file")
    parser.add_argument("--overwrite", action="store_true", help="--json may append to any file")
    args = parser.parse_args()
    if args.json:  # a new file or this script's own earlier lines, checked before the work
        from mara_mjx.cli.common import UserError
        from mara_mjx.runtime import outputs

        try:
            outputs.check_lines_output(
                args.json, "--json file", "mode", ("serial", "overlap"), args.overwrite
            )
        except UserError as e:
            raise SystemExit(f"error: {e}") from None
    for _ in range(args.repeat):
        for mode in ("serial", "overlap"):
            proc = subprocess.run(
                [sys.executable, "-c", CHILD, mode], capture_output=True, text=True, check=True
            )
            line = proc.stdout.strip().splitlines()[-1]
            print(line, flush=True)
            if args.json:
                with open(args.json, "a") as f:
                    f.write(line + "\n")


if __name__ == "__main__":
    main()
