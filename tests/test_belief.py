"""The discrete Bayes filter over the map (controllers.belief), on synthetic graphs whose views are
made up from the robot's true place: look-alike corridors, a kidnapped robot, noisy odometry, a
map without metric arcs."""

import math
from dataclasses import replace

import networkx as nx
import numpy as np
import pytest

from controllers.belief import LikelihoodError, NodeBelief, SimilarityModel, contrast
from controllers.config import BeliefConfig

SPACING_M = 0.8
MODEL = SimilarityModel(mean_same=3.0, mean_other=0.0, std=1.0)
W3 = BeliefConfig(weight=0.3)


def loop(n: int, spacing_m: float = SPACING_M) -> tuple[nx.DiGraph, dict]:
    """A directed loop of n nodes; node k at arc length k * spacing."""
    graph = nx.DiGraph()
    graph.add_nodes_from(range(n))
    for k in range(n):
        graph.add_edge(k, (k + 1) % n)
    return graph, {(k, (k + 1) % n): spacing_m for k in range(n)}


def circle(n: int) -> dict:
    """Node headings of a loop driven as a circle (counter-clockwise, node 0 heading east)."""
    return {k: math.pi / 2 + 2 * math.pi * k / n for k in range(n)}


class Views:
    """Similarity rows of a robot at arc length ``s`` on the loop: the nodes near it score high
    (falling off over about a node spacing), the others low, plus seeded noise; ``twins[a] = b``
    makes node a look exactly like node b (a corridor seen the same from two places)."""

    def __init__(self, n: int, twins: dict | None = None, noise: float = 0.03, seed: int = 0):
        self.n, self.twins, self.noise = n, twins or {}, noise
        self.rng = np.random.default_rng(seed)

    def row(self, s_m: float) -> np.ndarray:
        length = self.n * SPACING_M
        pos = np.arange(self.n) * SPACING_M
        gap = np.abs((pos - s_m + length / 2) % length - length / 2)
        clean = 0.25 + 0.6 * np.exp(-0.5 * (gap / (0.6 * SPACING_M)) ** 2)
        for a, b in self.twins.items():
            clean[a] = clean[b] = max(clean[a], clean[b])
        return np.clip(clean + self.rng.normal(0.0, self.noise, self.n), -1, 1)


def drive(belief: NodeBelief, views: Views, start_m: float, metres: float, step_m: float = 0.05,
          odometry_scale=lambda: 1.0, turn_per_m: float | None = None) -> float:
    """Drive forward ``metres`` from ``start_m``, one observation per step, turning ``turn_per_m``
    (default: as the loop does when it is driven as a circle, :func:`circle`); returns where it
    ended."""
    s = start_m
    turn_per_m = 2 * math.pi / (views.n * SPACING_M) if turn_per_m is None else turn_per_m
    for _ in range(int(round(metres / step_m))):
        s += step_m
        belief.move(step_m * odometry_scale(), step_m * turn_per_m)
        belief.observe(views.row(s))
    return s


def nearest(s_m: float, n: int) -> int:
    return int(round(s_m / SPACING_M)) % n


def test_contrast_ignores_a_global_drop_of_every_cosine():
    row = np.array([0.2, 0.3, 0.8, 0.25, 0.22, 0.31])
    np.testing.assert_allclose(contrast(row), contrast(0.5 * row - 0.05), atol=1e-9)
    assert np.argmax(contrast(row)) == 2


def test_the_likelihood_ratio_rises_with_the_score_between_far_places_and_a_cap():
    c = np.linspace(-3, 6, 50)
    r = MODEL.log_ratio(c)
    assert np.all(np.diff(r) >= -1e-12) and r[-1] > r[25] > r[0]
    assert MODEL.log_ratio(np.array([1.5]))[0] == 0.0                 # halfway: says nothing
    assert MODEL.log_ratio(np.array([-2.0]))[0] == MODEL.log_ratio(np.array([0.0]))[0] == pytest.approx(-4.5)
    assert MODEL.log_ratio(np.array([50.0]))[0] == MODEL.log_ratio(np.array([5.0]))[0] == pytest.approx(10.5)
    # one view on its own (a goal image): no upper cap, the better of two high scores wins
    high = MODEL.log_ratio(np.array([5.0, 8.0]), capped=False)
    assert high[1] > high[0] == pytest.approx(10.5)
    rng = np.random.default_rng(0)
    fitted = SimilarityModel.fit(rng.normal(3, 1, 500), rng.normal(0, 1, 500))
    assert fitted.mean_same == pytest.approx(3, abs=0.15) and fitted.std == pytest.approx(1, abs=0.1)
    with pytest.raises(LikelihoodError, match="look no more alike"):
        SimilarityModel.fit(rng.normal(0.1, 1, 500), rng.normal(0, 1, 500))


