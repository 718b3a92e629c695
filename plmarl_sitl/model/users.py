"""Ground users: cluster layouts and mobility (Gauss-Markov, Random Waypoint, RPGM).

All users move on the ground plane (north, east), at most `max_speed_mps`, and reflect
off the area's boundary. Batched over environments. Per-user 2-vectors are stored
*planar*, (B, 2, U): every update is then elementwise on contiguous (B, U) planes, which
is several times faster than the interleaved (B, U, 2) layout on the twin's hot path.
`UserState.xy` gives the (B, U, 2) view the rest of the toolkit uses.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
import torch

from plmarl_sitl.config import ConfigError
from plmarl_sitl.mission import Mission, Users
from plmarl_sitl.model.vehicle import clip_norm

MOBILITY_KINDS = ("gauss_markov", "random_waypoint", "rpgm")
_RWP_PAUSE_MAX_S = 10.0
_GROUP_RADIUS_STD = 2.0  # RPGM reference points roam within this many cluster std of home
RPGM_GROUP_SPEED = 0.6  # an RPGM group's reference point walks at this share of the users' max_speed_mps


@dataclass(frozen=True)
class UserState:
    pos: torch.Tensor  # (B, 2, U) metres, planar
    vel: torch.Tensor  # (B, 2, U) m/s
    home: torch.Tensor  # (B, 2, U) centre of the user's cluster
    kind: torch.Tensor  # (B,) index into MOBILITY_KINDS
    waypoint: torch.Tensor  # (B, 2, U) RWP target
    pause: torch.Tensor  # (B, U) RWP seconds left to wait
    speed: torch.Tensor  # (B, U) RWP leg speed
    group_ref: torch.Tensor  # (B, 2, U) RPGM reference point of the user's group
    group_wp: torch.Tensor  # (B, 2, U) RPGM target of that reference point
    offset: torch.Tensor  # (B, 2, U) RPGM user offset from the reference

    @property
    def xy(self) -> torch.Tensor:
        """(B, U, 2) positions (a view of the planar storage)."""
        return self.pos.transpose(-1, -2)


def cluster_centres(mission: Mission, batch: int, gen: torch.Generator) -> torch.Tensor:
    """(B, C, 2) cluster centres for the mission's layout."""
    u, area = mission.users, mission.area
    c = u.n_clusters
    if u.layout == "fixed":
        centres = torch.tensor(u.cluster_centers, dtype=torch.float64)
        return centres.unsqueeze(0).expand(batch, c, 2).clone()
    if u.layout == "lattice":
        cols = math.ceil(math.sqrt(c))
        rows = math.ceil(c / cols)
        pts = [(r, k) for r in range(rows) for k in range(cols)][:c]
        grid = torch.tensor(pts, dtype=torch.float64) * u.cluster_spacing_m
        grid -= grid.mean(0)
        grid += torch.tensor([area.north_m / 2, area.east_m / 2], dtype=torch.float64)
        return grid.unsqueeze(0).expand(batch, c, 2).clone()
    return _random_connected_centres(mission, batch, gen)


def _random_connected_centres(mission: Mission, batch: int, gen: torch.Generator) -> torch.Tensor:
    """Random layouts a connected swarm can still cover: each new centre is placed
    0.55-0.8 R_comm from an earlier one and at least 2 R_s from all others. Many clusters
    in a small area (20 in 1 km^2) jam this sequential draw; those layouts are grown on a
    randomly turned and shifted triangular lattice instead (`_lattice_grown_centres`)."""
    u, r = mission.users, mission.radii
    if u.n_clusters > 1 and 2 * r.sensing_m > 0.8 * r.comm_m:
        raise ConfigError(
            "users.layout",
            f"'random' places clusters 2 R_s apart within 0.8 R_comm of another; "
            f"radii.sensing_m {r.sensing_m:g} is too large for radii.comm_m {r.comm_m:g}",
        )
    rng = np.random.default_rng(int(torch.randint(0, 2**31 - 1, (1,), generator=gen)))
    margin = min(r.sensing_m + 2 * u.cluster_std_m, 0.3 * min(mission.area.north_m, mission.area.east_m))
    lo = np.array([margin, margin])
    hi = np.array([mission.area.north_m - margin, mission.area.east_m - margin])
    out = np.zeros((batch, u.n_clusters, 2))
    # The sequential draw jams long before the clusters fill the area: it found 18 of 20
    # layouts of 12 clusters in 1 km^2, 4 of 20 of 13 and none of 14, 0.6-0.75 s of failed
    # tries each. Past 0.6 of the disk-packing bound of its box it is not tried.
    d = 2 * r.sensing_m
    packing = (hi[0] - lo[0] + d) * (hi[1] - lo[1] + d) * 2 / (math.sqrt(3) * d * d)
    tries = 100 if u.n_clusters <= 0.6 * packing else 0
    for b in range(batch):
        for _attempt in range(tries):
            pts = [rng.uniform(lo, hi)]
            for _ in range(u.n_clusters - 1):
                for _try in range(200):
                    base = pts[rng.integers(len(pts))]
                    ang = rng.uniform(0, 2 * np.pi)
                    dist = rng.uniform(0.55, 0.8) * r.comm_m
                    p = base + dist * np.array([np.cos(ang), np.sin(ang)])
                    far = np.linalg.norm(np.asarray(pts) - p, axis=-1).min() >= 2 * r.sensing_m
                    if far and np.all(p >= lo) and np.all(p <= hi):
                        pts.append(p)
                        break
                else:
                    break
            if len(pts) == u.n_clusters:
                out[b] = np.array(pts)
                break
        else:
            out[b] = _lattice_grown_centres(mission, margin, rng)
    return torch.from_numpy(out)


