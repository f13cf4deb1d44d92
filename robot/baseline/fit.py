"""Training the learned baseline's action classifier on the expert's samples.

Samples of every ``validation_every``-th exploration drive are held out (whole drives, see
:meth:`robot.baseline.exploration.ExpertData.validation_mask`); the head is fitted on the rest
with Adam, a cross-entropy loss whose class weights are ``(1 / frequency) ** class_weight_power``
(0.5: halfway between plain and balanced, so the rarer class is not drowned without trading
away overall accuracy), fixed epochs and a fixed seed on the CPU. With ``mirror`` every
training sample is also used left-right mirrored (both images' strips reversed,
:func:`robot.baseline.features.mirror_features`, LEFT and RIGHT swapped): a walkthrough driven
counter-clockwise turns left at every corner, and without mirroring the classifier learns that
bias instead of the view geometry (on hospital data: validation accuracy 0.70 -> 0.75). Training
is deterministic for a seed (torch's global generator is left as it was).

Settings chosen on hospital data (40 drives, 5286 samples, 985 held out): hidden 128, weight
decay 1e-2, dropout 0.3, 40 epochs gave 0.75 validation accuracy; the inputs ``[a, b, cross]``
beat ``cross`` alone (0.66) and ``[a, b, a*b, cross]`` (0.73); differences of 0.03 are noise.

The statistics (:func:`accuracy_stats`) report, for the training and validation samples, the
overall accuracy, the accuracy per class (recall), and the majority-class rate to beat.
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass
from typing import Mapping, Optional, Sequence

import numpy as np
import torch
from torch import nn

from controllers.actions import Action
from core.validate import check_at_least, check_bool, check_count, check_range
from robot.baseline.expert import CLASSES
from robot.baseline.exploration import ExpertData
from robot.baseline.features import mirror_features
from robot.baseline.head import ActionHead, TrainedHead, input_dim, pair_inputs


class TrainingError(ValueError):
    """Training cannot run: no samples, a target node without features, bad settings."""


@dataclass(frozen=True)
class TrainConfig:
    """Classifier size and optimisation settings."""

    hidden: int = 128                  # hidden units of the MLP
    dropout: float = 0.3               # dropout after the hidden layer (few thousand samples, ~0.4M weights)
    epochs: int = 40                   # passes over the training samples
    batch_size: int = 128
    learning_rate: float = 1e-3        # Adam
    weight_decay: float = 1e-2         # L2 on the weights (Adam's coupled decay); 1e-3 overfits more
    class_weight_power: float = 0.5    # loss weight of a class ~ (1 / its frequency) ** power
    validation_every: int = 5          # every n-th exploration drive is held out (0: none)
    mirror: bool = True                # also train on every sample mirrored left-right (see the module docstring)

    def __post_init__(self) -> None:
        for name in ("hidden", "epochs", "batch_size"):
            check_count(f"training {name}", getattr(self, name), 1, error=TrainingError)
        if isinstance(self.validation_every, bool) or not isinstance(self.validation_every, int) \
                or self.validation_every < 0 or self.validation_every == 1:
            raise TrainingError(f"training validation_every must be 0 (none) or an integer >= 2, "
                                f"got {self.validation_every!r}")
        check_range("training dropout", self.dropout, 0.0, 1.0, high_open=True, error=TrainingError)
        check_bool("training mirror", self.mirror, error=TrainingError)
        for name in ("learning_rate", "weight_decay", "class_weight_power"):
            check_at_least(f"training {name}", getattr(self, name), 0.0, error=TrainingError)


def sample_features(data: ExpertData, node_ids: Sequence[int], node_feats: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(current, target) features of every sample: its frame's and its target node's, (S, dim) each."""
    row = {int(n): k for k, n in enumerate(node_ids)}
    missing = sorted({int(n) for n in data.sample_node.tolist()} - set(row))
    if missing:
        raise TrainingError(f"target node(s) {missing[:5]} have no thumbnail features (another map?)")
    target = np.asarray(node_feats, dtype=np.float32)[[row[int(n)] for n in data.sample_node]]
    return data.frame_features[data.sample_frame], target


#: class index of the mirrored label: LEFT <-> RIGHT, FORWARD stays
MIRRORED_CLASS = np.array([CLASSES.index({Action.LEFT: Action.RIGHT, Action.RIGHT: Action.LEFT}.get(a, a))
                           for a in CLASSES])