def test_the_likelihood_fits_on_a_maps_own_keyframes():
    """Keyframes along a loop share half their vector with the next: neighbours score high, far
    places near zero; places no more alike than strangers are refused with a reason."""
    rng = np.random.default_rng(2)
    base = rng.normal(size=(41, 32))
    keys = base[:-1] + 0.8 * base[1:]
    keys /= np.linalg.norm(keys, axis=1, keepdims=True)
    graph, _ = loop(40)
    model = SimilarityModel.from_references(keys, graph, range(40))
    assert model.mean_same > 1.5 and abs(model.mean_other) < 0.5 and model.slope > 0.5
    strangers = rng.normal(size=(40, 32))
    strangers /= np.linalg.norm(strangers, axis=1, keepdims=True)
    with pytest.raises(LikelihoodError):
        SimilarityModel.from_references(strangers, graph, range(40))
    with pytest.raises(ValueError, match="40 finite rows"):
        SimilarityModel.from_references(keys[:30], graph, range(40))


def test_the_filter_follows_a_robot_driving_the_loop():
    graph, lengths = loop(20)
    belief = NodeBelief(graph, range(20), MODEL, arc_lengths_m=lengths, config=W3)
    views = Views(20)
    s = 2 * SPACING_M
    for _ in range(10):                                   # standing at node 2, looking
        belief.observe(views.row(s))
    assert belief.mode == 2 and belief.confidence > 0.9
    for _ in range(40):
        s = drive(belief, views, s, 0.5)
        assert abs(belief.mode - nearest(s, 20)) in (0, 1, 19), (s, belief.top())
    assert belief.confidence > 0.8


@pytest.mark.parametrize("bins", [1, 8])
def test_a_corridor_alike_at_two_places_is_resolved_by_driving(bins):
    """Nodes 2-5 look exactly like nodes 12-15 (the same corridor seen twice); standing in it the
    mass splits; driving on past node 6, which has no twin, settles it."""
    graph, lengths = loop(20)
    twins = {2: 12, 3: 13, 4: 14, 5: 15}
    belief = NodeBelief(graph, range(20), MODEL, arc_lengths_m=lengths, config=replace(W3, heading_bins=bins),
                        node_headings=circle(20))
    views = Views(20, twins=twins, seed=3)
    s = 3 * SPACING_M
    for _ in range(20):
        belief.observe(views.row(s))
    nodes = belief.node_probabilities
    here, there = nodes[2:5].sum(), nodes[12:15].sum()
    assert here > 0.25 and there > 0.25, belief.top(6)        # ambiguous: both stretches hold mass
    assert belief.confidence < 0.6                            # not to be trusted yet
    s = drive(belief, views, s, 4 * SPACING_M)
    assert belief.mode == nearest(s, 20) and belief.confidence > 0.8, belief.top(4)


@pytest.mark.parametrize("bins", [1, 8])
def test_a_kidnapped_robot_is_found_again(bins):
    graph, lengths = loop(20)
    belief = NodeBelief(graph, range(20), MODEL, arc_lengths_m=lengths, config=replace(W3, heading_bins=bins),
                        node_headings=circle(20))
    views = Views(20, seed=5)
    s = drive(belief, views, 1 * SPACING_M, 3.0)
    assert belief.mode == nearest(s, 20)
    s = 13 * SPACING_M                                        # carried across the map, no odometry
    drive(belief, views, s, 2.0)
    assert belief.mode == nearest(s + 2.0, 20) and belief.confidence > 0.7, belief.top()