def _lattice_grown_centres(mission: Mission, margin: float, rng: np.random.Generator) -> np.ndarray:
    """(C, 2) centres on a triangular lattice of side s = max(2 R_s, 0.55 R_comm) (so
    neighbours are 0.55-0.8 R_comm apart and all others >= 2 R_s), turned and shifted at
    random, grown as a random connected set of lattice sites inside the area. The margin
    from the area's edge shrinks towards the cluster spread until the clusters fit."""
    u, r, area = mission.users, mission.radii, mission.area
    side = max(2 * r.sensing_m, 0.55 * r.comm_m) * (1 + 1e-6)
    span = max(area.north_m, area.east_m) * 1.5
    k = int(span / side) + 2
    i, j = np.meshgrid(np.arange(-k, k + 1), np.arange(-k, k + 1), indexing="ij")
    unit = np.stack([i + 0.5 * j, j * math.sqrt(3) / 2], -1).reshape(-1, 2) * side  # (S, 2)
    centre = np.array([area.north_m / 2, area.east_m / 2])
    for edge in np.linspace(margin, min(margin, u.cluster_std_m), 4):
        lo, hi = np.array([edge, edge]), np.array([area.north_m - edge, area.east_m - edge])
        for _try in range(50):
            a = rng.uniform(0, 2 * np.pi)
            rot = np.array([[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]])
            sites = unit @ rot.T + centre + rng.uniform(-side / 2, side / 2, 2)
            sites = sites[np.all((sites >= lo) & (sites <= hi), -1)]
            if len(sites) < u.n_clusters:
                continue
            adj = np.linalg.norm(sites[:, None] - sites[None], axis=-1) <= side * 1.01
            chosen = [int(rng.integers(len(sites)))]
            while len(chosen) < u.n_clusters:
                frontier = np.nonzero(adj[chosen].any(0) & ~np.isin(np.arange(len(sites)), chosen))[0]
                if len(frontier) == 0:
                    break
                chosen.append(int(rng.choice(frontier)))
            if len(chosen) == u.n_clusters:
                return sites[chosen]
    raise ConfigError(
        "users.layout",
        f"'random': {u.n_clusters} clusters 2 R_s apart do not fit in the {area.north_m:g} x {area.east_m:g} m "
        "area; enlarge area, or use fewer clusters (users.count / users.cluster_size) or layout lattice",
    )


def _uniform(gen: torch.Generator, shape: tuple[int, ...], lo: float, hi: float, like: torch.Tensor) -> torch.Tensor:
    return lo + (hi - lo) * torch.rand(shape, generator=gen, dtype=like.dtype).to(like.device)


def _in_disk_planar(gen: torch.Generator, centre: torch.Tensor, radius: float) -> torch.Tensor:
    """Uniform points in disks around planar (B, 2, K) centres."""
    return _in_disk(gen, centre.transpose(-1, -2), radius).transpose(-1, -2)


def _in_disk(gen: torch.Generator, centre: torch.Tensor, radius: float) -> torch.Tensor:
    shape = centre.shape[:-1]
    r = radius * torch.sqrt(torch.rand(shape, generator=gen, dtype=centre.dtype))
    a = 2 * math.pi * torch.rand(shape, generator=gen, dtype=centre.dtype)
    return centre + torch.stack([r * torch.cos(a), r * torch.sin(a)], -1)


