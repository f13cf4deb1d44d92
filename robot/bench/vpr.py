"""``python -m robot.bench vpr``: place recognition recall@1 / recall@5 of descriptor backends.

Two ways to say which reference image is the right answer for a query:

* **image folders** (``--ref DIR --query DIR --tolerance N``): both folders hold the same route,
  one image per place, in name order (Gardens Point's ``day_left`` / ``day_right`` /
  ``night_right``); query *i* is correct when the retrieved reference index is within ``±N``.
* **two recorded drives** (``--ref-recording DIR --query-recording DIR``), e.g. the simulator's
  walkthrough recorded twice under different appearance seeds: a retrieved reference frame is
  correct when its true position is within ``--tolerance-m`` metres of the query's (default
  1.0 m: about the spacing of map nodes, and 12 frames of a 0.4 m/s drive recorded at 5 Hz) and
  its true heading within ``--tolerance-deg`` degrees (default 45: the two 65 degree views still
  share about a third of their field; a frame facing the other way is not the same place).
  Queries with no reference frame inside the tolerance are left out of the recall and counted.

Every backend describes both sets; the similarity is the dot product of the L2-normalised
descriptors, and recall@k is the fraction of queries whose k most similar reference images
hold a correct one. VLAD backends fit their vocabulary on the *reference* images, as a map
fits its vocabulary on its own keyframes; with ``--vocab-seeds 0,1,2`` the fit is repeated per
k-means seed and the mean recall is reported (with the range). Backends built on a dense
extractor (``effnet-vlad``, ``effnet-gap``, ``anyloc-dinov2``) extract local features once per
image set and extractor settings; ``--cache DIR`` keeps them on disk between runs.

With ``--sequence`` every backend is also scored as the robot uses it: the belief filter of
:mod:`controllers.belief` runs over the query images in order, against the reference images as
a chain of places (one place per image, the step model in images: each query image moves one
place, ``stay`` / ``skip`` absorb a different pace), its likelihood fitted on the reference
images alone; ``seq@1`` is the fraction of queries whose filter mode, at that query and with no
look ahead, is a correct reference. Single-image recall uses one view; the filter uses every view
so far and the order they came in.

Speed is timed separately, at batch 1, on query frames resized to ``--timing-size`` (the
robot camera's 320x240 by default) with ``--threads`` inference threads: ``describe`` of one frame,
and ``describe_thirds`` (the frame and its Left / Middle / Right thirds, what a control step
needs). Median milliseconds per frame, and the fastest call (the better estimate of the
uncontended cost on a shared CPU). numpy's OpenBLAS threads, left spinning after VLAD's
assignment product, compete with torch's threads for the same cores (on a 2-core CPU VLAD of
block-10 maps took over a second per frame instead of 28 ms), and so does OpenCV's thread pool
(resizing); run with ``OPENBLAS_NUM_THREADS=1`` and ``--cv2-threads 1`` to time what a control
loop should see; the header says how it ran.
"""

from __future__ import annotations

import argparse
import hashlib
import io
import json
import math
import os
import re
import sys
import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Optional, Sequence

import cv2
import networkx as nx
import numpy as np
import yaml
from tqdm import tqdm

from controllers.belief import LikelihoodError, NodeBelief, SimilarityModel
from controllers.config import BeliefConfig
from core.atomic import write_bytes, write_json
from core.cli import UsageError, check_output_file, check_output_folder
from core.hal import Pose2D
from descriptors.base import DescriptorError
from descriptors.factory import make_descriptor
from descriptors.preprocess import MIN_SIDE_PX
from robot.mapping.recording import RecordingError, read_recording

IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png", ".bmp", ".ppm", ".pgm", ".tif", ".tiff", ".webp")
DEFAULT_BACKENDS = ("effnet-vlad", "effnet-gap")
RECALL_KS = (1, 5)
EXIT_BAD_INPUT = 2
_CHUNK = 16              # images loaded and described at a time (bounds memory for large folders)
_TIMING_WARMUP = 2       # first calls pay for lazy weight loading and allocator warm-up


class VprInputError(ValueError):
    """Bad input to the evaluation (folder, image, recording, backend spec); names the culprit."""


