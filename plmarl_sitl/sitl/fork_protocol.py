"""What both ends of the agents' fork server agree on (`sitl/forked.py`, the launcher's end;
`sitl/forked_child.py`, the server's): imported by both, so neither imports the other."""

# One BLAS/OpenMP thread per agent, as `plmarl agent` sets. Read once, when numpy and torch
# load; a launcher that forks its server shares them with it, so it runs with one too.
THREADS_ENV = {"OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1"}
MAX_MESSAGE = 1 << 16  # one JSON message per SOCK_SEQPACKET record; a fork request is ~1 kB
SERVER_NAME = "plmarl-forksrv"  # what ps and top show for the server (not "plmarl-agent*": it is none)
