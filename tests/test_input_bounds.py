"""Every input is bounded and checked before anything starts (issue 27, part 3).

A mission, a card or a flag a user (or an attacker) can write is refused in one line with
exit 2 before a broker, a key or a run folder exists: non-UTF-8 bytes, duplicate keys,
pathological nesting or alias expansion, a swarm larger than MAVLink's ids, seeds no
generator takes, speedups that are not finite, swarm names that are MQTT wildcards.
The fuzz tests drive the real loaders and the real `plmarl` entry point in-process.
"""

import contextlib
import io
import os
import shutil
from pathlib import Path

import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from plmarl_sitl.cli import main
from plmarl_sitl.config import MAX_CONFIG_BYTES, MAX_CONFIG_DEPTH, MAX_SEED, ConfigError, read_yaml
from plmarl_sitl.errors import PolicyFileError
from plmarl_sitl.learning.nn.io import load_policy
from plmarl_sitl.mission import MAX_EPISODE_S, MAX_UAVS, load_mission

ROOT = Path(__file__).resolve().parent.parent
BASE = yaml.safe_load((ROOT / "missions/paper_urban.yaml").read_text())


def _write(tmp_path: Path, text: str | bytes, name: str = "m.yaml") -> Path:
    p = tmp_path / name
    p.write_bytes(text if isinstance(text, bytes) else text.encode())
    return p


@pytest.mark.parametrize(
    ("text", "message"),
    [
        (b"name: x\nseed: 1\nseed: 2\n", "duplicate key 'seed' (line 3, column 1)"),
        (b"name: x\nusers: {count: 60, count: 120}\n", "duplicate key 'count'"),
        (b"name: caf\xe9\n", "not UTF-8 text (byte 0xe9 at offset 9)"),
        (("name: x\nevents: " + "[" * 3000 + "]" * 3000 + "\n").encode(), f"nested more than {MAX_CONFIG_DEPTH} levels"),
        (("name: x\nevents: " + "[" * 40 + "]" * 40 + "\n").encode(), f"nested more than {MAX_CONFIG_DEPTH} levels"),
        (b"name: x\n" + b"#" * (MAX_CONFIG_BYTES + 1), "not a configuration file"),
    ],
)
def test_pathological_yaml_is_refused(tmp_path, text, message):
    with pytest.raises(ConfigError) as exc:
        load_mission(_write(tmp_path, text))
    assert message in str(exc.value)
    assert "\n" not in str(exc.value)


def test_alias_bomb_is_refused_before_expansion(tmp_path):
    lines = ["name: x", "a0: &a0 [1, 1, 1, 1, 1, 1, 1, 1, 1, 1]"]
    lines += [f"a{i}: &a{i} [{', '.join([f'*a{i - 1}'] * 10)}]" for i in range(1, 10)]  # 10^10 values expanded
    with pytest.raises(ConfigError, match="values once its aliases are expanded"):
        read_yaml(_write(tmp_path, "\n".join(lines)))


def test_a_few_aliases_still_load(tmp_path):
    data = read_yaml(_write(tmp_path, "a: &p {north_m: 1.0}\nb: *p\nc: [*p, *p]\n"))
    assert data == {"a": {"north_m": 1.0}, "b": {"north_m": 1.0}, "c": [{"north_m": 1.0}] * 2}


@pytest.mark.parametrize(
    ("key", "value", "message"),
    [
        (["n_uavs"], MAX_UAVS + 1, f"n_uavs: must be <= {MAX_UAVS}"),
        (["n_uavs"], 2**63 - 1, f"n_uavs: must be <= {MAX_UAVS}"),
        (["seed"], 2**70, f"seed: must be <= {MAX_SEED}"),
        (["seed"], -1, "seed: must be >= 0"),
        (["timing", "episode_s"], MAX_EPISODE_S + 1, f"timing.episode_s: must be <= {MAX_EPISODE_S}"),
    ],
)
def test_mission_bounds(tmp_path, key, value, message):
    data = yaml.safe_load(yaml.safe_dump(BASE))
    node = data
    for k in key[:-1]:
        node = node.setdefault(k, {})
    node[key[-1]] = value
    with pytest.raises(ConfigError) as exc:
        load_mission(_write(tmp_path, yaml.safe_dump(data)))
    assert message in str(exc.value)