# --------------------------------------------------------------------------------------------
# Image sets and ground truth
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class ImageSet:
    """Images of one traversal, in order; ``poses`` are true poses (recordings only)."""

    source: Path
    paths: tuple[Path, ...]
    poses: Optional[tuple[Pose2D, ...]] = None

    def __len__(self) -> int:
        return len(self.paths)

    def load(self, index: int) -> np.ndarray:
        """RGB uint8 image ``index``; an unreadable or tiny file raises VprInputError naming it."""
        path = self.paths[index]
        bgr = cv2.imread(str(path), cv2.IMREAD_COLOR)
        if bgr is None:
            raise VprInputError(f"{path}: cannot read the image (not an image, or damaged)")
        h, w = bgr.shape[:2]
        if h < MIN_SIDE_PX or w < MIN_SIDE_PX:
            raise VprInputError(f"{path}: {w}x{h} px is too small for place recognition "
                                f"(at least {MIN_SIDE_PX}x{MIN_SIDE_PX} px)")
        return cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)

    def fingerprint(self) -> list:
        """What identifies the files' contents cheaply: path, size and modification time."""
        out = []
        for p in self.paths:
            st = p.stat()
            out.append([str(p.resolve()), st.st_size, st.st_mtime_ns])
        return out


def image_folder(folder: str | Path) -> ImageSet:
    """The image files of ``folder`` sorted by name."""
    folder = Path(folder)
    if not folder.exists():
        raise VprInputError(f"{folder}: no such folder")
    if not folder.is_dir():
        raise VprInputError(f"{folder}: not a folder")
    paths = tuple(sorted(p for p in folder.iterdir() if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES))
    if not paths:
        raise VprInputError(f"{folder}: no images ({', '.join(IMAGE_SUFFIXES)}) in this folder")
    return ImageSet(folder, paths)


def recording_set(folder: str | Path) -> ImageSet:
    """The frames of a recording with their true poses (a simulator recording)."""
    folder = Path(folder)
    if not folder.is_dir():
        raise VprInputError(f"{folder}: no such recording folder")
    try:
        frames = read_recording(folder)
    except RecordingError as exc:
        raise VprInputError(str(exc)) from None
    missing = [f.index for f in frames if f.true_pose is None]
    if missing:
        raise VprInputError(f"{folder / 'frames.csv'}: frame {missing[0]} (and {len(missing) - 1} more) has no "
                            "true pose; pose matching needs a simulator recording (true_x_m, true_y_m, true_yaw_rad)")
    return ImageSet(folder, tuple(f.path for f in frames), tuple(f.true_pose for f in frames))


def frame_positives(n_query: int, n_ref: int, tolerance: int) -> np.ndarray:
    """(Q, R) bool: reference j is correct for query i when ``|i - j| <= tolerance``."""
    if n_query != n_ref:
        raise VprInputError(f"the reference has {n_ref} images but the query has {n_query}: matching by frame "
                            "index (--tolerance) needs folders of the same route with equal counts")
    if tolerance < 0:
        raise VprInputError(f"--tolerance must be >= 0 frames, got {tolerance}")
    idx = np.arange(n_query)
    return np.abs(idx[:, None] - idx[None, :]) <= tolerance


def pose_positives(query: Sequence[Pose2D], ref: Sequence[Pose2D], tolerance_m: float,
                   tolerance_deg: float) -> np.ndarray:
    """(Q, R) bool: within ``tolerance_m`` metres and ``tolerance_deg`` degrees of heading."""
    if not tolerance_m > 0:
        raise VprInputError(f"--tolerance-m must be > 0, got {tolerance_m}")
    if not 0 < tolerance_deg <= 180:
        raise VprInputError(f"--tolerance-deg must be in (0, 180], got {tolerance_deg}")
    q = np.array([[p.x_m, p.y_m, p.yaw_rad] for p in query], dtype=np.float64)
    r = np.array([[p.x_m, p.y_m, p.yaw_rad] for p in ref], dtype=np.float64)
    dist = np.hypot(q[:, None, 0] - r[None, :, 0], q[:, None, 1] - r[None, :, 1])
    dyaw = np.abs(np.angle(np.exp(1j * (q[:, None, 2] - r[None, :, 2]))))
    return (dist <= tolerance_m) & (dyaw <= math.radians(tolerance_deg) + 1e-9)


