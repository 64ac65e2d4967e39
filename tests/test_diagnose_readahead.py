"""``diag diagnose`` reads its first piece while its start-up ends (issue 34, "Speed": 200,000
rows were ~1 s of start-up before the first replayed row): the historian's read is under way
before the libraries only the replay needs are imported, and the reader
(:class:`~diag_plugin.diagnose.readahead.ReadAhead`) starts its first read when made.

The example valve unit on a simulator seed used nowhere else (812).
"""

from __future__ import annotations

import threading

from helpers import read_probe

#: ``diag`` with its read watched at the first import of scipy.special (helpers.read_probe)
PROBE = read_probe("scipy.special")


def test_first_piece_read_before_the_replays_imports(tmp_path):
    """The first piece is being read when ``scipy.special`` is imported (numba's registries
    follow it): the read overlaps the rest of the start-up. Before the read ahead the pieces
    were asked for only after those imports ([False])."""
    from helpers import probed_valve_diagnose

    out, line = probed_valve_diagnose(tmp_path, PROBE, seed=812)
    assert line == "RESULT 0 [True]", line
    assert '"samples": 8640' in out


def test_read_ahead_starts_at_once_and_keeps_order():
    """The first item is asked for when the reader is made (before any iteration), the
    items come in order, and each next one is asked for while the caller has the last."""
    from diag_plugin.diagnose.readahead import ReadAhead

    started, asked = threading.Event(), []

    def items():
        started.set()
        for i in range(4):
            asked.append(i)
            yield i

    with ReadAhead(items(), ahead=1) as r:
        assert started.wait(30)
        got = []
        for x in r:
            got.append(x)
            if x < 3:
                r._next[-1].result()  # the next item is read while this one is used
                assert asked[-1] == x + 1
    assert got == [0, 1, 2, 3]


def test_read_ahead_reads_two_before_the_first_is_taken():
    """By default two items are read before the caller takes the first (the command's
    small first piece and the whole second one beside its start-up, issue 34), in order,
    then one more as each is taken, never more than two ahead, each once."""
    from diag_plugin.diagnose.readahead import ReadAhead

    asked = []
    both = threading.Event()

    def items():
        for i in range(5):
            asked.append(i)
            if i == 1:
                both.set()
            yield i

    with ReadAhead(items()) as r:
        assert both.wait(30)
        r._next[-1].result()
        assert asked == [0, 1]  # nothing taken yet: two read, no third
        got = []
        for x in r:
            got.append(x)
            r._next[-1].result()
            assert asked[-1] == min(x + 2, 4)
    assert got == [0, 1, 2, 3, 4] and asked == [0, 1, 2, 3, 4]


def test_read_ahead_closes_its_items_when_left_early():
    """Left before the end (an error in the caller's start-up), the reader waits for the
    read under way and closes the generator of items: the historian it holds is closed."""
    from diag_plugin.diagnose.readahead import ReadAhead

    closed = threading.Event()

    def items():
        try:
            yield from range(10)
        finally:
            closed.set()

    try:
        with ReadAhead(items()) as r:
            next(iter(r))
            raise RuntimeError("start-up failed")
    except RuntimeError:
        pass
    assert closed.is_set()
