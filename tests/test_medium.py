"""The network layer (netsim.medium) against closed forms of queueing and MAC theory.

Each MAC model runs in its own SimPy environment (the medium core, no scenario), seeded;
Monte Carlo tolerances are stated from the estimator's standard error.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import simpy
from netsim.models.medium import MEDIUM_MODELS, can_frame_bits, parse_medium

from netsim.medium import MAC_MODELS, Packet, Recorder, mac_model, poisson_source


def _medium(model: str, n_nodes: int, outs: list[list[int]], seed: int = 0, **params):
    spec = parse_medium({"model": model, **params}, n_agents=n_nodes, n_states=1)
    env = simpy.Environment()
    recorder = Recorder()
    medium = mac_model(model)(env, spec.params, n_nodes, outs, np.random.default_rng(seed),
                              recorder)
    return env, medium, recorder


def test_every_model_of_the_table_has_a_mac():
    assert set(MEDIUM_MODELS) - {"ns3"} == set(MAC_MODELS)  # ns3: netsim.medium.ns3source


def _batch_se(x: np.ndarray, batches: int = 20) -> float:
    """Standard error of the mean of a correlated series, by batch means."""
    means = np.array([b.mean() for b in np.array_split(x, batches)])
    return float(means.std(ddof=1) / math.sqrt(batches))


@pytest.mark.parametrize("rho", [0.5, 0.8])
def test_point_to_point_mean_wait_is_pollaczek_khinchine_md1(rho):
    """M/D/1: Poisson arrivals (rate lambda) on one link, service S = bits / rate:
    mean wait in queue W = lambda S^2 / (2 (1 - rho)), rho = lambda S."""
    S = 1.0
    lam = rho / S
    env, medium, rec = _medium("point-to-point", 2, [[1], []], bit_rate=1000.0,
                               propagation=0.25, queue=100000)
    env.process(poisson_source(env, medium, 0, (1,), lam, 1000.0, np.random.default_rng(7)))
    env.run(until=30000.0)
    b = rec.background_arrays()
    waits = b["done"] - b["created"] - S - 0.25
    waits = waits[len(waits) // 10:]  # drop the warm-up
    expected = lam * S**2 / (2 * (1 - rho))
    se = _batch_se(waits)
    assert waits.min() >= -1e-9
    assert se < 0.08 * expected  # the test has the power to see a 30 % error
    assert abs(waits.mean() - expected) < 4 * se, (waits.mean(), expected, se)


def test_tdma_delay_is_the_slot_wait_and_below_the_deterministic_worst_case():
    """One slot per node and frame, at most one packet per frame: delay = wait for the
    node's next slot start + C + propagation, always < F + C + propagation, and it
    comes within one sweep step of that bound for a packet made just after its slot."""
    N, node, prop = 4, 2, 1e-4
    env, medium, rec = _medium("tdma", N, [[1]] * N, bit_rate=1e5, header_bytes=10,
                               propagation=prop)
    C = medium.tx_time(Packet(0, (1,), -1, 0.0, 8 * 18))
    slot, F = medium.slot, medium.frame
    assert slot == pytest.approx(C) and F == pytest.approx(N * C)
    K = 400
    phases = (np.arange(K) + 0.5) / K * F  # a sweep of the frame, one packet per frame

    def source():
        for k in range(K):
            t = (2 * k) * F + phases[k]
            yield env.timeout(t - env.now)
            medium.submit(Packet(node, (0,), -1, env.now, 8 * 18))

    env.process(source())
    env.run(until=2 * K * F + 3 * F)
    b = rec.background_arrays()
    delays = b["done"] - b["created"]
    offset = node * slot
    expected = np.mod(offset - phases, F) + C + prop
    assert len(delays) == K
    np.testing.assert_allclose(delays, expected, rtol=0, atol=1e-9)
    worst = F + C + prop
    assert delays.max() < worst
    assert delays.max() > worst - F / K


def test_slotted_aloha_throughput_is_binomial_and_g_exp_minus_g():
    """Every node backlogged, each transmits with probability p: successes per slot
    S = G (1 - p)^(N-1), G = N p, which tends to G e^(-G)."""
    N, slots = 100, 3000
    for G in (0.5, 1.0, 2.0):
        env, medium, rec = _medium("aloha", N, [[0]] + [[0]] * (N - 1), seed=int(G * 10),
                                   p=G / N, queue=1000, bit_rate=1e3, header_bytes=0,
                                   payload_bytes=1)
        for i in range(N):
            for _ in range(200):  # more than any node can send in the run
                medium.submit(Packet(i, (0 if i else 1,), -1, 0.0, 8.0))
        env.run(until=slots * medium.slot - 1e-9)
        s = medium.stats
        assert s["slots"] == slots
        S = s["successes"] / s["slots"]
        exact = G * (1 - G / N) ** (N - 1)
        se = math.sqrt(exact * (1 - exact) / slots)  # successes are i.i.d. per slot
        assert abs(S - exact) < 4 * se, (G, S, exact, se)
        assert abs(exact - G * math.exp(-G)) < 0.01  # the classic limit, N = 100
        assert s["attempts"] / slots == pytest.approx(G, abs=4 * math.sqrt(G / slots))


def _can_rta(C: list[float], T: list[float], tau_bit: float) -> list[float]:
    """Worst-case response times by the standard analysis (Tindell et al. 1994; Davis
    et al. 2007, eqs. (5)-(9)) for zero jitter, priority = index, when every level-m
    busy period ends within T_m (then only the first instance matters)."""
    R = []
    for m in range(len(C)):
        B = max(C[m + 1:], default=0.0)
        # level-m busy period: t = B + sum_{k <= m} ceil(t / T_k) C_k
        t = B + sum(C[: m + 1])
        while True:
            nxt = B + sum(math.ceil((t + tau_bit) / T[k]) * C[k] for k in range(m + 1))
            if nxt <= t + 1e-15:
                break
            t = nxt
        assert t <= T[m], "the single-instance analysis needs t_m <= T_m"
        w = B
        while True:
            nxt = B + sum(math.ceil((w + tau_bit) / T[k]) * C[k] for k in range(m))
            if nxt <= w + 1e-15:
                break
            w = nxt
        R.append(w + C[m])
    return R


def _can_periodic(bit_rate, data_bytes, periods, offsets, horizon, seed=0):
    N = len(periods)
    env, medium, rec = _medium("can", N, [[(i + 1) % N] for i in range(N)], seed=seed,
                               bit_rate=bit_rate)

    def source(i):
        yield env.timeout(offsets[i])
        while True:
            medium.submit(Packet(i, ((i + 1) % N,), -1, env.now, 8.0 * data_bytes[i]))
            yield env.timeout(periods[i])

    for i in range(N):
        env.process(source(i))
    env.run(until=horizon)
    b = rec.background_arrays()
    return b["source"], b["done"] - b["created"], b["created"]


def _can_critical_offsets(m: int, C: list[float], lead: float) -> tuple[list[float], int | None]:
    """Release offsets of the critical instant of message ``m`` (frame times ``C``, priority
    = index): the longest lower-priority frame (the blocker, returned; None if ``m`` is the
    lowest) starts at 0, every higher-priority message is released ``lead`` later, the
    other lower-priority ones after the blocker's frame."""
    blocker = max(range(m + 1, len(C)), key=lambda k: C[k], default=None)
    offsets = [lead] * len(C)
    if blocker is not None:
        offsets[blocker] = 0.0
    for k in range(m + 1, len(C)):  # other lower-priority messages out of the way
        if k != blocker:
            offsets[k] = 2 * lead + C[blocker] if blocker is not None else lead
    return offsets, blocker