def recall_at(similarity: np.ndarray, positives: np.ndarray, ks: Sequence[int] = RECALL_KS) -> dict[int, float]:
    """Fraction of queries (rows with at least one positive) whose top-k references hold a positive."""
    has_match = positives.any(axis=1)
    if not has_match.any():
        raise VprInputError("no query has a correct reference inside the tolerance; nothing to evaluate")
    order = np.argsort(-similarity, axis=1, kind="stable")
    hits = np.take_along_axis(positives, order, axis=1)[has_match]
    return {k: float(hits[:, :min(k, hits.shape[1])].any(axis=1).mean()) for k in ks}


# --------------------------------------------------------------------------------------------
# Backends and feature extraction
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class BackendSpec:
    """``NAME[:key=value,...]`` from the command line; values are YAML (``[10,13]``, ``320``)."""

    label: str
    name: str
    settings: dict = field(default_factory=dict)


def parse_backend(text: str) -> BackendSpec:
    """Parse ``effnet-vlad:blocks=[10,13],input_width_px=384``; ``blocks=10+13`` also gives a list."""
    name, _, rest = text.partition(":")
    name = name.strip()
    if not name:
        raise VprInputError(f"--backend {text!r}: no backend name before ':'")
    settings: dict = {}
    for item in _split_top_level(rest):
        key, eq, value = item.partition("=")
        if not eq or not key.strip():
            raise VprInputError(f"--backend {text!r}: expected key=value, got {item!r}")
        settings[key.strip()] = _parse_value(value.strip(), text)
    return BackendSpec(text, name, settings)


def _split_top_level(text: str) -> list[str]:
    """Split at commas that are not inside brackets, so ``blocks=[10,13],seed=1`` is two items."""
    items, depth, start = [], 0, 0
    for i, ch in enumerate(text):
        depth += {"[": 1, "]": -1}.get(ch, 0)
        if ch == "," and depth == 0:
            items.append(text[start:i])
            start = i + 1
    items.append(text[start:])
    return [s for s in (x.strip() for x in items) if s]


def _parse_value(value: str, spec: str):
    if re.fullmatch(r"\d+(\+\d+)+", value):
        return [int(v) for v in value.split("+")]
    try:
        return yaml.safe_load(value)
    except yaml.YAMLError:
        raise VprInputError(f"--backend {spec!r}: cannot read the value {value!r}") from None


def _has_dense_features(descriptor) -> bool:
    return hasattr(descriptor, "local_features") and hasattr(descriptor, "extractor")


class FeatureStore:
    """Local feature maps per (image set, extractor): kept for the last extractor in memory, and
    on disk under ``cache_dir`` when given (``.npy`` files named by a hash of both)."""

    def __init__(self, cache_dir: Optional[Path] = None, progress: bool = True):
        self.cache_dir = cache_dir
        self.progress = progress
        self._memory: dict[str, np.ndarray] = {}

    def maps(self, descriptor, images: ImageSet, role: str) -> np.ndarray:
        key = self._key(descriptor, images)
        if key in self._memory:
            return self._memory[key]
        maps = self._load(key)
        if maps is None:
            maps = self._extract(descriptor, images, role)
            self._save(key, maps)
        if len(self._memory) >= 2:          # reference and query of one extractor at a time
            self._memory.pop(next(iter(self._memory)))
        self._memory[key] = maps
        return maps

    @staticmethod
    def _key(descriptor, images: ImageSet) -> str:
        extractor = descriptor.extractor
        ident = {"extractor": type(extractor).__name__, "settings": extractor.settings,
                 "files": images.fingerprint()}
        engine = getattr(extractor, "runtime", {}).get("engine")
        if engine is not None:               # the same features to 1e-6, but measured per engine
            ident["engine"] = engine
        weights = getattr(extractor, "weights_path", None)
        if weights is not None and Path(weights).is_file():
            st = Path(weights).stat()
            ident["weights"] = [str(Path(weights).resolve()), st.st_size, st.st_mtime_ns]
        return hashlib.sha256(json.dumps(ident, sort_keys=True, default=str).encode()).hexdigest()[:24]

    def _path(self, key: str) -> Optional[Path]:
        return None if self.cache_dir is None else self.cache_dir / f"maps-{key}.npy"

    def _load(self, key: str) -> Optional[np.ndarray]:
        path = self._path(key)
        if path is None or not path.is_file():
            return None
        try:
            return np.load(path, allow_pickle=False)
        except (OSError, ValueError):
            return None                      # a damaged cache file is recomputed, not fatal

    def _save(self, key: str, maps: np.ndarray) -> None:
        path = self._path(key)
        if path is None:
            return
        buf = io.BytesIO()
        np.save(buf, maps, allow_pickle=False)
        write_bytes(path, buf.getvalue())

    def _extract(self, descriptor, images: ImageSet, role: str) -> np.ndarray:
        desc = f"features {role} ({_extractor_text(descriptor)})"
        out = []
        with tqdm(total=len(images), desc=desc, unit="img", disable=not self.progress, leave=False) as bar:
            for chunk in _chunks(images):
                out.append(descriptor.local_features(chunk))
                bar.update(len(chunk))
        return np.concatenate(out, axis=0)


