"""One CLI contract (issue 22, docs/reference/cli.md): exit 0 done, 1 the job failed, 2 bad usage or
input, 3 environment; no traceback reaches the user from any command.

Every command of the parser (so a new command is covered without editing this file) is
driven with bad arguments, bad files, missing objects and an unreachable database."""

from __future__ import annotations

import argparse
import json
import socket

import pandas as pd
import pytest

from diag_plugin import cli

T0 = pd.Timestamp("2026-03-02", tz="UTC")


def leaf_commands() -> list[tuple[str, ...]]:
    out = []

    def walk(parser, prefix):
        for a in parser._actions:
            if isinstance(a, argparse._SubParsersAction):
                for name, sp in a.choices.items():
                    walk(sp, (*prefix, name))
                return
        out.append(prefix)

    walk(cli.build_parser(), ())
    return out


@pytest.fixture(scope="module")
def env(tmp_path_factory):
    """A historian with a small tank plant, a trained model, a broken model file, a unit
    file, a garbage unit file, a garbage matrix and a garbage plant.toml."""
    from diag_plugin.simulate.smallplants import export, simulate_tank
    from historian import Historian

    d = tmp_path_factory.mktemp("cli")
    db = f"sqlite:///{d / 'plant.db'}"
    with Historian(db) as h:
        h.write_samples(export(simulate_tank(0.05, seed=3), 10.0))
    rb = d / "rb"
    g = ["--db", db, "--rulebases", str(rb)]
    assert (
        cli.main([*g, "model", "new", "m", "--output", "FI102", "--input", "LIC101.OUT[k-1]"]) == 0
    )
    assert cli.main([*g, "train", "m"]) == 0
    (rb / "broken.toml").write_text("[model]\nname = 'broken'\n[output\n", encoding="utf-8")
    (rb / "u.unit.toml").write_text(
        "[unit]\nname = 'u'\n[tests]\nr1 = { model = 'm.toml' }\n", encoding="utf-8"
    )
    (rb / "bad.unit.toml").write_text("[unit\n", encoding="utf-8")
    (rb / "bad.matrix.toml").write_text("[matrix]\ntests = 3\n", encoding="utf-8")
    (d / "plant.toml").write_text("[plant]\ncycle = 'x'\n", encoding="utf-8")
    (d / "latin1.toml").write_bytes("[plant]\n# K\u00fchlwasser\n".encode("latin-1"))
    (d / "binary.csv").write_bytes(b"\x00\x01\x02")
    return {"dir": d, "db": db, "rb": str(rb), "g": g}


def _dead_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def cases(env) -> dict[tuple[str, ...], list[list[str]]]:
    """Per command, invocations that must fail cleanly (after the command words)."""
    d = env["dir"]
    bad_time = ["--from", "not-a-time"]
    return {
        ("simulate",): [
            ["--days", "-1", "--out", str(d / "x.csv")],
            ["--days", "1", "--out", str(d / "x.txt")],
            ["--days", "1", "--out", str(d / "x.csv"), "--min-flow", "50"],
        ],
        ("rules", "check"): [
            [str(d / "none.toml")],
            ["broken"],
            ["bad.unit.toml"],
            ["bad.matrix.toml"],
        ],
        ("rules", "show"): [["nothing"], ["broken"]],
        ("rules", "export-fcl"): [["nothing"], ["broken"]],
        ("demo",): [["--days", "-2", "--workdir", str(d / "demo")]],
        ("import",): [[str(d / "none.csv")], [str(d / "binary.csv")], [str(d)]],
        ("tags",): [["--start", "not-a-time"]],
        ("historian", "roll"): [["--before", "2026-13"], ["--before", "soon"]],
        ("historian", "check"): [["--bogus"]],
        ("historian", "vacuum"): [["--bogus"]],
        ("train",): [
            ["nothing"],
            ["broken"],
            ["m", *bad_time],
            ["m", "--holdout", "1.5"],
            ["m", "--chunk", "soon"],
            [],
        ],
        ("experiments",): [["nothing"]],
        ("model", "new"): [
            ["m2", "--output", "NOPE", "--input", "FI101[k]"],
            ["m3", "--output", "FI102", "--input", "LT101[k-]"],
            ["m4", "--output", "FI102", "--input", "FI101[k+1]"],
            ["m5", "--output", "FI102", "--input", "FI101[k]", "--period", "fast"],
        ],
        ("model", "add-input"): [
            ["nothing", "FI101[k]"],
            ["m", "X[k"],
            ["m", "NOPE[k]"],
            ["broken", "FI101[k]"],
        ],
        ("model", "set-input"): [
            ["m", "FI101[k]", "--sets", "5"],
            ["nothing", "FI101[k]"],
            ["m", "LIC101.OUT[k-1]", "--span", "5", "1"],
        ],
        ("model", "remove-input"): [
            ["m", "LIC101.OUT[k-1]"],
            ["m", "nope[k]"],
            ["nothing", "a[k]"],
        ],
        ("compare",): [["nothing"], ["broken"], ["m", *bad_time]],
        ("explain",): [["nothing"], ["m", *bad_time]],
        ("report",): [
            ["nothing", "--out", str(d / "r.html")],
            ["m", "--out", str(d / "r.html"), *bad_time],
        ],
        ("unit", "new"): [["u2", "--model", "nonsense"], ["u3", "--model", "r1=nothing"]],
        ("unit", "check"): [["bad"], ["nothing"]],
        ("unit", "show"): [["bad"], ["nothing"]],
        ("unit", "learn"): [
            ["nothing", "--from", "2026-03-02", "--to", "2026-03-03"],
            ["u", "--from", "x", "--to", "y"],
            ["bad", "--from", "2026-03-02", "--to", "2026-03-03"],
        ],
        ("unit", "accept"): [
            ["nothing", "--from", "2026-03-02", "--to", "2026-03-03"],
            ["u", "--from", "x", "--to", "y"],
            ["bad", "--from", "2026-03-02", "--to", "2026-03-03"],
            ["u", "--from", "2026-03-02", "--to", "2026-03-03", "--far", "-1"],
        ],
        ("unit", "rollback"): [["nothing"], ["u"]],
        ("unit", "build"): [
            ["u4", "--from", "2026-03-02", "--to", "2026-03-03", "--tags", "NOPE"],
            ["u4", "--from", "x", "--to", "y"],
            ["u4", "--from", "2020-01-01", "--to", "2020-01-02"],
            ["u4", "--from", "2026-03-02", "--to", "2026-03-03", "--tags-from", str(d / "no")],
            ["u", "--from", "2026-03-02", "--to", "2026-03-03"],
        ],
        ("diagnose",): [["nothing"], ["u", *bad_time], ["bad"]],
        ("benchmark",): [
            ["--unit", "nothing"],
            ["--unit", "bad"],
            ["--plant", "chemplant", "--period", "0"],
            ["--plant", "chemplant", "--fault", "nope"],
            ["--plant", "chemplant", "--seed", "1"],
            ["--plant", "chemplant", "--far", "-1"],
        ],
        ("run",): [
            ["--config", str(d / "none.toml")],
            ["--config", str(d / "plant.toml")],
            ["--config", str(d / "plant.toml"), "--check"],
            ["--config", str(d / "latin1.toml")],
            ["--check"],
            ["--cycle", "-1"],
        ],
        ("engine-fdi",): [["--seed", "x"], ["--method", "nope"]],
        ("compare-methods",): [["nothing"], ["broken"]],
    }


