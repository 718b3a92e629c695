import time, torch
g = torch.Generator().manual_seed(0)
users = (torch.rand(1200, 2, generator=g, dtype=torch.float64) * 1000).float()  # scale_20: 1200 users? (per mission)
pos = torch.cat([torch.rand(20, 2, generator=g, dtype=torch.float64) * 1000, -torch.full((20, 1), 60.0, dtype=torch.float64)], 1).float()
alive = torch.ones(20, dtype=torch.bool)
try:
    from plmarl_sitl.sitl.ground import sensed_users
    def sense(): sensed_users(users, pos, alive, 150.0)
except ImportError:
    def sense():
        for i in range(20):
            if not bool(alive[i]): continue
            d = users - pos[i, :2]; users[(d * d).sum(-1) <= 150.0**2].tolist()
sense(); t = time.process_time()
for _ in range(2000): sense()
print(f"sensing {(time.process_time()-t)/2000*1e6:.0f} us")
