"""Where an episode went wrong: its step log read against the map's true node poses.

A step log (``--step-logs``, or ``python -m robot.bench replay``) holds the robot's true pose and
the navigator's current node at every step; a map built in simulation holds every node's true
pose. Together they tell, without looking at pictures, whether each node the navigator
*confirmed* (localised at, or reached by driving) was really where the robot stood:

* a **confirmation** is a step where the navigator took a node as where the robot is: the
  first step after (re-)localisation, or a step where the current node changed while navigating;
* a confirmation is **wrong** when the robot stood more than ``FAR_M`` (3 m) from the node's
  true pose, or more than ``NEAR_M`` (1 m) from it facing more than ``TURNED_DEG`` (30 deg) away
  from the way the node's view looks: place recognition accepted a look-alike. A view from a
  metre or two back along the node's heading shows the node's scene, so distance alone is not
  an error (the median confirmation in run 4 was 0.5 m from its node, the 95th percentile 3.1 m);
  of run 4's confirmations within 1 m, 99 % faced within 29 deg of the node's heading;
* a **lost** event is a step where navigating turned into re-localising;
* a **pinned** stretch is at least ``PINNED_STEPS`` (20) consecutive steps that commanded motion
  while the robot's true pose stayed within ``PINNED_M`` (3 cm) and ``PINNED_DEG`` (5 deg) of
  where the stretch began: pressed against a wall or a shelf, its wheels blocked, whatever the
  navigator believed (a free robot covers 16 cm or turns 57 deg in 20 steps of its slowest
  moving action);
* a **collision** is a step at which the simulator's count of new contacts with walls and props
  (the log's ``collisions``, since the episode began) went up; each is told by what the robot
  was commanded then: turning in place (a search), driving, backing off, retracing (driving the
  way just come backwards before a turn in place) or standing;
* **driving on by odometry** (``supervisor.odometry_max_m``): the steps at which the views
  matched nothing and the supervisor drove on by the map's arc lengths, and the nodes it took
  as reached so (the log's ``odometry``; logs written before that field count none);
* where the log has the belief over the map (``belief_top``), the belief's mode is judged by the
  same rule at every step and at every confirmation: how often the belief would have placed the
  robot right where the navigator's single look did or did not; the same for the nodes reached
  by odometry, where the belief's mode is the alternative to the map's arc lengths.

:func:`diagnose` gives all of them and a one-line :meth:`Diagnosis.summary` (the first wrong
confirmation and the first lost event) for the paper report's failed episodes; the report also
counts wrong confirmations over all episodes of a route and method, a measure of how often place
recognition erred in the loop.
"""

from __future__ import annotations

import json
import math
import statistics
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Iterable, Mapping, Optional, Sequence

#: A confirmation counts as a wrong place farther than ``FAR_M`` from its node, or farther than
#: ``NEAR_M`` and facing more than ``TURNED_DEG`` away from the node's heading (module docstring).
FAR_M = 3.0
NEAR_M = 1.0
TURNED_DEG = 30.0
#: A pinned stretch: this many steps commanding motion, the true pose within PINNED_M and PINNED_DEG.
PINNED_STEPS = 20
PINNED_M = 0.03
PINNED_DEG = 5.0
#: the step log's actions that command no motion
_STILL = ("none", "stop")
#: the belief counts as confident from this mass near its mode (``navigation.belief.confidence``)
CONFIDENT = 0.6

_LOCALISING = ("localising", "relocalising")
_ON_THE_WAY = ("navigating", "turning", "recovering", "searching", "arrived")


class StepLogError(ValueError):
    """A step log that cannot be read (the message names the file and line)."""


@dataclass(frozen=True)
class Confirmation:
    """One node the navigator took as where the robot stood."""

    step: int
    node: object
    kind: str                  # "localised" (after a (re-)localisation) or "reached" (by driving)
    x_m: float                 # the robot's true position then
    y_m: float
    distance_m: float          # from the node's true position
    node_x_m: float            # the node's true position
    node_y_m: float
    heading_error_deg: float   # the robot's true yaw minus the node's (wrapped to [-180, 180))
    belief_node: object = None           # the belief's mode at that step (None: no belief in the log)
    belief_wrong: Optional[bool] = None  # the mode judged by the same rule
    by_odometry: bool = False            # reached by driving on by odometry (the log's ``odometry``)

    def is_wrong(self, far_m: float = FAR_M, near_m: float = NEAR_M, turned_deg: float = TURNED_DEG) -> bool:
        return wrong_place(self.distance_m, self.heading_error_deg, far_m, near_m, turned_deg)


