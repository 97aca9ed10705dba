"""The seeded link fault model and its in-flight queue (telesmooth.link.faults)."""

import math
import re

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from telesmooth.link.faults import LinkFaultConfig, LinkFaultModel, LinkQueue

PERIOD_S = 0.25   # the 4 Hz uplink
NUM_STATISTICAL = 20_000


def _fates(config, num_packets, period_s=PERIOD_S):
    dut = LinkFaultModel(config)
    return [dut.fate(k, k * period_s) for k in range(num_packets)]


def _first_copy_order(fates):
    """Packet indices in the order of their first delivered copy (lost ones left out)."""
    delivered = [(f.delivery_times_s[0], k) for k, f in enumerate(fates) if not f.lost]
    return [k for _, k in sorted(delivered)]


def _within_4_sigma(count, num, probability):
    sigma = math.sqrt(num * probability * (1 - probability))
    return abs(count - num * probability) <= 4 * sigma


# --- determinism -------------------------------------------------------------------------------

def test_fate_depends_only_on_seed_and_index_not_on_call_order():
    config = LinkFaultConfig(delay_s=0.5, jitter_s=0.4, loss_probability=0.2,
                             duplicate_probability=0.2, reorder_probability=0.2, seed=11)
    in_order = _fates(config, 300)
    dut = LinkFaultModel(config)
    shuffled = np.random.default_rng(0).permutation(300)
    by_index = {int(k): dut.fate(int(k), k * PERIOD_S) for k in shuffled}
    assert [by_index[k] for k in range(300)] == in_order
    # deliveries() (which counts) agrees with fate() and is repeatable.
    again = LinkFaultModel(config)
    assert [again.deliveries(k, k * PERIOD_S) for k in range(300)] == \
        [f.delivery_times_s for f in in_order]
    assert again.deliveries(17, 17 * PERIOD_S) == in_order[17].delivery_times_s


def test_fate_oracle_from_the_documented_draws():
    """Recomputes the fates from default_rng([seed, k]).random(5) and the module's formulas."""
    config = LinkFaultConfig(delay_s=1.5, jitter_s=0.3, loss_probability=0.3,
                             duplicate_probability=0.4, duplicate_spacing_s=0.02,
                             reorder_probability=0.25, reorder_delay_s=0.7, seed=3)
    dut = LinkFaultModel(config)
    for k in range(200):
        t = 0.25 * k
        u_loss, u_dup, u_reorder, u_j1, u_j2 = np.random.default_rng([3, k]).random(5)
        if u_loss < 0.3:
            expected = ()
        else:
            hold = 0.7 if u_reorder < 0.25 else 0.0
            expected = [t + 1.5 + hold + 0.3 * u_j1]
            if u_dup < 0.4:
                expected.append(t + 1.5 + hold + 0.02 + 0.3 * u_j2)
            expected = tuple(sorted(expected))
        assert dut.fate(k, t).delivery_times_s == expected, k


def test_different_seeds_give_different_fates_and_probabilities_are_coupled():
    base = dict(loss_probability=0.2, seed=1)
    lost_1 = {k for k, f in enumerate(_fates(LinkFaultConfig(**base), 2000)) if f.lost}
    lost_2 = {k for k, f in enumerate(_fates(LinkFaultConfig(loss_probability=0.2, seed=2), 2000))
              if f.lost}
    assert lost_1 != lost_2
    # Same seed, larger probability: the same draws, so a superset of the lost packets.
    lost_more = {k for k, f in enumerate(_fates(LinkFaultConfig(loss_probability=0.4, seed=1),
                                                2000)) if f.lost}
    assert lost_1 < lost_more


def test_perfect_link_delivers_every_packet_once_at_its_send_time():
    for k, fate in enumerate(_fates(LinkFaultConfig(), 100)):
        assert fate.delivery_times_s == (k * PERIOD_S,)
        assert not (fate.lost or fate.duplicated or fate.held_back)


