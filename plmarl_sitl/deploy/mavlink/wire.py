"""MAVLink numbers that are conventions rather than dialect enums, written once.

Both sides use them: the client (`client.py`) to send, the autopilot emulator to read and
echo. The dialect names the type_mask *bits* of SET_POSITION_TARGET_LOCAL_NED one by one
(POSITION_TARGET_TYPEMASK); the groups and the masks real clients send are ours to spell.
"""

from __future__ import annotations

# POSITION_TARGET_TYPEMASK: a set bit means "ignore this field".
MASK_POS = 0x007  # x, y, z
MASK_VEL = 0x038  # vx, vy, vz
MASK_ACC = 0x1C0  # afx, afy, afz
MASK_FORCE_SET = 0x200  # afx..afz are a force, not an acceleration
# One group used, yaw and yaw rate ignored: the masks MAVSDK sends (and PX4 echoes).
POSITION_ONLY = 0x0DF8
VELOCITY_ONLY = 0x0DC7
ACCEL_ONLY = 0x0C3F

# param2 of MAV_CMD_COMPONENT_ARM_DISARM that forces arming/disarming (PX4 and ArduPilot).
FORCE_ARM_MAGIC = 21196
