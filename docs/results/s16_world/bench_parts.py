"""Per-call CPU of the world's pieces this session changed, on the checkout in PYTHONPATH."""
import time, numpy as np, torch
from plmarl_sitl.model.vehicle import Limits
from plmarl_sitl.sitl.autopilot.fleet import Fleet
from plmarl_sitl.sitl.autopilot.guidance import Kind
def per_call(fn, n):
    t = time.process_time()
    for _ in range(n): fn()
    return (time.process_time() - t) / n * 1e6
lim = Limits(20.0, 5.0, 0.0, 120.0)
rng = np.random.default_rng(0)
p0 = np.column_stack([rng.normal(size=(20, 2)) * 100, -np.full(20, 60.0)]); v0 = rng.normal(size=(20, 3))
tg = rng.normal(size=(20, 3)) * 0.5
f = Fleet(20, lim, {}); f.guidance.max_speed[:] = 20; f.guidance.max_accel[:] = 5; f.guidance.drag[:] = 1.0
for i in range(20): f.guidance.set(i, Kind.ACCEL, tuple(tg[i]))
def quiet():
    f.pos_np, f.vel_np = p0.copy(), v0.copy(); f.step_many(0.02, 5)
g = Fleet(20, lim, {}); g.guidance.max_speed[:] = 5; g.guidance.max_accel[:] = 5
g.pos_np[:] = np.column_stack([rng.normal(size=(20, 2)) * 100, -rng.uniform(0, 30, 20)])
for i in range(20): g.guidance.set(i, Kind.POSITION, (0.0, 0.0, -60.0))
gp, gv = g.pos_np.copy(), g.vel_np.copy()
def climb():
    g.pos_np, g.vel_np = gp.copy(), gv.copy(); g.pos, g.vel = torch.from_numpy(g.pos_np), torch.from_numpy(g.vel_np); g.step(0.02)
users = (torch.rand(3000, 2, dtype=torch.float64) * 1000).float()
pos = torch.cat([torch.rand(20, 2, dtype=torch.float64) * 1000, -torch.full((20, 1), 60.0, dtype=torch.float64)], 1).float()
alive = torch.ones(20, dtype=torch.bool)
try:
    from plmarl_sitl.sitl.ground import sensed_users
    def sense(): sensed_users(users, pos, alive, 150.0)
except ImportError:
    def sense():
        for i in range(20):
            d = users - pos[i, :2]; users[(d * d).sum(-1) <= 150.0**2].tolist()
for name, fn, n in (("quiet 5 substeps, PX4 drag", quiet, 3000), ("climb substep (position loops)", climb, 2000), ("sensing, 20 vehicles x 3000 users", sense, 1000)):
    fn()
    print(f"{name:36s} {per_call(fn, n):8.0f} us")