def init_users(
    mission: Mission, batch: int, gen: torch.Generator, dtype: torch.dtype = torch.float32, device: str = "cpu"
) -> UserState:
    u = mission.users
    centres = cluster_centres(mission, batch, gen)  # (B, C, 2) float64
    home = centres.repeat_interleave(u.cluster_size, dim=1)  # (B, U, 2)
    pos = home + u.cluster_std_m * torch.randn(home.shape, generator=gen, dtype=home.dtype)
    for k, size in enumerate((mission.area.north_m, mission.area.east_m)):
        pos[..., k] = _fold(pos[..., k], size)[0]
    if u.mobility == "mixed":
        kind = torch.randint(0, len(MOBILITY_KINDS), (batch,), generator=gen)
    else:
        kind = torch.full((batch,), MOBILITY_KINDS.index(u.mobility), dtype=torch.long)
    wp_radius = 2.5 * u.cluster_std_m
    waypoint = _in_disk(gen, home, wp_radius)
    speed = _uniform(gen, home.shape[:-1], 0.1 * u.max_speed_mps, u.max_speed_mps, home)
    pause = _uniform(gen, home.shape[:-1], 0.0, _RWP_PAUSE_MAX_S, home)
    group_ref = centres.repeat_interleave(u.cluster_size, dim=1)
    group_wp = _group_waypoints(_in_disk(gen, centres, _group_range(u)), mission).repeat_interleave(u.cluster_size, dim=1)
    offset = pos - group_ref
    sigma_v = 0.5 * u.max_speed_mps
    vel = clip_norm(sigma_v * torch.randn(home.shape, generator=gen, dtype=home.dtype), u.max_speed_mps)

    def cast(x: torch.Tensor) -> torch.Tensor:
        if x.is_floating_point() and x.dim() == 3:  # (B, U, 2) -> planar (B, 2, U)
            x = x.transpose(-1, -2).contiguous()
        return x.to(device=device, dtype=dtype if x.is_floating_point() else x.dtype)

    return UserState(*(cast(x) for x in (pos, vel, home, kind, waypoint, pause, speed, group_ref, group_wp, offset)))


def _clip_planar(v: torch.Tensor, vmax: float) -> torch.Tensor:
    """Clip planar (B, 2, U) vectors to norm <= vmax."""
    n2 = v[:, 0] * v[:, 0] + v[:, 1] * v[:, 1]
    return v * torch.clamp(vmax * torch.rsqrt(torch.clamp(n2, min=1e-24)), max=1.0).unsqueeze(1)


def _norm_planar(v: torch.Tensor) -> torch.Tensor:
    return torch.sqrt(v[:, 0] * v[:, 0] + v[:, 1] * v[:, 1])


def _fold(p: torch.Tensor, size: float) -> tuple[torch.Tensor, torch.Tensor]:
    """Reflect coordinates into [0, size] off both walls, for any excursion: fold into
    [0, 2 size) and mirror the upper half. Also returns where the number of mirrors is
    odd, i.e. where the velocity along this axis flips."""
    folded = torch.remainder(p, 2.0 * size)
    flipped = folded > size
    return torch.where(flipped, 2.0 * size - folded, folded), flipped


def _reflect(pos: torch.Tensor, vel: torch.Tensor, mission: Mission) -> tuple[torch.Tensor, torch.Tensor]:
    """Reflect planar positions that left the area back inside and flip that velocity
    component."""
    sizes = (mission.area.north_m, mission.area.east_m)
    # Fast path: users seldom touch the edge; two reductions are cheaper than folding.
    if all(float(pos[:, k].min()) >= 0.0 and float(pos[:, k].max()) <= size for k, size in enumerate(sizes)):
        return pos, vel
    out_p, out_v = torch.empty_like(pos), torch.empty_like(vel)
    for k, size in enumerate(sizes):
        out_p[:, k], flipped = _fold(pos[:, k], size)
        out_v[:, k] = torch.where(flipped, -vel[:, k], vel[:, k])
    return out_p, out_v


def _gauss_markov_vel(s: UserState, u: Users, dt: float, gen: torch.Generator) -> torch.Tensor:
    alpha = u.gm_alpha**dt
    sigma_v = 0.5 * u.max_speed_mps
    noise = torch.randn(s.vel.shape, generator=gen, dtype=s.vel.dtype).to(s.vel.device)
    return torch.add(noise.mul_(math.sqrt(max(0.0, 1 - alpha * alpha)) * sigma_v), s.vel, alpha=alpha)


def _group_range(u: Users) -> float:
    """Radius around home within which an RPGM group picks its waypoints."""
    return u.rpgm_range_m if u.rpgm_range_m > 0 else _GROUP_RADIUS_STD * u.cluster_std_m