# --- statistics (fixed seeds, 4σ tolerances) ---------------------------------------------------

@pytest.mark.parametrize("probability", [0.01, 0.1, 0.5, 0.9])
def test_loss_fraction(probability):
    config = LinkFaultConfig(loss_probability=probability, seed=5)
    fates = _fates(config, NUM_STATISTICAL)
    lost = sum(f.lost for f in fates)
    assert _within_4_sigma(lost, NUM_STATISTICAL, probability), lost
    assert all(f.delivery_times_s == () for f in fates if f.lost)


@pytest.mark.parametrize("probability", [0.05, 0.3])
def test_duplicate_fraction_and_spacing(probability):
    config = LinkFaultConfig(delay_s=0.2, duplicate_probability=probability,
                             duplicate_spacing_s=0.01, loss_probability=0.1, seed=6)
    fates = _fates(config, NUM_STATISTICAL)
    kept = [f for f in fates if not f.lost]
    duplicated = [f for f in kept if f.duplicated]
    assert _within_4_sigma(len(duplicated), len(kept), probability), len(duplicated)
    assert all(len(f.delivery_times_s) == 2 for f in duplicated)
    assert all(len(f.delivery_times_s) == 1 for f in kept if not f.duplicated)
    np.testing.assert_allclose([f.delivery_times_s[1] - f.delivery_times_s[0]
                                for f in duplicated], 0.01, atol=1e-9)


def test_jitter_range_and_mean():
    jitter = 0.4
    config = LinkFaultConfig(delay_s=2.0, jitter_s=jitter, seed=8)
    extra = np.array([f.delivery_times_s[0] - k * PERIOD_S - 2.0
                      for k, f in enumerate(_fates(config, NUM_STATISTICAL))])
    assert extra.min() >= 0.0 and extra.max() <= jitter
    assert extra.min() < 0.01 * jitter and extra.max() > 0.99 * jitter   # fills the range
    assert abs(extra.mean() - jitter / 2) <= 4 * jitter / math.sqrt(12 * NUM_STATISTICAL)


def test_jitter_above_the_period_reorders_packets():
    fates = _fates(LinkFaultConfig(delay_s=0.5, jitter_s=2 * PERIOD_S, seed=9), 2000)
    order = _first_copy_order(fates)
    inversions = sum(a > b for a, b in zip(order, order[1:]))
    assert inversions > 100
    assert sorted(order) == list(range(2000))


def test_reorder_probability_holds_packets_back_so_later_ones_overtake():
    probability = 0.1
    config = LinkFaultConfig(delay_s=0.5, reorder_probability=probability,
                             reorder_delay_s=0.6, seed=10)
    dut = LinkFaultModel(config)
    for k in range(NUM_STATISTICAL):
        dut.deliveries(k, k * PERIOD_S)
    held = dut.counts()["reordered"]
    assert _within_4_sigma(held, NUM_STATISTICAL, probability), held
    fates = _fates(config, 2000)
    order = _first_copy_order(fates)
    assert order != sorted(order)
    # A held packet (hold 0.6 s > 2 periods) is overtaken by exactly its next two packets
    # unless those are held too.
    for k, fate in enumerate(fates[:-2]):
        if fate.held_back and not fates[k + 1].held_back and not fates[k + 2].held_back:
            assert order.index(k) == order.index(k + 2) + 1


@pytest.mark.parametrize("config", [
    LinkFaultConfig(delay_s=3.0),
    LinkFaultConfig(delay_s=0.75, loss_probability=0.3, duplicate_probability=0.3, seed=2),
    LinkFaultConfig(jitter_s=0.0, reorder_probability=0.5, reorder_delay_s=0.0, seed=4),
    LinkFaultConfig(jitter_s=0.9 * PERIOD_S, reorder_probability=0.0, seed=4),
])
def test_no_reordering_without_jitter_above_the_period_or_holds(config):
    fates = _fates(config, 3000)
    times = [t for f in fates for t in f.delivery_times_s]   # in packet order
    assert times == sorted(times)


