"""MAPPO for PL-MARL and its learnt baselines, CTDE, one file top to bottom (CleanRL style).

Decentralised actors (one shared attention policy, Sec. III-B) act on their own state,
their beliefs about neighbours (Algorithm 1's tracker with the method's predictor) and
their local user sensing. A centralised critic sees the twin's global state. The
reward is the twin's adaptive Eq. (4): its weights switch with the failure state f.

Methods differ only in the neighbour-belief engine (frozen during MAPPO):
  pl-marl    KinematicPredictor phi (trained by plmarl_sitl.learning.train.predictor)
  gru        GRUPredictor (GRU-MARL)
  tag-mappo  StaleHold: the last received state, no inference

Table I: 1000 episodes; from episode 500 on, p = 0.2 of one random node failing at
t = 100 s; lr 1e-4 (actor) / 5e-4 (critic) annealed linearly to 0.1x over 800 episodes;
minibatch 800 agent-decisions, 5 epochs, entropy 0.05 -> 0.02, gamma 0.99.
MAPPO details (Yu et al. 2022, on-policy repo): value normalisation (running mean/var of
returns), GAE, clipped value loss, advantage normalisation, and death masking: a failed
node's decisions are excluded from the actor loss (its actions are ignored by the twin).
"""

from __future__ import annotations

import dataclasses
import json
import math
import pickle
import random
import time
import zipfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch
from torch import nn

from plmarl_sitl.config import PAPER_MISSION
from plmarl_sitl.errors import UserError
from plmarl_sitl.learning.nn.belief import BeliefTracker
from plmarl_sitl.learning.nn.contract import PolicyForm
from plmarl_sitl.learning.nn.features import (
    DEMAND_BINS,
    EGO_FEATURES,
    FeatureScales,
    demand_descriptor,
    policy_input,
    ring_edges_sq,
)
from plmarl_sitl.learning.nn.perception import Perception
from plmarl_sitl.learning.nn.policy import Actor, Critic, action_to_accel
from plmarl_sitl.learning.nn.predictor import make_predictor
from plmarl_sitl.learning.train.scenarios import random_launch, trainer_scenario
from plmarl_sitl.learning.train.seeds import training_twin_seed
from plmarl_sitl.learning.train.trajectories import mixed_mobility
from plmarl_sitl.mission import Mission, load_mission
from plmarl_sitl.model.demand import cell_centres, demand_cells, demand_map
from plmarl_sitl.twin.env import CoverageEnv

METHOD_PREDICTOR = {"pl-marl": "mlp", "gru": "gru", "tag-mappo": "hold", "dead-reckoning": "cv"}


@dataclass
class Args:
    method: str = "pl-marl"
    mission: str = str(PAPER_MISSION)
    predictor_state: str | None = None  # state dict of the trained predictor (pl-marl, gru)
    seed: int = 1
    episodes: int = 1000
    num_envs: int = 16  # parallel episodes per rollout
    lr_actor: float = 1e-4
    lr_critic: float = 5e-4
    anneal_episodes: int = 800
    lr_min_ratio: float = 0.1
    gamma: float = 0.99
    gae_lambda: float = 0.95
    update_epochs: int = 5
    minibatch_size: int = 800  # agent-decisions
    clip_coef: float = 0.2
    vf_clip: float = 0.2
    ent_start: float = 0.05
    ent_end: float = 0.02
    vf_coef: float = 1.0
    max_grad_norm: float = 0.5
    failure_start_episode: int = 500
    failure_prob: float = 0.2
    failure_at_s: float = 100.0
    tup_choices: tuple[int, ...] = (5, 10, 15, 20, 25, 30, 35, 40, 45, 50)
    mixed_mobility: bool = True
    # Issue 12's training distribution: per rollout a scenario (N 3..8, random connected
    # layouts of 2..8 clusters; plmarl_sitl.learning.train.scenarios) and per environment a
    # random launch line. False: the mission as given, from its launch line.
    general: bool = True
    # Moving demand (issue 24.3): the share of training scenarios whose crowds walk 1.5-3 m/s far from
    # home (ScenarioArgs.moving_share); 0: the distribution of before.
    moving_share: float = 0.0
    # Long transits (issue 24.3, session 21): the share of training scenarios flown along a strip from a launch
    # 0.5-1.5 km short of its clusters (ScenarioArgs.transit_share); 0: the distribution of before.
    transit_share: float = 0.0
    # Oracle-imitation warm start (plmarl_sitl.learning.train.imitation), 0 rounds = MAPPO from scratch.
    imitation_rounds: int = 6
    imitation_episodes_per_round: int = 40
    imitation_tup_chunks: int = 5  # >1: every T_up imitated equally often (ImitationArgs.tup_chunks)
    imitation_teacher: str = "plan"  # ImitationArgs.teacher: "plan", "oracle" (greedy) or "react" (CTDE, issue 24)
    imitation_failures: str = "random"  # ImitationArgs.failures: "random" or "scripted"
    imitation_track_m: float = 30.0  # ImitationArgs.track_m: the "track" teacher's leash
    imitation_track_link: float = 0.95  # ImitationArgs.track_link_frac: its link length in R_comm
    critic_warmup_iters: int = 3  # first iterations update only the critic (after a warm start)
    embed_dim: int = 32
    # False: a map-blind actor (the plan target, own state, sensing, f, neighbours; no demand
    # descriptor or demand attention), the light decision. True: the map-reading actor.
    reads_map: bool = False
    log_std_init: float = -1.0  # std 0.37 of the normalised action after the warm start
    out: str = "runs/pl-marl"
    threads: int = 1
    checkpoint_every: int = 10  # iterations
    # Model selection: every `validate_every` iterations (and after the warm start) the
    # deterministic actor flies a fixed validation set of training-distribution scenarios
    # (seeds of the training range, never an evaluation seed); the best one is exported.
    # 0: export the last actor.
    validate_every: int = 8
    validation_batches: int = 4
    validation_envs: int = 6
    extra: dict = field(default_factory=dict)


