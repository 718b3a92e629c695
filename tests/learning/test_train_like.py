"""`plmarl train --like DIR`: train with the recipe a trained policy's card records (the
shipped default's is not the flags' Table I defaults), flags given on the command line win."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from plmarl_sitl.cli import build_parser, main
from plmarl_sitl.cli.train import RECIPE_DEFAULTS, recipe_from_card, resolve_recipe

ROOT = Path(__file__).resolve().parents[2]


def _resolved(*argv: str):
    args = build_parser("train").parse_args(["train", *argv])
    resolve_recipe(args)
    return args


def test_the_shipped_defaults_card_gives_its_recipe() -> None:
    card = yaml.safe_load((ROOT / "policies" / "pl-marl" / "card.yaml").read_text())
    recipe = recipe_from_card(card)
    assert recipe == {"method": "pl-marl", "episodes": 16, "num_envs": 16, "imitation_rounds": 6,
                      "imitation_episodes": 40, "imitation_tup_chunks": 5, "teacher": "track",
                      "teacher_track_m": 30.0, "teacher_track_link": 0.7, "moving_share": 0.5,
                      "scenarios": "general", "policy_inputs": "plan"}
    # A card of before a flag existed gives no value for it (the flag's own default then applies); a later one does.
    transit = recipe_from_card(yaml.safe_load((ROOT / "policies" / "transit" / "pl-marl" / "card.yaml").read_text()))
    assert recipe | {"transit_share": 0.25} == transit


def test_without_like_the_flags_keep_their_table_one_defaults() -> None:
    args = _resolved()
    assert {k: getattr(args, k) for k in RECIPE_DEFAULTS} == RECIPE_DEFAULTS and args.predictor is None


def test_like_by_name_from_any_directory_and_given_flags_win(tmp_path: Path, monkeypatch) -> None:
    monkeypatch.chdir(tmp_path)
    # --teacher plan is also the flag's own default: given, it still wins over the card's track.
    args = _resolved("--like", "pl-marl", "--teacher", "plan", "--episodes", "3")
    assert (args.teacher, args.episodes, args.teacher_track_link, args.moving_share) == ("plan", 3, 0.7, 0.5)
    assert Path(args.predictor) == ROOT / "policies" / "pl-marl" / "predictor.pt"  # its engine, not a new fit
    gru = _resolved("--like", "policies/gru")
    assert gru.method == "gru" and Path(gru.predictor) == ROOT / "policies" / "gru" / "predictor.pt"
    # Another method than the card's: the card's engine is not that method's.
    assert _resolved("--like", "pl-marl", "--method", "gru").predictor is None


def test_like_with_the_mission_as_given_drops_the_cards_walking_crowds_and_strips(capsys) -> None:
    args = _resolved("--like", "transit/pl-marl", "--scenarios", "mission")
    out = capsys.readouterr().out
    assert (args.moving_share, args.transit_share) == (0.0, 0.0)
    assert "moving share 0.5 does not apply" in out and "transit share 0.25 does not apply" in out


@pytest.mark.parametrize("like, said", [
    ("nosuch-dir", "--like nosuch-dir: no card.yaml there"),
    ("missions", "no card.yaml there"),
    ("CARD", "has no training config"),
    ("LIST", "has no training config"),
])
def test_a_wrong_like_is_one_line_and_exit_2(tmp_path: Path, monkeypatch, capsys, like: str, said: str) -> None:
    monkeypatch.chdir(tmp_path)
    if like in ("CARD", "LIST"):
        (tmp_path / "odd").mkdir()
        (tmp_path / "odd" / "card.yaml").write_text("method: pl-marl\n" if like == "CARD" else "- 1\n- 2\n")
        like = "odd"
    assert main(["train", "--like", like, "--out", "x"]) == 2
    err = capsys.readouterr().err
    assert said in err and "Traceback" not in err and len(err.strip().splitlines()) == 1, err

