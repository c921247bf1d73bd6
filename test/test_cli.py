"""``gpf-nav`` refuses bad arguments with one line on stderr naming the problem and exit status 2, for
the command itself and every sub-command; nothing runs and no traceback is printed."""
import subprocess
import sys

import pytest

from gpf_nav import cli

BAD = [
    (["nosuch"], "unknown command 'nosuch'"),
    ([], "a command is required"),
    (["demo", "--particles", "0"], "--particles: '0' is not a positive integer"),
    (["demo", "--filter", "foo"], "invalid choice: 'foo'"),
    (["demo", "--filter", "enkf", "--particles", "1"], "'n_particles' = 1 must be an integer >= 2"),
    (["demo", "--rate-factor", "-3"], "--rate-factor: '-3' is not a positive number"),
    (["demo", "--duration", "nan"], "--duration: 'nan' is not a positive number"),
    (["demo", "--bogus"], "unrecognized arguments: --bogus"),
    (["bench", "--particles", "0"], "--particles: '0' is not a positive integer"),
    (["bench", "--repeats", "x"], "--repeats: 'x' is not a positive integer"),
    (["bench", "--bogus"], "unrecognised arguments: --bogus"),
    (["bench", "--node", "--", "--rates", "0"], "--rates: '0' is not a comma list of positive numbers"),
    (["bench", "--node", "--", "--filter", "kf"], "invalid choice: 'kf'"),
    (["montecarlo", "--runs", "0"], "--runs: '0' is not a positive integer"),
    (["montecarlo", "--filters", "KF9000"], "unknown filter(s) ['kf9000']"),
    (["montecarlo", "--cases", "half"], "--cases must be among"),
    (["montecarlo", "--config", "/no/such/scenario.yaml"], "/no/such/scenario.yaml"),
    (["sweep"], "the following arguments are required: --param"),
    (["sweep", "--param", "mismatch", "--values", "a,b"], "--values must be comma-separated numbers"),
    (["sweep", "--param", "noise", "--particles", "-1"], "--particles: '-1' is not a positive integer"),
    (["integrity", "--runs", "0"], "--runs: '0' is not a positive integer"),
    (["bench", "--warmup", "-1"], "--warmup: '-1' is not a non-negative integer"),
    (["integrity", "--variants", "XYZ"], "--variants must be a comma list"),
    (["integrity", "--false-alarm-rate", "2"], "false_alarm_rate"),
    (["integrity", "--range-biases", "x"], "must be comma-separated numbers"),
    (["sensors", "--runs", "0"], "--runs: '0' is not a positive integer"),
    (["sensors", "--suite", "trn_latency"], "--suite: expected KEY=VALUE, got 'trn_latency'"),
    (["sensors", "--suite", "radar=1"], "unknown sensor-suite keys ['radar']"),
    (["sensors", "--suite", "trn_period=3"], "must be a multiple of the step dt = 2.0 s"),
    (["sensors", "--case", "half"], "case must be one of"),
    (["sensors", "--fix-gate", "1"], "--fix-gate must lie in [0, 1), got 1.0"),
    (["sensors", "--estimate-range-bias", "-1"], "--estimate-range-bias must be a non-negative std"),
    (["sensors", "--filters", "KF9000"], "unknown filter(s) ['kf9000']"),
    (["record"], "the following arguments are required: OUT"),
    (["record", "/nonexistent/bag", "--duration", "0"], "--duration: '0' is not a positive number"),
    (["record", "/nonexistent/bag", "--storage", "zip"], "--storage: invalid choice: 'zip'"),
    (["record", "/nonexistent/bag", "--seed", "one"], "--seed: invalid int value: 'one'"),
    (["record", "/nonexistent/bag", "--bogus"], "unrecognized arguments: --bogus"),
    (["replay", "/nonexistent/bag"], "the following arguments are required: --out"),
    (["replay", "/nonexistent/bag", "--out", "/nonexistent/out", "--storage", "zip"],
     "--storage: invalid choice: 'zip'"),
    (["replay", "/nonexistent/bag", "--out", "/nonexistent/out", "--bogus"], "unrecognized arguments: --bogus"),
]


@pytest.mark.parametrize("argv, problem", BAD, ids=[" ".join(a) or "(none)" for a, _ in BAD])
def test_bad_arguments_give_one_line_and_exit_status_2(argv, problem, capsys):
    try:
        code = cli.main(argv)
    except SystemExit as stop:
        code = stop.code
    out, err = capsys.readouterr()
    assert code == 2, (out, err)
    lines = err.strip().splitlines()
    assert len(lines) == 1 and problem in lines[0], err
    assert lines[0].startswith("gpf-nav") and "error:" in lines[0]
    assert out == ""


def test_help_is_not_an_error(capsys):
    assert cli.main(["--help"]) == 0
    assert "gpf-nav demo" in capsys.readouterr().out


def test_console_entry_point_in_a_process():
    result = subprocess.run([sys.executable, "-m", "gpf_nav.cli", "demo", "--particles", "0"],
                            capture_output=True, text=True, timeout=120)
    assert result.returncode == 2
    assert result.stderr.strip() == ("gpf-nav demo: error: argument --particles: '0' is not a positive integer "
                                     "(see gpf-nav demo --help)")
    assert "Traceback" not in result.stderr and result.stdout == ""
