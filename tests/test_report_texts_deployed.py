"""The words of the reports about the chain and the limits: ``LinkFaultConfig.describe``,
``describe_chain`` (diagrams/scenario.py) and ``limits_text`` (scripts/simulate_report.py).

Oracles: the sentences written out here by hand from small hand-made inputs (fault configs,
metrics dicts whose ratios and shares are chosen so that every joint, ratio and share is
distinguishable in the text).
"""

import pytest

from telesmooth.diagrams.scenario import LoadScenario, describe_chain
from telesmooth.link.faults import LinkFaultConfig
from telesmooth.scripts.simulate_report import limits_text

# -- LinkFaultConfig.describe ---------------------------------------------------------------


@pytest.mark.parametrize("fields, words", [
    ({"delay_s": 2.0}, "delay 2 s"),
    ({"jitter_s": 0.15}, "jitter up to 0.15 s"),
    ({"loss_probability": 0.1}, "loss 10 %"),
    ({"duplicate_probability": 0.25}, "duplicates 25 %"),
    ({"reorder_probability": 0.3, "reorder_delay_s": 0.4}, "30 % held back 0.4 s"),
    ({"outages": [[1.5, 3.0]]}, "outage 1.5–3 s"),
])
def test_each_fault_in_words_with_its_seed(fields, words):
    # Catches: a fault left out of the words, a probability printed as a fraction (0.1 %)
    # instead of a percentage, the wrong value for a fault (e.g. the reorder probability
    # where its delay belongs), and the seed left out (the same words would then describe
    # runs whose packets fare differently).
    assert LinkFaultConfig(**fields, seed=7).describe() == f"{words}; seed 7"


def test_every_fault_together_in_order():
    # Catches: faults joined without separators or out of the documented order, a second
    # outage dropped (only the first window reported).
    config = LinkFaultConfig(delay_s=1.0, jitter_s=0.1, loss_probability=0.2,
                             duplicate_probability=0.05, reorder_probability=0.1,
                             reorder_delay_s=0.3, outages=[[2.0, 2.8], [10.0, 12.5]], seed=5)
    assert config.describe() == ("delay 1 s, jitter up to 0.1 s, loss 20 %, duplicates 5 %, "
                                 "10 % held back 0.3 s, outage 2–2.8 s, outage 10–12.5 s; "
                                 "seed 5")


@pytest.mark.parametrize("fields", [
    {}, {"seed": 9},
    # A reordering that holds nothing back, and a duplicate spacing without duplicates, are
    # no faults (``enabled`` is False): the words must agree.
    {"reorder_probability": 0.5, "reorder_delay_s": 0.0}, {"duplicate_spacing_s": 0.5},
])
def test_no_fault_is_a_perfect_link(fields):
    # Catches: an empty string or "; seed 9" for a perfect link, and words that name a fault
    # the link model does not apply.
    config = LinkFaultConfig(**fields)
    assert not config.enabled
    assert config.describe() == "a perfect link"


# -- describe_chain -------------------------------------------------------------------------

def test_describe_chain_names_the_chain_and_the_link():
    # Catches: the paper's chain described as guarded (or the deployed one as unguarded), and
    # the deployed chain's link not said (perfect, or which faults).
    paper = describe_chain(LoadScenario(scenario_text="{chain: paper}"))
    assert paper.startswith("the paper's chain: ")
    assert "no onboard packet checks and no link guard" in paper
    deployed = describe_chain(LoadScenario())
    assert deployed.startswith("the deployed chain: ")
    assert "crosses a perfect link," in deployed and "link guard" in deployed
    faulty = describe_chain(LoadScenario(
        scenario_text="{link: {faults: {loss_probability: 0.1, seed: 3}}}"))
    assert "crosses the seeded link fault model (loss 10 %; seed 3)," in faulty


# -- limits_text ----------------------------------------------------------------------------

NAMES = ["shoulder", "elbow", "wrist"]


def _statistics(over_limit, fraction):
    return {"max_over_limit": list(over_limit), "fraction_over_limit": list(fraction)}


WITHIN = {"joint_names": NAMES,
          "fd_acceleration": _statistics([0.5, 0.9, 1.0], [0.0, 0.0, 0.0]),
          "fd_jerk": _statistics([0.2, 0.99, 0.3], [0.0, 0.0, 0.0])}