def test_counts():
    config = LinkFaultConfig(loss_probability=0.2, duplicate_probability=0.3,
                             reorder_probability=0.1, seed=12)
    dut = LinkFaultModel(config)
    fates = []
    for k in range(1000):
        dut.deliveries(k, k * PERIOD_S)
        fates.append(dut.fate(k, k * PERIOD_S))   # fate() does not count
    assert dut.counts() == {
        "sent": 1000,
        "lost": sum(f.lost for f in fates),
        "duplicated": sum(f.duplicated for f in fates),
        "reordered": sum(f.held_back for f in fates),
    }
    assert not any(f.lost and (f.duplicated or f.held_back) for f in fates)


# --- outages -----------------------------------------------------------------------------------

def test_outages_lose_exactly_the_packets_sent_in_their_windows():
    config = LinkFaultConfig(delay_s=0.75, outages=((1.0, 2.0), (5.0, 5.25), (30.0, math.inf)))
    fates = _fates(config, 200)
    lost = [k for k, f in enumerate(fates) if f.lost]
    # Half-open windows: t = 1.0 (k = 4) is lost, t = 2.0 (k = 8) is delivered.
    assert lost == [4, 5, 6, 7, 20] + list(range(120, 200))
    assert all(f.in_outage for f in fates if f.lost)
    assert fates[8].delivery_times_s == (2.75,)


def test_outages_apply_to_send_time_not_delivery_time():
    config = LinkFaultConfig(delay_s=1.0, outages=((1.0, 1.5),))
    dut = LinkFaultModel(config)
    assert dut.fate(0, 0.5).delivery_times_s == (1.5,)   # in flight during the outage
    assert dut.fate(1, 1.25).lost


# --- validation --------------------------------------------------------------------------------

BAD_VALUES = [
    ("delay_s", -0.1), ("delay_s", math.nan), ("delay_s", math.inf), ("delay_s", "1"),
    ("delay_s", True), ("jitter_s", -1.0), ("jitter_s", math.inf),
    ("loss_probability", -0.01), ("loss_probability", 1.5), ("loss_probability", math.nan),
    ("duplicate_probability", 2), ("reorder_probability", -1),
    ("duplicate_spacing_s", -0.01), ("duplicate_spacing_s", math.nan),
    ("reorder_delay_s", -0.3), ("reorder_delay_s", math.inf),
    ("seed", -1), ("seed", 1.5), ("seed", "0"), ("seed", True),
]


@pytest.mark.parametrize("field, value", BAD_VALUES)
def test_invalid_field_is_named_with_its_value(field, value):
    with pytest.raises(ValueError, match=re.escape(f"{field} = {value!r}")):
        LinkFaultConfig(**{field: value})
    with pytest.raises(ValueError, match=re.escape(f"{field} = {value!r}")):
        LinkFaultConfig.from_mapping({field: value})


@pytest.mark.parametrize("outages, message", [
    ("1-2", "outages = '1-2'"),
    (((2.0, 1.0),), "outages[0] = (2.0, 1.0): end must be > start"),
    (((0.0, 1.0), (3.0, 3.0)), "outages[1] = (3.0, 3.0): end must be > start"),
    (((1.0,),), "outages[0] = (1.0,) must be a pair"),
    (((0.0, 1.0, 2.0),), "outages[0] = (0.0, 1.0, 2.0) must be a pair"),
    (((math.nan, 1.0),), "outages[0] = (nan, 1.0): start nan s must be finite"),
    (((0.0, math.nan),), "outages[0] = (0.0, nan): end must be > start"),
    ((("a", 1.0),), "outages[0] start = 'a' must be a number"),
    ((5.0,), "outages[0] = 5.0 must be a pair"),
])
def test_invalid_outage_windows_are_named(outages, message):
    with pytest.raises(ValueError, match=re.escape(message)):
        LinkFaultConfig(outages=outages)


