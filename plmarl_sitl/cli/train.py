"""`plmarl train`: the inference engine and MAPPO for PL-MARL, GRU-MARL or TAG-MAPPO."""

from __future__ import annotations

import argparse
import math
import time
from pathlib import Path

from plmarl_sitl.cmdline import add_seed, progress
from plmarl_sitl.config import PAPER_MISSION, PROJECT_POLICIES
from plmarl_sitl.errors import UserError

METHODS = ("pl-marl", "gru", "tag-mappo")

# The recipe: flags whose value, when not given, comes from --like's card, else from here (the
# letter's Table I and the pipeline's defaults; the help texts read their defaults from here).
RECIPE_DEFAULTS = {
    "method": "pl-marl", "episodes": 1000, "num_envs": 16, "imitation_rounds": 6, "imitation_episodes": 40,
    "imitation_tup_chunks": 5, "teacher": "plan", "teacher_track_m": 30.0, "teacher_track_link": 0.95,
    "moving_share": 0.0, "transit_share": 0.0, "scenarios": "general", "policy_inputs": "plan",
}


def recipe_from_card(card: dict) -> dict:
    """The training recipe a policy's card records (its `config`: the trainer's Args), as this
    command's flags; the seed, mission and output are the new run's own."""
    c = card.get("config") if isinstance(card, dict) else None
    if not isinstance(c, dict) or c.get("method") not in METHODS:
        raise ValueError("its card.yaml has no training config (`config.method`): not a policy `plmarl train` wrote")
    keys = {"method": "method", "episodes": "episodes", "num_envs": "num_envs", "imitation_rounds": "imitation_rounds",
            "imitation_episodes": "imitation_episodes_per_round", "imitation_tup_chunks": "imitation_tup_chunks",
            "teacher": "imitation_teacher", "teacher_track_m": "imitation_track_m",
            "teacher_track_link": "imitation_track_link", "moving_share": "moving_share",
            "transit_share": "transit_share"}
    recipe = {flag: c[key] for flag, key in keys.items() if key in c}
    if "general" in c:
        recipe["scenarios"] = "general" if c["general"] else "mission"
    if "reads_map" in c:
        recipe["policy_inputs"] = "plan+map" if c["reads_map"] else "plan"
    return recipe


def resolve_recipe(args: argparse.Namespace) -> None:
    """Fill the recipe's flags not given: from --like DIR's card, else RECIPE_DEFAULTS; with
    --like, also the engine (DIR/predictor.pt) unless --predictor gives one."""
    recipe: dict = {}
    if args.like is not None:
        import yaml

        # A directory here, else a shipped policy by name ("pl-marl", "plan/pl-marl") or by its
        # path in the project ("policies/pl-marl"), from any directory.
        like = next((d for d in (Path(args.like), PROJECT_POLICIES / args.like, PROJECT_POLICIES.parent / args.like)
                     if d.is_dir()), Path(args.like))
        args.like = str(like)
        card = like / "card.yaml"
        if not card.is_file():
            raise UserError(f"--like {like}: no card.yaml there (give a trained policy's directory, e.g. policies/pl-marl)")
        try:
            recipe = recipe_from_card(yaml.safe_load(card.read_text()) or {})
        except (ValueError, yaml.YAMLError) as exc:
            raise UserError(f"--like {like}: {str(exc).splitlines()[0]}") from None
    from_card = {flag for flag in RECIPE_DEFAULTS if getattr(args, flag) is None and flag in recipe}
    for flag, default in RECIPE_DEFAULTS.items():
        if getattr(args, flag) is None:
            setattr(args, flag, recipe.get(flag, default))
    for share in ("moving_share", "transit_share"):
        if args.scenarios == "mission" and share in from_card and getattr(args, share) > 0:
            # Walking crowds and strips are drawn only in the general scenarios; the mission as given keeps its own.
            print(f"--like {args.like}: its {share.replace('_', ' ')} {getattr(args, share):g} does not apply with "
                  "--scenarios mission")
            setattr(args, share, 0.0)
    if args.like is not None and args.predictor is None and args.method in ("pl-marl", "gru") \
            and recipe.get("method") == args.method and (Path(args.like) / "predictor.pt").is_file():
        args.predictor = str(Path(args.like) / "predictor.pt")