class ValueNorm(nn.Module):
    """Running mean/variance of value targets (debiased EMA, as the on-policy MAPPO repo)."""

    def __init__(self, beta: float = 0.99999, eps: float = 1e-5) -> None:
        super().__init__()
        self.beta, self.eps = beta, eps
        self.register_buffer("mean", torch.zeros(()))
        self.register_buffer("mean_sq", torch.zeros(()))
        self.register_buffer("debias", torch.zeros(()))

    def stats(self) -> tuple[torch.Tensor, torch.Tensor]:
        d = torch.clamp(self.debias, min=self.eps)
        mean, mean_sq = self.mean / d, self.mean_sq / d
        return mean, torch.sqrt(torch.clamp(mean_sq - mean**2, min=1e-2))

    @torch.no_grad()
    def update(self, x: torch.Tensor) -> None:
        self.mean.mul_(self.beta).add_(x.mean() * (1 - self.beta))
        self.mean_sq.mul_(self.beta).add_((x**2).mean() * (1 - self.beta))
        self.debias.mul_(self.beta).add_(1 - self.beta)

    def normalize(self, x: torch.Tensor) -> torch.Tensor:
        mean, std = self.stats()
        return (x - mean) / std

    def denormalize(self, x: torch.Tensor) -> torch.Tensor:
        mean, std = self.stats()
        return x * std + mean


def make_tracker(method: str, mission: Mission, predictor_state: str | None) -> BeliefTracker | torch.jit.ScriptModule:
    """The frozen belief tracker MAPPO trains against: a fresh engine loaded from a state dict
    (what `fit_predictor` writes), or a shipped policy's own predictor.pt (a frozen TorchScript
    tracker, used as it is: the same module the agent will run)."""
    vm = mission.vehicle_model()
    sig = mission.signalling
    if predictor_state is not None and zipfile.is_zipfile(predictor_state) and _is_torchscript(predictor_state):
        tracker = torch.jit.load(predictor_state, map_location="cpu")
        if int(tracker.buffer_len) != sig.buffer_len or abs(float(tracker.dt) - mission.timing.dt_s) > 1e-9:
            raise UserError(f"--predictor {predictor_state}: made for buffer length {int(tracker.buffer_len)} and dt "
                            f"{float(tracker.dt):g} s; the mission has {sig.buffer_len} and {mission.timing.dt_s:g} s")
        return tracker
    pred = make_predictor(METHOD_PREDICTOR[method], sig.buffer_len, mission.timing.dt_s, vm.max_speed_mps, vm.max_accel_mps2)
    if predictor_state is not None:
        try:
            pred.load_state_dict(torch.load(predictor_state, weights_only=True))
        except (RuntimeError, pickle.UnpicklingError, KeyError) as exc:
            raise UserError(f"--predictor {predictor_state}: not a {METHOD_PREDICTOR[method]} engine's state dict nor a "
                            f"policy's predictor.pt ({str(exc).splitlines()[0][:120]})") from None
    elif method in ("pl-marl", "gru"):
        raise ValueError(f"method {method} needs a trained predictor (predictor_state)")
    pred.eval()
    for p in pred.parameters():
        p.requires_grad_(False)
    return BeliefTracker(pred, sig.buffer_len, mission.timing.dt_s)