@pytest.mark.parametrize("bins", [1, 8])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_noisy_odometry_does_not_make_the_belief_diverge(seed, bins):
    """Odometry off by up to +-30 % every step (slip, a blocked wheel): over 60 m the mode never
    strays more than one node from the truth."""
    graph, lengths = loop(25)
    belief = NodeBelief(graph, range(25), MODEL, arc_lengths_m=lengths, config=replace(W3, heading_bins=bins),
                        node_headings=circle(25))
    views = Views(25, seed=seed, noise=0.05)
    rng = np.random.default_rng(seed)
    s, worst = 0.0, 0
    for _ in range(120):
        s = drive(belief, views, s, 0.5, odometry_scale=lambda: rng.uniform(0.7, 1.3))
        gap = abs(belief.mode - nearest(s, 25))
        worst = max(worst, min(gap, 25 - gap))
    assert worst <= 1


def test_a_map_without_odometry_steps_in_node_units():
    """From a video: no metric arcs; each query frame moves about a node (a sequence of images)."""
    graph, _ = loop(12)
    belief = NodeBelief(graph, range(12), MODEL, config=BeliefConfig(cells_per_arc=1, stay=0.2, skip=0.2, weight=0.5))
    assert not belief.metric and belief.n_cells == 12
    views = Views(12, twins={3: 9, 4: 10}, seed=7)
    for k in range(3, 9):
        if k > 3:
            belief.move(1.0)
        belief.observe(views.row(k * SPACING_M))
    assert belief.mode == 8 and belief.confidence > 0.8, belief.top()


def test_bad_arguments_are_named():
    graph, lengths = loop(4)
    with pytest.raises(ValueError, match="weight"):
        BeliefConfig(weight=0.0)
    with pytest.raises(ValueError, match="node 3"):
        NodeBelief(graph, range(3), MODEL)
    belief = NodeBelief(graph, range(4), MODEL, arc_lengths_m=lengths)
    with pytest.raises(ValueError, match="4 finite similarities"):
        belief.observe(np.zeros(3))
    with pytest.raises(ValueError, match="along"):
        belief.move(math.nan)
    with pytest.raises(ValueError, match="heading_bins 4 needs"):
        NodeBelief(graph, range(4), MODEL, config=BeliefConfig(heading_bins=4))
    with pytest.raises(ValueError, match="heading_bins"):
        BeliefConfig(heading_bins=0)
    with pytest.raises(ValueError, match="stay \\+ skip"):
        BeliefConfig(stay=0.6, skip=0.5)


def test_cells_follow_the_arc_lengths():
    graph, lengths = loop(4, spacing_m=1.0)
    belief = NodeBelief(graph, range(4), MODEL, config=BeliefConfig(cell_m=0.25), arc_lengths_m=lengths)
    assert belief.n_cells == 4 + 4 * 3
    belief.reset({0: 1.0})
    for _ in range(4):
        belief.move(0.25)
    assert belief.mode == 1 and belief.node_probabilities[1] > 0.5
    assert math.isclose(belief.node_probabilities.sum(), 1.0)


def test_on_a_loop_the_filter_is_filterpys_discrete_bayes():
    """One cell per arc around a loop: the motion step is filterpy's ``predict`` (offset one, kernel
    stay / advance / skip, wrapping) and the measurement step its ``update`` with the likelihood
    ``exp(weight * log_ratio)``; the numpy version exists because a map's graph branches."""
    from filterpy import discrete_bayes

    config = BeliefConfig(cells_per_arc=1, stay=0.15, skip=0.05, mixing=0.0, weight=0.4)
    graph, _ = loop(9)
    belief = NodeBelief(graph, range(9), MODEL, config=config)
    rng = np.random.default_rng(11)
    reference = rng.random(9)
    reference /= reference.sum()
    belief._p = reference.copy()[:, None]
    for _ in range(5):
        reference = discrete_bayes.predict(reference, 1, [config.stay, 1 - config.stay - config.skip, config.skip])
        belief.advance()
        np.testing.assert_allclose(belief.cell_probabilities, reference, atol=1e-12)
        row = rng.uniform(0.1, 0.9, 9)
        reference = discrete_bayes.update(np.exp(0.4 * MODEL.log_ratio(contrast(row))), reference)
        belief.observe(row)
        np.testing.assert_allclose(belief.cell_probabilities, reference, atol=1e-12)