def test_can_worst_case_response_time_by_response_time_analysis():
    """Four periodic messages, priority = node index: the critical instant (the longest
    lower-priority frame starts just before every higher-priority message is released)
    gives exactly the analysis' R_m (less the lead), and random phases never exceed it."""
    rate = 500e3
    tau = 1 / rate
    data = [2, 4, 8, 8]
    T = [1.0e-3, 1.5e-3, 2.5e-3, 4.0e-3]
    C = [can_frame_bits(s) * tau for s in data]
    assert C == pytest.approx([150e-6, 190e-6, 270e-6, 270e-6])  # 75, 95, 135, 135 bits
    R = _can_rta(C, T, tau)
    lead = 1e-6
    for m in range(4):
        offsets, blocker = _can_critical_offsets(m, C, lead)
        source, response, created = _can_periodic(rate, data, T, offsets, 0.004)
        first = response[(source == m) & (np.abs(created - lead) < 1e-12)]
        assert first.size == 1
        # the blocker started ``lead`` before the release; without one (B = 0) all of
        # R_m is measured
        expected = R[m] - (lead if blocker is not None else 0.0)
        assert first[0] == pytest.approx(expected, abs=1e-9), (m, first[0], R[m])
    rng = np.random.default_rng(3)
    worst = np.zeros(4)
    for trial in range(10):
        offsets = list(rng.uniform(0, 2e-3, 4))
        source, response, _ = _can_periodic(rate, data, T, offsets, 0.2, seed=trial)
        for m in range(4):
            worst[m] = max(worst[m], response[source == m].max())
    assert np.all(worst <= np.array(R) + 1e-12), (worst, R)


