"""The contact terms evaluate only their tool's candidate nodes (sim.terms.contact_reach): the
same energy, gradient and Hessian as the evaluation of every skin node, to the last bit, at
every state a Newton iteration may visit, including nodes thrown into a tool from far away."""

import numpy as np

from sim.scene.load import load_scene
from sim.stepping.simulation import Simulation
from sim.terms.contact_reach import Reach, lipschitz, moved_out
from sim.tools.builders import punch
from sim.tools.pose import rotation
from tests.support import ROOT


def _everything(term) -> Reach:
    """A candidate list holding every node, never made again: the full evaluation."""
    return Reach(term.prog, term.nodes, term.delta, np.inf)


def _terms_at(term, x, pattern):
    g = np.zeros_like(x)
    data = np.zeros(pattern.nnz)
    E = term.add_gradient_hessian(x, g, data)
    g2 = np.zeros_like(x)
    term.add_gradient(x, g2)
    return E, term.energy(x), g, g2, data


def test_candidates_give_the_full_evaluation_and_never_miss_a_node():
    """The 3 mm cup after 3 steps (punch, die, force-controlled holder, friction lagged), then
    a walk of states: small Newton-like moves, the tools moved on by a step, and single nodes
    thrown from far away into each tool. Filtered and full evaluations agree bit for bit,
    while the filtered term makes its list far less often than it is evaluated."""
    sim = Simulation.from_scene(load_scene(ROOT / "scenes" / "cup_drawing.toml", {
        "mesh.edge_length": 0.003, "stepping.steps": 25, "tools.0.velocity": [0, 0, -0.0125]}))
    for _ in range(3):
        sim.step()
    pattern = sim.model.pattern
    rng = np.random.default_rng(7)
    for term in sim.tools:
        term.begin_step(sim.t + 0.04, 0.04, sim.x)
    assert any(t.vdof is not None for t in sim.tools)
    assert all(t.mu > 0 and t.lagged[0].any() for t in sim.tools)
    x = sim.x.copy()
    evaluations = 0
    for k in range(40):
        x = x.copy()
        skin = sim.tools[0].nodes
        x[skin] += rng.normal(scale=2e-5, size=(len(skin), 3))  # a correction's size
        if k % 10 == 5:  # a correction that throws one far node into each tool
            for term in sim.tools:
                d = term.gap(x)
                far = np.flatnonzero(d > term.delta + term.reach.margin)
                node = term.nodes[far[rng.integers(len(far))]]
                probe = x.copy()
                # straight along the tool's normal at the node until 1 % of the layer inside
                for _ in range(50):
                    dd = term.gap(probe)[term.nodes == node][0]
                    if dd < 0.5 * term.delta:
                        break
                    normal = _normal(term, probe[node], probe)
                    probe[node] -= (dd - 0.5 * term.delta) * normal
                assert term.gap(probe)[term.nodes == node][0] < term.delta
                x = probe
        if k == 20:  # the tools move on by another step
            for term in sim.tools:
                term.begin_step(sim.t + 0.08, 0.08, x)
        for term in sim.tools:
            filtered = _terms_at(term, x, pattern)
            kept = term.reach
            term.reach = _everything(term)
            try:
                full = _terms_at(term, x, pattern)
            finally:
                term.reach = kept
            for a, b in zip(filtered, full, strict=True):
                assert np.array_equal(a, b), term.name
            assert term.lag_change(x) == _lag_change_full(term, x)
            evaluations += 3
    builds = sum(t.reach.builds for t in sim.tools)
    # the thrown nodes and the tools' moves make the lists again; small moves do not
    assert builds < evaluations / 4, (builds, evaluations)


def _normal(term, p, x):
    """The tool's outward normal at point p (world), by the signed distance's gradient."""
    from sim.tools.evaluate import sdf_world

    _, g, _ = sdf_world(term.prog, term.R_now, term.translation(x), p[None])
    return g[0] / np.linalg.norm(g[0])


def _lag_change_full(term, x):
    kept = term.reach
    term.reach = _everything(term)
    try:
        return term.lag_change(x)
    finally:
        term.reach = kept


def test_moved_out_measures_the_move_in_the_tool_frame():
    """A node's move is taken relative to the tool: the tool's translation and rotation
    move every node in its frame, a node carried along with the tool does not move, and
    unwatched nodes (slack inf) are never reported."""
    rng = np.random.default_rng(1)
    X = rng.normal(size=(200, 3))
    nodes = np.arange(200)
    R = rotation([0.3, -0.2, 0.9], 0.4)
    t = np.array([0.1, -0.2, 0.3])
    ref = (X - t) @ R
    slack = np.full(200, 0.05)
    assert not moved_out(X, nodes, R, t, ref, slack)
    # the tool turns by a small angle about its origin: a node at distance r from it moves
    # by about r * angle in the tool frame
    R2 = rotation([0.0, 0.0, 1.0], 0.01) @ R
    r = np.linalg.norm(X - t, axis=1)
    move = np.linalg.norm((X - t) @ R2 - ref, axis=1)
    assert np.allclose(move, 2 * r * np.sin(0.005) * np.linalg.norm(
        np.cross([0, 0, 1], (X - t) / r[:, None]), axis=1), rtol=1e-9)
    assert moved_out(X, nodes, R2, t, ref, slack) == bool((move >= 0.05).any())
    # a node carried rigidly with the tool stays put in its frame
    Y = (X - t) @ R @ R2.T + t + 0.5
    assert not moved_out(Y, nodes, R2, t + 0.5, ref, slack)
    # one node moved by its slack is found; unwatched, it is not
    Z = X.copy()
    Z[17] += [0.0, 0.05, 0.0]
    assert moved_out(Z, nodes, R, t, ref, slack)
    slack[17] = np.inf
    assert not moved_out(Z, nodes, R, t, ref, slack)


def test_analytic_tools_are_exact_distances():
    """L = 1 for the analytic primitives: the punch's signed distance changes by at most the
    distance between two points (sampled pairs around its nose and wall)."""
    prog = punch(0.0165, 0.04, 0.005)
    assert lipschitz(prog) == 1.0
    from sim.tools.evaluate import sdf_distance

    rng = np.random.default_rng(3)
    A = rng.uniform([-0.03, -0.03, -0.01], [0.03, 0.03, 0.05], size=(20000, 3))
    B = A + rng.normal(scale=2e-3, size=A.shape)
    dd = np.abs(sdf_distance(prog, A) - sdf_distance(prog, B))
    assert np.all(dd <= np.linalg.norm(A - B, axis=1) * (1 + 1e-12))