def register(sub: argparse._SubParsersAction) -> None:
    D = RECIPE_DEFAULTS
    p = sub.add_parser(
        "train",
        help="train PL-MARL or a learnt baseline in the digital twin and export it",
        description="Train a method in the digital twin (MAPPO, CTDE, Table I hyperparameters) "
        "and export TorchScript files with a card to --out. pl-marl and gru first fit their "
        "inference engine (phi / GRU) on twin trajectories under the mixed-mobility curriculum, "
        "unless --predictor gives one: a policy's predictor.pt (e.g. policies/pl-marl/predictor.pt) "
        "or an engine state dict an earlier run wrote (runs/work/<out>-seed<S>/predictor_mlp_state.pt). "
        "The training curve goes to <out>/curve.jsonl (charts/... and losses/... scalars); "
        "engine state and MAPPO checkpoints to runs/work/.",
        epilog="examples:\n  plmarl train --method pl-marl --seed 1                  # -> runs/train/pl-marl-seed1\n"
        "  plmarl train --method pl-marl --predictor policies/pl-marl/predictor.pt --episodes 200\n"
        "  plmarl train --method tag-mappo --episodes 50 --out runs/smoke\n"
        "  plmarl train --like policies/pl-marl --seed 2 --out runs/mine  # the shipped policy's recipe, a new seed\n"
        "  plmarl train --like policies/pl-marl --mission my_site.yaml     # ... with your site among the scenarios\n"
        "  plmarl train --method pl-marl --out policies/pl-marl --force   # replace the shipped policy",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--like", metavar="DIR", default=None,
                   help="train with the recipe a trained policy's card records (DIR/card.yaml: method, episodes, "
                   "imitation, teacher, scenarios, policy inputs) and its engine (DIR/predictor.pt); flags given here "
                   "win. `--like policies/pl-marl` is how the shipped default was trained (default: none, the flags' "
                   "own defaults: Table I)")
    p.add_argument("--method", choices=METHODS, default=None, help=f"the method (default: {D['method']})")
    p.add_argument("--mission", default=str(PAPER_MISSION), help="mission YAML (default: the project's missions/paper_urban.yaml)")
    p.add_argument("--episodes", type=int, default=None, help=f"training episodes (default: {D['episodes']}, Table I)")
    add_seed(p, default=1)
    p.add_argument("--out", default=None, help="output directory (default: runs/train/<method>-seed<S>)")
    p.add_argument("--force", action="store_true",
                   help="write over a trained policy in --out (a card.yaml there, or anything under the project's policies/)")
    p.add_argument("--num-envs", type=int, default=None, help=f"parallel episodes per rollout (default: {D['num_envs']})")
    p.add_argument("--predictor", default=None,
                   help="a trained engine to reuse, skipping the fit: a policy's predictor.pt or an engine state dict")
    p.add_argument("--predictor-iters", type=int, default=None, help="engine fit iterations (default: 800 mlp / 300 gru)")
    p.add_argument("--eval-episodes", type=int, default=100, help="deterministic evaluation episodes for the card (0: skip)")
    p.add_argument("--threads", type=int, default=1, help="torch threads (default: 1; measured fastest here)")
    p.add_argument("--imitation-rounds", type=int, default=None,
                   help="warm-start rounds imitating the team-plan follower (`service`; DAgger-style: the student "
                   "flies, the plan follower labels its states) before MAPPO; 0 = MAPPO from scratch "
                   f"(default: {D['imitation_rounds']})")
    p.add_argument("--imitation-episodes", type=int, default=None, help=f"imitation episodes per round (default: {D['imitation_episodes']})")
    p.add_argument("--imitation-tup-chunks", type=int, default=None,
                   help="split each imitation round into this many batches whose T_up cycle through 5..50 s, so every "
                   "T_up is imitated equally often; 1 = one random T_up per round (the pipeline before 2026-11-21) "
                   f"(default: {D['imitation_tup_chunks']})")
    p.add_argument("--teacher", choices=("plan", "react", "track"), default=None,
                   help="the imitation teacher: plan, fly to your own point of the team plan (what the student has); "
                   "react (CTDE, issue 24): the plan re-solved the second a UAV fails from the survivors' true positions, "
                   "with 1-2 UAVs failing in every imitation batch at a random second in 20..160 s; "
                   "track (CTDE, issue 24.3): your plan point moved toward the users you sense by at most --teacher-track-m, "
                   "each UAV in turn as far as the team's true chosen points stay linked (0.95 R_comm) and spaced (2 R_s), "
                   "a check no deployed UAV can make; the student still sees the unshifted plan point "
                   f"(default: {D['teacher']})")
    p.add_argument("--teacher-track-m", type=float, default=None,
                   help=f"the track teacher's leash in metres (default: {D['teacher_track_m']:g})")
    p.add_argument("--teacher-track-link", type=float, default=None,
                   help="the track teacher's link margin as a fraction of R_comm: a pair linked in the plan stays linked while "
                   "it is at most this far apart (or its plan distance, if longer); below 0.95 it leaves room for the "
                   "student's imitation error "
                   f"(default: {D['teacher_track_link']:g}, the plan's own link length)")
    p.add_argument("--moving-share", type=float, default=None,
                   help="with --scenarios general: the share of training scenarios with moving demand, RPGM crowds walking "
                   "1.5-3 m/s up to 200-400 m from home (users.rpgm_range_m), recorded in the card "
                   f"(default: {D['moving_share']:g}, none)")
    p.add_argument("--transit-share", type=float, default=None,
                   help="with --scenarios general: the share of training scenarios with a long transit, the clusters a "
                   "chain along a strip 350-600 m wide and the launch across it 0.5-1.5 km short of the first cluster "
                   "(300-s episodes), recorded in the card "
                   f"(default: {D['transit_share']:g}, none)")
    p.add_argument("--scenarios", choices=("general", "mission"), default=None,
                   help="general: per rollout a random scenario (N 3..8, random connected layouts of 2..8 clusters, "
                   "random launch lines; the mission itself 15 %% of the time); mission: the mission as given "
                   f"(default: {D['scenarios']})")
    p.add_argument("--policy-inputs", choices=("plan", "plan+map"), default=None,
                   help="plan: the actor reads its own state, sensing, f, the neighbours' beliefs and the offset to its "
                   "team-plan point; the demand map reaches it only through the plan (a map-blind policy, the light "
                   "decision). plan+map: also the demand descriptor and an attention over the map's cells (the "
                   "generalising policies shipped before the map-blind ones; docs/POLICY_IO.md) "
                   f"(default: {D['policy_inputs']})")
    p.set_defaults(func=run)