def _policy_copy(tmp_path: Path, edit) -> Path:  # noqa: ANN001 - a function of the card's data
    d = tmp_path / "policy"
    shutil.copytree(ROOT / "policies/pl-marl", d)
    card = yaml.safe_load((d / "card.yaml").read_text())
    edit(card)
    (d / "card.yaml").write_text(yaml.safe_dump(card, sort_keys=False))
    return d


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (lambda c: c.update(method=123), "method: expected a string"),
        (lambda c: c.update(colour="blue"), "colour: unknown key"),
        (lambda c: c["io"].update(obs_dim="many"), "io.obs_dim: unknown key"),
        (lambda c: c["io"].update(buffer_len="ten"), "io.buffer_len: expected an integer"),
        (lambda c: c["io"]["scales"].update(v_max="fast"), "io.scales.v_max: expected a number"),
        (lambda c: c["sha256"].update({"policy.pt": "abc"}), "sha256.policy.pt: expected 64 lowercase hex digits"),
        (lambda c: c.update(seed=-3), "seed: must be >= 0"),
    ],
)
def test_card_is_checked_like_a_mission(tmp_path, edit, message):
    with pytest.raises(PolicyFileError) as exc:
        load_policy(_policy_copy(tmp_path, edit))
    assert message in str(exc.value)


def test_shipped_cards_pass_the_schema():
    for card in sorted(ROOT.glob("policies/**/card.yaml")):
        load_policy(card.parent)


def _run(argv: list[str]) -> tuple[int, str]:
    """`plmarl ARGV` in-process: (exit code, stderr)."""
    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        try:
            code = main(argv)
        except SystemExit as exc:  # argparse's own errors
            code = exc.code
    return int(code or 0), err.getvalue()


def _last_line_only_error(stderr: str) -> bool:
    """argparse prints its usage, then one `error:` line; our errors are that line alone."""
    lines = stderr.strip().splitlines()
    return bool(lines) and "error:" in lines[-1] and "Traceback" not in stderr and sum("error:" in x for x in lines) == 1


@pytest.mark.parametrize(
    "flags",
    [
        ["--speedup", "nan"], ["--speedup", "inf"], ["--speedup", "1e9"], ["--speedup", "0"], ["--speedup", "-2"],
        ["--seed", "1180591620717411303424"], ["--seed", "-1"], ["--seed", "1.5"],
        ["--swarm-name", "#"], ["--swarm-name", "a/+"], ["--swarm-name", ""], ["--swarm-name", "x" * 65],
    ],
)
def test_swarm_up_flags_are_bounded(tmp_path, monkeypatch, flags):
    monkeypatch.chdir(tmp_path)
    code, err = _run(["swarm", "up", str(ROOT / "missions/paper_urban.yaml"), "--headless", "--out", "run", *flags])
    assert code == 2 and _last_line_only_error(err), err
    assert os.listdir(tmp_path) == []  # nothing written


# --- fuzz: any mission text is a Mission or one ConfigError; the CLI is exit 2 and writes nothing ---

_scalars = st.one_of(st.none(), st.booleans(), st.integers(min_value=-(2**70), max_value=2**70),
                     st.floats(allow_nan=True, allow_infinity=True), st.text(max_size=8))
_values = st.recursive(_scalars, lambda inner: st.one_of(st.lists(inner, max_size=3),
                                                        st.dictionaries(st.text(max_size=6), inner, max_size=3)),
                       max_leaves=6)


def _paths(node, prefix=()):  # noqa: ANN001, ANN202 - plain YAML data
    if isinstance(node, dict):
        for k, v in node.items():
            yield (*prefix, k)
            yield from _paths(v, (*prefix, k))


PATHS = sorted(set(_paths(BASE)) | {("n_uavs",), ("seed",), ("timing", "episode_s"), ("events",), ("extends",)}, key=str)


@st.composite
def _missions(draw):  # noqa: ANN001, ANN202
    data = yaml.safe_load(yaml.safe_dump(BASE))
    for _ in range(draw(st.integers(1, 3))):
        path = draw(st.sampled_from(PATHS))
        node = data
        for k in path[:-1]:
            node = node.setdefault(k, {}) if isinstance(node, dict) else {}
        if isinstance(node, dict):
            node[path[-1]] = draw(_values)
    return data


@pytest.mark.parametrize("base", ["", "0", "nothere.yaml", "."])
def test_extends_what_is_no_file_names_the_mission_that_says_so(tmp_path, base):
    # found by the fuzz below: `extends: ''` named only the directory it resolved to
    p = _write(tmp_path, yaml.safe_dump({"extends": base}))
    with pytest.raises(ConfigError) as exc:
        load_mission(p)
    assert str(exc.value).startswith(f"{p}: extends: no mission file ")


