"""CLI: user errors are one line and exit code 2; the subcommands are registered."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from plmarl_sitl.cli import SUBCOMMANDS, main


def test_registered() -> None:
    assert "agent" in SUBCOMMANDS and "world" in SUBCOMMANDS
    from plmarl_sitl.cli.bench import TARGETS

    assert "agent" in TARGETS


def test_help_of_every_command_imports_neither_torch_nor_scipy() -> None:
    """`plmarl --help` registers every subcommand: each must keep its heavy imports (the
    twin, the statistics) inside the function that runs it, or the help takes seconds.
    A fresh interpreter, since this one has imported torch already."""
    probe = ("import sys; from plmarl_sitl.cli import build_parser; build_parser(); "
             "print(sorted(m for m in ('torch', 'scipy') if m in sys.modules))")
    r = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, timeout=60, check=True)
    assert r.stdout.strip() == "[]", r.stdout


def test_swarm_up_says_a_wrong_mission_key_before_importing_torch(tmp_path) -> None:  # noqa: ANN001
    """A user's typo in the mission is one line at once: `swarm up` loads the mission before
    its fork server imports torch (and the world's modules) for the agents."""
    bad = tmp_path / "bad.yaml"
    bad.write_text("extends: %s\nname: bad\nradii: {sensing_mm: 3}\n" % (Path(__file__).resolve().parents[2] / "missions" / "paper_urban.yaml"))
    probe = ("import sys; from plmarl_sitl.cli import main; rc = main(['swarm', 'up', sys.argv[1], '--headless']); "
             "print(rc, 'torch' in sys.modules)")
    r = subprocess.run([sys.executable, "-c", probe, str(bad)], capture_output=True, text=True, timeout=60)
    assert r.stdout.split() == ["2", "False"], r.stdout + r.stderr
    assert "radii.sensing_mm: unknown key" in r.stderr and "Traceback" not in r.stderr


@pytest.mark.parametrize(
    "argv,needle",
    [
        (["agent", "--id", "0", "--connect", "udpout://127.0.0.1:1", "--broker", "mqtt://127.0.0.1:1", "--policy", "/nope",
          "--no-auth"],
         "missing policy directory"),
        (["agent", "--id", "0", "--connect", "http://x", "--broker", "mqtt://127.0.0.1:1", "--no-auth"], "scheme must be udpout"),
        (["agent", "--id", "9", "--connect", "udpout://127.0.0.1:1", "--broker", "mqtt://127.0.0.1:1", "--no-auth"], "--id 9"),
        (["agent", "--id", "0", "--connect", "udpout://127.0.0.1:1", "--broker", "mqtt://127.0.0.1:1"], "no --swarm-key FILE"),
        (["agent", "--id", "0", "--connect", "udpout://127.0.0.1:1", "--broker", "mqtt://127.0.0.1:1", "--swarm-key", "/nope"],
         "--swarm-key /nope: cannot read the key file"),
        (["world", "missions/paper_urban.yaml", "--broker", "ftp://x", "--no-auth"], "scheme must be mqtt"),
        (["world", "missions/paper_urban.yaml", "--broker", "mqtt://127.0.0.1:1", "--loss", "2", "--no-auth"], "--loss"),
        (["world", "missions/paper_urban.yaml", "--broker", "mqtt://127.0.0.1:1"], "no --swarm-key FILE"),
    ],
)
def test_user_errors(argv: list[str], needle: str, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch) -> None:
    from pathlib import Path

    monkeypatch.chdir(Path(__file__).resolve().parents[2])
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert needle in err and "Traceback" not in err


@pytest.mark.parametrize(
    "argv,needle",
    [
        (["bench", "swarm", "--seeds", "0,x"], "'x' is not a valid seed"),
        (["bench", "swarm", "--n", "7"], "swarm size '7' is not one of 4, 20"),
        (["bench", "swarm", "--speedups", "10,-1"], "speedup must be > 0"),
        (["bench", "infer", "--n", ","], "give at least one swarm size"),
        (["bench", "dt", "--envs", "64,lots"], "'lots' is not a valid batch size"),
        (["bench", "agent", "--rt-priority", "150"], "SCHED_FIFO priority 150 is outside 0-99"),
    ],
)
def test_bad_lists_are_argparse_errors(argv: list[str], needle: str, capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert needle in err and "Traceback" not in err


def test_bench_infer_times_the_shipped_files_beside_the_wave_1_baseline(capsys: pytest.CaptureFixture[str],
                                                                         monkeypatch: pytest.MonkeyPatch) -> None:
    """Each file is called with the inputs of its version: the shipped policies (team plan,
    input version 2) and the wave-1 PL-MARL (version 1) in the same run."""
    import json
    from pathlib import Path

    monkeypatch.chdir(Path(__file__).resolve().parents[2])
    assert main(["bench", "infer", "--n", "4", "--calls", "5", "--json"]) == 0
    res = json.loads(capsys.readouterr().out)
    assert {"pl-marl", "gru", "pl-marl-wave1"} <= {r["method"] for r in res["rows"]}
    assert res["weights"] == {"pl-marl": "trained", "gru": "trained", "pl-marl-wave1": "trained"}