def _check_out(out: Path, force: bool) -> None:
    """Never write over a trained policy (a card.yaml in --out, or the project's shipped
    policies) without --force; an --out that is a file is a mistake."""
    if out.exists() and not out.is_dir():
        raise UserError(f"--out {out}: exists and is not a directory")
    if force:
        return
    shipped = out.resolve().is_relative_to(PROJECT_POLICIES.resolve())
    if (out / "card.yaml").exists() or shipped:
        what = "the project's shipped policies" if shipped else "a trained policy"
        raise UserError(f"--out {out}: would write over {what}; give another --out, or --force to replace it")


def run(args: argparse.Namespace) -> int:
    resolve_recipe(args)  # a wrong --like is said before torch loads
    from plmarl_sitl.learning.pipeline import EVAL_TUPS, engine_iters, run_training  # heavy imports only when used
    from plmarl_sitl.mission import load_mission

    if args.episodes < 1:
        raise UserError("--episodes must be >= 1")
    if args.predictor is not None and not Path(args.predictor).is_file():
        raise UserError(f"--predictor {args.predictor}: no such file")
    if args.num_envs < 1:
        raise UserError("--num-envs must be >= 1")
    if not 0.0 <= args.moving_share <= 1.0:
        raise UserError(f"--moving-share {args.moving_share:g}: must be in [0, 1]")
    if args.moving_share > 0 and args.scenarios != "general":
        raise UserError("--moving-share needs --scenarios general (the mission as given keeps its own users)")
    if not 0.0 <= args.transit_share <= 1.0:
        raise UserError(f"--transit-share {args.transit_share:g}: must be in [0, 1]")
    if args.transit_share > 0 and args.scenarios != "general":
        raise UserError("--transit-share needs --scenarios general (the mission as given keeps its own area and launch)")
    if not args.teacher_track_m > 0:
        raise UserError(f"--teacher-track-m {args.teacher_track_m:g}: must be > 0")
    if not 0.0 < args.teacher_track_link <= 1.0:
        raise UserError(f"--teacher-track-link {args.teacher_track_link:g}: must be in (0, 1]")
    out = Path(args.out or f"runs/train/{args.method}-seed{args.seed}")
    _check_out(out, args.force)
    t0 = time.time()
    # MAPPO runs whole rollouts of --num-envs episodes: the bar's total is what it will run.
    total = math.ceil(args.episodes / args.num_envs) * args.num_envs
    with progress() as bar:
        fits_engine = args.method in ("pl-marl", "gru") and args.predictor is None
        engine = (bar.add_task("inference engine fit", total=engine_iters("mlp" if args.method == "pl-marl" else "gru",
                                                                          args.predictor_iters)) if fits_engine else None)
        teacher = {"plan": "the plan follower", "react": "re-plans at each failure with true states",
                   "track": "follows its sensed users as far as the team stays linked"}[args.teacher]
        imitation = (bar.add_task(f"imitation (DAgger; teacher: {teacher})", total=args.imitation_rounds)
                     if args.imitation_rounds > 0 else None)
        task = bar.add_task(f"{args.method} (seed {args.seed})", total=total)
        evaluation = None
        if args.eval_episodes > 0:
            timing = load_mission(args.mission).timing
            decisions = math.ceil(timing.episode_s / timing.decision_every_s)
            evaluation = bar.add_task(f"evaluation: {args.eval_episodes} episodes at T_up {', '.join(map(str, EVAL_TUPS))} s",
                                      total=decisions * args.eval_episodes * len(EVAL_TUPS))

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
            on_engine_iter=None if engine is None else lambda done: bar.update(engine, completed=done),
            on_imitation_round=None if imitation is None else lambda done: bar.update(imitation, completed=done),
            on_eval_decision=None if evaluation is None else lambda b: bar.advance(evaluation, b),
            log=bar.console.print,
            args_overrides={"imitation_rounds": args.imitation_rounds, "imitation_episodes_per_round": args.imitation_episodes,
                            "imitation_tup_chunks": args.imitation_tup_chunks, "general": args.scenarios == "general",
                            "reads_map": args.policy_inputs == "plan+map", "imitation_teacher": args.teacher,
                            "imitation_failures": "scripted" if args.teacher == "react" else "random",
                            "imitation_track_m": args.teacher_track_m,
                            "imitation_track_link": args.teacher_track_link, "moving_share": args.moving_share,
                            "transit_share": args.transit_share}
            | ({} if args.imitation_rounds else {"critic_warmup_iters": 0, "log_std_init": -0.5}),
        )
    tr = card["training"]
    print(f"{args.method}: {tr['episodes']} MAPPO episodes in {tr['mappo_wall_s']:.0f} s (+ engine {tr.get('predictor_wall_s', 0):.0f} s, "
          f"+ imitation {tr.get('imitation_wall_s', 0):.0f} s), wrote {out} ({time.time() - t0:.0f} s total)")
    if card.get("eval"):
        for row in card["eval"]["coverage"]:
            print(f"  T_up {row['tup']:>2}: coverage {row['coverage_mean']:.3f} [{row['coverage_ci95'][0]:.3f}, {row['coverage_ci95'][1]:.3f}]")
    return 0