def accuracy_stats(labels: np.ndarray, predicted: np.ndarray) -> Optional[dict]:
    """Accuracy, accuracy per class (recall) and majority-class rate; None without samples."""
    labels, predicted = np.asarray(labels), np.asarray(predicted)
    if labels.size == 0:
        return None
    counts = np.bincount(labels, minlength=len(CLASSES))
    per_class = {a.value: (float(np.mean(predicted[labels == k] == k)) if counts[k] else None)
                 for k, a in enumerate(CLASSES)}
    return {"samples": int(labels.size), "accuracy": float(np.mean(predicted == labels)),
            "per_class": per_class, "counts": {a.value: int(counts[k]) for k, a in enumerate(CLASSES)},
            "majority_rate": float(counts.max() / labels.size),
            "majority_class": CLASSES[int(np.argmax(counts))].value}


def _class_weights(labels: np.ndarray, power: float) -> torch.Tensor:
    counts = np.bincount(labels, minlength=len(CLASSES)).astype(np.float64)
    freq = np.where(counts > 0, counts / counts.sum(), 1.0)
    w = (1.0 / freq) ** power
    w = w / np.sum(w * np.where(counts > 0, freq, 0.0))    # mean weight per sample = 1
    return torch.tensor(w, dtype=torch.float32)


def train_head(data: ExpertData, node_ids: Sequence[int], node_feats: np.ndarray, *,
               config: TrainConfig = TrainConfig(), seed: int = 0,
               extra_stats: Optional[Mapping] = None) -> TrainedHead:
    """Fit an :class:`ActionHead` on ``data`` (targets' features: ``node_feats`` rows in
    ``node_ids`` order); returns it in eval mode with its statistics."""
    if data.n_samples == 0:
        raise TrainingError("no expert samples to train on")
    started = time.perf_counter()
    settings = data.feature_settings
    current, target = sample_features(data, node_ids, node_feats)
    x_all = pair_inputs(current, target, settings)
    y_all = data.sample_label.astype(np.int64)
    val = data.validation_mask(config.validation_every) if config.validation_every else np.zeros(len(y_all), bool)
    if not np.any(~val):
        raise TrainingError(f"every sample is held out for validation ({data.episodes} drives, validation_every "
                            f"{config.validation_every}); collect more drives")
    x_train, y_train = x_all[~val], y_all[~val]
    if config.mirror:
        mirrored = pair_inputs(mirror_features(current[~val], settings), mirror_features(target[~val], settings),
                               settings)
        x_train = np.concatenate([x_train, mirrored])
        y_train = np.concatenate([y_train, MIRRORED_CLASS[y_train]])

    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(int(seed))
        model = ActionHead(input_dim(data.feature_settings), config.hidden, config.dropout)
        model.input_mean.copy_(torch.from_numpy(x_train.mean(axis=0)))
        model.input_std.copy_(torch.from_numpy(x_train.std(axis=0) + 1e-3))   # constant inputs stay finite
        optimiser = torch.optim.Adam(model.parameters(), lr=config.learning_rate, weight_decay=config.weight_decay)
        loss_fn = nn.CrossEntropyLoss(weight=_class_weights(y_train, config.class_weight_power))
        xt, yt = torch.from_numpy(x_train), torch.from_numpy(y_train)
        order = torch.Generator().manual_seed(int(seed))
        model.train()
        losses = []
        for _ in range(config.epochs):
            perm = torch.randperm(len(yt), generator=order)
            total = 0.0
            for start in range(0, len(perm), config.batch_size):
                idx = perm[start:start + config.batch_size]
                optimiser.zero_grad()
                loss = loss_fn(model(xt[idx]), yt[idx])
                loss.backward()
                optimiser.step()
                total += float(loss.detach()) * len(idx)
            losses.append(total / len(yt))
    model.eval()
    predicted = model.predict(x_all)
    stats = {
        "seed": int(seed), "train_config": asdict(config),
        "frames": data.n_frames, "samples": data.n_samples, "drives": data.episodes,
        "appearance_seeds": list(data.appearance_seeds),
        "train": accuracy_stats(y_all[~val], predicted[~val]),
        "validation": accuracy_stats(y_all[val], predicted[val]),
        "final_loss": losses[-1], "train_seconds": time.perf_counter() - started,
        **dict(extra_stats or {}),
    }
    return TrainedHead(model=model, feature_settings=data.feature_settings, classes=CLASSES, stats=stats)
