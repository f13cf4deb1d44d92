"""The learned baseline's action classifier and its file.

**Inputs** (:func:`pair_inputs`): the features of the current view ``a`` and of the target
node's thumbnail ``b`` (:mod:`robot.baseline.features`: ``columns`` unit-length strips of one
block), concatenated as ``[a, b, cross]`` where ``cross`` is the ``columns x columns`` matrix
of cosine similarities between a's strips and b's strips: where the target's middle strip
reappears in the current view (left or right) is the steering cue. (Adding ``a*b`` made
validation accuracy slightly worse on hospital data: more inputs, same few thousand samples.)
Inputs are standardised with the training set's mean and standard deviation (kept in the model).

**Model** (:class:`ActionHead`): an MLP (one hidden ReLU layer with dropout) -> 3 logits in the
order of :data:`robot.baseline.expert.CLASSES` (left, forward, right).

**File** (:func:`save_head` / :func:`load_head`): one ``torch.save`` file holding a plain dict:
a format tag and version, the feature settings, the classes, the layer sizes, the state dict
(tensors only) and JSON-able training statistics; read back with ``weights_only=True``, so
loading never runs code from the file. Written atomically (temporary file, fsync, rename).
Every problem raises :class:`BaselineFileError` naming the file.
"""

from __future__ import annotations

import io
from dataclasses import dataclass, field
from pathlib import Path
from typing import Mapping, Optional, Union

import numpy as np
import torch
from torch import nn

from controllers.actions import Action
from core.atomic import write_bytes
from robot.baseline.expert import CLASSES
from robot.baseline.features import FeatureError, FeatureSettings

FILE_FORMAT = "sptm-action-head"
FILE_VERSION = 1


class BaselineFileError(ValueError):
    """A trained-head file is missing, unreadable, not a head file, or does not fit; names the file."""


def input_dim(settings: FeatureSettings) -> int:
    """Length of one classifier input for these feature settings."""
    return 2 * settings.dim + settings.columns ** 2


def pair_inputs(current: np.ndarray, target: np.ndarray, settings: FeatureSettings) -> np.ndarray:
    """Classifier inputs of (N, dim) current-view features and (N, dim) target features: (N, input_dim)."""
    a = np.asarray(current, dtype=np.float32)
    b = np.asarray(target, dtype=np.float32)
    if a.ndim != 2 or a.shape != b.shape or a.shape[1] != settings.dim:
        raise FeatureError(f"pair_inputs needs two (N, {settings.dim}) feature arrays, got {a.shape} and {b.shape}")
    cols, ch = settings.columns, settings.channels
    cross = np.einsum("nic,njc->nij", a.reshape(-1, cols, ch), b.reshape(-1, cols, ch)).reshape(len(a), -1)
    return np.concatenate([a, b, cross], axis=1).astype(np.float32)


class ActionHead(nn.Module):
    """Standardise -> Linear -> ReLU -> Dropout -> Linear: inputs (N, in_dim) to (N, 3) logits."""

    def __init__(self, in_dim: int, hidden: int = 128, dropout: float = 0.3, n_classes: int = len(CLASSES)):
        super().__init__()
        self.in_dim, self.hidden, self.dropout, self.n_classes = int(in_dim), int(hidden), float(dropout), int(n_classes)
        self.register_buffer("input_mean", torch.zeros(self.in_dim))
        self.register_buffer("input_std", torch.ones(self.in_dim))
        self.net = nn.Sequential(nn.Linear(self.in_dim, self.hidden), nn.ReLU(), nn.Dropout(self.dropout),
                                 nn.Linear(self.hidden, self.n_classes))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.net((x - self.input_mean) / self.input_std)

    @torch.inference_mode()
    def predict(self, inputs: np.ndarray) -> np.ndarray:
        """Class indices (N,) of inputs (N, in_dim), in eval mode."""
        was_training = self.training
        self.eval()
        logits = self(torch.from_numpy(np.ascontiguousarray(inputs, dtype=np.float32)))
        self.train(was_training)
        return logits.argmax(dim=1).numpy()


@dataclass
class TrainedHead:
    """A trained classifier with everything needed to use it again (see the module docstring)."""

    model: ActionHead
    feature_settings: FeatureSettings
    classes: tuple[Action, ...] = CLASSES
    stats: dict = field(default_factory=dict)       # JSON-able: data sizes, accuracies, seed, wall time

    def predict(self, current: np.ndarray, target: np.ndarray) -> list[Action]:
        """Actions for (N, dim) current-view and target features."""
        idx = self.model.predict(pair_inputs(current, target, self.feature_settings))
        return [self.classes[int(k)] for k in idx]


