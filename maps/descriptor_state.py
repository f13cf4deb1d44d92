"""The descriptor's state (vocabulary arrays plus JSON-able settings) as the bytes of one .npz
file, opaque to the map; loading never runs code from the file (no pickles)."""

from __future__ import annotations

import io
import json
import zipfile
from typing import Mapping

import numpy as np

from maps.graph import MapError

_SETTINGS_KEY = "__settings_json__"


def encode_state(state: Mapping[str, object]) -> bytes:
    """numpy arrays (or array-likes such as CPU tensors) go in as arrays, everything else must be
    JSON-able and goes in as one JSON settings entry."""
    if not isinstance(state, Mapping):
        raise MapError(f"descriptor_state must be a mapping, got {type(state).__name__}")
    arrays: dict[str, np.ndarray] = {}
    settings: dict[str, object] = {}
    for key, value in state.items():
        if not isinstance(key, str) or not key or key == _SETTINGS_KEY:
            raise MapError(f"descriptor_state key {key!r} is not allowed")
        if isinstance(value, np.generic):
            value = value.item()
        if isinstance(value, np.ndarray) or (hasattr(value, "__array__") and not isinstance(
                value, (bool, int, float, str, list, tuple, dict))):
            arr = np.asarray(value)
            if arr.dtype == object:
                raise MapError(f"descriptor_state[{key!r}] is an object array; only numeric arrays are stored")
            arrays[key] = arr
            continue
        try:
            json.dumps(value)
        except (TypeError, ValueError) as exc:
            raise MapError(f"descriptor_state[{key!r}] is neither an array nor JSON-able ({exc})") from None
        settings[key] = value
    arrays[_SETTINGS_KEY] = np.frombuffer(json.dumps(settings, sort_keys=True).encode("utf-8"), dtype=np.uint8)
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    return buf.getvalue()


def decode_state(data: bytes, where: str) -> dict:
    try:
        with np.load(io.BytesIO(data), allow_pickle=False) as npz:
            arrays = {k: npz[k] for k in npz.files}
        settings = json.loads(bytes(arrays.pop(_SETTINGS_KEY)).decode("utf-8"))
    except KeyError:
        raise MapError(f"{where}: not a descriptor state written by this software (no settings entry)") from None
    except ValueError as exc:
        if "allow_pickle" in str(exc):   # numpy's words for Python objects in the file, never loaded
            raise MapError(f"{where}: not a descriptor state written by this software (it holds Python "
                           "objects, which are never loaded from a map)") from None
        raise MapError(f"{where}: not a readable descriptor state ({exc})") from None
    except (OSError, EOFError, zipfile.BadZipFile) as exc:
        raise MapError(f"{where}: not a readable descriptor state (damaged or not an .npz file: {exc})") from None
    return {**settings, **arrays}
