import os

os.environ.setdefault("MAVLINK20", "1")  # pymavlink's mavutil reads this at import time
