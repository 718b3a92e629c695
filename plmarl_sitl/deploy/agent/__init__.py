"""The deployable agent (one process per UAV): see `core.Agent` and `plmarl agent`."""
