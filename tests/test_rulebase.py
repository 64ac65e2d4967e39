"""Rule-base files: round trip, expert edits, locks, and file:line error reports."""

import math
import re

import numpy as np
import pytest

from diag_plugin.rulebase.document import RuleBase, RuleBaseError, Variable, check


def train_data(seed=0, n=20_000):
    rng = np.random.default_rng(seed)
    cv = rng.uniform(0, 100, n)
    p = rng.uniform(200, 800, n)
    f = 40 * (cv / 100) ** 2 * np.sqrt(p / 800) + rng.normal(0, 0.1, n)
    return np.c_[cv, p], f


@pytest.fixture
def rb_path(tmp_path):
    rb = RuleBase.new(
        "valve_a",
        Variable("F[k]", "F", "t/h", (0.0, 40.0), 31),
        [
            Variable("CV[k-1]", "U", "%", (0.0, 100.0), 31),
            Variable("P1[k]", "P", "kPa", (0.0, 1000.0), 31),
        ],
        description="Model A (Kościelny et al., eq. 8)",
        path=tmp_path / "valve_a.toml",
    )
    X, y = train_data()
    rb.apply_training(rb.new_model().fit(X, y), {"source": "test", "samples": len(y)})
    rb.save()
    return tmp_path / "valve_a.toml"


def rule_line(text, label_u, label_p):
    lines = text.splitlines()
    pat = f'if = ["{label_u}", "{label_p}"]'
    return next(i for i, ln in enumerate(lines) if pat in ln)


def test_unedited_round_trip_gives_identical_bytes(rb_path, tmp_path):
    raw = rb_path.read_bytes()
    RuleBase.load(rb_path).save(tmp_path / "copy.toml")
    assert (tmp_path / "copy.toml").read_bytes() == raw
    # with hand comments and odd spacing too
    text = raw.decode().replace("[model]", "# expert notes, JK 2026-03\n[model]   # the unit")
    text = text.replace("lock = false },", "lock = false },   # checked", 1)
    (tmp_path / "edited.toml").write_text(text)
    RuleBase.load(tmp_path / "edited.toml").save(tmp_path / "edited2.toml")
    assert (tmp_path / "edited2.toml").read_text() == text


def test_loaded_model_predicts_like_trained_model(rb_path):
    X, _ = train_data(seed=1, n=2000)
    X = np.r_[X, [[99.0, 990.0], [50.0, 5.0]]]  # and two points where no rule was trained
    rb = RuleBase.load(rb_path)
    trained = rb.new_model().fit(*train_data())
    loaded = rb.to_model()
    # every trained rule is in the file, with its premise, and no other rule
    assert len(rb.rules) == loaded.n_rules_ == trained.n_rules_
    premises = [tuple(int(i) for i in row) for row in trained.cell_indices()]
    assert [r.premise for r in rb.rules] == premises
    np.testing.assert_array_equal(loaded.keys_, trained.keys_)
    # each conclusion is the trained one, clipped to the output span and rounded to the
    # file's 3 decimals (1e-4 of the 40 t/h span)
    want = [float(f"{v:.3f}") for v in np.clip(trained.conclusions_, 0.0, 40.0)]
    np.testing.assert_allclose([r.then for r in rb.rules], want, rtol=0, atol=1e-9)
    # so no prediction is lost (or made up) and the rest differ by the rounding only
    a, b = loaded.predict(X), trained.predict(X)
    np.testing.assert_array_equal(np.isnan(a), np.isnan(b))
    assert np.isfinite(b).sum() == len(X) - 2 and np.isnan(b[-2:]).all()
    clipped = np.abs(np.clip(trained.conclusions_, 0.0, 40.0) - trained.conclusions_).max()
    assert np.max(np.abs(a - b)[:-2]) <= 0.0005 + clipped + 1e-9


def test_expert_edit_is_used_and_lock_survives_retraining(rb_path):
    text = rb_path.read_text()
    lines = text.splitlines()
    i = rule_line(text, "U20", "P15")
    j = rule_line(text, "U21", "P15")
    lines[i] = re.sub(r"then = [0-9.]+", "then = 33.3", lines[i]).replace(
        "lock = false", "lock = true"
    )
    lines.insert(i, "    # expert: valve cavitates here, value from the vendor sheet")
    lines[j + 1] = re.sub(r"then = [0-9.]+", "then = 11.1", lines[j + 1])  # edited, not locked
    rb_path.write_text("\n".join(lines) + "\n")
    rb = RuleBase.load(rb_path)
    m = rb.to_model()
    x = np.array([[20 * 100 / 30, 15 * 1000 / 30]])  # exactly at the rule's centre
    assert m.predict(x)[0] == pytest.approx(33.3)
    # retrain on new data
    rb.apply_training(rb.new_model().fit(*train_data(seed=7)), {"samples": 20_000})
    rb.save()
    again = RuleBase.load(rb_path)
    r = {r.premise: r for r in again.rules}
    assert r[(20, 15)].then == 33.3 and r[(20, 15)].lock
    assert r[(20, 15)].comments == ["# expert: valve cavitates here, value from the vendor sheet"]
    assert r[(21, 15)].then != 11.1  # not locked: retraining replaced it
    assert "# expert: valve cavitates here" in rb_path.read_text()