def _chunks(images: ImageSet):
    for start in range(0, len(images), _CHUNK):
        yield [images.load(i) for i in range(start, min(start + _CHUNK, len(images)))]


def _extractor_text(descriptor) -> str:
    s = dict(descriptor.extractor.settings)
    s.pop("weights", None)
    return ", ".join(f"{k}={v}" for k, v in s.items())


def _describe_set(descriptor, images: ImageSet, role: str, progress: bool) -> np.ndarray:
    out = []
    with tqdm(total=len(images), desc=f"describe {role}", unit="img", disable=not progress, leave=False) as bar:
        for chunk in _chunks(images):
            out.append(descriptor.describe(chunk))
            bar.update(len(chunk))
    return np.concatenate(out, axis=0)


# --------------------------------------------------------------------------------------------
# Evaluation of one backend
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class BackendResult:
    """The numbers of one backend: recall per k (mean and per vocabulary seed), size and speed."""

    label: str
    backend: str
    settings: dict               # the descriptor's own settings (identity), first seed
    dim: int
    recall: dict[int, float]     # mean over vocabulary seeds
    recall_per_seed: dict[int, list[float]]
    seeds: list[int]             # [] when the backend has no vocabulary
    sequence_per_seed: list[float] = field(default_factory=list)   # seq@1 per seed (--sequence)
    describe: Optional[Timing] = None          # describe() of one frame
    describe_thirds: Optional[Timing] = None   # describe_thirds() of one frame: full view + 3 thirds

    @property
    def bytes(self) -> int:
        return 4 * self.dim      # float32

    def to_dict(self) -> dict:
        out = {"label": self.label, "backend": self.backend, "settings": self.settings, "dim": self.dim,
               "bytes": self.bytes, "vocab_seeds": self.seeds,
               **_timing_dict("describe", self.describe), **_timing_dict("describe_thirds", self.describe_thirds)}
        for k in sorted(self.recall):
            out[f"recall_at_{k}"] = round(self.recall[k], 4)
            out[f"recall_at_{k}_per_seed"] = [round(v, 4) for v in self.recall_per_seed[k]]
        if self.sequence_per_seed:
            out["sequence_recall_at_1"] = round(float(np.mean(self.sequence_per_seed)), 4)
            out["sequence_recall_at_1_per_seed"] = [round(v, 4) for v in self.sequence_per_seed]
        return out


def _timing_dict(name: str, timing: Optional[Timing]) -> dict:
    if timing is None:
        return {f"{name}_ms": None, f"{name}_min_ms": None}
    return {f"{name}_ms": round(timing.median_ms, 2), f"{name}_min_ms": round(timing.min_ms, 2)}


def build_variants(spec: BackendSpec, seeds: Sequence[int]) -> list:
    """One descriptor per vocabulary seed for VLAD backends (unless the spec fixes ``seed``)."""
    first = make_descriptor(spec.name, **spec.settings)
    if not first.needs_fit or "seed" in spec.settings or "seed" not in getattr(first, "settings", {}):
        return [first]
    return [make_descriptor(spec.name, **{**spec.settings, "seed": int(s)}) for s in seeds]


