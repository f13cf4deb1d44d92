"""Map folders: one folder per map, written atomically, validated on load.

Layout of a map folder::

    manifest.json            schema_version, descriptor identity, thresholds, nodes, arcs, file table
    descriptors.npy          (n_nodes, D) float32, row k = manifest nodes[k]
    descriptor_state.npz     the descriptor's state (vocabulary, settings), opaque to the map
    walkthrough.npz          optional: the build log and the walkthrough's similarity sample
    columns.npy              optional: (n_nodes, W, C) float16, each keyframe's column profile
                             (descriptors.columns: steering by bearing), row k = nodes[k]
    thumbs/000000.jpg ...    one small JPEG per node (THUMB_SIZE, quality THUMB_QUALITY)

The manifest's ``files`` table lists every other file with its size and SHA-256, so truncation
and corruption are caught on load.

**Atomic save.** :func:`save_map` writes everything into a fresh hidden folder next to the
target (``.NAME.saving-PID-RANDOM``, :class:`core.atomic.AtomicFolder`), fsyncs every file and the
folder, and then swaps it with the target in one step (Linux ``renameat2(RENAME_EXCHANGE)``; where that is unavailable, the old map
is first renamed to ``.NAME.old-PID-RANDOM`` and the new one renamed into place). A crash at any point
leaves either the previous map or the new one at the target path; after a crash between the two
renames of the fallback, :func:`recover_interrupted_save` (run by :func:`load_map` and
:func:`save_map`) puts the previous map back. Leftover hidden folders of dead saves are removed
by the next save.

**Load.** :func:`load_map` checks everything and raises :class:`~maps.graph.MapError` naming the
folder, the file and the problem: missing file, size or hash mismatch, bad shape or dtype, NaN,
arcs to unknown nodes, a descriptor identity other than the expected one, a newer schema.
"""

from __future__ import annotations

import hashlib
import io
import json
import math
import time
import zipfile
from dataclasses import dataclass, field
from pathlib import Path, PurePosixPath
from typing import Mapping, Optional

import cv2
import numpy as np

from core.atomic import AtomicFolder, recover_folder
from core.hal import Pose2D
from descriptors.base import DescriptorIdentity
from maps.builder import NORM_TOLERANCE, BuildLog
from maps.calibration import SimilaritySample
from maps.config import MapThresholds
from maps.descriptor_state import decode_state, encode_state
from maps.graph import ARC_KINDS, HEADING_FIELDS, MapError, TopoMap
from maps.thumbnails import encode_thumbnail

SCHEMA_VERSION = 1
MANIFEST = "manifest.json"
DESCRIPTORS = "descriptors.npy"
STATE = "descriptor_state.npz"
WALKTHROUGH = "walkthrough.npz"
COLUMNS = "columns.npy"
THUMBS = "thumbs"


# -- fault injection ---------------------------------------------------------------------
def _checkpoint(step: str) -> None:
    """Called after every step of a save (:class:`core.atomic.AtomicFolder`). Does nothing;
    tests replace it to simulate a crash (an exception or ``os._exit``) right after ``step``."""


# -- small file helpers ------------------------------------------------------------------
def _npy_bytes(array: np.ndarray) -> bytes:
    buf = io.BytesIO()
    np.save(buf, array, allow_pickle=False)
    return buf.getvalue()


def _npz_bytes(arrays: Mapping[str, np.ndarray]) -> bytes:
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    return buf.getvalue()