def wrong_place(distance_m: float, heading_error_deg: float, far_m: float = FAR_M, near_m: float = NEAR_M,
                turned_deg: float = TURNED_DEG) -> bool:
    """The rule of the module docstring: too far from the node, or off it and facing away."""
    return distance_m > far_m or (distance_m > near_m and abs(heading_error_deg) > turned_deg)


def placement(step: Mapping, node, poses: Mapping) -> tuple[float, float]:
    """The robot's distance from the node's true pose and its heading error (degrees)."""
    if node not in poses:
        raise KeyError(f"node {node!r} of the step log is not a node of the map")
    x, y, yaw = poses[node]
    error = math.degrees(math.remainder(math.radians(float(step["yaw_deg"])) - yaw, 2 * math.pi))
    return (round(math.hypot(float(step["x_m"]) - x, float(step["y_m"]) - y), 3),
            round(error if error < 180.0 else error - 360.0, 1))


@dataclass(frozen=True)
class LostEvent:
    step: int
    x_m: float
    y_m: float
    current_node: object
    target_node: object


@dataclass(frozen=True)
class PinnedStretch:
    step: int                  # its first step
    steps: int                 # how many steps it lasted
    x_m: float                 # where the robot stood (true position)
    y_m: float


@dataclass(frozen=True)
class CollisionOnset:
    step: int
    count: int                 # new contacts at this step
    state: str
    action: str
    x_m: float                 # the robot's true position
    y_m: float

    @property
    def doing(self) -> str:
        """What the robot was commanded: "turning in place", "backing off", "retracing", "standing" or
        "driving"."""
        return _DOING.get(self.action, "driving")


_DOING = {"search_rotate": "turning in place", "backward": "backing off", "retrace": "retracing", "none": "standing",
          "stop": "standing"}