def test_deleted_rule_stays_deleted_until_retraining_refills_it(rb_path):
    text = rb_path.read_text()
    lines = text.splitlines()
    i = rule_line(text, "U10", "P10")
    del lines[i]
    k = rule_line(text, "U11", "P10") - 1
    lines[k] = re.sub(r"then = [0-9.]+", "then = nan", lines[k]).replace(
        "lock = false", "lock = true"
    )
    rb_path.write_text("\n".join(lines) + "\n")
    rb = RuleBase.load(rb_path)
    prem = {r.premise for r in rb.rules}
    assert (10, 10) not in prem
    assert math.isnan({r.premise: r for r in rb.rules}[(11, 10)].then)
    m = rb.to_model()
    assert m.n_rules_ == len(rb.rules) - 1  # the locked-deleted cell holds no rule
    rb.save()
    assert (10, 10) not in {r.premise for r in RuleBase.load(rb_path).rules}
    rb.apply_training(rb.new_model().fit(*train_data(seed=3)))
    rb.save()
    r = {r.premise: r for r in RuleBase.load(rb_path).rules}
    assert (10, 10) in r and not math.isnan(r[(10, 10)].then)  # refilled by retraining
    assert math.isnan(r[(11, 10)].then) and r[(11, 10)].lock  # locked-deleted stays empty


BAD_EDITS = [
    ('"U05", "P12"]', '"U05", "Q05"]', "unknown set label 'Q05'"),
    ('"U05", "P12"]', '"U05", "P31"]', "unknown set label 'P31'"),
    ('"U05", "P12"]', '"U05"]', "'if' has 1 labels for 2 inputs"),
    ("then = ", "then = 99", "outside the output span [0, 40] t/h"),
    ("then = ", 'then = "high", x = ', "then must be a number"),
    (", n = ", ", n = -", "n must be a non-negative integer"),
    ("lock = false", "lock = 1", "lock must be true or false"),
    ("lock = false", "lock = false, weight = 2", "unknown key(s) weight"),
]


@pytest.mark.parametrize("old,new,msg", BAD_EDITS)
def test_bad_rule_edit_reports_file_and_line(rb_path, old, new, msg):
    text = rb_path.read_text()
    lines = text.splitlines()
    i = rule_line(text, "U05", "P12")
    lines[i] = lines[i].replace(old, new, 1)
    rb_path.write_text("\n".join(lines) + "\n")
    problems = check(rb_path)
    assert any(p.startswith(f"{rb_path}:{i + 1}: ") and msg in p for p in problems), problems


def test_duplicate_premise_names_both_lines(rb_path):
    text = rb_path.read_text()
    lines = text.splitlines()
    i = rule_line(text, "U05", "P12")
    lines.insert(i + 3, lines[i])
    rb_path.write_text("\n".join(lines) + "\n")
    (p,) = check(rb_path)
    assert p.startswith(f"{rb_path}:{i + 4}: ")
    assert f"duplicate premise ['U05', 'P12'] (first at line {i + 1})" in p


@pytest.mark.parametrize(
    "mutate,line_of,msg",
    [
        (lambda t: t.replace("[output]", "[outputs]"), None, "missing section [output]"),
        (
            lambda t: t.replace('method = "wm-avg"', 'method = "wm-max"'),
            'method = "wm-max"',
            "method must be one of",
        ),
        (lambda t: t.replace("sets = 31", 'sets = "31"', 1), 'sets = "31"', "sets must be int"),
        (
            lambda t: t.replace("span = [0.0, 100.0]", "span = [100.0, 0.0]"),
            "span = [100.0, 0.0]",
            "lo < hi",
        ),
        (
            lambda t: t.replace('spec = "P1[k]"', 'spec = "P1(k)"'),
            'spec = "P1(k)"',
            "bad input spec",
        ),
        (
            lambda t: t.replace('spec = "P1[k]"', 'spec = "dir(P1)[k-1]"'),
            'spec = "dir(P1)[k-1]"',
            "give dir() its move threshold in P1's unit, e.g. dir(P1,0.5)[k-1]",
        ),
        (
            lambda t: t.replace("lock = false }", "lock = false", 1),
            "lock = false",
            "TOML syntax error",
        ),
    ],
)
def test_structure_errors_report_file_and_line(rb_path, mutate, line_of, msg):
    text = mutate(rb_path.read_text())
    rb_path.write_text(text)
    problems = check(rb_path)
    assert problems, "the broken file passed the check"
    hit = [p for p in problems if msg in p]
    assert hit, problems
    if line_of is not None:
        want = next(i for i, ln in enumerate(text.splitlines()) if line_of in ln) + 1
        # a syntax error may only be noticed on the next line (unclosed brace)
        assert hit[0].startswith((f"{rb_path}:{want}: ", f"{rb_path}:{want + 1}: ")), hit
    with pytest.raises(RuleBaseError):
        RuleBase.load(rb_path)