def test_from_mapping_rejects_unknown_keys_naming_them():
    with pytest.raises(ValueError, match=re.escape("unknown key(s) ['colour', 'delay']")):
        LinkFaultConfig.from_mapping({"delay": 0.3, "colour": "red", "seed": 1})
    with pytest.raises(ValueError, match="must be a mapping"):
        LinkFaultConfig.from_mapping([("delay_s", 0.3)])


def test_from_mapping_normalises_and_round_trips():
    dut = LinkFaultConfig.from_mapping({"delay_s": 1, "outages": [[2, 3.5]], "seed": 4})
    assert dut == LinkFaultConfig(delay_s=1.0, outages=((2.0, 3.5),), seed=4)
    assert isinstance(dut.delay_s, float) and dut.outages == ((2.0, 3.5),)
    assert LinkFaultConfig.from_mapping(dut.to_mapping()) == dut
    assert LinkFaultConfig.from_mapping(None) == LinkFaultConfig()
    yaml = pytest.importorskip("yaml")
    assert LinkFaultConfig.from_mapping(yaml.safe_load(
        "{delay_s: 0.3, outages: [[1.0, .inf]]}")).outages == ((1.0, math.inf),)


def test_enabled():
    assert not LinkFaultConfig().enabled
    # Non-default but inert settings keep the link perfect.
    assert not LinkFaultConfig(duplicate_spacing_s=1.0, reorder_delay_s=2.0, seed=5).enabled
    assert not LinkFaultConfig(reorder_probability=0.5, reorder_delay_s=0.0).enabled
    for change in [dict(delay_s=0.1), dict(jitter_s=0.1), dict(loss_probability=0.1),
                   dict(duplicate_probability=0.1), dict(reorder_probability=0.1),
                   dict(outages=((1.0, 2.0),))]:
        assert LinkFaultConfig(**change).enabled, change


@pytest.mark.parametrize("index, time, message", [
    (-1, 0.0, "packet_index = -1"), (1.0, 0.0, "packet_index = 1.0"),
    (0, math.nan, "send_time_s = nan"), (0, math.inf, "send_time_s = inf"),
])
def test_fate_arguments_are_validated(index, time, message):
    with pytest.raises(ValueError, match=re.escape(message)):
        LinkFaultModel(LinkFaultConfig()).fate(index, time)


# --- LinkQueue ---------------------------------------------------------------------------------

def test_queue_delivers_in_delivery_time_order_against_a_sorted_oracle():
    config = LinkFaultConfig(delay_s=0.5, jitter_s=0.6, loss_probability=0.2,
                             duplicate_probability=0.3, reorder_probability=0.1, seed=21)
    dut = LinkQueue(config)
    oracle_model = LinkFaultModel(config)
    oracle = []
    delivered = []
    num_packets = 400
    for k in range(num_packets):
        t = k * PERIOD_S
        delivered += dut.due_deliveries(t)   # collect before sending, as a stepped system
        times = dut.send(k, t, f"packet {k}".encode())
        assert times == oracle_model.fate(k, t).delivery_times_s
        oracle += [(time_s, k, copy) for copy, time_s in enumerate(times)]
    delivered += dut.due_deliveries(math.inf)
    assert [(d.delivery_time_s, d.packet_index, d.copy) for d in delivered] == sorted(oracle)
    assert [d.payload for d in delivered] == [f"packet {k}".encode() for _, k, _ in sorted(oracle)]
    assert dut.pending() == 0
    assert dut.counts()["sent"] == num_packets


def test_queue_due_returns_only_what_is_due_and_pending_counts_copies():
    dut = LinkQueue(LinkFaultConfig(delay_s=1.0, duplicate_probability=1.0,
                                    duplicate_spacing_s=0.5))
    dut.send(0, 0.0, b"a")
    dut.send(1, 0.25, b"b")
    assert dut.pending() == 4
    assert dut.next_delivery_time() == 1.0
    assert dut.due(0.99) == []
    assert dut.due(1.0) == [b"a"]              # ≤ now is due
    assert dut.due(1.5) == [b"b", b"a"]        # b at 1.25, a's duplicate at 1.5
    assert dut.pending() == 1
    assert dut.due(10.0) == [b"b"]
    assert dut.next_delivery_time() is None and dut.due(20.0) == []