# -- directions: the robot's heading relative to the route ---------------------------------

B8 = BeliefConfig(weight=0.3, heading_bins=8)


def square(n_side: int = 5) -> tuple[nx.DiGraph, dict, dict]:
    """A loop around a square block, ``n_side`` arcs per side; the route turns left 90 deg at
    every corner (node headings 0, 90, 180, 270 deg)."""
    graph, lengths = loop(4 * n_side)
    headings = {k: math.radians(90.0 * (k // n_side)) for k in range(4 * n_side)}
    return graph, lengths, headings


def unmatched_row(rng: np.random.Generator, n: int) -> np.ndarray:
    """A view that no keyframe shows (a wall, the route seen backwards): every node scores low,
    and one node at random looks alike."""
    row = 0.25 + rng.normal(0.0, 0.03, n)
    row[rng.integers(n)] = 0.8
    return row


def test_a_turn_in_place_keeps_what_the_views_said():
    """Placed at node 3 facing along the route, the robot turns a full circle in place; the views
    on the way match no keyframe but a random look-alike each, until it faces along again. The
    belief keeps node 3 all the way round (those views are what facing away from the route
    predicts) and knows which way it faces."""
    graph, lengths, headings = square()
    n = len(headings)
    views, rng = Views(n, seed=2), np.random.default_rng(2)
    belief = NodeBelief(graph, range(n), MODEL, config=B8, arc_lengths_m=lengths, node_headings=headings)
    for _ in range(15):
        belief.observe(views.row(3 * SPACING_M))
    for k in range(1, 41):                                   # 9 deg per step, 360 deg in all
        belief.move(0.0, math.radians(9.0))
        facing_along = min(9 * k, 360 - 9 * k) < 25
        belief.observe(views.row(3 * SPACING_M) if facing_along else unmatched_row(rng, n))
        assert belief.mode == 3 and belief.confidence > 0.8, (k, belief.top())
        if k == 20:
            assert belief.facing_deg == 180.0                # facing back down the route
    assert belief.facing_deg == 0.0


def test_driving_round_corners_keeps_the_place_and_the_direction():
    """Driving the square, turning at every corner node as the route does: the relative direction
    stays along the route and the mode follows the robot."""
    graph, lengths, headings = square()
    n = len(headings)
    belief = NodeBelief(graph, range(n), MODEL, config=B8, arc_lengths_m=lengths, node_headings=headings)
    views = Views(n, seed=4)
    s = 1 * SPACING_M
    for _ in range(10):
        belief.observe(views.row(s))
    for _ in range(n + 5):                                   # more than a lap, one node at a time
        s = drive(belief, views, s, SPACING_M, step_m=0.1, turn_per_m=0.0)
        if nearest(s, n) % 5 == 0:                           # a corner: turn left on the spot
            for _ in range(9):
                belief.move(0.0, math.radians(10.0))
                belief.observe(views.row(s))
        assert belief.mode == nearest(s, n), (s, belief.top())
        assert belief.facing_deg == 0.0, belief.facing_deg
    assert belief.confidence > 0.8


def test_each_direction_moves_its_own_way():
    """Facing along the route the mass drives forward, facing back it drives backward, side-on
    it stays: the motion model, without views."""
    graph, lengths, headings = square()
    belief = NodeBelief(graph, range(20), MODEL, config=replace(B8, stay=0.0, skip=0.0, mixing=0.0),
                        arc_lengths_m=lengths, node_headings=headings)
    belief.reset({7: 1.0})                                  # on the straight side 5-10, every direction
    belief.move(2 * SPACING_M)
    p = belief.state_probabilities
    nodes = list(range(20))
    assert p[nodes.index(9), 0] == pytest.approx(1 / 8)     # along the route: two nodes on
    assert p[nodes.index(5), 4] == pytest.approx(1 / 8)     # facing back: two nodes back
    assert p[nodes.index(7), 2] == p[nodes.index(7), 6] == pytest.approx(1 / 8)   # side-on: stays
    assert belief.cell_probabilities.sum() == pytest.approx(1.0)