def _group_waypoints(wp: torch.Tensor, mission: Mission) -> torch.Tensor:
    """(..., 2) RPGM waypoints; with a set `rpgm_range_m` clamped into the area (a wide range
    reaches past the edge; the default range never does, and its draws stay bit for bit)."""
    if mission.users.rpgm_range_m <= 0:
        return wp
    hi = torch.tensor([mission.area.north_m, mission.area.east_m], dtype=wp.dtype)
    return torch.minimum(torch.clamp(wp, min=0.0), hi)


def _rwp_step(s: UserState, u: Users, dt: float, gen: torch.Generator) -> tuple[torch.Tensor, ...]:
    """Random waypoint inside the user's cluster disk: go, arrive, pause, pick again."""
    to_wp = s.waypoint - s.pos
    dist = _norm_planar(to_wp)
    moving = s.pause <= 0
    arrive = moving & (s.speed * dt >= dist)
    vel = torch.where(moving.unsqueeze(1), to_wp / torch.clamp(dist, min=1e-9).unsqueeze(1) * s.speed.unsqueeze(1), 0 * to_wp)
    vel = torch.where(arrive.unsqueeze(1), to_wp / dt, vel)
    new_wp = _in_disk_planar(gen, s.home.double(), 2.5 * u.cluster_std_m).to(s.pos.dtype)
    waypoint = torch.where(arrive.unsqueeze(1), new_wp, s.waypoint)
    new_pause = _uniform(gen, s.pause.shape, 0.0, _RWP_PAUSE_MAX_S, s.pause)
    new_speed = _uniform(gen, s.speed.shape, 0.1 * u.max_speed_mps, u.max_speed_mps, s.speed)
    pause = torch.where(arrive, new_pause, torch.clamp(s.pause - dt, min=0.0))
    speed = torch.where(arrive, new_speed, s.speed)
    return vel, waypoint, pause, speed


def _rpgm_step(s: UserState, mission: Mission, dt: float, gen: torch.Generator) -> tuple[torch.Tensor, ...]:
    """Reference Point Group Mobility: the group's reference point does a slow random
    waypoint walk around the cluster home (within `rpgm_range_m`); each user follows it at its own offset."""
    u = mission.users
    group_speed = RPGM_GROUP_SPEED * u.max_speed_mps
    to_wp = s.group_wp - s.group_ref
    dist = _norm_planar(to_wp).unsqueeze(1)
    ref_vel = to_wp / torch.clamp(dist, min=1e-9) * torch.clamp(dist / dt, max=group_speed)
    group_ref = s.group_ref + ref_vel * dt
    arrived = dist.squeeze(1) <= group_speed * dt
    # All users of a cluster share the reference point: draw one new target per cluster.
    new_wp = _in_disk_planar(gen, s.home[..., :: u.cluster_size].double(), _group_range(u))
    if u.rpgm_range_m > 0:
        new_wp = _group_waypoints(new_wp.transpose(-1, -2), mission).transpose(-1, -2)
    new_wp = new_wp.to(s.pos.dtype).repeat_interleave(u.cluster_size, dim=-1)
    group_wp = torch.where(arrived.unsqueeze(1), new_wp, s.group_wp)
    local = _clip_planar((group_ref + s.offset - s.pos) / 5.0, 0.4 * u.max_speed_mps)
    return ref_vel + local, group_ref, group_wp


def step_users(s: UserState, mission: Mission, dt: float, gen: torch.Generator) -> UserState:
    """Advance all users by `dt` seconds; speed stays <= max and positions in the area."""
    u = mission.users
    present = set(int(k) for k in torch.unique(s.kind)) if u.mobility == "mixed" else {MOBILITY_KINDS.index(u.mobility)}
    vel = torch.zeros_like(s.vel)
    fields: dict[str, torch.Tensor] = {}

    def select(k: int, new: torch.Tensor, old: torch.Tensor) -> torch.Tensor:
        if len(present) == 1:
            return new
        m = (s.kind == k).view(-1, *([1] * (new.dim() - 1)))  # per-environment choice
        return torch.where(m, new, old)

    if 0 in present:
        vel = select(0, _gauss_markov_vel(s, u, dt, gen), vel)
    if 1 in present:
        v1, wp, pause, speed = _rwp_step(s, u, dt, gen)
        vel = select(1, v1, vel)
        fields.update(waypoint=select(1, wp, s.waypoint), pause=select(1, pause, s.pause), speed=select(1, speed, s.speed))
    if 2 in present:
        v2, ref, gwp = _rpgm_step(s, mission, dt, gen)
        vel = select(2, v2, vel)
        fields.update(group_ref=select(2, ref, s.group_ref), group_wp=select(2, gwp, s.group_wp))
    vel = _clip_planar(vel, u.max_speed_mps)
    pos, vel = _reflect(s.pos + vel * dt, vel, mission)
    return replace(s, pos=pos, vel=vel, **fields)