def test_queue_ties_are_broken_by_packet_index_then_copy():
    dut = LinkQueue(LinkFaultConfig(duplicate_probability=1.0, duplicate_spacing_s=0.0))
    for index in (3, 1, 2):
        dut.send(index, 0.0, f"p{index}".encode())
    out = dut.due_deliveries(0.0)
    assert [(d.packet_index, d.copy) for d in out] == [(1, 0), (1, 1), (2, 0), (2, 1),
                                                       (3, 0), (3, 1)]


def test_queue_shares_the_model_it_is_given():
    model = LinkFaultModel(LinkFaultConfig(loss_probability=1.0))
    dut = LinkQueue(model)
    assert dut.send(0, 0.0, b"x") == ()
    assert dut.model is model and model.counts()["lost"] == 1 and dut.pending() == 0


_configs = st.builds(
    LinkFaultConfig,
    delay_s=st.floats(0.0, 5.0),
    jitter_s=st.floats(0.0, 1.0),
    loss_probability=st.floats(0.0, 1.0),
    duplicate_probability=st.floats(0.0, 1.0),
    duplicate_spacing_s=st.floats(0.0, 0.5),
    reorder_probability=st.floats(0.0, 1.0),
    reorder_delay_s=st.floats(0.0, 2.0),
    seed=st.integers(0, 2**32),
)


@settings(max_examples=200, deadline=None)
@given(config=_configs, gaps=st.lists(st.floats(0.0, 1.0), min_size=1, max_size=40),
       poll_period=st.floats(0.01, 1.0))
def test_queue_property_delivers_only_what_was_sent_never_early_never_twice_unless_dup(
        config, gaps, poll_period):
    dut = LinkQueue(config)
    model = LinkFaultModel(config)
    send_times = np.cumsum(gaps)
    delivered = []   # (now, delivery)
    now = 0.0
    for k, send_time in enumerate(send_times):
        while now + poll_period <= send_time:
            now += poll_period
            delivered += [(now, d) for d in dut.due_deliveries(now)]
        dut.send(k, float(send_time), k.to_bytes(2, "big"))
    delivered += [(math.inf, d) for d in dut.due_deliveries(math.inf)]
    assert dut.pending() == 0
    times = [d.delivery_time_s for _, d in delivered]
    assert times == sorted(times)
    copies = {}
    for now_s, d in delivered:
        k = int.from_bytes(d.payload, "big")
        assert k == d.packet_index and 0 <= k < len(send_times)   # was sent
        assert d.delivery_time_s <= now_s
        assert d.delivery_time_s >= send_times[k] + config.delay_s - 1e-12
        copies[k] = copies.get(k, 0) + 1
    for k, send_time in enumerate(send_times):
        fate = model.fate(k, float(send_time))
        assert copies.get(k, 0) == len(fate.delivery_times_s)
        assert copies.get(k, 0) <= (2 if fate.duplicated else 1)
        assert (copies.get(k, 0) == 0) == fate.lost


def test_queue_deep_copy_is_independent():
    import copy

    dut = LinkQueue(LinkFaultConfig(delay_s=1.0, loss_probability=0.3, seed=2))
    for k in range(10):
        dut.send(k, 0.1 * k, bytes([k]))
    twin = copy.deepcopy(dut)
    assert twin.due(1.5) == dut.due(1.5)
    twin.send(10, 1.0, b"only in twin")
    assert twin.pending() == dut.pending() + len(twin.model.fate(10, 1.0).delivery_times_s)
    assert twin.counts()["sent"] == 11 and dut.counts()["sent"] == 10
