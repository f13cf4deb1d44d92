"""The SPTM-style learned action policy: the navigator's voter replaced by a classifier.

Plugs into :func:`robot.episode.loop.run_episode` (and ``robot.episode.sim.run_sim_navigation``)
as ``action_policy``: localisation, planning and node switching stay the navigator's; each tick
the classifier looks at the camera frame and the target node's thumbnail and says LEFT,
FORWARD or RIGHT. Every node thumbnail is described once when the policy is built; a frame is
described once per tick (in :meth:`SptmPolicy.for_frame`), and the classifier runs only for
the target the navigator asks about.
"""

from __future__ import annotations

from typing import Callable, Optional

import numpy as np

from controllers.actions import Action
from maps.graph import MapError
from maps.store import LoadedMap
from robot.baseline.features import ImageFeatures, node_features
from robot.baseline.head import TrainedHead


class SptmPolicy:
    """``robot.episode.loop.ActionPolicy`` backed by a :class:`robot.baseline.head.TrainedHead`.

    ``features``: the feature extractor (default: one built from the head's feature settings;
    pass one to share its loaded network). Works with any map, of any world: the head sees only
    images, so a head trained in one world can be tested in another.
    """

    name = "sptm"

    def __init__(self, head: TrainedHead, loaded_map: LoadedMap, features: Optional[ImageFeatures] = None):
        if features is None:
            features = ImageFeatures(head.feature_settings)
        elif features.settings != head.feature_settings:
            raise ValueError(f"the feature extractor's settings {features.settings.to_dict()} differ from the "
                             f"head's {head.feature_settings.to_dict()}")
        self.head = head
        self.features = features
        self.node_ids = [int(n) for n in loaded_map.topomap.node_ids.tolist()]
        self._row = {n: k for k, n in enumerate(self.node_ids)}
        self.node_features = node_features(loaded_map, features, self.node_ids)
        self.map_path = loaded_map.path

    def for_frame(self, rgb: np.ndarray) -> Callable[[int], Action]:
        """Describe ``rgb`` once; return ``choose(target_node) -> Action`` for this frame."""
        current = self.features.of_frames([rgb])
        chosen: dict[int, Action] = {}

        def choose(node_id: int) -> Action:
            node = int(node_id)
            if node not in chosen:
                if node not in self._row:
                    raise MapError(f"map {self.map_path}: the policy was asked about node {node}, "
                                   "which the map does not have")
                target = self.node_features[self._row[node]][None, :]
                chosen[node] = self.head.predict(current, target)[0]
            return chosen[node]

        return choose