def _is_torchscript(path: str) -> bool:
    """A TorchScript archive holds its code beside the weights (a state dict does not)."""
    with zipfile.ZipFile(path) as z:
        return any(n.split("/", 1)[-1].startswith("code/") for n in z.namelist())


CRITIC_EXTRA = DEMAND_BINS + 3  # uncovered-user descriptor, C(t), t / T, global f


def critic_input(env: CoverageEnv, ego_x: torch.Tensor, scales: FeatureScales) -> torch.Tensor:
    """(B, N, EGO_FEATURES + CRITIC_EXTRA): the agent-specific global state of MAPPO (Yu et
    al. 2022) with a size independent of N and of the clusters: agent i's own policy
    features, plus (training-time knowledge only) the users NOT covered right now, binned
    around agent i like the demand map, the coverage C(t), the episode time and f."""
    m = env.mission
    counts = demand_map(env.users.xy, m.area.north_m, m.area.east_m, m.demand.cell_m, user_valid=~env.covered)
    cells = demand_cells(counts, cell_centres(m.area.north_m, m.area.east_m, m.demand.cell_m, env.dtype))
    cells = cells.unsqueeze(1).expand(-1, env.n, -1, -1)
    no_claims = torch.zeros(env.num_envs, env.n, 1, dtype=torch.bool)
    desc = demand_descriptor(env.pos, cells, env.pos.unsqueeze(-2), no_claims, scales.claim_m, scales.demand_unit, ring_edges_sq())
    tail = torch.stack([env.covered.to(env.dtype).mean(-1), torch.full((env.num_envs,), env.t / env.horizon),
                        env.failed.to(env.dtype)], -1)
    return torch.cat([ego_x, desc[..., :DEMAND_BINS], tail.unsqueeze(1).expand(-1, env.n, -1)], -1)


def validation_set(args: Args, mission: Mission) -> list[tuple[Mission, int]]:
    """Fixed (scenario, twin seed) pairs drawn like training rollouts, from their own stream."""
    rng = np.random.default_rng(args.seed + 7_777)
    tups = [int(x) for x in np.linspace(min(args.tup_choices), max(args.tup_choices), args.validation_batches)]
    out = []
    for j, tup in enumerate(tups):
        scenario = trainer_scenario(mission, rng, args)
        out.append((scenario.with_tup(tup), training_twin_seed(args.seed * 100_003 + 90_000 + j)))
    return out


@torch.no_grad()
def validate(actor: Actor, tracker: BeliefTracker, scales: FeatureScales, sets: list[tuple[Mission, int]], envs: int,
             general: bool) -> float:
    """Mean coverage of the deterministic actor over the validation set (no failures)."""
    covs = []
    for m, seed in sets:
        env = CoverageEnv(m, envs, seed, random_launch=random_launch(m, general))
        obs = env.reset()
        perceive = Perception(tracker, PolicyForm.trained(actor.reads_map), scales.r_comm, m)
        while not env.done:
            u = actor(*policy_input(scales, perceive(obs)))
            obs, _, info = env.step(action_to_accel(u, scales.a_max))
            covs.append(info.coverage.mean())
    return float(torch.stack(covs).mean())


def linear(start: float, end: float, frac: float) -> float:
    return start + (end - start) * min(max(frac, 0.0), 1.0)


