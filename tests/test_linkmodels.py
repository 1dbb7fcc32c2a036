"""Link models: delay distributions, losses, outages, buffers, serialisation, replay.

Statistical tolerances: a discrete distribution passes a chi-square goodness-of-fit
test (bins with expected count < 5 merged into the tail) with p > 1e-4; a continuous
one a Kolmogorov-Smirnov test with p > 1e-4; means, loss rates and burst lengths lie
within 4 standard errors of the configured value. Every test uses fixed seeds, so the
outcome is deterministic; the tolerances say how unlikely a false failure would be.
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import replace

import numpy as np
import pytest
from helpers import lcsys
from netsim.models.delays import FixedDelays, latency_to_steps
from netsim.models.linkmodels import (
    BernoulliLoss,
    ConstantDelay,
    DistributionDelays,
    EmpiricalDelay,
    GeometricDelay,
    GilbertElliottLoss,
    LinkModel,
    Outages,
    SerialisedDelays,
    ShiftedGamma,
    ShiftedPareto,
    UniformDelay,
    load_latency_csv,
)
from netsim.models.plant import LinearPlant
from netsim.models.scenario import ScenarioError, builtin_scenarios, parse_scenario
from netsim.models.seeding import child_sequence, stream
from scipy import stats

from netsim.kernel import AgentSpec, Simulation
from netsim.links import ConfiguredLink, Link

P_MIN = 1e-4
N_DRAWS = 20000


# -- helpers ---------------------------------------------------------------------------


class Stub:
    """An estimator that accepts every message and does no arithmetic."""

    def __init__(self) -> None:
        self.estimate = np.zeros(1)
        self.arrivals: list[tuple[int, int]] = []

    def message_arrived(self, sender, sent_step, payload):
        self.arrivals.append((sender, sent_step))
        return True

    def step(self, k, y):
        return self.estimate


class Scripted:
    """Step delays given per sending step (deterministic), same on every link."""

    unit = "steps"
    time_invariant = False

    def __init__(self, delays, default=0):
        self.delays = list(delays)
        self.default = default
        self.max_delay = max(self.delays + [default])

    def draw(self, sender, receiver, send_step):
        return self.delays[send_step] if send_step < len(self.delays) else self.default


class Recorder:
    """Observer collecting drops (message, reason, time) and deliveries."""

    def __init__(self):
        self.dropped = []
        self.delivered = []
        self.sent = []

    def on_plant(self, k, state, measurements):
        pass

    def on_sent(self, message):
        self.sent.append(message)

    def on_delivered(self, message, accepted):
        self.delivered.append(message)

    def on_dropped(self, message, reason="", drop_time=None):
        self.dropped.append((message, reason, drop_time))

    def on_update(self, agent, k, estimate, delays):
        pass


def two_agents(delay_model, steps, *, link_models=None, sample_period=1.0):
    """Two agents, 0 <-> 1, scalar plant; returns (simulation, result, recorder)."""
    plant = LinearPlant(np.array([[0.5]]), (np.eye(1), np.eye(1)), 0.01 * np.eye(1),
                        (0.01 * np.eye(1), 0.01 * np.eye(1)), np.zeros(1), np.eye(1))
    agents = [AgentSpec(Stub(), lambda ys, i=i: ys[i], [1 - i]) for i in range(2)]
    rec = Recorder()
    sim = Simulation(plant, agents, delay_model, stream(0, "plant"),
                     sample_period=sample_period, record_messages=True, observer=rec,
                     link_models=link_models)
    return sim, sim.run(steps), rec


def chi_square_p(observed: np.ndarray, expected_prob: np.ndarray) -> float:
    """Chi-square p-value, merging bins with expected count < 5 (tail included)."""
    n = observed.sum()
    expected = expected_prob * n
    obs, exp = [], []
    acc_o = acc_e = 0.0
    for o, e in zip(observed, expected, strict=True):
        acc_o += o
        acc_e += e
        if acc_e >= 5:
            obs.append(acc_o)
            exp.append(acc_e)
            acc_o = acc_e = 0.0
    if acc_e > 0 or acc_o > 0:
        obs[-1] += acc_o
        exp[-1] += acc_e
    exp = np.array(exp) * (n / np.sum(exp))
    return float(stats.chisquare(obs, exp).pvalue)


def draws(dist, n=N_DRAWS, mode="asynchronous"):
    model = DistributionDelays(dist, mode, seed=3, static_seed=4)
    return np.array([model.draw(0, 1, s) for s in range(n)])


# -- delay distributions -----------------------------------------------------------------


@pytest.mark.parametrize("dist", [
    UniformDelay(0, 7, "steps"),
    UniformDelay(2, 2, "steps"),
    GeometricDelay(0.3, shift=1),
    EmpiricalDelay([0, 1, 1, 2, 5, 5, 5, 9], unit="steps"),
], ids=["uniform-steps", "uniform-degenerate", "geometric", "empirical-steps"])
def test_discrete_delays_match_their_distribution(dist):
    x = draws(dist).astype(int)
    top = int(x.max())
    observed = np.bincount(x, minlength=top + 1).astype(float)
    k = np.arange(top + 1)
    cdf = dist.cdf(k)
    prob = np.diff(np.concatenate([[0.0], cdf]))
    prob[-1] += 1.0 - cdf[-1]  # tail beyond the largest draw
    if np.count_nonzero(prob) > 1:
        assert chi_square_p(observed, prob) > P_MIN
    else:
        assert np.all(x == dist.upper)
    se = x.std(ddof=1) / math.sqrt(len(x))
    assert abs(x.mean() - dist.mean()) <= 4 * se + 1e-12


@pytest.mark.parametrize("dist", [
    UniformDelay(0.2, 3.5, "time"),
    ShiftedGamma(2.0, 0.6, shift=0.4),
    ShiftedPareto(3.5, 1.2, shift=0.3),
    EmpiricalDelay(np.linspace(0.05, 4.0, 400) ** 1.5, unit="time"),
], ids=["uniform-time", "gamma", "pareto", "empirical-time"])
def test_continuous_latencies_match_their_distribution(dist):
    x = draws(dist)
    if isinstance(dist, EmpiricalDelay):
        # resampling a finite set: compare frequencies of each value (chi-square)
        values, counts = np.unique(x, return_counts=True)
        ref, ref_counts = np.unique(dist.values, return_counts=True)
        np.testing.assert_array_equal(values, ref)
        assert chi_square_p(counts.astype(float), ref_counts / ref_counts.sum()) > P_MIN
    else:
        assert stats.kstest(x, dist.cdf).pvalue > P_MIN
    se = x.std(ddof=1) / math.sqrt(len(x))
    assert abs(x.mean() - dist.mean()) <= 4 * se


def test_heavy_tail_pareto_quantiles():
    dist = ShiftedPareto(1.5, 1.0, shift=0.0)  # infinite variance: compare quantiles
    x = draws(dist, 50000)
    for q in (0.5, 0.9, 0.99):
        # binomial standard error of the empirical CDF at the true quantile
        se = math.sqrt(q * (1 - q) / len(x))
        assert abs(np.mean(x <= dist.quantile(q)) - q) <= 4 * se


def test_kernel_maps_latencies_to_steps_by_the_design_rule():
    """Messages through the kernel: d = ceil(l / Ts) - 1 (clamped at 0), arrival = send + l,
    and the step delays follow the distribution the rule implies (chi-square)."""
    ts = 0.5
    dist = ShiftedGamma(2.0, 0.4, shift=0.1)
    model = DistributionDelays(dist, "asynchronous", seed=5, sample_period=ts)
    sim, result, rec = two_agents(model, 4000, sample_period=ts)
    assert result.messages_sent == len(rec.sent) == 2 * 4001
    lat = np.array([m.arrival_time - m.send_time for m in rec.sent])
    d = np.array([m.delay_steps for m in rec.sent])
    assert all(latency_to_steps(max(v, 0.0), ts) == k for v, k in zip(lat, d, strict=True)
               if abs(v / ts - round(v / ts)) > 1e-9)
    assert stats.kstest(lat, dist.cdf).pvalue > P_MIN
    edges = np.arange(d.max() + 2) * ts
    prob = np.diff(np.concatenate([[0.0], dist.cdf(edges[1:])]))
    prob[-1] += 1 - dist.cdf(edges[-1])
    assert chi_square_p(np.bincount(d, minlength=len(prob)).astype(float), prob) > P_MIN
    # the link is the plain, fastest one
    assert all(type(link) is Link for link in sim.links.values())


def test_synchronous_mode_shares_each_step_and_fixed_mode_is_constant():
    sync = DistributionDelays(UniformDelay(0, 9), "synchronous", seed=1)
    assert all(sync.draw(0, 1, s) == sync.draw(1, 0, s) == sync.draw(2, 3, s)
               for s in range(200))
    assert len({sync.draw(0, 1, s) for s in range(200)}) > 5
    fixed_a = DistributionDelays(UniformDelay(0, 9), "fixed", seed=1, static_seed=7)
    fixed_b = DistributionDelays(UniformDelay(0, 9), "fixed", seed=2, static_seed=7)
    for link in [(0, 1), (1, 0), (2, 3)]:
        values = {fixed_a.draw(*link, s) for s in range(50)}
        assert len(values) == 1
        assert values == {fixed_b.draw(*link, 0)}  # the same in every trial
    assert fixed_a.time_invariant and not sync.time_invariant
    asyn = DistributionDelays(UniformDelay(0, 9), "asynchronous", seed=1)
    assert [asyn.draw(0, 1, s) for s in range(20)] != [asyn.draw(1, 0, s) for s in range(20)]


def test_empirical_csv(tmp_path):
    good = tmp_path / "lat.csv"
    good.write_text("latency_ms\n12.5\n30\n\n7.25\n")
    dist = load_latency_csv(good, scale=0.01)
    np.testing.assert_allclose(sorted(dist.values), [0.0725, 0.125, 0.3])
    bad = {
        "two.csv": ("1.0,2.0\n", "line 1: expected one column"),
        "text.csv": ("1.0\nabc\n", "line 2: not a number"),
        "neg.csv": ("1.0\n-2\n", "line 2: latency must be finite and >= 0"),
        "nan.csv": ("nan\n", "line 1"),
        "empty.csv": ("header\n", "has no latencies"),
    }
    for name, (text, message) in bad.items():
        path = tmp_path / name
        path.write_text(text)
        with pytest.raises(ValueError, match=message) as info:
            load_latency_csv(path)
        assert name in str(info.value)
    with pytest.raises(ValueError, match="cannot read latency file .*missing.csv"):
        load_latency_csv(tmp_path / "missing.csv")


# -- losses and outages ------------------------------------------------------------------


def test_bernoulli_loss_rate():
    p = 0.2
    loss = BernoulliLoss(p, stream(0, "x"))
    lost = np.array([loss.drop_reason(s, s) is not None for s in range(N_DRAWS)])
    se = math.sqrt(p * (1 - p) / N_DRAWS)
    assert abs(lost.mean() - p) <= 4 * se


def runs_of(flags: np.ndarray, value: bool) -> np.ndarray:
    """Lengths of the maximal runs of ``value`` (the first and last run dropped: censored)."""
    change = np.flatnonzero(np.diff(flags.astype(int))) + 1
    bounds = np.concatenate([[0], change, [len(flags)]])
    lengths = np.diff(bounds)
    kinds = flags[bounds[:-1]]
    return lengths[1:-1][kinds[1:-1] == value]


def test_gilbert_elliott_mean_burst_length_and_loss_rate():
    p, r = 0.05, 0.25  # mean burst 4 messages, mean gap 20, loss rate 1/6
    ge = GilbertElliottLoss(p, r, stream(1, "ge"))
    n = 60000
    lost = np.array([ge.drop_reason(s, s) is not None for s in range(n)])
    bursts = runs_of(lost, True)
    # bursts are geometric with mean 1/r, standard deviation sqrt(1-r)/r
    se = math.sqrt(1 - r) / r / math.sqrt(len(bursts))
    assert abs(bursts.mean() - ge.mean_burst_length) <= 4 * se
    gaps = runs_of(lost, False)
    se_gap = math.sqrt(1 - p) / p / math.sqrt(len(gaps))
    assert abs(gaps.mean() - 1 / p) <= 4 * se_gap
    # loss rate: a renewal-reward estimate with independent cycles of burst + gap
    cycles = min(len(bursts), len(gaps))
    ratio_se = ge.loss_rate * math.sqrt((np.var(bursts) / bursts.mean() ** 2 + np.var(gaps)
                                         / gaps.mean() ** 2) / cycles)
    assert abs(lost.mean() - ge.loss_rate) <= 4 * ratio_se
    assert ge.loss_rate == pytest.approx(p / (p + r))


def test_gilbert_elliott_state_loss_probabilities():
    ge = GilbertElliottLoss(0.1, 0.1, stream(2, "ge"), loss_good=0.05, loss_bad=0.5)
    reasons = [ge.drop_reason(s, s) for s in range(N_DRAWS)]
    rate = np.mean([x is not None for x in reasons])
    assert {x for x in reasons if x} == {GilbertElliottLoss.REASON_GOOD,
                                         GilbertElliottLoss.REASON_BAD}
    # bursty chain: allow 4 standard errors of a generous effective sample size (n / 20)
    se = math.sqrt(ge.loss_rate * (1 - ge.loss_rate) / (N_DRAWS / 20))
    assert abs(rate - ge.loss_rate) <= 4 * se


def test_outages_drop_exactly_the_messages_sent_in_the_intervals():
    intervals = [(5, 9), (20, 21), (30, 30), (40, 45), (43, 50)]
    model = LinkModel(outages=Outages(intervals))
    sim, result, rec = two_agents(FixedDelays(default=1), 60,
                                  link_models={(0, 1): model})
    down = {s for a, b in [(5, 9), (20, 21), (40, 50)] for s in range(a, b)}
    dropped = [(m.sender, m.sent_step) for m, reason, _ in rec.dropped]
    assert dropped == [(0, s) for s in sorted(down)]
    assert all(reason == "outage" for _, reason, _ in rec.dropped)
    assert result.messages_dropped == len(down) == result.drop_reasons["outage"]
    assert isinstance(sim.links[(0, 1)], ConfiguredLink) and type(sim.links[(1, 0)]) is Link
    delivered_01 = {m.sent_step for m in rec.delivered if m.sender == 0}
    assert delivered_01 == set(range(0, 59)) - down  # sent at 59, 60 arrive after the end


def test_loss_through_the_kernel_is_counted_and_traced():
    model = LinkModel(loss=BernoulliLoss(0.3, stream(4, "loss")))
    sim, result, rec = two_agents(FixedDelays(default=0), 3000, link_models={(1, 0): model})
    lost = [m for m, reason, _ in rec.dropped]
    assert all(m.sender == 1 and reason == "loss: bernoulli" for m, reason, _ in rec.dropped)
    assert result.messages_dropped == len(lost) == sim.links[(1, 0)].dropped
    assert result.messages_sent == result.messages_delivered + result.messages_dropped + 2
    se = math.sqrt(0.3 * 0.7 / 3001)
    assert abs(len(lost) / 3001 - 0.3) <= 4 * se


# -- buffers ---------------------------------------------------------------------------


def buffered(delays, capacity, policy, steps=20):
    model = LinkModel(buffer_capacity=capacity, buffer_policy=policy)
    return two_agents(Scripted(delays), steps, link_models={(0, 1): model})


def drops_on_01(rec):
    return [(m.sequence, reason, t) for m, reason, t in rec.dropped if m.sender == 0]


def test_drop_tail_drops_the_new_messages_while_full():
    # messages 0 and 1 take 5 steps (arrive at 6 and 7); 2.. take 0 (arrive next step)
    sim, result, rec = buffered([5, 5], 2, "drop-tail")
    # full (0 and 1 in flight) at the sends of steps 2..5; message 0 leaves at 6
    assert drops_on_01(rec) == [(s, "buffer full (drop-tail)", float(s)) for s in range(2, 6)]
    assert result.drop_reasons == {"buffer full (drop-tail)": 4}


def test_drop_oldest_cancels_the_oldest_in_flight_message():
    sim, result, rec = buffered([5, 5], 2, "drop-oldest")
    # at step 2 the buffer holds 0 and 1: message 0 is cancelled, 2 accepted
    assert drops_on_01(rec) == [(0, "buffer full (drop-oldest)", 2.0)]
    delivered = [m.sequence for m in rec.delivered if m.sender == 0]
    assert 0 not in delivered and 1 in delivered
    assert sim.links[(0, 1)].delivered == len(delivered)
    assert result.messages_dropped == 1


def test_keep_latest_drops_superseded_arrivals():
    # message 0 takes 5 steps: messages 1..5 overtake it; it is dropped on arrival at 6
    sim, result, rec = buffered([5], None, "keep-latest")
    assert drops_on_01(rec) == [(0, "superseded (keep-latest)", 6.0)]
    # with capacity 2 as well: 0 cancelled at step 2 (drop-oldest), 1 superseded at 7
    sim, result, rec = buffered([5, 5], 2, "keep-latest")
    assert drops_on_01(rec) == [(0, "buffer full (drop-oldest)", 2.0),
                                (1, "superseded (keep-latest)", 7.0)]
    arrivals = [s for sender, s in sim.agents[1].estimator.arrivals if sender == 0]
    assert arrivals == sorted(arrivals)  # delivered in order


def test_tau_plus_one_buffer_never_drops_delays_within_the_bound():
    tau = 4
    model = DistributionDelays(UniformDelay(0, tau), "asynchronous", seed=9)
    links = {link: LinkModel(buffer_capacity=tau + 1, buffer_policy="drop-oldest")
             for link in [(0, 1), (1, 0)]}
    sim, result, rec = two_agents(model, 3000, link_models=links)
    assert result.messages_dropped == 0
    assert max(len(link.in_flight) for link in sim.links.values()) <= tau + 1
    # delays up to tau + 2: it overflows, and every message it drops is a late one
    model = DistributionDelays(UniformDelay(0, tau + 2), "asynchronous", seed=9)
    sim, result, rec = two_agents(model, 3000, link_models=links)
    assert result.messages_dropped > 0
    assert all(m.delay_steps > tau for m, _, _ in rec.dropped)


def test_tau_plus_one_buffer_from_the_scenario():
    data = _lcsys_data()
    data["delays"] = {"model": "asynchronous", "tau": 3}
    data["links"] = {"buffer": {"capacity": "tau+1"}}
    scenario = parse_scenario(data, "x.toml")
    model = scenario.delay_model(child_sequence(0, "trial", 0))
    link = model.link(0, 1)
    assert link.buffer_capacity == 4 and link.buffer_policy == "drop-oldest"
    assert scenario.with_tau(6).delay_model(0).link(0, 1).buffer_capacity == 7


# -- serialisation ----------------------------------------------------------------------


def test_serialisation_adds_size_over_bandwidth():
    size, bandwidth, ts = 8000.0, 16000.0, 0.25   # 0.5 time units = 2 periods
    base = DistributionDelays(ConstantDelay(0.3, "time"), "asynchronous", sample_period=ts)
    model = SerialisedDelays(base, size / bandwidth, ts)
    sim, result, rec = two_agents(model, 50, sample_period=ts)
    for m in rec.sent:
        assert m.arrival_time - m.send_time == pytest.approx(0.3 + 0.5, abs=1e-12)
        assert m.delay_steps == latency_to_steps(0.8, ts) == 3
    # on a step-delay model, d counts as the latency (d + 1) Ts
    steps = SerialisedDelays(FixedDelays(default=2), 0.1, 1.0)
    assert steps.draw(0, 1, 0) == pytest.approx(3.1) and steps.max_delay == 3


def test_serialisation_from_the_scenario():
    data = _lcsys_data()
    data["delays"] = {"model": "none"}
    data["links"] = {"delay": {"distribution": "constant", "value": 0.5, "unit": "time"},
                     "bandwidth": 384.0,
                     "per_link": [{"from": 0, "to": 1, "message_size": 768.0}]}
    scenario = parse_scenario(data, "x.toml")
    model = scenario.delay_model(0)
    # n = 6 doubles = 384 bits by default: 1 time unit; link 0->1 sends 768 bits: 2
    assert model.link(1, 2).delay.draw(1, 2, 0) == pytest.approx(1.5)
    assert model.link(0, 1).delay.draw(0, 1, 0) == pytest.approx(2.5)
    assert scenario.max_delay == 2 and scenario.delay_bound == 2


# -- scenario schema ---------------------------------------------------------------------


def _lcsys_data():
    return tomllib.loads(builtin_scenarios()["lcsys2022-heterogeneous"].read_text())


def test_links_table_builds_per_link_models(tmp_path):
    csv = tmp_path / "lat.csv"
    csv.write_text("\n".join(str(v) for v in [0.5, 1.5, 2.5, 3.0]))
    data = _lcsys_data()
    data["links"] = {
        "delay": {"distribution": "pareto", "alpha": 2.5, "scale": 0.5, "shift": 0.2},
        "loss": {"model": "gilbert-elliott", "p": 0.02, "r": 0.5},
        "outages": [[10, 20]],
        "bound": 6,
        "per_link": [
            {"from": 0, "to": 1, "delay": {"distribution": "empirical", "file": "lat.csv"},
             "loss": {"model": "none"}},
            {"from": 2, "to": 3, "buffer": {"capacity": 3, "policy": "drop-tail"}},
        ],
    }
    scenario = parse_scenario(data, str(tmp_path / "s.toml"))
    assert scenario.delay_bound == 6
    model = scenario.delay_model(child_sequence(1, "trial", 0))
    assert model.link(0, 1).loss is None and model.link(0, 1).delay.distribution.values.size == 4
    assert isinstance(model.link(1, 2).loss, GilbertElliottLoss)
    assert model.link(2, 3).buffer_capacity == 3
    assert not model.time_invariant
    summary = scenario.summary()["link_models"]
    assert summary["per_link"]["0->1"]["delay"]["distribution"] == "empirical"
    with pytest.raises(ScenarioError, match="delays.tau"):
        scenario.with_tau(3)


def test_scenario_without_links_is_unchanged():
    scenario = lcsys()
    assert scenario.link_spec is None
    assert isinstance(scenario.delay_model(0), FixedDelays)


@pytest.mark.parametrize("links, key", [
    ({"foo": 1}, "links.foo"),
    ({"delay": {"distribution": "weibull"}}, "links.delay.distribution"),
    ({"delay": {"distribution": "gamma", "shape": -1, "scale": 1}}, "links.delay.shape"),
    ({"delay": {"distribution": "gamma", "shape": 1}}, "links.delay.scale"),
    ({"delay": {"distribution": "gamma", "shape": 1, "scale": 1, "unit": "steps"}},
     "links.delay.unit"),
    ({"delay": {"distribution": "uniform", "low": 3, "high": 1}}, "links.delay.high"),
    ({"delay": {"distribution": "uniform", "low": 0, "high": 2, "mode": "sometimes"}},
     "links.delay.mode"),
    ({"delay": {"distribution": "geometric", "p": 0}}, "links.delay.p"),
    ({"delay": {"distribution": "empirical", "file": "nope.csv"}}, "links.delay.file"),
    ({"delay": {"distribution": "trace", "file": "nope.mcap"}}, "links.delay.file"),
    ({"loss": {"model": "bernoulli", "p": 1.5}}, "links.loss.p"),
    ({"loss": {"model": "gilbert-elliott", "p": 0.1}}, "links.loss.r"),
    ({"loss": {"model": "bernoulli", "p": 0.1, "r": 0.2}}, "links.loss.r"),
    ({"buffer": {"capacity": 0}}, "links.buffer.capacity"),
    ({"buffer": {"capacity": "lots"}}, "links.buffer.capacity"),
    ({"buffer": {"capacity": 2, "policy": "random-early"}}, "links.buffer.policy"),
    ({"buffer": {"policy": "drop-tail"}}, "links.buffer.capacity"),
    ({"outages": [[5, 2]]}, "links.outages[0]"),
    ({"outages": [5, 2]}, "links.outages[0]"),
    ({"bandwidth": 0}, "links.bandwidth"),
    ({"message_size": -1}, "links.message_size"),
    ({"bound": -1}, "links.bound"),
    ({"per_link": [{"from": 0, "to": 2}]}, "links.per_link[0]"),
    ({"per_link": [{"from": 0, "to": 1, "loss": {"model": "bernoulli", "p": -0.1}}]},
     "links.per_link[0].loss.p"),
    ({"per_link": [{"from": 0, "to": 1, "lost": 1}]}, "links.per_link[0].lost"),
])
def test_bad_links_tables_name_the_key(tmp_path, links, key):
    data = _lcsys_data()
    data["links"] = links
    with pytest.raises(ScenarioError) as info:
        parse_scenario(data, str(tmp_path / "bad.toml"))
    assert info.value.key == key, str(info.value)


def test_bad_csv_in_scenario_names_the_file(tmp_path):
    (tmp_path / "bad.csv").write_text("0.5\nfast\n")
    data = _lcsys_data()
    data["links"] = {"delay": {"distribution": "empirical", "file": "bad.csv"}}
    with pytest.raises(ScenarioError, match=r"bad\.csv, line 2") as info:
        parse_scenario(data, str(tmp_path / "s.toml"))
    assert info.value.key == "links.delay.file"


# -- trace replay ------------------------------------------------------------------------


@pytest.fixture(scope="module")
def gains():
    from netsim.runner import scenario_gains

    return scenario_gains(lcsys())


def _record(tmp_path, scenario, gains, name, steps=80):
    from netsim.traces.reader import read_trace
    from netsim.traces.recorder import TraceRecorder

    from netsim.runner import run_trial

    path = tmp_path / f"{name}.mcap"
    with TraceRecorder.for_run(path, scenario, gains, "compensated", 0, seed=0,
                               steps=steps) as recorder:
        run_trial(scenario, "compensated", gains, child_sequence(11, "trial", 0), steps,
                  observer=recorder)
    return path, read_trace(path)


def _link_table(trace):
    out = {}
    for link in trace.links:
        for ev in trace.link_events(*link):
            out[(link, ev.sequence, ev.event)] = (ev.sent_step, ev.delay_steps,
                                                 ev.arrival_time, ev.reason if
                                                 ev.event == "dropped" else "")
    return out


@pytest.mark.parametrize("kind", ["steps", "latency"])
def test_trace_driven_delays_reproduce_the_recorded_ones_exactly(tmp_path, gains, kind):
    """Record a run with random delays and losses, replay its links in a new run (another
    trial seed, so different noise), and compare every link event message by message."""
    data = _lcsys_data()
    if kind == "steps":
        data["delays"] = {"model": "asynchronous", "tau": 4}
        data["links"] = {"loss": {"model": "gilbert-elliott", "p": 0.1, "r": 0.4},
                         "buffer": {"capacity": 3, "policy": "drop-oldest"}}
    else:
        data["delays"] = {"model": "none"}
        data["links"] = {"delay": {"distribution": "gamma", "shape": 2.0, "scale": 0.7},
                         "loss": {"model": "bernoulli", "p": 0.1}}
    original = parse_scenario(data, str(tmp_path / "orig.toml"))
    path, trace = _record(tmp_path, original, gains, "orig")
    replay_data = _lcsys_data()
    replay_data["delays"] = {"model": "none"}
    replay_data["links"] = {"delay": {"distribution": "trace", "file": path.name}}
    replayed = parse_scenario(replay_data, str(tmp_path / "replay.toml"))
    _, trace2 = _record(tmp_path, replayed, gains, "replay")
    a, b = _link_table(trace), _link_table(trace2)
    sent = {k: v for k, v in a.items() if k[2] == "sent"}
    assert sent and {k: v for k, v in b.items() if k[2] == "sent"} == sent
    delivered = {k[:2] for k in a if k[2] == "delivered"}
    assert delivered == {k[:2] for k in b if k[2] == "delivered"}
    dropped_a = {k[:2] for k in a if k[2] == "dropped"}
    assert dropped_a and dropped_a == {k[:2] for k in b if k[2] == "dropped"}
    assert all(b[k][3].startswith("trace: ") for k in b if k[2] == "dropped")


def test_trace_replay_beyond_the_recording_fails_clearly(tmp_path, gains):
    from netsim.runner import run_trial

    data = _lcsys_data()
    data["delays"] = {"model": "asynchronous", "tau": 2}
    path, _ = _record(tmp_path, parse_scenario(data, str(tmp_path / "o.toml")), gains, "o",
                      steps=20)
    data = _lcsys_data()
    data["links"] = {"delay": {"distribution": "trace", "file": str(path)}}
    replayed = parse_scenario(data, str(tmp_path / "r.toml"))
    with pytest.raises(ValueError, match="recorded 21 messages on link"):
        run_trial(replayed, "compensated", gains, 0, 40)


def test_link_seeds_are_independent_per_component():
    """A loss model on one link changes no delay draw anywhere (named streams)."""
    data = _lcsys_data()
    data["delays"] = {"model": "none"}
    data["links"] = {"delay": {"distribution": "uniform", "low": 0, "high": 5}}
    plain = parse_scenario(data, "a.toml")
    data["links"]["per_link"] = [{"from": 0, "to": 1,
                                  "loss": {"model": "bernoulli", "p": 0.5}}]
    lossy = parse_scenario(data, "b.toml")
    seed = child_sequence(3, "trial", 0)
    m1, m2 = plain.delay_model(seed), lossy.delay_model(seed)
    for j, i in plain.links:
        assert [m1.link(j, i).delay.draw(j, i, s) for s in range(50)] == \
            [m2.link(j, i).delay.draw(j, i, s) for s in range(50)]


def test_same_seed_same_drops(gains):
    from netsim.runner import run_trial

    data = _lcsys_data()
    data["links"] = {"loss": {"model": "gilbert-elliott", "p": 0.1, "r": 0.3},
                     "buffer": {"capacity": 2, "policy": "keep-latest"}}
    scenario = replace(parse_scenario(data, "x.toml"), steps=100)
    runs = [run_trial(scenario, "uncompensated", gains, child_sequence(5, "trial", 0))
            for _ in range(2)]
    assert runs[0].drop_reasons == runs[1].drop_reasons and runs[0].messages_dropped > 0
    np.testing.assert_array_equal(runs[0].estimates, runs[1].estimates)
    assert sum(runs[0].drop_reasons.values()) == runs[0].messages_dropped
