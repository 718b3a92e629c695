"""`plmarl train`: the inference engine and MAPPO for PL-MARL, GRU-MARL or TAG-MAPPO."""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from plmarl_sitl.cmdline import add_seed, progress
from plmarl_sitl.config import PAPER_MISSION
from plmarl_sitl.errors import UserError

METHODS = ("pl-marl", "gru", "tag-mappo")


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "train",
        help="train PL-MARL or a learnt baseline in the digital twin and export it",
        description="Train a method in the digital twin (MAPPO, CTDE, Table I hyperparameters) "
        "and export TorchScript files with a card to --out. pl-marl and gru first fit their "
        "inference engine (phi / GRU) on twin trajectories under the mixed-mobility curriculum, "
        "unless --predictor gives a trained state dict. The training curve goes to "
        "<out>/curve.jsonl (charts/... and losses/... scalars).",
        epilog="examples:\n  plmarl train --method pl-marl --seed 1 --out policies/pl-marl\n"
        "  plmarl train --method tag-mappo --episodes 50 --out runs/smoke",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--method", choices=METHODS, default="pl-marl")
    p.add_argument("--mission", default=str(PAPER_MISSION), help="mission YAML (default: the project's missions/paper_urban.yaml)")
    p.add_argument("--episodes", type=int, default=1000, help="training episodes (default: 1000, Table I)")
    add_seed(p, default=1)
    p.add_argument("--out", default=None, help="output directory (default: policies/<method>)")
    p.add_argument("--num-envs", type=int, default=16, help="parallel episodes per rollout (default: 16)")
    p.add_argument("--predictor", default=None, help="trained predictor state dict to reuse (skips the engine fit)")
    p.add_argument("--predictor-iters", type=int, default=None, help="engine fit iterations (default: 800 mlp / 300 gru)")
    p.add_argument("--eval-episodes", type=int, default=100, help="deterministic evaluation episodes for the card (0: skip)")
    p.add_argument("--threads", type=int, default=1, help="torch threads (default: 1; measured fastest here)")
    p.add_argument("--imitation-rounds", type=int, default=6,
                   help="imitation (DAgger) warm-start rounds before MAPPO; 0 = MAPPO from scratch (default: 6)")
    p.add_argument("--imitation-episodes", type=int, default=40, help="imitation episodes per round (default: 40)")
    p.add_argument("--imitation-tup-chunks", type=int, default=5,
                   help="split each imitation round into this many batches whose T_up cycle through 5..50 s, so every "
                   "T_up is imitated equally often; 1 = one random T_up per round (the pipeline before 2026-11-21) (default: 5)")
    p.add_argument("--scenarios", choices=("general", "mission"), default="general",
                   help="general: per rollout a random scenario (N 3..8, random connected layouts of 2..8 clusters, "
                   "random launch lines; the mission itself 15 %% of the time); mission: the mission as given (default: general)")
    p.add_argument("--policy-inputs", choices=("plan", "plan+map"), default="plan",
                   help="plan: the actor reads its own state, sensing, f, the neighbours' beliefs and the offset to its "
                   "team-plan point; the demand map reaches it only through the plan (a map-blind policy, the light "
                   "decision). plan+map: also the demand descriptor and an attention over the map's cells (the "
                   "generalising policies shipped before the map-blind ones; docs/POLICY_IO.md) (default: plan)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from plmarl_sitl.learning.pipeline import run_training  # heavy imports only when used

    if args.episodes < 1:
        raise UserError("--episodes must be >= 1")
    if args.predictor is not None and not Path(args.predictor).is_file():
        raise UserError(f"--predictor {args.predictor}: no such file")
    out = Path(args.out or f"policies/{args.method}")
    t0 = time.time()
    with progress() as bar:
        task = bar.add_task(f"{args.method} (seed {args.seed})", total=args.episodes)

        def on_iter(episodes: int, row: dict) -> None:
            bar.update(
                task,
                completed=episodes,
                description=f"{args.method} (seed {args.seed}) C={row['charts/coverage']:.3f}",
            )

        card = run_training(
            method=args.method,
            mission_path=args.mission,
            episodes=args.episodes,
            seed=args.seed,
            out=out,
            num_envs=args.num_envs,
            predictor_state=args.predictor,
            predictor_iters=args.predictor_iters,
            eval_episodes=args.eval_episodes,
            threads=args.threads,
            on_iter=on_iter,
            log=bar.console.print,
            args_overrides={"imitation_rounds": args.imitation_rounds, "imitation_episodes_per_round": args.imitation_episodes,
                            "imitation_tup_chunks": args.imitation_tup_chunks, "general": args.scenarios == "general",
                            "reads_map": args.policy_inputs == "plan+map"}
            | ({} if args.imitation_rounds else {"critic_warmup_iters": 0, "log_std_init": -0.5}),
        )
    tr = card["training"]
    print(f"{args.method}: {tr['episodes']} MAPPO episodes in {tr['mappo_wall_s']:.0f} s (+ engine {tr.get('predictor_wall_s', 0):.0f} s, "
          f"+ imitation {tr.get('imitation_wall_s', 0):.0f} s), wrote {out} ({time.time() - t0:.0f} s total)")
    if card.get("eval"):
        for row in card["eval"]["coverage"]:
            print(f"  T_up {row['tup']:>2}: coverage {row['coverage_mean']:.3f} [{row['coverage_ci95'][0]:.3f}, {row['coverage_ci95'][1]:.3f}]")
    return 0
