"""A teacher run made small enough to carry: each seed's config.json and newest checkpoint
with only what `mara_mjx.ppo.teacher.load_teacher` reads (params/, obs_stats/ and the
metadata; the envs' state and the optimiser's, 90% of a checkpoint, dropped).

    python benchmarks/strip_teacher.py TEACHER.tgz OUT.tgz   # a lib.sh `keep` archive

The result is a teacher, not a checkpoint to resume from. Used to send a teacher run to
the GPU machine inside its 64-MiB carry (benchmarks/NOTES.md section 54)."""

from __future__ import annotations

import io
import sys
import tarfile

import numpy as np

KEEP = ("params/", "obs_stats/", "__meta__", "update", "key")


def strip(src: str, dst: str) -> None:
    with tarfile.open(src) as tin, tarfile.open(dst, "x:gz") as tout:  # never replaces a file
        for member in tin.getmembers():
            data = tin.extractfile(member).read() if member.isfile() else None
            if data is not None and member.name.endswith(".npz"):
                with np.load(io.BytesIO(data), allow_pickle=False) as z:
                    arrays = {k: z[k] for k in z.files if k.startswith(KEEP)}
                buf = io.BytesIO()
                np.savez(buf, **arrays)
                data = buf.getvalue()
                member.size = len(data)
            tout.addfile(member, io.BytesIO(data) if data is not None else None)


if __name__ == "__main__":
    try:
        strip(sys.argv[1], sys.argv[2])
    except FileExistsError:
        sys.exit(f"error: {sys.argv[2]} exists; name a new file")
