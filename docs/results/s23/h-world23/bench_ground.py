"""Ground.measure and Ground.sense of scale_20 (1,200 users, 20 UAVs at 60 m spread over the
area): best of 7, us per call; and a digest of their outputs over 300 random placements."""
import hashlib, timeit, sys
import torch
from plmarl_sitl.mission import load_mission
from plmarl_sitl.sitl.ground import Ground
m = load_mission("missions/scale_20.yaml")
class Outbox:
    cut = False
    def publish(self, topic, payload): self.out.append((topic, payload))
    def publish_retained(self, topic, payload): pass
class Wire:
    def sense(self, i, t_ms, inside): return repr((i, t_ms, inside))
    def demand(self, *a): return b""
class Topics:
    demand = "demand"
    def sense(self, i): return f"sense/{i}"
ob = Outbox(); ob.out = []
g = Ground(m, 0, ob, Wire(), Topics())
g.step_to(0)
gen = torch.Generator().manual_seed(1)
cases = []
for c in range(300):
    pos = torch.rand(20, 3, generator=gen) * torch.tensor([1000.0, 1000.0, 0.0]) + torch.tensor([0.0, 0.0, -60.0])
    if c % 3 == 0:
        pos[:, 2] = -torch.rand(20, generator=gen) * 120
    alive = torch.rand(20, generator=gen) > 0.1
    cases.append((pos.float(), alive))
h = hashlib.sha256()
for k, (pos, alive) in enumerate(cases):
    r = g.measure(pos, alive); h.update(repr(r).encode())
    ob.out.clear(); g.sense(1, pos, alive); h.update(repr(ob.out).encode())
print("digest", h.hexdigest()[:16], end="  ")
pos, alive = cases[1]
tm = min(timeit.repeat(lambda: g.measure(pos, alive), number=200, repeat=7)) / 200
ts = min(timeit.repeat(lambda: (ob.out.clear(), g.sense(1, pos, alive)), number=200, repeat=7)) / 200
from plmarl_sitl.model.coverage import covered_users
tc = min(timeit.repeat(lambda: covered_users(g.users.xy[0], pos, alive, g.radius(-pos[:, 2])), number=200, repeat=7)) / 200
print(f"measure {1e6 * tm:.0f} us (covered_users {1e6 * tc:.0f} us), sense {1e6 * ts:.0f} us")