# elbow breaks the acceleration limit 1.6× on a third of its samples; shoulder and wrist
# break the jerk limit 1.25× on 10 % and 4.8× on every sample; the others stay within.
OVER = {"joint_names": NAMES,
        "fd_acceleration": _statistics([0.4, 1.6, 0.9], [0.0, 1 / 3, 0.0]),
        "fd_jerk": _statistics([1.25, 0.8, 4.8], [0.1, 0.0, 1.0])}
OVER_WORDS = ("the acceleration limit on elbow (1.60× the limit, 33.3 % of the samples over), "
              "the jerk limit on shoulder (1.25× the limit, 10.0 % of the samples over) and "
              "the jerk limit on wrist (4.80× the limit, 100.0 % of the samples over)")


def _guard(limited, cut):
    return {"commands": 24, "limited": limited, "accepted_packets": 23,
            "largest_cut_rad": cut, "stream_distance_rad": 0.4319,
            "time_in_mode_s": {"track": 5.49, "stopping": 0.0, "held": 0.01,
                               "resuming": 0.5},
            "received": {"fd_acceleration": _statistics([0.97, 0.999, 0.5], [0, 0, 0]),
                         "fd_jerk": _statistics([0.3, 0.2, 0.95], [0, 0, 0])}}


def test_within_the_limits_it_says_so_and_nothing_else():
    # Catches: a joint at exactly its limit (wrist, 1.0) reported as breaking it, and a
    # sentence about enforcement when there is nothing to enforce.
    assert limits_text({"commands": WITHIN}) == (
        "The commands the ground sent stay within the FD acceleration and jerk limits on "
        "every joint.")
    assert limits_text({"commands": WITHIN, "guard": None}) == limits_text(
        {"commands": WITHIN})


def test_over_the_limits_in_the_papers_chain_names_each_joint_and_says_nothing_enforces():
    # Catches: a joint within the limits named, a joint over left out, a ratio or a share of
    # another joint or quantity (the acceleration's numbers under jerk), and the paper's chain
    # not saying that the robot got these commands unchanged.
    assert limits_text({"commands": OVER, "guard": None}) == (
        f"The commands the ground sent break {OVER_WORDS}. In the paper's chain nothing "
        "between the uplink and the robot enforces the limits: the robot received these "
        "commands as they were sent.")


def test_with_the_guard_it_says_what_was_limited_and_the_largest_cut_with_its_joint():
    # Catches: the largest cut attributed to the wrong joint (the first, the last, the
    # smallest: elbow's 432 mrad is the largest, neither end of the list), mrad printed as
    # rad, the counts swapped (commands, packets, limited), the received FD ratios not the
    # worst joint's, a mode with no time listed.
    text = limits_text({"commands": OVER, "guard": _guard(19, [0.0389, 0.4319, 0.2572])})
    assert text == (
        f"The commands the ground sent break {OVER_WORDS}. The onboard link guard issued 24 "
        "commands for the 23 packets it accepted and limited 19 of them, so that what "
        "reached the robot stays within the limits (its FD acceleration at most 1.00 and "
        "jerk at most 0.95 of the limit); its largest cut was 431.9 mrad on elbow, and the "
        "robot's command was at most 431.9 mrad (max over joints) from the newest accepted "
        "packet. Time per guard mode: track 5.49 s, held 0.01 s, resuming 0.50 s.")


def test_with_the_guard_and_nothing_limited_no_cut_is_reported():
    # Catches: a "largest cut" sentence (of 0.0 mrad on the first joint) when the guard
    # passed every command unchanged.
    text = limits_text({"commands": WITHIN, "guard": _guard(0, [0.0, 0.0, 0.0])})
    assert text == (
        "The commands the ground sent stay within the FD acceleration and jerk limits on "
        "every joint. The onboard link guard issued 24 commands for the 23 packets it "
        "accepted and limited 0 of them, so that what reached the robot stays within the "
        "limits (its FD acceleration at most 1.00 and jerk at most 0.95 of the limit). Time "
        "per guard mode: track 5.49 s, held 0.01 s, resuming 0.50 s.")
    assert "cut" not in text