def _first_collision_probability(n: int, W: int) -> float:
    """n nodes, one frame each at the same instant, backoffs uniform on 0..W-1: the first
    transmission collides unless exactly one node drew the smallest value."""
    unique = sum(n * (1 / W) * ((W - 1 - m) / W) ** (n - 1) for m in range(W))
    return 1 - unique


def _first_transmission_collisions(n: int, bursts: int, seed: int, **params) -> int:
    """CSMA/CA on an idle channel: every 0.1 s each of ``n`` nodes gets one frame (to the
    next node) at the same instant; how many of the ``bursts`` bursts' first transmission
    was lost."""
    env, medium, rec = _medium("csma", n, [[(i + 1) % n] for i in range(n)], seed=seed,
                               **params)

    def bursts_process():
        for b in range(bursts):
            yield env.timeout(b * 0.1 - env.now)
            for i in range(n):
                medium.submit(Packet(i, ((i + 1) % n,), -1, env.now, 8 * 18))

    env.process(bursts_process())
    env.run(until=bursts * 0.1)
    b = rec.background_arrays()
    burst = np.floor(b["created"] / 0.1 + 0.5).astype(int)
    collided = 0
    for k in range(bursts):
        rows = burst == k
        first = np.argmin(np.where(rows, b["done"], np.inf))
        collided += bool(b["dropped"][first])
    return collided


@pytest.mark.parametrize("n", [2, 4])
def test_csma_ca_first_transmission_collides_as_the_backoff_combinatorics_say(n):
    """802.15.4 defaults (macMinBE 3: W = 8): bursts of one broadcast frame per node at the
    same instant on an idle channel."""
    bursts = 1500
    collided = _first_transmission_collisions(n, bursts, seed=n, max_backoffs=4)
    p = _first_collision_probability(n, 8)
    se = math.sqrt(p * (1 - p) / bursts)
    assert abs(collided / bursts - p) < 4 * se, (collided / bursts, p, se)


def test_csma_ca_isolated_node_delay_is_backoff_cca_turnaround_and_transmission():
    """Alone on the channel, a frame waits U{0..7} unit backoff periods (20 symbols),
    a CCA (8) and the turnaround (12), then transmits: 8 equally likely delays."""
    env, medium, rec = _medium("csma", 2, [[1], []], seed=5)
    K = 4000

    def source():
        for k in range(K):
            yield env.timeout(k * 0.05 - env.now)
            medium.submit(Packet(0, (1,), -1, env.now, 8 * 18))

    env.process(source())
    env.run(until=K * 0.05)
    b = rec.background_arrays()
    sym = 16e-6
    tx = 8 * 18 / 250e3
    slots = (b["done"] - b["created"] - 20 * sym - tx) / (20 * sym)
    assert not b["dropped"].any()
    np.testing.assert_allclose(slots, np.round(slots), atol=1e-6)
    counts = np.bincount(np.round(slots).astype(int), minlength=8)
    assert counts.size == 8
    se = math.sqrt(K * (1 / 8) * (7 / 8))
    assert np.all(np.abs(counts - K / 8) < 4 * se), counts


def test_switched_burst_to_one_port_leaves_back_to_back_and_overflows_the_buffer():
    """N - 1 senders, one packet each to node 0 at t = 0 over idle uplinks: all reach the
    switch after one transmission time C; the port sends them back to back (k-th at
    (k + 1) C) and drops all but switch_buffer + 1 (drop-tail)."""
    N, buffer = 7, 2
    env, medium, rec = _medium("switched", N, [[]] + [[0]] * (N - 1), bit_rate=1e6,
                               switch_buffer=buffer)
    bits = 8 * 100.0
    C = bits / 1e6
    for i in range(1, N):
        medium.submit(Packet(i, (0,), -1, 0.0, bits))
    env.run(until=1.0)
    b = rec.background_arrays()
    delivered = np.sort(b["done"][~b["dropped"]])
    np.testing.assert_allclose(delivered, C * np.arange(2, buffer + 3), rtol=1e-12)
    assert int(b["dropped"].sum()) == (N - 1) - (buffer + 1)


def test_point_to_point_links_have_their_own_rate_and_propagation():
    """A lone packet on a link takes its serialisation time plus its propagation, with the
    link's own values where ``per_link`` gives them."""
    env, medium, rec = _medium("point-to-point", 3, [[1, 2], [], []], bit_rate=1e3,
                               propagation=0.5,
                               per_link=[{"from": 0, "to": 2, "bit_rate": 4e3,
                                          "propagation": 0.125}])
    medium.submit(Packet(0, (1, 2), -1, 0.0, 1000.0))
    env.run(until=10.0)
    b = rec.background_arrays()
    done = dict(zip(b["destination"].tolist(), b["done"].tolist(), strict=True))
    assert done == {1: pytest.approx(1.0 + 0.5), 2: pytest.approx(0.25 + 0.125)}
