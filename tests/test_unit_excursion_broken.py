"""A relation broken beyond the learned range (issue 34 item 4, branch ``i34-feedloss``): a lost
feed sends its flow to 0 while its controller opens the valve to its limit; the flow's test
(reading the valve alone) and the valve's (reading the flow alone) are unknown there, their
inputs beyond what the unit learned, and on tep-studio's IDV6 the unit named the tags
downstream. ``Excursions`` now names a test's output and its one input where the test is
unknown at an alarm sample and the output left its range on the side opposite to where its
input's excursion takes it (the sign of the test's gain): no characteristic, steeper or
flatter, explains that. A flow and valve that left their ranges together (a rate step the
loop follows) keep the sign and are not named by it, nor is a test still known.

The figures here are written by hand (a flow ``F`` learned over 0.2–0.3, its valve ``V`` over
20–30 %, a tag ``D`` downstream holding the largest share of ``T²``), not read off the
plant the rule was chosen on."""

from __future__ import annotations

import numpy as np

from diag_plugin.diagnose.unittags import Excursions

TAGS = ["F", "V", "D"]


def _excursions() -> Excursions:
    """Two tests, ``F = f(V)`` (gain 0.01 per %) and ``V = f(F)`` (gain 100 % per unit), the
    third tag ``D`` ranked by ``T²`` only."""
    return Excursions(
        reads=[[(("V", 0), 1, 10.0)], [(("F", 0), 0, 1000.0)]],
        own=np.array([0, 1]),
        ranges={"F": (0.2, 0.3), "V": (20.0, 30.0)},
        keys={0: "F", 1: "V"},
        up={0: [(("V", 0), 1)], 1: [(("F", 0), 0)]},
        center=np.zeros(2),
        broken=[(0, 0, ("V", 0), 1, 0.01), (1, 1, ("F", 0), 0, 100.0)],
    )


def _name(f: float, v: float, known: bool = False) -> np.ndarray:
    """The shares of three alarm samples named, the flow at ``f`` and the valve at ``v``."""
    n = 3
    share = np.tile([0.05, 0.05, 0.9], (n, 1))
    s = np.zeros((n, 2)) if known else np.full((n, 2), np.nan)
    cols = {"F": np.full(n, f), "V": np.full(n, v)}
    return _excursions().name(share, np.zeros((n, 2)), s, cols.__getitem__, np.ones(n, bool))


def test_a_lost_feed_names_the_flow_and_its_valve_ahead_of_the_shares():
    """The flow at 0 (2 ranges below), the valve at 100 % (7 ranges above): the valve's
    positive gain says the flow should be above its range. Both named above every share of
    ``T²``, the one further beyond first (on main ``D`` kept the first place)."""
    out = _name(0.0, 100.0)
    assert np.allclose(out[:, 1], 1.0 + 7.0)  # V: 1 + its excess as a share of its range
    assert np.allclose(out[:, 0], 1.0 + 2.0)  # F
    assert (np.argsort(-out, axis=1)[:, :2] == [1, 0]).all()


def test_a_flow_and_valve_moved_together_beyond_the_range_are_not_named_by_it():
    """A rate step the loop follows: flow and valve both above their ranges, the sign the
    gains give; neither test is on, so nothing is named and the shares stay."""
    out = _name(0.6, 60.0)
    assert np.array_equal(out, np.tile([0.05, 0.05, 0.9], (3, 1)))


def test_a_known_test_is_left_to_its_residual():
    """The same opposite excursions with both tests known (their models answered there):
    their residuals speak, through the shares and the rule's other half."""
    out = _name(0.0, 100.0, known=True)
    assert np.array_equal(out, np.tile([0.05, 0.05, 0.9], (3, 1)))
