"""How an episode is set up around the navigator: the ``episode`` section of the stack config."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Optional

from controllers.config import NavigationConfig
from core.validate import check_at_least, check_bool, check_count


@dataclass(frozen=True)
class EpisodeConfig:
    """How an episode is set up around the navigator (the ``episode`` section of the stack config).

    Thresholds: with ``thresholds_from_map`` (default) they are derived from the map's own
    statistics by :func:`robot.episode.setup.derive_thresholds`; otherwise
    ``NavigationConfig.thresholds`` is used as written. Step budget: ``min_steps`` plus ``budget_factor`` times the ticks needed to drive
    the route's shortest length at the forward speed; ``default_max_steps`` when the length is
    unknown (a goal node or image without a route).
    """

    #: derive t_milestone, t_change_node, t_lost and t_limited_control from the map (default);
    #: false: use navigation.thresholds as written
    thresholds_from_map: bool = True
    #: the step budget allows this many times the time needed to drive the route at forward speed
    budget_factor: float = 3.0
    #: plus this many ticks for localisation turns and searches
    min_steps: int = 600
    #: the budget when the route length is unknown (10 minutes at 10 Hz)
    default_max_steps: int = 6000
    #: the voter sees each third's similarity to the target as a contrast against the other
    #: nodes (controllers.voter.contrast_thirds: 1 = the node this third resembles most,
    #: 0 = a typical node) instead of the raw cosine, so votes survive lighting changes that
    #: lower every cosine; t_limited_control is then on that scale (navigation.threshold_fractions.control_contrast)
    thirds_contrast: bool = True

    def __post_init__(self) -> None:
        for name in ("thresholds_from_map", "thirds_contrast"):
            check_bool(name, getattr(self, name))
        check_at_least("budget_factor", self.budget_factor, 1.0)
        for name in ("min_steps", "default_max_steps"):
            check_count(name, getattr(self, name), 1)


def step_budget(config: EpisodeConfig, navigation: NavigationConfig, control_period_s: float,
                route_length_m: Optional[float] = None) -> int:
    """The episode's step budget (control ticks); see :class:`EpisodeConfig`."""
    if route_length_m is None:
        return config.default_max_steps
    drive_ticks = route_length_m / navigation.speeds.forward.v_mps / control_period_s
    return config.min_steps + int(math.ceil(config.budget_factor * drive_ticks))