@dataclass(frozen=True)
class Diagnosis:
    confirmations: tuple[Confirmation, ...]
    lost: tuple[LostEvent, ...]
    goal_node: object = None
    goal_node_error_m: Optional[float] = None   # the goal node's true position from the true goal
    belief_steps: int = 0                       # steps with a belief in the log
    belief_right: int = 0                       # ... whose mode was at the right place
    belief_confident: int = 0                   # ... whose confidence reached CONFIDENT
    belief_confident_right: int = 0
    pinned: tuple[PinnedStretch, ...] = ()
    collisions: tuple[CollisionOnset, ...] = ()
    odometry_steps: int = 0                     # steps driven on by odometry (views matching nothing)
    odometry_nodes: int = 0                     # ... of them, nodes taken as reached by odometry
    odometry_judged: bool = False               # its confirmations mark the nodes reached by odometry
                                                # (records written before they did: unknown, not right)

    def to_dict(self) -> dict:
        """Plain lists and scalars for an episode's JSON record (:meth:`from_dict` reads it back)."""
        return asdict(self)

    @classmethod
    def from_dict(cls, data: Mapping) -> "Diagnosis":
        """The diagnosis :meth:`to_dict` wrote; raises ``KeyError`` / ``TypeError`` on another mapping."""
        parts = {"confirmations": Confirmation, "lost": LostEvent, "pinned": PinnedStretch,
                 "collisions": CollisionOnset}
        return cls(**{key: tuple(parts[key](**item) for item in value) if key in parts else value
                      for key, value in data.items()})

    def collisions_by_doing(self) -> dict:
        """``{"turning in place": 7, "driving": 2}``: the collisions by what the robot was doing."""
        counts: dict = {}
        for c in self.collisions:
            counts[c.doing] = counts.get(c.doing, 0) + c.count
        return counts

    @property
    def pinned_steps(self) -> int:
        """Steps spent pinned (:class:`PinnedStretch`), over the episode."""
        return sum(p.steps for p in self.pinned)

    @property
    def wrong(self) -> tuple[Confirmation, ...]:
        """The confirmations at a wrong place (:meth:`Confirmation.is_wrong`)."""
        return tuple(c for c in self.confirmations if c.is_wrong())

    def belief_summary(self) -> Optional[str]:
        """``"belief: mode at the right place at 812 of 1000 steps; confident at 600, right at 590 of
        them; at the 3 (re-)localisations the navigator was wrong at 1, the belief at 0"`` (None: no
        belief in the log)."""
        if not self.belief_steps:
            return None
        localised = [c for c in self.confirmations if c.kind == "localised" and c.belief_wrong is not None]
        return (f"belief: mode at the right place at {self.belief_right} of {self.belief_steps} steps; confident at "
                f"{self.belief_confident}, right at {self.belief_confident_right} of them; at the {len(localised)} "
                f"(re-)localisations the navigator was wrong at {sum(c.is_wrong() for c in localised)}, the belief at "
                f"{sum(bool(c.belief_wrong) for c in localised)}")

    def summary(self) -> str:
        """``"first wrong place: step 1665, node 26 reached 1.7 m from it at (11.5, 7.7); first
        lost: step 1685 at (11.4, 7.7), 26 -> 27"`` (or what of it happened)."""
        parts = []
        if self.goal_node_error_m is not None and self.goal_node_error_m > FAR_M:
            parts.append(f"the goal image matched node {self.goal_node}, {self.goal_node_error_m:.1f} m from the goal")
        wrong = self.wrong
        if wrong:
            c = wrong[0]
            parts.append(f"first wrong place: step {c.step}, node {c.node} {c.kind} {c.distance_m:.1f} m from it "
                         f"at ({c.x_m:.1f}, {c.y_m:.1f}), heading {c.heading_error_deg:+.0f} deg off")
        else:
            parts.append("every node confirmed at its place")
        if self.lost:
            e = self.lost[0]
            parts.append(f"first lost: step {e.step} at ({e.x_m:.1f}, {e.y_m:.1f}), "
                         f"{e.current_node} -> {e.target_node}")
        if self.pinned:
            p = max(self.pinned, key=lambda q: q.steps)
            parts.append(f"pinned for {self.pinned_steps} steps in {len(self.pinned)} stretch(es), the longest "
                         f"{p.steps} from step {p.step} at ({p.x_m:.1f}, {p.y_m:.1f})")
        if self.odometry_steps:
            parts.append(f"drove on by odometry for {self.odometry_steps} steps, {self.odometry_nodes} node(s) "
                         "reached so")
        if self.collisions:
            by = sorted(self.collisions_by_doing().items(), key=lambda kv: -kv[1])
            parts.append(f"{sum(n for _, n in by)} collisions: " + ", ".join(f"{n} {doing}" for doing, n in by))
        return "; ".join(parts)


def node_poses(manifest: Mapping) -> Optional[dict]:
    """``{node id: (x_m, y_m, yaw_rad)}`` from a map manifest, or None when a node has no true
    pose (a map built from a video or a real drive)."""
    poses = {}
    for n in manifest.get("nodes", []):
        p = n.get("true_pose")
        if not isinstance(p, Mapping) or not all(isinstance(p.get(k), (int, float)) for k in ("x_m", "y_m", "yaw_rad")):
            return None
        poses[n["id"]] = (float(p["x_m"]), float(p["y_m"]), float(p["yaw_rad"]))
    return poses or None


def map_node_poses(map_dir: Path) -> Optional[dict]:
    """:func:`node_poses` of the map in ``map_dir`` (None when it has none or no manifest)."""
    try:
        manifest = json.loads((Path(map_dir) / "manifest.json").read_text(encoding="utf-8"))
    except (OSError, json.JSONDecodeError):
        return None
    return node_poses(manifest)


_FIELDS = ("step", "x_m", "y_m", "yaw_deg", "state", "current_node", "target_node")