def train(args: Args, progress=None, on_imitation_round=None) -> dict:  # noqa: ANN001 - callbacks
    # ------------------------------------------------------------------ seeding, setup
    random.seed(args.seed)
    np.random.seed(args.seed)
    torch.manual_seed(args.seed)
    torch.set_num_threads(args.threads)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    base = load_mission(args.mission)
    mission = mixed_mobility(base) if args.mixed_mobility else base
    scales = FeatureScales.from_mission(mission)
    B = args.num_envs
    T = math.ceil(mission.timing.episode_s / mission.timing.dt_s / mission.timing.decision_every_s)  # decisions per episode
    G = EGO_FEATURES + CRITIC_EXTRA
    tracker = make_tracker(args.method, mission, args.predictor_state)
    actor = Actor(args.embed_dim, log_std_init=args.log_std_init, reads_map=args.reads_map)
    critic = Critic(G)
    vnorm = ValueNorm()
    warm: dict = {}
    if args.imitation_rounds > 0:
        from plmarl_sitl.learning.train.imitation import ImitationArgs, imitate_oracle

        warm = imitate_oracle(
            actor, tracker, mission,
            ImitationArgs(rounds=args.imitation_rounds, episodes_per_round=args.imitation_episodes_per_round, seed=args.seed,
                          tup_chunks=args.imitation_tup_chunks, general=args.general, teacher=args.imitation_teacher,
                          failures=args.imitation_failures, moving_share=args.moving_share, transit_share=args.transit_share,
                          track_m=args.imitation_track_m, track_link_frac=args.imitation_track_link),
            on_round=on_imitation_round,
        )
    opt_a = torch.optim.Adam(actor.parameters(), lr=args.lr_actor, eps=1e-5)
    opt_c = torch.optim.Adam(critic.parameters(), lr=args.lr_critic, eps=1e-5)
    iterations = math.ceil(args.episodes / B)
    rng = np.random.default_rng(args.seed)

    val_sets = validation_set(args, mission) if args.validate_every > 0 else []
    best = {"coverage": -1.0, "episodes": 0, "actor": None}

    def select(episodes: int) -> float:
        cov = validate(actor, tracker, scales, val_sets, args.validation_envs, args.general)
        if cov > best["coverage"]:
            best.update(coverage=cov, episodes=episodes, actor={k: v.clone() for k, v in actor.state_dict().items()})
        return cov

    if val_sets:
        best["after_warm_start"] = select(0)
    curve_path = out / "curve.jsonl"
    curve_f = curve_path.open("w")
    t_start = time.time()
    episodes_done = 0
    summary: dict = {}
    for it in range(iterations):
        # -------------------------------------------------------------- schedules
        frac_lr = episodes_done / max(args.anneal_episodes, 1)
        lr_mult = linear(1.0, args.lr_min_ratio, frac_lr)
        for g in opt_a.param_groups:
            g["lr"] = args.lr_actor * lr_mult
        for g in opt_c.param_groups:
            g["lr"] = args.lr_critic * lr_mult
        ent_coef = linear(args.ent_start, args.ent_end, episodes_done / max(args.episodes, 1))
        tup = int(rng.choice(args.tup_choices))
        p_fail = args.failure_prob if episodes_done >= args.failure_start_episode else 0.0
        scenario = trainer_scenario(mission, rng, args)
        env = CoverageEnv(scenario.with_tup(tup), B, training_twin_seed(args.seed * 100_003 + it), failure_prob=p_fail,
                          failure_at_s=args.failure_at_s, random_launch=random_launch(scenario, args.general))
        N = env.n

        # -------------------------------------------------------------- rollout buffers (N varies per rollout)
        inputs_b: list[tuple[torch.Tensor, ...]] = []  # the actor's inputs per step (policy_input)
        act_b = torch.zeros(T, B, N, 3)
        logp_b = torch.zeros(T, B, N)
        live_b = torch.zeros(T, B, N, dtype=torch.bool)
        gs_b = torch.zeros(T, B, N, G)
        val_b = torch.zeros(T, B, N)  # normalised values, one per agent (shared reward)
        rew_b = torch.zeros(T, B)
        cov_b = torch.zeros(T, B)

        # -------------------------------------------------------------- rollout
        obs = env.reset()
        perceive = Perception(tracker, PolicyForm.trained(args.reads_map), scales.r_comm, scenario)
        cov_last = []
        with torch.no_grad():
            for step in range(T):
                x = policy_input(scales, perceive(obs))
                gs = critic_input(env, x[0], scales)
                dist = actor.dist(*x)
                u = dist.sample()
                inputs_b.append(x)
                act_b[step], logp_b[step] = u, dist.log_prob(u).sum(-1)
                live_b[step], gs_b[step], val_b[step] = obs.alive, gs, critic(gs)
                obs, reward, info = env.step(action_to_accel(u, scales.a_max))
                rew_b[step] = reward
                cov_b[step] = info.coverage.mean(-1)
                if obs.t > 50:
                    cov_last.append(info.coverage.mean(-1))

            # ---------------------------------------------------------- GAE (terminal at T)
            values = vnorm.denormalize(val_b)
            adv = torch.zeros(T, B, N)
            last = torch.zeros(B, N)
            for step in reversed(range(T)):
                next_v = values[step + 1] if step + 1 < T else torch.zeros(B, N)
                delta = rew_b[step].unsqueeze(-1) + args.gamma * next_v - values[step]
                last = delta + args.gamma * args.gae_lambda * last
                adv[step] = last
            returns = adv + values
            vnorm.update(returns[live_b])
            ret_n = vnorm.normalize(returns)
        episodes_done += B

        # -------------------------------------------------------------- flatten, death mask
        live = live_b.flatten()
        idx_all = torch.nonzero(live).flatten()
        f_inputs = [torch.stack(parts).flatten(0, 2) for parts in zip(*inputs_b, strict=True)]
        f_act, f_logp = act_b.flatten(0, 2), logp_b.flatten(0, 2)
        f_adv = adv.flatten()
        f_gs, f_val, f_ret = gs_b.flatten(0, 2), val_b.flatten(), ret_n.flatten()

        # -------------------------------------------------------------- PPO update
        stats = {"pg": [], "v": [], "ent": [], "kl": [], "clipfrac": []}
        for _epoch in range(args.update_epochs):
            perm = idx_all[torch.randperm(len(idx_all))]
            for lo in range(0, len(perm), args.minibatch_size):
                mb = perm[lo : lo + args.minibatch_size]
                if len(mb) < 2:
                    continue
                rows = mb  # per-agent critic: the same sample row
                dist = actor.dist(*(x[mb] for x in f_inputs))
                logp = dist.log_prob(f_act[mb]).sum(-1)
                ratio = (logp - f_logp[mb]).exp()
                a = f_adv[mb]
                a = (a - a.mean()) / (a.std() + 1e-8)
                pg = torch.max(-a * ratio, -a * torch.clamp(ratio, 1 - args.clip_coef, 1 + args.clip_coef)).mean()
                ent = dist.entropy().sum(-1).mean()
                v = critic(f_gs[rows])
                v_old = f_val[rows]
                v_clip = v_old + torch.clamp(v - v_old, -args.vf_clip, args.vf_clip)
                v_loss = torch.max((v - f_ret[rows]) ** 2, (v_clip - f_ret[rows]) ** 2).mean()
                opt_a.zero_grad()
                opt_c.zero_grad()
                actor_on = it >= args.critic_warmup_iters
                ((pg - ent_coef * ent) * float(actor_on) + args.vf_coef * v_loss).backward()
                nn.utils.clip_grad_norm_(actor.parameters(), args.max_grad_norm)
                nn.utils.clip_grad_norm_(critic.parameters(), args.max_grad_norm)
                if actor_on:
                    opt_a.step()
                opt_c.step()
                with torch.no_grad():
                    log_ratio = logp - f_logp[mb]
                    stats["kl"].append(float(((ratio - 1) - log_ratio).mean()))
                    stats["clipfrac"].append(float(((ratio - 1).abs() > args.clip_coef).float().mean()))
                stats["pg"].append(float(pg.detach()))
                stats["v"].append(float(v_loss.detach()))
                stats["ent"].append(float(ent.detach()))

        # -------------------------------------------------------------- logging
        wall = time.time() - t_start
        row = {
            "iteration": it,
            "episodes": episodes_done,
            "wall_s": round(wall, 2),
            "charts/episodic_return": float(rew_b.sum(0).mean()),
            "charts/coverage": float(cov_b.mean()),
            "charts/coverage_steady": float(torch.stack(cov_last).mean()) if cov_last else float("nan"),
            "charts/tup": tup,
            "charts/n_uavs": N,
            "charts/clusters": env.mission.users.n_clusters,
            "charts/failure_prob": p_fail,
            "charts/lr_actor": args.lr_actor * lr_mult,
            "charts/ent_coef": ent_coef,
            "charts/action_std": float(actor.log_std.detach().exp().mean()),
            "charts/SPS": episodes_done * T * N / max(wall, 1e-9),
            "losses/policy_loss": float(np.mean(stats["pg"])),
            "losses/value_loss": float(np.mean(stats["v"])),
            "losses/entropy": float(np.mean(stats["ent"])),
            "losses/approx_kl": float(np.mean(stats["kl"])),
            "losses/clipfrac": float(np.mean(stats["clipfrac"])),
        }
        if val_sets and ((it + 1) % args.validate_every == 0 or it == iterations - 1):
            row["charts/validation_coverage"] = select(episodes_done)
        curve_f.write(json.dumps(row) + "\n")
        curve_f.flush()
        summary = row
        if progress is not None:
            progress(episodes_done, row)
        if (it + 1) % args.checkpoint_every == 0 or it == iterations - 1:
            torch.save(
                {"actor": actor.state_dict(), "critic": critic.state_dict(), "vnorm": vnorm.state_dict(),
                 "iteration": it, "episodes": episodes_done, "args": dataclasses.asdict(args)},
                out / "checkpoint.pt",
            )
    curve_f.close()
    selection = {k: v for k, v in best.items() if k != "actor"}
    if best["actor"] is not None:
        actor.load_state_dict(best["actor"])  # the exported actor is the validated best
    return {"selection": selection, "actor": actor, "critic": critic, "tracker": tracker, "wall_s": time.time() - t_start,
            "episodes": episodes_done, "last": summary, "curve": str(curve_path), "imitation": warm}
