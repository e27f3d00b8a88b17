"""Suite-wide settings."""

from hypothesis import settings

# Property tests check logic, not speed: Hypothesis's default 200 ms per-example deadline would
# fail them on a stall of the shared 2-core CI machine (DESIGN.md: ms stalls happen, 50+ ms at times).
settings.register_profile("tvsd", deadline=None)
settings.load_profile("tvsd")