def read_step_log(path: Path) -> list[dict]:
    """The steps of a step log (JSON lines); raises :class:`StepLogError` naming the file and line."""
    steps = []
    try:
        with open(path, encoding="utf-8") as f:
            for number, line in enumerate(f, 1):
                try:
                    entry = json.loads(line)
                except json.JSONDecodeError as exc:
                    raise StepLogError(f"{path}: line {number} is not JSON ({exc.msg})") from None
                missing = [k for k in _FIELDS if not isinstance(entry, dict) or k not in entry]
                if missing:
                    raise StepLogError(f"{path}: line {number} has no {', '.join(missing)} (not a step log?)")
                steps.append(entry)
    except OSError as exc:
        raise StepLogError(f"{path}: cannot read the step log ({exc.strerror or exc})") from None
    return steps


def route_goal(spec, route: str, goal_node) -> Optional[tuple]:
    """``(goal node, (x_m, y_m) of the route's true goal)`` for :func:`diagnose`, or None when the
    world spec (``spec``, a :class:`sim.world_spec.WorldSpec` or None) has no evaluation route
    ``route`` or the episode placed no goal node."""
    found = None if spec is None else spec.routes.evaluation.get(route)
    if found is None or goal_node is None:
        return None
    return goal_node, (float(found.goal[0]), float(found.goal[1]))


def pinned_stretches(steps: Sequence[Mapping]) -> tuple[PinnedStretch, ...]:
    """The pinned stretches of an episode's steps (see the module docstring)."""
    found = []
    start = None                 # the first step of the current stretch of motion in place

    def close(end: int) -> None:
        if start is not None and end - start >= PINNED_STEPS:
            first = steps[start]
            found.append(PinnedStretch(int(first["step"]), end - start, float(first["x_m"]), float(first["y_m"])))

    for i, s in enumerate(steps):
        if s.get("action", "none") in _STILL:
            close(i)
            start = None
            continue
        if start is not None:
            a = steps[start]
            turned = abs((float(s["yaw_deg"]) - float(a["yaw_deg"]) + 180.0) % 360.0 - 180.0)
            if math.hypot(float(s["x_m"]) - float(a["x_m"]), float(s["y_m"]) - float(a["y_m"])) <= PINNED_M \
                    and turned <= PINNED_DEG:
                continue
            close(i)
        start = i
    close(len(steps))
    return tuple(found)


def collision_onsets(steps: Sequence[Mapping]) -> tuple[CollisionOnset, ...]:
    """The steps at which the log's collision count went up (none where the log has no count)."""
    found, before = [], 0
    for s in steps:
        count = s.get("collisions")
        if count is None:
            continue
        if count > before:
            found.append(CollisionOnset(int(s["step"]), int(count - before), str(s["state"]),
                                        str(s.get("action", "none")), float(s["x_m"]), float(s["y_m"])))
        before = count
    return tuple(found)


def diagnose(steps: Iterable[Mapping], poses: Mapping, goal: Optional[tuple] = None) -> Diagnosis:
    """The confirmations and lost events of one episode's steps (see the module docstring).

    ``poses``: :func:`node_poses` of the map the episode ran on; a node missing from it raises
    ``KeyError`` naming the node (the step log is of another map). ``goal``: optional
    ``(goal node, (x_m, y_m) of the true goal)``, to tell whether the goal image was placed at
    the right node."""
    confirmations: list[Confirmation] = []
    lost: list[LostEvent] = []
    previous: Optional[Mapping] = None
    counts = {"steps": 0, "right": 0, "confident": 0, "confident_right": 0, "odometry": 0, "odometry_nodes": 0}
    steps = list(steps)
    for s in steps:
        state, node = s["state"], s["current_node"]
        kind = None
        if node is not None and state in _ON_THE_WAY:
            if previous is None or previous["state"] in _LOCALISING:
                kind = "localised"
            elif node != previous["current_node"]:
                kind = "reached"
        counts["odometry"] += s.get("odometry") in ("driving on", "reached")
        counts["odometry_nodes"] += s.get("odometry") == "reached"
        belief = s.get("belief_top")
        mode = belief[0][0] if belief else None
        mode_wrong = None
        if mode is not None:
            mode_wrong = wrong_place(*placement(s, mode, poses))
            counts["steps"] += 1
            counts["right"] += not mode_wrong
            if (s.get("belief_confidence") or 0.0) >= CONFIDENT:
                counts["confident"] += 1
                counts["confident_right"] += not mode_wrong
        if kind is not None:
            distance, error = placement(s, node, poses)
            x, y, _ = poses[node]
            confirmations.append(Confirmation(
                step=int(s["step"]), node=node, kind=kind, x_m=float(s["x_m"]), y_m=float(s["y_m"]),
                distance_m=distance, node_x_m=x, node_y_m=y, heading_error_deg=error,
                belief_node=mode, belief_wrong=mode_wrong,
                by_odometry=kind == "reached" and s.get("odometry") == "reached"))
        if state == "relocalising" and previous is not None and previous["state"] in _ON_THE_WAY:
            lost.append(LostEvent(step=int(s["step"]), x_m=float(s["x_m"]), y_m=float(s["y_m"]),
                                  current_node=previous["current_node"], target_node=previous["target_node"]))
        previous = s
    beliefs = {"belief_steps": counts["steps"], "belief_right": counts["right"],
               "belief_confident": counts["confident"], "belief_confident_right": counts["confident_right"],
               "pinned": pinned_stretches(steps), "collisions": collision_onsets(steps),
               "odometry_steps": counts["odometry"], "odometry_nodes": counts["odometry_nodes"],
               "odometry_judged": True}
    if goal is None:
        return Diagnosis(tuple(confirmations), tuple(lost), **beliefs)
    node, (gx, gy) = goal
    if node not in poses:
        raise KeyError(f"goal node {node!r} is not a node of the map")
    x, y, _ = poses[node]
    return Diagnosis(tuple(confirmations), tuple(lost), node, round(math.hypot(x - gx, y - gy), 3), **beliefs)


