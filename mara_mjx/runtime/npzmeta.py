"""One .npz file = named arrays + a JSON metadata entry: the format of checkpoints and of
exported policies. numpy only, so an exported policy loads without JAX code paths."""

from __future__ import annotations

import json
import zipfile
from pathlib import Path
from typing import Any

import numpy as np

META_KEY = "__meta__"
# What reading a damaged or foreign .npz can raise.
NPZ_ERRORS = (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile)


def read_npz_with_meta(path: Path) -> tuple[dict[str, np.ndarray], Any]:
    """The arrays of an .npz written with a JSON `META_KEY` entry, and that entry decoded.
    Raises one of NPZ_ERRORS on a damaged or foreign file (callers name the file kind)."""
    with np.load(path, allow_pickle=False) as z:
        arrays = {k: z[k] for k in z.files}
    return arrays, json.loads(str(arrays.pop(META_KEY)))
