import sys, numpy as np
from plmarl_sitl.mission import load_mission
from plmarl_sitl.twin.env import CoverageEnv
m = load_mission(sys.argv[1]); env = CoverageEnv(m, 1, 0); obs = env.reset()
c = obs.demand[0]; c = c[c[:, 2] > 0]
np.savez(sys.argv[2], ego=obs.ego[0, 0].numpy(), held=obs.nbr_state[0, 0].numpy(), t_rx=obs.nbr_t_rx[0, 0].numpy(), cells=c.numpy())