def confirmation_counts(diagnoses: Sequence[Diagnosis]) -> dict:
    """Totals over episodes: confirmations and wrong ones, the same for (re-)localisations, the
    episodes and steps pinned, the episodes, steps and nodes driven on by odometry, and the
    collisions by what the robot was doing. Where the belief is in the logs: its mode's wrong
    places at the (re-)localisations and at the nodes reached by odometry, and how many of them
    the navigator got wrong too."""
    every = [c for d in diagnoses for c in d.confirmations]
    localised = [c for c in every if c.kind == "localised"]
    judged = [c for c in localised if c.belief_wrong is not None]
    odometry = [c for d in diagnoses if d.odometry_judged for c in d.confirmations if c.by_odometry]
    odometry_judged = [c for c in odometry if c.belief_wrong is not None]
    return {"episodes": len(diagnoses), "confirmations": len(every), "wrong": sum(c.is_wrong() for c in every),
            "localisations": len(localised), "wrong_localisations": sum(c.is_wrong() for c in localised),
            "belief_localisations": len(judged), "belief_wrong_localisations": sum(c.belief_wrong for c in judged),
            "both_wrong_localisations": sum(c.belief_wrong and c.is_wrong() for c in judged),
            "belief_steps": sum(d.belief_steps for d in diagnoses), "belief_right": sum(d.belief_right for d in diagnoses),
            "belief_confident": sum(d.belief_confident for d in diagnoses),
            "belief_confident_right": sum(d.belief_confident_right for d in diagnoses),
            "pinned_episodes": sum(bool(d.pinned) for d in diagnoses),
            "pinned_steps": sum(d.pinned_steps for d in diagnoses),
            "odometry_episodes": sum(bool(d.odometry_steps) for d in diagnoses),
            "odometry_steps": sum(d.odometry_steps for d in diagnoses),
            "odometry_nodes": sum(d.odometry_nodes for d in diagnoses),
            "odometry_nodes_judged": len(odometry), "odometry_nodes_wrong": sum(c.is_wrong() for c in odometry),
            "belief_odometry_nodes": len(odometry_judged),
            "belief_wrong_odometry_nodes": sum(c.belief_wrong for c in odometry_judged),
            "both_wrong_odometry_nodes": sum(c.belief_wrong and c.is_wrong() for c in odometry_judged),
            "collisions": _sum_counts(d.collisions_by_doing() for d in diagnoses),
            "median_distance_m": None if not every else round(statistics.median(c.distance_m for c in every), 3)}


def _sum_counts(counts: Iterable[Mapping]) -> dict:
    total: dict = {}
    for c in counts:
        for key, n in c.items():
            total[key] = total.get(key, 0) + n
    return total