def test_all_problems_are_reported_at_once(rb_path):
    text = rb_path.read_text()
    lines = text.splitlines()
    for lab in ("U03", "U04", "U05"):
        i = rule_line(text, lab, "P12")
        lines[i] = re.sub(r"then = [0-9.]+", "then = -5", lines[i])
    rb_path.write_text("\n".join(lines) + "\n")
    assert len(check(rb_path)) == 3


def test_unreadable_file_is_a_clear_error(tmp_path):
    assert check(tmp_path / "nope.toml")[0].startswith(f"{tmp_path / 'nope.toml'}:0: cannot read")


@pytest.mark.parametrize(
    "old, new",
    [
        (None, None),  # as written by training: read line by line
        ("lock = false },", "lock = false },  # checked on site"),  # trailing comment
        ("{ if = [", "# a comment line above\n    { if = ["),  # comment line
        ("then = ", "then  =  "),  # other spacing: the TOML parser reads it
        ("n = ", "n = 1_0"),  # TOML digit separators: the TOML parser reads it
    ],
)
def test_plain_rule_lines_read_as_the_toml_parser_reads_them(rb_path, old, new):
    """The line-by-line reader of the rule list gives what tomllib gives, or declines."""
    import tomllib

    from diag_plugin.rulebase.document import _plain_rule_list

    text = rb_path.read_text()
    if old is not None:
        text = text.replace(old, new, 1)
    rb = RuleBase(text, rb_path)
    a, b = rb._list_span
    lines = rb._lines[a : b + 1]
    fast = _plain_rule_list(lines)
    slow = tomllib.loads("\n".join(lines))["list"]
    if old in (None, "lock = false },", "{ if = ["):
        assert fast is not None and len(fast) == len(slow) > 100
    if fast is not None:
        assert [{k: str(v) for k, v in r.items()} for r in fast] == [
            {k: str(v) for k, v in r.items()} for r in slow
        ]  # str: nan == nan
        assert [type(r["then"]) for r in fast] == [type(r["then"]) for r in slow]
    assert [(r.premise, r.n, r.lock) for r in rb.rules] == [
        (r.premise, r.n, r.lock) for r in RuleBase(text.replace("lock", "lock "), rb_path).rules
    ]  # the same rules as the TOML parser's reading (the extra space forces it)


def test_eq5_as_printed_is_an_option_of_the_file(rb_path):
    """``conclusion = "sets"`` in ``[rules]`` trains eq. 5 as printed; a wrong value is a
    ``file:line`` error."""
    text = rb_path.read_text().replace("[rules]\n", '[rules]\nconclusion = "sets"\n', 1)
    rb_path.write_text(text)
    rb = RuleBase.load(rb_path)
    assert rb.new_model().conclusion == "sets"
    rb_path.write_text(text.replace('conclusion = "sets"', 'conclusion = "median"'))
    problems = check(rb_path)
    line = text.splitlines().index('conclusion = "sets"') + 1
    assert problems == [f"{rb_path}:{line}: conclusion must be 'mean' or 'sets' (what a cell "
                        "averages: the outputs, or their sets' centres as eq. 5 prints), got "
                        "'median'"]  # fmt: skip


@pytest.mark.parametrize(
    "old, new, line_of",
    [
        ("sets = 31", "sets = 31 x", "sets = 31 x"),  # in the head of the file
        ("list = [", "list = [ xx", "list = [ xx"),  # in the rule list (parsed apart)
        ("[training]", "[training", "[training"),  # a section header
    ],
)
def test_a_toml_syntax_error_names_one_line(rb_path, old, new, line_of):
    """Issue 37: the message carried our file:line and the parser's own 'at line L col C',
    which for the rule list (parsed apart) counted from the list: two different lines."""
    text = rb_path.read_text().replace(old, new, 1)
    rb_path.write_text(text)
    (p,) = check(rb_path)
    want = next(i for i, ln in enumerate(text.splitlines()) if ln.startswith(line_of)) + 1
    assert re.fullmatch(
        rf"{re.escape(str(rb_path))}:{want}: TOML syntax error: .+ \(column \d+\)", p
    ), p
    assert "line" not in p.split("TOML syntax error")[1], p


def test_then_as_text_is_one_message_naming_the_unit(rb_path):
    """Issue 37: `then = "high"` also printed the unrelated 'then = nan is only allowed on a
    locked rule'."""
    text = rb_path.read_text()
    lines = text.splitlines()
    i = rule_line(text, "U05", "P12")
    lines[i] = re.sub(r"then = [0-9.]+", 'then = "high"', lines[i])
    rb_path.write_text("\n".join(lines) + "\n")
    (p,) = check(rb_path)
    assert p.startswith(f"{rb_path}:{i + 1}: ") and "nan" not in p
    assert "then must be a number in the output's unit" in p and "got 'high'" in p
