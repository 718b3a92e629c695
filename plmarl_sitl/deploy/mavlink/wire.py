"""MAVLink wire constants that both ends of our links use: the agent's client sends them,
the autopilot emulator parses them. Written once so the two cannot drift apart."""

from __future__ import annotations

# type_mask bit groups of SET_POSITION_TARGET_LOCAL_NED (POSITION_TARGET_TYPEMASK): a set
# bit means "ignore this field".
MASK_POS, MASK_VEL, MASK_ACC = 0x007, 0x038, 0x1C0
MASK_FORCE_SET = 0x200  # accelerations are forces: refused by PX4 and by us

# Whole type_masks with only one group in use (yaw and yaw rate ignored), as MAVSDK sends
# them and as PX4/ArduPilot echo them in POSITION_TARGET_LOCAL_NED.
ACCEL_ONLY = 0x0C3F
VELOCITY_ONLY = 0x0DC7
POSITION_ONLY = 0x0DF8

# param2 of MAV_CMD_COMPONENT_ARM_DISARM that forces arming or disarming (PX4 and ArduPilot).
FORCE_ARM_MAGIC = 21196