def _seed_of(descriptor) -> Optional[int]:
    return getattr(descriptor, "settings", {}).get("seed") if descriptor.needs_fit else None


#: the filter over an image sequence: each image a separate look (weight 1), one place per image
SEQUENCE_BELIEF = BeliefConfig(weight=1.0)


def sequence_modes(query_desc: np.ndarray, ref_desc: np.ndarray, config: BeliefConfig = SEQUENCE_BELIEF) -> np.ndarray:
    """The belief filter's mode (a reference index) after each query image, in query order."""
    n = ref_desc.shape[0]
    if n < 7:
        raise VprInputError(f"--sequence needs at least 7 reference images to fit its likelihood, got {n}")
    chain = nx.path_graph(n, create_using=nx.DiGraph)
    try:
        model = SimilarityModel.from_references(ref_desc, chain, range(n), same_hops=1, far_hops=min(4, n // 2 - 1))
    except LikelihoodError as exc:
        raise VprInputError(f"--sequence needs references along a route: {exc}") from None
    belief = NodeBelief(chain, range(n), model, config=config)
    modes = np.empty(query_desc.shape[0], dtype=np.int64)
    for i, row in enumerate(query_desc @ ref_desc.T):
        if i:
            belief.move(1.0)
        belief.observe(row)
        modes[i] = belief.mode
    return modes


def sequence_recall(modes: np.ndarray, positives: np.ndarray) -> float:
    """Fraction of queries (with a correct reference) whose filter mode is correct."""
    has_match = positives.any(axis=1)
    return float(positives[np.arange(len(modes)), modes][has_match].mean())


def evaluate_backend(spec: BackendSpec, ref: ImageSet, query: ImageSet, positives: np.ndarray,
                     seeds: Sequence[int], store: FeatureStore, progress: bool = True,
                     sequence: bool = False) -> tuple[BackendResult, object]:
    """Recall of one backend (mean over seeds), and with ``sequence`` the belief filter's;
    returns the result and a fitted descriptor."""
    variants = build_variants(spec, seeds)
    fit_seeds = [_seed_of(d) for d in variants if d.needs_fit]
    per_seed: dict[int, list[float]] = {k: [] for k in RECALL_KS}
    sequence_per_seed: list[float] = []
    for descriptor in variants:
        ref_desc, query_desc = _descriptors(descriptor, ref, query, store, progress)
        for k, v in recall_at(query_desc @ ref_desc.T, positives).items():
            per_seed[k].append(v)
        if sequence:
            sequence_per_seed.append(sequence_recall(sequence_modes(query_desc, ref_desc), positives))
    first = variants[0]
    result = BackendResult(
        label=spec.label, backend=spec.name, settings=dict(first.identity.settings), dim=int(first.identity.dim),
        recall={k: float(np.mean(v)) for k, v in per_seed.items()}, recall_per_seed=per_seed,
        seeds=[int(s) for s in fit_seeds if s is not None], sequence_per_seed=sequence_per_seed)
    return result, first


def _descriptors(descriptor, ref: ImageSet, query: ImageSet, store: FeatureStore,
                 progress: bool) -> tuple[np.ndarray, np.ndarray]:
    if _has_dense_features(descriptor):
        ref_maps = store.maps(descriptor, ref, "reference")
        if descriptor.needs_fit:
            descriptor.fit_features(ref_maps)
        query_maps = store.maps(descriptor, query, "query")
        return descriptor.aggregate(ref_maps), descriptor.aggregate(query_maps)
    if descriptor.needs_fit:
        descriptor.fit([ref.load(i) for i in range(len(ref))])
    return _describe_set(descriptor, ref, "reference", progress), _describe_set(descriptor, query, "query", progress)


# --------------------------------------------------------------------------------------------
# Timing
# --------------------------------------------------------------------------------------------
def timing_frames(images: ImageSet, count: int, size: tuple[int, int]) -> list[np.ndarray]:
    """Up to ``count`` images spread over the set, resized to ``size`` (width, height) px."""
    picks = np.unique(np.linspace(0, len(images) - 1, num=min(count, len(images))).round().astype(int))
    return [cv2.resize(images.load(int(i)), size, interpolation=cv2.INTER_AREA) for i in picks]


@dataclass(frozen=True)
class Timing:
    """Milliseconds per frame at batch 1: the median, and the fastest call (on a CPU shared with
    other work the fastest is the better estimate of the uncontended cost)."""

    median_ms: float
    min_ms: float

    def text(self) -> str:
        return f"{self.median_ms:.1f} ({self.min_ms:.1f})"


def time_batch1(fn, frames: Sequence[np.ndarray]) -> Timing:
    """Time ``fn([frame])`` for each of ``frames`` after a warm-up."""
    for frame in frames[:_TIMING_WARMUP]:
        fn([frame])
    times = []
    for frame in frames:
        t0 = time.perf_counter()
        fn([frame])
        times.append((time.perf_counter() - t0) * 1000.0)
    return Timing(float(np.median(times)), float(np.min(times)))


def _set_threads(threads: int) -> None:
    from descriptors.inference import set_threads

    set_threads(threads)      # torch (when loaded) and ONNX Runtime sessions made from now on


# --------------------------------------------------------------------------------------------
# Command line
# --------------------------------------------------------------------------------------------
def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.description = (
        "Place recognition recall@1 / recall@5 of descriptor backends, a table per backend. Either two "
        "image folders of the same route matched by frame index (--ref, --query, --tolerance), or two "
        "recorded drives matched by true pose (--ref-recording, --query-recording, --tolerance-m, "
        "--tolerance-deg). VLAD vocabularies are fitted on the reference set, as a map fits on its own "
        "keyframes. Speed: describe and describe_thirds of one frame at batch 1.")
    g = parser.add_argument_group("image folders (match by frame index)")
    g.add_argument("--ref", type=Path, help="reference images, one per place, in name order")
    g.add_argument("--query", type=Path, help="query images of the same route, same count and order")
    g.add_argument("--tolerance", type=int, default=2,
                   help="query i is correct when the retrieved reference index is within +-N (default 2)")
    g = parser.add_argument_group("recorded drives (match by true pose)")
    g.add_argument("--ref-recording", type=Path, help="a simulator recording (robot.run --mode map --no-map)")
    g.add_argument("--query-recording", type=Path, help="a second drive of the same route (another appearance seed)")
    g.add_argument("--tolerance-m", type=float, default=1.0,
                   help="correct when the retrieved frame's true position is within M metres (default 1.0)")
    g.add_argument("--tolerance-deg", type=float, default=45.0,
                   help="... and its true heading within this many degrees (default 45)")
    g = parser.add_argument_group("backends and output")
    g.add_argument("--backend", action="append", metavar="NAME[:key=value,...]",
                   help="a descriptor backend with settings, repeatable, e.g. 'effnet-vlad:blocks=[10,13]' or "
                        "'anyloc-dinov2:weights=PATH' (default: effnet-vlad and the effnet-gap baseline)")
    g.add_argument("--vocab-seeds", default="0", metavar="LIST",
                   help="k-means seeds of VLAD vocabularies, comma-separated; recall is their mean (default 0)")
    g.add_argument("--sequence", action="store_true",
                   help="also score the belief filter over the query sequence (seq@1, see the top of this module)")
    g.add_argument("--json", type=Path, metavar="PATH", help="also write the numbers as JSON here")
    g.add_argument("--cache", type=Path, metavar="DIR",
                   help="keep extracted local features here and reuse them on later runs")
    g.add_argument("--timing-frames", type=int, default=20,
                   help="query frames timed at batch 1 per backend (default 20; 0 skips timing)")
    g.add_argument("--timing-size", default="320x240", metavar="WxH",
                   help="frames are resized to this before timing, as the camera delivers them (default 320x240)")
    g.add_argument("--threads", type=int, default=2,
                   help="inference threads, torch or ONNX Runtime (default 2, this CPU's cores)")
    g.add_argument("--cv2-threads", type=int, default=None, metavar="N",
                   help="OpenCV threads (default: OpenCV's own choice); 1 keeps OpenCV's idle pool from "
                        "competing with torch's threads on a small CPU")
    g.add_argument("--quiet", action="store_true", help="no progress bars")


@dataclass(frozen=True)
class Task:
    """What to compare: the two image sets, the ground truth and how it was defined."""

    ref: ImageSet
    query: ImageSet
    positives: np.ndarray
    match: dict


def _task(args: argparse.Namespace) -> Task:
    folders = args.ref is not None or args.query is not None
    recordings = args.ref_recording is not None or args.query_recording is not None
    if folders == recordings:
        raise VprInputError("give either --ref DIR and --query DIR (image folders) or --ref-recording DIR and "
                            "--query-recording DIR (recorded drives)")
    if folders:
        if args.ref is None or args.query is None:
            raise VprInputError("image folders need both --ref and --query")
        ref, query = _named("--ref", image_folder, args.ref), _named("--query", image_folder, args.query)
        positives = frame_positives(len(query), len(ref), args.tolerance)
        match = {"mode": "frame index", "tolerance_frames": args.tolerance}
    else:
        if args.ref_recording is None or args.query_recording is None:
            raise VprInputError("recorded drives need both --ref-recording and --query-recording")
        ref = _named("--ref-recording", recording_set, args.ref_recording)
        query = _named("--query-recording", recording_set, args.query_recording)
        positives = pose_positives(query.poses, ref.poses, args.tolerance_m, args.tolerance_deg)
        match = {"mode": "true pose", "tolerance_m": args.tolerance_m, "tolerance_deg": args.tolerance_deg}
    return Task(ref, query, positives, match)


def _named(option: str, load, folder):
    """``load(folder)``, its errors prefixed with the option that named the folder."""
    try:
        return load(folder)
    except VprInputError as exc:
        raise VprInputError(f"{option} {exc}") from None


def _parse_seeds(text: str) -> list[int]:
    try:
        seeds = [int(s) for s in text.split(",") if s.strip()]
    except ValueError:
        raise VprInputError(f"--vocab-seeds must be comma-separated integers, got {text!r}") from None
    if not seeds:
        raise VprInputError("--vocab-seeds needs at least one seed")
    return seeds


def _parse_size(text: str) -> tuple[int, int]:
    m = re.fullmatch(r"\s*(\d+)\s*[xX]\s*(\d+)\s*", text)
    if not m or min(int(m.group(1)), int(m.group(2))) < MIN_SIDE_PX:
        raise VprInputError(f"--timing-size must be WxH with sides >= {MIN_SIDE_PX} px, got {text!r}")
    return int(m.group(1)), int(m.group(2))


def _header(task: Task, seeds: list[int], timing: Optional[dict]) -> list[str]:
    evaluated = int(task.positives.any(axis=1).sum())
    m = task.match
    if m["mode"] == "frame index":
        rule = f"query i is correct when the retrieved reference index is within +-{m['tolerance_frames']}"
    else:
        rule = (f"a retrieved frame is correct within {m['tolerance_m']:g} m and {m['tolerance_deg']:g} deg "
                "of the query's true pose")
    lines = [f"reference: {task.ref.source} ({len(task.ref)} images)",
             f"query:     {task.query.source} ({len(task.query)} images)",
             f"match:     {rule}; {evaluated} of {len(task.query)} queries have a correct reference",
             f"vocabulary: VLAD backends fit their vocabulary on the reference images (as a map fits on its own "
             f"keyframes); k-means seeds {','.join(map(str, seeds))}, recall is the mean"]
    if timing:
        lines.append(f"timing:    ms per frame at batch 1, median (fastest) of {timing['frames']} query frames "
                     f"resized to {timing['width_px']}x{timing['height_px']}, {timing['threads']} torch threads, "
                     f"OPENBLAS_NUM_THREADS={timing['openblas_num_threads']}, {timing['cv2_threads']} OpenCV threads; "
                     "thirds = the frame and its Left/Middle/Right thirds")
    return lines


def format_table(results: Sequence[BackendResult]) -> str:
    """The per-backend table: recall@1, recall@5 (with the range over seeds), ms, size."""
    width = max([len("backend")] + [len(r.label) for r in results])
    sequence = any(r.sequence_per_seed for r in results)
    head = (f"{'backend':<{width}}  {'recall@1':<19}  {'recall@5':<19}  " + (f"{'seq@1':<19}  " if sequence else "")
            + f"{'describe ms':>13}  {'thirds ms':>13}  {'dim':>6}  {'bytes':>7}")
    rows = [head, "-" * len(head)]
    for r in results:
        seq = f"{_range_text(r.sequence_per_seed):<19}  " if sequence else ""
        rows.append(f"{r.label:<{width}}  {_recall_text(r, 1):<19}  {_recall_text(r, 5):<19}  {seq}"
                    f"{_ms(r.describe):>13}  {_ms(r.describe_thirds):>13}  {r.dim:>6}  {r.bytes:>7}")
    return "\n".join(rows)


def _recall_text(r: BackendResult, k: int) -> str:
    return _range_text(r.recall_per_seed[k])


def _range_text(values: Sequence[float]) -> str:
    """The mean, and the range over seeds when there are several."""
    if not values:
        return "-"
    text = f"{float(np.mean(values)):.3f}"
    if len(values) > 1:
        text += f" ({min(values):.3f}-{max(values):.3f})"
    return text


def _ms(timing: Optional[Timing]) -> str:
    return "-" if timing is None else timing.text()


def run(args: argparse.Namespace) -> tuple[Task, list[BackendResult], Optional[dict]]:
    """Evaluate every backend of ``args``; the pieces :func:`main` prints."""
    specs = [parse_backend(b) for b in (args.backend or DEFAULT_BACKENDS)]
    for spec in specs:        # an unknown backend or a bad setting is named before any work
        make_descriptor(spec.name, **spec.settings)
    try:
        check_output_file("--json", args.json)
        check_output_folder("--cache", args.cache)
    except UsageError as exc:
        raise VprInputError(str(exc)) from None
    seeds = _parse_seeds(args.vocab_seeds)
    size = _parse_size(args.timing_size)
    if args.timing_frames < 0 or args.threads < 1 or (args.cv2_threads is not None and args.cv2_threads < 0):
        raise VprInputError("--timing-frames must be >= 0, --threads >= 1 and --cv2-threads >= 0")
    if args.cv2_threads is not None:
        cv2.setNumThreads(args.cv2_threads)
    task = _task(args)
    progress = not args.quiet
    if any(spec.name != "tiny" for spec in specs):
        _set_threads(args.threads)
    store = FeatureStore(args.cache, progress)
    frames = timing_frames(task.query, args.timing_frames, size) if args.timing_frames else []
    # numpy's OpenBLAS threads spin after a matrix product and then fight torch's threads for the
    # same cores; the environment variable (read when numpy loads) is the only switch, so say it.
    timing = ({"frames": len(frames), "width_px": size[0], "height_px": size[1], "threads": args.threads,
               "openblas_num_threads": os.environ.get("OPENBLAS_NUM_THREADS", "unset"),
               "cv2_threads": cv2.getNumThreads()} if frames else None)
    results = []
    for spec in tqdm(specs, desc="backends", unit="backend", disable=not progress or len(specs) < 2):
        result, fitted = evaluate_backend(spec, task.ref, task.query, task.positives, seeds, store, progress,
                                          sequence=args.sequence)
        if frames:
            result = replace(result, describe=time_batch1(fitted.describe, frames),
                             describe_thirds=time_batch1(fitted.describe_thirds, frames))
        results.append(result)
    return task, results, timing


def main(args: argparse.Namespace) -> int:
    try:
        task, results, timing = run(args)
    except (VprInputError, DescriptorError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    seeds = _parse_seeds(args.vocab_seeds)
    print("\n".join(_header(task, seeds, timing)))
    print()
    print(format_table(results))
    if args.json is not None:
        payload = {"command": "vpr", "reference": str(task.ref.source), "query": str(task.query.source),
                   "reference_images": len(task.ref), "query_images": len(task.query),
                   "queries_evaluated": int(task.positives.any(axis=1).sum()), "match": task.match,
                   "vocabulary_fitted_on": "reference", "vocab_seeds": seeds, "timing": timing,
                   "backends": [r.to_dict() for r in results]}
        write_json(args.json, payload)
        print(f"\nwrote {args.json}")
    return 0