def run(argv: list[str], capfd) -> tuple[int, str]:
    try:
        rc = cli.main(argv)
    except SystemExit as exc:  # argparse's usage errors
        rc = exc.code
    out, err = capfd.readouterr()
    return rc, out + err


def test_every_command_is_covered(env):
    missing = [" ".join(c) for c in leaf_commands() if c not in cases(env)]
    assert not missing, f"commands with no bad-input cases here: {missing}"


@pytest.mark.parametrize("command", leaf_commands(), ids=" ".join)
def test_bad_input_is_a_message_and_exit_2_never_a_traceback(env, command, capfd):
    for argv in cases(env)[command]:
        rc, text = run([*env["g"], *command, *argv], capfd)
        shown = " ".join([*command, *argv])
        assert "Traceback" not in text, f"diag {shown}:\n{text}"
        assert rc == 2, f"diag {shown}: exit {rc}, want 2 (bad usage or input):\n{text}"
        assert text.strip(), f"diag {shown}: no message"


@pytest.mark.parametrize(
    "argv",
    [["train", "m"], ["compare", "m"], ["tags"], ["experiments", "m"], ["diagnose", "u"]],
    ids=" ".join,
)
def test_an_unreachable_database_is_exit_3_naming_it(env, argv, capfd):
    url = f"postgresql://postgres@127.0.0.1:{_dead_port()}/nothing"
    rc, text = run(["--db", url, "--rulebases", env["rb"], *argv], capfd)
    assert "Traceback" not in text, text
    assert rc == 3, text
    assert "database error" in text and "nothing" in text


def test_a_busy_port_is_exit_3(env, capfd, tmp_path):
    """``diag run --config`` whose status port another program holds."""
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        cfg = tmp_path / "plant.toml"
        cfg.write_text(
            f"""[plant]
cycle = 0.1
units = ["{env["rb"]}/u.unit.toml"]
[outputs]
modbus_port = {port}
opcua_port = 0
[[source]]
name = "plc"
type = "modbus"
host = "127.0.0.1"
port = {_dead_port()}
map = "{tmp_path / "map.csv"}"
""",
            encoding="utf-8",
        )
        (tmp_path / "map.csv").write_text(
            "tag,table,address,type\nFI102,hr,0,float32\nLIC101.OUT,hr,2,float32\n",
            encoding="utf-8",
        )
        rc, text = run(["run", "--config", str(cfg), "--duration", "1"], capfd)
    assert "Traceback" not in text, text
    assert rc in (2, 3), text  # a busy port: refused at load (2) or at bind (3)
    assert str(port) in text


def test_json_on_the_commands_that_print_a_result(env, capfd):
    g = env["g"]
    for argv in (
        ["rules", "show", "m", "--json"],
        ["rules", "check", "m", "--json"],
        ["train", "m", "--json"],
        ["experiments", "m", "--json"],
        ["compare", "m", "--json"],
        ["tags", "--json"],
        ["model", "set-input", "m", "LIC101.OUT[k-1]", "--sets", "9", "--json"],
    ):
        rc, text = run([*g, *argv], capfd)
        assert rc == 0, text
        json.loads(text[text.index("{") if text.lstrip().startswith("{") else text.index("[") :])


def test_holdout_0_trains_on_everything_and_says_there_is_no_validation_figure(env, capfd):
    rc, text = run([*env["g"], "train", "m", "--holdout", "0"], capfd)
    assert rc == 0 and "nan" not in text.lower() and "no held-out validation" in text, text
    rc, text = run([*env["g"], "train", "m", "--holdout", "0", "--json"], capfd)
    res = json.loads(text)
    assert res["validation"]["samples"] == 0 and res["samples"] > 300
