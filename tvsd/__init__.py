"""tvsd — controller daemon, simulator and model doctor of the TVS laser scanner."""

__version__ = "0.1.0"