@pytest.mark.parametrize(("key", "shown"), [("\n", "\\n"), ("a\tb", "a\\tb"), ("\x00", "\\x00"), ("é", "é")])
def test_a_key_with_a_control_character_is_named_on_one_line(tmp_path, key, shown):
    # found by the fuzz below (session 29): `timing: {"\n": null}` made a two-line error
    p = _write(tmp_path, yaml.safe_dump({**BASE, "timing": {key: None}}, allow_unicode=True))
    with pytest.raises(ConfigError) as exc:
        load_mission(p)
    assert str(exc.value) == f"{p}: timing.{shown}: unknown key (allowed: decision_every_s, dt_s, episode_s)"


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=_missions())
def test_fuzz_mission_loads_or_names_the_error(tmp_path, data):
    p = _write(tmp_path, yaml.safe_dump(data, allow_unicode=True))
    try:
        load_mission(p)
    except ConfigError as exc:
        assert "\n" not in str(exc) and str(p) in str(exc)


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=_missions(), junk=st.binary(max_size=40))
def test_fuzz_cli_refuses_bad_missions_in_one_line(tmp_path_factory, data, junk):
    work = tmp_path_factory.mktemp("fuzz")
    text = yaml.safe_dump(data, allow_unicode=True).encode() + junk
    p = work / "m.yaml"
    p.write_bytes(text)
    try:
        load_mission(p)
        return  # a valid mission would fly: the loader accepted it, nothing to refuse
    except ConfigError:
        pass
    cwd = os.getcwd()
    os.chdir(work)
    try:
        for argv in (["swarm", "up", "m.yaml", "--headless", "--out", "run"], ["sim", "m.yaml", "--episodes", "1"]):
            code, err = _run(argv)
            assert code == 2 and _last_line_only_error(err), err
        assert sorted(os.listdir(work)) == ["m.yaml"]  # no run folder, key or login file
    finally:
        os.chdir(cwd)


def test_a_broken_policy_fails_the_preflight(tmp_path, monkeypatch):
    """Checked against the mission before a broker, key or run folder exists (it used to be an
    agent's exit 1 after start-up)."""
    d = tmp_path / "policy"
    shutil.copytree(ROOT / "policies/pl-marl", d)
    (d / "policy.pt").write_bytes(b"junk")
    monkeypatch.chdir(tmp_path)
    code, err = _run(["swarm", "up", str(ROOT / "missions/paper_urban.yaml"), "--policy", str(d), "--headless", "--out", "run"])
    assert code == 2 and _last_line_only_error(err) and "policy.pt: does not match card.yaml" in err, err
    assert not (tmp_path / "run").exists()


def test_swarm_size_outside_training_is_named():
    from plmarl_sitl.learning.nn.card import swarm_size_warning

    card = yaml.safe_load((ROOT / "policies/pl-marl/card.yaml").read_text())
    assert swarm_size_warning(card, 4) is None  # trained on N = 3..8
    assert "trained at N = 3..8; this mission flies N = 20 (zero-shot" in swarm_size_warning(card, 20)
    assert "trained at N = 5; this mission flies N = 4" in swarm_size_warning({"method": "x", "n_uavs": 5}, 4)


@pytest.mark.parametrize(("flags", "message"), [
    (["--id", "9", "--n-uavs", "4"], "--id 9: the mission has 4 UAVs (ids 0..3"),
    (["--id", "-1"], "argument --id: -1 is outside 0..249"),
    (["--id", "0", "--n-uavs", "0"], "argument --n-uavs: 0 is outside 1..250"),
    (["--id", "0", "--airframe-drag", "-1"], "--airframe-drag -1: must be 0..10 /s"),
])
def test_agent_names_a_wrong_id_before_loading_anything_heavy(flags, message):
    """Issue 26: `--id` / `--n-uavs` mistakes are one line before torch is imported (they came
    after seconds of imports and the policy load)."""
    import subprocess
    import sys

    code = ("import contextlib, io, sys; from plmarl_sitl.cli import main\n"
            "err = io.StringIO()\n"
            "with contextlib.redirect_stderr(err):\n"
            "    try: rc = main(sys.argv[1:])\n"
            "    except SystemExit as e: rc = e.code\n"
            "print(rc, 'torch' in sys.modules); print(err.getvalue().strip().splitlines()[-1])")
    r = subprocess.run([sys.executable, "-c", code, "agent", *flags, "--connect", "udpout://127.0.0.1:9",
                        "--broker", "mqtt://127.0.0.1:1", "--no-auth"], capture_output=True, text=True, cwd=ROOT, timeout=120)
    status, line = r.stdout.strip().splitlines()
    assert status == "2 False", r.stdout + r.stderr
    assert message in line


def test_result_tables_keep_full_names_when_piped(capsys):
    """Issue 26: piped to a file, rich cut the tables to 80 columns ("covera…", "tag-ma…")."""
    from plmarl_sitl.learning.eval.report import print_tables

    rows = [{"method": m, "tup": 15, "coverage_mean": 0.9, "coverage_ci95": [0.8, 0.95], "coverage_full_mean": 0.85,
             "lambda2_mean": 3.0, "fraction_of_best_mean": 0.99, "best_reference": "clairvoyant 9/10, greedy 1/10"}
            for m in ("pl-marl", "tag-mappo", "dead-reckoning", "clairvoyant")]
    print_tables({"results": rows, "p_values": [{"versus": "tag-mappo", "tup": 15, "p": 0.5}],
                  "extra": {"from_s": 50, "episodes": 10, "rows": []}})
    out = capsys.readouterr().out
    assert "…" not in out and "tag-mappo" in out and "dead-reckoning" in out and "clairvoyant 9/10, greedy 1/10" in out