def _sha256(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def recover_interrupted_save(path: str | Path) -> bool:
    """If a save crashed after moving the previous map aside (fallback swap only), move it back.

    Returns True when something was restored.
    """
    return recover_folder(path, complete=lambda p: (p / MANIFEST).is_file())


# -- save --------------------------------------------------------------------------------
def _pose_dict(pose: Optional[Pose2D]) -> Optional[dict]:
    return None if pose is None else {"x_m": pose.x_m, "y_m": pose.y_m, "yaw_rad": pose.yaw_rad}


def save_map(path: str | Path, topomap: TopoMap, *, identity: DescriptorIdentity,
             descriptor_state: Mapping[str, object], thresholds: MapThresholds,
             thumbnails: Mapping[int, np.ndarray | bytes], calibration: Optional[Mapping] = None,
             log: Optional[BuildLog] = None, similarity: Optional[SimilaritySample] = None,
             merged: Optional[Mapping[int, int]] = None, extra: Optional[Mapping] = None,
             columns: Optional[np.ndarray] = None) -> Path:
    """Write the map folder at ``path`` atomically (see the module docstring); return the path.

    ``identity``: the descriptor's :class:`DescriptorIdentity` (its ``dim`` must match the map).
    ``descriptor_state``: ``descriptor.state_dict()``: arrays plus JSON-able settings.
    ``thresholds``: the thresholds the map was built with. ``thumbnails``: node id -> RGB uint8
    image (any size; shrunk with :func:`maps.thumbnails.make_thumbnail`) or
    :func:`maps.thumbnails.encode_thumbnail` bytes, for
    every node; ids of nodes no longer in the map are ignored. ``calibration``: ``Calibration.to_dict()`` when calibrated. ``log`` and
    ``similarity``: the build log and walkthrough similarity sample, for the pictures.
    ``merged``: the optimisation pass's removed -> kept node ids (``MergeResult.merged``).
    ``extra``: any JSON-able summary (frames read, source video, ...). ``columns``: the nodes'
    column profiles ``(n_nodes, W, C)`` in the map's node order (stored as float16), or None.

    An existing target is replaced only if it is a map folder (has a manifest) or is empty.
    """
    path = Path(path)
    if not isinstance(identity, DescriptorIdentity):
        raise MapError(f"identity must be a DescriptorIdentity, got {type(identity).__name__}")
    if not isinstance(thresholds, MapThresholds):
        raise MapError(f"thresholds must be a MapThresholds, got {type(thresholds).__name__}")
    if len(topomap) == 0:
        raise MapError("refusing to save an empty map")
    if identity.dim and identity.dim != topomap.dim:
        raise MapError(f"descriptor identity says dim {identity.dim}, the map's descriptors have {topomap.dim}")
    missing = [n for n in topomap.node_ids.tolist() if n not in thumbnails]
    if missing:
        raise MapError(f"no thumbnail for node(s) {missing[:5]}{'...' if len(missing) > 5 else ''}")
    if similarity is not None and log is None:
        raise MapError("a similarity sample is only stored together with its build log")
    if columns is not None:
        columns = np.asarray(columns)
        if columns.ndim != 3 or columns.shape[0] != len(topomap) or not np.all(np.isfinite(columns)):
            raise MapError(f"columns must be finite, of shape ({len(topomap)}, W, C), one row per node; "
                           f"got shape {columns.shape}")

    recover_interrupted_save(path)
    if path.exists():
        if not path.is_dir():
            raise MapError(f"{path}: exists and is not a folder; refusing to replace it")
        if not (path / MANIFEST).is_file() and any(path.iterdir()):
            raise MapError(f"{path}: exists and is not a map folder (no {MANIFEST}); refusing to replace it")

    # everything is encoded before the first byte is written, so a bad input leaves no debris
    files: dict[str, bytes] = {
        DESCRIPTORS: _npy_bytes(np.ascontiguousarray(topomap.descriptors, dtype=np.float32)),
        STATE: encode_state(descriptor_state),
    }
    if log is not None:
        arrays = {f"log_{k}": v for k, v in log.to_arrays().items()}
        if similarity is not None:
            arrays["similarity_seq"] = np.asarray(similarity.seq, dtype=np.int64)
            arrays["similarity_matrix"] = np.asarray(similarity.matrix, dtype=np.float16)
        files[WALKTHROUGH] = _npz_bytes(arrays)
    if columns is not None:
        files[COLUMNS] = _npy_bytes(np.ascontiguousarray(columns, dtype=np.float16))
    nodes = []
    for node in topomap.nodes():
        thumb = f"{THUMBS}/{node.node_id:06d}.jpg"
        files[thumb] = encode_thumbnail(thumbnails[node.node_id])
        entry = {"id": node.node_id, "keyframe_index": node.keyframe_index, "stamp_s": node.stamp_s,
                 "thumbnail": thumb}
        if node.true_pose is not None:
            entry["true_pose"] = _pose_dict(node.true_pose)
        if node.odom_yaw_rad is not None:
            entry["odom_yaw_rad"] = node.odom_yaw_rad
        if node.gyro_yaw_rad is not None:
            entry["gyro_yaw_rad"] = node.gyro_yaw_rad
        nodes.append(entry)
    arcs = [{"src": a.src, "dst": a.dst, "weight": a.weight, "kind": a.kind, "n_frames": a.n_frames,
             **({"length_m": a.length_m} if a.length_m is not None else {})} for a in topomap.arcs()]
    manifest = {
        "schema_version": SCHEMA_VERSION,
        "created_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        "descriptor": identity.to_dict(),
        "descriptor_state": STATE,
        "vocabulary_sha256": identity.vocabulary_sha256,
        "descriptors": {"file": DESCRIPTORS, "shape": [len(topomap), topomap.dim], "dtype": "float32"},
        "walkthrough": WALKTHROUGH if log is not None else None,
        "columns": None if columns is None else {"file": COLUMNS, "shape": list(columns.shape), "dtype": "float16"},
        "thresholds": thresholds.to_dict(),
        "calibration": dict(calibration) if calibration is not None else None,
        "merged": {str(int(k)): int(v) for k, v in (merged or {}).items()},
        "extra": dict(extra) if extra is not None else {},
        "nodes": nodes,
        "arcs": arcs,
        "files": {name: {"bytes": len(data), "sha256": _sha256(data)} for name, data in sorted(files.items())},
    }
    try:
        manifest_bytes = json.dumps(manifest, indent=1, allow_nan=False).encode("utf-8")
    except (TypeError, ValueError) as exc:
        raise MapError(f"manifest is not JSON-able (calibration or extra?): {exc}") from None

    with AtomicFolder(path, checkpoint=lambda step: _checkpoint(step)) as folder:
        folder.mkdir(THUMBS)
        for name, data in files.items():
            folder.write(name, data)
        folder.write(MANIFEST, manifest_bytes)          # last: a folder with a manifest is complete
        folder.commit()
    return path


# -- load --------------------------------------------------------------------------------
@dataclass(frozen=True)
class LoadedMap:
    """A validated map folder. ``calibration`` is the calibration record or ``None``; ``log``
    and ``similarity`` are ``None`` when the folder has no walkthrough file; ``columns``
    (float32, ``(n_nodes, W, C)``, row k = node ``topomap.node_ids[k]``) is ``None`` when it has
    no column profiles (maps made before 2026-12-07, or with a descriptor that gives none)."""

    path: Path
    topomap: TopoMap
    identity: DescriptorIdentity
    descriptor_state: dict
    thresholds: MapThresholds
    schema_version: int
    calibration: Optional[dict] = None
    log: Optional[BuildLog] = None
    similarity: Optional[SimilaritySample] = None
    merged: dict = field(default_factory=dict)
    extra: dict = field(default_factory=dict)
    thumbnail_files: dict = field(default_factory=dict)
    columns: Optional[np.ndarray] = None

    def thumbnail_path(self, node_id: int) -> Path:
        if node_id not in self.thumbnail_files:
            raise MapError(f"{self.path}: no thumbnail for node {node_id}")
        return self.path / self.thumbnail_files[node_id]

    def thumbnail(self, node_id: int) -> np.ndarray:
        """The node's thumbnail as an RGB uint8 image."""
        p = self.thumbnail_path(node_id)
        img = cv2.imdecode(np.frombuffer(p.read_bytes(), dtype=np.uint8), cv2.IMREAD_COLOR)
        if img is None:
            raise MapError(f"{p}: not a readable JPEG")
        return cv2.cvtColor(img, cv2.COLOR_BGR2RGB)


class _Checker:
    """Raises MapError messages that name the map folder and the item."""

    def __init__(self, path: Path):
        self.path = path

    def fail(self, where: str, problem: str) -> MapError:
        return MapError(f"map {self.path}: {where}: {problem}")

    def relpath(self, where: str, value: object) -> str:
        if not isinstance(value, str) or not value:
            raise self.fail(where, f"expected a file name, got {value!r}")
        p = PurePosixPath(value)
        if p.is_absolute() or ".." in p.parts:
            raise self.fail(where, f"file name {value!r} points outside the map folder")
        return value

    def number(self, where: str, value: object, least: float | None = None) -> float:
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise self.fail(where, f"expected a finite number, got {value!r}")
        if least is not None and value < least:
            raise self.fail(where, f"expected a number >= {least}, got {value!r}")
        return float(value)

    def integer(self, where: str, value: object, least: int | None = None) -> int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise self.fail(where, f"expected an integer, got {value!r}")
        if least is not None and value < least:
            raise self.fail(where, f"expected an integer >= {least}, got {value!r}")
        return value

    def key(self, where: str, data: object, name: str) -> object:
        if not isinstance(data, Mapping):
            raise self.fail(where, f"expected a mapping, got {data!r}")
        if name not in data:
            raise self.fail(where, f"missing field {name!r}")
        return data[name]


def _read_files(chk: _Checker, manifest: Mapping, verify_hashes: bool) -> dict[str, bytes]:
    table = chk.key(MANIFEST, manifest, "files")
    if not isinstance(table, dict):
        raise chk.fail(f"{MANIFEST}: files", "expected a mapping of file name -> size and hash")
    out = {}
    for name, info in table.items():
        chk.relpath(f"{MANIFEST}: files", name)
        p = chk.path / name
        if not p.is_file():
            raise chk.fail(name, "file is missing")
        data = p.read_bytes()
        where = f"{MANIFEST}: files[{name!r}]"
        size = chk.integer(f"{where}.bytes", chk.key(where, info, "bytes"), 0)
        if len(data) != size:
            raise chk.fail(name, f"is {len(data)} bytes, the manifest says {size} (truncated or replaced)")
        if verify_hashes and _sha256(data) != chk.key(where, info, "sha256"):
            raise chk.fail(name, "content does not match its SHA-256 in the manifest (corrupted)")
        out[name] = data
    return out


def _parse_nodes(chk: _Checker, manifest: Mapping, files: Mapping[str, bytes]) -> list[dict]:
    raw = chk.key(MANIFEST, manifest, "nodes")
    if not isinstance(raw, list) or not raw:
        raise chk.fail(f"{MANIFEST}: nodes", "expected a non-empty list")
    nodes, seen = [], set()
    for k, entry in enumerate(raw):
        where = f"{MANIFEST}: nodes[{k}]"
        if not isinstance(entry, dict):
            raise chk.fail(where, f"expected a mapping, got {entry!r}")
        node_id = chk.integer(f"{where}.id", chk.key(where, entry, "id"), 0)
        if node_id in seen:
            raise chk.fail(f"{where}.id", f"node id {node_id} appears twice")
        seen.add(node_id)
        thumb = chk.relpath(f"{where}.thumbnail", chk.key(where, entry, "thumbnail"))
        if thumb not in files:
            raise chk.fail(f"{where}.thumbnail", f"{thumb!r} is not in the manifest's file table")
        pose = entry.get("true_pose")
        if pose is not None:
            if not isinstance(pose, dict):
                raise chk.fail(f"{where}.true_pose", f"expected a mapping, got {pose!r}")
            pose = Pose2D(*(chk.number(f"{where}.true_pose.{f}", chk.key(f"{where}.true_pose", pose, f))
                            for f in ("x_m", "y_m", "yaw_rad")))
        yaws = {}
        for field in HEADING_FIELDS.values():
            yaw = entry.get(field)
            yaws[field] = None if yaw is None else chk.number(f"{where}.{field}", yaw)
        nodes.append({"id": node_id, "thumbnail": thumb, "true_pose": pose, **yaws,
                      "keyframe_index": chk.integer(f"{where}.keyframe_index", chk.key(where, entry, "keyframe_index")),
                      "stamp_s": chk.number(f"{where}.stamp_s", chk.key(where, entry, "stamp_s"))})
    return nodes


def _parse_descriptors(chk: _Checker, data: bytes, n_nodes: int, dim: int) -> np.ndarray:
    try:
        x = np.load(io.BytesIO(data), allow_pickle=False)
    except (ValueError, OSError, EOFError) as exc:
        raise chk.fail(DESCRIPTORS, f"not a readable .npy array ({exc})") from None
    if not isinstance(x, np.ndarray):
        raise chk.fail(DESCRIPTORS, "holds an archive, expected one array")
    if x.dtype != np.float32:
        raise chk.fail(DESCRIPTORS, f"dtype is {x.dtype}, expected float32")
    if x.ndim != 2 or x.shape[0] != n_nodes or (dim and x.shape[1] != dim):
        want = f"({n_nodes}, {dim if dim else 'D'})"
        raise chk.fail(DESCRIPTORS, f"shape is {x.shape}, expected {want} for {n_nodes} nodes")
    if not np.all(np.isfinite(x)):
        bad = int(np.nonzero(~np.all(np.isfinite(x), axis=1))[0][0])
        raise chk.fail(DESCRIPTORS, f"row {bad} has NaN or infinite values")
    norms = np.linalg.norm(x, axis=1)
    if np.any(np.abs(norms - 1.0) > NORM_TOLERANCE):
        bad = int(np.argmax(np.abs(norms - 1.0)))
        raise chk.fail(DESCRIPTORS, f"row {bad} has norm {norms[bad]:.4f}; descriptors must be L2-normalised")
    return x


def _add_arcs(chk: _Checker, manifest: Mapping, topomap: TopoMap) -> None:
    raw = chk.key(MANIFEST, manifest, "arcs")
    if not isinstance(raw, list):
        raise chk.fail(f"{MANIFEST}: arcs", "expected a list")
    seen = set()
    for k, entry in enumerate(raw):
        where = f"{MANIFEST}: arcs[{k}]"
        if not isinstance(entry, dict):
            raise chk.fail(where, f"expected a mapping, got {entry!r}")
        src = chk.integer(f"{where}.src", chk.key(where, entry, "src"))
        dst = chk.integer(f"{where}.dst", chk.key(where, entry, "dst"))
        for end in (src, dst):
            if end not in topomap:
                raise chk.fail(where, f"arc {src} -> {dst} refers to unknown node {end}")
        if src == dst:
            raise chk.fail(where, f"arc {src} -> {dst} is a self-loop")
        if (src, dst) in seen:
            raise chk.fail(where, f"arc {src} -> {dst} appears twice")
        seen.add((src, dst))
        kind = chk.key(where, entry, "kind")
        if kind not in ARC_KINDS:
            raise chk.fail(f"{where}.kind", f"{kind!r} is not one of {list(ARC_KINDS)}")
        length = entry.get("length_m")
        topomap.add_arc(src, dst, chk.number(f"{where}.weight", chk.key(where, entry, "weight"), 0.0), kind,
                        chk.integer(f"{where}.n_frames", entry.get("n_frames", 0), 0),
                        None if length is None else chk.number(f"{where}.length_m", length, 0.0))


def _parse_walkthrough(chk: _Checker, data: bytes) -> tuple[BuildLog, Optional[SimilaritySample]]:
    try:
        with np.load(io.BytesIO(data), allow_pickle=False) as npz:
            arrays = {k: npz[k] for k in npz.files}
    except (ValueError, OSError, EOFError, zipfile.BadZipFile) as exc:
        raise chk.fail(WALKTHROUGH, f"not a readable .npz ({exc})") from None
    try:
        log = BuildLog.from_arrays({k[4:]: v for k, v in arrays.items() if k.startswith("log_")})
    except MapError as exc:
        raise chk.fail(WALKTHROUGH, str(exc)) from None
    similarity = None
    if "similarity_seq" in arrays:
        seq, mat = arrays["similarity_seq"], arrays.get("similarity_matrix")
        if mat is None or mat.shape != (seq.size, seq.size):
            raise chk.fail(WALKTHROUGH, f"similarity matrix does not match its {seq.size} sampled frames")
        similarity = SimilaritySample(seq=seq, matrix=mat)
    return log, similarity


def _parse_columns(chk: _Checker, manifest: Mapping, files: Mapping[str, bytes], n_nodes: int) -> Optional[np.ndarray]:
    entry = manifest.get("columns")
    if entry is None:
        return None
    where = f"{MANIFEST}: columns"
    name = chk.relpath(f"{where}.file", chk.key(where, entry, "file")) if isinstance(entry, dict) else None
    if name is None or name not in files:
        raise chk.fail(where, f"expected a file of the manifest's file table, got {entry!r}")
    try:
        x = np.load(io.BytesIO(files[name]), allow_pickle=False)
    except (ValueError, OSError, EOFError) as exc:
        raise chk.fail(name, f"not a readable .npy array ({exc})") from None
    if not isinstance(x, np.ndarray) or x.ndim != 3 or x.shape[0] != n_nodes:
        raise chk.fail(name, f"shape is {getattr(x, 'shape', None)}, expected ({n_nodes}, W, C) for {n_nodes} nodes")
    if not np.all(np.isfinite(x)):
        raise chk.fail(name, "has NaN or infinite values")
    return x.astype(np.float32)


def load_map(path: str | Path, expected_identity: Optional[DescriptorIdentity] = None, *,
             verify_hashes: bool = True) -> LoadedMap:
    """Load and validate the map folder at ``path``.

    ``expected_identity``: the descriptor that will be used with the map; a different backend,
    settings, vocabulary or dimension is refused. ``verify_hashes``: check every file's SHA-256
    (cheap; turn off only for very large maps on slow disks).
    """
    path = Path(path)
    recover_interrupted_save(path)
    chk = _Checker(path)
    if not path.is_dir():
        raise MapError(f"map {path}: folder not found")
    mpath = path / MANIFEST
    if not mpath.is_file():
        raise chk.fail(MANIFEST, "file is missing (not a map folder, or an unfinished copy)")
    try:
        manifest = json.loads(mpath.read_text(encoding="utf-8"))
    except (ValueError, UnicodeDecodeError) as exc:
        raise chk.fail(MANIFEST, f"not valid JSON ({exc})") from None
    if not isinstance(manifest, dict):
        raise chk.fail(MANIFEST, "expected a JSON object at the top level")
    version = chk.integer(f"{MANIFEST}: schema_version", chk.key(MANIFEST, manifest, "schema_version"), 1)
    if version > SCHEMA_VERSION:
        raise chk.fail(MANIFEST, f"schema_version {version} is newer than this software reads "
                                 f"({SCHEMA_VERSION}); update the software")

    ident_raw = chk.key(MANIFEST, manifest, "descriptor")
    try:
        identity = DescriptorIdentity.from_dict(ident_raw)
    except (KeyError, TypeError, ValueError, AttributeError) as exc:
        raise chk.fail(f"{MANIFEST}: descriptor", f"not a descriptor identity ({exc!r})") from None
    if manifest.get("vocabulary_sha256", identity.vocabulary_sha256) != identity.vocabulary_sha256:
        raise chk.fail(f"{MANIFEST}: vocabulary_sha256", "does not match the descriptor identity's")
    if expected_identity is not None:
        problem = expected_identity.mismatch(identity)
        if problem:
            raise chk.fail(MANIFEST, f"built with another descriptor than the one in use (map's value "
                                     f"first): {problem}")
    try:
        thresholds = MapThresholds.from_dict(chk.key(MANIFEST, manifest, "thresholds"))
    except (ValueError, TypeError, AttributeError) as exc:
        raise chk.fail(f"{MANIFEST}: thresholds", str(exc)) from None

    files = _read_files(chk, manifest, verify_hashes)
    desc_name = chk.relpath(f"{MANIFEST}: descriptors.file",
                            chk.key(f"{MANIFEST}: descriptors", chk.key(MANIFEST, manifest, "descriptors"), "file"))
    state_name = chk.relpath(f"{MANIFEST}: descriptor_state", chk.key(MANIFEST, manifest, "descriptor_state"))
    for required in (desc_name, state_name):
        if required not in files:
            raise chk.fail(required, "is not in the manifest's file table")
    nodes = _parse_nodes(chk, manifest, files)
    x = _parse_descriptors(chk, files[desc_name], len(nodes), identity.dim)
    topomap = TopoMap(int(x.shape[1]))
    for row, node in enumerate(nodes):
        topomap.add_node(x[row], node["keyframe_index"], node["stamp_s"], node["true_pose"], node_id=node["id"])
        if node["odom_yaw_rad"] is not None:
            topomap.set_odom_yaw(node["id"], node["odom_yaw_rad"])
        if node["gyro_yaw_rad"] is not None:
            topomap.set_gyro_yaw(node["id"], node["gyro_yaw_rad"])
    _add_arcs(chk, manifest, topomap)
    state = decode_state(files[state_name], f"map {path}: {state_name}")

    log = similarity = None
    if manifest.get("walkthrough"):
        name = chk.relpath(f"{MANIFEST}: walkthrough", manifest["walkthrough"])
        if name not in files:
            raise chk.fail(name, "is not in the manifest's file table")
        log, similarity = _parse_walkthrough(chk, files[name])
    columns = _parse_columns(chk, manifest, files, len(nodes))
    calibration = manifest.get("calibration")
    extra = manifest.get("extra") or {}
    merged_raw = manifest.get("merged") or {}
    try:
        merged = {int(k): int(v) for k, v in merged_raw.items()}
    except (AttributeError, TypeError, ValueError):
        raise chk.fail(f"{MANIFEST}: merged", f"expected a mapping of node ids, got {merged_raw!r}") from None
    return LoadedMap(path=path, topomap=topomap, identity=identity, descriptor_state=state,
                     thresholds=thresholds, schema_version=version,
                     calibration=calibration if isinstance(calibration, dict) else None,
                     log=log, similarity=similarity, merged=merged,
                     extra=extra if isinstance(extra, dict) else {},
                     thumbnail_files={n["id"]: n["thumbnail"] for n in nodes}, columns=columns)


# -- size --------------------------------------------------------------------------------
@dataclass(frozen=True)
class MapSize:
    """Bytes on disk. ``per_node_bytes`` = (manifest + descriptors + thumbnails) / nodes, the
    part that grows with the map; the descriptor state and walkthrough file are fixed costs."""

    n_nodes: int
    manifest_bytes: int
    descriptor_bytes: int
    thumbnail_bytes: int
    state_bytes: int
    walkthrough_bytes: int
    total_bytes: int
    per_node_bytes: float

    def to_dict(self) -> dict:
        return dict(self.__dict__)


def map_size(path: str | Path) -> MapSize:
    """Sizes of a saved map folder (it is loaded and validated first)."""
    loaded = load_map(path, verify_hashes=False)
    p = loaded.path
    size = lambda name: (p / name).stat().st_size if (p / name).is_file() else 0   # noqa: E731
    thumbs = sum(size(t) for t in loaded.thumbnail_files.values())
    manifest, desc, state, walk = size(MANIFEST), size(DESCRIPTORS), size(STATE), size(WALKTHROUGH)
    n = len(loaded.topomap)
    return MapSize(n_nodes=n, manifest_bytes=manifest, descriptor_bytes=desc, thumbnail_bytes=thumbs,
                   state_bytes=state, walkthrough_bytes=walk,
                   total_bytes=manifest + desc + thumbs + state + walk,
                   per_node_bytes=(manifest + desc + thumbs) / n)