def _atomic_write(path: Path, payload: dict) -> None:
    buf = io.BytesIO()
    torch.save(payload, buf)
    write_bytes(path, buf.getvalue())


def save_head(path: Union[str, Path], head: TrainedHead) -> Path:
    """Write ``head`` to ``path`` atomically (a crash leaves the old file or the new one); returns the path."""
    path = Path(path)
    model = head.model
    payload = {
        "format": FILE_FORMAT,
        "version": FILE_VERSION,
        "feature_settings": head.feature_settings.to_dict(),
        "classes": [a.value for a in head.classes],
        "layers": {"in_dim": model.in_dim, "hidden": model.hidden, "dropout": model.dropout,
                   "n_classes": model.n_classes},
        "state_dict": {k: v.detach().cpu().clone() for k, v in model.state_dict().items()},
        "stats": dict(head.stats),
    }
    _atomic_write(path, payload)
    return path


def _require(data: Mapping, key: str, kind, where: str):
    if key not in data:
        raise BaselineFileError(f"{where}: no {key!r} entry (not a complete trained-head file)")
    value = data[key]
    if not isinstance(value, kind):
        raise BaselineFileError(f"{where}: entry {key!r} is a {type(value).__name__}, expected {kind}")
    return value


def load_head(path: Union[str, Path], expect_features: Optional[FeatureSettings] = None) -> TrainedHead:
    """Read a head written by :func:`save_head`, in eval mode.

    ``expect_features``: the feature settings the caller will compute; a head trained on other
    features is refused. Raises :class:`BaselineFileError` naming the file when it is missing,
    unreadable (truncated, corrupt, not a torch file), of another format or a newer version, or
    its contents do not fit together.
    """
    path = Path(path)
    where = f"trained baseline head {path}"
    if not path.is_file():
        raise BaselineFileError(f"{where}: no such file (train one with: python -m robot.bench baseline --map DIR "
                                f"--out {path})")
    try:
        data = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:   # torch raises many types for damaged files; all mean "unreadable"
        raise BaselineFileError(f"{where}: cannot read it ({type(exc).__name__}: {str(exc).splitlines()[0][:200]}); "
                                "the file is damaged or not a trained head") from None
    if not isinstance(data, dict) or data.get("format") != FILE_FORMAT:
        raise BaselineFileError(f"{where}: not a trained-head file (format tag {FILE_FORMAT!r} missing)")
    version = _require(data, "version", int, where)
    if version > FILE_VERSION:
        raise BaselineFileError(f"{where}: file version {version} is newer than this code reads ({FILE_VERSION})")
    try:
        settings = FeatureSettings.from_dict(_require(data, "feature_settings", dict, where))
    except (FeatureError, TypeError) as exc:
        raise BaselineFileError(f"{where}: bad feature settings: {exc}") from None
    if expect_features is not None and settings != expect_features:
        raise BaselineFileError(f"{where}: trained on features {settings.to_dict()}, but the caller computes "
                                f"{expect_features.to_dict()}; train a head for these features")
    try:
        classes = tuple(Action(v) for v in _require(data, "classes", list, where))
    except ValueError as exc:
        raise BaselineFileError(f"{where}: bad class list: {exc}") from None
    if classes != CLASSES:
        raise BaselineFileError(f"{where}: classes {[a.value for a in classes]} differ from "
                                f"{[a.value for a in CLASSES]}")
    layers = _require(data, "layers", dict, where)
    try:
        model = ActionHead(layers["in_dim"], layers["hidden"], layers["dropout"], layers["n_classes"])
    except (KeyError, TypeError, ValueError, RuntimeError) as exc:
        raise BaselineFileError(f"{where}: bad layer sizes {layers}: {exc}") from None
    if model.in_dim != input_dim(settings) or model.n_classes != len(CLASSES):
        raise BaselineFileError(f"{where}: layer sizes {layers} do not fit the feature settings "
                                f"(input {input_dim(settings)}, {len(CLASSES)} classes)")
    try:
        model.load_state_dict(_require(data, "state_dict", dict, where), strict=True)
    except RuntimeError as exc:
        raise BaselineFileError(f"{where}: weights do not fit the layers: {str(exc).splitlines()[0]}") from None
    if not all(torch.isfinite(v).all() for v in model.state_dict().values()):
        raise BaselineFileError(f"{where}: weights hold NaN or infinite values")
    stats = data.get("stats", {})
    return TrainedHead(model=model.eval(), feature_settings=settings, classes=classes,
                       stats=dict(stats) if isinstance(stats, dict) else {})


__all__ = ["ActionHead", "BaselineFileError", "FILE_FORMAT", "FILE_VERSION", "TrainedHead", "input_dim",
           "load_head", "pair_inputs", "save_head"]
